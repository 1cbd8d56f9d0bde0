"""What the main job returns: a map run (one or several logs) with each method's result, and a
localisation run; the result folder is written from these."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.common import Note
from markergraph.estimator import (
    Estimate,
    Frames,
    MapError,
    MarkerHeight,
    Method,
    Trajectory,
    TrajectoryError,
)
from markergraph.estimator.localization import Localization
from markergraph.frontend import Extraction
from markergraph.markermap import MarkerMap
from markergraph.settings import MapConfig
from markergraph.verdicts import Judgement, Verdict

__all__ = [
    "ITERATING_METHODS",
    "LINKING_METHODS",
    "LocalizationRun",
    "MapRun",
    "MethodResult",
    "Session",
    "marker_map_of",
]

LINKING_METHODS = frozenset({Method.CLOSED_FORM, Method.MARKER_GRAPH, Method.SLAM, Method.ISAM2})
"""Methods that measure links between markers seen together; the EKF measures none (its
markers are tied through its covariance alone), so its links are shown as "-"."""
ITERATING_METHODS = frozenset({Method.MARKER_GRAPH, Method.SLAM, Method.ISAM2})
"""Methods whose solver iterates to convergence; "converged" means nothing for the closed form
(computed once) or the EKF (one update a frame), so it is shown as "-" for them."""


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


@dataclass
class MethodResult:
    """One method's map, and its error against ground truth when the log carries it.

    Attributes:
        method: the method.
        estimate: what it estimated.
        marker_map: the estimate as a map (what map.json holds).
        map_error, map_error_aligned: marker errors in the home frame, and after the best
            rigid alignment.
        trajectory_error: ATE and RPE at ``path``'s stamps (the odometry's rate).
        true_path: the true base poses at ``path``'s stamps, in the home marker's frame.
        path: the corrected path at the odometry's rate (the map frame): the estimate's poses
            with the odometry between them (:func:`~markergraph.estimator.corrected_odometry`);
            None until :func:`~markergraph.run.map_logs` fills it.
        odometry_map: the raw odometry placed by the first optimised pose (the map frame).
        inside_95_ellipse: the share of true markers inside the estimate's 95 % ellipses (None
            without covariances or truth): 0.95 when they are honest.
        yaw_inside_95: the share of true marker yaws inside the estimate's 95 % intervals
            (None likewise).
        judgement: how far the estimate can be trusted, and why (:mod:`markergraph.verdicts`).
    """

    method: Method
    estimate: Estimate
    marker_map: MarkerMap
    map_error: MapError | None = None
    map_error_aligned: MapError | None = None
    trajectory_error: TrajectoryError | None = None
    true_path: Trajectory | None = None
    path: Trajectory | None = None
    odometry_map: Trajectory | None = None
    inside_95_ellipse: float | None = None
    yaw_inside_95: float | None = None
    judgement: Judgement = field(default_factory=lambda: Judgement(Verdict.OK))

    @property
    def label(self) -> str:
        return self.method.value


@dataclass(frozen=True)
class Session:
    """One log of a several-log map: where its robot went in the map (None: it shares no
    marker with the map, and is mapped on its own in ``MapRun.separate``)."""

    log: Path
    extraction: Extraction
    frames: Frames
    trajectory: Trajectory | None


@dataclass
class MapRun:
    """Everything the main job produced.

    Attributes:
        log: the log read (with several, the first placed in the map).
        config: the settings it was read and estimated with.
        extraction: the front end's output.
        frames: the estimator's input.
        results: one per method, in the order asked.
        true_markers: ground truth ``T_map_marker`` in the estimate's map frame (empty for a
            real log).
        true_path: the true base path in the estimate's map frame, if logged.
        camera_delay_ns: how late the camera's stamps were taken to be against odometry [ns].
        odometry_source: the odometry noise model used (``wheel``, ``vio``, ``t265``).
        odometry_model_reason: what chose that model.
        odometry_scale: what the odometry's distances were multiplied by.
        odometry_scale_sigma: its standard deviation where SLAM's residuals chose it, else None.
        odometry_turn_scale: what the odometry's turns were multiplied by (a track width off).
        odometry_turn_scale_sigma: its standard deviation where SLAM's residuals chose it.
        camera_delay_sigma_ns: the camera delay's, the same way [ns].
        notes: what the front end and the preparation of the log noticed, in that order.
        seconds: stage -> wall time.
        sessions: with several logs, each log and its trajectory in the map.
        separate: maps of logs that share no marker with this one: (their logs, the map).
        judgement: the run's verdict: the gravest of its methods', each reason naming its
            method (:func:`~markergraph.run.judge`).
        misread_markers: markers whose every observation was left out as a misread id (none
            of them is missing from the map: each was never there).
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
    odometry_model_reason: str | None = None
    odometry_scale: float = 1.0
    odometry_scale_sigma: float | None = None
    odometry_turn_scale: float = 1.0
    odometry_turn_scale_sigma: float | None = None
    camera_delay_sigma_ns: float | None = None
    notes: list[Note] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)
    sessions: list[Session] = field(default_factory=list)
    separate: list[tuple[list[Path], MarkerMap]] = field(default_factory=list)
    judgement: Judgement = field(default_factory=lambda: Judgement(Verdict.OK))
    misread_markers: frozenset[int] = frozenset()


