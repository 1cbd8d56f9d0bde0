"""The result folder: maps, trajectories, the solved graph, plots, the overlay and the report,
written whole or not at all."""

from __future__ import annotations

import math
from dataclasses import asdict
from pathlib import Path
from typing import Any

from markergraph.common.files import (
    MANIFEST_KEY,
    REPORT_SCHEMA_PREFIX,
    files_in,
    result_folder,
)
from markergraph.diagnostics import diagnostics
from markergraph.estimator.trajectory import Trajectory
from markergraph.formats import write_g2o, write_tum
from markergraph.frontend.extraction import MOUNT_FROM_SETTINGS
from markergraph.localize_accuracy import accuracy_entry, accuracy_of
from markergraph.markermap import write_json
from markergraph.overlay import write_overlay
from markergraph.plotter import Plotter
from markergraph.records import (
    ITERATING_METHODS,
    LINKING_METHODS,
    LocalizationRun,
    MapRun,
    MethodResult,
)
from markergraph.report_page import REPORT_PAGE, write_report_page

__all__ = [
    "DIAGNOSTICS_FIGURE",
    "LOCALIZE_FIGURE",
    "REPORT_SCHEMA",
    "TUM_FRAMES",
    "write_localization",
    "write_results",
]

DIAGNOSTICS_FIGURE = "diagnostics.png"
LOCALIZE_FIGURE = "map.png"  # localize's: the saved map, the localised path, moved markers
# Which frame each trajectory file is in, and what it holds: report.json's "file_frames" and
# each file's header comment line.
TUM_FRAMES: dict[str, tuple[str, str]] = {
    "trajectory.tum": (
        "map",
        "the corrected path at the odometry's rate: the optimised poses with the odometry "
        "between them, in the home marker's frame",
    ),
    "odometry_map.tum": (
        "map",
        "the raw odometry placed by the first optimised pose, from that pose on (its drift "
        "shows against trajectory.tum)",
    ),
    "odometry.tum": ("odom", "the raw odometry as logged, in its own odom frame"),
    "ground_truth.tum": (
        "map",
        "the logged true path at trajectory.tum's stamps, in the home marker's frame",
    ),
}
REPORT_SCHEMA = f"{REPORT_SCHEMA_PREFIX}1"  # report.json's layout; bump on a breaking change


def _report(run: MapRun, files: list[str]) -> dict[str, Any]:
    """report.json: what was read, what each method made of it, and the verdicts."""
    extraction = run.extraction
    report: dict[str, Any] = {
        "schema": REPORT_SCHEMA,
        MANIFEST_KEY: files,  # what --force may later replace, and nothing else
        "log": str(run.log),
        "frames": extraction.frames,
        "frames_with_depth": extraction.frames_with_depth,
        "observations": len(extraction.observations),
        "markers_seen": len({o.marker_id for o in extraction.observations}),
        "odometry_samples": len(extraction.odometry),
        "skipped_frames": dict(extraction.skipped),
        "undecodable_frames": extraction.undecodable_frames,
        "unusable_depth_images": extraction.unusable_depth,
        "depth_scale": extraction.depth_scale,
        "measured_depth_scale": extraction.measured_depth_scale,
        "depth_scale_sigma": extraction.depth_scale_sigma,
        "camera_delay_ms": run.camera_delay_ns / 1e6,
        "camera_delay_sigma_ms": (
            None if run.camera_delay_sigma_ns is None else run.camera_delay_sigma_ns / 1e6
        ),
        "odometry_source": run.odometry_source,
        "odometry_scale": run.odometry_scale,
        "odometry_scale_sigma": run.odometry_scale_sigma,
        "odometry_turn_scale": run.odometry_turn_scale,
        "odometry_turn_scale_sigma": run.odometry_turn_scale_sigma,
        "levelled_frames": extraction.levelled_frames,
        "marker_detections": {
            str(i): {
                "detections": c.detections,
                "dropped": c.dropped,
                "off_wall": c.off_wall,
                "no_pose": c.no_pose,
                "corners_reversed": c.rewound,
                "left_out": c.left_out,
            }
            for i, c in sorted(extraction.marker_detections.items())
        },
        "inputs": {
            **extraction.input_evidence(),
            "odometry_model_reason": run.odometry_model_reason,
        },
        "notes": [*(note.text for note in run.notes), *extraction.warnings],
        "ground_truth": bool(run.true_markers),
        "seconds": run.seconds,
        "settings": _settings_used(run),
        "camera_mount": _mount_entry(run),
        "file_frames": {
            name: {"frame": frame, "holds": holds}
            for name, (frame, holds) in TUM_FRAMES.items()
            if name in files
        },
        **run.judgement.to_json(),
        "methods": {},
    }
    if run.sessions:
        report["sessions"] = [
            {"log": str(session.log), "frames": session.extraction.frames,
             "observations": len(session.extraction.observations),
             "placed": session.trajectory is not None}
            for session in run.sessions
        ]  # fmt: skip
        report["separate"] = [
            {"logs": [str(log) for log in logs], "markers": sorted(marker_map.markers)}
            for logs, marker_map in run.separate
        ]
    for result in run.results:
        report["methods"][result.label] = _method_entry(run, result)
    return report


