"""Many logs of one place: one map from several sessions (optionally refining a saved map), and
a log localised against a saved map with moved and new markers reported.

The front end of each log runs where :func:`~markergraph.executors.extract_logs` puts it (local
processes or Ray); the estimation runs here, on the caller.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gtsam
import numpy as np

from markergraph.common.errors import SettingsError
from markergraph.estimator import Estimate, Frames, Method, Trajectory, marker_heights
from markergraph.estimator.sessions import (
    Localization,
    MapPrior,
    SessionsEstimate,
    localize,
    solve_sessions,
)
from markergraph.executors import extract_logs
from markergraph.frontend import Extraction
from markergraph.markermap import MarkerMap
from markergraph.run import (
    MapRun,
    MethodResult,
    _score,
    judge,
    marker_map_of,
    path_error,
    prepare,
    truth_in_home_frame,
)
from markergraph.settings import MapConfig

__all__ = ["LocalizationRun", "Session", "localize_log", "map_logs", "priors_of"]

SESSION_METHODS = (Method.SLAM, Method.ISAM2, Method.MARKER_GRAPH)
# A saved map without covariances (the closed form's) still needs its markers held: this firmly.
DEFAULT_PRIOR_SIGMAS = np.array([0.01, 0.01, math.radians(1.0)])


@dataclass(frozen=True)
class Session:
    """One log of a several-log map: where its robot went in the map (None: it shares no
    marker with the map, and is mapped on its own in ``MapRun.separate``)."""

    log: Path
    extraction: Extraction
    frames: Frames
    trajectory: Trajectory | None


def priors_of(saved: MarkerMap, notes: list[str]) -> dict[int, MapPrior]:
    """A saved map's markers as priors, at their covariances relative to the map as a whole
    (their marginals in the home marker's frame would carry the home's own uncertainty on every
    marker, and independent priors that wide hold nothing)."""
    default = np.diag(DEFAULT_PRIOR_SIGMAS**2)
    bare = [m.marker_id for m in saved.markers.values() if m.covariance is None]
    if bare:
        notes.append(
            f"the saved map has no covariance for marker(s) {', '.join(map(str, bare))}: held "
            "at 1 cm and 1 deg"
        )
    priors = {}
    for m in saved.markers.values():
        covariance = m.relative_covariance if m.relative_covariance is not None else m.covariance
        held = default if covariance is None else covariance
        priors[m.marker_id] = MapPrior(m.T_map_marker, held)
    return priors


def _as_estimate(solved: SessionsEstimate, method: Method, home_id: int) -> Estimate:
    """A several-log solution as one method's estimate, with the first placed log's path."""
    trajectory = next(t for t in solved.trajectories if t is not None)
    return Estimate(
        method=method, home_id=home_id, markers=solved.markers, trajectory=trajectory,
        residuals=solved.residuals, notes=solved.notes, graph=solved.graph, values=solved.values,
        pose_graph=solved.pose_graph,
    )  # fmt: skip


def map_logs(
    logs: Sequence[Path],
    config: MapConfig | None = None,
    *,
    prior: MarkerMap | None = None,
    executor: str = "local",
    address: str | None = None,
    progress: Callable[[int, int], None] | None = None,
    stage: Callable[[str], None] | None = None,
) -> MapRun:
    """One map from several logs of one place, or one log refining a saved map (``prior``).

    Each log keeps its own odometry chain; markers seen in several logs tie them together; the
    home marker is the first log's unless the settings name one (with a prior, the saved
    map's frame stays). A log sharing no marker with the rest is mapped on its own (by SLAM), in
    ``MapRun.separate``. SLAM, iSAM2 and the marker graph take several logs; the closed form and
    the EKF follow one robot through one log and are left out (with ``all``, said so).

    Raises:
        SettingsError: only methods that take one log.
        MarkerGraphError: a log without markers or odometry (naming it).
    """
    config = config or MapConfig.from_values()
    stage = stage or (lambda name: None)
    methods = [m for m in config.methods if m in SESSION_METHODS]
    if not methods:
        raise SettingsError(
            f"several logs (or --prior) are mapped by {', '.join(m.value for m in SESSION_METHODS)}"
            ": the closed form and the EKF follow one robot through one log"
        )
    seconds: dict[str, float] = {}
    start = time.perf_counter()
    stage(f"reading {len(logs)} logs ({executor})")
    extractions = extract_logs(
        logs, config.frontend, executor=executor, address=address, workers=config.workers,
        progress=progress,
    )  # fmt: skip
    seconds["front end"] = time.perf_counter() - start
    prepared = []
    for i, (log, extraction) in enumerate(zip(logs, extractions, strict=True)):
        home = config.home_id if i == 0 and prior is None else None
        prepared.append(prepare(log, extraction, config, stage, home))
    notes: list[str] = []
    if len(methods) < len(config.methods):
        notes.append("the closed form and the EKF follow one log: left out of a several-log map")
    priors = priors_of(prior, notes) if prior is not None else None
    frames = [p.frames for p in prepared]
    mounts = [e.mount.T_base_camera for e in extractions]
    # The first log was read with the settings' home marker (or, under a prior, the map's).
    home_id = prior.home_id if prior is not None else frames[0].home_id
    heights = marker_heights([o for p in prepared for o in p.observations])
    results, first_solved = [], None
    for method in methods:
        stage(f"estimating: {method.value} over every log")
        start = time.perf_counter()
        solved = solve_sessions(frames, mounts, robust=config.noise.robust, priors=priors,
                                home_id=config.home_id, method=method)  # fmt: skip
        seconds[method.value] = time.perf_counter() - start
        first_solved = first_solved or solved
        estimate = _as_estimate(solved, method, home_id)
        estimate.notes = notes + estimate.notes
        marker_map = marker_map_of(estimate, ", ".join(map(str, logs)), config, heights)
        results.append(MethodResult(method, estimate, marker_map))
    assert first_solved is not None
    solved = first_solved
    first = next(i for i, t in enumerate(solved.trajectories) if t is not None)
    extraction = extractions[first]
    truth, true_path = truth_in_home_frame(extraction, home_id)
    for result in results:
        _score(result, truth, true_path)
    run = MapRun(Path(logs[first]), config, extraction, frames[first], results, truth,
                 true_path, camera_delay_ns=prepared[first].camera_delay_ns,
                 odometry_source=prepared[first].odometry_source,
                 odometry_scale=prepared[first].odometry_scale, seconds=seconds)  # fmt: skip
    run.sessions = [
        Session(Path(log), extraction, frames[i], solved.trajectories[i])
        for i, (log, extraction) in enumerate(zip(logs, extractions, strict=True))
    ]
    run.separate = _separate(solved.apart, logs, frames, mounts, config)
    return judge(run)


def _separate(
    apart: list[int],
    logs: Sequence[Path],
    frames: list,
    mounts: list[gtsam.Pose2],
    config: MapConfig,
) -> list[tuple[list[Path], MarkerMap]]:
    """The maps of sessions that share no marker with the main map, each group on its own."""
    maps = []
    while apart:
        solved = solve_sessions([frames[i] for i in apart], [mounts[i] for i in apart],
                                robust=config.noise.robust)  # fmt: skip
        placed = [apart[j] for j, t in enumerate(solved.trajectories) if t is not None]
        estimate = _as_estimate(solved, Method.SLAM, frames[placed[0]].home_id)
        group = [Path(logs[i]) for i in placed]
        maps.append((group, marker_map_of(estimate, ", ".join(map(str, group)), config)))
        apart = [apart[j] for j in solved.apart]
    return maps


@dataclass
class LocalizationRun:
    """A log localised against a saved map.

    Attributes:
        log, map_path: the log and the saved map.
        saved: the saved map.
        config: the settings.
        extraction: the front end's output.
        localization: trajectory, pose covariances, moved and new markers.
        ate_m: the trajectory's RMS error against the logged truth, if any [m].
        true_path: the logged truth at the trajectory's stamps, in the map frame.
        notes: what a person should read.
    """

    log: Path
    map_path: Path
    saved: MarkerMap
    config: MapConfig
    extraction: Extraction
    localization: Localization
    ate_m: float | None
    true_path: Trajectory | None
    notes: list[str]

    def document(self) -> dict[str, Any]:
        """``localization.json``: every pose with its covariance, the moved and new markers,
        and how far each map marker was pulled (schema ``markergraph.localization/1``)."""
        loc = self.localization
        return {
            "schema": "markergraph.localization/1",
            "map": str(self.map_path),
            "log": str(self.log),
            "frame": "the saved map's (its home marker's) frame; x, y [m], yaw [rad]",
            "poses": [
                {
                    "t_ns": int(t),
                    "x": float(p[0]),
                    "y": float(p[1]),
                    "yaw": float(p[2]),
                    "covariance": c.tolist(),
                }
                for t, p, c in zip(
                    loc.trajectory.t_ns, loc.trajectory.poses, loc.pose_covariances, strict=True
                )
            ],
            "moved": [
                {
                    "id": m.marker_id,
                    "displacement_m": m.displacement_m,
                    "before": _pose(m.T_map_before),
                    "now": _pose(m.T_map_now),
                    "pulled_sigmas": m.prior_whitened,
                }
                for m in loc.moved
            ],
            "new": [{"id": i, **_pose(m.T_map_marker)} for i, m in sorted(loc.new.items())],
            "pulled_sigmas": {str(i): v for i, v in sorted(loc.checked.items())},
            "ate_m": self.ate_m,
            "notes": self.notes,
        }


def _pose(T: gtsam.Pose2) -> dict[str, float]:
    return {"x": T.x(), "y": T.y(), "yaw": T.theta()}


def localize_log(
    log: Path,
    saved: MarkerMap,
    map_path: Path,
    config: MapConfig | None = None,
    *,
    progress: Callable[[int, int], None] | None = None,
    stage: Callable[[str], None] | None = None,
) -> LocalizationRun:
    """A log's robot trajectory in a saved map (:func:`~markergraph.estimator.sessions.localize`).

    Raises:
        MarkerGraphError: the log cannot be read, has no markers or odometry, or sees no
            marker of the map.
    """
    config = config or MapConfig.from_values()
    stage = stage or (lambda name: None)
    stage(f"reading {Path(log).name}")
    (extraction,) = extract_logs([log], config.frontend, workers=config.workers,
                                 progress=progress)  # fmt: skip
    frames = prepare(log, extraction, config, stage).frames
    notes = list(extraction.notes)
    priors = priors_of(saved, notes)
    stage("localising against the saved map")
    localization = localize(
        frames, extraction.mount.T_base_camera, priors, robust=config.noise.robust
    )
    for m in localization.moved:
        notes.append(
            f"marker {m.marker_id} moved {100 * m.displacement_m:.1f} cm since the map was made "
            f"(pulled {m.prior_whitened:.1f} sigmas): left out of the localisation"
        )
    if localization.new:
        notes.append(
            f"marker(s) {', '.join(map(str, sorted(localization.new)))} are not in the map: "
            "placed by this log (see localization.json)"
        )
    _, path = truth_in_home_frame(extraction, saved.home_id)
    error, true_path = path_error(localization.trajectory, path)
    ate_m = error.ate_rmse_m if error is not None else None
    return LocalizationRun(
        Path(log), Path(map_path), saved, config, extraction, localization, ate_m, true_path,
        notes,
    )  # fmt: skip
