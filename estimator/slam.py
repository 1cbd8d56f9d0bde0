"""The GTSAM methods: MARKER_GRAPH (markers only), SLAM (batch) and ISAM2 (incremental)."""

from __future__ import annotations

import math
import time
from collections import Counter, deque
from functools import partial

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from markergraph.common.errors import EstimationError
from markergraph.common.notes import Note
from markergraph.estimator.estimate import Estimate
from markergraph.estimator.frames import Frames
from markergraph.estimator.gauge import relative_covariances
from markergraph.estimator.graph import (
    GraphBuilder,
    Robust,
    base_pose,
    observation_measurement,
    read_residuals,
)
from markergraph.estimator.links import (
    MAX_LINK_SIGMA_THETA_RAD,
    components,
    describe_disconnected,
    link_counts,
    linkable,
    measure_links,
)
from markergraph.estimator.trajectory import Trajectory
from markergraph.estimator.types import MarkerEstimate, Method

__all__ = [
    "IncrementalSlam",
    "lm_params",
    "localise_on_markers",
    "marginals_or_note",
    "slam_cost",
    "solve_isam2",
    "solve_marker_graph",
    "solve_slam",
]

MAX_ITERATIONS = 100


def lm_params() -> gtsam.LevenbergMarquardtParams:
    """Levenberg-Marquardt's settings for every batch solve here and in sessions.py."""
    # Tighter tolerances buy nothing measurable and cost rejected steps at convergence
    # (1.5 s instead of 0.36 s on the 10,000-pose benchmark).
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(MAX_ITERATIONS)
    params.setRelativeErrorTol(1e-10)
    params.setAbsoluteErrorTol(1e-12)
    return params


def _T_map_odom(frames: Frames, T_base_camera: gtsam.Pose2) -> gtsam.Pose2:
    """The odometry frame in the map, from the first sight of the home marker."""
    frame = frames.frames[frames.home_frame]
    home = next(o for o in frame.observations if o.marker_id == frames.home_id)
    T_base_home, _ = observation_measurement(home, T_base_camera)
    return T_base_home.inverse().compose(frame.T_odom_base.inverse())


def marker_estimates(
    values: gtsam.Values,
    marker_ids: list[int],
    counts: Counter[int],
    marginals: gtsam.Marginals | None,
) -> dict[int, MarkerEstimate]:
    poses = [values.atPose2(L(i)) for i in marker_ids]
    if marginals is None:
        return {
            i: MarkerEstimate(i, T, None, counts[i]) for i, T in zip(marker_ids, poses, strict=True)
        }
    keys = gtsam.KeyVector([L(i) for i in marker_ids])
    joint = marginals.jointMarginalCovariance(keys).fullMatrix()
    relative = relative_covariances(poses, joint)
    return {
        i: MarkerEstimate(i, T, joint[3 * k : 3 * k + 3, 3 * k : 3 * k + 3].copy(), counts[i],
                          relative[k])
        for k, (i, T) in enumerate(zip(marker_ids, poses, strict=True))
    }  # fmt: skip


def marginals_or_note(
    graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, notes: list[Note]
) -> gtsam.Marginals | None:
    """The solution's marginals, or None with a note saying why when the system is
    indeterminate (the means are kept)."""
    try:
        return gtsam.Marginals(graph, values)
    except RuntimeError as error:  # an indeterminate system: report, keep the means
        notes.append(
            Note("marginals.unavailable", f"marginal covariances unavailable: {first_line(error)}")
        )
        return None


def first_line(error: Exception) -> str:
    """GTSAM's messages start with a blank line: the first line that says something."""
    return next((line.strip() for line in str(error).splitlines() if line.strip()), repr(error))


def _observation_counts(frames: Frames) -> Counter[int]:
    return Counter(o.marker_id for f in frames.frames for o in f.observations)


def build_slam_graph(
    frames: Frames, T_base_camera: gtsam.Pose2, robust: Robust = Robust.NONE
) -> GraphBuilder:
    """The full SLAM graph: home prior, odometry chain, one factor per observation, with
    initial values from odometry anchored on home."""
    builder = GraphBuilder(T_base_camera, robust)
    builder.add_home_prior(frames.home_id)
    T_map_odom = _T_map_odom(frames, T_base_camera)
    for k in range(len(frames.frames)):
        builder.add_frame(frames, k, T_map_odom)
    return builder


def _trajectory(values: gtsam.Values, frames: Frames, builder: GraphBuilder) -> Trajectory:
    return Trajectory(
        np.array([f.t_ns for f in frames.frames], dtype=np.int64),
        builder.base_poses(values, [X(k) for k in range(len(frames.frames))]),
    )