# The settings that say the camera's mount, and the mount's field each is read from.
_MOUNT_SETTINGS = (
    ("camera.x", "x_m", 1.0),
    ("camera.y", "y_m", 1.0),
    ("camera.height", "height_m", 1.0),
    ("camera.pitch_deg", "pitch_rad", math.degrees(1.0)),
    ("camera.yaw_deg", "yaw_rad", math.degrees(1.0)),
)


def _settings_used(run: MapRun | LocalizationRun) -> dict[str, Any]:
    """Every setting as the run used it: a mount read from the log's static transforms
    replaces the configured one (``camera_mount`` says where it came from)."""
    values = dict(run.config.values)
    extraction = run.extraction
    if extraction.mount_origin() != MOUNT_FROM_SETTINGS:
        for key, name, factor in _MOUNT_SETTINGS:
            if key in values:
                values[key] = round(getattr(extraction.mount, name) * factor, 6)
    return values


def _mount_entry(run: MapRun | LocalizationRun) -> dict[str, Any]:
    """The camera's mount used and where it came from (report.json's ``camera_mount``)."""
    mount = run.extraction.mount
    return {
        "source": run.extraction.mount_origin(),
        "x_m": mount.x_m,
        "y_m": mount.y_m,
        "height_m": mount.height_m,
        "pitch_rad": mount.pitch_rad,
        "yaw_rad": mount.yaw_rad,
        "roll_rad": mount.roll_rad,
    }


def _method_entry(run: MapRun, result: MethodResult) -> dict[str, Any]:
    """One method's part of report.json: its verdict, what it placed, its notes and, with
    ground truth, its errors."""
    entry: dict[str, Any] = {
        **result.judgement.to_json(),
        "markers_placed": len(result.estimate.markers),
        # None where the column means nothing for the method (records.LINKING_METHODS, ...).
        "links": len(result.estimate.links) if result.method in LINKING_METHODS else None,
        "unplaced": {str(k): v for k, v in result.estimate.unplaced.items()},
        "converged": result.estimate.converged if result.method in ITERATING_METHODS else None,
        "notes": [note.text for note in result.estimate.notes],
        "diagnostics": diagnostics(result.estimate, [s.frames for s in run.sessions] or run.frames),
    }
    if result.estimate.placements:  # the closed form: how each marker was reached
        entry["placements"] = {
            str(i): {k: v for k, v in asdict(p).items() if k != "marker_id"}
            for i, p in result.estimate.placements.items()
        }
    if result.map_error is not None:
        entry["marker_rmse_m"] = result.map_error.rmse_position_m
        entry["marker_yaw_rmse_rad"] = result.map_error.rmse_yaw_rad
    if result.map_error_aligned is not None:
        entry["marker_rmse_aligned_m"] = result.map_error_aligned.rmse_position_m
    if result.inside_95_ellipse is not None:
        entry["inside_95_ellipse_share"] = result.inside_95_ellipse
    if result.yaw_inside_95 is not None:
        entry["yaw_inside_95_share"] = result.yaw_inside_95
    if result.path is not None:
        entry["trajectory_poses"] = len(result.path)  # in trajectory.tum
        entry["optimised_poses"] = len(result.estimate.trajectory)
    if result.trajectory_error is not None:
        entry["ate_m"] = result.trajectory_error.ate_rmse_m  # home-fixed, as evo_ape without -a
        entry["ate_aligned_m"] = result.trajectory_error.ate_aligned_rmse_m  # evo_ape -a
        entry["ate_poses"] = len(result.true_path) if result.true_path is not None else 0
        rpe = result.trajectory_error.rpe_rmse_m_per_m
        entry["rpe_m_per_m"] = rpe if math.isfinite(rpe) else None  # a path under 1 m
    return entry


