"""The marker's yaw theta from its four corner pixels, four ways.

Conventions (README.md): theta is the camera's polar angle in the marker's frame, positive when
the camera stands to the marker's right as a viewer facing it sees it, where the marker's left
edge images shorter. With the paper's corner labels, a = top-left, b = bottom-left,
c = bottom-right, d = top-right (OpenCV's corners 0, 3, 2, 1).
"""

from __future__ import annotations

import math
from enum import Enum

import cv2
import numpy as np
from numpy.typing import NDArray

from markergraph.frontend.camera import Camera

__all__ = [
    "YawMethod",
    "marker_centre",
    "marker_object_points",
    "pnp_pose",
    "pnp_projection_jacobian",
    "pnp_solutions",
    "pnp_theta",
    "yaw_from_corners",
    "yaw_sigma",
]


class YawMethod(Enum):
    """How theta is computed from the corners."""

    PAPER = "paper"
    """The paper's formula: ``arccos(s_a / |y_a - y_b|)``, one vertical edge; no camera needed.
    Biased (the left edge is not the mean height) and without a solution for small theta of
    one sign, where s_a exceeds the left edge."""
    MEAN_EDGE = "mean-edge"
    """``arccos(s_a / mean vertical edge)``: exact for a level camera and a centred marker."""
    CALIBRATED = "calibrated"
    """MEAN_EDGE corrected for the marker's bearing (``cos theta = ratio * cos bearing``)."""
    PNP = "pnp"
    """OpenCV ``solvePnP`` with ``SOLVEPNP_IPPE_SQUARE`` and the marker's side length."""


def marker_centre(corners: NDArray[np.float64]) -> NDArray[np.float64]:
    """The marker centre's pixel: where the diagonals cross (exact under perspective)."""
    p0, p1, p2, p3 = corners
    d1, d2 = p2 - p0, p3 - p1
    denominator = d1[0] * d2[1] - d1[1] * d2[0]
    if abs(denominator) < 1e-12:
        return np.asarray(corners.mean(axis=0))
    t = ((p1[0] - p0[0]) * d2[1] - (p1[1] - p0[1]) * d2[0]) / denominator
    return np.asarray(p0 + t * d1)


def _edges(corners: NDArray[np.float64]) -> tuple[float, float, float]:
    """(s_a, left edge |y_a - y_b|, right edge |y_d - y_c|) of OpenCV-ordered corners."""
    top_left, top_right, bottom_right, bottom_left = corners
    s_a = (abs(top_left[0] - top_right[0]) + abs(bottom_right[0] - bottom_left[0])) / 2.0
    return s_a, abs(top_left[1] - bottom_left[1]), abs(top_right[1] - bottom_right[1])


def _signed(ratio: float, left: float, right: float) -> float:
    """The paper's sign rule applied to ``arccos(ratio)``; NaN when the ratio exceeds 1."""
    if ratio > 1.0:
        return math.nan
    magnitude = math.acos(max(-1.0, ratio))
    return magnitude if left < right else -magnitude


def yaw_from_corners(
    corners: NDArray[np.float64],
    method: YawMethod,
    camera: Camera | None = None,
    marker_length_m: float | None = None,
) -> float:
    """theta [rad] of one marker from its (4, 2) corners in OpenCV's order.

    Args:
        corners: undistorted pixel corners (top-left, top-right, bottom-right, bottom-left).
        method: see :class:`YawMethod`.
        camera: intrinsics, needed by CALIBRATED and PNP.
        marker_length_m: the black square's side, needed by PNP.

    Returns:
        theta, or NaN where the method has no solution (PAPER when s_a exceeds the left edge).

    Raises:
        ValueError: a method that needs the camera or marker length did not get it.
    """
    corners = np.asarray(corners, dtype=np.float64).reshape(4, 2)
    s_a, left, right = _edges(corners)
    if method is YawMethod.PAPER:
        return _signed(s_a / left, left, right)
    ratio = s_a / ((left + right) / 2.0)
    if method is YawMethod.MEAN_EDGE:
        return _signed(min(ratio, 1.0), left, right)
    if camera is None:
        raise ValueError(f"yaw method {method.value} needs the camera's intrinsics")
    if method is YawMethod.CALIBRATED:
        # Off-centre, s_a / mean edge = cos(theta) / cos(bearing) exactly, with the bearing of
        # the projective centre. The edges' difference follows sin(theta - bearing), not
        # sin(theta): pick the sign of theta whose predicted difference matches the measured.
        bearing = math.atan2(camera.cx - marker_centre(corners)[0], camera.fx)
        magnitude = math.acos(min(ratio * math.cos(bearing), 1.0))
        mean_edge = (left + right) / 2.0
        measured = (right - left) / mean_edge
        size = mean_edge / camera.fy  # about L / Z
        return min(
            (magnitude, -magnitude),
            key=lambda theta: abs(measured - size * math.sin(theta - bearing)),
        )
    if marker_length_m is None:
        raise ValueError("yaw method pnp needs the marker's side length")
    return pnp_theta(pnp_pose(corners, camera, marker_length_m))


def pnp_theta(pose: tuple[NDArray[np.float64], NDArray[np.float64]] | None) -> float:
    """theta [rad] from the marker's pose in the optical frame (:func:`pnp_pose`); NaN for
    none."""
    if pose is None:
        return math.nan
    R, t = pose
    camera_in_marker = -R.T @ t
    # Our marker frame (top view): +x = OpenCV z (the normal), +y = OpenCV x (viewer's right).
    return math.atan2(camera_in_marker[0], camera_in_marker[2])


