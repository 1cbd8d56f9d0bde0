"""Estimator inputs: validated observations grouped into frames, odometry interpolated at each."""

from __future__ import annotations

import math
from collections.abc import Collection, Iterable
from dataclasses import dataclass, field

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.common.errors import MarkerGraphError, RejectedObservationError
from markergraph.common.notes import Note
from markergraph.estimator.trajectory import Trajectory
from markergraph.estimator.types import Observation, OdometryNoise, OdometrySample
from markergraph.estimator.views import shared_over_views

__all__ = ["RELEASED_MOTION_COVARIANCE", "Frame", "Frames", "build_frames"]

# The motion across an odometry jump: metres and radians of doubt, next to which the jump
# itself weighs nothing.
RELEASED_MOTION_COVARIANCE = np.diag([100.0, 100.0, 10.0])


@dataclass(frozen=True)
class Frame:
    """The observations of one camera frame and the odometry pose at its stamp.

    Attributes:
        t_ns: the frame's stamp [ns].
        T_odom_base: the base's odometry pose at ``t_ns``.
        observations: the markers seen, at most one per id.
        odometry_covariance: covariance of the motion from the previous frame to this one (in
            its tangent space), composed over every odometry sample between them; zero for the
            first frame.
    """

    t_ns: int
    T_odom_base: gtsam.Pose2
    observations: tuple[Observation, ...]
    odometry_covariance: NDArray[np.float64]


@dataclass
class Frames:
    """Everything an estimator consumes.

    Attributes:
        frames: frames with observations, in time order.
        home_id: the marker whose frame is the map frame.
        home_frame: index of the first frame that sees the home marker.
        notes: what was dropped and why (kinds ``frames.*``).
    """

    frames: list[Frame]
    home_id: int
    home_frame: int
    notes: list[Note] = field(default_factory=list)

    def marker_ids(self) -> list[int]:
        """Every marker id observed, in order of first sight."""
        seen: dict[int, None] = {}
        for frame in self.frames:
            for obs in frame.observations:
                seen.setdefault(obs.marker_id, None)
        return list(seen)


def build_frames(
    observations: Iterable[Observation],
    odometry: Trajectory | Iterable[OdometrySample],
    home_id: int | None = None,
    marker_ids: Collection[int] | None = None,
    odometry_noise: OdometryNoise = OdometryNoise(),
    odometry_breaks: Collection[int] = (),
) -> Frames:
    """Validate observations, group them by stamp and attach the odometry pose at each stamp;
    theta's shared error is counted once a view (:func:`shared_over_views`).

    Args:
        observations: marker observations, any order.
        odometry: ``T_odom_base``: a trajectory, or samples in any order; at least one pose.
        home_id: the map's home marker (default: the first marker observed).
        marker_ids: if given, the only ids allowed; others are rejected.
        odometry_noise: the noise model of one odometry increment.
        odometry_breaks: stamps where the odometry jumped (``Trajectory.jumps``): the motion
            between the two frames around each is released (a switched-off factor, in effect),
            so the jump cannot bend the map; observations carry it across.

    Raises:
        RejectedObservationError: an observation is unusable (the message names it).
        MarkerGraphError: no odometry, no observation, or the home marker is never seen.
    """
    by_stamp = _by_stamp(shared_over_views(list(observations)), marker_ids)
    path = odometry if isinstance(odometry, Trajectory) else Trajectory.from_samples(odometry)
    if not len(path):
        raise MarkerGraphError("no odometry samples: the estimators need odometry")
    if not by_stamp:
        raise MarkerGraphError("no marker observations: nothing to map")
    frames, skipped, released = _frames_on(by_stamp, path, odometry_noise, odometry_breaks)
    if not frames:
        first, last = min(by_stamp), max(by_stamp)
        raise MarkerGraphError(
            f"none of the {len(by_stamp)} frames with markers (stamps {first} to {last} ns) "
            f"falls within the odometry's time span ({path.t_ns[0]} to {path.t_ns[-1]} ns): "
            "do the camera and odometry stamps come from different clocks?"
        )
    notes = []
    if released:
        notes.append(Note(
            "frames.odometry_released",
            f"odometry released across {released} jump(s): those steps' odometry factors carry "
            "no weight",
            figure=released,
        ))  # fmt: skip
    if skipped:
        notes.append(Note(
            "frames.outside_odometry",
            f"{skipped} frame(s) outside the odometry's time span were skipped",
            figure=skipped,
        ))  # fmt: skip
    home, home_frame = _home(frames, home_id)
    return Frames(frames, home, home_frame, notes)


def _by_stamp(
    observations: Iterable[Observation], marker_ids: Collection[int] | None
) -> dict[int, dict[int, Observation]]:
    """Validated observations by stamp, then by marker id (the nearer of two of one id).

    Raises:
        RejectedObservationError: an observation is unusable or of an id not allowed.
    """
    by_stamp: dict[int, dict[int, Observation]] = {}
    for obs in observations:
        obs.validate()
        if marker_ids is not None and obs.marker_id not in marker_ids:
            raise RejectedObservationError(
                f"observation at t_ns={obs.t_ns} has unknown marker id {obs.marker_id}"
            )
        # Two detections of one id in one frame: keep the nearer, it is the better measured.
        current = by_stamp.setdefault(obs.t_ns, {}).get(obs.marker_id)
        if current is None or obs.range_m < current.range_m:
            by_stamp[obs.t_ns][obs.marker_id] = obs
    return by_stamp


