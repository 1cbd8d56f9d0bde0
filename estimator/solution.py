"""What the GTSAM methods share once a graph is built: Levenberg-Marquardt's settings and
solve, the marginals, and the :class:`~markergraph.estimator.estimate.Estimate` of a solved
graph with its notes."""

from __future__ import annotations

import time
from collections import Counter
from functools import partial

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L
from numpy.typing import NDArray

from markergraph.common.errors import EstimationError
from markergraph.common.notes import Note
from markergraph.estimator.estimate import Estimate
from markergraph.estimator.frames import Frames
from markergraph.estimator.gauge import relative_covariances_of_groups
from markergraph.estimator.graph import GraphBuilder, read_residuals
from markergraph.estimator.links import describe_disconnected
from markergraph.estimator.trajectory import Trajectory
from markergraph.estimator.types import MarkerEstimate, Method

__all__ = [
    "MAX_ITERATIONS",
    "SEARCH_RELATIVE_ERROR_TOL",
    "disconnected_notes",
    "first_line",
    "lm_params",
    "marginals_or_note",
    "marker_estimates",
    "not_converged_note",
    "observation_counts",
    "optimise",
    "solved_estimate",
]

MAX_ITERATIONS = 100
"""Levenberg-Marquardt's iteration limit: a solve that reaches it has not converged."""


SEARCH_RELATIVE_ERROR_TOL = 1e-6
"""Where a search's solves stop (:func:`~markergraph.estimator.slam.slam_cost`): a step that
lowers the cost by less than this share of it. Under a robust kernel Levenberg-Marquardt's last
iterations close in on the optimum by a constant ratio (about 0.86 a step on an 8-minute
corridor log) and lower the cost by a few millionths each: the cost stopped here is within about
0.01 of the optimum's, where grid values 10 ms or 1 % apart differ by 5-100, so the parabola's
minimum moves by under 0.001 ms or 0.00002 of a scale; a solve to 1e-10 took 82 iterations,
this one 7-20."""


def lm_params(relative_error_tol: float = 1e-10) -> gtsam.LevenbergMarquardtParams:
    """Levenberg-Marquardt's settings for every batch solve here and in sessions.py; a search
    stops sooner (:data:`SEARCH_RELATIVE_ERROR_TOL`)."""
    # Tighter tolerances buy nothing measurable and cost rejected steps at convergence
    # (1.5 s instead of 0.36 s on the 10,000-pose benchmark).
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(MAX_ITERATIONS)
    params.setRelativeErrorTol(relative_error_tol)
    params.setAbsoluteErrorTol(1e-12)
    return params


def first_line(error: Exception) -> str:
    """GTSAM's messages start with a blank line: the first line that says something."""
    return next((line.strip() for line in str(error).splitlines() if line.strip()), repr(error))


def marginals_or_note(
    graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, notes: list[Note]
) -> gtsam.Marginals | None:
    """The solution's marginals, or None with a note saying why when the system is
    indeterminate (the means are kept)."""
    try:
        return gtsam.Marginals(graph, values)
    except RuntimeError as error:  # an indeterminate system: report, keep the means
        notes.append(
            Note("marginals.unavailable", f"marginal covariances unavailable: {first_line(error)}")
        )
        return None


def marker_estimates(
    values: gtsam.Values,
    marker_ids: list[int],
    counts: Counter[int],
    marginals: gtsam.Marginals | None,
    graph: gtsam.NonlinearFactorGraph | None = None,
) -> dict[int, MarkerEstimate]:
    """Each marker's pose, marginal covariance and relative covariance
    (:func:`~markergraph.estimator.gauge.relative_covariances`).

    With ``graph``, markers that no chain of factors joins are independent, so the joint
    covariance is asked only within each connected group: a saved map's 20,000 markers that a
    log never sees are 20,000 3x3 marginals, not one dense 60,000 x 60,000 matrix (29 GB, and
    minutes of GTSAM's time)."""
    poses = [values.atPose2(L(i)) for i in marker_ids]
    if marginals is None:
        return {
            i: MarkerEstimate(i, T, None, counts[i]) for i, T in zip(marker_ids, poses, strict=True)
        }
    groups = _connected(graph, marker_ids) if graph is not None else [list(range(len(poses)))]
    blocks = []
    for group in groups:
        keys = [L(marker_ids[k]) for k in group]
        if len(keys) == 1:
            blocks.append((group, marginals.marginalCovariance(keys[0])))
        else:
            joint = marginals.jointMarginalCovariance(gtsam.KeyVector(keys)).fullMatrix()
            blocks.append((group, joint))
    relative = relative_covariances_of_groups(poses, blocks)
    own: dict[int, NDArray[np.float64]] = {}
    for group, joint in blocks:
        for j, k in enumerate(group):
            own[k] = joint[3 * j : 3 * j + 3, 3 * j : 3 * j + 3].copy()
    return {
        i: MarkerEstimate(i, T, own[k], counts[i], relative[k])
        for k, (i, T) in enumerate(zip(marker_ids, poses, strict=True))
    }


