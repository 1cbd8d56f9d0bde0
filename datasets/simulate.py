"""The fast simulator: (bearing, theta, range) observations straight from the geometry, no pixels.

Made for Monte Carlo studies of thousands of runs. Which markers are seen is decided as the
renderer would (corners inside the image, facing the camera, not behind a wall, large enough to
detect); what is measured is the exact value plus Gaussian noise from :class:`ObservationNoise`,
whose standard deviations the observations also carry, so the estimators weight them honestly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.datasets.route import Route, WheelErrors, drive
from markergraph.datasets.world import World
from markergraph.estimator.angles import wrap_array
from markergraph.estimator.types import Observation, OdometryNoise, OdometrySample
from markergraph.frontend.camera import Camera, CameraMount

# The simulated robot's camera: 0.6 m high, pitched up 10 degrees towards 1 m-high markers.
SIMULATED_MOUNT = CameraMount(x_m=0.1, height_m=0.6, pitch_rad=math.radians(10.0))

__all__ = [
    "SIMULATED_MOUNT",
    "MarkerGeometry",
    "ObservationNoise",
    "SimulatedRun",
    "Visibility",
    "simulate_fast",
    "visible_markers",
]


@dataclass(frozen=True, slots=True)
class ObservationNoise:
    """The fast mode's stated noise model (standard deviations).

    ``sigma_theta = theta_base + theta_per_m * range`` (the corner-based yaw degrades with
    distance as the marker shrinks in the image); ``sigma_range = range_base +
    range_per_m2 * range^2`` (structured-light depth error grows with the square of range).
    ``realised`` scales the noise actually drawn: 0 gives exact measurements that still carry
    the stated standard deviations, for noise-free tests with sane weights.
    """

    bearing: float = 0.002
    theta_base: float = math.radians(0.5)
    theta_per_m: float = math.radians(0.4)
    range_base: float = 0.004
    range_per_m2: float = 0.003
    realised: float = 1.0

    def sigmas(self, range_m: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
        """(sigma_bearing, sigma_theta, sigma_range) for each range."""
        return (
            np.full_like(range_m, self.bearing),
            self.theta_base + self.theta_per_m * range_m,
            self.range_base + self.range_per_m2 * range_m**2,
        )


@dataclass(frozen=True, slots=True)
class Visibility:
    """When a marker counts as seen.

    Attributes:
        margin_px: corners must lie this far inside the image [px].
        min_edge_px: the marker's shorter vertical edge must image at least this long [px].
        max_view_angle: largest |theta| at which the marker is still read [rad].
        max_range_m: farthest horizontal range [m].
    """

    margin_px: float = 4.0
    min_edge_px: float = 14.0
    max_view_angle: float = math.radians(70.0)
    max_range_m: float = 6.0


@dataclass
class SimulatedRun:
    """One simulated run with its ground truth.

    Attributes:
        world, route, camera, mount: what was simulated.
        frame_t_ns: (F,) camera frame stamps [ns].
        T_world_base_frames: (F, 3) true base poses at the frames (x, y, yaw) in the world.
        odometry: wheel odometry samples ``T_odom_base`` at ``odometry_hz``.
        odometry_truth: (N, 3) true base poses at the odometry stamps, in the world.
        observations: every observation, in time order.
        odometry_noise: the odometry noise model an estimator should assume.
    """

    world: World
    route: Route
    camera: Camera
    mount: CameraMount
    frame_t_ns: NDArray[np.int64]
    T_world_base_frames: NDArray[np.float64]
    odometry: list[OdometrySample]
    odometry_truth: NDArray[np.float64]
    observations: list[Observation]
    odometry_noise: OdometryNoise = field(default_factory=OdometryNoise)

    @property
    def T_map_world(self) -> gtsam.Pose2:
        return self.world.T_world_marker(self.world.home_id).inverse()

    def true_markers(self) -> dict[int, gtsam.Pose2]:
        """Marker id -> true ``T_map_marker``."""
        return self.world.T_map_markers()

    def true_trajectory(self) -> NDArray[np.float64]:
        """(F, 3) true base poses at the frames, in the map frame."""
        T_map_world = self.T_map_world
        rows = [T_map_world.compose(gtsam.Pose2(*p)) for p in self.T_world_base_frames]
        return np.array([[T.x(), T.y(), T.theta()] for T in rows])


@dataclass(frozen=True)
class MarkerGeometry:
    """A world's marker poses and corners as arrays, built once per run.

    Attributes:
        ids: (M,) marker ids.
        poses: (M, 3) ``T_world_marker`` rows (x, y, yaw).
        corners: (M, 4, 3) world corners in OpenCV's order.
    """

    ids: NDArray[np.int64]
    poses: NDArray[np.float64]
    corners: NDArray[np.float64]

    @classmethod
    def of(cls, world: World) -> MarkerGeometry:
        poses = [world.T_world_marker(m.id) for m in world.markers]
        return cls(
            np.array([m.id for m in world.markers], dtype=np.int64),
            np.array([[T.x(), T.y(), T.theta()] for T in poses]),
            np.array([world.marker_corners(m.id) for m in world.markers]),
        )


def visible_markers(
    world: World,
    camera: Camera,
    mount: CameraMount,
    T_world_base: gtsam.Pose2,
    visibility: Visibility = Visibility(),
    geometry: MarkerGeometry | None = None,
) -> list[int]:
    """Ids of the markers the camera sees whole from a base pose.

    Args:
        geometry: the world's :class:`MarkerGeometry`, to avoid rebuilding it on every call.
    """
    geometry = geometry or MarkerGeometry.of(world)
    T_world_camera = T_world_base.compose(mount.T_base_camera)
    p_camera = np.array([T_world_camera.x(), T_world_camera.y()])
    # The camera in every marker's frame: in front, in range, not too oblique.
    d = p_camera - geometry.poses[:, :2]
    c, s = np.cos(geometry.poses[:, 2]), np.sin(geometry.poses[:, 2])
    local_x, local_y = c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]
    candidates = np.flatnonzero(
        (local_x > 0.0)
        & (np.hypot(local_x, local_y) <= visibility.max_range_m)
        & (np.abs(np.arctan2(local_y, local_x)) <= visibility.max_view_angle)
    )
    if candidates.size == 0:
        return []
    corners = mount.world_to_optical(T_world_base, geometry.corners[candidates].reshape(-1, 3))
    in_front = np.all(corners[:, 2].reshape(-1, 4) >= 0.05, axis=1)
    pixels = camera.project(np.where(corners[:, 2:3] >= 0.05, corners, 1.0)).reshape(-1, 4, 2)
    m = visibility.margin_px
    inside = np.all(
        (pixels[..., 0] >= m)
        & (pixels[..., 0] <= camera.width - m)
        & (pixels[..., 1] >= m)
        & (pixels[..., 1] <= camera.height - m),
        axis=1,
    )
    left_edge = np.linalg.norm(pixels[:, 0] - pixels[:, 3], axis=1)
    right_edge = np.linalg.norm(pixels[:, 1] - pixels[:, 2], axis=1)
    large = np.minimum(left_edge, right_edge) >= visibility.min_edge_px
    seen = []
    for index in candidates[in_front & inside & large]:
        if not world.blocked(p_camera, geometry.poses[index, :2]):
            seen.append(int(geometry.ids[index]))
    return seen


def _exact_measurements(
    T_world_camera: gtsam.Pose2, T_world_marker: gtsam.Pose2
) -> tuple[float, float, float]:
    """(bearing, theta, range) of a marker from a camera's horizontal pose."""
    p_cam = T_world_camera.transformTo(T_world_marker.translation())
    p_marker = T_world_marker.transformTo(T_world_camera.translation())
    return (
        math.atan2(p_cam[1], p_cam[0]),
        math.atan2(p_marker[1], p_marker[0]),
        math.hypot(p_cam[0], p_cam[1]),
    )


