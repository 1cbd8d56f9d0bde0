"""When each observation was really made: a camera whose stamps trail its captures (USB
transport), a rolling shutter that reads each row later than the one above, an exposure that
smears a turn.

- :func:`retimed`: observations moved to their capture time, the shutter's row delay included;
- :func:`widened_for_motion`: sigmas widened by what the turn swept during a time window (the
  alternative to modelling the shutter, and the remedy for blur);
- :func:`unleaned`: theta freed of the lean a rolling shutter gives a marker in a turn, or
  widened to cover it where the readout is not known;
- :func:`camera_delay_by_residuals`: the stamps' delay against odometry, chosen as the one whose
  SLAM solution explains the observations and odometry best.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import gtsam
import numpy as np

from markergraph.estimator.graph import FactorMemo
from markergraph.estimator.residual_search import SlamInputs, cheapest_on_grid
from markergraph.estimator.trajectory import Trajectory, turn_rate
from markergraph.estimator.types import LEANING, Observation

__all__ = [
    "READOUT_MAX_S",
    "CameraDelay",
    "camera_delay_by_residuals",
    "retimed",
    "unleaned",
    "widened_for_motion",
]

DELAYS_S = tuple(np.arange(-0.05, 0.1001, 0.01))  # the grid searched first [s]
COARSE_STRIDE = 3  # the grid is first searched at every third delay (30 ms)


def retimed(
    observations: Sequence[Observation], delay_ns: int, readout_ns: int = 0, image_height: int = 0
) -> list[Observation]:
    """Observations moved to when the marker was imaged: ``delay_ns`` before the stamp, plus
    the rolling shutter's delay to the row of the marker's centre (the stamp being the top
    row's) when ``readout_ns`` and ``image_height`` are given."""
    moved = []
    for o in observations:
        row_ns = 0
        if readout_ns and image_height and o.corners:
            row = sum(v for _, v in o.corners) / len(o.corners)
            row_ns = round(readout_ns * min(max(row / image_height, 0.0), 1.0))
        moved.append(replace(o, t_ns=o.t_ns - delay_ns + row_ns))
    return moved


def widened_for_motion(
    observations: Sequence[Observation], odometry: Trajectory, window_s: float
) -> list[Observation]:
    """Bearing and theta sigmas widened by the angle the robot turned during ``window_s`` (an
    exposure's smear, or a rolling shutter's skew left unmodelled): a uniform spread of that
    width adds its variance, ``width^2 / 12``."""
    widened = []
    for o in observations:
        swept = abs(turn_rate(odometry, o.t_ns)) * window_s
        extra = swept**2 / 12.0
        widened.append(
            replace(
                o,
                sigma_bearing=math.sqrt(o.sigma_bearing**2 + extra),
                sigma_theta=math.sqrt(o.sigma_theta**2 + extra),
            )
        )
    return widened


READOUT_MAX_S = 1.0 / 30.0
"""The longest a rolling shutter of a camera at 30 frames a second takes to read its rows out [s]:
what theta is widened to cover where the readout is not known."""


def unleaned(
    observations: Sequence[Observation],
    odometry: Trajectory,
    readout_s: float,
    *,
    known: bool = True,
) -> list[Observation]:
    """Theta without the lean a rolling shutter gives a marker while the camera turns: the turn
    during the readout, ``omega * readout_s`` (the odometry's heading rate at each capture
    time), times the observation's ``theta_per_turn``, taken off. Where the readout is not
    ``known``, ``readout_s`` its bound, theta stays and its sigma grows to cover a lean anywhere
    within that (a spread of +-b adds ``b^2 / 3``) and the observation is flagged
    :data:`LEANING`. ``theta_per_turn`` is 0 afterwards, as it is counted."""
    handled = []
    for o in observations:
        lean = o.theta_per_turn * turn_rate(odometry, o.t_ns) * readout_s
        if known:
            o = replace(o, theta=math.remainder(o.theta - lean, math.tau), theta_per_turn=0.0)
        else:
            sigma = math.sqrt(o.sigma_theta**2 + lean * lean / 3.0)
            flags = (o.flags | {LEANING}) if lean else o.flags
            o = replace(o, sigma_theta=sigma, theta_per_turn=0.0, flags=flags)
        handled.append(o)
    return handled


@dataclass(frozen=True)
class CameraDelay:
    """The camera stamps' delay against odometry, as the residuals chose it.

    Attributes:
        delay_ns: the chosen delay: the stamp minus the capture [ns]; None when the cost has
            no minimum inside the range searched (the residuals cannot tell).
        delays_ns, costs: each delay tried and SLAM's final cost with it.
        solution: SLAM's solution at the delay tried of least cost, for the odometry scale's
            search to start from.
        sigma_ns: the chosen delay's standard deviation, from the cost's curvature (see
            :class:`~markergraph.estimator.residual_search.GridMinimum`) [ns]; None where
            ``delay_ns`` is.
    """

    delay_ns: int | None
    delays_ns: tuple[int, ...]
    costs: tuple[float, ...]
    solution: gtsam.Values | None = None
    sigma_ns: float | None = None


def camera_delay_by_residuals(
    inputs: SlamInputs, *, readout_ns: int = 0, image_height: int = 0
) -> CameraDelay:
    """The delay, from -50 to +100 ms, under which batch SLAM's solution has the lowest cost:
    downhill on a 30 ms grid, then on the 10 ms grid, then a parabola through the best point
    and its neighbours (:func:`cheapest_on_grid`); None (in ``delay_ns``) when the lowest cost
    is at either end of the range. A long log is searched on :data:`SEARCH_FRAMES` of its
    frames, evenly spread (and every frame that sees the home marker): sixteen full solves of a
    10-minute log cost 23 s; ten cost-only solves, each from the last one's solution, 3-4 s.
    """
    sampled = inputs.sampled()
    memo: FactorMemo = {}  # a delay moves the frames' stamps, not what they measured

    def cost(delay_ns: float, near: gtsam.Values | None) -> tuple[float, gtsam.Values | None]:
        moved = retimed(sampled.observations, round(delay_ns), readout_ns, image_height)
        return replace(sampled, observations=moved).cost(near, memo)

    delays = [round(d * 1e9) for d in DELAYS_S]
    # Every third delay of the grid first: the cost is smooth over tens of milliseconds. From
    # the one nearest no delay: each solve starts from its neighbour's solution.
    coarse = sorted({*range(0, len(delays), COARSE_STRIDE), len(delays) - 1})
    start = min(coarse, key=lambda i: abs(delays[i]))
    found = cheapest_on_grid(delays, cost, coarse, start)
    chosen = None if found.chosen is None else round(found.chosen)
    return CameraDelay(
        chosen, tuple(map(int, found.tried)), found.costs, found.solution, found.sigma
    )