def _connected(graph: gtsam.NonlinearFactorGraph, marker_ids: list[int]) -> list[list[int]]:
    """The markers (as indices into ``marker_ids``) in groups that factors join, through
    robot poses or directly (union-find over every factor's keys); in order of first index."""
    parent: dict[int, int] = {}

    def root(key: int) -> int:
        parent.setdefault(key, key)
        while parent[key] != key:
            parent[key] = parent[parent[key]]  # path halving
            key = parent[key]
        return key

    for n in range(graph.size()):
        factor = graph.at(n)
        if factor is None:
            continue
        keys = list(factor.keys())
        for key in keys[1:]:
            parent[root(key)] = root(keys[0])
    groups: dict[int, list[int]] = {}
    for k, marker_id in enumerate(marker_ids):
        groups.setdefault(root(L(marker_id)), []).append(k)
    return list(groups.values())


def observation_counts(frames: Frames) -> Counter[int]:
    return Counter(o.marker_id for f in frames.frames for o in f.observations)


def optimise(
    builder: GraphBuilder,
    timings: dict[str, float],
    warm: bool = True,
    params: gtsam.LevenbergMarquardtParams | None = None,
) -> tuple[gtsam.Values, bool]:
    """Levenberg-Marquardt (``params``, else :func:`lm_params`) from the builder's initial
    values, or (``warm``) from its pose-graph form's solution
    (:meth:`GraphBuilder.warm_start`); (solution, converged)."""
    start = time.perf_counter()
    params = lm_params() if params is None else params
    try:
        start_values = builder.warm_start(params) if warm else builder.values
        optimizer = gtsam.LevenbergMarquardtOptimizer(builder.graph, start_values, params)
        result = optimizer.optimize()
    except RuntimeError as error:  # GTSAM's IndeterminantLinearSystemException
        raise EstimationError(
            f"GTSAM could not solve the graph: {str(error).splitlines()[0]}"
        ) from None
    timings["optimize"] = time.perf_counter() - start
    return result, optimizer.iterations() < MAX_ITERATIONS


def solved_estimate(
    method: Method,
    frames: Frames,
    builder: GraphBuilder,
    result: gtsam.Values,
    *,
    marker_ids: list[int],
    trajectory: Trajectory,
    links: list,
    notes: list[Note],
    converged: bool,
    timings: dict[str, float],
    unplaced: dict[int, str] | None = None,
    observations_unlinked: int | None = None,
) -> Estimate:
    """The Estimate of a solved factor graph: markers with their joint marginals, the
    trajectory, residuals, links and notes, and the graph and solution themselves."""
    graph = builder.graph
    start = time.perf_counter()
    marginals = marginals_or_note(graph, result, notes)
    estimate = Estimate(
        method=method,
        home_id=frames.home_id,
        markers=marker_estimates(result, marker_ids, observation_counts(frames), marginals, graph),
        trajectory=trajectory,
        residuals=read_residuals(graph, result, builder.kinds),
        links=links,
        unplaced=unplaced or {},
        converged=converged,
        notes=notes,
        graph=graph,
        values=result,
        pose_graph=partial(builder.pose_graph, result),
        observations_unlinked=observations_unlinked,
    )
    timings["marginals"] = time.perf_counter() - start
    estimate.timings_s = timings
    return estimate


def disconnected_notes(
    kind: str, groups: list[list[int]], home_id: int, ending: str = ""
) -> list[Note]:
    """A note per group of markers no link chain joins to home, and one for the markers linked
    to none (``describe_disconnected``'s sentences), its figure how many markers it names."""
    return [
        Note(kind, f"{sentence}{ending}", figure=len(group))
        for group, sentence in describe_disconnected(groups, home_id)
    ]


def not_converged_note() -> Note:
    """The note of a Levenberg-Marquardt solve that stopped at :data:`MAX_ITERATIONS`."""
    return Note(
        "slam.not_converged",
        f"Levenberg-Marquardt stopped after {MAX_ITERATIONS} iterations without "
        "converging; the map is its last estimate",
        figure=MAX_ITERATIONS,
    )
