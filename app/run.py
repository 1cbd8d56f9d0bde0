"""The main job as a library call: a log to corrected marker maps, scored when the log carries
ground truth."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import gtsam
import numpy as np

from markergraph.common.errors import EstimationError, MarkerGraphError
from markergraph.estimator import (
    Estimate,
    Form,
    Frames,
    MapError,
    MarkerHeight,
    Method,
    Observation,
    OdometryNoise,
    SlamInputs,
    Trajectory,
    TrajectoryError,
    build_frames,
    camera_delay_by_residuals,
    ellipse_coverage,
    estimate_frames,
    map_error,
    marker_heights,
    odometry_scale_by_residuals,
    retimed,
    trajectory_error,
    widened_for_motion,
)
from markergraph.frontend import Extraction, extract
from markergraph.markermap import MarkerMap
from markergraph.sections import Shutter
from markergraph.settings import MapConfig
from markergraph.verdicts import Judgement, Verdict, judge_run

__all__ = ["MapRun", "MethodResult", "judge", "map_log"]


@dataclass
class MethodResult:
    """One method's map, and its error against ground truth when the log carries it.

    Attributes:
        method: the method.
        estimate: what it estimated.
        marker_map: the estimate as a map (what map.json holds).
        map_error, map_error_aligned: marker errors in the home frame, and after the best
            rigid alignment.
        trajectory_error: ATE and RPE at the estimate's stamps.
        true_path: the true base poses at the estimate's stamps, in the home marker's frame.
        inside_95_ellipse: the share of true markers inside the estimate's 95 % ellipses (None
            without covariances or truth): 0.95 when they are honest.
        judgement: how far the estimate can be trusted, and why (:mod:`markergraph.verdicts`).
    """

    method: Method
    estimate: Estimate
    marker_map: MarkerMap
    map_error: MapError | None = None
    map_error_aligned: MapError | None = None
    trajectory_error: TrajectoryError | None = None
    true_path: Trajectory | None = None
    inside_95_ellipse: float | None = None
    judgement: Judgement = field(default_factory=lambda: Judgement(Verdict.OK))

    @property
    def label(self) -> str:
        return self.method.value


class Prepared(NamedTuple):
    """One log made ready for the estimators (:func:`prepare`).

    Attributes:
        observations: at their capture times, sigmas widened for blur if asked.
        frames: the estimators' input, on the scaled odometry.
        camera_delay_ns: the camera's delay used [ns].
        odometry_source: the odometry noise model used.
        odometry_scale: what the odometry's distances were multiplied by.
    """

    observations: list[Observation]
    frames: Frames
    camera_delay_ns: int
    odometry_source: str
    odometry_scale: float


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
        true_path: the true base path in the estimate's map frame, if logged.
        camera_delay_ns: how late the camera's stamps were taken to be against odometry [ns].
        odometry_source: the odometry noise model used (``wheel``, ``vio``, ``t265``).
        odometry_scale: what the odometry's distances were multiplied by.
        seconds: stage -> wall time.
        sessions: with several logs, each log and its trajectory in the map.
        separate: maps of logs that share no marker with this one: (their logs, the map).
        judgement: the run's verdict: the gravest of its methods', each reason naming its
            method (:func:`judge`).
    """

    log: Path
    config: MapConfig
    extraction: Extraction
    frames: Frames
    results: list[MethodResult]
    true_markers: dict[int, gtsam.Pose2] = field(default_factory=dict)
    true_path: Trajectory | None = None
    camera_delay_ns: int = 0
    odometry_source: str = "wheel"
    odometry_scale: float = 1.0
    seconds: dict[str, float] = field(default_factory=dict)
    sessions: list[Any] = field(default_factory=list)
    separate: list[tuple[list[Path], MarkerMap]] = field(default_factory=list)
    judgement: Judgement = field(default_factory=lambda: Judgement(Verdict.OK))


def judge(run: MapRun) -> MapRun:
    """Give the run and each of its methods a verdict from the run's own evidence."""
    run.judgement, per_method = judge_run(
        [result.estimate for result in run.results], run.extraction,
        camera_delay_ns=run.camera_delay_ns, odometry_scale=run.odometry_scale,
        delay_searched=run.config.camera.delay_ns is None,
        scale_searched=run.config.odometry.scale is None,
    )  # fmt: skip
    for result in run.results:
        result.judgement = per_method[result.method]
    return run


def truth_in_home_frame(
    extraction: Extraction, home_id: int
) -> tuple[dict[int, gtsam.Pose2], Trajectory | None]:
    """A log's ground truth (markers, path) in the frame of the map's home marker, when it
    carries both; ``({}, None)`` otherwise."""
    if home_id not in extraction.true_markers:
        return {}, None
    T_home_world = extraction.true_markers[home_id].inverse()
    truth = {i: T_home_world.compose(T) for i, T in extraction.true_markers.items()}
    path = extraction.true_path.in_frame(T_home_world, "map") if len(extraction.true_path) else None
    return truth, path


