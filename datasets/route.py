"""Robot routes made of the paper's rotate-translate-rotate goals, and drifting wheel odometry."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from markergraph.datasets.world import World
from markergraph.estimator.angles import wrap, wrap_array
from markergraph.estimator.types import OdometrySample

__all__ = [
    "START_NS",
    "Drive",
    "GoTo",
    "Look",
    "Route",
    "RoutePlan",
    "WheelErrors",
    "drive",
    "plan",
    "wheel_odometry",
]

START_NS = 1_750_000_000_000_000_000  # a plausible wall-clock epoch for the first stamp


@dataclass(frozen=True, slots=True)
class GoTo:
    """Turn in place to face the point, then drive straight to it [m]."""

    x: float
    y: float


@dataclass(frozen=True, slots=True)
class Look:
    """Turn in place until the marker is centred, then pause to observe it [s]."""

    marker_id: int
    pause_s: float = 1.5


@dataclass(frozen=True)
class Route:
    """Where the robot starts and the goals it executes, ``laps`` times over.

    Attributes:
        start: (x, y, yaw) in the world [m, rad].
        steps: the goals of one lap.
        laps: how many times the steps are repeated.
        speed_mps, turn_rate_rps: driving speed [m/s] and turning rate [rad/s].
    """

    start: tuple[float, float, float]
    steps: tuple[GoTo | Look, ...]
    laps: int = 1
    speed_mps: float = 0.35
    turn_rate_rps: float = 0.6


@dataclass(frozen=True)
class RoutePlan:
    """A route's piecewise motion: each segment a pure turn, a straight drive or a pause.

    Attributes:
        t0_s: (S,) segment start times from the route's start [s].
        pose0: (S, 3) pose (x, y, yaw) at each segment's start.
        speed: (S,) forward speed [m/s].
        turn_rate: (S,) yaw rate [rad/s].
        duration_s: the whole route's duration [s].
    """

    t0_s: NDArray[np.float64]
    pose0: NDArray[np.float64]
    speed: NDArray[np.float64]
    turn_rate: NDArray[np.float64]
    duration_s: float

    def poses(self, t_s: NDArray[np.float64]) -> NDArray[np.float64]:
        """(N, 3) true poses (x, y, yaw) at times ``t_s`` [s] (clamped to the route)."""
        t = np.clip(np.asarray(t_s, dtype=np.float64), 0.0, self.duration_s)
        k = np.searchsorted(self.t0_s, t, side="right") - 1
        dt = t - self.t0_s[k]
        x0, y0, yaw0 = self.pose0[k].T
        # Segments never turn and drive at once, so a straight line or a turn in place is exact.
        dist = self.speed[k] * dt
        return np.column_stack(
            [
                x0 + dist * np.cos(yaw0),
                y0 + dist * np.sin(yaw0),
                wrap_array(yaw0 + self.turn_rate[k] * dt),
            ]
        )


def plan(world: World, route: Route) -> RoutePlan:
    """The trajectory a route drives in a world."""
    x, y, yaw = route.start
    t = 0.0
    segments: list[tuple[float, float, float, float, float, float]] = []

    def turn_to(target_yaw: float) -> None:
        nonlocal t, yaw
        turn = wrap(target_yaw - yaw)
        if abs(turn) > 1e-9:
            segments.append((t, x, y, yaw, 0.0, math.copysign(route.turn_rate_rps, turn)))
            t += abs(turn) / route.turn_rate_rps
        yaw = wrap(target_yaw)

    for _ in range(route.laps):
        for step in route.steps:
            if isinstance(step, GoTo):
                dist = math.hypot(step.x - x, step.y - y)
                if dist < 1e-9:
                    continue
                turn_to(math.atan2(step.y - y, step.x - x))
                segments.append((t, x, y, yaw, route.speed_mps, 0.0))
                t += dist / route.speed_mps
                x, y = step.x, step.y
            else:
                T_marker = world.T_world_marker(step.marker_id)
                turn_to(math.atan2(T_marker.y() - y, T_marker.x() - x))
                segments.append((t, x, y, yaw, 0.0, 0.0))
                t += step.pause_s
    segments.append((t, x, y, yaw, 0.0, 0.0))  # standing still at the end
    table = np.array(segments, dtype=np.float64)
    return RoutePlan(table[:, 0], table[:, 1:4], table[:, 4], table[:, 5], t)


@dataclass(frozen=True, slots=True)
class WheelErrors:
    """A differential-drive base's odometry errors, so it drifts as a real one does.

    Systematic errors are drawn once per run; random ones per step, growing with the square root
    of the step (a random walk).

    Attributes:
        scale_sigma: spread of the distance scale error (wheel radius) [1].
        yaw_scale_sigma: spread of the turn scale error (track width) [1].
        yaw_bias_sigma: spread of the heading bias per metre driven (wheel mismatch) [rad/m].
        distance_noise: random distance error [m per sqrt(m)].
        yaw_noise: random heading error [rad per sqrt(m + rad)].
    """

    scale_sigma: float = 0.01
    yaw_scale_sigma: float = 0.01
    yaw_bias_sigma: float = 0.004
    distance_noise: float = 0.005
    yaw_noise: float = 0.004


def wheel_odometry(
    true_poses: NDArray[np.float64], errors: WheelErrors, rng: np.random.Generator
) -> NDArray[np.float64]:
    """Integrate noisy increments of a true trajectory; (N, 3) poses in the odometry frame.

    Each increment is the true relative pose between two samples, its translation scaled and
    noised along the direction of travel, its turn scaled, biased and noised; the increments are
    then composed. With every error zero this reproduces the trajectory exactly. The odometry
    frame is where the base stood at the first sample.
    """
    scale = 1.0 + rng.normal(0.0, errors.scale_sigma)
    yaw_scale = 1.0 + rng.normal(0.0, errors.yaw_scale_sigma)
    yaw_bias = rng.normal(0.0, errors.yaw_bias_sigma)
    d_xy = np.diff(true_poses[:, :2], axis=0)
    yaw = true_poses[:-1, 2]
    c, s = np.cos(yaw), np.sin(yaw)
    forward = c * d_xy[:, 0] + s * d_xy[:, 1]  # the increment in the base's own frame
    left = -s * d_xy[:, 0] + c * d_xy[:, 1]
    dyaw = wrap_array(np.diff(true_poses[:, 2]))
    n = len(forward)
    distance = np.hypot(forward, left)
    stretch = scale + errors.distance_noise * rng.standard_normal(n) / np.sqrt(
        np.maximum(distance, 1e-12)
    )  # random walk: noise grows with sqrt(distance)
    forward_measured, left_measured = forward * stretch, left * stretch
    dyaw_measured = (
        dyaw * yaw_scale
        + yaw_bias * distance
        + errors.yaw_noise * np.sqrt(distance + np.abs(dyaw)) * rng.standard_normal(n)
    )
    heading = np.concatenate([[0.0], np.cumsum(dyaw_measured)])
    ch, sh = np.cos(heading[:-1]), np.sin(heading[:-1])
    x = np.concatenate([[0.0], np.cumsum(ch * forward_measured - sh * left_measured)])
    y = np.concatenate([[0.0], np.cumsum(sh * forward_measured + ch * left_measured)])
    return np.column_stack([x, y, wrap_array(heading)])


@dataclass(frozen=True)
class Drive:
    """A route driven: true poses, wheel odometry and camera frame stamps.

    Attributes:
        odometry_t_ns: (N,) odometry stamps [ns].
        odometry_truth: (N, 3) true base poses (x, y, yaw) in the world at those stamps.
        odometry: (N, 3) wheel odometry ``T_odom_base`` at those stamps.
        frame_t_ns: (F,) camera frame stamps [ns].
        frame_poses: (F, 3) true base poses in the world at the frames.
    """

    odometry_t_ns: NDArray[np.int64]
    odometry_truth: NDArray[np.float64]
    odometry: NDArray[np.float64]
    frame_t_ns: NDArray[np.int64]
    frame_poses: NDArray[np.float64]

    def odometry_samples(self) -> list[OdometrySample]:
        return [
            OdometrySample(int(t), float(x), float(y), float(yaw))
            for t, (x, y, yaw) in zip(self.odometry_t_ns, self.odometry, strict=True)
        ]


def drive(
    world: World,
    route: Route,
    rng: np.random.Generator,
    *,
    wheel: WheelErrors = WheelErrors(),
    frame_hz: float = 15.0,
    odometry_hz: float = 50.0,
    frame_phase: float = 0.5,
    duration_s: float | None = None,
) -> Drive:
    """Drive a route: sample the true trajectory, integrate drifting odometry, stamp frames.

    Args:
        frame_phase: where camera frames fall between odometry samples, as a fraction of the
            odometry period (0.5 by default, so readers must interpolate odometry; 0 with an
            odometry rate that is a multiple of the frame rate puts frames on samples).
        duration_s: cut the route short (default: the whole route).
    """
    trajectory = plan(world, route)
    duration = (
        trajectory.duration_s if duration_s is None else min(duration_s, trajectory.duration_s)
    )
    odometry_t_s = np.arange(0.0, duration + 1e-9, 1.0 / odometry_hz)
    odometry_truth = trajectory.poses(odometry_t_s)
    odometry = wheel_odometry(odometry_truth, wheel, rng)
    frame_t_s = np.arange(frame_phase / odometry_hz, duration, 1.0 / frame_hz)
    return Drive(
        START_NS + np.round(odometry_t_s * 1e9).astype(np.int64),
        odometry_truth,
        odometry,
        START_NS + np.round(frame_t_s * 1e9).astype(np.int64),
        trajectory.poses(frame_t_s),
    )