def _slam_notes(frames: Frames, T_base_camera: gtsam.Pose2) -> tuple[list, list[Note]]:
    links = measure_links(frames, T_base_camera)
    groups = components(frames.marker_ids(), links)
    notes = _disconnected_notes(
        "slam.disconnected", groups, frames.home_id, "; only odometry joins them to the map"
    )
    return link_counts(links), notes


def _disconnected_notes(
    kind: str, groups: list[list[int]], home_id: int, ending: str = ""
) -> list[Note]:
    """A note per group of markers no link chain joins to home (``describe_disconnected``'s
    sentences), its figure the group's size."""
    apart = [group for group in groups if home_id not in group]
    sentences = describe_disconnected(groups, home_id)
    return [
        Note(kind, f"{sentence}{ending}", figure=len(group))
        for group, sentence in zip(apart, sentences, strict=True)
    ]


def solve_slam(
    frames: Frames, T_base_camera: gtsam.Pose2, robust: Robust = Robust.NONE
) -> Estimate:
    """``Method.SLAM``: batch Levenberg-Marquardt over robot poses and markers."""
    timings: dict[str, float] = {}
    start = time.perf_counter()
    builder = build_slam_graph(frames, T_base_camera, robust)
    timings["build"] = time.perf_counter() - start
    result, converged = _optimise(builder, timings)
    stop_note = Note(
        "slam.not_converged",
        f"Levenberg-Marquardt stopped after {MAX_ITERATIONS} iterations without "
        "converging; the map is its last estimate",
        figure=MAX_ITERATIONS,
    )
    return _slam_estimate(
        Method.SLAM, frames, T_base_camera, builder, result, converged, stop_note, timings
    )


def slam_cost(
    frames: Frames,
    T_base_camera: gtsam.Pose2,
    robust: Robust = Robust.NONE,
    near: gtsam.Values | None = None,
) -> tuple[float, gtsam.Values]:
    """Batch SLAM's final cost alone (no marginals, residuals or links) and its solution: what
    a search over a setting compares. ``near``: the solution under a nearby setting, to start
    from when it holds the same variables (else the pose-graph form's solution is the start).

    Raises:
        EstimationError: GTSAM cannot solve the graph.
    """
    builder = build_slam_graph(frames, T_base_camera, robust)
    keys = builder.values.keys()  # a gtsam KeyVector
    if near is not None and near.size() == len(keys) and all(near.exists(k) for k in keys):
        builder.values = near
        result, _ = _optimise(builder, {}, warm=False)
    else:
        result, _ = _optimise(builder, {})
    return float(builder.graph.error(result)), result


def _optimise(
    builder: GraphBuilder, timings: dict[str, float], warm: bool = True
) -> tuple[gtsam.Values, bool]:
    """Levenberg-Marquardt from the builder's initial values, or (``warm``) from its pose-graph
    form's solution (:meth:`GraphBuilder.warm_start`); (solution, converged)."""
    start = time.perf_counter()
    try:
        start_values = builder.warm_start(lm_params()) if warm else builder.values
        optimizer = gtsam.LevenbergMarquardtOptimizer(builder.graph, start_values, lm_params())
        result = optimizer.optimize()
    except RuntimeError as error:  # GTSAM's IndeterminantLinearSystemException
        raise EstimationError(
            f"GTSAM could not solve the graph: {str(error).splitlines()[0]}"
        ) from None
    timings["optimize"] = time.perf_counter() - start
    return result, optimizer.iterations() < MAX_ITERATIONS


def _solved_estimate(
    method: Method,
    frames: Frames,
    builder: GraphBuilder,
    result: gtsam.Values,
    *,
    marker_ids: list[int],
    trajectory: Trajectory,
    links: list,
    notes: list[Note],
    converged: bool,
    timings: dict[str, float],
    unplaced: dict[int, str] | None = None,
    observations_unlinked: int | None = None,
) -> Estimate:
    """The Estimate of a solved factor graph: markers with their joint marginals, the
    trajectory, residuals, links and notes, and the graph and solution themselves."""
    graph = builder.graph
    start = time.perf_counter()
    marginals = marginals_or_note(graph, result, notes)
    estimate = Estimate(
        method=method,
        home_id=frames.home_id,
        markers=marker_estimates(result, marker_ids, _observation_counts(frames), marginals),
        trajectory=trajectory,
        residuals=read_residuals(graph, result, builder.kinds),
        links=links,
        unplaced=unplaced or {},
        converged=converged,
        notes=notes,
        graph=graph,
        values=result,
        pose_graph=partial(builder.pose_graph, result),
        observations_unlinked=observations_unlinked,
    )
    timings["marginals"] = time.perf_counter() - start
    estimate.timings_s = timings
    return estimate


