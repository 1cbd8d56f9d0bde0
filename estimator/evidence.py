"""What an estimate says about its own trustworthiness, without ground truth: its residuals
against their chi-square range, the size of its marker ellipses against the map, how far two
estimates of the same markers lie apart against their covariances, and whether the robot was in
front of each marker it saw.

These are figures, not judgements; :mod:`markergraph.verdicts` turns them into a verdict.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from markergraph.estimator.estimate import Estimate
from markergraph.estimator.types import Observation

__all__ = [
    "ResidualFit",
    "chi2_upper",
    "ellipse_semi_axes_m",
    "facing_away",
    "map_extent_m",
    "marker_disagreement",
    "position_covariance",
    "residual_fit",
]

_FACTOR_DIM = 3  # every factor markergraph builds (observation, odometry, edge, prior) is 3-D
_NEAREST_POSE_NS = 500_000_000  # an observation further than this from every pose is not judged


@dataclass(frozen=True)
class ResidualFit:
    """The solution's whitened residuals against the chi-square they should follow.

    Attributes:
        chi2: the sum of squared whitened residuals (twice the graph's error).
        dof: residual dimensions less estimated dimensions (what ``chi2`` should average).
    """

    chi2: float
    dof: int

    @property
    def ratio(self) -> float:
        """``chi2 / dof``: 1 when the noise model is honest, above when the data disagree."""
        return self.chi2 / self.dof if self.dof > 0 else math.nan


def residual_fit(estimate: Estimate) -> ResidualFit | None:
    """The solution's chi-square and its degrees of freedom, or None for a method without
    factors (the closed form) or a graph with nothing to spare (``dof <= 0``)."""
    if not estimate.residuals or estimate.values is None:
        return None
    residuals = [r for r in estimate.residuals if r.kind != "prior"]  # the gauge's, ~0 by design
    priors = len(estimate.residuals) - len(residuals)
    unknowns = _FACTOR_DIM * estimate.values.size()
    # A prior fixes the gauge: its dimensions are estimated dimensions the data need not fit.
    dof = _FACTOR_DIM * len(residuals) - (unknowns - _FACTOR_DIM * priors)
    if dof <= 0:
        return None
    chi2 = float(sum(r.whitened_error**2 for r in residuals))
    return ResidualFit(chi2, dof)


def chi2_upper(dof: int, z: float = 3.090232306167813) -> float:
    """The chi-square's upper quantile for ``dof`` (default 99.9 %) by Wilson-Hilferty."""
    k = float(dof)
    return k * (1.0 - 2.0 / (9.0 * k) + z * math.sqrt(2.0 / (9.0 * k))) ** 3


def position_covariance(T_map_marker_yaw: float, covariance: NDArray[np.float64]) -> NDArray:
    """A marker's 2x2 position covariance in the map frame from its 3x3 tangent-space one
    (GTSAM's right perturbation: the position part is in the marker's own axes)."""
    c, s = math.cos(T_map_marker_yaw), math.sin(T_map_marker_yaw)
    R = np.array([[c, -s], [s, c]])
    return R @ covariance[:2, :2] @ R.T


def ellipse_semi_axes_m(covariance: NDArray[np.float64], sigmas: float = 1.0) -> NDArray:
    """(2,) the position ellipse's semi-axes, largest first [m], at ``sigmas`` standard
    deviations."""
    eigenvalues = np.linalg.eigvalsh(covariance[:2, :2])
    return sigmas * np.sqrt(np.clip(eigenvalues[::-1], 0.0, None))


def map_extent_m(estimate: Estimate) -> float:
    """The largest distance between two of the estimate's markers [m] (0 for one marker)."""
    xy = [m.T_map_marker.translation() for m in estimate.markers.values()]
    return max((float(np.hypot(*(a - b))) for a, b in itertools.combinations(xy, 2)), default=0.0)


def marker_disagreement(a: Estimate, b: Estimate) -> dict[int, tuple[float, float | None]]:
    """For each marker both estimates place: (the distance between its two positions [m], its
    squared Mahalanobis length under the sum of the two position covariances, or None where
    either has none).

    The sum ignores that both used the same data (their errors correlate), so it is generous:
    a large figure is a real disagreement.
    """
    result: dict[int, tuple[float, float | None]] = {}
    for marker_id in sorted(set(a.markers) & set(b.markers)):
        ma, mb = a.markers[marker_id], b.markers[marker_id]
        difference = mb.T_map_marker.translation() - ma.T_map_marker.translation()
        distance = float(np.hypot(*difference))
        if ma.covariance is None or mb.covariance is None:
            result[marker_id] = (distance, None)
            continue
        S = position_covariance(ma.T_map_marker.theta(), ma.covariance) + position_covariance(
            mb.T_map_marker.theta(), mb.covariance
        )
        try:
            d2 = float(difference @ np.linalg.solve(S, difference))
        except np.linalg.LinAlgError:
            d2 = math.inf
        result[marker_id] = (distance, d2)
    return result


def facing_away(
    estimate: Estimate, observations: list[Observation], T_base_camera_x_m: float = 0.0
) -> dict[int, tuple[int, int]]:
    """For each placed marker: (its observations from behind its face, its observations with an
    estimated robot pose), the pose taken at the nearest stamp of the estimate's trajectory.

    A camera sees a marker's printed face only from in front of it, so with the marker's +x the
    normal into the room, the camera lies at positive x in the marker's frame. A marker seen
    from behind in most of its observations has its yaw turned round (or the path is wrong).

    Args:
        T_base_camera_x_m: the camera's offset ahead of the base [m]: its position is taken on
            the base's heading line (a few centimetres beside it change nothing here).
    """
    trajectory = estimate.trajectory
    if not len(trajectory):
        return {}
    counts: dict[int, list[int]] = {}
    for obs in observations:
        marker = estimate.markers.get(obs.marker_id)
        if marker is None:
            continue
        i = int(np.clip(np.searchsorted(trajectory.t_ns, obs.t_ns), 1, len(trajectory) - 1))
        i -= abs(int(trajectory.t_ns[i - 1]) - obs.t_ns) <= abs(int(trajectory.t_ns[i]) - obs.t_ns)
        if abs(int(trajectory.t_ns[i]) - obs.t_ns) > _NEAREST_POSE_NS:
            continue
        x, y, yaw = trajectory.poses[i]
        camera = np.array([x, y]) + T_base_camera_x_m * np.array([math.cos(yaw), math.sin(yaw)])
        T = marker.T_map_marker
        # The camera's x in the marker's frame: along the marker's normal.
        in_front = (camera - T.translation()) @ np.array([math.cos(T.theta()), math.sin(T.theta())])
        tally = counts.setdefault(obs.marker_id, [0, 0])
        tally[0] += bool(in_front < 0.0)
        tally[1] += 1
    return {i: (behind, n) for i, (behind, n) in counts.items()}
