"""``Method.CLOSED_FORM``: the paper's own mapping procedure, with no optimisation.

The robot localises on the home marker, dead-reckons with odometry, and re-localises on every
placed marker it sees again. A marker seen for the first time is linked to the marker it was last
localised on by ``E_ab`` (:func:`paper.edge_from_observation`) and placed by composing ``M`` from
home (:func:`paper.compose`): a spanning tree, each marker placed once, no loop closure.
"""

from __future__ import annotations

import math
import time
from collections import Counter

import gtsam
import numpy as np

from markergraph.estimator.angles import wrap
from markergraph.estimator.frames import Frames
from markergraph.estimator.graph import observation_measurement
from markergraph.estimator.paper import (
    Edge,
    Form,
    compose,
    edge_from_observation,
    edge_to_pose2,
)
from markergraph.estimator.trajectory import Trajectory
from markergraph.estimator.types import Estimate, MarkerEstimate, MarkerLink, Method, Observation

__all__ = ["solve_closed_form"]

# The paper measures theta only on a marker it has turned to face; an observation whose theta
# is this uncertain (a grazing view, where the square's two poses look alike) is not used.
MAX_SIGMA_THETA_RAD = math.radians(10.0)


def _edge_to_new_marker(
    T_a_base: gtsam.Pose2, obs_b: Observation, T_base_camera: gtsam.Pose2, form: Form
) -> Edge:
    """``E_ab`` from the dead-reckoned camera pose about a and an observation of b.

    The paper's inputs: the camera's polar position ``(d_a, theta_a)`` about a, the turn
    ``theta_delta`` from facing straight away from a to facing b (the camera's heading plus b's
    bearing, so off-centre observations need no extra turn), b's range and theta.
    """
    T_a_camera = T_a_base.compose(T_base_camera)
    d_a = math.hypot(T_a_camera.x(), T_a_camera.y())
    theta_a = math.atan2(T_a_camera.y(), T_a_camera.x())
    theta_delta = wrap(T_a_camera.theta() + obs_b.bearing - theta_a)
    return edge_from_observation(d_a, theta_a, theta_delta, obs_b.range_m, obs_b.theta, form)


def solve_closed_form(
    frames: Frames, T_base_camera: gtsam.Pose2, form: Form = Form.SIGNED
) -> Estimate:
    """The paper's procedure in one of its forms; see the module docstring."""
    start = time.perf_counter()
    home = frames.home_id
    edges_from_home: dict[int, Edge | None] = {home: None}  # None: home itself
    T_map_marker: dict[int, gtsam.Pose2] = {home: gtsam.Pose2()}
    links: list[MarkerLink] = []
    localised: tuple[int, gtsam.Pose2, gtsam.Pose2] | None = None  # (a, T_a_base, T_odom_base)
    trajectory_t_ns, trajectory = [], []
    for k, frame in enumerate(frames.frames):
        if k < frames.home_frame:
            continue
        usable = [o for o in frame.observations if o.sigma_theta <= MAX_SIGMA_THETA_RAD]
        placed = [o for o in usable if o.marker_id in T_map_marker]
        if placed:  # localise on the nearest placed marker
            nearest = min(placed, key=lambda o: o.range_m)
            T_base_a, _ = observation_measurement(nearest, T_base_camera)
            localised = (nearest.marker_id, T_base_a.inverse(), frame.T_odom_base)
        if localised is None:
            continue
        a, T_a_base_then, T_odom_base_then = localised
        T_a_base = T_a_base_then.compose(T_odom_base_then.between(frame.T_odom_base))
        for obs in usable:
            b = obs.marker_id
            if b in T_map_marker:
                continue
            e_ab = _edge_to_new_marker(T_a_base, obs, T_base_camera, form)
            e_home_a = edges_from_home[a]
            e_home_b = e_ab if e_home_a is None else compose(e_home_a, e_ab, form)
            edges_from_home[b] = e_home_b
            T_map_marker[b] = edge_to_pose2(e_home_b)
            links.append(MarkerLink(min(a, b), max(a, b), 1))
        T_map_base = T_map_marker[a].compose(T_a_base)
        trajectory_t_ns.append(frame.t_ns)
        trajectory.append([T_map_base.x(), T_map_base.y(), T_map_base.theta()])
    counts = Counter(o.marker_id for f in frames.frames for o in f.observations)
    unplaced = {
        i: "never seen while the robot was localised on a placed marker"
        for i in frames.marker_ids()
        if i not in T_map_marker
    }
    return Estimate(
        method=Method.CLOSED_FORM,
        home_id=home,
        markers={i: MarkerEstimate(i, T, None, counts[i]) for i, T in T_map_marker.items()},
        trajectory=Trajectory(np.array(trajectory_t_ns, dtype=np.int64), np.array(trajectory)),
        links=links,
        unplaced=unplaced,
        notes=list(frames.notes),
        timings_s={"solve": time.perf_counter() - start},
    )
