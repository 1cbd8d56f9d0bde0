"""Localisation against a saved map that finds moved and new markers.

Localisation is the same graph with the saved map's markers entering as priors at their
covariances (so the map's own uncertainty reaches the robot's poses) and solved in one batch:
offline the whole log is in hand, and the smoothed solution is what iSAM2 would hold after the
last frame, with every pose's marginal covariance. A marker that was moved since the map was
made shows as observations that disagree with its prior; it is found by its residuals, freed
from its prior and placed anew, so it cannot pull the trajectory.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.common.errors import EstimationError
from markergraph.estimator.frames import Frames
from markergraph.estimator.graph import Robust
from markergraph.estimator.sessions import MapPrior, SessionsEstimate, solve_sessions
from markergraph.estimator.trajectory import Trajectory
from markergraph.estimator.types import FactorResidual, MarkerEstimate

__all__ = ["Localization", "MovedMarker", "MovedSearch", "localize", "moved_markers"]

# A map marker is a suspect when its prior's whitened error (how hard the observations pull it)
# or the median of its observations' (how hard the prior holds them off) exceeds this; honest
# data give about 1.5 (3 degrees of freedom). A suspect is moved when the map's pose and the
# pose this log alone gives it differ beyond chi-square's 99.9 % point for 3 dof.
SUSPECT_WHITENED = 3.0
MOVED_CHI2 = 16.27
MIN_OBSERVATIONS_TO_MOVE = 3


@dataclass(frozen=True)
class MovedMarker:
    """A saved map's marker that is no longer where the map puts it.

    Attributes:
        marker_id: its id.
        T_map_before: where the map has it.
        T_map_now: where this log's observations put it.
        displacement_m: how far its centre moved [m].
        prior_whitened: how many sigmas the log's observations pulled the map's pose.
        covariance_now: (3, 3) ``T_map_now``'s covariance (its own tangent), or None.
    """

    marker_id: int
    T_map_before: gtsam.Pose2
    T_map_now: gtsam.Pose2
    displacement_m: float
    prior_whitened: float
    covariance_now: NDArray[np.float64] | None = None


@dataclass
class Localization:
    """A log's robot trajectory in a saved map's frame.

    Attributes:
        trajectory: the robot's poses in the map frame.
        pose_covariances: (N, 3, 3) their marginal covariances.
        moved: the map's markers that were moved, left out of the localisation.
        new: markers the map does not know, placed by this log.
        checked: for each map marker, how many sigmas this log pulled it from the map.
        estimate: the final solution (residuals, graph, markers).
    """

    trajectory: Trajectory
    pose_covariances: NDArray[np.float64]
    moved: list[MovedMarker]
    new: dict[int, MarkerEstimate]
    checked: dict[int, float]
    estimate: SessionsEstimate


def _median_whitened(residuals: Sequence[FactorResidual]) -> dict[int, tuple[float, int]]:
    errors: defaultdict[int, list[float]] = defaultdict(list)
    for r in residuals:
        if r.kind == "observation":
            for key in r.keys:
                if key.startswith("m"):
                    errors[int(key[1:])].append(r.whitened_error)
    return {i: (float(np.median(e)), len(e)) for i, e in errors.items()}


def _prior_whitened(residuals: Sequence[FactorResidual]) -> dict[int, float]:
    return {int(r.keys[0][1:]): r.whitened_error for r in residuals if r.kind == "prior"}


def _strain(solution: SessionsEstimate, held: set[int]) -> dict[int, float]:
    """How far each held map marker (seen often enough to judge) disagrees with this log, in
    sigmas: its prior pulled by the observations, or its observations held off by the prior."""
    observed = _median_whitened(solution.residuals)
    pulled = _prior_whitened(solution.residuals)
    return {
        i: max(pulled.get(i, 0.0), observed[i][0])
        for i in held
        if observed.get(i, (0.0, 0))[1] >= MIN_OBSERVATIONS_TO_MOVE
    }


def _suspects(solution: SessionsEstimate, held: set[int]) -> list[int]:
    return sorted(i for i, s in _strain(solution, held).items() if s > SUSPECT_WHITENED)


def _strain_left(solution: SessionsEstimate, held: set[int]) -> float:
    return max(_strain(solution, held).values(), default=0.0)


def localize(
    frames: Frames,
    T_base_camera: gtsam.Pose2,
    saved: Mapping[int, MapPrior],
    *,
    robust: Robust = Robust.HUBER,
) -> Localization:
    """The robot's trajectory in a saved map, its markers held at their covariances, those
    moved since found and left out (:func:`moved_markers`). Markers the map does not know are
    placed and reported as new.

    Raises:
        EstimationError: as :func:`moved_markers`.
    """

    def solve(freed: Sequence[int]) -> SessionsEstimate:
        priors = {i: p for i, p in saved.items() if i not in freed}
        return solve_sessions(
            [frames], [T_base_camera], robust=robust, priors=priors, pose_covariances=True
        )

    found = moved_markers(solve, set(frames.marker_ids()), saved)
    pulled = _prior_whitened(found.first.residuals)
    return _localization(found.final, found.moved, saved, pulled)


@dataclass(frozen=True)
class MovedSearch:
    """What :func:`moved_markers` found.

    Attributes:
        first: the solution with every prior.
        final: the solution without the moved markers' priors (``first`` where none moved).
        moved: the markers moved since the map was made.
    """

    first: SessionsEstimate
    final: SessionsEstimate
    moved: list[int]


def moved_markers(
    solve: Callable[[Sequence[int]], SessionsEstimate],
    seen: set[int],
    saved: Mapping[int, MapPrior],
) -> MovedSearch:
    """The saved map's markers moved since it was made, found by this log's residuals
    (``solve``: the log's solution without the priors of the markers given; ``seen``: the
    markers the log sees).

    A map marker seen at least :data:`MIN_OBSERVATIONS_TO_MOVE` times whose prior or
    observations are more than :data:`SUSPECT_WHITENED` sigmas off is freed and placed by the
    log alone, one at a time: the suspect whose absence leaves the others least strained (one
    moved marker pulls the robot, and with it every other marker's residuals: freeing every
    suspect at once, or the most strained, frees the wrong ones on a map of three); if its pose
    differs from the map's beyond chi-square's 99.9 % point (:data:`MOVED_CHI2`, both
    covariances), it moved, and the log is solved without its prior, so it cannot pull the
    robot.

    Raises:
        EstimationError: the log sees no marker of the map; every marker it sees disagrees
            with the map; or a moved marker is found against a single other, which cannot
            tell which of the two moved.
    """
    first = solve(())
    seen = seen & set(saved)
    freed: list[int] = []
    solution = first
    while suspects := _suspects(solution, seen - set(freed)):
        held = seen - set(freed)
        if len(held) == 1:
            raise EstimationError(
                f"every map marker this log sees ({', '.join(map(str, sorted(seen)))}) "
                "disagrees with the map: nothing to localise against"
            )
        # One moved marker strains its neighbours too: free the suspect whose absence leaves
        # the others least strained, not the most strained one.
        trials = {i: solve([*freed, i]) for i in suspects}
        worst = min(trials, key=lambda i: _strain_left(trials[i], held - {i}))
        freed.append(worst)
        solution = trials[worst]
    moved = [i for i in freed if _moved(saved[i], solution.markers[i], i, solution)]
    holding = sorted(seen - set(freed))
    if moved and len(holding) == 1:
        raise EstimationError(
            f"map markers {', '.join(map(str, sorted([*moved, *holding])))} disagree with "
            "each other beyond their covariances, and this log sees no further map marker to "
            "tell which of them moved"
        )
    if not moved:
        return MovedSearch(first, first, [])
    return MovedSearch(first, solution if moved == freed else solve(moved), moved)


def _moved(
    before: MapPrior, now: MarkerEstimate, marker_id: int, solution: SessionsEstimate
) -> bool:
    """The map's pose against this log's, each with its own covariance: beyond chi-square's
    99.9 % point (3 dof)."""
    if now.covariance is None:
        raise EstimationError(
            f"no covariance for marker {marker_id}: {'; '.join(n.text for n in solution.notes)}"
        )
    difference = before.T_map_marker.localCoordinates(now.T_map_marker)
    covariance = before.covariance + now.covariance
    return float(difference @ np.linalg.solve(covariance, difference)) > MOVED_CHI2


def _localization(
    final: SessionsEstimate,
    moved_ids: list[int],
    saved: Mapping[int, MapPrior],
    pulled: Mapping[int, float],
) -> Localization:
    moved = []
    for i in moved_ids:
        before, now = saved[i].T_map_marker, final.markers[i].T_map_marker
        moved.append(MovedMarker(
            i, before, now, math.hypot(now.x() - before.x(), now.y() - before.y()), pulled[i],
            final.markers[i].covariance,
        ))  # fmt: skip
    new = {i: m for i, m in final.markers.items() if i not in saved}
    trajectory, covariances = final.trajectories[0], final.pose_covariances[0]
    assert trajectory is not None
    if covariances is None:
        raise EstimationError(f"no pose covariances: {'; '.join(n.text for n in final.notes)}")
    return Localization(trajectory, covariances, moved, new, dict(pulled), final)
