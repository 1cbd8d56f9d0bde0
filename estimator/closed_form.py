"""``Method.CLOSED_FORM``: the paper's own mapping procedure, with no optimisation.

The robot localises on the home marker, dead-reckons with odometry for as long as it takes, and
re-localises on every placed marker it sees again. A marker seen for the first time is linked to
the marker it was last localised on by ``E_ab`` (:func:`paper.edge_from_observation`) and placed
by composing ``M`` from home (:func:`paper.compose`): a spanning tree, each marker placed once,
no loop closure.

The log need not start at the home marker: after the pass forward from the first localisation,
a second pass runs back in time from it, dead-reckoning backwards, so markers seen only before
the robot first saw home are placed too. Each placement records the marker it came from and how
far and how long the robot dead-reckoned to it (:class:`Placement`): the drift it cost.
"""

from __future__ import annotations

import itertools
import math
import time
from collections import Counter
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.common.notes import Note
from markergraph.estimator.angles import wrap
from markergraph.estimator.estimate import Estimate
from markergraph.estimator.frames import Frame, Frames
from markergraph.estimator.graph import observation_measurement
from markergraph.estimator.paper import (
    Edge,
    Form,
    compose,
    edge_from_observation,
    edge_to_pose2,
)
from markergraph.estimator.trajectory import Trajectory
from markergraph.estimator.types import (
    MarkerEstimate,
    MarkerLink,
    Method,
    Observation,
    Placement,
)

__all__ = ["MAX_SIGMA_THETA_RAD", "solve_closed_form"]

# The paper measures theta only on a marker it has turned to face; a view whose theta is this
# uncertain (a grazing view, where the square's two poses look alike) is not used while the
# marker has better ones. A marker with no view this good (small, far, or seen through a fisheye
# whose PnP is ambiguous) is used through its best views instead of never: its gate is its own
# smallest sigma (:func:`_theta_gates`).
MAX_SIGMA_THETA_RAD = math.radians(10.0)


def _theta_gates(frames: Frames) -> dict[int, float]:
    """Per marker, the largest theta sigma of a view the procedure uses: the usual gate, or the
    marker's own best sigma where it has nothing better."""
    best: dict[int, float] = {}
    for frame in frames.frames:
        for o in frame.observations:
            best[o.marker_id] = min(best.get(o.marker_id, math.inf), o.sigma_theta)
    return {i: max(MAX_SIGMA_THETA_RAD, sigma) for i, sigma in best.items()}


def _path_lengths(frames: list[Frame]) -> NDArray[np.float64]:
    """Odometry path length from the first frame to each [m]."""
    steps = [
        math.hypot(*a.T_odom_base.between(b.T_odom_base).translation())
        for a, b in itertools.pairwise(frames)
    ]
    return np.concatenate([[0.0], np.cumsum(steps)])


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


@dataclass(frozen=True)
class _Fix:
    """The last localisation: on marker ``a`` at frame ``k``, ``T_a_base`` then."""

    a: int
    k: int
    T_a_base: gtsam.Pose2


