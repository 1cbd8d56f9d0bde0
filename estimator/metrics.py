"""Error against ground truth: marker map, trajectory (absolute and per metre), NEES, chi-square."""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.estimator.angles import angle_diff, wrap_array
from markergraph.estimator.estimate import Estimate

__all__ = [
    "ELLIPSE_95_D2",
    "EllipseCoverage",
    "MapError",
    "TagErrors3d",
    "TrajectoryError",
    "align_rigid_2d",
    "align_rigid_3d",
    "chi2_interval",
    "ellipse_coverage",
    "map_error",
    "nees",
    "tag_errors_3d",
    "trajectory_error",
]

_Z_975 = 1.959963984540054  # standard normal quantile at 0.975


@dataclass(frozen=True)
class MapError:
    """Marker map error against ground truth.

    Attributes:
        marker_ids: (N,) the markers compared (those both estimated and known).
        position_m: (N,) position error of each [m].
        yaw_rad: (N,) absolute yaw error of each [rad].
        rmse_position_m, rmse_yaw_rad: their root mean squares.
        aligned: whether a rigid 2-D alignment was applied first.
    """

    marker_ids: NDArray[np.int64]
    position_m: NDArray[np.float64]
    yaw_rad: NDArray[np.float64]
    rmse_position_m: float
    rmse_yaw_rad: float
    aligned: bool


def align_rigid_2d(source_xy: NDArray[np.float64], target_xy: NDArray[np.float64]) -> gtsam.Pose2:
    """The rotation and translation (no scale) that best maps ``source`` onto ``target``
    in least squares (Kabsch/Umeyama), as a Pose2 ``T_target_source``."""
    source_mean, target_mean = source_xy.mean(axis=0), target_xy.mean(axis=0)
    covariance = (target_xy - target_mean).T @ (source_xy - source_mean)
    angle = math.atan2(covariance[1, 0] - covariance[0, 1], covariance[0, 0] + covariance[1, 1])
    c, s = math.cos(angle), math.sin(angle)
    translation = target_mean - np.array([[c, -s], [s, c]]) @ source_mean
    return gtsam.Pose2(translation[0], translation[1], angle)


def map_error(
    estimate: Estimate, truth: Mapping[int, gtsam.Pose2], align: bool = False
) -> MapError:
    """Per-marker and RMS error of an estimated map, in the home-marker frame or aligned.

    Args:
        truth: marker id -> true ``T_map_marker``.
        align: first apply the rigid 2-D alignment of estimated onto true positions.
    """
    ids = np.array(sorted(set(estimate.markers) & set(truth)), dtype=np.int64)
    if ids.size == 0:
        raise ValueError("no marker is both estimated and in the ground truth")
    estimated = [estimate.markers[int(i)].T_map_marker for i in ids]
    true = [truth[int(i)] for i in ids]
    if align:
        T = align_rigid_2d(
            np.array([[p.x(), p.y()] for p in estimated]), np.array([[p.x(), p.y()] for p in true])
        )
        estimated = [T.compose(p) for p in estimated]
    position = np.array(
        [math.hypot(e.x() - t.x(), e.y() - t.y()) for e, t in zip(estimated, true, strict=True)]
    )
    yaw = np.array(
        [abs(angle_diff(e.theta(), t.theta())) for e, t in zip(estimated, true, strict=True)]
    )
    return MapError(
        ids,
        position,
        yaw,
        float(np.sqrt(np.mean(position**2))),
        float(np.sqrt(np.mean(yaw**2))),
        align,
    )


@dataclass(frozen=True)
class TrajectoryError:
    """Trajectory error as evo computes it.

    Attributes:
        ate_rmse_m: absolute translation error RMSE in the map frame [m].
        ate_aligned_rmse_m: the same after a rigid 2-D alignment [m].
        rpe_rmse_m_per_m: relative translation error RMSE over 1 m segments [m per m].
        rpe_yaw_rmse_rad_per_m: relative yaw error RMSE over the same segments [rad per m].
        n_poses, n_segments: how many poses and segments were compared.
    """

    ate_rmse_m: float
    ate_aligned_rmse_m: float
    rpe_rmse_m_per_m: float
    rpe_yaw_rmse_rad_per_m: float
    n_poses: int
    n_segments: int


def _segment_ends(positions: NDArray[np.float64], delta_m: float) -> list[int]:
    """Where evo's ``filter_pairs_by_path`` cuts a path: the start, then each index at which
    the distance since the last cut reaches ``delta_m``."""
    ends, travelled = [0], 0.0
    steps = np.concatenate([[0.0], np.hypot(*np.diff(positions, axis=0).T)])
    for i, step in enumerate(steps):
        travelled += float(step)
        if travelled >= delta_m:
            ends.append(i)
            travelled = 0.0
    return ends


