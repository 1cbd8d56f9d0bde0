"""Many logs of one place: several sessions in one graph, a saved map's markers as priors
(localisation against a saved map, built on it, is in localization.py).

Each session keeps its own odometry chain: nothing joins the last pose of one log to the first
of the next, because a robot switched off, pushed or carried between logs has no odometry for
it. Markers seen in several sessions tie them together. A session that shares no marker with
the map built so far cannot be placed in it and is handed back, to be mapped on its own.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X
from numpy.typing import NDArray

from markergraph.common.errors import EstimationError
from markergraph.common.notes import Note
from markergraph.estimator.frames import Frames
from markergraph.estimator.graph import (
    GraphBuilder,
    Robust,
    base_covariance,
    observation_measurement,
    read_residuals,
)
from markergraph.estimator.links import measure_links
from markergraph.estimator.marker_graph import localise_on_markers
from markergraph.estimator.slam import new_isam2
from markergraph.estimator.solution import (
    first_line,
    lm_params,
    marginals_or_note,
    marker_estimates,
)
from markergraph.estimator.trajectory import Trajectory
from markergraph.estimator.types import FactorResidual, MarkerEstimate, Method

__all__ = [
    "MapPrior",
    "SessionsEstimate",
    "solve_sessions",
]


@dataclass(frozen=True)
class MapPrior:
    """A saved map's marker: its pose in the map frame and its 3x3 covariance (x, y, yaw, in
    its tangent space)."""

    T_map_marker: gtsam.Pose2
    covariance: NDArray[np.float64]


@dataclass
class SessionsEstimate:
    """One map from several sessions.

    Attributes:
        markers: marker id -> its estimate, in the map frame.
        trajectories: each session's robot poses in the map frame; None for a session that
            could not be placed (see ``apart``).
        pose_covariances: each placed session's (N, 3, 3) pose covariances, when asked for.
        apart: sessions that share no marker with this map, in their order.
        residuals: every factor's whitened error.
        notes: what a person should read (kinds ``sessions.*``, ``marginals.*``).
        graph, values: the graph solved and its solution (robot poses are the camera's).
        pose_graph: makes the solution as a plain pose graph (``GraphBuilder.pose_graph``).
    """

    markers: dict[int, MarkerEstimate]
    trajectories: list[Trajectory | None]
    pose_covariances: list[NDArray[np.float64] | None]
    apart: list[int]
    residuals: list[FactorResidual] = field(default_factory=list)
    notes: list[Note] = field(default_factory=list)
    graph: gtsam.NonlinearFactorGraph | None = None
    values: gtsam.Values | None = None
    pose_graph: Callable[[], tuple[gtsam.NonlinearFactorGraph, gtsam.Values]] | None = None


def _anchor(
    frames: Frames,
    known: Mapping[int, gtsam.Pose2],
    T_base_camera: gtsam.Pose2,
) -> gtsam.Pose2 | None:
    """``T_map_odom`` of a session, from its first sight of a marker already in the map; None
    if it sees none."""
    for frame in frames.frames:
        for obs in frame.observations:
            if obs.marker_id in known:
                T_base_marker, _ = observation_measurement(obs, T_base_camera)
                T_map_base = known[obs.marker_id].compose(T_base_marker.inverse())
                return T_map_base.compose(frame.T_odom_base.inverse())
    return None


def _add_links(
    builder: GraphBuilder, frames: Frames, T_base_camera: gtsam.Pose2, T_map_odom: gtsam.Pose2
) -> None:
    """A session's measured E_ab as factors; markers new to the map start where the session's
    odometry, anchored by ``T_map_odom``, first sees them."""
    links = measure_links(frames, T_base_camera)
    for link in links:
        builder.add_link(link.marker_a, link.marker_b, link.T_a_b, link.covariance)
    for frame in frames.frames:
        T_map_base = T_map_odom.compose(frame.T_odom_base)
        for obs in frame.observations:
            if not builder.values.exists(L(obs.marker_id)):
                T_base_marker, _ = observation_measurement(obs, T_base_camera)
                builder.set_initial(obs.marker_id, T_map_base.compose(T_base_marker))


def _update(isam: gtsam.ISAM2, builder: GraphBuilder) -> None:
    graph, values = builder.take_new()
    if graph.size() or values.size():
        try:
            isam.update(graph, values)
        except RuntimeError as error:  # GTSAM's IndeterminantLinearSystemException
            raise EstimationError(f"iSAM2 could not solve the graph: {first_line(error)}") from None


def _isam2_to_rest(isam: gtsam.ISAM2, builder: GraphBuilder) -> gtsam.Values:
    """iSAM2's estimate after full relinearisations, then a batch pass from it (as
    :func:`~markergraph.estimator.slam.solve_isam2` ends) so robust weights settle."""
    params = gtsam.ISAM2UpdateParams()
    params.force_relinearize = True
    params.forceFullSolve = True
    for _ in range(5):
        isam.update(gtsam.NonlinearFactorGraph(), gtsam.Values(), params)
    start = isam.calculateEstimate()
    return gtsam.LevenbergMarquardtOptimizer(builder.graph, start, lm_params()).optimize()


def solve_sessions(
    sessions: Sequence[Frames],
    T_base_cameras: Sequence[gtsam.Pose2],
    *,
    robust: Robust = Robust.HUBER,
    priors: Mapping[int, MapPrior] | None = None,
    home_id: int | None = None,
    pose_covariances: bool = False,
    method: Method = Method.SLAM,
) -> SessionsEstimate:
    """SLAM over several sessions (logs) of one place: batch (``Method.SLAM``), one iSAM2
    update per frame, session after session (``Method.ISAM2``), or the paper's marker graph
    from every session's measured links (``Method.MARKER_GRAPH``, robots localised on their
    nearest marker).

    Args:
        sessions: each log's frames (``build_frames``), in the order given by the user.
        T_base_cameras: each session's camera mount.
        priors: a saved map's markers; without them the home marker is fixed at the origin.
        home_id: the home marker (default: the first session's).
        pose_covariances: also compute every robot pose's marginal covariance.

    Raises:
        EstimationError: no session can be placed, or GTSAM cannot solve the graph.
    """
    builder, known = _start_graph(sessions, T_base_cameras[0], robust, priors, home_id)
    offsets = np.concatenate([[0], np.cumsum([len(s.frames) for s in sessions])]).astype(int)
    isam = new_isam2() if method is Method.ISAM2 else None
    placed, pending = _place_sessions(
        _Placing(builder, known, sessions, T_base_cameras, offsets, method, isam)
    )
    values = _solve(builder, isam, method)
    notes: list[Note] = []
    marginals = marginals_or_note(builder.graph, values, notes)
    counts = Counter(
        o.marker_id for s in placed for f in sessions[s].frames for o in f.observations
    )
    markers = marker_estimates(
        values, [i for i in sorted(known) if values.exists(L(i))], counts, marginals,
        builder.graph,
    )  # fmt: skip
    trajectories: list[Trajectory | None] = [None] * len(sessions)
    covariances: list[NDArray[np.float64] | None] = [None] * len(sessions)
    for s in placed:
        if method is Method.MARKER_GRAPH:  # no robot poses: each frame on its nearest marker
            trajectories[s] = localise_on_markers(
                sessions[s], values, set(markers), T_base_cameras[s]
            )
            continue
        keys = [X(int(offsets[s]) + k) for k in range(len(sessions[s].frames))]
        trajectories[s] = Trajectory(
            np.array([f.t_ns for f in sessions[s].frames], dtype=np.int64),
            builder.base_poses(values, keys),
        )
        if pose_covariances and marginals is not None:
            covariances[s] = np.array([
                base_covariance(marginals.marginalCovariance(key), T_base_cameras[s])
                for key in keys
            ])  # fmt: skip
    if pending:
        notes.append(Note(
            "sessions.apart",
            f"session(s) {', '.join(str(s + 1) for s in pending)} share no marker with the "
            "map and are left out of it",
            figure=len(pending),
        ))  # fmt: skip
    return SessionsEstimate(
        markers, trajectories, covariances, pending,
        read_residuals(builder.graph, values, builder.kinds), notes, builder.graph, values,
        partial(builder.pose_graph, values),
    )  # fmt: skip


def _start_graph(
    sessions: Sequence[Frames],
    T_base_camera: gtsam.Pose2,
    robust: Robust,
    priors: Mapping[int, MapPrior] | None,
    home_id: int | None,
) -> tuple[GraphBuilder, dict[int, gtsam.Pose2]]:
    """The graph before any session: the saved map's priors, or the home marker fixed at the
    origin; and the markers it places (id -> pose in the map)."""
    builder = GraphBuilder(T_base_camera, robust)
    known: dict[int, gtsam.Pose2] = {}
    if priors:
        for marker_id, prior in sorted(priors.items()):
            builder.add_marker_prior(marker_id, prior.T_map_marker, prior.covariance)
            known[marker_id] = prior.T_map_marker
    else:
        home = sessions[0].home_id if home_id is None else home_id
        builder.add_home_prior(home)
        known[home] = gtsam.Pose2()
    return builder, known


@dataclass(frozen=True, slots=True)
class _Placing:
    """What placing the sessions in the graph works on."""

    builder: GraphBuilder
    """The graph, grown session by session."""
    known: dict[int, gtsam.Pose2]
    """Markers placed so far -> their pose in the map; grows as sessions are placed."""
    sessions: Sequence[Frames]
    """Each log's frames."""
    T_base_cameras: Sequence[gtsam.Pose2]
    """Each session's camera mount."""
    offsets: NDArray[np.int_]
    """Each session's first pose key (``X(offset)``)."""
    method: Method
    """SLAM, ISAM2 or MARKER_GRAPH."""
    isam: gtsam.ISAM2 | None
    """The incremental solver (``Method.ISAM2``), updated after every frame; else None."""


def _place_sessions(placing: _Placing) -> tuple[list[int], list[int]]:
    """Add every session that sees a marker already in the map, again until none more can be
    placed; (placed, pending) session indices.

    Raises:
        EstimationError: no session can be placed.
    """
    builder, known, sessions = placing.builder, placing.known, placing.sessions
    pending, placed = list(range(len(sessions))), []
    progress = True
    while pending and progress:
        progress = False
        for s in list(pending):
            T_map_odom = _anchor(sessions[s], known, placing.T_base_cameras[s])
            if T_map_odom is None:
                continue
            builder.T_base_camera = placing.T_base_cameras[s]
            if placing.method is Method.MARKER_GRAPH:
                _add_links(builder, sessions[s], placing.T_base_cameras[s], T_map_odom)
            else:
                for k in range(len(sessions[s].frames)):
                    builder.add_frame(sessions[s], k, T_map_odom, int(placing.offsets[s]))
                    if placing.isam is not None:
                        _update(placing.isam, builder)
            for marker_id in sessions[s].marker_ids():
                known.setdefault(marker_id, builder.values.atPose2(L(marker_id)))
            pending.remove(s)
            placed.append(s)
            progress = True
    if not placed:
        raise EstimationError(
            "no session sees a marker of the map (or the home marker): nothing to place"
        )
    return placed, pending


def _solve(builder: GraphBuilder, isam: gtsam.ISAM2 | None, method: Method) -> gtsam.Values:
    """The placed sessions' solution: iSAM2 brought to rest, or batch Levenberg-Marquardt
    (from the pose-graph form's solution for SLAM, from the links' initial values for the
    marker graph).

    Raises:
        EstimationError: GTSAM cannot solve the graph.
    """
    if isam is not None:
        _update(isam, builder)
    try:
        if isam is not None:
            return _isam2_to_rest(isam, builder)
        start = (
            builder.values if method is Method.MARKER_GRAPH
            else builder.warm_start(lm_params())
        )  # fmt: skip
        optimizer = gtsam.LevenbergMarquardtOptimizer(builder.graph, start, lm_params())
        return optimizer.optimize()
    except RuntimeError as error:
        raise EstimationError(f"GTSAM could not solve the graph: {first_line(error)}") from None