class _Procedure:
    """The paper's walk over the frames, in either direction, sharing one map."""

    def __init__(self, frames: Frames, T_base_camera: gtsam.Pose2, form: Form) -> None:
        self.frames, self.T_base_camera, self.form = frames.frames, T_base_camera, form
        self.home = frames.home_id
        self.gates = _theta_gates(frames)
        self.travelled_m = _path_lengths(self.frames)
        self.edges_from_home: dict[int, Edge | None] = {self.home: None}  # None: home itself
        self.T_map_marker: dict[int, gtsam.Pose2] = {self.home: gtsam.Pose2()}
        self.links: list[MarkerLink] = []
        self.placements: dict[int, Placement] = {}
        self.poses: dict[int, gtsam.Pose2] = {}  # frame index -> T_map_base

    def usable(self, frame: Frame) -> list[Observation]:
        return [o for o in frame.observations if o.sigma_theta <= self.gates[o.marker_id]]

    def localise(self, k: int) -> _Fix | None:
        """A fix on the nearest placed marker usable in frame k, if any."""
        placed = [o for o in self.usable(self.frames[k]) if o.marker_id in self.T_map_marker]
        if not placed:
            return None
        nearest = min(placed, key=lambda o: o.range_m)
        T_base_a, _ = observation_measurement(nearest, self.T_base_camera)
        if not self.placements:  # the home marker, placed by the first fix
            frame = self.frames[k]
            self.placements[self.home] = Placement(
                self.home, self.home, 0.0, 0.0, frame.t_ns, nearest.sigma_theta
            )
        return _Fix(nearest.marker_id, k, T_base_a.inverse())

    def walk(self, order: range, fix: _Fix) -> None:
        """Dead-reckon from ``fix`` through the frames in ``order``, re-localising and placing."""
        backward = order.step < 0
        for k in order:
            fix = self.localise(k) or fix
            frame, then = self.frames[k], self.frames[fix.k]
            T_a_base = fix.T_a_base.compose(then.T_odom_base.between(frame.T_odom_base))
            for obs in self.usable(frame):
                if obs.marker_id not in self.T_map_marker:
                    self.place(obs, fix, k, T_a_base, backward)
            self.poses[k] = self.T_map_marker[fix.a].compose(T_a_base)

    def place(self, obs: Observation, fix: _Fix, k: int, T_a_base: gtsam.Pose2, back: bool) -> None:
        a, b = fix.a, obs.marker_id
        e_ab = _edge_to_new_marker(T_a_base, obs, self.T_base_camera, self.form)
        e_home_a = self.edges_from_home[a]
        e_home_b = e_ab if e_home_a is None else compose(e_home_a, e_ab, self.form)
        self.edges_from_home[b] = e_home_b
        self.T_map_marker[b] = edge_to_pose2(e_home_b)
        self.links.append(MarkerLink(min(a, b), max(a, b), 1))
        self.placements[b] = Placement(
            b,
            a,
            float(abs(self.travelled_m[k] - self.travelled_m[fix.k])),
            abs(self.frames[k].t_ns - self.frames[fix.k].t_ns) * 1e-9,
            self.frames[k].t_ns,
            obs.sigma_theta,
            back,
        )


def solve_closed_form(
    frames: Frames, T_base_camera: gtsam.Pose2, form: Form = Form.SIGNED
) -> Estimate:
    """The paper's procedure in one of its forms; see the module docstring."""
    start = time.perf_counter()
    procedure = _Procedure(frames, T_base_camera, form)
    n = len(frames.frames)
    first = next((fix for k in range(frames.home_frame, n) if (fix := procedure.localise(k))), None)
    if first is not None:
        procedure.walk(range(first.k, n), first)
        procedure.walk(range(first.k - 1, -1, -1), first)
    placed = procedure.T_map_marker
    counts = Counter(o.marker_id for f in frames.frames for o in f.observations)
    unplaced = {
        i: "never seen while the robot's pose was known from a placed marker"
        for i in frames.marker_ids()
        if i not in placed
    }
    notes = list(frames.notes)
    for p in procedure.placements.values():
        if p.sigma_theta_rad > MAX_SIGMA_THETA_RAD:
            notes.append(Note(
                "closed_form.uncertain_theta",
                f"closed form: marker {p.marker_id} placed from a view whose theta is uncertain "
                f"by {math.degrees(p.sigma_theta_rad):.0f} deg (it had no better one)",
                figure=math.degrees(p.sigma_theta_rad),
            ))  # fmt: skip
    stamps = sorted(procedure.poses)
    poses = [procedure.poses[k] for k in stamps]
    trajectory = np.array([[T.x(), T.y(), T.theta()] for T in poses])
    return Estimate(
        method=Method.CLOSED_FORM,
        home_id=frames.home_id,
        markers={i: MarkerEstimate(i, T, None, counts[i]) for i, T in placed.items()},
        trajectory=Trajectory(
            np.array([frames.frames[k].t_ns for k in stamps], dtype=np.int64),
            trajectory.reshape(-1, 3),
        ),
        links=procedure.links,
        unplaced=unplaced,
        placements=dict(sorted(procedure.placements.items())),
        notes=notes,
        timings_s={"solve": time.perf_counter() - start},
    )
