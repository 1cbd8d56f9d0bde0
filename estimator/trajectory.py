"""Timed SE(2) paths: odometry, estimated and true trajectories alike, and the pose at a stamp."""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from markergraph.estimator.angles import wrap, wrap_array
from markergraph.estimator.types import OdometrySample

if TYPE_CHECKING:  # GTSAM loads with the first pose asked for: the front end's paths need none
    import gtsam

__all__ = [
    "MAX_EXTRAPOLATION_NS",
    "MAX_ODOMETRY_SPEED_MPS",
    "RATE_WINDOW_NS",
    "Trajectory",
    "corrected_odometry",
    "interpolated_xy_yaw",
    "interpolated_xy_yaws",
    "map_to_odom",
    "odometry_in_map",
    "turn_rate",
]

# Stamps this far outside a trajectory's time span still take its first or last pose.
MAX_EXTRAPOLATION_NS = 100_000_000
# Faster than a wheeled robot drives or a person walks with a rig: a step this fast between two
# odometry poses is a jump of the odometry itself.
MAX_ODOMETRY_SPEED_MPS = 5.0
RATE_WINDOW_NS = 20_000_000  # the turn rate is the odometry's heading change over +-this


@dataclass(frozen=True, eq=False)
class Trajectory:
    """The robot base's poses at increasing stamps, in one frame.

    Attributes:
        t_ns: (N,) int64 stamps, increasing [ns].
        poses: (N, 3) rows (x, y, yaw) of ``T_frame_base`` [m, m, rad].
        frame: the frame the poses are in (``"odom"`` for odometry, ``"map"`` for estimates and
            ground truth).
    """

    t_ns: NDArray[np.int64]
    poses: NDArray[np.float64]
    frame: str = "map"

    def __post_init__(self) -> None:
        t_ns = np.asarray(self.t_ns, dtype=np.int64).reshape(-1)
        poses = np.asarray(self.poses, dtype=np.float64).reshape(-1, 3)
        if len(t_ns) != len(poses):
            raise ValueError(f"{len(t_ns)} stamps for {len(poses)} poses")
        t_ns.flags.writeable = poses.flags.writeable = False
        object.__setattr__(self, "t_ns", t_ns)
        object.__setattr__(self, "poses", poses)

    @classmethod
    def from_samples(cls, samples: Iterable[OdometrySample], frame: str = "odom") -> Trajectory:
        """From odometry samples, sorted by stamp."""
        ordered = sorted(samples, key=lambda sample: sample.t_ns)
        return cls(
            np.array([s.t_ns for s in ordered], dtype=np.int64),
            np.array([[s.x, s.y, s.yaw] for s in ordered], dtype=np.float64),
            frame,
        )

    def __len__(self) -> int:
        return len(self.t_ns)

    def __eq__(self, other: object) -> bool:
        return (
            isinstance(other, Trajectory)
            and self.frame == other.frame
            and np.array_equal(self.t_ns, other.t_ns)
            and np.array_equal(self.poses, other.poses)
        )

    __hash__ = None  # type: ignore[assignment]  # mutable-looking arrays: not hashable

    def pose(self, i: int) -> gtsam.Pose2:
        """The i-th pose."""
        import gtsam

        return gtsam.Pose2(*self.poses[i])

    def at(self, t_ns: int, max_extrapolation_ns: int = MAX_EXTRAPOLATION_NS) -> gtsam.Pose2 | None:
        """The pose at ``t_ns``, interpolated in SE(2) (a constant twist between samples); the
        first or last pose up to ``max_extrapolation_ns`` outside the span; None beyond."""
        if not len(self):
            return None
        i = int(np.searchsorted(self.t_ns, t_ns))
        if i == 0:
            return self.pose(0) if self.t_ns[0] - t_ns <= max_extrapolation_ns else None
        if i == len(self):
            return self.pose(-1) if t_ns - self.t_ns[-1] <= max_extrapolation_ns else None
        from markergraph.estimator.models import interpolate_pose

        t0, t1 = self.t_ns[i - 1], self.t_ns[i]
        return interpolate_pose(self.pose(i - 1), self.pose(i), (t_ns - t0) / (t1 - t0))

    def at_xy_yaw(
        self, t_ns: int, max_extrapolation_ns: int = MAX_EXTRAPOLATION_NS
    ) -> tuple[float, float, float] | None:
        """:meth:`at` as ``(x, y, yaw)`` [m, m, rad], without GTSAM: ``markergraph detect``
        writes each observation's odometry pose and loads no solver for it."""
        if not len(self):
            return None
        i = int(np.searchsorted(self.t_ns, t_ns))
        if i == 0 or i == len(self):
            end = 0 if i == 0 else -1
            if abs(int(self.t_ns[end]) - t_ns) > max_extrapolation_ns:
                return None
            x, y, yaw = self.poses[end]
            return float(x), float(y), wrap(float(yaw))
        t0, t1 = self.t_ns[i - 1], self.t_ns[i]
        return interpolated_xy_yaw(self.poses[i - 1], self.poses[i], float((t_ns - t0) / (t1 - t0)))

    def xy_yaw_at(
        self, stamps_ns: NDArray[np.int64], max_extrapolation_ns: int = MAX_EXTRAPOLATION_NS
    ) -> NDArray[np.float64]:
        """:meth:`at` at many stamps at once, as (N, 3) rows (x, y, yaw) [m, m, rad]; rows of
        NaN where the path does not reach. One numpy pass: frames are built many times over
        in the delay and scale searches."""
        stamps = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
        poses = np.full((len(stamps), 3), np.nan)
        if not len(self):
            return poses
        i = np.searchsorted(self.t_ns, stamps)
        before, after = i == 0, i == len(self)
        near = np.where(before, self.t_ns[0] - stamps, stamps - self.t_ns[-1])
        for ends, row in ((before, 0), (after, -1)):
            kept = ends & (near <= max_extrapolation_ns)
            poses[kept] = self.poses[row]
            poses[kept, 2] = wrap_array(self.poses[row, 2])
        inside = np.flatnonzero(~before & ~after)
        k = i[inside]
        t0, t1 = self.t_ns[k - 1], self.t_ns[k]
        fraction = (stamps[inside] - t0) / (t1 - t0)
        poses[inside] = interpolated_xy_yaws(self.poses[k - 1], self.poses[k], fraction)
        return poses

    def at_stamps(self, stamps_ns: Iterable[int]) -> Trajectory:
        """This trajectory at the given stamps (those it does not reach are left out); a stamp
        of its own takes its pose as it is."""
        stamps = np.asarray(list(stamps_ns), dtype=np.int64)
        poses = np.full((len(stamps), 3), np.nan)
        if len(self) and len(stamps):
            i = np.minimum(np.searchsorted(self.t_ns, stamps), len(self) - 1)
            own = self.t_ns[i] == stamps
            poses[own] = self.poses[i[own]]  # no interpolation: most stamps asked are our own
        else:
            own = np.zeros(len(stamps), dtype=bool)
        for k in np.flatnonzero(~own):
            pose = self.at(int(stamps[k]))
            if pose is not None:
                poses[k] = pose.x(), pose.y(), pose.theta()
        kept = ~np.isnan(poses[:, 0])
        return Trajectory(stamps[kept], poses[kept].reshape(-1, 3), self.frame)

    def in_frame(self, T_new_frame: gtsam.Pose2, frame: str) -> Trajectory:
        """The same path expressed in another frame: ``T_new_base = T_new_frame * T_frame_base``."""
        row = np.array([[T_new_frame.x(), T_new_frame.y(), T_new_frame.theta()]])
        moved = _compose(np.repeat(row, len(self), axis=0), self.poses.reshape(-1, 3))
        return Trajectory(self.t_ns, moved, frame)

    def scaled(self, factor: float) -> Trajectory:
        """Every step's translation times ``factor``, headings kept: odometry whose wheels read
        ``1 / factor`` of the distance travelled. With headings unchanged this is the
        positions scaled about the first one."""
        poses = self.poses.copy()
        if len(self):
            poses[:, :2] = poses[0, :2] + factor * (poses[:, :2] - poses[0, :2])
        return Trajectory(self.t_ns, poses, self.frame)

    def turned(self, factor: float) -> Trajectory:
        """Every step's turn times ``factor``, each step's translation kept in the base's own
        frame: odometry whose track width is off (a diff-drive base reads every turn ``1 /
        factor`` of its true angle), the poses composed again from the first one."""
        if len(self) < 2 or factor == 1.0:
            return self
        poses = np.asarray(self.poses, dtype=np.float64)
        d = np.diff(poses[:, :2], axis=0)
        c, s = np.cos(poses[:-1, 2]), np.sin(poses[:-1, 2])
        forward, left = c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]
        dyaw = wrap_array(np.diff(poses[:, 2])) * factor
        heading = poses[0, 2] + np.concatenate([[0.0], np.cumsum(dyaw)])
        ch, sh = np.cos(heading[:-1]), np.sin(heading[:-1])
        x = poses[0, 0] + np.concatenate([[0.0], np.cumsum(ch * forward - sh * left)])
        y = poses[0, 1] + np.concatenate([[0.0], np.cumsum(sh * forward + ch * left)])
        return Trajectory(self.t_ns, np.column_stack([x, y, wrap_array(heading)]), self.frame)

    def jumps(self, max_speed_mps: float = MAX_ODOMETRY_SPEED_MPS) -> list[tuple[int, float]]:
        """Steps faster than ``max_speed_mps`` between consecutive poses, as (stamp of the pose
        after the step [ns], the step's length [m]): a visual-inertial reset or relocalisation,
        not motion."""
        if len(self) < 2:
            return []
        steps = np.hypot(*np.diff(self.poses[:, :2], axis=0).T)
        seconds = np.diff(self.t_ns) * 1e-9
        fast = np.flatnonzero(steps > max_speed_mps * seconds)
        return [(int(self.t_ns[i + 1]), float(steps[i])) for i in fast]

    def T_self_other(self, other: Trajectory, t_ns: int) -> gtsam.Pose2 | None:
        """The transform from ``other``'s frame into this one's at a stamp both reach: for an
        estimated path and odometry, ``T_map_odom``."""
        mine, theirs = self.at(t_ns), other.at(t_ns)
        if mine is None or theirs is None:
            return None
        return mine.compose(theirs.inverse())