def _rmse(result: MethodResult) -> tuple[float, float] | None:
    """Marker RMSE in the home marker's frame and after a rigid alignment, if truth is known."""
    if result.map_error is None or result.map_error_aligned is None:
        return None
    return result.map_error.rmse_position_m, result.map_error_aligned.rmse_position_m


def write_results(
    run: MapRun,
    out: Path,
    *,
    force: bool = False,
    plots: bool = True,
    plotter: Plotter | None = None,
) -> list[Path]:
    """The result folder, written whole or not at all
    (:func:`~markergraph.common.files.result_folder`); an existing one is replaced only with
    ``force``, and only if markergraph wrote it or it is empty.

    Files: ``map.json``, ``map.g2o`` (graph methods), ``map.png`` and ``map.svg`` for the first
    method, and ``overlay.mcap`` (its map and trajectory as ROS 2 messages, to show over the
    log) with ``overlay.layout.json`` (a Foxglove layout for it); ``methods/<method>/`` with
    the same for every method when there are several, and
    ``comparison.png``; TUM trajectories, each naming its frame in a header comment line and
    in report.json's ``file_frames`` (:data:`TUM_FRAMES`: the corrected path per method at the
    odometry's rate, the odometry in its odom frame and placed in the map, ground truth);
    ``report.json`` and ``report.html`` (the same report as one self-contained page). The
    figures are drawn by ``plotter`` (:class:`~markergraph.plotter.Plotter`: in processes of
    their own, while the rest is written), else here.

    Returns:
        The files written, relative to ``out``.

    Raises:
        OutputError: ``out`` may not be replaced, or another run wrote it meanwhile.
    """
    plotter = plotter or Plotter()
    with result_folder(Path(out), force=force) as folder, plotter.stopped_on_error():
        _write_all(run, folder, plotter if plots else None)
        written = files_in(folder)
    return written


def _write_method(result: MethodResult, folder: Path) -> None:
    estimate = result.estimate
    result.marker_map.save(folder / "map.json")
    if estimate.pose_graph is not None:
        write_g2o(folder / "map.g2o", *estimate.pose_graph())  # what was solved, as g2o has it
    path = result.path if result.path is not None else estimate.trajectory
    if len(path):
        _write_tum(folder, "trajectory.tum", path)


def _write_tum(folder: Path, name: str, trajectory: Trajectory) -> None:
    """A trajectory file whose header comment line says its frame and what it holds."""
    frame, holds = TUM_FRAMES[name]
    write_tum(folder / name, trajectory, f"{name}: frame {frame}; {holds}")


def _method_folders(run: MapRun, folder: Path) -> list[tuple[MethodResult, Path]]:
    """Each method's result and its folder: the first method's is the top folder, and with
    several methods each has its own under ``methods/`` too."""
    folders = [(run.results[0], folder)]
    if len(run.results) > 1:
        folders += [(r, folder / "methods" / r.label) for r in run.results]
    return folders


