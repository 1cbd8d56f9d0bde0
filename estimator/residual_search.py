"""A setting chosen by SLAM's residuals: the value on a grid under which batch SLAM's solution
costs least, as the camera's delay (:mod:`markergraph.estimator.timing`) and the odometry's
scale (:mod:`markergraph.estimator.odometry_scale`) are chosen."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import gtsam

from markergraph.common.errors import EstimationError
from markergraph.estimator.frames import build_frames
from markergraph.estimator.graph import FactorMemo, Robust
from markergraph.estimator.slam import slam_cost
from markergraph.estimator.trajectory import Trajectory
from markergraph.estimator.types import Observation, OdometryNoise

__all__ = ["SEARCH_FRAMES", "GridMinimum", "SlamInputs", "cheapest_on_grid", "search_sample"]

SEARCH_FRAMES = 600  # enough frames to place the cost's minimum; more only cost time

# A cost of one grid value, given the solution of the value solved before it (None at first),
# and that value's own solution.
Cost = Callable[[float, gtsam.Values | None], tuple[float, gtsam.Values | None]]


@dataclass(frozen=True)
class GridMinimum:
    """The grid value under which SLAM costs least (:func:`cheapest_on_grid`).

    Attributes:
        chosen: that value, refined by a parabola; None when the least cost is at either end
            of the grid or infinite (the residuals cannot tell).
        tried, costs: each value tried and SLAM's final cost with it.
        solution: SLAM's solution at the grid value of least cost (None where it had none):
            a start for a search of another setting on the same frames.
        sigma: the chosen value's standard deviation, from the parabola's curvature: the cost
            is half the whitened residuals' squared sum, so its second derivative is the
            value's information (Laplace); None where ``chosen`` is. On a long log it is the
            searched sample's, not shrunk to the whole log's: neighbouring frames' errors
            correlate, and the wheels' systematic errors do not average out over more frames.
    """

    chosen: float | None
    tried: tuple[float, ...]
    costs: tuple[float, ...]
    solution: gtsam.Values | None = None
    sigma: float | None = None


def search_sample(observations: Sequence[Observation], home_id: int | None) -> list[Observation]:
    """The observations of at most about :data:`SEARCH_FRAMES` frames, evenly spread, plus
    every frame that sees ``home_id``."""
    stamps = sorted({o.t_ns for o in observations})
    if len(stamps) <= SEARCH_FRAMES:
        return list(observations)
    kept = set(stamps[:: math.ceil(len(stamps) / SEARCH_FRAMES)])
    kept |= {o.t_ns for o in observations if o.marker_id == home_id}
    return [o for o in observations if o.t_ns in kept]


@dataclass(frozen=True)
class SlamInputs:
    """One log's batch SLAM problem, whose cost a search varies one setting of.

    Attributes:
        observations: at their capture times (for the camera delay's search: as stamped).
        odometry, home_id, T_base_camera, odometry_noise, odometry_breaks, robust: as
            :func:`~markergraph.estimator.frames.build_frames` and
            :func:`~markergraph.estimator.slam.slam_cost` take them.
    """

    observations: Sequence[Observation]
    odometry: Trajectory
    home_id: int | None
    T_base_camera: gtsam.Pose2
    odometry_noise: OdometryNoise = OdometryNoise()
    odometry_breaks: Sequence[int] = ()
    robust: Robust = Robust.HUBER

    def sampled(self) -> SlamInputs:
        """The same problem on :func:`search_sample`'s frames."""
        return replace(self, observations=search_sample(self.observations, self.home_id))

    def cost(
        self, near: gtsam.Values | None, memo: FactorMemo | None = None
    ) -> tuple[float, gtsam.Values | None]:
        """Batch SLAM's final cost, and its solution (started from ``near``; ``memo``: the
        search's observation factors, :class:`~markergraph.estimator.graph.GraphBuilder`);
        infinite where GTSAM cannot solve the graph."""
        try:
            frames = build_frames(self.observations, self.odometry, self.home_id,
                                  odometry_noise=self.odometry_noise,
                                  odometry_breaks=self.odometry_breaks)  # fmt: skip
            return slam_cost(frames, self.T_base_camera, self.robust, near, memo)
        except EstimationError:
            return math.inf, near


def cheapest_on_grid(
    grid: Sequence[float],
    cost: Cost,
    coarse: Sequence[int],
    start: int,
    near: gtsam.Values | None = None,
) -> GridMinimum:
    """The grid value of least cost, found by walking downhill: from ``start`` (one of the
    increasing indices ``coarse``) to a coarse neighbour that costs less (the one above first,
    the one below only where that one costs more), on along the coarse indices while the grid
    value back costs more and the one on less, then on the whole grid until both neighbours
    cost more; a parabola through that point and its neighbours.

    On a cost with one minimum over the grid (SLAM's cost over a delay or a scale is smooth and
    bowl-shaped) this is the grid value that solving every one would choose, with the same
    neighbours, at a third to a half of the solves; the values far off, whose solves need the most
    iterations, are never solved. Each solve starts from the solution of the nearest grid value
    solved before it (the first from ``near``, else from scratch): fewer iterations than from
    the last one solved, which may lie across the grid."""
    costs: dict[int, float] = {}  # grid index -> cost
    solutions: dict[int, gtsam.Values | None] = {}

    def solve(i: int) -> float:
        if i not in costs:
            nearest = min(solutions, key=lambda j: abs(j - i), default=None)
            begin = near if nearest is None else solutions[nearest]
            costs[i], solutions[i] = cost(grid[i], begin)
        return costs[i]

    best, step = coarse.index(start), 0
    solve(start)
    # Past a single minimum one falling side tells the way: the other is solved only where
    # the first rises.
    for side in (1, -1):
        if 0 <= best + side < len(coarse) and solve(coarse[best + side]) < costs[start]:
            best, step = best + side, side
            break
    # On along the coarse values while the costs fall: first a value back (lower, it brackets
    # the minimum behind), then one onward (higher, it brackets it here), then the next coarse
    # one; a value onward costs less to solve than the next coarse one and tells as much.
    while step:
        at = coarse[best]
        if solve(at - step) < costs[at]:
            break
        if not 0 <= at + step < len(grid) or solve(at + step) >= costs[at]:
            break
        if not 0 <= best + step < len(coarse) or solve(coarse[best + step]) >= costs[at + step]:
            break
        best += step
    return _refined(grid, solve, costs, solutions, min(costs, key=costs.__getitem__))


def _refined(
    grid: Sequence[float],
    solve: Callable[[int], float],
    costs: dict[int, float],
    solutions: dict[int, gtsam.Values | None],
    best: int,
) -> GridMinimum:
    """From grid index ``best``, downhill on the whole grid until both neighbours cost more;
    that value refined by a parabola through it and its neighbours (None at either end of the
    grid or at an infinite cost). A neighbour already solved is looked at first, then the one
    nearer another solved value (the side the minimum is bracketed on); the first that costs
    less is the way, and the other is not solved."""

    def nearest_other(i: int) -> tuple[float, float]:
        """How far the nearest other solved value lies, and its cost (the lower, the likelier
        the minimum lies that way)."""
        return min(((abs(i - j), costs[j]) for j in costs if j != best), default=(math.inf, 0.0))

    while True:
        around = [i for i in (best - 1, best + 1) if 0 <= i < len(grid)]
        around.sort(key=lambda i: (i not in costs, *nearest_other(i)))
        lower = next((i for i in around if solve(i) < costs[best]), None)  # a tie stays put
        if lower is None:
            break
        best = lower
    tried = sorted(costs)
    values, tried_costs = tuple(grid[i] for i in tried), tuple(costs[i] for i in tried)
    if best in (0, len(grid) - 1) or not math.isfinite(costs[best]):
        return GridMinimum(None, values, tried_costs, solutions[best])
    chosen, sigma = grid[best], None
    c0, c1, c2 = costs[best - 1], costs[best], costs[best + 1]
    curvature = c0 - 2 * c1 + c2  # the cost's second derivative times the grid's step squared
    if math.isfinite(c0) and math.isfinite(c2) and curvature > 0:
        step = grid[best + 1] - grid[best]
        chosen += 0.5 * step * (c0 - c2) / curvature
        sigma = step / math.sqrt(curvature)
    return GridMinimum(chosen, values, tried_costs, solutions[best], sigma)
