"""A 3-D map's result folder: map.json, map.png, the rig's path, the solved map as g2o and the
report, written whole or not at all."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.common import Note
from markergraph.common.files import MANIFEST_KEY, files_in, result_folder
from markergraph.estimator.metrics import tag_errors_3d
from markergraph.estimator.tags3d import Camera3d, TagMap3d, quaternion_wxyz
from markergraph.formats import write_g2o_3d, write_tum_3d
from markergraph.markermap import MarkerMap, write_json
from markergraph.plotter import Plotter
from markergraph.report_page import REPORT_PAGE, write_report_page
from markergraph.results import REPORT_SCHEMA
from markergraph.settings import MapConfig
from markergraph.verdicts import Judgement, Verdict

__all__ = ["FILES_3D", "Map3dRun", "report_3d", "write_results_3d"]

FILES_3D = ("map.json", "map.png", "trajectory.tum", "map.g2o", "report.json", REPORT_PAGE)
"""What a 3-D result folder holds (map.png only when plots are drawn)."""


@dataclass
class Map3dRun:
    """A 3-D map run: what :func:`write_results_3d` writes.

    Attributes:
        log: the log read.
        config: the settings it was read and estimated with.
        tag_map: the estimator's 3-D map.
        marker_map: the same as a map (:meth:`MarkerMap.from_tag_map`): map.json.
        frames_read: rig frames read from the log (with any tag view).
        views_read: tag views read (one camera's view of one tag's corners).
        notes: what the front end and the flow noticed (the estimator's own are in
            ``tag_map.notes``).
        seconds: stage -> wall time [s].
        truth: tag id -> true ``T_ref_tag`` (tag frame, z out of the print) in any frame (a
            simulator's, TagSLAM's), or None.
    """

    log: Path
    config: MapConfig
    tag_map: TagMap3d
    marker_map: MarkerMap
    frames_read: int
    views_read: int
    notes: list[Note] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)
    truth: dict[int, gtsam.Pose3] | None = None
    tags_seen: int = 0
    """Tags with a view in the log (mapped or not)."""
    judgement: Judgement = field(default_factory=lambda: Judgement(Verdict.OK))
    """How far the map can be trusted (:func:`~markergraph.verdicts.judge_tag_map`)."""


def _largest_sigma(covariance: NDArray[np.float64]) -> float:
    """The square root of a covariance block's largest eigenvalue."""
    return math.sqrt(max(float(np.linalg.eigvalsh(covariance)[-1]), 0.0))


def _sigmas(covariance: NDArray[np.float64] | None) -> dict[str, list[float] | None]:
    """A 6x6's standard deviations: rotation [rad] and translation [m], about its own axes."""
    if covariance is None:
        return {"sigma_rotation_rad": None, "sigma_translation_m": None}
    diagonal = [math.sqrt(max(float(v), 0.0)) for v in np.diag(covariance)]
    return {"sigma_rotation_rad": diagonal[:3], "sigma_translation_m": diagonal[3:]}


def _camera(camera: Camera3d) -> dict[str, Any]:
    t, q = camera.T_rig_camera.translation(), quaternion_wxyz(camera.T_rig_camera.rotation())
    return {
        "topic": camera.topic,
        "estimated": camera.estimated,
        "n_views": camera.n_views,
        "x_m": float(t[0]),
        "y_m": float(t[1]),
        "z_m": float(t[2]),
        "quaternion_wxyz": list(q),
        **_sigmas(camera.covariance),
    }


def _tags(marker_map: MarkerMap) -> dict[str, dict[str, Any]]:
    """The tag table: position, heading, whether on a wall or surveyed, views, and the largest
    position (map axes) and rotation sigmas."""
    table = {}
    for i, m in marker_map.markers3d.items():
        assert m.T_map_marker3 is not None  # a 3-D map's markers all have one
        t = m.T_map_marker3.translation()
        sigma_p = sigma_r = None
        if m.covariance6 is not None:
            sigma_r = _largest_sigma(m.covariance6[:3, :3])
            sigma_p = _largest_sigma(m.covariance6[3:, 3:])  # a rotation keeps eigenvalues
        table[str(i)] = {
            "x_m": float(t[0]),
            "y_m": float(t[1]),
            "z_m": float(t[2]),
            "yaw_rad": m.T_map_marker.theta(),
            "wall": m.wall,
            "surveyed": m.known,
            "n_views": m.n_observations,
            "size_m": m.size_m,
            "sigma_position_m": sigma_p,
            "sigma_rotation_rad": sigma_r,
        }
    return table


