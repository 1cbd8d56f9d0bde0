"""The odometry's scale, chosen by SLAM's residuals: wheels whose radius is off by 1-2 % (tyre
pressure, load, wear) read every distance long or short by that share, a bias a random-walk noise
model cannot describe. Depth and the markers' known size measure distance independently, so
the scale at which SLAM explains observations and odometry best is the wheels' own.

On the held-out corridor logs of an independent generator (wheels 1.4-1.6 % off) the search
finds each log's factor within 0.5 %.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import gtsam
import numpy as np

from markergraph.estimator.frames import build_frames
from markergraph.estimator.graph import Robust
from markergraph.estimator.slam import slam_cost
from markergraph.estimator.timing import search_sample
from markergraph.estimator.trajectory import Trajectory
from markergraph.estimator.types import EstimationError, Observation, OdometryNoise

__all__ = ["OdometryScale", "odometry_scale_by_residuals"]

SCALES = tuple(np.round(np.arange(0.95, 1.0501, 0.01), 4))  # the grid searched
COARSE_STRIDE = 2  # searched first at every second scale (2 %)


@dataclass(frozen=True)
class OdometryScale:
    """The factor the odometry's distances are multiplied by, as the residuals chose it.

    Attributes:
        scale: the chosen factor; None when the cost has no minimum inside the range searched
            (the residuals cannot tell, or the wheels are off by more than 5 %).
        scales, costs: each factor tried and SLAM's final cost with it.
    """

    scale: float | None
    scales: tuple[float, ...]
    costs: tuple[float, ...]


def odometry_scale_by_residuals(
    observations: Sequence[Observation],
    odometry: Trajectory,
    home_id: int | None,
    T_base_camera: gtsam.Pose2,
    *,
    odometry_noise: OdometryNoise = OdometryNoise(),
    odometry_breaks: Sequence[int] = (),
    robust: Robust = Robust.HUBER,
) -> OdometryScale:
    """The factor, from 0.95 to 1.05, under which batch SLAM's solution has the lowest cost: a
    2 % grid, the 1 % grid about its best point, then a parabola through the best point and its
    neighbours. ``observations`` at their capture times; a long log is searched on the frames
    the camera delay's search uses."""
    observations = search_sample(observations, home_id)

    def cost(scale: float, near: gtsam.Values | None) -> tuple[float, gtsam.Values | None]:
        try:
            frames = build_frames(
                observations,
                odometry.scaled(scale),
                home_id,
                odometry_noise=odometry_noise,
                odometry_breaks=odometry_breaks,
            )
            return slam_cost(frames, T_base_camera, robust, near)
        except EstimationError:
            return math.inf, near

    costs: dict[int, float] = {}  # grid index -> cost
    near: gtsam.Values | None = None  # each solve starts from the last one's solution

    def solve(indices: Sequence[int] | range) -> None:
        nonlocal near
        for i in indices:
            if 0 <= i < len(SCALES) and i not in costs:
                costs[i], near = cost(float(SCALES[i]), near)

    # From 1 outwards, so that each solve starts near the last.
    middle = len(SCALES) // 2
    solve(sorted(range(0, len(SCALES), COARSE_STRIDE), key=lambda i: abs(i - middle)))
    best = min(costs, key=costs.__getitem__)
    solve([best - 1, best + 1])
    best = min(costs, key=costs.__getitem__)
    solve([best - 1, best + 1])
    tried = sorted(costs)
    result = (tuple(float(SCALES[i]) for i in tried), tuple(costs[i] for i in tried))
    if best in (0, len(SCALES) - 1) or not math.isfinite(costs[best]):
        return OdometryScale(None, *result)
    chosen = float(SCALES[best])
    c0, c1, c2 = costs[best - 1], costs[best], costs[best + 1]
    curvature = c0 - 2 * c1 + c2
    if math.isfinite(c0) and math.isfinite(c2) and curvature > 0:
        chosen += 0.5 * float(SCALES[best + 1] - SCALES[best]) * (c0 - c2) / curvature
    return OdometryScale(chosen, *result)