@dataclass
class LocalizationRun:
    """A log localised against a saved map.

    Attributes:
        log, map_path: the log and the saved map.
        saved: the saved map.
        config: the settings.
        extraction: the front end's output.
        localization: trajectory, pose covariances, moved and new markers.
        ate_m: the trajectory's RMS error against the logged truth, if any, home-fixed (the
            truth carried into the map frame by the home marker's true pose) [m].
        true_path: the logged truth at ``path``'s stamps, in the map frame.
        notes: what a person should read.
        ate_aligned_m: the same error after a rigid 2-D alignment, if any [m].
        path: the robot's path at the odometry's rate: the localised poses at the frames with
            markers, the odometry between them (:func:`~markergraph.estimator.corrected_odometry`);
            None: the localised poses alone.
    """

    log: Path
    map_path: Path
    saved: MarkerMap
    config: MapConfig
    extraction: Extraction
    localization: Localization
    ate_m: float | None
    true_path: Trajectory | None
    notes: list[Note]
    ate_aligned_m: float | None = None
    path: Trajectory | None = None

    def document(self) -> dict[str, Any]:
        """``localization.json``: every pose with its covariance, the moved and new markers,
        and how far each map marker was pulled (schema ``markergraph.localization/1``)."""
        loc = self.localization
        return {
            "schema": "markergraph.localization/1",
            "map": str(self.map_path),
            "log": str(self.log),
            "frame": "the saved map's (its home marker's) frame; x, y [m], yaw [rad]; a "
            "marker's covariance over (x, y, yaw) in its own frame, as map.json's",
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
                    "now_covariance": _listed(m.covariance_now),
                    "pulled_sigmas": m.prior_whitened,
                }
                for m in loc.moved
            ],
            "new": [
                {"id": i, **_pose(m.T_map_marker), "covariance": _listed(m.covariance)}
                for i, m in sorted(loc.new.items())
            ],
            "pulled_sigmas": {str(i): v for i, v in sorted(loc.checked.items())},
            "ate_m": self.ate_m,
            "ate_aligned_m": self.ate_aligned_m,
            "notes": [note.text for note in self.notes],
        }


def _listed(covariance: NDArray[np.float64] | None) -> list[list[float]] | None:
    return None if covariance is None else np.asarray(covariance).tolist()


def _pose(T: gtsam.Pose2) -> dict[str, float]:
    return {"x": T.x(), "y": T.y(), "yaw": T.theta()}
