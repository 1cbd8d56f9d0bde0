"""ROS 2 messages written as CDR bytes (little-endian XCDR1, what ``ros2msg`` channels in MCAP
hold), field by field, for the overlay's messages.

mcap_ros2's encoder walks the message definition for every field of every message in Python
(about 2 ms a message for the overlay's paths; 1.5-3 s a sample overlay), and a path message
repeats every pose before it. Here messages of one fixed shape (the same frame names) are
numpy records (:func:`layout`), filled a column at a time, and a path message is the records
of its poses, encoded once; :class:`CdrWriter` writes the few others field by field.
Alignment is counted from the end of the 4-byte encapsulation header, as the CDR standard and
mcap_ros2 do.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

import numpy as np

__all__ = [
    "ENCAPSULATION",
    "CdrWriter",
    "fill_string",
    "layout",
    "string_fields",
]

ENCAPSULATION = b"\x00\x01\x00\x00"
"""CDR_LE: the representation identifier (0x0001, big-endian) and two option bytes."""


class CdrWriter:
    """One message's bytes from :data:`ENCAPSULATION` on, appended field by field with each
    field's alignment."""

    def __init__(self) -> None:
        self._parts: list[bytes] = [ENCAPSULATION]
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

    @property
    def offset(self) -> int:
        """Where the next field goes, from the end of the encapsulation header."""
        return self._at

    def encoded(self, data: bytes, start: int = 0) -> CdrWriter:
        """Bytes encoded elsewhere for an offset ``start`` modulo 8 (e.g. records of
        :func:`layout`), placed here.

        Raises:
            ValueError: the offset here is another modulo 8, where their padding would be wrong.
        """
        if self._at % 8 != start % 8:
            raise ValueError(f"bytes laid out from {start} (mod 8) cannot go at {self._at}")
        self._parts.append(data)
        self._at += len(data)
        return self

    def sequence(self, count: int) -> CdrWriter:
        """A sequence's length; its elements follow."""
        return self.uint32(count)

    def data(self) -> bytes:
        """The bytes written so far."""
        return b"".join(self._parts)


Field = tuple[str, str]  # (name, numpy format: "<i4", "<u4", "<f8", "(7,)<f8", "S12")


def string_fields(name: str, text: str) -> list[Field]:
    """A string of fixed content as two fields: ``<name>_length`` (uint32, the NUL included)
    and ``name``, its bytes and the NUL; fill them with :func:`fill_string`."""
    return [(f"{name}_length", "<u4"), (name, f"S{len(text.encode()) + 1}")]


def fill_string(records: np.ndarray, name: str, text: str) -> None:
    """Set a string of :func:`string_fields` in every record."""
    data = text.encode()
    records[f"{name}_length"] = len(data) + 1
    records[name] = data  # numpy pads the last byte with the NUL


def layout(fields: Sequence[Field], start: int = 0) -> np.dtype:
    """The numpy record of CDR fields in order, each aligned to its own size, as counted from
    ``start`` (the record's offset after the encapsulation header); its padding is zeros in
    ``np.zeros``.

    Raises:
        ValueError: records of this layout would not keep their alignment one after the
            other (the size is not a multiple of the largest alignment).
    """
    names, formats, offsets = [], [], []
    at, largest = start, 1
    for name, fmt in fields:
        dtype = np.dtype(fmt)
        align = 1 if dtype.base.kind == "S" else dtype.base.itemsize
        largest = max(largest, align)
        at += -at % align
        names.append(name)
        formats.append(dtype)
        offsets.append(at - start)
        at += dtype.itemsize
    size = at - start
    if start % largest == 0 and size % largest:
        raise ValueError(f"a record of {size} bytes does not keep {largest}-byte alignment")
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": size})
