"""The share of a map's uncertainty that a parameter held fixed brings (a *consider* covariance,
after Schmidt): a sensor setting the data cannot choose, such as a rolling shutter's readout, or
one they chose only to a standard deviation, such as the odometry's scale, moves every marker
together, so its error is common to the whole map, and no residual shows it.

The map is solved again with the parameter elsewhere: each marker's move between the two,
``d`` (in its tangent space), gives the covariance it adds, ``fraction d d^T``. Solved at
either end of a uniform range, the true value lies anywhere up to the other end, and the
error's second moment is ``d d^T / 3`` (``d d^T / 12`` from the middle); solved one standard
deviation further for a Gaussian error, it is ``d d^T`` to first order.
"""

from __future__ import annotations

from dataclasses import replace

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.estimator.estimate import Estimate
from markergraph.estimator.gauge import rigid_motion_maps

__all__ = ["AT_ONE_END", "marker_moves", "with_considered"]

AT_ONE_END = 1.0 / 3.0
"""The second moment of a uniform value's distance from one end of its range, per range^2."""


def marker_moves(estimate: Estimate, moved: Estimate) -> dict[int, NDArray[np.float64]]:
    """Each marker's move from ``estimate`` to ``moved`` (the same map solved with the
    parameter elsewhere) in its own tangent space, ``Logmap(T^-1 T')`` (x, y, yaw): markers in
    both, but the home marker (each map's origin).

    Raises:
        ValueError: the two maps are on different home markers (in different frames, their
            moves would be the change of frame).
    """
    if estimate.home_id != moved.home_id:
        raise ValueError(
            f"maps on home markers {estimate.home_id} and {moved.home_id}: not one frame"
        )
    return {
        i: np.asarray(gtsam.Pose2.Logmap(m.T_map_marker.between(moved.markers[i].T_map_marker)))
        for i, m in estimate.markers.items()
        if i in moved.markers and i != estimate.home_id
    }


def with_considered(estimate: Estimate, moved: Estimate, fraction: float) -> Estimate:
    """``estimate`` with each marker's covariance grown by ``fraction * d d^T``, ``d`` its move
    to ``moved`` (:func:`marker_moves`); its relative covariance (the map's common rigid motion
    removed: :mod:`~markergraph.estimator.gauge`) by the moves less the rigid motion that best
    explains them. Markers without a covariance, or not in ``moved``, are left as they are."""
    moves = marker_moves(estimate, moved)
    relative = _less_rigid_motion(estimate, moves)
    markers = dict(estimate.markers)
    for i, d in moves.items():
        marker = markers[i]
        if marker.covariance is None:
            continue
        grown = marker.covariance + fraction * np.outer(d, d)
        relative_grown = marker.relative_covariance
        if relative_grown is not None:
            relative_grown = relative_grown + fraction * np.outer(relative[i], relative[i])
        markers[i] = replace(marker, covariance=grown, relative_covariance=relative_grown)
    return replace(estimate, markers=markers)


def _less_rigid_motion(
    estimate: Estimate, moves: dict[int, NDArray[np.float64]]
) -> dict[int, NDArray[np.float64]]:
    """The moves with the map's rigid motion that best explains them taken out (the projection
    :func:`~markergraph.estimator.gauge.relative_covariances` applies to a covariance)."""
    ids = sorted(moves)
    if len(ids) < 2:
        return {i: np.zeros(3) for i in ids}
    G, M = rigid_motion_maps([estimate.markers[i].T_map_marker for i in ids])
    d = np.stack([moves[i] for i in ids])
    return dict(zip(ids, d - G @ np.einsum("iab,ib->a", M, d), strict=True))
