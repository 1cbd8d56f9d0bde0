"""What several logs of one place need beyond one log's job: a saved map's markers as priors,
a several-log solution as one method's estimate, and the maps of logs that share no marker with
the rest. The flow that uses them is :mod:`markergraph.run`'s."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L
from numpy.typing import NDArray

from markergraph.common import Note
from markergraph.common.notes import some_of
from markergraph.estimator import Estimate, Frames, Method
from markergraph.estimator.graph import HOME_PRIOR_NOISE
from markergraph.estimator.sessions import MapPrior, SessionsEstimate, solve_sessions
from markergraph.markermap import MarkerMap
from markergraph.records import marker_map_of
from markergraph.settings import MapConfig, with_map_defaults

__all__ = [
    "SESSION_METHODS",
    "as_estimate",
    "in_home_frame",
    "priors_of",
    "separate_maps",
    "settings_for_map",
]

SESSION_METHODS = (Method.SLAM, Method.ISAM2, Method.MARKER_GRAPH)
# A saved map without covariances (the closed form's) still needs its markers held: this firmly.
DEFAULT_PRIOR_SIGMAS = np.array([0.01, 0.01, math.radians(1.0)])


def settings_for_map(values: dict[str, Any], saved: MarkerMap, path: Path) -> dict[str, Any]:
    """The settings a log read against a saved map takes (:func:`with_map_defaults`): the map's
    dictionary and marker sizes where the settings give none.

    Raises:
        SettingsError: a dictionary or marker size given that the map contradicts.
    """
    apart = {i: m.size_m for i, m in saved.markers.items() if m.size_m != saved.marker_size_m}
    return with_map_defaults(values, saved.dictionary, saved.marker_size_m, apart, path)


def priors_of(saved: MarkerMap) -> tuple[dict[int, MapPrior], list[Note]]:
    """A saved map's markers as priors, at their covariances relative to the map as a whole
    (their marginals in the home marker's frame would carry the home's own uncertainty on every
    marker, and independent priors that wide hold nothing); and a note of those held by
    default."""
    default = np.diag(DEFAULT_PRIOR_SIGMAS**2)
    bare = [m.marker_id for m in saved.markers.values() if m.covariance is None]
    notes = []
    if bare:
        notes.append(Note(
            "prior.no_covariance",
            f"the saved map has no covariance for marker(s) {', '.join(map(str, bare))}: held "
            "at 1 cm and 1 deg",
            figure=len(bare),
        ))  # fmt: skip
    marginal = [m.marker_id for m in saved.markers.values()
                if m.relative_covariance is None and m.covariance is not None]  # fmt: skip
    if marginal:
        what = "a 3-D map's wall tags" if saved.dimensions == 3 else "the saved map's markers"
        notes.append(Note(
            "prior.marginal",
            f"{what} ({some_of(marginal)}) have no covariance relative to the map as a "
            "whole: held at their marginals in the home marker's frame, which carry the home's "
            "own uncertainty on every marker, hold the robot loosely and can hide a moved marker",
            figure=len(marginal),
        ))  # fmt: skip
    priors, floored = {}, []
    for m in saved.markers.values():
        covariance = m.relative_covariance if m.relative_covariance is not None else m.covariance
        held = default if covariance is None else _floored(covariance)
        # Said only of a covariance no map measures (an edited one): a real map's best
        # markers come near the floor (TagSLAM's test 21: 0.76 mm), and the home marker's
        # marginal is the map frame's anchor.
        if (
            covariance is not None
            and np.linalg.eigvalsh(covariance)[0] < UNMEASURED_VARIANCE
            and m.marker_id != saved.home_id
        ):
            floored.append(m.marker_id)
        priors[m.marker_id] = MapPrior(m.T_map_marker, held)
    if floored:
        notes.append(Note(
            "prior.floored",
            f"the saved map holds marker(s) {some_of(floored)} to under 0.1 mm or 0.1 mrad, "
            "tighter than a map measures: held at 1 mm and 1 mrad (a marker held rigid cannot "
            "be found moved, and would move the robot instead)",
            figure=len(floored),
        ))  # fmt: skip
    return priors, notes


MIN_PRIOR_VARIANCE = 1e-6
"""The least variance a prior is held at, (1 mm)^2 or (1 mrad)^2, under any marker a map
measures relative to the others: a map may hold a singular covariance (semi-definite is a
covariance), which GTSAM would take as an infinite weight, and a marker held far tighter than
its observations would take the blame for a move of its own as the robot's (a map edited to
zero on one marker, moved 0.3 m: ten others called moved, the robot 21 cm off; held at 0.3 mm,
five others; at 0.55 mm, marker 7 alone)."""
UNMEASURED_VARIANCE = MIN_PRIOR_VARIANCE / 100
"""Under this, (0.1 mm)^2, a map's covariance is no measurement's: said in a note."""


def _floored(covariance: NDArray[np.float64]) -> NDArray[np.float64]:
    """``covariance`` with no eigenvalue below :data:`MIN_PRIOR_VARIANCE`."""
    values, vectors = np.linalg.eigh(covariance)
    if float(values[0]) >= MIN_PRIOR_VARIANCE:
        return covariance
    floored = (vectors * np.maximum(values, MIN_PRIOR_VARIANCE)) @ vectors.T
    return 0.5 * (floored + floored.T)


def as_estimate(solved: SessionsEstimate, method: Method, home_id: int) -> Estimate:
    """A several-log solution as one method's estimate, with the first placed log's path."""
    trajectory = next(t for t in solved.trajectories if t is not None)
    return Estimate(
        method=method, home_id=home_id, markers=solved.markers, trajectory=trajectory,
        residuals=solved.residuals, notes=solved.notes, graph=solved.graph, values=solved.values,
        pose_graph=solved.pose_graph,
    )  # fmt: skip


def in_home_frame(estimate: Estimate) -> Estimate:
    """``estimate`` with each marker's covariance that of its pose relative to the home marker,
    as a map's ``covariance`` is (its relative covariances as they are). A saved map's priors
    hold a several-log map's frame as a whole, not by its home marker, so the solution's
    marginals leave out the home's own uncertainty: on an unchanged office log, the refined map
    held 7 of 23 true markers within its 95 % ellipses in the home marker's frame (mean NEES 35).
    A marker and the home's joint marginal gives it: ``xi_hj = -Ad(T_hj^-1) xi_h + xi_j``."""
    home, graph, values = estimate.home_id, estimate.graph, estimate.values
    if graph is None or values is None or home not in estimate.markers:
        return estimate
    marginals = gtsam.Marginals(graph, values)
    T_home = values.atPose2(L(home))
    markers = {}
    for i, marker in estimate.markers.items():
        covariance = marker.covariance
        if i == home:
            covariance = np.diag(HOME_PRIOR_NOISE.sigmas() ** 2)  # the frame's origin
        elif covariance is not None:
            joint = marginals.jointMarginalCovariance(gtsam.KeyVector([L(home), L(i)]))
            T_home_marker = T_home.between(values.atPose2(L(i)))
            A = np.hstack([-T_home_marker.inverse().AdjointMap(), np.eye(3)])
            covariance = A @ joint.fullMatrix() @ A.T
        markers[i] = replace(marker, covariance=covariance)
    return replace(estimate, markers=markers)


def separate_maps(
    apart: list[int],
    logs: Sequence[Path],
    frames: list[Frames],
    mounts: list[gtsam.Pose2],
    config: MapConfig,
) -> list[tuple[list[Path], MarkerMap]]:
    """The maps of sessions that share no marker with the main map, each group on its own."""
    maps = []
    while apart:
        solved = solve_sessions([frames[i] for i in apart], [mounts[i] for i in apart],
                                robust=config.noise.robust)  # fmt: skip
        placed = [apart[j] for j, t in enumerate(solved.trajectories) if t is not None]
        estimate = as_estimate(solved, Method.SLAM, frames[placed[0]].home_id)
        group = [Path(logs[i]) for i in placed]
        maps.append((group, marker_map_of(estimate, ", ".join(map(str, group)), config)))
        apart = [apart[j] for j in solved.apart]
    return maps
