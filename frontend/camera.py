"""Pinhole camera intrinsics and the camera's mounting on the robot base."""

from __future__ import annotations

import math
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

__all__ = ["Camera", "CameraMount"]

# Optical frame (x right, y down, z forward) axes expressed in a level, forward-looking base frame
# (x forward, y left, z up): the columns are the optical x, y and z axes.
_R_LEVEL_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True, slots=True)
class Camera:
    """Pinhole intrinsics of an undistorted (or rectified) image.

    Attributes:
        fx, fy: focal lengths [px].
        cx, cy: principal point [px].
        width, height: image size [px].
    """

    fx: float = 615.0
    fy: float = 615.0
    cx: float = 320.0
    cy: float = 240.0
    width: int = 640
    height: int = 480

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
    """

    x_m: float = 0.1
    y_m: float = 0.0
    height_m: float = 0.6
    yaw_rad: float = 0.0
    pitch_rad: float = math.radians(10.0)

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
        return R_yaw @ R_pitch @ _R_LEVEL_OPTICAL

    def world_to_optical(
        self, T_world_base: gtsam.Pose2, p_world: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """Points (N, 3) in the world (z up from the floor) to the optical frame."""
        c, s = math.cos(T_world_base.theta()), math.sin(T_world_base.theta())
        d = p_world - np.array([T_world_base.x(), T_world_base.y(), 0.0])
        p_base = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2]])
        return (p_base - np.array([self.x_m, self.y_m, self.height_m])) @ self.R_base_optical
