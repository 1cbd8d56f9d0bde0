"""Fixed-layout CDR readers for the few high-rate ROS 2 messages the front end reads.

mcap-ros2-support decodes any message from its schema, in Python, field by field: about 0.25 ms
for an odometry message, as long as detecting markers in a 640x480 frame when a log has a
hundred of them per frame. These readers know their layouts and produce objects with the same
attribute names (``header.stamp.sec``, ``data``, ...), but an image's ``data`` is a read-only
``memoryview`` into its chunk, not ``bytes``; every other type still goes through
mcap-ros2-support.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from types import SimpleNamespace
from typing import Any

__all__ = ["FAST_DECODERS"]


class _Reader:
    """Reads CDR primitives with alignment counted from after the 4-byte encapsulation."""

    def __init__(self, data: bytes | memoryview) -> None:
        self.data = memoryview(data)
        if len(self.data) < 4:
            raise ValueError("shorter than a CDR encapsulation header")
        self.prefix = "<" if self.data[1] & 1 else ">"
        self.offset = 4

    def _align(self, size: int) -> None:
        self.offset += (-(self.offset - 4)) % size

    def unpack(self, code: str, size: int, count: int = 1) -> tuple[Any, ...]:
        self._align(size)
        values = struct.unpack_from(f"{self.prefix}{count}{code}", self.data, self.offset)
        self.offset += size * count
        return values

    def uint32(self) -> int:
        return int(self.unpack("I", 4)[0])

    def string(self) -> str:
        length = self.uint32()  # includes the terminating NUL
        end = self.offset + length
        if end > len(self.data):
            raise ValueError("a string runs past the end of the message")
        text = bytes(self.data[self.offset : end - 1]).decode("utf-8")
        self.offset = end
        return text

    def byte_array(self) -> memoryview:
        length = self.uint32()
        end = self.offset + length
        if end > len(self.data):
            raise ValueError("a byte array runs past the end of the message")
        # A view, not a copy: a D435i's raw depth is 0.6 MB a frame, and copying it held the
        # GIL the pool's threads wait on. It keeps its chunk alive while it is held.
        data = self.data[self.offset : end].toreadonly()
        self.offset = end
        return data

    def header(self) -> SimpleNamespace:
        self._align(4)
        sec, nanosec = struct.unpack_from(self.prefix + "iI", self.data, self.offset)
        self.offset += 8
        return SimpleNamespace(
            stamp=SimpleNamespace(sec=sec, nanosec=nanosec), frame_id=self.string()
        )

    def pose(self, then: int = 0) -> tuple[SimpleNamespace, tuple[float, ...]]:
        """A geometry_msgs/Pose, and the ``then`` doubles after it (read in one call: the
        odometry's 50-400 messages a second are read in Python)."""
        x, y, z, qx, qy, qz, qw, *rest = self.unpack("d", 8, 7 + then)
        return SimpleNamespace(
            position=SimpleNamespace(x=x, y=y, z=z),
            orientation=SimpleNamespace(x=qx, y=qy, z=qz, w=qw),
        ), tuple(rest)


def _image(data: bytes | memoryview) -> SimpleNamespace:
    reader = _Reader(data)
    header = reader.header()
    height, width = reader.uint32(), reader.uint32()
    encoding = reader.string()
    is_bigendian = reader.unpack("B", 1)[0]
    step = reader.uint32()
    return SimpleNamespace(
        header=header,
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=is_bigendian,
        step=step,
        data=reader.byte_array(),
    )


def _compressed_image(data: bytes | memoryview) -> SimpleNamespace:
    reader = _Reader(data)
    header = reader.header()
    return SimpleNamespace(header=header, format=reader.string(), data=reader.byte_array())


def _odometry(data: bytes | memoryview) -> SimpleNamespace:
    reader = _Reader(data)
    header = reader.header()
    child = reader.string()
    pose, covariance = reader.pose(36)  # row-major 6x6 over x, y, z, roll, pitch, yaw
    return SimpleNamespace(
        header=header,
        child_frame_id=child,
        pose=SimpleNamespace(pose=pose, covariance=covariance),
    )


def _pose_stamped(data: bytes | memoryview) -> SimpleNamespace:
    reader = _Reader(data)
    header = reader.header()
    return SimpleNamespace(header=header, pose=reader.pose()[0])


FAST_DECODERS: dict[str, Callable[[bytes | memoryview], SimpleNamespace]] = {
    "sensor_msgs/msg/Image": _image,
    "sensor_msgs/msg/CompressedImage": _compressed_image,
    "nav_msgs/msg/Odometry": _odometry,
    "geometry_msgs/msg/PoseStamped": _pose_stamped,
}
"""Schema name -> reader of a CDR-encoded message of that type."""
