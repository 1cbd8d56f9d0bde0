"""The main job as a library call: a log to corrected marker maps, scored and written out."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gtsam
import numpy as np

from markergraph.estimator import (
    Estimate,
    Form,
    Frames,
    MapError,
    Method,
    TrajectoryError,
    build_frames,
    estimate_frames,
    map_error,
    trajectory_error,
)
from markergraph.estimator.slam import build_slam_graph
from markergraph.estimator.types import MarkerGraphError
from markergraph.frontend.config import MapConfig, map_config
from markergraph.frontend.files import REPORT_SCHEMA, result_folder
from markergraph.frontend.formats import (
    estimate_values,
    map_document,
    write_g2o,
    write_json,
    write_tum,
)
from markergraph.frontend.overlay import write_overlay
from markergraph.frontend.pipeline import Extraction, extract

__all__ = ["MapRun", "MethodResult", "map_log", "write_results"]


@dataclass
class MethodResult:
    """One method's map, and its error against ground truth when the log carries it."""

    method: Method
    estimate: Estimate
    map_error: MapError | None = None
    map_error_aligned: MapError | None = None
    trajectory_error: TrajectoryError | None = None
    true_path: np.ndarray | None = None  # (N, 3) true poses at the estimate's stamps

    @property
    def label(self) -> str:
        return self.method.value


@dataclass
class MapRun:
    """Everything the main job produced.

    Attributes:
        log: the log read.
        config: the settings it was read and estimated with.
        extraction: the front end's output.
        frames: the estimator's input.
        results: one per method, in the order asked.
        true_markers: ground truth ``T_map_marker`` in the estimate's map frame (empty for a
            real log).
        seconds: stage -> wall time.
    """

    log: Path
    config: MapConfig
    extraction: Extraction
    frames: Frames
    results: list[MethodResult]
    true_markers: dict[int, gtsam.Pose2] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)


def _truth_in_home_frame(extraction: Extraction, home_id: int) -> dict[int, gtsam.Pose2]:
    """Logged true marker poses re-expressed in the frame of the estimate's home marker."""
    truth = extraction.true_markers
    if home_id not in truth:
        return {}
    T_home_map = truth[home_id].inverse()
    return {i: T_home_map.compose(T) for i, T in truth.items()}


def _true_trajectory(extraction: Extraction, home_id: int, t_ns: np.ndarray) -> np.ndarray | None:
    """The true base poses at the given stamps, in the home marker's frame, if logged."""
    poses = extraction.true_poses
    truth = extraction.true_markers
    if len(poses) < 2 or home_id not in truth or len(t_ns) == 0:
        return None
    T_home_map = truth[home_id].inverse()
    rows = []
    for t in t_ns:
        i = int(np.clip(np.searchsorted(poses[:, 0], t), 1, len(poses) - 1))
        nearest = i if abs(poses[i, 0] - t) < abs(poses[i - 1, 0] - t) else i - 1
        T = T_home_map.compose(gtsam.Pose2(*poses[nearest, 1:]))
        rows.append([T.x(), T.y(), T.theta()])
    return np.array(rows)


def map_log(
    log: Path,
    config: MapConfig | None = None,
    *,
    progress: Callable[[int, int], None] | None = None,
) -> MapRun:
    """Read a log, estimate the map with each method, and score it when ground truth is logged.

    Raises:
        MarkerGraphError: the log cannot be read, has no marker observations, or no odometry.
    """
    config = config or map_config()
    seconds: dict[str, float] = {}
    start = time.perf_counter()
    extraction = extract(log, config.frontend, progress=progress, workers=config.workers)
    seconds["front end"] = time.perf_counter() - start
    if not extraction.observations:
        left_out = sorted(extraction.ids_left_out)
        raise MarkerGraphError(
            f"{log}: no markers of {config.frontend.dictionary} were found in "
            f"{extraction.frames} frames"
            + (
                f" (markers {', '.join(map(str, left_out))} were seen but are not in --ids)"
                if left_out
                else ""
            )
        )
    if not extraction.odometry:
        raise MarkerGraphError(
            f"{log}: no odometry (no nav_msgs/Odometry topic and no odom -> base transforms on /tf)"
        )
    seen = {o.marker_id for o in extraction.observations}
    if len(seen) == 1:
        extraction.notes.append(
            f"only marker {seen.pop()} was seen: the map is that marker alone, with the robot's "
            "path in its frame; there is nothing to link"
        )
    frames = build_frames(
        extraction.observations,
        extraction.odometry,
        config.home_id,
        odometry_noise=config.odometry_noise,
    )
    truth = _truth_in_home_frame(extraction, frames.home_id)
    results = []
    for method in config.methods:
        start = time.perf_counter()
        estimate = estimate_frames(
            frames,
            method,
            extraction.mount.T_base_camera,
            form=Form.SIGNED,
            robust=config.robust,
        )
        seconds[method.value] = time.perf_counter() - start
        result = MethodResult(method, estimate)
        if truth and set(estimate.markers) & set(truth):
            result.map_error = map_error(estimate, truth)
            if len(estimate.markers) >= 2:
                result.map_error_aligned = map_error(estimate, truth, align=True)
            result.true_path = _true_trajectory(
                extraction, frames.home_id, estimate.trajectory_t_ns
            )
            if result.true_path is not None and len(result.true_path) >= 2:
                result.trajectory_error = trajectory_error(estimate.trajectory, result.true_path)
        results.append(result)
    return MapRun(Path(log), config, extraction, frames, results, truth, seconds)


