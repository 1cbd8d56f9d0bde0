"""The target heading's 1-sigma from the map's marker covariances (first-order propagation)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.estimator.paper import Form, edge_from_pose2, heading
from markergraph.markermap import MarkerMap, MarkerMapError

__all__ = ["HeadingSigma", "heading_jacobian_markers", "heading_sigma", "marker_covariance"]

STEP = 1e-6  # central-difference step in each marker's tangent [m, rad]: well inside linearity


@dataclass(frozen=True, slots=True)
class HeadingSigma:
    """The heading's uncertainty from the map alone (the robot's own ``d``, theta taken as exact).

    Attributes:
        distance_m: 1-sigma of the distance to drive [m].
        turn_rad: 1-sigma of the turn toward the target [rad].
        covariance: (2, 2) over (distance [m], turn [rad]).
    """

    distance_m: float
    turn_rad: float
    covariance: NDArray[np.float64]


def marker_covariance(marker_map: MarkerMap, marker_id: int) -> NDArray[np.float64]:
    """(3, 3) a marker's covariance over its own tangent (x, y, yaw): the relative one where the
    map has it, since the heading reads only the two markers' relative pose and the map's common
    rigid motion cancels in it; else the plain one.

    Raises:
        MarkerMapError: the marker has no covariance (a map without covariances).
    """
    marker = marker_map.markers[marker_id]
    P = marker.relative_covariance if marker.relative_covariance is not None else marker.covariance
    if P is None:
        raise MarkerMapError(f"marker {marker_id} has no covariance: no sigma for the heading")
    return np.asarray(P, dtype=np.float64)


def _heading_of(
    T_map_a: gtsam.Pose2, T_map_c: gtsam.Pose2, d: float, theta: float
) -> NDArray[np.float64]:
    """(distance, turn) from ``a`` to ``c`` (the paper's closed form, exact version)."""
    distance, turn = heading(edge_from_pose2(T_map_a.between(T_map_c)), d, theta, Form.EXACT)
    return np.array([distance, turn])


def heading_jacobian_markers(
    T_map_a: gtsam.Pose2, T_map_c: gtsam.Pose2, d: float, theta: float
) -> NDArray[np.float64]:
    """(2, 6) the derivative of (distance, turn) by the two markers' tangents (a's x, y, yaw,
    then c's), each perturbed on the right as GTSAM does (``T.retract(xi)``).

    Central differences of the closed form: it is smooth away from the robot standing on the
    target, and one derivative serves the exact and the paper's signed form alike.
    """
    J = np.zeros((2, 6))
    for k in range(6):
        xi = np.zeros(6)
        xi[k] = STEP
        plus = _heading_of(T_map_a.retract(xi[:3]), T_map_c.retract(xi[3:]), d, theta)
        minus = _heading_of(T_map_a.retract(-xi[:3]), T_map_c.retract(-xi[3:]), d, theta)
        difference = plus - minus
        difference[1] = math.remainder(difference[1], math.tau)  # the turn wraps at +-pi
        J[:, k] = difference / (2 * STEP)
    return J


def heading_sigma(
    marker_map: MarkerMap, source: int, d: float, theta: float, target: int
) -> HeadingSigma:
    """The 1-sigma of :meth:`MarkerMap.heading`'s distance and turn, propagated to first order
    from the two markers' covariances, taken as independent (map.json keeps no
    cross-covariances).

    Raises:
        MarkerMapError: a marker not in the map, the two the same, or one without covariance.
    """
    marker_map.heading(source, d, theta, target)  # its checks, with its messages
    J = heading_jacobian_markers(
        marker_map.markers[source].T_map_marker, marker_map.markers[target].T_map_marker, d, theta
    )
    P = np.zeros((6, 6))
    P[:3, :3] = marker_covariance(marker_map, source)
    P[3:, 3:] = marker_covariance(marker_map, target)
    covariance = J @ P @ J.T
    return HeadingSigma(
        math.sqrt(max(float(covariance[0, 0]), 0.0)),
        math.sqrt(max(float(covariance[1, 1]), 0.0)),
        covariance,
    )
