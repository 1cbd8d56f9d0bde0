"""Observation and motion models with their hand-derived Jacobians (shared by the graph and EKF).

An observation (bearing b, theta, range r) of a marker from the camera fixes the marker's pose in
the camera's horizontal frame completely (the polar-to-pose map)::

    T_camera_marker = (r cos b, r sin b, b + pi - theta)

because the ray from the marker back to the camera has direction ``b + pi`` in the camera's
frame and ``theta`` in the marker's.

Pose covariances follow GTSAM: 3x3 over the tangent (x, y, yaw) at the pose, perturbed on the
right (``T * Exp(xi)``), which is what ``BetweenFactorPose2`` noise models mean. The EKF works in
plain (x, y, yaw) coordinates of the map frame instead; its functions say so.
"""

from __future__ import annotations

import math

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.estimator.angles import wrap
from markergraph.estimator.types import Observation

__all__ = [
    "compose_covariance",
    "ekf_marker_init",
    "ekf_motion",
    "ekf_observation",
    "interpolate_pose",
    "invert_covariance",
    "observation_covariance",
    "observation_pose",
    "polar_to_pose_jacobian",
]

Matrix = NDArray[np.float64]


def observation_pose(obs: Observation) -> gtsam.Pose2:
    """``T_camera_marker`` from one observation."""
    b, r = obs.bearing, obs.range_m
    return gtsam.Pose2(r * math.cos(b), r * math.sin(b), wrap(b + math.pi - obs.theta))


def polar_to_pose_jacobian(bearing: float, range_m: float) -> Matrix:
    """d(x, y, yaw) of ``T_camera_marker`` / d(bearing, theta, range), in the camera's frame."""
    c, s = math.cos(bearing), math.sin(bearing)
    return np.array([[-range_m * s, 0.0, c], [range_m * c, 0.0, s], [1.0, -1.0, 0.0]])


def observation_covariance(obs: Observation) -> Matrix:
    """3x3 covariance of ``T_camera_marker`` in its own tangent space (GTSAM's convention)."""
    J = polar_to_pose_jacobian(obs.bearing, obs.range_m)
    sigma = np.diag([obs.sigma_bearing**2, obs.sigma_theta**2, obs.sigma_range**2])
    yaw = obs.bearing + math.pi - obs.theta
    # Right perturbation: a translation error in the camera's frame is R(yaw)^T times it in the
    # marker's own frame; the yaw error is the same in both.
    c, s = math.cos(yaw), math.sin(yaw)
    to_local = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    return to_local @ J @ sigma @ J.T @ to_local.T


def invert_covariance(T: gtsam.Pose2, covariance: Matrix) -> Matrix:
    """Covariance of ``T^-1`` given that of ``T`` (both right-perturbed): Ad(T) S Ad(T)^T."""
    ad = T.AdjointMap()
    return ad @ covariance @ ad.T


def compose_covariance(
    poses: list[gtsam.Pose2], covariances: list[Matrix]
) -> tuple[gtsam.Pose2, Matrix]:
    """``T_0 * T_1 * ... * T_n`` and its covariance, the factors independent.

    ``(T_0 Exp(e_0)) ... (T_n Exp(e_n)) = T Exp(sum_i Ad((T_{i+1} ... T_n)^-1) e_i)`` to first
    order, so each covariance is carried through the adjoint of what follows it.
    """
    total = np.zeros((3, 3))
    following = gtsam.Pose2()
    for pose, covariance in zip(reversed(poses), reversed(covariances), strict=True):
        ad = following.inverse().AdjointMap()
        total += ad @ covariance @ ad.T
        following = pose.compose(following)
    return following, total


def interpolate_pose(T0: gtsam.Pose2, T1: gtsam.Pose2, fraction: float) -> gtsam.Pose2:
    """SE(2) interpolation ``T0 * Exp(fraction * Log(T0^-1 T1))``: a constant-twist motion."""
    return T0.compose(gtsam.Pose2.Expmap(fraction * gtsam.Pose2.Logmap(T0.between(T1))))


# --- the EKF's models, in plain (x, y, yaw) coordinates of the map frame --------------------


