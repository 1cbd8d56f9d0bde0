"""Transforms: the camera's mount from ``/tf_static``, and odometry from ``/tf``."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from markergraph.estimator.types import OdometrySample
from markergraph.frontend.camera import CameraMount
from markergraph.frontend.decode import stamp_ns
from markergraph.frontend.logs.records import LogError
from markergraph.frontend.ros2 import yaw_from_quaternion

__all__ = [
    "chain_between",
    "is_rotation",
    "mount_from_transforms",
    "odometry_from_tf",
    "parent_frame",
    "planar_pose",
    "rot_z",
    "rotation_of",
    "transform_between",
    "transforms_of",
]


def odometry_from_tf(
    decoded: Any, base_frame: str, odom_frame: str = "odom"
) -> list[OdometrySample]:
    """``T_odom_base`` samples from a ``/tf`` message's odom -> base transforms (for logs
    without an odometry topic)."""
    samples = []
    for transform in transforms_of(decoded):
        if transform.child_frame_id == base_frame and transform.header.frame_id == odom_frame:
            t, q = transform.transform.translation, transform.transform.rotation
            samples.append(
                OdometrySample(
                    stamp_ns(transform),
                    float(t.x),
                    float(t.y),
                    yaw_from_quaternion(q.x, q.y, q.z, q.w),
                )
            )
    return samples


def is_rotation(q: Any) -> bool:
    """Whether a quaternion (``x``, ``y``, ``z``, ``w``) stands for a rotation: finite and not
    zero (:func:`rotation_of` gives its matrix)."""
    squared = float(q.x) ** 2 + float(q.y) ** 2 + float(q.z) ** 2 + float(q.w) ** 2
    return math.isfinite(squared) and squared >= 1e-12


def rotation_of(q: Any) -> NDArray[np.float64] | None:
    """The rotation matrix of a quaternion, normalised; None if it is not finite or not a
    rotation at all (zero)."""
    if not is_rotation(q):
        return None
    x, y, z, w = (float(v) for v in (q.x, q.y, q.z, q.w))
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / norm, y / norm, z / norm, w / norm
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


@dataclass
class _TransformTree:
    """Static transforms parent -> child as (R, t)."""

    edges: dict[str, tuple[str, NDArray[np.float64], NDArray[np.float64]]] = field(
        default_factory=dict
    )

    def add(self, transform: Any) -> None:
        """A ROS ``TransformStamped`` or a Foxglove ``FrameTransform``."""
        if hasattr(transform, "transform"):
            parent, moved = transform.header.frame_id, transform.transform
            t, q = moved.translation, moved.rotation
        else:
            parent, t, q = transform.parent_frame_id, transform.translation, transform.rotation
        child = transform.child_frame_id
        R, offset = rotation_of(q), np.array([t.x, t.y, t.z], dtype=np.float64)
        if R is None or not np.all(np.isfinite(offset)):
            raise LogError(
                f"/tf_static: the transform {parent} -> {child} has a non-finite translation or "
                f"a rotation that is not one (quaternion {q.x}, {q.y}, {q.z}, {q.w})"
            )
        self.edges[child] = (parent, R, offset)

    def chain(self, base: str, frame: str) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(R, t) of ``frame`` in ``base``, or raise if they are not joined."""
        R, t = np.eye(3), np.zeros(3)
        current, visited = frame, [frame]
        while current != base:
            if current not in self.edges:
                raise LogError(f"/tf_static does not join {frame} to {base}")
            if self.edges[current][0] in visited:
                loop = " -> ".join([*visited[visited.index(self.edges[current][0]) :],
                                    self.edges[current][0]])  # fmt: skip
                raise LogError(f"/tf_static: frames {loop} form a loop")
            visited.append(self.edges[current][0])
            parent, R_parent_child, t_parent_child = self.edges[current]
            R, t = R_parent_child @ R, R_parent_child @ t + t_parent_child
            current = parent
        return R, t


def rot_z(angle: float) -> NDArray[np.float64]:
    """The rotation by ``angle`` [rad] about z."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def planar_pose(
    t: NDArray[np.float64], R: NDArray[np.float64], forward: NDArray[np.float64]
) -> tuple[float, float, float]:
    """A 3-D pose on the floor: (x, y, heading of the body's ``forward`` axis projected on it)."""
    f = R @ forward
    return float(t[0]), float(t[1]), math.atan2(f[1], f[0])


def transform_between(
    transforms: list[Any], base: str | Sequence[str | None], frame: str
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(R, t) of ``frame`` in ``base`` through a chain of static transforms, any depth; given
    several bases (None among them skipped), in the first that the chain reaches.

    Raises:
        LogError: the transforms do not join the frames, form a loop, or hold a value that is
            not a transform.
    """
    tree = _TransformTree()
    for transform in transforms:
        tree.add(transform)
    bases = [base] if isinstance(base, str) else list(dict.fromkeys(b for b in base if b))
    errors = []
    for candidate in bases:
        try:
            return tree.chain(candidate, frame)
        except LogError as error:
            errors.append(str(error))
    raise LogError("; ".join(errors) or f"no base frame to join {frame} to")


def parent_frame(transform: Any) -> str:
    """A ROS ``TransformStamped``'s or a Foxglove ``FrameTransform``'s parent frame."""
    if hasattr(transform, "transform"):
        return str(transform.header.frame_id)
    return str(transform.parent_frame_id)


def chain_between(
    transforms: list[Any], bases: Sequence[str | None], frame: str
) -> tuple[str, ...]:
    """The frames from the first of ``bases`` the static transforms join to ``frame``, base
    first: the chain :func:`transform_between` composes.

    Raises:
        LogError: as :func:`transform_between`: not joined, a loop, or a value that is not a
            transform.
    """
    errors = []
    for base in dict.fromkeys(b for b in bases if b):
        try:
            transform_between(transforms, base, frame)
        except LogError as error:
            errors.append(str(error))
            continue
        parents = {str(t.child_frame_id): parent_frame(t) for t in transforms}  # the last wins
        frames = [frame]
        while frames[-1] != base:
            frames.append(parents[frames[-1]])
        return tuple(reversed(frames))
    raise LogError("; ".join(errors) or f"no base frame to join {frame} to")


def mount_from_transforms(
    transforms: list[Any], base: str | Sequence[str | None], optical_frame: str
) -> CameraMount:
    """The camera's mount from ``/tf_static``: the chain from ``base`` (or the first of several
    it reaches) to the optical frame (x right, y down, z forward), its yaw, pitch and roll."""
    R, t = transform_between(transforms, base, optical_frame)
    return CameraMount.from_pose(R, t)


def transforms_of(decoded: Any) -> list[Any]:
    """The transforms a ``tf2_msgs/TFMessage``, Foxglove ``FrameTransforms`` or a single
    Foxglove ``FrameTransform`` carries."""
    return list(decoded.transforms) if hasattr(decoded, "transforms") else [decoded]
