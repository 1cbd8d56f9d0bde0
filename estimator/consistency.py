"""Is an odometry noise model honest? Odometry's motion over stretches of a path against a
reference path (ground truth, or a peer's optimised trajectory): each stretch's error, its NEES
under an :class:`OdometryNoise`, and the model that fits the errors best.

The model's covariance of a stretch is linear in its three variances (see
:meth:`OdometryNoise.covariance`, composed through :func:`compose_covariance`), so a stretch keeps
one 3x3 part per variance and any model's covariance is their weighted sum.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.estimator.models import compose_covariance
from markergraph.estimator.trajectory import Trajectory
from markergraph.estimator.types import OdometryNoise

__all__ = ["OdometryStretch", "fit_odometry_noise", "odometry_nees", "odometry_stretches"]

_PARTS = ("per_m", "yaw_per_m", "yaw_per_rad")


@dataclass(frozen=True)
class OdometryStretch:
    """Odometry's motion over one stretch of the path against the reference's.

    Attributes:
        t0_ns, t1_ns: the stretch's ends [ns].
        length_m: the reference's path length over it [m].
        error: (3,) ``Log(reference_motion^-1 * odometry_motion)`` (x, y, yaw) [m, m, rad].
        parts: (4, 3, 3) the stretch's covariance for a unit ``per_m``, ``yaw_per_m`` and
            ``yaw_per_rad`` variance each, and for the floors of ``OdometryNoise()``.
    """

    t0_ns: int
    t1_ns: int
    length_m: float
    error: NDArray[np.float64]
    parts: NDArray[np.float64]

    def covariance(self, noise: OdometryNoise) -> NDArray[np.float64]:
        """The stretch's covariance under ``noise`` (its floors taken as the default's)."""
        weights = np.array([noise.per_m**2, noise.yaw_per_m**2, noise.yaw_per_rad**2, 1.0])
        return np.einsum("k,kij->ij", weights, self.parts)


def _unit_models() -> list[OdometryNoise]:
    zero = {name: 0.0 for name in _PARTS}
    return [
        *(OdometryNoise(**{**zero, name: 1.0}, floor_m=0.0, floor_rad=0.0) for name in _PARTS),
        OdometryNoise(**zero),
    ]


def odometry_stretches(
    odometry: Trajectory,
    reference: Trajectory,
    stretch_m: float,
    breaks_ns: Sequence[int] = (),
) -> list[OdometryStretch]:
    """The reference path cut into consecutive stretches of at least ``stretch_m`` travelled,
    each compared with odometry over the same time span.

    Stretches holding an odometry break (a jump: see :meth:`Trajectory.jumps`) are left out,
    as the estimators release those steps.
    """
    if stretch_m <= 0:
        raise ValueError(f"stretch_m {stretch_m} must be positive")
    units = _unit_models()
    stretches: list[OdometryStretch] = []
    start, travelled = 0, 0.0
    for i in range(1, len(reference)):
        travelled += math.hypot(*(reference.poses[i, :2] - reference.poses[i - 1, :2]))
        if travelled < stretch_m:
            continue
        t0, t1 = int(reference.t_ns[start]), int(reference.t_ns[i])
        stretch = _stretch(odometry, reference.pose(start), reference.pose(i), t0, t1, units)
        if stretch is not None and not any(t0 < t <= t1 for t in breaks_ns):
            stretches.append(OdometryStretch(t0, t1, travelled, *stretch))
        start, travelled = i, 0.0
    return stretches


def _stretch(
    odometry: Trajectory,
    reference_start: gtsam.Pose2,
    reference_end: gtsam.Pose2,
    t0_ns: int,
    t1_ns: int,
    units: list[OdometryNoise],
) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    first, last = odometry.at(t0_ns), odometry.at(t1_ns)
    if first is None or last is None:
        return None
    inside = np.flatnonzero((odometry.t_ns > t0_ns) & (odometry.t_ns < t1_ns))
    poses = [first, *(odometry.pose(int(i)) for i in inside), last]
    steps = [a.between(b) for a, b in itertools.pairwise(poses)]
    parts = np.array(
        [compose_covariance(steps, [unit.covariance(s) for s in steps])[1] for unit in units]
    )
    motion = first.between(last)
    error = gtsam.Pose2.Logmap(reference_start.between(reference_end).between(motion))
    return np.asarray(error, dtype=np.float64), parts


def odometry_nees(
    stretches: Sequence[OdometryStretch], noise: OdometryNoise
) -> NDArray[np.float64]:
    """Each stretch's ``e^T P^-1 e`` under ``noise``: 3 on average when the model is honest."""
    return np.array([s.error @ np.linalg.solve(s.covariance(noise), s.error) for s in stretches])


def fit_odometry_noise(stretches: Sequence[OdometryStretch]) -> OdometryNoise:
    """The noise model under which the stretches' errors are most likely (Gaussian maximum
    likelihood, by coordinate search over each standard deviation on a log grid)."""
    if not stretches:
        raise ValueError("no stretches to fit a noise model to")
    errors = np.array([s.error for s in stretches])
    parts = np.array([s.parts for s in stretches])

    def cost(sigmas: NDArray[np.float64]) -> float:
        weights = np.append(sigmas**2, 1.0)
        covariances = np.einsum("k,nkij->nij", weights, parts)
        _, log_det = np.linalg.slogdet(covariances)
        whitened = np.linalg.solve(covariances, errors[..., None])[..., 0]
        return float(np.sum(log_det) + np.einsum("ni,ni->", errors, whitened))

    grid = np.geomspace(1e-5, 1.0, 201)
    sigmas = np.array(
        [OdometryNoise().per_m, OdometryNoise().yaw_per_m, OdometryNoise().yaw_per_rad]
    )
    for _ in range(4):
        for k in range(3):
            trial = np.repeat(sigmas[None], len(grid), axis=0)
            trial[:, k] = grid
            sigmas = trial[int(np.argmin([cost(t) for t in trial]))]
    return OdometryNoise(*(float(s) for s in sigmas))