def _report(run: MapRun) -> dict[str, Any]:
    extraction = run.extraction
    report: dict[str, Any] = {
        "schema": REPORT_SCHEMA,
        "log": str(run.log),
        "frames": extraction.frames,
        "frames_with_depth": extraction.frames_with_depth,
        "observations": len(extraction.observations),
        "markers_seen": len({o.marker_id for o in extraction.observations}),
        "odometry_samples": len(extraction.odometry),
        "skipped_frames": dict(extraction.skipped),
        "undecodable_frames": extraction.undecodable_frames,
        "unusable_depth_images": extraction.unusable_depth,
        "notes": extraction.notes + extraction.warnings,
        "ground_truth": bool(run.true_markers),
        "seconds": run.seconds,
        "settings": dict(run.config.values),
        "methods": {},
    }
    for result in run.results:
        entry: dict[str, Any] = {
            "markers_placed": len(result.estimate.markers),
            "links": len(result.estimate.links),
            "unplaced": {str(k): v for k, v in result.estimate.unplaced.items()},
            "converged": result.estimate.converged,
            "notes": result.estimate.notes,
        }
        if result.map_error is not None:
            entry["marker_rmse_m"] = result.map_error.rmse_position_m
            entry["marker_yaw_rmse_rad"] = result.map_error.rmse_yaw_rad
        if result.map_error_aligned is not None:
            entry["marker_rmse_aligned_m"] = result.map_error_aligned.rmse_position_m
        if result.trajectory_error is not None:
            entry["ate_m"] = result.trajectory_error.ate_rmse_m
            entry["rpe_m_per_m"] = result.trajectory_error.rpe_rmse_m_per_m
        report["methods"][result.label] = entry
    return report


def write_results(run: MapRun, out: Path, *, force: bool = False, plots: bool = True) -> list[Path]:
    """The result folder, written whole or not at all
    (:func:`~markergraph.frontend.files.result_folder`); an existing one is replaced only with
    ``force``, and only if markergraph wrote it or it is empty.

    Files: ``map.json``, ``map.g2o`` (graph methods), ``map.png`` and ``map.svg`` for the first
    method, and ``overlay.mcap`` (its map and trajectory as ROS 2 messages, to show over the
    log); ``methods/<method>/`` with the same for every method when there are several, and
    ``comparison.png``; TUM trajectories (estimated per method, odometry, ground truth);
    ``report.json``.

    Returns:
        The files written, relative to ``out``.

    Raises:
        OutputError: ``out`` may not be replaced, or another run wrote it meanwhile.
    """
    with result_folder(Path(out), force=force) as folder:
        _write_all(run, folder, plots)
        written = sorted(p.relative_to(folder) for p in folder.rglob("*") if p.is_file())
    return written


def _write_method(run: MapRun, result: MethodResult, folder: Path, plots: bool) -> None:
    config = run.config.frontend
    write_json(
        folder / "map.json",
        map_document(
            result.estimate,
            log=str(run.log),
            dictionary=config.dictionary,
            marker_length_m=config.marker_length_m,
            marker_lengths_m=config.marker_lengths_m,
        ),
    )
    if result.method in (Method.SLAM, Method.ISAM2):
        graph, _, _ = build_slam_graph(run.frames, run.extraction.mount.T_base_camera)
        write_g2o(folder / "map.g2o", graph, estimate_values(result.estimate))
    if len(result.estimate.trajectory):
        write_tum(
            folder / "trajectory.tum", result.estimate.trajectory_t_ns, result.estimate.trajectory
        )
    if plots:
        from markergraph.frontend.plots import plot_map

        plot_map(
            result.estimate,
            run.true_markers,
            folder / "map.png",
            odometry=run.extraction.odometry,
            truth_path=result.true_path,
        )


def _write_all(run: MapRun, folder: Path, plots: bool) -> None:
    first = run.results[0]
    _write_method(run, first, folder, plots)
    if len(run.results) > 1:
        for result in run.results:
            method_folder = folder / "methods" / result.label
            method_folder.mkdir(parents=True)
            _write_method(run, result, method_folder, plots)
        if plots:
            from markergraph.frontend.plots import plot_comparison

            plot_comparison(
                [(r.label, r.estimate) for r in run.results],
                run.true_markers,
                folder / "comparison.png",
            )
    odometry = run.extraction.odometry
    write_overlay(folder / "overlay.mcap", first.estimate, odometry)
    write_tum(
        folder / "odometry.tum",
        np.array([s.t_ns for s in odometry], dtype=np.int64),
        np.array([[s.x, s.y, s.yaw] for s in odometry]).reshape(-1, 3),
    )
    true_t = run.extraction.true_poses[:, 0].astype(np.int64)
    true_path = _true_trajectory(run.extraction, run.frames.home_id, true_t)
    if true_path is not None:
        write_tum(folder / "ground_truth.tum", true_t, true_path)
    write_json(folder / "report.json", _report(run))