def turn_rate(odometry: Trajectory, t_ns: int) -> float:
    """The odometry's heading rate about ``t_ns`` [rad/s]; 0 where it does not reach."""
    before = odometry.at(t_ns - RATE_WINDOW_NS)
    after = odometry.at(t_ns + RATE_WINDOW_NS)
    if before is None or after is None:
        return 0.0
    return before.between(after).theta() / (2 * RATE_WINDOW_NS * 1e-9)


def _compose(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Row-wise SE(2) products ``a * b`` of (N, 3) (x, y, yaw) rows."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    x = a[:, 0] + c * b[:, 0] - s * b[:, 1]
    y = a[:, 1] + s * b[:, 0] + c * b[:, 1]
    yaw = np.arctan2(np.sin(a[:, 2] + b[:, 2]), np.cos(a[:, 2] + b[:, 2]))
    return np.stack([x, y, yaw], axis=1)


def _inverse(a: NDArray[np.float64]) -> NDArray[np.float64]:
    """Row-wise SE(2) inverses of (N, 3) (x, y, yaw) rows."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    return np.stack([-c * a[:, 0] - s * a[:, 1], s * a[:, 0] - c * a[:, 1], -a[:, 2]], axis=1)


def map_to_odom(optimised: Trajectory, odometry: Trajectory) -> Trajectory:
    """``T_map_odom = T_map_base * T_odom_base^-1`` at each optimised stamp the odometry
    reaches."""
    odometry_there = odometry.at_stamps(optimised.t_ns)
    kept = np.isin(optimised.t_ns, odometry_there.t_ns)
    return Trajectory(
        optimised.t_ns[kept],
        _compose(optimised.poses[kept], _inverse(odometry_there.poses)),
        "map",
    )


def corrected_odometry(optimised: Trajectory, odometry: Trajectory) -> Trajectory:
    """The optimised path at the odometry's rate: the first optimised pose, every odometry
    sample between the first and the last optimised stamps moved into the map by the correction
    ``T_map_odom`` interpolated between the optimised poses either side, then the last
    optimised pose.

    The standard way (a ``map -> odom`` transform held between key frames): the odometry
    carries the shape of the path between detections, the graph where the robot was at each.

    Args:
        optimised: the estimate's poses ``T_map_base`` (at the frames' stamps).
        odometry: ``T_odom_base`` as the estimator used it (scaled).

    Returns:
        ``T_map_base`` at the odometry's stamps in the optimised span (frame ``"map"``); the
        optimised path itself when fewer than two of its stamps meet the odometry.
    """
    corrections = map_to_odom(optimised, odometry)
    if len(corrections) < 2:
        return optimised
    t_ns, poses = corrections.t_ns, corrections.poses
    inside = (odometry.t_ns > t_ns[0]) & (odometry.t_ns < t_ns[-1])
    stamps, odom = odometry.t_ns[inside], odometry.poses[inside]
    k = np.clip(np.searchsorted(t_ns, stamps, side="right") - 1, 0, len(t_ns) - 2)
    fraction = ((stamps - t_ns[k]) / (t_ns[k + 1] - t_ns[k]))[:, None]
    step = poses[k + 1] - poses[k]
    step[:, 2] = np.arctan2(np.sin(step[:, 2]), np.cos(step[:, 2]))  # the short way round
    # Linear in (x, y, yaw): consecutive corrections differ by millimetres and milliradians,
    # where this and SE(2)'s constant twist agree to well under a micrometre.
    correction = poses[k] + fraction * step
    ends = optimised.poses[np.isin(optimised.t_ns, t_ns[[0, -1]])]  # exact, not re-composed
    return Trajectory(
        np.concatenate([t_ns[:1], stamps, t_ns[-1:]]),
        np.concatenate([ends[:1], _compose(correction, odom), ends[-1:]]),
        "map",
    )


def odometry_in_map(optimised: Trajectory, odometry: Trajectory) -> Trajectory:
    """The raw odometry placed in the map by the first optimised pose, from that pose on: its
    drift shows against the corrected path.

    Returns:
        ``T_map_base`` (frame ``"map"``): the first optimised pose, then every odometry sample
        after it moved by ``T_map_odom`` at that stamp; empty when they never meet.
    """
    corrections = map_to_odom(optimised, odometry)
    if not len(corrections):
        return Trajectory(np.zeros(0, dtype=np.int64), np.zeros((0, 3)), "map")
    t0 = int(corrections.t_ns[0])
    after = odometry.t_ns > t0
    placed = _compose(np.repeat(corrections.poses[:1], int(after.sum()), axis=0),
                      odometry.poses[after])  # fmt: skip
    start = optimised.poses[optimised.t_ns == t0][:1]
    return Trajectory(
        np.concatenate([[t0], odometry.t_ns[after]]), np.concatenate([start, placed]), "map"
    )


def interpolated_xy_yaw(
    pose0: NDArray[np.float64], pose1: NDArray[np.float64], fraction: float
) -> tuple[float, float, float]:
    """GTSAM's ``T0 * Expmap(fraction * Logmap(T0^-1 * T1))`` on ``(x, y, yaw)`` poses, in closed
    form (gtsam/geometry/Pose2.cpp's ``Logmap`` and ``Expmap``; a straight line below 1e-10 rad)."""
    x0, y0, yaw0 = (float(v) for v in pose0)
    c0, s0 = math.cos(yaw0), math.sin(yaw0)
    dx, dy = float(pose1[0]) - x0, float(pose1[1]) - y0
    tx, ty = c0 * dx + s0 * dy, -s0 * dx + c0 * dy  # T1's position in T0's frame
    w = wrap(float(pose1[2]) - yaw0)
    if abs(w) < 1e-10:
        vx, vy = tx, ty
    else:  # Logmap: v = w / det * R(pi/2) (R(w)^-1 t - t)
        c, s = math.cos(w), math.sin(w)
        ux, uy = c * tx + s * ty - tx, -s * tx + c * ty - ty
        scale = w / ((c - 1.0) ** 2 + s * s)
        vx, vy = -uy * scale, ux * scale
    vx, vy, w = vx * fraction, vy * fraction, w * fraction
    if abs(w) < 1e-10:
        px, py = vx, vy
    else:  # Expmap: t = (v_ortho - R(w) v_ortho) / w, v_ortho = R(pi/2) v
        c, s = math.cos(w), math.sin(w)
        ox, oy = -vy, vx
        px, py = (ox - (c * ox - s * oy)) / w, (oy - (s * ox + c * oy)) / w
    return x0 + c0 * px - s0 * py, y0 + s0 * px + c0 * py, wrap(yaw0 + w)


def interpolated_xy_yaws(
    poses0: NDArray[np.float64], poses1: NDArray[np.float64], fractions: NDArray[np.float64]
) -> NDArray[np.float64]:
    """:func:`interpolated_xy_yaw` row by row over (N, 3) poses and (N,) fractions, as (N, 3)."""
    x0, y0, yaw0 = poses0[:, 0], poses0[:, 1], poses0[:, 2]
    c0, s0 = np.cos(yaw0), np.sin(yaw0)
    dx, dy = poses1[:, 0] - x0, poses1[:, 1] - y0
    tx, ty = c0 * dx + s0 * dy, -s0 * dx + c0 * dy
    w = wrap_array(poses1[:, 2] - yaw0)
    straight = np.abs(w) < 1e-10
    turning = np.where(straight, 1.0, w)  # no division by a zero turn; those rows are replaced
    c, s = np.cos(turning), np.sin(turning)
    ux, uy = c * tx + s * ty - tx, -s * tx + c * ty - ty
    scale = turning / ((c - 1.0) ** 2 + s * s)
    vx = np.where(straight, tx, -uy * scale) * fractions
    vy = np.where(straight, ty, ux * scale) * fractions
    w = w * fractions
    straight = np.abs(w) < 1e-10
    turning = np.where(straight, 1.0, w)
    c, s = np.cos(turning), np.sin(turning)
    ox, oy = -vy, vx
    px = np.where(straight, vx, (ox - (c * ox - s * oy)) / turning)
    py = np.where(straight, vy, (oy - (s * ox + c * oy)) / turning)
    return np.stack([x0 + c0 * px - s0 * py, y0 + s0 * px + c0 * py, wrap_array(yaw0 + w)], axis=1)