def trajectory_error(
    estimated: NDArray[np.float64], truth: NDArray[np.float64], delta_m: float = 1.0
) -> TrajectoryError:
    """ATE and RPE of an estimated trajectory against the true one at the same stamps.

    The RPE is evo's ``evo_rpe --delta 1 --delta_unit m`` (its defaults: consecutive pairs,
    cut on the estimated path): the estimated path is cut at its start and wherever the
    distance since the last cut reaches ``delta_m``, and each pair of consecutive cuts (i, j)
    gives the error of the relative motion i -> j. A path shorter than ``delta_m`` gives NaN.

    Args:
        estimated, truth: (N, 3) poses (x, y, yaw), row for row at the same stamps.
    """
    if estimated.shape != truth.shape or len(estimated) == 0:
        raise ValueError(
            f"trajectories must have one shape, got {estimated.shape} and {truth.shape}"
        )
    translation = np.hypot(*(estimated[:, :2] - truth[:, :2]).T)
    T = align_rigid_2d(estimated[:, :2], truth[:, :2])
    aligned = np.array([T.transformFrom(p) for p in estimated[:, :2]]).reshape(-1, 2)
    aligned_error = np.hypot(*(aligned - truth[:, :2]).T)
    rpe_t, rpe_yaw = [], []
    ends = _segment_ends(estimated[:, :2], delta_m)
    for i, j in itertools.pairwise(ends):
        est_rel = gtsam.Pose2(*estimated[i]).between(gtsam.Pose2(*estimated[j]))
        true_rel = gtsam.Pose2(*truth[i]).between(gtsam.Pose2(*truth[j]))
        error = true_rel.between(est_rel)
        rpe_t.append(math.hypot(error.x(), error.y()))
        rpe_yaw.append(error.theta())

    def rms(values: list[float] | NDArray[np.float64]) -> float:
        return float(np.sqrt(np.mean(np.square(values)))) if len(values) else float("nan")

    return TrajectoryError(
        rms(translation),
        rms(aligned_error),
        rms(rpe_t) / delta_m,
        rms(rpe_yaw) / delta_m,
        len(truth),
        len(rpe_t),
    )


