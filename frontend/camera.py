"""Pinhole camera intrinsics and the camera's mounting on the robot base."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import gtsam
import numpy as np
from numpy.typing import NDArray

__all__ = ["EQUIDISTANT", "PLUMB_BOB", "Camera", "CameraMount", "distortion_model"]

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
        points = np.asarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
        coefficients = np.array(self.distortion)
        if self.model == EQUIDISTANT:
            undistorted = cv2.fisheye.undistortPoints(points, self.K, coefficients, P=self.K)
        else:
            undistorted = cv2.undistortPoints(points, self.K, coefficients, P=self.K)
        return np.asarray(undistorted, dtype=np.float64).reshape(-1, 2)

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
            f"{self.x_m:.2f} m ahead, {self.y_m:.2f} m left, {self.height_m:.2f} m up, "
            f"pitched {math.degrees(self.pitch_rad):+.1f} deg"
        )
        if self.yaw_rad:
            words += f", turned {math.degrees(self.yaw_rad):+.1f} deg left"
        if self.roll_rad:
            words += f", rolled {math.degrees(self.roll_rad):+.1f} deg"
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