def _draw_figures(run: MapRun, folder: Path, plotter: Plotter) -> list[Path]:
    """Every figure of the folder asked for at once, the longest to draw first (the comparison
    of several methods: 2-3 s, a map 0.4-0.5 s): drawn while the rest is written, where the
    plotter has processes of its own. The first method's map under ``methods/`` is left to
    :func:`_copy_first_map`. Returns the files they write, the copy's included."""
    from markergraph.plots import plot_comparison, plot_diagnostics, plot_map

    # The first method with residuals (the closed form has none).
    shown = next((r for r in run.results if r.estimate.residuals), run.results[0])
    frames = [s.frames for s in run.sessions] or run.frames
    files: list[Path] = []
    if len(run.results) > 1:
        plotter.draw(
            plot_comparison, [(r.label, r.marker_map, _rmse(r)) for r in run.results],
            run.true_markers, folder / "comparison.png",
        )  # fmt: skip
        files.append(folder / "comparison.png")
    for n, (result, method_folder) in enumerate(_method_folders(run, folder)):
        files += [method_folder / "map.png", method_folder / "map.svg"]
        if n > 0 and result is run.results[0]:  # its folder under methods/: the top one's map
            continue
        path = result.path if result.path is not None else result.estimate.trajectory
        plotter.draw(
            plot_map, result.marker_map, run.true_markers, method_folder / "map.png",
            trajectory=path,
            # Placed by the first optimised pose, which is the path's first pose too.
            odometry=result.odometry_map, truth_path=result.true_path, rmse_m=_rmse(result),
        )  # fmt: skip
        if n == 0:
            plotter.draw(
                plot_diagnostics, shown.label, diagnostics(shown.estimate, frames),
                run.extraction.observations, folder / DIAGNOSTICS_FIGURE,
            )  # fmt: skip
            files.append(folder / DIAGNOSTICS_FIGURE)
    return files


def _copy_first_map(run: MapRun, folder: Path) -> None:
    """With several methods, the first method's map (drawn in the top folder) copied to its
    folder under ``methods/``: one map in two folders is drawn once."""
    from markergraph.plots import copy_map

    for result, method_folder in _method_folders(run, folder)[1:]:
        if result is run.results[0]:
            copy_map(folder / "map.png", method_folder / "map.png")


def _write_all(run: MapRun, folder: Path, plotter: Plotter | None) -> None:
    first = run.results[0]
    for _, method_folder in _method_folders(run, folder):
        method_folder.mkdir(parents=True, exist_ok=True)
    figures = _draw_figures(run, folder, plotter) if plotter is not None else []
    for result, method_folder in _method_folders(run, folder):
        _write_method(result, method_folder)
    odometry = run.extraction.odometry
    write_overlay(
        folder / "overlay.mcap", first.marker_map,
        first.path if first.path is not None else first.estimate.trajectory, odometry,
        map_frame=run.config.overlay.map_frame,
        odom_frame=run.config.overlay.odom_frame,
        image_topic=run.extraction.topics.color,
        calibration_topic=run.extraction.topics.camera_info,
    )  # fmt: skip
    _write_tum(folder, "odometry.tum", odometry)
    if first.odometry_map is not None and len(first.odometry_map):
        _write_tum(folder, "odometry_map.tum", first.odometry_map)
    for n, session in enumerate(run.sessions, start=1):
        if session.trajectory is not None:
            (folder / "sessions").mkdir(exist_ok=True)
            write_tum(folder / "sessions" / f"{n}-{session.log.stem}.tum", session.trajectory)
    for n, (_, marker_map) in enumerate(run.separate, start=1):
        (folder / "separate" / str(n)).mkdir(parents=True)
        marker_map.save(folder / "separate" / str(n) / "map.json")
    if first.true_path is not None:
        # At the estimate's own stamps, so that evo pairs them exactly and prints our figures.
        _write_tum(folder, "ground_truth.tum", first.true_path)
    files = [str(p) for p in files_in(folder, figures)]
    report = _report(run, sorted([*files, "report.json", REPORT_PAGE]))
    write_json(folder / "report.json", report)
    if plotter is not None:
        plotter.finish()  # the page inlines the figures
        _copy_first_map(run, folder)
    write_report_page(folder / REPORT_PAGE, report, folder)  # the same figures, one page