def _truth_error(run: Map3dRun) -> dict[str, Any] | None:
    """The 3-D error against the truth after a rigid alignment, or None without truth."""
    if run.truth is None:
        return None
    poses = {i: tag.T_map_tag for i, tag in run.tag_map.tags.items()}
    try:
        errors = tag_errors_3d(poses, run.truth)
    except ValueError as error:
        return {"tags_compared": len(set(poses) & set(run.truth)), "why_not": str(error)}
    return {
        "tags_compared": len(errors.tag_ids),
        "median_position_m": errors.median_position_m,
        "max_position_m": errors.max_position_m,
        "median_rotation_rad": errors.median_rotation_rad,
        "max_rotation_rad": errors.max_rotation_rad,
        "tags_in_truth_not_mapped": sorted(set(run.truth) - set(poses)),
    }


def report_3d(run: Map3dRun, files: list[str]) -> dict[str, Any]:
    """report.json of a 3-D map: what was read, placed and left out, each camera's mount, each
    tag, the notes, the times and the settings; with truth, the aligned 3-D error."""
    tag_map = run.tag_map
    report: dict[str, Any] = {
        "schema": REPORT_SCHEMA,
        MANIFEST_KEY: files,  # what --force may later replace, and nothing else
        "dimensions": 3,
        "log": str(run.log),
        "frames": run.frames_read,
        "frames_placed": len(tag_map.frame_times),
        "frames_skipped": tag_map.frames_skipped,
        "views": run.views_read,
        "views_used": tag_map.views_used,
        "views_dropped": tag_map.views_dropped,
        "tags_seen": run.tags_seen,
        "tags_mapped": len(run.tag_map.tags),
        "wall_tags": sum(m.wall for m in run.marker_map.markers3d.values()),
        "surveyed_tags": sum(tag.known for tag in tag_map.tags.values()),
        "home_id": tag_map.home_id,
        "up": tag_map.up,
        "frame": run.marker_map.frame,
        "converged": tag_map.converged,
        "reprojection_rms_px": tag_map.reprojection_rms_px,
        "ground_truth": run.truth is not None,
        "notes": [*(note.text for note in run.notes), *(note.text for note in tag_map.notes)],
        "cameras": {name: _camera(c) for name, c in sorted(tag_map.cameras.items())},
        "tags": _tags(run.marker_map),
        "seconds": run.seconds,
        "settings": dict(run.config.values),
        **run.judgement.to_json(),
    }
    error = _truth_error(run)
    if error is not None:
        report["error_3d"] = error
    return report


def write_results_3d(
    run: Map3dRun,
    out: Path,
    force: bool = False,
    *,
    plots: bool = True,
    plotter: Plotter | None = None,
) -> list[Path]:
    """A 3-D map's result folder, written whole or not at all
    (:func:`~markergraph.common.files.result_folder`); an existing one is replaced only with
    ``force``, and only if markergraph wrote it or it is empty.

    Files: ``map.json`` (schema ``markergraph.map/2``, every tag's full pose), ``map.png`` (a
    top view and a side view), ``trajectory.tum`` (the rig's 3-D path ``T_map_rig``),
    ``map.g2o`` (rig poses ``k`` and tags ``1000000+id`` as ``VERTEX_SE3:QUAT``, each tag's
    ``T_map_tag`` in the tag frame, z out of the print; no edges), ``report.json`` and
    ``report.html``. The figure is drawn by ``plotter`` as in
    :func:`~markergraph.results.write_results`.

    Returns:
        The files written, relative to ``out``.

    Raises:
        OutputError: ``out`` may not be replaced, or another run wrote it meanwhile.
    """
    tag_map = run.tag_map
    plotter = plotter or Plotter()
    with result_folder(Path(out), force=force) as folder, plotter.stopped_on_error():
        figures = []
        if plots:
            from markergraph.plots3d import plot_map_3d

            figures = [folder / "map.png"]
            plotter.draw(plot_map_3d, tag_map, folder / "map.png", truth=run.truth)
        run.marker_map.save(folder / "map.json")
        write_tum_3d(folder / "trajectory.tum", tag_map.frame_times, tag_map.rig_poses)
        tags = {i: tag.T_map_tag for i, tag in tag_map.tags.items()}
        write_g2o_3d(folder / "map.g2o", tag_map.rig_poses, tags)
        files = [str(p) for p in files_in(folder, figures)]
        report = report_3d(run, sorted([*files, "report.json", REPORT_PAGE]))
        write_json(folder / "report.json", report)
        plotter.finish()  # the page inlines the figure
        write_report_page(folder / REPORT_PAGE, report, folder)
        written = files_in(folder)
    return written