def pnp_pose(
    corners: NDArray[np.float64], camera: Camera, marker_length_m: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """The marker's pose in the optical frame, (R (3, 3), t (3,) [m]), from its undistorted
    corners (OpenCV's order) by IPPE for squares; None if it finds none."""
    solutions = pnp_solutions(corners, camera, marker_length_m)
    return (solutions[0][1], solutions[0][2]) if solutions else None


def pnp_solutions(
    corners: NDArray[np.float64], camera: Camera, marker_length_m: float
) -> list[tuple[float, NDArray[np.float64], NDArray[np.float64]]]:
    """IPPE's poses of the marker for its undistorted corners, (reprojection error [px], R, t
    [m]) each, best first: a square's two planar poses, which explain the corners alike when
    it is small or seen face-on."""
    count, rvecs, tvecs, errors = cv2.solvePnPGeneric(
        marker_object_points(marker_length_m),
        corners,
        camera.K,
        None,
        flags=cv2.SOLVEPNP_IPPE_SQUARE,
    )
    found = []
    for i in range(count):
        R, _ = cv2.Rodrigues(rvecs[i])
        t = np.asarray(tvecs[i], dtype=np.float64).ravel()
        found.append((float(np.ravel(errors)[i]), np.asarray(R, dtype=np.float64), t))
    return sorted(found, key=lambda s: s[0])


def marker_object_points(marker_length_m: float) -> NDArray[np.float64]:
    half = marker_length_m / 2.0
    # OpenCV's marker frame: x to the viewer's right, y up, z out of the marker toward the viewer.
    return np.array(
        [[-half, half, 0.0], [half, half, 0.0], [half, -half, 0.0], [-half, -half, 0.0]]
    )


def pnp_projection_jacobian(
    R: NDArray[np.float64], t: NDArray[np.float64], camera: Camera, marker_length_m: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(rvec (3, 1), J (8, 6)): the marker's pose (R, t in the optical frame) as a rotation
    vector, and the Jacobian of its undistorted corners' pixels, (u0, v0, u1, ...), in
    (rvec, t), which ``projectPoints`` gives. PnP fits the pose to the corners by least
    squares, so their change du moves it by ``(J^T J)^-1 J^T du``."""
    rvec, _ = cv2.Rodrigues(R)
    _, jacobian = cv2.projectPoints(marker_object_points(marker_length_m), rvec, t, camera.K, None)
    return np.asarray(rvec, dtype=np.float64), np.asarray(jacobian[:, :6], dtype=np.float64)


def pnp_theta_sigma(
    pose: tuple[NDArray[np.float64], NDArray[np.float64]],
    camera: Camera,
    marker_length_m: float,
    corner_sigma_px: float,
) -> float:
    """Standard deviation of :func:`pnp_theta` for independent corner noise, from the one
    solve: PnP fits the pose to the corners by least squares, so its covariance is
    ``sigma^2 (J^T J)^-1`` with J the reprojection's Jacobian in the pose (``projectPoints``
    gives it), and theta's variance is ``g (J^T J)^-1 g^T`` with g theta's gradient in the
    pose. The same as perturbing each corner and solving again (:func:`yaw_sigma`), at one
    solve's cost instead of nine."""
    R, t = pose
    rvec, J = pnp_projection_jacobian(R, t, camera, marker_length_m)
    # theta = atan2(c_x, c_z) of the camera in the marker, c = -R^T t: its gradient in c, and
    # c's in the pose (Rodrigues gives R's entries, row by row, in rvec).
    c = -R.T @ t
    d_theta_d_c = np.array([c[2], 0.0, -c[0]]) / max(c[0] ** 2 + c[2] ** 2, 1e-300)
    d_R = cv2.Rodrigues(rvec)[1].reshape(3, 3, 3)  # [k, i, j] = dR[i, j] / d rvec[k]
    d_c = np.hstack([-np.einsum("kji,j->ik", d_R, t), -R.T])
    gradient = d_theta_d_c @ d_c
    try:
        variance = float(gradient @ np.linalg.solve(J.T @ J, gradient))
    except np.linalg.LinAlgError:
        return math.pi / 2
    sigma = corner_sigma_px * math.sqrt(max(variance, 0.0))
    return sigma if math.isfinite(sigma) else math.pi / 2


def yaw_sigma(
    corners: NDArray[np.float64],
    method: YawMethod,
    corner_sigma_px: float,
    camera: Camera | None = None,
    marker_length_m: float | None = None,
) -> float:
    """Standard deviation of theta for independent corner noise of ``corner_sigma_px``.

    Propagated through the method by forward differences (0.01 px steps, 9 evaluations), so
    every method gets the same honest treatment; near theta = 0 the arccos makes it large, as
    it should.
    """
    corners = np.asarray(corners, dtype=np.float64).reshape(4, 2)
    step = 0.01
    centre = yaw_from_corners(corners, method, camera, marker_length_m)
    gradient = np.zeros(8)
    for i in range(8):
        delta = np.zeros(8)
        delta[i] = step
        moved = yaw_from_corners(corners + delta.reshape(4, 2), method, camera, marker_length_m)
        gradient[i] = (moved - centre) / step
    sigma = corner_sigma_px * float(np.linalg.norm(gradient))
    return sigma if math.isfinite(sigma) else math.pi / 2
