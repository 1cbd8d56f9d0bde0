"""TUM trajectories (``t tx ty tz qx qy qz qw``, seconds), as evo reads them."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.common.errors import MarkerGraphError
from markergraph.common.files import written_whole
from markergraph.estimator.tags3d import quaternion_wxyz
from markergraph.estimator.trajectory import Trajectory

__all__ = ["read_tum", "write_tum", "write_tum_3d"]


def write_tum(path: Path, trajectory: Trajectory, comment: str | None = None) -> None:
    """A trajectory in TUM format, whole or not at all; non-finite poses are refused.

    Args:
        path: the file.
        trajectory: the poses, written in their own frame.
        comment: one header line (after ``# ``) saying what the file holds and in which frame;
            evo and :func:`read_tum` skip lines that begin with ``#``.

    Raises:
        MarkerGraphError: a pose is NaN or infinite (a bug upstream: never written).
    """
    if not np.all(np.isfinite(trajectory.poses)):
        raise MarkerGraphError(f"{path}: refusing to write a trajectory with non-finite poses")
    # Written a block of poses at a time, not joined first: odometry may hold millions of
    # poses, whose text as one string took some 250 bytes a pose.
    block = 1 << 16
    with written_whole(path) as partial, open(partial, "w", encoding="utf-8") as out:
        if comment is not None:
            out.write(f"# {' '.join(comment.split())}\n")  # one line, whatever it was given
        for start in range(0, len(trajectory), block):
            stamps = trajectory.t_ns[start : start + block].tolist()
            poses = trajectory.poses[start : start + block].tolist()
            out.write(
                "".join(
                    _tum_line(t, x, y, yaw) for t, (x, y, yaw) in zip(stamps, poses, strict=True)
                )
            )


def _tum_line(t_ns: int, x: float, y: float, yaw: float) -> str:
    """One planar pose as a TUM line, its stamp in exact decimal seconds."""
    half = yaw / 2.0
    seconds = f"{t_ns // 1_000_000_000}.{t_ns % 1_000_000_000:09d}"
    return f"{seconds} {x!r} {y!r} 0.0 0.0 0.0 {math.sin(half)!r} {math.cos(half)!r}\n"


def _seconds(t_ns: int) -> str:
    """Integer nanoseconds as exact decimal seconds."""
    sign = "-" if t_ns < 0 else ""
    return f"{sign}{abs(t_ns) // 1_000_000_000}.{abs(t_ns) % 1_000_000_000:09d}"


def write_tum_3d(path: Path, t_ns: NDArray[np.int64], poses: Sequence[gtsam.Pose3]) -> None:
    """A 3-D path (``T_map_rig`` at each stamp [ns]) in TUM format, ``t x y z qx qy qz qw``,
    whole or not at all; non-finite poses are refused.

    Raises:
        MarkerGraphError: a pose is NaN or infinite, or the stamps and poses differ in number.
    """
    if len(t_ns) != len(poses):
        raise MarkerGraphError(f"{path}: {len(t_ns)} stamps for {len(poses)} poses")
    lines = []
    for t, T in zip(t_ns, poses, strict=True):
        if not np.all(np.isfinite(T.matrix())):
            raise MarkerGraphError(f"{path}: refusing to write a trajectory with non-finite poses")
        p, (w, x, y, z) = T.translation(), quaternion_wxyz(T.rotation())
        values = (*p, x, y, z, w)
        lines.append(_seconds(int(t)) + "".join(f" {float(v)!r}" for v in values) + "\n")
    with written_whole(path) as partial:
        partial.write_text("".join(lines), encoding="utf-8")


def read_tum(path: Path, frame: str = "map") -> Trajectory:
    """A TUM trajectory's stamps [ns] and (x, y, yaw) poses (roll and pitch ignored).

    Raises:
        MarkerGraphError: a line that is not ``t tx ty tz qx qy qz qw``; it is named.
    """
    stamps, rows = [], []
    with open(path, encoding="utf-8") as stream:
        for number, line in enumerate(stream, start=1):
            if not line.strip() or line.startswith("#"):
                continue
            fields = line.split()
            if len(fields) != 8:
                raise MarkerGraphError(
                    f"{path}:{number}: a TUM line has 8 fields, not {len(fields)}"
                )
            whole, _, fraction = fields[0].partition(".")
            stamps.append(int(whole) * 1_000_000_000 + int((fraction + "000000000")[:9]))
            x, y, _, qx, qy, qz, qw = map(float, fields[1:])
            rows.append([x, y, math.atan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz))])
    return Trajectory(np.array(stamps, dtype=np.int64), np.array(rows).reshape(-1, 3), frame)