def _frames_on(
    by_stamp: dict[int, dict[int, Observation]],
    path: Trajectory,
    odometry_noise: OdometryNoise,
    odometry_breaks: Collection[int],
) -> tuple[list[Frame], int, int]:
    """The frames within the odometry's time span, each with the motion's covariance since the
    previous; (frames, how many were skipped, how many steps were released across a jump)."""
    stamps = np.array(sorted(by_stamp), dtype=np.int64)
    poses = path.xy_yaw_at(stamps)
    kept = ~np.isnan(poses[:, 0])
    stamps, poses = stamps[kept], poses[kept]
    covariances = motion_covariances(path, stamps, poses, odometry_noise)
    breaks = np.sort(np.fromiter(odometry_breaks, dtype=np.int64))
    passed = np.searchsorted(breaks, stamps, "right")  # breaks at or before each stamp
    across = np.diff(passed, prepend=passed[:1]) > 0  # a break in (previous, this]; none kept: none
    covariances[across] += RELEASED_MOTION_COVARIANCE
    frames = [
        Frame(int(t_ns), gtsam.Pose2(*pose), tuple(by_stamp[int(t_ns)].values()), covariance)
        for t_ns, pose, covariance in zip(stamps, poses, covariances, strict=True)
    ]
    return frames, int((~kept).sum()), int(across.sum())


def _home(frames: list[Frame], home_id: int | None) -> tuple[int, int]:
    """The home marker (given, or the first seen) and the first frame that sees it.

    Raises:
        MarkerGraphError: the home marker is never observed.
    """
    first_seen = next((obs.marker_id for f in frames for obs in f.observations), None)
    home = first_seen if home_id is None else home_id
    home_frame = next(
        (k for k, f in enumerate(frames) if any(o.marker_id == home for o in f.observations)),
        None,
    )
    if home is None or home_frame is None:
        raise MarkerGraphError(f"the home marker {home} is never observed: no map frame")
    return home, home_frame


def motion_covariance(poses: NDArray[np.float64], noise: OdometryNoise) -> NDArray[np.float64]:
    """Covariance of the odometry motion along ``poses`` ((n + 1, 3): x, y, yaw), composed
    increment by increment (:func:`~markergraph.estimator.models.compose_covariance`), so
    heading errors early in a long gap show up as lateral errors at its end.

    In closed form: a step's covariance diag(a, a, b) carried to the end by the adjoint of the
    motion after it is ``a diag(1, 1, 0) + b c c^T`` with ``c = (q_y, -q_x, 1)`` and ``q`` the
    step's end in the frame of the path's end, so the sum over steps is a few dot products (the
    step-by-step composition cost 4 s of a 10-minute log's 16 delay solves).
    """
    steps = np.diff(poses, axis=0)
    turn = np.abs(np.remainder(steps[:, 2] + np.pi, 2 * np.pi) - np.pi)
    a, b = noise.variances(np.hypot(steps[:, 0], steps[:, 1]), turn)
    c, s = math.cos(poses[-1, 2]), math.sin(poses[-1, 2])
    dx, dy = (poses[1:, 0] - poses[-1, 0]), (poses[1:, 1] - poses[-1, 1])
    qx, qy = c * dx + s * dy, -s * dx + c * dy
    bx, by = b @ qx, b @ qy
    return np.array([
        [a.sum() + b @ (qy * qy), -(b @ (qx * qy)), by],
        [-(b @ (qx * qy)), a.sum() + b @ (qx * qx), -bx],
        [by, -bx, b.sum()],
    ])  # fmt: skip


def motion_covariances(
    path: Trajectory,
    stamps_ns: NDArray[np.int64],
    poses: NDArray[np.float64],
    noise: OdometryNoise,
) -> NDArray[np.float64]:
    """:func:`motion_covariance` of the odometry between each pair of consecutive frames, all
    at once: (K, 3, 3), the first zero.

    Args:
        path: the odometry.
        stamps_ns: (K,) the frames' stamps, increasing [ns].
        poses: (K, 3) the odometry's poses at them (x, y, yaw).
    """
    covariances = np.zeros((len(stamps_ns), 3, 3))
    if len(stamps_ns) < 2:
        return covariances
    # Each gap's path: the pose before, the samples strictly between, the pose after; its
    # steps laid end to end, every gap at least one step long.
    first = np.searchsorted(path.t_ns, stamps_ns[:-1], "right")
    inside = np.searchsorted(path.t_ns, stamps_ns[1:], "left") - first
    counts = inside + 1
    gap = np.repeat(np.arange(len(counts)), counts)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    j = np.arange(len(gap)) - starts[gap]  # each step's place in its gap
    sample = np.minimum(first[gap] + j, len(path) - 1)
    ends = np.where((j < inside[gap])[:, None], path.poses[sample], poses[1:][gap])
    begins = np.where((j == 0)[:, None], poses[:-1][gap], path.poses[np.maximum(sample - 1, 0)])
    steps = ends - begins
    turn = np.abs(np.remainder(steps[:, 2] + np.pi, 2 * np.pi) - np.pi)
    a, b = noise.variances(np.hypot(steps[:, 0], steps[:, 1]), turn)
    last = poses[1:][gap]  # each gap's end
    c, s = np.cos(last[:, 2]), np.sin(last[:, 2])
    dx, dy = ends[:, 0] - last[:, 0], ends[:, 1] - last[:, 1]
    qx, qy = c * dx + s * dy, -s * dx + c * dy
    sums = np.add.reduceat(
        np.stack([a, b, b * qx, b * qy, b * qx * qx, b * qy * qy, b * qx * qy], axis=1), starts
    ).reshape(-1, 7)
    a_sum, b_sum, bx, by, bxx, byy, bxy = sums.T
    covariances[1:] = np.stack([
        np.stack([a_sum + byy, -bxy, by], axis=1),
        np.stack([-bxy, a_sum + bxx, -bx], axis=1),
        np.stack([by, -bx, b_sum], axis=1),
    ], axis=1)  # fmt: skip
    return covariances
