"""Markers' covariances relative to the map as a whole, not to the one marker that fixes it.

A map's frame is fixed by its home marker, so every other marker's marginal in that frame also
carries the home marker's own uncertainty, above all its yaw: a home seen obliquely a few dozen
times leaves 0.3 rad on every marker, a metre at the far wall. That part moves all markers
together and says nothing about the map's shape. What a saved map should hand on (to localise a
robot, to spot a moved marker) is each marker's uncertainty with that common motion removed:
the joint covariance projected onto the motions that are not a rigid motion of the whole map
(every marker weighing alike: a fit weighted by the covariance would let the home marker, held
to 0.1 mm by its prior, define the common motion alone and remove nothing).
"""

from __future__ import annotations

from collections.abc import Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

__all__ = ["relative_covariances"]


def relative_covariances(
    poses: Sequence[gtsam.Pose2], joint: NDArray[np.float64]
) -> list[NDArray[np.float64]]:
    """Each marker's 3x3 covariance (its own tangent space) with the map's common rigid motion
    removed: ``P S P^T`` for the joint covariance ``S`` over the markers in order, with
    ``P = I - G (G^T G)^-1 G^T`` and ``G`` the motion of each marker's tangent space under a
    rigid motion of the map (``Ad(T_i^-1)``). Needs two markers or more; one is returned as
    it is."""
    n = len(poses)
    if n < 2:
        return [joint[:3, :3]] if n else []
    G = np.vstack([T.inverse().AdjointMap() for T in poses])
    P = np.eye(3 * n) - G @ np.linalg.solve(G.T @ G, G.T)
    relative = P @ joint @ P.T
    return [_positive(relative[3 * i : 3 * i + 3, 3 * i : 3 * i + 3]) for i in range(n)]


def _positive(covariance: NDArray[np.float64]) -> NDArray[np.float64]:
    """Symmetric, with no variance below (10 micrometres)^2: a block of a projected matrix can
    be singular (two markers: the projection leaves three degrees of freedom for six)."""
    values, vectors = np.linalg.eigh(0.5 * (covariance + covariance.T))
    return (vectors * np.maximum(values, MIN_VARIANCE)) @ vectors.T


MIN_VARIANCE = 1e-10