def simulate_fast(
    world: World,
    route: Route,
    seed: int,
    *,
    camera: Camera = Camera(),
    mount: CameraMount = SIMULATED_MOUNT,
    noise: ObservationNoise = ObservationNoise(),
    wheel: WheelErrors = WheelErrors(),
    visibility: Visibility = Visibility(),
    frame_hz: float = 15.0,
    odometry_hz: float = 50.0,
    frame_phase: float = 0.5,
    duration_s: float | None = None,
) -> SimulatedRun:
    """Drive a route, record drifting wheel odometry and noisy observations.

    Args:
        world, route: the scenario.
        seed: seeds every random draw; the same seed gives the same run.
        frame_phase: where camera frames fall between odometry samples, as a fraction of the
            odometry period (0.5 by default, so readers must interpolate odometry; 0 with an
            odometry rate that is a multiple of the frame rate puts frames on samples).
        duration_s: cut the route short (default: the whole route).
    """
    rng = np.random.default_rng(seed)
    motion = drive(
        world,
        route,
        rng,
        wheel=wheel,
        frame_hz=frame_hz,
        odometry_hz=odometry_hz,
        frame_phase=frame_phase,
        duration_s=duration_s,
    )
    frame_t_ns, frame_poses = motion.frame_t_ns, motion.frame_poses
    marker_poses = {m.id: world.T_world_marker(m.id) for m in world.markers}
    geometry = MarkerGeometry.of(world)
    observations: list[Observation] = []
    for t_ns, pose in zip(frame_t_ns, frame_poses, strict=True):
        T_world_base = gtsam.Pose2(*pose)
        T_world_camera = T_world_base.compose(mount.T_base_camera)
        ids = visible_markers(world, camera, mount, T_world_base, visibility, geometry)
        if not ids:
            continue
        exact = np.array([_exact_measurements(T_world_camera, marker_poses[i]) for i in ids])
        sigmas = np.column_stack(noise.sigmas(exact[:, 2]))
        measured = exact + noise.realised * sigmas * rng.standard_normal(exact.shape)
        measured[:, :2] = wrap_array(measured[:, :2])
        for marker_id, (bearing, theta, range_m), (s_b, s_t, s_r) in zip(
            ids, measured, sigmas, strict=True
        ):
            observations.append(
                Observation(
                    int(t_ns),
                    marker_id,
                    float(bearing),
                    float(theta),
                    float(range_m),
                    float(s_b),
                    float(s_t),
                    float(s_r),
                )
            )
    return SimulatedRun(
        world,
        route,
        camera,
        mount,
        frame_t_ns,
        frame_poses,
        motion.odometry_samples(),
        motion.odometry_truth,
        observations,
    )
