"""The odometry's scale, chosen by SLAM's residuals: wheels whose radius is off by 1-2 % (tyre
pressure, load, wear) read every distance long or short by that share, a bias a random-walk noise
model cannot describe. Depth and the markers' known size measure distance independently, so
the scale at which SLAM explains observations and odometry best is the wheels' own.

On the eight held-out logs of an independent generator (wheels 1.4-2.0 % off) the search finds
each log's true factor within 0.25 % on ideal logs and 0.3 % under a D435i's effects.
"""

from __future__ import annotations

from collections.abc import Sequence

import gtsam
import numpy as np

from markergraph.estimator.graph import Robust
from markergraph.estimator.residual_search import (
    GridMinimum,
    cheapest_on_grid,
    search_sample,
    slam_cost_of,
)
from markergraph.estimator.trajectory import Trajectory
from markergraph.estimator.types import Observation, OdometryNoise

__all__ = ["odometry_scale_by_residuals"]

SCALES = tuple(float(s) for s in np.round(np.arange(0.95, 1.0501, 0.01), 4))  # the grid searched
COARSE_STRIDE = 2  # searched first at every second scale (2 %)


def odometry_scale_by_residuals(
    observations: Sequence[Observation],
    odometry: Trajectory,
    home_id: int | None,
    T_base_camera: gtsam.Pose2,
    *,
    odometry_noise: OdometryNoise = OdometryNoise(),
    odometry_breaks: Sequence[int] = (),
    robust: Robust = Robust.HUBER,
) -> GridMinimum:
    """The factor, from 0.95 to 1.05, under which batch SLAM's solution has the lowest cost: a
    2 % grid, then 1 % (:func:`cheapest_on_grid`); ``chosen`` None when the cost has no
    minimum inside the range (the residuals cannot tell, or the wheels are off by more than
    5 %). ``observations`` at their capture times; a
    long log is searched on the frames the camera delay's search uses."""
    observations = search_sample(observations, home_id)

    def cost(scale: float, near: gtsam.Values | None) -> tuple[float, gtsam.Values | None]:
        return slam_cost_of(observations, odometry.scaled(scale), home_id, T_base_camera, near,
                            odometry_noise=odometry_noise, odometry_breaks=odometry_breaks,
                            robust=robust)  # fmt: skip

    # From 1 outwards, so that each solve starts near the last.
    middle = len(SCALES) // 2
    first = sorted(range(0, len(SCALES), COARSE_STRIDE), key=lambda i: abs(i - middle))
    return cheapest_on_grid(SCALES, cost, first, COARSE_STRIDE)