def _slam_estimate(
    method: Method,
    frames: Frames,
    T_base_camera: gtsam.Pose2,
    builder: GraphBuilder,
    result: gtsam.Values,
    converged: bool,
    stop_note: Note,
    timings: dict[str, float],
) -> Estimate:
    """The Estimate of a solved SLAM graph, batch or incremental."""
    links, notes = _slam_notes(frames, T_base_camera)
    return _solved_estimate(
        method,
        frames,
        builder,
        result,
        marker_ids=frames.marker_ids(),
        trajectory=_trajectory(result, frames, builder),
        links=links,
        notes=frames.notes + notes + ([] if converged else [stop_note]),
        converged=converged,
        timings=timings,
    )


def new_isam2() -> gtsam.ISAM2:
    """An iSAM2 as every incremental method here uses it."""
    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(0.01)
    params.relinearizeSkip = 1
    # Cholesky declared a 10,000-pose warehouse run indeterminate (turning in place makes
    # odometry nearly exact in translation); QR solves it at the same speed.
    params.setFactorization("QR")
    return gtsam.ISAM2(params)


class IncrementalSlam:
    """The SLAM graph grown and solved frame by frame with iSAM2.

    Frames before the first sight of the home marker wait in a buffer: until then nothing fixes
    the map frame. New poses start from odometry carried by a correction ``T_map_odom`` that is
    re-read from the solution every ``REANCHOR_EVERY`` updates: reading the estimate each frame
    would cost half as much again as the update itself.
    """

    REANCHOR_EVERY = 10

    def __init__(
        self, frames: Frames, T_base_camera: gtsam.Pose2, robust: Robust = Robust.NONE
    ) -> None:
        self.isam = new_isam2()
        self.frames = frames
        self.builder = GraphBuilder(T_base_camera, robust)
        self.T_map_odom = _T_map_odom(frames, T_base_camera)
        self.next_frame = 0
        self.updates = 0

    def add_frames_through(self, k: int) -> None:
        """Add every frame up to and including ``k`` in one iSAM2 update (if home was seen)."""
        if k < self.frames.home_frame:
            return
        if self.next_frame == 0:
            self.builder.add_home_prior(self.frames.home_id)
        for j in range(self.next_frame, k + 1):
            self.builder.add_frame(self.frames, j, self.T_map_odom)
        try:
            self.isam.update(*self.builder.take_new())
        except RuntimeError as error:  # GTSAM's IndeterminantLinearSystemException
            raise EstimationError(
                f"iSAM2 could not solve the graph at frame {k}: {str(error).splitlines()[0]}"
            ) from None
        self.next_frame = k + 1
        self.updates += 1
        if self.updates % self.REANCHOR_EVERY == 0:
            T_map_base = base_pose(
                self.isam.calculateEstimatePose2(X(k)), self.builder.T_base_camera
            )
            self.T_map_odom = T_map_base.compose(self.frames.frames[k].T_odom_base.inverse())

    def finish(self, max_sweeps: int = 30, tolerance: float = 1e-6) -> bool:
        """Relinearise everything until the estimate stops moving; True if it did.

        A full solve as well: during the incremental updates iSAM2 skips back-substituting
        changes below its wildfire threshold, which leaves ~1e-3 m between it and batch. Each
        sweep is one Gauss-Newton step; with a robust kernel the weights move with it and the
        steps shrink only linearly (16 sweeps on the corridor sample with Huber).
        """
        params = gtsam.ISAM2UpdateParams()
        params.force_relinearize = True
        params.forceFullSolve = True
        before = self.isam.calculateEstimate()
        for _ in range(max_sweeps):
            self.isam.update(gtsam.NonlinearFactorGraph(), gtsam.Values(), params)
            after = self.isam.calculateEstimate()
            keys = after.keys()  # a gtsam KeyVector
            change = max(
                np.max(np.abs(gtsam.Pose2.Logmap(before.atPose2(key).between(after.atPose2(key)))))
                for key in keys
            )
            before = after
            if change < tolerance:
                return True
        return False


