"""ROS 2 messages written as CDR bytes (little-endian XCDR1, what ``ros2msg`` channels in MCAP
hold), field by field, for the overlay's messages.

mcap_ros2's encoder walks the message definition for every field of every message in Python
(about 2 ms a message for the overlay's paths; 1.5-3 s a sample overlay), and a path message
repeats every pose before it. Here each pose is encoded once (:func:`pose_stamped`) and a
path message joins those bytes. Alignment is counted from the end of the 4-byte
encapsulation header, as the CDR standard and mcap_ros2 do.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

__all__ = ["ENCAPSULATION", "CdrWriter", "pose_stamped"]

ENCAPSULATION = b"\x00\x01\x00\x00"
"""CDR_LE: the representation identifier (0x0001, big-endian) and two option bytes."""


class CdrWriter:
    """One message's bytes, appended field by field with each field's alignment.

    Args:
        header: start with :data:`ENCAPSULATION` (a whole message); False for a body placed
            later at an offset that is a multiple of 8 (see :meth:`body`).
    """

    def __init__(self, header: bool = True) -> None:
        self._parts: list[bytes] = [ENCAPSULATION] if header else []
        self._at = 0  # offset from the end of the encapsulation header

    def _put(self, code: str, size: int, values: Sequence[float | int]) -> CdrWriter:
        pad = -self._at % size
        packed = struct.pack(f"<{pad}x{len(values)}{code}", *values)
        self._parts.append(packed)
        self._at += len(packed)
        return self

    def int32(self, *values: int) -> CdrWriter:
        return self._put("i", 4, values)

    def uint32(self, *values: int) -> CdrWriter:
        return self._put("I", 4, values)

    def float32(self, *values: float) -> CdrWriter:
        return self._put("f", 4, values)

    def float64(self, *values: float) -> CdrWriter:
        return self._put("d", 8, values)

    def boolean(self, value: bool) -> CdrWriter:
        return self._put("B", 1, (int(value),))

    def string(self, text: str) -> CdrWriter:
        """A uint32 length (the NUL included), the UTF-8 bytes and a NUL."""
        data = text.encode()
        self.uint32(len(data) + 1)
        self._parts.append(data + b"\0")
        self._at += len(data) + 1
        return self

    def time(self, t_ns: int) -> CdrWriter:
        """A ``builtin_interfaces/Time`` (or ``Duration``) from integer nanoseconds."""
        return self.int32(t_ns // 1_000_000_000).uint32(t_ns % 1_000_000_000)

    def header(self, t_ns: int, frame_id: str) -> CdrWriter:
        """A ``std_msgs/Header``."""
        return self.time(t_ns).string(frame_id)

    def body(self, data: bytes) -> CdrWriter:
        """Bytes encoded by ``CdrWriter(header=False)`` that end on a multiple of 8 (e.g.
        :func:`pose_stamped`), placed here.

        Raises:
            ValueError: the offset here is not a multiple of 8, where the body's own padding
                would be wrong.
        """
        if self._at % 8:
            raise ValueError(f"a body is placed at a multiple of 8 bytes, not at {self._at}")
        self._parts.append(data)
        self._at += len(data)
        return self

    def bodies(self, data: Sequence[bytes]) -> CdrWriter:
        """Several bodies of :meth:`body`, one after the other (each ends on a multiple of 8)."""
        return self.body(b"".join(data))

    def aligned_to(self, size: int) -> bool:
        """Whether the next field starts on a multiple of ``size`` bytes."""
        return self._at % size == 0

    def sequence(self, count: int) -> CdrWriter:
        """A sequence's length; its elements follow."""
        return self.uint32(count)

    def data(self) -> bytes:
        """The bytes written so far."""
        return b"".join(self._parts)


def pose_stamped(
    writer: CdrWriter, t_ns: int, frame_id: str, xyz: Sequence[float], xyzw: Sequence[float]
) -> CdrWriter:
    """A ``geometry_msgs/PoseStamped`` appended: header, position, orientation quaternion
    (x, y, z, w)."""
    return writer.header(t_ns, frame_id).float64(*xyz, *xyzw)