def ekf_motion(robot: Matrix, delta: gtsam.Pose2) -> tuple[Matrix, Matrix, Matrix]:
    """Move the robot state (x, y, yaw) by an odometry increment given in the robot's frame.

    Returns:
        (new state, F = d new / d state, G = d new / d (dx, dy, dyaw)).
    """
    x, y, yaw = robot
    c, s = math.cos(yaw), math.sin(yaw)
    dx, dy, dyaw = delta.x(), delta.y(), delta.theta()
    new = np.array([x + c * dx - s * dy, y + s * dx + c * dy, wrap(yaw + dyaw)])
    F = np.array([[1.0, 0.0, -s * dx - c * dy], [0.0, 1.0, c * dx - s * dy], [0.0, 0.0, 1.0]])
    G = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return new, F, G


def _camera_in_map(robot: Matrix, T_base_camera: gtsam.Pose2) -> tuple[Matrix, float, Matrix]:
    """Camera position, heading, and d(position)/d(robot yaw)."""
    _, _, yaw = robot
    c, s = math.cos(yaw), math.sin(yaw)
    mx, my = T_base_camera.x(), T_base_camera.y()
    position = robot[:2] + np.array([c * mx - s * my, s * mx + c * my])
    d_position_d_yaw = np.array([-s * mx - c * my, c * mx - s * my])
    return position, robot[2] + T_base_camera.theta(), d_position_d_yaw


def ekf_observation(
    robot: Matrix, marker: Matrix, T_base_camera: gtsam.Pose2
) -> tuple[Matrix, Matrix, Matrix]:
    """Predicted (bearing, theta, range) of a marker and its Jacobians.

    Returns:
        (z, H_robot = dz / d robot (x, y, yaw), H_marker = dz / d marker (x, y, yaw)).
    """
    camera, camera_yaw, d_camera_d_yaw = _camera_in_map(robot, T_base_camera)
    delta = marker[:2] - camera
    range_sq = float(delta @ delta)
    range_m = math.sqrt(range_sq)
    direction = math.atan2(delta[1], delta[0])
    d_direction = np.array([-delta[1], delta[0]]) / range_sq  # d direction / d delta
    d_range = delta / range_m
    # d delta / d robot: -I on (x, y), -d camera / d yaw on yaw.
    d_delta_d_robot = np.column_stack([[-1.0, 0.0], [0.0, -1.0], -d_camera_d_yaw])
    z = np.array([wrap(direction - camera_yaw), wrap(direction + math.pi - marker[2]), range_m])
    H_robot = np.vstack(
        [
            d_direction @ d_delta_d_robot - np.array([0.0, 0.0, 1.0]),
            d_direction @ d_delta_d_robot,
            d_range @ d_delta_d_robot,
        ]
    )
    H_marker = np.array([[*d_direction, 0.0], [*d_direction, -1.0], [*d_range, 0.0]])
    return z, H_robot, H_marker


def ekf_marker_init(
    robot: Matrix, z: Matrix, T_base_camera: gtsam.Pose2
) -> tuple[Matrix, Matrix, Matrix]:
    """A newly seen marker's (x, y, yaw) from the robot state and its observation.

    Returns:
        (marker, G_robot = d marker / d robot, G_z = d marker / d (bearing, theta, range)).
    """
    camera, camera_yaw, d_camera_d_yaw = _camera_in_map(robot, T_base_camera)
    bearing, theta, range_m = z
    direction = camera_yaw + bearing
    c, s = math.cos(direction), math.sin(direction)
    marker = np.array(
        [camera[0] + range_m * c, camera[1] + range_m * s, wrap(direction + math.pi - theta)]
    )
    G_robot = np.array(
        [
            [1.0, 0.0, d_camera_d_yaw[0] - range_m * s],
            [0.0, 1.0, d_camera_d_yaw[1] + range_m * c],
            [0.0, 0.0, 1.0],
        ]
    )
    G_z = np.array([[-range_m * s, 0.0, c], [range_m * c, 0.0, s], [1.0, -1.0, 0.0]])
    return marker, G_robot, G_z
