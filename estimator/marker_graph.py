"""``Method.MARKER_GRAPH``: the paper's node graph of markers alone, every measured E_ab a
between factor, and the robot localised on its nearest marker."""

from __future__ import annotations

import math
import time
from collections import deque

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L

from markergraph.common.notes import Note
from markergraph.estimator.estimate import Estimate
from markergraph.estimator.frames import Frames
from markergraph.estimator.graph import GraphBuilder, Robust, observation_measurement
from markergraph.estimator.links import (
    MAX_LINK_SIGMA_THETA_RAD,
    components,
    link_counts,
    linkable,
    measure_links,
)
from markergraph.estimator.solution import disconnected_notes, optimise, solved_estimate
from markergraph.estimator.trajectory import Trajectory
from markergraph.estimator.types import Method

__all__ = ["localise_on_markers", "solve_marker_graph"]


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
    notes = frames.notes + disconnected_notes("marker_graph.disconnected", groups, frames.home_id)
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
    result, converged = optimise(builder, timings, warm=False)  # links are relative poses
    return solved_estimate(
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
