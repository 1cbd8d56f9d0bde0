"""The tag views of one rig frame as one GTSAM factor: the corners' reprojection errors in
normalised image coordinates, through the rig's pose, each camera's mount on the rig and each
tag's pose.

The residual of view v is ``pi(T_camera_map * T_map_tag * c_i) - u_i`` over the tag's four
corners ``c_i`` (8 values a view), with ``pi(p) = (x/z, y/z)`` and ``T_map_camera = T_map_rig *
T_rig_camera``. The lens model was applied by the front end (the corners arrive undistorted, as
rays), so one factor serves pinhole, rational polynomial and fisheye cameras alike. Jacobians are
written out (GTSAM's right perturbation: rotation first, translation in the body frame) and
vectorised over every corner of the frame: the factor runs in Python, once a frame, not once a
corner.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.estimator.tags3d import tag_corners

__all__ = ["FrameViews", "adjoint_inverse", "frame_factor", "residuals"]


MIN_DEPTH_M = 1e-3
"""A corner's depth is taken as at least this: a guess that puts it behind the camera gives a
large error that a solver can step back from, not an infinite one."""


def _skew(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """(..., 3) vectors to (..., 3, 3) cross-product matrices."""
    out = np.zeros((*v.shape, 3))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    out[..., 1, 0], out[..., 2, 0], out[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return out


def adjoint_inverse(T: NDArray[np.float64]) -> NDArray[np.float64]:
    """(n, 4, 4) poses to the (n, 6, 6) adjoints of their inverses (rotation first)."""
    R_t = np.swapaxes(T[:, :3, :3], 1, 2)
    out = np.zeros((len(T), 6, 6))
    out[:, :3, :3] = out[:, 3:, 3:] = R_t
    out[:, 3:, :3] = -R_t @ _skew(T[:, :3, 3])
    return out


def residuals(
    T_map_camera: NDArray[np.float64],
    T_map_tag: NDArray[np.float64],
    corners: NDArray[np.float64],
    rays: NDArray[np.float64],
    jacobians: bool = False,
) -> tuple[NDArray[np.float64], NDArray[np.float64] | None, NDArray[np.float64] | None]:
    """Residuals (n, 8) of n views, and with ``jacobians`` their (n, 8, 6) derivatives with
    respect to each view's camera pose and tag pose.

    Args:
        T_map_camera, T_map_tag: (n, 4, 4) poses.
        corners: (n, 4, 3) each view's tag corners in the tag's frame.
        rays: (n, 4, 2) the corners seen.
    """
    Ra, ta = T_map_camera[:, :3, :3], T_map_camera[:, :3, 3]
    Rb, tb = T_map_tag[:, :3, :3], T_map_tag[:, :3, 3]
    # The corners in the camera, Ra^T (Rb c + tb - ta), as batched products (a tenth of
    # einsum's time on these small matrices).
    q = corners @ np.swapaxes(Rb, 1, 2) + (tb - ta)[:, None, :]
    p = q @ Ra
    inverse_z = 1.0 / np.maximum(p[..., 2], MIN_DEPTH_M)  # a corner behind: large, not infinite
    residual = (p[..., :2] * inverse_z[..., None] - rays).reshape(len(p), 8)
    if not jacobians:
        return residual, None, None
    D = np.zeros((*p.shape[:2], 2, 3))  # d pi / d p
    D[..., 0, 0] = D[..., 1, 1] = inverse_z
    D[..., 0, 2] = -p[..., 0] * inverse_z * inverse_z
    D[..., 1, 2] = -p[..., 1] * inverse_z * inverse_z
    # camera: dp = [p]x w - v; tag: dp = Ra^T Rb (-[c]x w + v)
    J_camera = np.concatenate([D @ _skew(p), -D], axis=3).reshape(len(p), 8, 6)
    M = D @ (np.swapaxes(Ra, 1, 2) @ Rb)[:, None, :, :]
    J_tag = np.concatenate([-M @ _skew(corners), M], axis=3).reshape(len(p), 8, 6)
    return residual, J_camera, J_tag


@dataclass(frozen=True)
class FrameViews:
    """One rig frame's views, laid out for its factor.

    Attributes:
        rig_key: the rig pose's key.
        tag_keys: each view's tag key.
        sizes: (n,) each view's tag side [m].
        rays: (n, 4, 2) the corners seen.
        sigmas: (n, 8) each view's ray noise, coordinate by coordinate.
        mounts: (n, 4, 4) each view's camera mount where fixed (unused rows where estimated).
        mount_keys: each view's mount key where estimated, else None.
    """

    rig_key: int
    tag_keys: list[int]
    sizes: NDArray[np.float64]
    rays: NDArray[np.float64]
    sigmas: NDArray[np.float64]
    mounts: NDArray[np.float64]
    mount_keys: list[int | None]

    def keys(self) -> list[int]:
        """The factor's keys: the rig, the estimated mounts, the tags (each once)."""
        estimated = [k for k in self.mount_keys if k is not None]
        return [self.rig_key, *dict.fromkeys(estimated), *dict.fromkeys(self.tag_keys)]

    def corners(self) -> NDArray[np.float64]:
        return np.array([tag_corners(s) for s in self.sizes])


def _mounts_now(views: FrameViews, values: gtsam.Values) -> NDArray[np.float64]:
    mounts = views.mounts.copy()
    for k, key in enumerate(views.mount_keys):
        if key is not None:
            mounts[k] = values.atPose3(key).matrix()
    return mounts


def _error(
    views: FrameViews,
    corners: NDArray[np.float64],
    this: gtsam.CustomFactor,
    values: gtsam.Values,
    H: list[NDArray[np.float64]] | None,
) -> NDArray[np.float64]:
    mounts = _mounts_now(views, values)
    rig = values.atPose3(views.rig_key).matrix()
    tags = np.array([values.atPose3(k).matrix() for k in views.tag_keys])
    residual, J_camera, J_tag = residuals(rig @ mounts, tags, corners, views.rays, H is not None)
    if H is not None and J_camera is not None and J_tag is not None:
        n = len(views.tag_keys)
        J_rig = J_camera @ adjoint_inverse(mounts)  # the rig moves each camera through its mount
        H[0] = J_rig.reshape(8 * n, 6)
        for slot, key in enumerate(this.keys()[1:], start=1):
            block = np.zeros((n, 8, 6))
            mine = np.array([m == key for m in views.mount_keys])
            block[mine] += J_camera[mine]
            tag = np.array([t == key for t in views.tag_keys])
            block[tag] += J_tag[tag]
            H[slot] = block.reshape(8 * n, 6)
    return residual.ravel()


def frame_factor(views: FrameViews, robust_k: float | None = None) -> gtsam.CustomFactor:
    """The factor of one rig frame's views; with ``robust_k``, a Cauchy kernel of that width
    (in sigmas) on the factor's whole error."""
    noise: Any = gtsam.noiseModel.Diagonal.Sigmas(views.sigmas.ravel())
    if robust_k is not None:
        noise = gtsam.noiseModel.Robust.Create(
            gtsam.noiseModel.mEstimator.Cauchy.Create(robust_k), noise
        )
    corners = views.corners()

    def evaluate(this: gtsam.CustomFactor, values: gtsam.Values, H: Any) -> Any:
        return _error(views, corners, this, values, H)

    return gtsam.CustomFactor(noise, views.keys(), evaluate)