def marker_map_of(
    estimate: Estimate,
    log: str,
    config: MapConfig,
    heights: Mapping[int, MarkerHeight] | None = None,
    extraction: Extraction | None = None,
) -> MarkerMap:
    """An estimate's marker map with the settings' dictionary and the marker sides used: the
    extraction's where given (depth may have measured them), else the settings'."""
    sizes = config.marker_sizes
    if extraction is not None and extraction.marker_sizes_used is not None:
        sizes = extraction.marker_sizes_used
    return MarkerMap.from_estimate(
        estimate, log=log, dictionary=config.dictionary, marker_sizes=sizes, heights=heights
    )


def _score(result: MethodResult, truth: dict[int, gtsam.Pose2], path: Trajectory | None) -> None:
    """Marker and trajectory errors against the logged truth, where it covers the estimate."""
    estimate = result.estimate
    if not truth or not set(estimate.markers) & set(truth):
        return
    result.map_error = map_error(estimate, truth)
    coverage = ellipse_coverage(estimate, truth)
    result.inside_95_ellipse = None if math.isnan(coverage.share) else coverage.share
    if len(estimate.markers) >= 2:
        result.map_error_aligned = map_error(estimate, truth, align=True)
    result.trajectory_error, result.true_path = path_error(estimate.trajectory, path)


def path_error(
    trajectory: Trajectory, path: Trajectory | None
) -> tuple[TrajectoryError | None, Trajectory | None]:
    """An estimated trajectory's error against the true path at its own stamps, and that true
    path (None where the truth does not cover two of them)."""
    if path is None or len(path) < 2:
        return None, None
    true_path = path.at_stamps(trajectory.t_ns)
    if len(true_path) < 2:
        return None, true_path
    covered = np.isin(trajectory.t_ns, true_path.t_ns)
    return trajectory_error(trajectory.poses[covered], true_path.poses), true_path


def _timed(
    extraction: Extraction,
    config: MapConfig,
    noise: OdometryNoise,
    breaks: list[int],
    home_id: int | None,
) -> tuple[list[Observation], int]:
    """The observations at their capture times (the camera's delay, chosen by the residuals
    unless set, and a rolling shutter's row delays), sigmas widened for blur and, if asked,
    for the shutter instead; and the camera's delay used [ns]."""
    camera = config.camera
    observations = extraction.observations
    readout_ns = camera.readout_ns
    height = extraction.camera.height if extraction.camera is not None else 0
    window_s = camera.exposure_s
    if camera.shutter is Shutter.WIDEN:
        window_s += readout_ns * 1e-9
        readout_ns = 0
    if window_s > 0:
        observations = widened_for_motion(observations, extraction.odometry, window_s)
    if camera.delay_ns is None:
        mount = extraction.mount.T_base_camera
        inputs = SlamInputs(
            observations, extraction.odometry, home_id, mount, noise, breaks, config.noise.robust
        )
        chosen = camera_delay_by_residuals(inputs, readout_ns=readout_ns, image_height=height)
        if chosen.delay_ns is None:
            delay_ns = 0
            extraction.notes.append(
                f"camera stamps taken as they are against {extraction.topics.odom}: SLAM's "
                "residuals have no minimum between -50 and +100 ms (--camera-delay sets a delay)"
            )
        else:
            delay_ns = chosen.delay_ns
            extraction.notes.append(
                f"camera stamps {delay_ns / 1e6:+.1f} ms against {extraction.topics.odom} "
                "(chosen by SLAM's residuals over -50..+100 ms; --camera-delay sets it)"
            )
    else:
        delay_ns = camera.delay_ns
    return retimed(observations, delay_ns, readout_ns, height), delay_ns


