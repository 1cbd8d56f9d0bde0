"""The SLAM methods: SLAM (batch Levenberg-Marquardt) and ISAM2 (incremental), over robot
poses and markers."""

from __future__ import annotations

import time

import gtsam
import numpy as np
from gtsam.symbol_shorthand import X

from markergraph.common.errors import EstimationError
from markergraph.common.notes import Note
from markergraph.estimator.estimate import Estimate
from markergraph.estimator.frames import Frames
from markergraph.estimator.graph import (
    FactorMemo,
    GraphBuilder,
    Robust,
    base_pose,
    observation_measurement,
)
from markergraph.estimator.links import components, link_counts, measure_links
from markergraph.estimator.solution import (
    SEARCH_RELATIVE_ERROR_TOL,
    disconnected_notes,
    lm_params,
    not_converged_note,
    optimise,
    solved_estimate,
)
from markergraph.estimator.trajectory import Trajectory
from markergraph.estimator.types import Method

__all__ = [
    "IncrementalSlam",
    "build_slam_graph",
    "new_isam2",
    "slam_cost",
    "solve_isam2",
    "solve_slam",
]


def _T_map_odom(frames: Frames, T_base_camera: gtsam.Pose2) -> gtsam.Pose2:
    """The odometry frame in the map, from the first sight of the home marker."""
    frame = frames.frames[frames.home_frame]
    home = next(o for o in frame.observations if o.marker_id == frames.home_id)
    T_base_home, _ = observation_measurement(home, T_base_camera)
    return T_base_home.inverse().compose(frame.T_odom_base.inverse())


def build_slam_graph(
    frames: Frames,
    T_base_camera: gtsam.Pose2,
    robust: Robust = Robust.NONE,
    memo: FactorMemo | None = None,
) -> GraphBuilder:
    """The full SLAM graph: home prior, odometry chain, one factor per observation, with
    initial values from odometry anchored on home, each marker at its medoid sighting
    (``memo``: :class:`GraphBuilder`'s)."""
    builder = GraphBuilder(T_base_camera, robust, memo)
    builder.add_home_prior(frames.home_id)
    T_map_odom = _T_map_odom(frames, T_base_camera)
    for k in range(len(frames.frames)):
        builder.add_frame(frames, k, T_map_odom)
    builder.start_markers_at_medoids()
    return builder


def _trajectory(values: gtsam.Values, frames: Frames, builder: GraphBuilder) -> Trajectory:
    return Trajectory(
        np.array([f.t_ns for f in frames.frames], dtype=np.int64),
        builder.base_poses(values, [X(k) for k in range(len(frames.frames))]),
    )


def _slam_notes(frames: Frames, T_base_camera: gtsam.Pose2) -> tuple[list, list[Note]]:
    links = measure_links(frames, T_base_camera)
    groups = components(frames.marker_ids(), links)
    notes = disconnected_notes(
        "slam.disconnected", groups, frames.home_id, "; only odometry joins them to the map"
    )
    return link_counts(links), notes


def solve_slam(
    frames: Frames, T_base_camera: gtsam.Pose2, robust: Robust = Robust.NONE
) -> Estimate:
    """``Method.SLAM``: batch Levenberg-Marquardt over robot poses and markers."""
    timings: dict[str, float] = {}
    start = time.perf_counter()
    builder = build_slam_graph(frames, T_base_camera, robust)
    timings["build"] = time.perf_counter() - start
    result, converged = optimise(builder, timings)
    return _slam_estimate(
        Method.SLAM, frames, T_base_camera, builder, result, converged, not_converged_note(),
        timings,
    )  # fmt: skip


def slam_cost(
    frames: Frames,
    T_base_camera: gtsam.Pose2,
    robust: Robust = Robust.NONE,
    near: gtsam.Values | None = None,
    memo: FactorMemo | None = None,
) -> tuple[float, gtsam.Values]:
    """Batch SLAM's final cost alone (no marginals, residuals or links) and its solution: what
    a search over a setting compares. ``near``: the solution under a nearby setting, to start
    from when it holds the same variables (else the pose-graph form's solution is the start);
    ``memo``: the search's observation factors (:class:`GraphBuilder`).

    Raises:
        EstimationError: GTSAM cannot solve the graph.
    """
    builder = build_slam_graph(frames, T_base_camera, robust, memo)
    keys = builder.values.keys()  # a gtsam KeyVector
    params = lm_params(SEARCH_RELATIVE_ERROR_TOL)
    if near is not None and near.size() == len(keys) and all(near.exists(k) for k in keys):
        builder.values = near
        result, _ = optimise(builder, {}, warm=False, params=params)
    else:
        result, _ = optimise(builder, {}, params=params)
    return float(builder.graph.error(result)), result


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
    return solved_estimate(
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
        result, converged = optimise(polish, timings, warm=False)
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
