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

__all__ = ["relative_covariances", "relative_covariances_of_groups", "rigid_motion_maps"]


def relative_covariances(
    poses: Sequence[gtsam.Pose2], joint: NDArray[np.float64]
) -> list[NDArray[np.float64]]:
    """Each marker's 3x3 covariance (its own tangent space) with the map's common rigid motion
    removed: ``P S P^T`` for the joint covariance ``S`` over the markers in order, with
    ``P = I - G (G^T G)^-1 G^T`` and ``G`` the motion of each marker's tangent space under a
    rigid motion of the map (``Ad(T_i^-1)``). Needs two markers or more; one is returned as
    it is. (:func:`relative_covariances_of_groups` with one group.)"""
    return relative_covariances_of_groups(poses, [(list(range(len(poses))), joint)])


def relative_covariances_of_groups(
    poses: Sequence[gtsam.Pose2],
    groups: Sequence[tuple[Sequence[int], NDArray[np.float64]]],
) -> list[NDArray[np.float64]]:
    """:func:`relative_covariances` where the joint covariance is block diagonal: markers in
    different groups are independent (a saved map's markers that this log never sees are held
    by their priors alone). Each group is (indices into ``poses``, their joint covariance).

    Only the diagonal blocks of ``P S P^T`` are wanted, so ``P`` (3n x 3n) is never formed:
    with ``M = (G^T G)^-1 G^T`` (3 x 3n, blocks ``M_i``), ``B_i = sum_j M_j S_ji`` (nonzero
    only within a group) and ``C = sum_i B_i M_i^T``, block i is
    ``S_ii - G_i B_i - B_i^T G_i^T + G_i C G_i^T``: memory and time linear in the markers,
    beyond each group's own joint covariance (a dense 3n x 3n over 20,000 markers was 29 GB).
    """
    n = len(poses)
    if n < 2:
        return [groups[0][1][:3, :3]] if n else []
    G, M = rigid_motion_maps(poses)
    B = np.zeros((n, 3, 3))
    S_ii = np.zeros((n, 3, 3))
    for indices, joint in groups:
        index = np.asarray(indices, dtype=np.int64)
        S = joint.reshape(len(index), 3, len(index), 3)
        B[index] = np.einsum("jab,jbic->iac", M[index], S)
        S_ii[index] = S[np.arange(len(index)), :, np.arange(len(index)), :]
    C = np.einsum("iab,icb->ac", B, M)
    relative = S_ii - G @ B - (G @ B).transpose(0, 2, 1) + G @ C @ G.transpose(0, 2, 1)
    return [_positive(block) for block in relative]


def rigid_motion_maps(
    poses: Sequence[gtsam.Pose2],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """How a rigid motion of the map moves each marker's tangent space, ``G_i = Ad(T_i^-1)``,
    and the blocks of its least-squares inverse, ``M_i = (G^T G)^-1 G_i^T``: both (n, 3, 3),
    ``sum_i M_i d_i`` the rigid motion that best explains moves ``d_i`` of the markers. Needs
    two markers or more."""
    n = len(poses)
    G = np.stack([T.inverse().AdjointMap() for T in poses])
    M = np.linalg.solve(np.einsum("nji,njk->ik", G, G), G.reshape(n * 3, 3).T)
    return G, M.reshape(3, n, 3).transpose(1, 0, 2)


def _positive(covariance: NDArray[np.float64]) -> NDArray[np.float64]:
    """Symmetric, with no variance below (10 micrometres)^2: a block of a projected matrix can
    be singular (two markers: the projection leaves three degrees of freedom for six)."""
    values, vectors = np.linalg.eigh(0.5 * (covariance + covariance.T))
    return (vectors * np.maximum(values, MIN_VARIANCE)) @ vectors.T


MIN_VARIANCE = 1e-10
