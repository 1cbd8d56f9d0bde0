"""Pinhole camera intrinsics and the camera's mounting on the robot base."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from markergraph.common.numbers import shown

if TYPE_CHECKING:  # both load when first used: a settings file or --help reads none of them
    import gtsam

__all__ = [
    "EQUIDISTANT",
    "PLUMB_BOB",
    "Camera",
    "CameraMount",
    "distortion_model",
    "majority_camera",
]

# Optical frame (x right, y down, z forward) axes expressed in a level, forward-looking base frame
# (x forward, y left, z up): the columns are the optical x, y and z axes.
_R_LEVEL_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


# Distortion models, by the names CameraInfo and Kalibr give them.
PLUMB_BOB, EQUIDISTANT = "plumb_bob", "equidistant"
_MODELS = {
    "plumb_bob": PLUMB_BOB,
    "rational_polynomial": PLUMB_BOB,  # OpenCV's 8 coefficients: the same undistortion call
    "radtan": PLUMB_BOB,  # Kalibr's name
    "": PLUMB_BOB,
    "equidistant": EQUIDISTANT,  # fisheye (cv2.fisheye); Kalibr and CameraInfo agree
    "fisheye": EQUIDISTANT,
}


def distortion_model(name: str) -> str:
    """The model of a CameraInfo or Kalibr distortion name.

    Raises:
        ValueError: a model this reader does not undistort.
    """
    key = str(name).strip().lower()
    if key not in _MODELS:
        known = ", ".join(sorted(k for k in _MODELS if k))
        raise ValueError(f"distortion model {name!r} is not read (only {known})")
    return _MODELS[key]


@dataclass(frozen=True, slots=True)
class Camera:
    """Pinhole intrinsics, with their lens distortion.

    Attributes:
        fx, fy: focal lengths [px].
        cx, cy: principal point [px].
        width, height: image size [px].
        distortion: coefficients as OpenCV orders them for ``model``: (k1, k2, p1, p2[, k3,
            k4, k5, k6]) for plumb_bob and rational_polynomial, (k1, k2, k3, k4) for
            equidistant; empty for none.
        model: ``"plumb_bob"`` or ``"equidistant"`` (fisheye, ``cv2.fisheye``).
    """

    fx: float = 615.0
    fy: float = 615.0
    cx: float = 320.0
    cy: float = 240.0
    width: int = 640
    height: int = 480
    distortion: tuple[float, ...] = ()
    model: str = PLUMB_BOB

    @classmethod
    def from_camera_info(cls, info: Any) -> Camera:
        """From a decoded ``sensor_msgs/msg/CameraInfo`` (or Foxglove ``CameraCalibration``,
        whose fields are ``K``, ``D``)."""
        # ROS 2 names them k and d, ROS 1 and Foxglove K and D; rosbags gives numpy arrays, so
        # no truth tests on them.
        fields = [getattr(info, n, None) for n in ("k", "K", "d", "D")]
        k: list[float] = [float(v) for v in next((f for f in fields[:2] if f is not None), [])]
        d: list[float] = [float(v) for v in next((f for f in fields[2:] if f is not None), [])]
        if len(k) != 9 or not all(math.isfinite(v) for v in k) or not (k[0] > 0 and k[4] > 0):
            raise ValueError(f"camera info has no usable intrinsic matrix K: {k}")
        if not all(math.isfinite(v) for v in d):
            raise ValueError(f"camera info has a non-finite distortion coefficient D: {d}")
        model = distortion_model(getattr(info, "distortion_model", "") or "")
        distortion = tuple(float(v) for v in d) if any(v != 0.0 for v in d) else ()
        return cls(
            float(k[0]),
            float(k[4]),
            float(k[2]),
            float(k[5]),
            int(info.width),
            int(info.height),
            distortion,
            model,
        )

    @classmethod
    def from_kalibr(cls, entry: Any, source: str = "cameras.yaml") -> Camera:
        """From one camera of a Kalibr ``cameras.yaml`` (``intrinsics: [fx, fy, cx, cy]``,
        ``distortion_model``, ``distortion_coeffs``, ``resolution: [width, height]``).

        Raises:
            ValueError: a field is missing or not usable; the message names ``source``.
        """
        try:
            fx, fy, cx, cy = (float(v) for v in entry["intrinsics"])
            width, height = (int(v) for v in entry["resolution"])
            coefficients = tuple(float(v) for v in entry.get("distortion_coeffs") or ())
            model = distortion_model(entry.get("distortion_model", "") or "")
        except (KeyError, TypeError, ValueError) as error:
            raise ValueError(f"{source}: not a Kalibr camera ({error})") from None
        if not all(math.isfinite(v) for v in (fx, fy, cx, cy, *coefficients)) or min(fx, fy) <= 0:
            raise ValueError(f"{source}: unusable intrinsics {entry['intrinsics']}")
        distortion = coefficients if any(v != 0.0 for v in coefficients) else ()
        return cls(fx, fy, cx, cy, width, height, distortion, model)

    @classmethod
    def from_opencv_yaml(
        cls, path: str | Path, width: int | None = None, height: int | None = None
    ) -> Camera:
        """From an OpenCV calibration file (``camera_matrix``, ``distortion_coefficients``,
        optionally ``image_width``/``image_height``)."""
        import cv2

        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
        if not storage.isOpened():
            raise ValueError(f"{path}: not a readable OpenCV calibration file")
        try:
            K = storage.getNode("camera_matrix").mat()
            if K is None or K.shape != (3, 3):
                raise ValueError(f"{path}: no 3x3 camera_matrix")
            D = storage.getNode("distortion_coefficients").mat()
            width = width or int(storage.getNode("image_width").real() or 0)
            height = height or int(storage.getNode("image_height").real() or 0)
        finally:
            storage.release()
        distortion = () if D is None or not np.any(D) else tuple(float(v) for v in D.ravel())
        return cls(
            float(K[0, 0]),
            float(K[1, 1]),
            float(K[0, 2]),
            float(K[1, 2]),
            width or round(2 * K[0, 2]),
            height or round(2 * K[1, 2]),
            distortion,
        )

    def undistort(self, pixels: NDArray[np.float64]) -> NDArray[np.float64]:
        """Pixels (N, 2) as an undistorted camera with the same K would see them."""
        if not self.distortion:
            return np.asarray(pixels, dtype=np.float64)
        import cv2

        points = np.asarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
        coefficients = np.array(self.distortion)
        if self.model == EQUIDISTANT:
            undistorted = cv2.fisheye.undistortPoints(points, self.K, coefficients, P=self.K)
        else:
            undistorted = cv2.undistortPoints(points, self.K, coefficients, P=self.K)
        return np.asarray(undistorted, dtype=np.float64).reshape(-1, 2)

    def implausible(self) -> str | None:
        """Why this model cannot be the camera's, or None when it can: the image's own border
        (:data:`BORDER_POINTS` points on each edge) must undistort to finite rays, in order
        along each edge (a lens does not fold the image over), spanning a field of view of at
        least :data:`MIN_FOV_RAD`, and those rays must project back through the model onto the
        border within :data:`ROUND_TRIP_PX` (a model whose distortion throws the image's
        corners far outside it does neither)."""
        if self.width <= 0 or self.height <= 0:
            return None  # no image size to judge against (some old bags leave it 0)
        border = _border_pixels(self.width, self.height)
        if self.model == EQUIDISTANT:
            return self._implausible_fisheye(border)
        rays = self.rays(border)
        if not np.all(np.isfinite(rays)):
            return "its undistortion of the image's border is not finite"
        n = BORDER_POINTS
        top, bottom = rays[:n, 0], rays[n : 2 * n, 0]
        left, right = rays[2 * n : 3 * n, 1], rays[3 * n :, 1]
        if not all(np.all(np.diff(edge) > 0) for edge in (top, bottom, left, right)):
            return "its undistortion folds the image's border over (not monotone along an edge)"
        x = rays[:, 0]
        fov_rad = math.atan(float(x.max())) - math.atan(float(x.min()))
        if fov_rad < MIN_FOV_RAD:
            return f"a field of view of {math.degrees(fov_rad):.3g} deg across the image"
        back = self.distort(rays)
        miss_px = float(np.max(np.linalg.norm(back - border, axis=1)))
        if not math.isfinite(miss_px) or miss_px > ROUND_TRIP_PX:
            return (
                f"its distortion maps the image's border up to {miss_px:.3g} px from where it "
                "came from"
            )
        return None

    def _implausible_fisheye(self, border: NDArray[np.float64]) -> str | None:
        """:meth:`implausible` for the equidistant model, judged on its angles (a fisheye's
        corners may lie beyond 90 degrees, where a ray's x/z means nothing): the distorted
        angle ``theta_d = theta (1 + k1 theta^2 + ... + k4 theta^8)`` must rise with the true
        angle until it reaches the image's farthest border point, within 180 degrees."""
        k = np.zeros(4)
        k[: len(self.distortion)] = self.distortion[:4]
        theta = np.linspace(0.0, math.pi, 3601)
        t2 = theta * theta
        with np.errstate(all="ignore"):
            theta_d = theta * (1 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))))
            normal = (border - [self.cx, self.cy]) / [self.fx, self.fy]
            r_d = np.hypot(normal[:, 0], normal[:, 1])
        if not (np.all(np.isfinite(theta_d)) and np.all(np.isfinite(r_d))):
            return "its model of the image's border is not finite"
        beyond = np.flatnonzero(theta_d >= r_d.max())
        if not beyond.size or not np.all(np.diff(theta_d[: beyond[0] + 1]) > 0):
            return "its distortion does not reach the image's border with a lens that rises"
        x = normal[:, 0]
        fov_rad = float(np.interp(-x.min(), theta_d, theta) + np.interp(x.max(), theta_d, theta))
        if fov_rad < MIN_FOV_RAD:
            return f"a field of view of {math.degrees(fov_rad):.3g} deg across the image"
        return None

    def rays(self, pixels: NDArray[np.float64]) -> NDArray[np.float64]:
        """Pixels (N, 2) to normalised rays (N, 2): x/z and y/z in the optical frame."""
        import cv2

        points = np.asarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
        coefficients = np.array(self.distortion)
        with np.errstate(all="ignore"):
            if not self.distortion:
                out = cv2.undistortPoints(points, self.K, None)
            elif self.model == EQUIDISTANT:
                out = cv2.fisheye.undistortPoints(points, self.K, coefficients)
            else:
                out = cv2.undistortPoints(points, self.K, coefficients)
        return np.asarray(out, dtype=np.float64).reshape(-1, 2)

    def distort(self, rays: NDArray[np.float64]) -> NDArray[np.float64]:
        """Normalised rays (N, 2) to pixels (N, 2) through the lens model."""
        import cv2

        points = np.column_stack([rays, np.ones(len(rays))]).reshape(-1, 1, 3)
        coefficients = np.array(self.distortion) if self.distortion else np.zeros(4)
        zero = np.zeros(3)
        with np.errstate(all="ignore"):
            if self.model == EQUIDISTANT and self.distortion:
                out, _ = cv2.fisheye.projectPoints(points, zero, zero, self.K, coefficients)
            else:
                out, _ = cv2.projectPoints(points, zero, zero, self.K, coefficients)
        return np.asarray(out, dtype=np.float64).reshape(-1, 2)

    def key(self) -> tuple[object, ...]:
        """What two messages must share to describe the same camera (to 9 digits)."""
        return (
            self.model,
            self.width,
            self.height,
            *(float(f"{v:.9g}") for v in (self.fx, self.fy, self.cx, self.cy, *self.distortion)),
        )

    @property
    def K(self) -> NDArray[np.float64]:
        """The 3x3 intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def project(self, p_optical: NDArray[np.float64]) -> NDArray[np.float64]:
        """Pixels (N, 2) of points (N, 3) in the optical frame; callers check z > 0 themselves."""
        z = p_optical[:, 2]
        return np.column_stack(
            [self.fx * p_optical[:, 0] / z + self.cx, self.fy * p_optical[:, 1] / z + self.cy]
        )


BORDER_POINTS = 9  # points along each edge of the image that a model is judged on
MIN_FOV_RAD = math.radians(1.0)  # narrower than any lens a robot maps with
ROUND_TRIP_PX = 1.0  # undistorting then distorting the border returns it within this


def _border_pixels(width: int, height: int) -> NDArray[np.float64]:
    """:data:`BORDER_POINTS` pixels along the top, bottom, left and right edges, in order of
    increasing u (top, bottom) or v (left, right); pixel centres 0 .. size - 1."""
    u = np.linspace(0.0, width - 1.0, BORDER_POINTS)
    v = np.linspace(0.0, height - 1.0, BORDER_POINTS)
    zeros_u, zeros_v = np.zeros_like(u), np.zeros_like(v)
    return np.vstack([
        np.column_stack([u, zeros_u]),
        np.column_stack([u, zeros_u + height - 1.0]),
        np.column_stack([zeros_v, v]),
        np.column_stack([zeros_v + width - 1.0, v]),
    ])  # fmt: skip


def majority_camera(
    cameras: list[Camera | str],
) -> tuple[Camera | None, dict[str, int]]:
    """The camera model most of a topic's messages give, among those that can be a camera
    (:meth:`Camera.implausible`), and why the others were set aside: reason -> count.

    Args:
        cameras: each message's model, or why it gave none (it did not parse).
    """
    set_aside: Counter[str] = Counter()
    groups: dict[tuple[object, ...], list[Camera]] = {}
    for camera in cameras:
        if isinstance(camera, str):
            set_aside[camera] += 1
            continue
        reason = camera.implausible()
        if reason is not None:
            set_aside[reason] += 1
            continue
        groups.setdefault(camera.key(), []).append(camera)
    if not groups:
        return None, dict(set_aside)
    ranked = sorted(groups.values(), key=len, reverse=True)
    for other in ranked[1:]:
        set_aside["it disagrees with the majority's model"] += len(other)
    return ranked[0][0], dict(set_aside)


@dataclass(frozen=True, slots=True)
class CameraMount:
    """Where the camera sits on the robot base (x forward, y left, z up from the floor).

    Attributes:
        x_m, y_m: optical centre's position on the base [m].
        height_m: optical centre's height above the floor [m].
        yaw_rad: optical axis' heading relative to the base's x axis [rad].
        pitch_rad: optical axis' elevation above the horizontal [rad], positive tilted up.
        roll_rad: the camera's roll about the base's forward axis after yaw and pitch
            (right-handed: positive lifts its left side) [rad]; zero on most robots.
    """

    x_m: float = 0.1
    y_m: float = 0.0
    height_m: float = 0.6
    yaw_rad: float = 0.0
    pitch_rad: float = 0.0
    roll_rad: float = 0.0

    @property
    def T_base_camera(self) -> gtsam.Pose2:
        """The camera's horizontal (top-view) pose on the base."""
        import gtsam

        return gtsam.Pose2(self.x_m, self.y_m, self.yaw_rad)

    @property
    def R_base_optical(self) -> NDArray[np.float64]:
        """Rotation of the optical frame in the base frame."""
        cy, sy = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        cp, sp = math.cos(self.pitch_rad), math.sin(self.pitch_rad)
        R_yaw = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
        # Positive pitch lifts the forward axis: a rotation of -pitch about the base's y (left).
        R_pitch = np.array([[cp, 0.0, -sp], [0.0, 1.0, 0.0], [sp, 0.0, cp]])
        cr, sr = math.cos(self.roll_rad), math.sin(self.roll_rad)
        R_roll = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
        return R_yaw @ R_pitch @ R_roll @ _R_LEVEL_OPTICAL

    def describe(self) -> str:
        """The mount in plain words and units, for notes."""
        words = (
            f"{shown(self.x_m, '.2f')} m ahead, {shown(self.y_m, '.2f')} m left, "
            f"{shown(self.height_m, '.2f')} m up, "
            f"pitched {shown(math.degrees(self.pitch_rad), '+.1f')} deg"
        )
        if self.yaw_rad:
            words += f", turned {shown(math.degrees(self.yaw_rad), '+.1f')} deg left"
        if self.roll_rad:
            words += f", rolled {shown(math.degrees(self.roll_rad), '+.1f')} deg"
        return words

    @property
    def t_base_optical(self) -> NDArray[np.float64]:
        """The optical centre in the base frame [m]."""
        return np.array([self.x_m, self.y_m, self.height_m])

    @classmethod
    def from_pose(
        cls, R_base_optical: NDArray[np.float64], t_base_optical: NDArray[np.float64]
    ) -> CameraMount:
        """The mount of a camera whose optical frame sits at ``(R, t)`` on the base."""
        M = R_base_optical @ _R_LEVEL_OPTICAL.T  # yaw, then pitch (about -y), then roll (x)
        return cls(
            x_m=float(t_base_optical[0]),
            y_m=float(t_base_optical[1]),
            height_m=float(t_base_optical[2]),
            yaw_rad=math.atan2(M[1, 0], M[0, 0]),
            pitch_rad=math.asin(max(-1.0, min(1.0, float(M[2, 0])))),
            roll_rad=math.atan2(M[2, 1], M[2, 2]),
        )

    def world_to_optical(
        self, T_world_base: gtsam.Pose2, p_world: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """Points (N, 3) in the world (z up from the floor) to the optical frame."""
        c, s = math.cos(T_world_base.theta()), math.sin(T_world_base.theta())
        d = p_world - np.array([T_world_base.x(), T_world_base.y(), 0.0])
        p_base = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2]])
        return (p_base - np.array([self.x_m, self.y_m, self.height_m])) @ self.R_base_optical