def prepare(
    log: Path,
    extraction: Extraction,
    config: MapConfig,
    stage: Callable[[str], None] = lambda name: None,
    home_id: int | None = None,
) -> Prepared:
    """One log's extraction made ready for the estimators: checked, odometry jumps released,
    its noise model chosen, the camera's delay and the odometry's scale applied (each chosen by
    SLAM's residuals unless set).

    Raises:
        MarkerGraphError: no marker observations, or no odometry.
    """
    if not extraction.observations:
        left_out = sorted(extraction.ids_left_out)
        raise MarkerGraphError(
            f"{log}: no markers of {config.dictionary} were found in "
            f"{extraction.frames} frames"
            + (
                f" (markers {', '.join(map(str, left_out))} were seen but are not in --ids)"
                if left_out
                else ""
            )
        )
    if not len(extraction.odometry):
        topic = extraction.topics.odom
        dropped = [n for n in extraction.notes if topic and n.startswith("dropped") and topic in n]
        raise MarkerGraphError(
            f"{log}: no usable odometry on {topic} ({'; '.join(dropped) or 'no samples'})"
            if topic
            else f"{log}: no odometry (no nav_msgs/Odometry topic and no odom -> base "
            "transforms on /tf)"
        )
    seen = {o.marker_id for o in extraction.observations}
    if len(seen) == 1:
        extraction.notes.append(
            f"only marker {seen.pop()} was seen: the map is that marker alone, with the robot's "
            "path in its frame; there is nothing to link"
        )
    jumps = extraction.odometry.jumps()
    for t_ns, size_m in jumps:
        after_s = (t_ns - int(extraction.odometry.t_ns[0])) * 1e-9
        extraction.notes.append(
            f"odometry on {extraction.topics.odom} jumped {size_m:.2f} m at {after_s:.2f} s into "
            "the log (a visual-inertial reset or relocalisation): that step is left to the "
            "observations"
        )
    evidence = extraction.odometry_evidence
    source, odometry_noise = config.odometry_noise(extraction.topics.odom, evidence)
    _, why = config.odometry_source(extraction.topics.odom, evidence)
    extraction.odometry_model_reason = why
    extraction.notes.append(
        f"odometry noise: the {source} model ({100 * odometry_noise.per_m:.1f} cm and "
        f"{math.degrees(odometry_noise.yaw_per_m):.2f} deg per sqrt(m), "
        f"{math.degrees(odometry_noise.yaw_per_rad):.2f} deg per sqrt(rad) turned): {why}"
    )
    breaks = [t for t, _ in jumps]
    if config.camera.delay_ns is None:
        stage("choosing the camera's delay by SLAM's residuals")
    observations, delay_ns = _timed(extraction, config, odometry_noise, breaks, home_id)
    scale = _odometry_scale(
        extraction, config, observations, odometry_noise, breaks, home_id, stage
    )
    frames = build_frames(
        observations,
        extraction.odometry.scaled(scale),
        home_id,
        odometry_noise=odometry_noise,
        odometry_breaks=breaks,
    )
    return Prepared(observations, frames, delay_ns, source, scale)


def _odometry_scale(
    extraction: Extraction,
    config: MapConfig,
    observations: list[Observation],
    noise: OdometryNoise,
    breaks: list[int],
    home_id: int | None,
    stage: Callable[[str], None],
) -> float:
    """The factor the odometry's distances are multiplied by: as set, or chosen by SLAM's
    residuals (1 where they have no minimum), and said in the notes."""
    configured = config.odometry.scale
    if configured is not None:
        return float(configured)
    stage("choosing the odometry's scale by SLAM's residuals")
    found = odometry_scale_by_residuals(
        SlamInputs(observations, extraction.odometry, home_id, extraction.mount.T_base_camera,
                   noise, breaks, config.noise.robust)
    )  # fmt: skip
    topic = extraction.topics.odom
    if found.chosen is None:
        extraction.notes.append(
            f"odometry on {topic} taken at its scale: SLAM's residuals have no minimum between "
            "0.95 and 1.05 (--odometry-scale sets one)"
        )
        return 1.0
    off = 100 * (1 / found.chosen - 1)
    extraction.notes.append(
        f"odometry on {topic} reads distances {abs(off):.2f} % {'long' if off > 0 else 'short'}: "
        f"its steps are scaled by {found.chosen:.4f} (chosen by SLAM's residuals over "
        "0.95..1.05; --odometry-scale sets it)"
    )
    return found.chosen


def map_log(
    log: Path,
    config: MapConfig | None = None,
    *,
    progress: Callable[[int, int], None] | None = None,
    stage: Callable[[str], None] | None = None,
) -> MapRun:
    """Read a log, estimate the map with each method, and score it when ground truth is logged.

    Args:
        log: an MCAP file or a rosbag2 folder.
        config: the settings (default: every default).
        progress: called with (colour frames read, frames in all) while the log is read.
        stage: called with the name of each stage as it begins.

    Raises:
        MarkerGraphError: the log cannot be read, has no marker observations, or no odometry
            (``LogError`` and ``SettingsError`` among them).
    """
    config = config or MapConfig.from_values()
    stage = stage or (lambda name: None)
    stage(f"reading {Path(log).name}")
    seconds: dict[str, float] = {}
    start = time.perf_counter()
    extraction = extract(log, config.frontend, progress=progress, workers=config.workers)
    seconds["front end"] = time.perf_counter() - start
    prepared = prepare(log, extraction, config, stage, config.home_id)
    observations, frames = prepared.observations, prepared.frames
    truth, true_path = truth_in_home_frame(extraction, frames.home_id)
    heights = marker_heights(observations)
    results = []
    for i, method in enumerate(config.methods, start=1):
        stage(f"estimating: {method.value} ({i} of {len(config.methods)})")
        start = time.perf_counter()
        try:
            estimate = estimate_frames(
                frames, method, extraction.mount.T_base_camera, form=Form.SIGNED,
                robust=config.noise.robust,
            )  # fmt: skip
        except EstimationError as error:
            raise EstimationError(f"{log}: {method.value}: {error}") from None
        seconds[method.value] = time.perf_counter() - start
        result = MethodResult(
            method, estimate, marker_map_of(estimate, str(log), config, heights, extraction)
        )
        _score(result, truth, true_path)
        results.append(result)
    return judge(MapRun(
        Path(log), config, extraction, frames, results, truth, true_path,
        camera_delay_ns=prepared.camera_delay_ns, odometry_source=prepared.odometry_source,
        odometry_scale=prepared.odometry_scale, seconds=seconds,
    ))  # fmt: skip