def solve_isam2(
    frames: Frames, T_base_camera: gtsam.Pose2, robust: Robust = Robust.NONE
) -> Estimate:
    """``Method.ISAM2``: the SLAM graph, one iSAM2 update per frame, then relinearised to rest.

    With a robust kernel the final relinearisations reweight one Gauss-Newton step at a time
    and may creep (75 sweeps on TagSLAM's outdoor recording); after ``finish``'s sweeps a
    batch Levenberg-Marquardt pass from iSAM2's estimate brings it to rest, and a note says so.
    """
    start = time.perf_counter()
    slam = IncrementalSlam(frames, T_base_camera, robust)
    for k in range(len(frames.frames)):
        slam.add_frames_through(k)
    timings = {"updates": time.perf_counter() - start}
    start = time.perf_counter()
    converged = slam.finish()
    timings["finish"] = time.perf_counter() - start
    result = slam.isam.calculateEstimate()
    builder = slam.builder
    polished = not converged
    if polished:
        polish = GraphBuilder(T_base_camera, robust)
        polish.graph, polish.values = builder.graph, result
        result, converged = _optimise(polish, timings, warm=False)
    estimate = _slam_estimate(
        Method.ISAM2,
        frames,
        T_base_camera,
        builder,
        result,
        converged,
        Note("isam2.not_converged", "iSAM2 did not come to rest, nor did a batch pass after it"),
        timings,
    )
    if polished and converged:
        estimate.notes.append(Note(
            "isam2.polished",
            "iSAM2's final relinearisations crept (a robust kernel reweights one step at a "
            "time); a batch Levenberg-Marquardt pass from its estimate brought it to rest",
        ))  # fmt: skip
    return estimate


def localise_on_markers(
    frames: Frames, values: gtsam.Values, placed: set[int], T_base_camera: gtsam.Pose2
) -> Trajectory:
    """The robot in each frame, from its nearest placed marker: the marker graph keeps no
    robot poses, so this is how the paper's robot localises on the map. Only observations whose
    theta was measured place it: the robot's heading is the marker's yaw turned by theta."""
    t_ns, rows = [], []
    for frame in frames.frames:
        seen = [o for o in frame.observations if o.marker_id in placed and linkable(o)]
        if not seen:
            continue
        nearest = min(seen, key=lambda o: o.range_m)
        T_base_marker, _ = observation_measurement(nearest, T_base_camera)
        T_map_base = values.atPose2(L(nearest.marker_id)).compose(T_base_marker.inverse())
        t_ns.append(frame.t_ns)
        rows.append([T_map_base.x(), T_map_base.y(), T_map_base.theta()])
    return Trajectory(np.array(t_ns, dtype=np.int64), np.array(rows))


def solve_marker_graph(
    frames: Frames, T_base_camera: gtsam.Pose2, robust: Robust = Robust.NONE
) -> Estimate:
    """``Method.MARKER_GRAPH``: the paper's node graph, every measured E_ab a between factor."""
    timings: dict[str, float] = {}
    start = time.perf_counter()
    links = measure_links(frames, T_base_camera)
    marker_ids = frames.marker_ids()
    groups = components(marker_ids, links)
    placed = next(group for group in groups if frames.home_id in group)
    notes = frames.notes + _disconnected_notes("marker_graph.disconnected", groups, frames.home_id)
    unlinked = sum(not linkable(o) for f in frames.frames for o in f.observations)
    if unlinked:
        total = sum(len(f.observations) for f in frames.frames)
        notes.append(Note(
            "marker_graph.unlinked",
            f"{unlinked} of {total} observations end no link: their theta's sigma is over "
            f"{math.degrees(MAX_LINK_SIGMA_THETA_RAD):.0f} deg (grazing views), and a link "
            "turns on the theta at each end",
            figure=unlinked,
        ))  # fmt: skip
    unplaced = {
        i: "no chain of links reaches the home marker"
        for group in groups
        if frames.home_id not in group
        for i in group
    }
    builder = GraphBuilder(T_base_camera, robust)
    builder.add_home_prior(frames.home_id)
    for link in links:
        if link.marker_a in placed:
            builder.add_link(link.marker_a, link.marker_b, link.T_a_b, link.covariance)
    # Initial values: compose the first link found outward from home (a spanning tree).
    builder.set_initial(frames.home_id, gtsam.Pose2())
    by_marker: dict[int, list] = {}
    for link in links:
        by_marker.setdefault(link.marker_a, []).append((link.marker_b, link.T_a_b))
        by_marker.setdefault(link.marker_b, []).append((link.marker_a, link.T_a_b.inverse()))
    queue = deque([frames.home_id])
    while queue:
        a = queue.popleft()
        for b, T_a_b in by_marker.get(a, []):
            if not builder.values.exists(L(b)):
                builder.set_initial(b, builder.values.atPose2(L(a)).compose(T_a_b))
                queue.append(b)
    timings["build"] = time.perf_counter() - start
    result, converged = _optimise(builder, timings, warm=False)  # links are relative poses
    return _solved_estimate(
        Method.MARKER_GRAPH,
        frames,
        builder,
        result,
        marker_ids=placed,
        trajectory=localise_on_markers(frames, result, set(placed), T_base_camera),
        links=link_counts(links),
        notes=notes,
        converged=converged,
        timings=timings,
        unplaced=unplaced,
        observations_unlinked=unlinked,
    )
