"""Random convex rooms with markers on their walls, and the exact measurements a robot makes there.

Used to test and chart the paper's closed forms: every quantity here is computed from exact poses,
so it is the ground truth the closed forms are checked against.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.estimator.angles import wrap

__all__ = [
    "ConvexRoom",
    "MarkerObservation",
    "observe_marker",
    "random_convex_room",
    "turn_toward",
]


@dataclass(frozen=True)
class ConvexRoom:
    """A convex floor plan with markers hung on its walls, facing into the room.

    Attributes:
        corners_xy: (N, 2) wall corners [m], counter-clockwise; wall i runs from corner i to i+1.
        T_room_markers: one ``gtsam.Pose2`` per marker: its frame in the room frame, +x along the
            wall's inward normal.
        marker_walls: index of the wall each marker hangs on.
    """

    corners_xy: NDArray[np.float64]
    T_room_markers: tuple[gtsam.Pose2, ...]
    marker_walls: tuple[int, ...]

    def contains(self, p_xy: NDArray[np.float64], margin_m: float = 0.0) -> bool:
        """Whether a point lies inside the room, at least ``margin_m`` from every wall."""
        starts = self.corners_xy
        ends = np.roll(self.corners_xy, -1, axis=0)
        edge = ends - starts
        # For a counter-clockwise polygon the interior is left of every wall.
        cross = edge[:, 0] * (p_xy[1] - starts[:, 1]) - edge[:, 1] * (p_xy[0] - starts[:, 0])
        return bool(np.all(cross / np.linalg.norm(edge, axis=1) >= margin_m))

    def random_point(self, rng: np.random.Generator, margin_m: float = 0.3) -> NDArray[np.float64]:
        """A uniformly drawn point inside the room, ``margin_m`` clear of the walls."""
        low, high = self.corners_xy.min(axis=0), self.corners_xy.max(axis=0)
        for _ in range(10_000):
            p_xy = rng.uniform(low, high)
            if self.contains(p_xy, margin_m):
                return p_xy
        raise ValueError(f"no point found {margin_m} m inside the room; use a smaller margin")


def random_convex_room(
    rng: np.random.Generator,
    n_walls: int = 5,
    n_markers: int = 3,
    size_m: tuple[float, float] = (3.0, 8.0),
) -> ConvexRoom:
    """A random convex room: corners on an ellipse at sorted random angles, markers on walls.

    Points taken in angular order on an ellipse always form a convex polygon. Markers sit on a
    wall drawn with probability proportional to its length, between 10% and 90% along it.

    Args:
        rng: the random generator (seed it for repeatable rooms).
        n_walls: number of walls, >= 3.
        n_markers: number of markers, >= 1.
        size_m: range the ellipse's two diameters are drawn from [m].
    """
    if n_walls < 3 or n_markers < 1:
        raise ValueError(f"need n_walls >= 3 and n_markers >= 1, got {n_walls}, {n_markers}")
    # Gaps of at least a third of the even spacing keep walls from degenerating to slivers.
    gaps = rng.uniform(1.0 / 3.0, 1.0, n_walls)
    angles = np.cumsum(gaps / gaps.sum() * 2.0 * np.pi) + rng.uniform(0.0, 2.0 * np.pi)
    half_axes = rng.uniform(*size_m, 2) / 2.0
    corners_xy = np.column_stack(
        [half_axes[0] * np.cos(angles), half_axes[1] * np.sin(angles)]
    ).astype(np.float64)
    lengths = np.linalg.norm(np.roll(corners_xy, -1, axis=0) - corners_xy, axis=1)
    walls = rng.choice(n_walls, size=n_markers, p=lengths / lengths.sum())
    poses = []
    for wall in walls:
        start, end = corners_xy[wall], corners_xy[(wall + 1) % n_walls]
        centre = start + rng.uniform(0.1, 0.9) * (end - start)
        along = end - start
        inward_yaw = math.atan2(along[1], along[0]) + math.pi / 2.0  # left of a CCW wall
        poses.append(gtsam.Pose2(centre[0], centre[1], wrap(inward_yaw)))
    return ConvexRoom(corners_xy, tuple(poses), tuple(int(w) for w in walls))


@dataclass(frozen=True, slots=True)
class MarkerObservation:
    """A centred observation ``(d, theta)`` of a marker: the robot at ``d (cos theta, sin theta)``
    in the marker's frame [m, rad]."""

    d: float
    theta: float


def observe_marker(
    T_room_marker: gtsam.Pose2, p_room_robot: NDArray[np.float64]
) -> MarkerObservation:
    """The exact centred observation of a marker from a robot position in the room."""
    p_marker_robot = T_room_marker.transformTo(np.asarray(p_room_robot, dtype=np.float64))
    return MarkerObservation(
        d=float(np.hypot(p_marker_robot[0], p_marker_robot[1])),
        theta=math.atan2(p_marker_robot[1], p_marker_robot[0]),
    )


def turn_toward(
    heading_rad: float, p_room_robot: NDArray[np.float64], p_room_target: NDArray[np.float64]
) -> float:
    """The counter-clockwise turn from a heading to face a target point [rad]."""
    delta = np.asarray(p_room_target) - np.asarray(p_room_robot)
    return wrap(math.atan2(delta[1], delta[0]) - heading_rad)