def write_localization(
    run: LocalizationRun,
    out: Path,
    *,
    force: bool = False,
    plots: bool = True,
    plotter: Plotter | None = None,
) -> list[Path]:
    """A localisation's result folder, whole or not at all: ``trajectory.tum`` (the path in
    the map frame at the odometry's rate: the localised poses, the odometry between them),
    ``localization.json`` (every pose with its covariance, moved and new markers),
    ``overlay.mcap`` (the saved map, the path and map -> odom) with ``overlay.layout.json`` (its
    Foxglove layout), ``ground_truth.tum`` when the log carries it, ``map.png`` (the map, the
    path, moved markers as arrows; unless not
    ``plots``; drawn by ``plotter`` as in :func:`write_results`), ``report.json`` and
    ``report.html`` (the same report as one self-contained page)."""
    plotter = plotter or Plotter()
    with result_folder(Path(out), force=force) as folder, plotter.stopped_on_error():
        loc = run.localization
        write_tum(folder / "trajectory.tum", run.path if run.path is not None else loc.trajectory)
        if run.true_path is not None:
            write_tum(folder / "ground_truth.tum", run.true_path)
        write_json(folder / "localization.json", run.document())
        overlay = run.config.overlay
        write_overlay(
            folder / "overlay.mcap", run.saved, loc.trajectory, run.extraction.odometry,
            map_frame=overlay.map_frame, odom_frame=overlay.odom_frame,
            image_topic=run.extraction.topics.color,
            calibration_topic=run.extraction.topics.camera_info,
        )  # fmt: skip
        accuracy = accuracy_of(loc, run.ate_m, run.ate_aligned_m)
        figures = []
        if plots:
            from markergraph.plots_localize import plot_localization

            figures = [folder / LOCALIZE_FIGURE]
            plotter.draw(plot_localization, run.saved, loc, folder / LOCALIZE_FIGURE,
                         truth_path=run.true_path, title=_localize_title(run))  # fmt: skip
        files = [str(p) for p in files_in(folder, figures)]
        report = _localize_report(run, sorted([*files, "report.json", REPORT_PAGE]))
        report["accuracy"] = accuracy_entry(accuracy)
        write_json(folder / "report.json", report)
        plotter.finish()  # the page inlines the figure
        write_report_page(folder / REPORT_PAGE, report, folder)
        written = files_in(folder)
    return written


def _localize_title(run: LocalizationRun) -> str:
    """localize's map.png title: what the map is, and the ATE with its alignment."""
    home = run.saved.home_id
    title = f"{Path(run.log).name} localised in {run.map_path} (frame of marker {home})"
    if run.ate_m is not None:
        title += f"\nATE {100 * run.ate_m:.1f} cm home-fixed"
        if run.ate_aligned_m is not None:
            title += f", {100 * run.ate_aligned_m:.1f} cm aligned"
    return title


def _localize_report(run: LocalizationRun, files: list[str]) -> dict[str, Any]:
    """localize's report.json (schema as map's): what was read, the path, the moved and new
    markers (before and now) and the notes."""
    loc = run.localization
    return {
        "schema": REPORT_SCHEMA, MANIFEST_KEY: files, "command": "localize",
        "log": str(run.log), "map": str(run.map_path), "poses": len(loc.trajectory),
        "trajectory_poses": len(run.path if run.path is not None else loc.trajectory),
        "moved": [m.marker_id for m in loc.moved], "new": sorted(loc.new),
        "moved_markers": [
            {"id": m.marker_id, "displacement_m": m.displacement_m,
             "before_x_m": m.T_map_before.x(), "before_y_m": m.T_map_before.y(),
             "now_x_m": m.T_map_now.x(), "now_y_m": m.T_map_now.y()}
            for m in loc.moved
        ],
        "ate_m": run.ate_m, "ate_aligned_m": run.ate_aligned_m,
        "notes": [note.text for note in run.notes],
        "settings": _settings_used(run),
        "camera_mount": _mount_entry(run),
    }  # fmt: skip