def nees(
    estimated: NDArray[np.float64], covariances: NDArray[np.float64], truth: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Normalised estimation error squared of each pose: ``e^T P^-1 e``, e in (x, y, yaw).

    Args:
        estimated, truth: (N, 3) poses; covariances: (N, 3, 3) in the same plain coordinates.
    """
    error = truth - estimated
    error[:, 2] = wrap_array(error[:, 2])
    return np.einsum("ni,ni->n", error, np.linalg.solve(covariances, error[..., None])[..., 0])


def chi2_interval(dof: float, confidence: float = 0.95) -> tuple[float, float]:
    """Two-sided chi-square interval for ``dof`` degrees of freedom (Wilson-Hilferty).

    Accurate to well under 1% for dof >= 3, which is all the consistency checks need; divide by
    the number of averaged terms to bound a mean NEES or NIS.
    """
    if confidence != 0.95:
        raise ValueError("only the 95% interval is tabulated")
    spread = math.sqrt(2.0 / (9.0 * dof))
    return (
        dof * (1.0 - 2.0 / (9.0 * dof) - _Z_975 * spread) ** 3,
        dof * (1.0 - 2.0 / (9.0 * dof) + _Z_975 * spread) ** 3,
    )


# The 95 % quantile of chi-square with 2 dof, -2 ln(0.05): a 2-D Gaussian's 95 % ellipse.
ELLIPSE_95_D2 = -2.0 * math.log(0.05)
YAW_95_Z = 1.959963984540054  # the normal's two-sided 95 % bound


@dataclass(frozen=True)
class EllipseCoverage:
    """How many true markers lie inside an estimate's 95 % position ellipses.

    Attributes:
        marker_ids: (N,) the markers checked: estimated with a covariance, known to the truth,
            and not the home marker (the map frame itself, exact by definition).
        d2: (N,) each one's squared Mahalanobis distance of the true position from the
            estimated one under its 2x2 position covariance (2 dof).
        share: the fraction with ``d2`` at most :data:`ELLIPSE_95_D2` (NaN with none checked);
            0.95 for honest covariances, over many markers.
        sigma_max_m: (N,) the semi-major axis of each 1-sigma ellipse [m]: with ``share`` it
            tells honest ellipses from ones too wide to be of use.
        yaw_z: (N,) each one's yaw error over its yaw's sigma.
        yaw_share: the fraction with ``|yaw_z|`` at most :data:`YAW_95_Z` (NaN with none).
    """

    marker_ids: NDArray[np.int64]
    d2: NDArray[np.float64]
    share: float
    sigma_max_m: NDArray[np.float64]
    yaw_z: NDArray[np.float64]
    yaw_share: float


def ellipse_coverage(estimate: Estimate, truth: Mapping[int, gtsam.Pose2]) -> EllipseCoverage:
    """Which true markers fall inside the estimate's 95 % position ellipses, and their yaws
    inside their 95 % intervals.

    The covariance is GTSAM's (tangent space at the estimated pose, perturbed on the right), so
    the position error is taken in the estimated marker's frame before it is whitened.

    Args:
        estimate: markers with covariances (those without are skipped).
        truth: marker id -> true ``T_map_marker`` in the estimate's map frame (home's frame).
    """
    ids, d2, sigma_max, yaw_z = [], [], [], []
    for marker_id in sorted(set(estimate.markers) & set(truth)):
        marker = estimate.markers[marker_id]
        if marker.covariance is None or marker_id == estimate.home_id:
            continue
        error_local = marker.T_map_marker.rotation().unrotate(
            gtsam.Point2(*(truth[marker_id].translation() - marker.T_map_marker.translation()))
        )
        position_covariance = marker.covariance[:2, :2]
        ids.append(marker_id)
        d2.append(float(error_local @ np.linalg.solve(position_covariance, error_local)))
        sigma_max.append(math.sqrt(float(np.linalg.eigvalsh(position_covariance)[-1])))
        yaw_error = math.remainder(truth[marker_id].theta() - marker.T_map_marker.theta(), math.tau)
        yaw_z.append(yaw_error / math.sqrt(max(float(marker.covariance[2, 2]), 1e-300)))
    d2_array, yaw_z_array = np.array(d2), np.array(yaw_z)
    share = float(np.mean(d2_array <= ELLIPSE_95_D2)) if d2 else float("nan")
    yaw_share = float(np.mean(np.abs(yaw_z_array) <= YAW_95_Z)) if yaw_z else float("nan")
    return EllipseCoverage(
        np.array(ids, dtype=np.int64), d2_array, share, np.array(sigma_max), yaw_z_array, yaw_share
    )


def align_rigid_3d(source: NDArray[np.float64], target: NDArray[np.float64]) -> gtsam.Pose3:
    """The rotation and translation (no scale) that best maps ``source`` onto ``target`` in
    least squares (Kabsch/Umeyama), as a Pose3 ``T_target_source``.

    Args:
        source, target: (n, 3) matching points, n >= 3 and not all on one line.

    Raises:
        ValueError: shapes that differ or are not (n, 3), fewer than 3 points, or points on
            one line (the rotation about it is not determined).
    """
    source, target = np.asarray(source, dtype=float), np.asarray(target, dtype=float)
    if source.shape != target.shape or source.ndim != 2 or source.shape[1] != 3:
        raise ValueError(f"need two (n, 3) arrays, got {source.shape} and {target.shape}")
    if len(source) < 3:
        raise ValueError(f"a 3-D alignment needs 3 points or more, got {len(source)}")
    source_mean, target_mean = source.mean(axis=0), target.mean(axis=0)
    covariance = (target - target_mean).T @ (source - source_mean)
    U, singular, Vt = np.linalg.svd(covariance)
    if singular[1] <= 1e-12 * max(singular[0], 1e-300):
        raise ValueError("the points lie on one line: the rotation about it is not determined")
    # The sign fix keeps a proper rotation when the best orthogonal fit is a reflection.
    D = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(U @ Vt)) or 1.0)])
    R = U @ D @ Vt
    return gtsam.Pose3(gtsam.Rot3(R), target_mean - R @ source_mean)


@dataclass(frozen=True)
class TagErrors3d:
    """Each tag's 3-D error against a reference after the rigid alignment of the positions.

    Attributes:
        tag_ids: (N,) the tags compared (in both maps).
        position_m: (N,) position error of each after the alignment [m].
        rotation_rad: (N,) the angle of each tag's rotation error after the alignment [rad].
        T_reference_map: the alignment (the estimate's map frame in the reference's).
    """

    tag_ids: NDArray[np.int64]
    position_m: NDArray[np.float64]
    rotation_rad: NDArray[np.float64]
    T_reference_map: gtsam.Pose3

    @property
    def median_position_m(self) -> float:
        return float(np.median(self.position_m))

    @property
    def max_position_m(self) -> float:
        return float(np.max(self.position_m))

    @property
    def median_rotation_rad(self) -> float:
        return float(np.median(self.rotation_rad))

    @property
    def max_rotation_rad(self) -> float:
        return float(np.max(self.rotation_rad))


def tag_errors_3d(
    poses: Mapping[int, gtsam.Pose3], reference: Mapping[int, gtsam.Pose3]
) -> TagErrors3d:
    """Each tag's position and rotation error against the reference after the rigid 3-D
    alignment fitted on the positions alone (so a tag turned round shows, not aligned away).

    Args:
        poses, reference: tag id -> pose, both in the same tag convention.

    Raises:
        ValueError: fewer than 3 tags in common, or all on one line.
    """
    ids = np.array(sorted(set(poses) & set(reference)), dtype=np.int64)
    ours = [poses[int(i)] for i in ids]
    theirs = [reference[int(i)] for i in ids]
    T = align_rigid_3d(
        np.array([p.translation() for p in ours]).reshape(-1, 3),
        np.array([p.translation() for p in theirs]).reshape(-1, 3),
    )
    aligned = [T.compose(p) for p in ours]
    position = np.array(
        [
            np.linalg.norm(a.translation() - t.translation())
            for a, t in zip(aligned, theirs, strict=True)
        ]
    )
    rotation = np.array(
        [np.linalg.norm(gtsam.Rot3.Logmap(t.rotation().between(a.rotation())))
         for a, t in zip(aligned, theirs, strict=True)]
    )  # fmt: skip
    return TagErrors3d(ids, position, rotation, T)
