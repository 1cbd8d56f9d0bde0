"""A ROS 1 bag (format 2.0) read chunk by chunk, every length checked against the file before
anything is read or allocated, so that a damaged chunk costs only its own messages.

The layout (http://wiki.ros.org/Bags/Format/2.0): the magic line, a bag header record (padded
to 4096 bytes) giving the index's offset, then chunk records, each followed by one index data
record per connection in it, then the index: a connection record per connection and a chunk
info record per chunk (its offset, time span and message count per connection). A record is a
header (``name=value`` fields, each with a 4-byte length) and data, each with a 4-byte length.

A bag whose index is missing (a recording killed before closing) or damaged is read by a scan
of its records from the first chunk: the index data records after each chunk give its counts
and times, and the connection records come from the index if it is there, else from inside the
chunks. Messages are decoded elsewhere (``rosbags``' ROS 1 deserialiser): this gives raw bytes.
"""

from __future__ import annotations

import bz2
import struct
from collections import Counter
from collections.abc import Collection
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

import lz4.frame

from markergraph.frontend.logs.files import ROS1_MAGIC

__all__ = ["DamagedBagError", "Ros1Bag", "Ros1Chunk", "Ros1Connection", "lost_counts", "open_ros1"]

# Record opcodes (the header's ``op`` field).
_MESSAGE, _BAG_HEADER, _INDEX_DATA, _CHUNK, _CHUNK_INFO, _CONNECTION = 2, 3, 4, 5, 6, 7
# The bag header record is padded with spaces: by rosbag to 4096 bytes of header and data (the
# first chunk at 4117), by the rosbags library to 4096 in all (at 4109). The nearer bounds an
# index's offset; a scan starts where the header record itself ends.
_FIRST_RECORD = len(ROS1_MAGIC) + 4096
MAX_HEADER_BYTES = 16 << 20
"""A record header is a few fields (a connection's carries its message definitions: kB)."""
MAX_CHUNK_BYTES = 512 << 20
"""A chunk claiming more once decompressed is damaged: rosbag writes 768 kB chunks, and one
message beyond this would not fit the 1 GB a run may take."""
_LZ4_RATIO = 256  # lz4 never expands more than 255:1: a larger claim is a damaged size field
_U32 = struct.Struct("<I")
_TIME = struct.Struct("<II")  # seconds, nanoseconds


class DamagedBagError(Exception):
    """Damage found in a ROS 1 bag; the message says what and at which byte."""


@dataclass(frozen=True)
class Ros1Connection:
    """A connection record: one topic with one type."""

    id: int
    """Its number, by which message records name it."""
    topic: str
    """The topic's name."""
    msgtype: str
    """Its type, ROS 2 style (``sensor_msgs/msg/Image``)."""
    definition: str
    """The type's definition as the bag carries it ("" where it carries none)."""


@dataclass(frozen=True)
class Ros1Chunk:
    """What the index (or a scan) says of one chunk."""

    pos: int
    """The chunk record's offset in the file [bytes]."""
    start_ns: int
    """Its first message's time [ns]."""
    end_ns: int
    """Its last message's time [ns]."""
    counts: dict[int, int]
    """Connection id -> its number of messages in the chunk."""
    times: dict[int, tuple[int, int]] = field(default_factory=dict)
    """Connection id -> its first and last message time in the chunk [ns], from the index
    data records after the chunk (empty where they cannot be read)."""


@dataclass(frozen=True)
class Ros1Bag:
    """A ROS 1 bag's connections and chunks, from its index or a scan of its records."""

    path: Path
    """The bag."""
    size: int
    """Its size [bytes]."""
    connections: dict[int, Ros1Connection]
    """Connection id -> connection."""
    chunks: list[Ros1Chunk]
    """Every chunk, in file order."""
    scanned: str = ""
    """Why the index was not used and the records were scanned instead ("" where it was)."""
    stopped: str = ""
    """The damage at which the scan stopped short of the end ("" where it did not): the
    messages after it are lost, uncounted."""

    def chunk_messages(
        self, stream: BinaryIO, chunk: Ros1Chunk, wanted: Collection[int]
    ) -> tuple[list[tuple[int, int, bytes]], DamagedBagError | None]:
        """The (connection id, time [ns], raw bytes) of the wanted connections' messages in a
        chunk, in its order, and the damage that stopped the reading of it (None where none
        did): the messages before the damage are kept."""
        found: list[tuple[int, int, bytes]] = []
        try:
            data = _chunk_data(stream, chunk.pos, self.size)
            for op, header, start, end in _records(data, chunk.pos):
                if op != _MESSAGE:
                    continue
                connection = _u32(header, "conn", chunk.pos)
                if connection in wanted:
                    found.append((connection, _time(header, "time", chunk.pos), data[start:end]))
        except DamagedBagError as damage:
            return found, damage
        return found, None


def open_ros1(path: Path) -> Ros1Bag:
    """A ROS 1 bag's connections and chunks, from its index, or by a scan of its records where
    the index is missing or damaged.

    Raises:
        DamagedBagError: not a ROS 1 bag of format 2.0, or nothing readable in it.
        OSError: the file cannot be read.
    """
    path = Path(path)
    with open(path, "rb") as stream:
        size = stream.seek(0, 2)
        stream.seek(0)
        if stream.read(len(ROS1_MAGIC)) != ROS1_MAGIC:
            raise DamagedBagError("not a ROS 1 bag of format 2.0 (its first line)")
        try:
            return _from_index(path, stream, size)
        except DamagedBagError as damage:
            why = str(damage)
        return _from_scan(path, stream, size, why)


# --- the index -----------------------------------------------------------------------------


def _from_index(path: Path, stream: BinaryIO, size: int) -> Ros1Bag:
    """The bag as its bag header and index describe it."""
    header, _, _, _ = _record(stream, len(ROS1_MAGIC), size, _BAG_HEADER)
    index_pos = _u64(header, "index_pos", len(ROS1_MAGIC))
    if index_pos == 0:
        raise DamagedBagError("it has no index (a recording that was not closed)")
    if not _FIRST_RECORD <= index_pos < size:
        raise DamagedBagError(f"its index offset {index_pos} lies outside the file of {size} bytes")
    n_connections = _u32(header, "conn_count", len(ROS1_MAGIC))
    n_chunks = _u32(header, "chunk_count", len(ROS1_MAGIC))
    connections: dict[int, Ros1Connection] = {}
    chunks: list[Ros1Chunk] = []
    pos = index_pos
    for _ in range(n_connections):
        header, data_pos, data_len, pos = _record(stream, pos, size, _CONNECTION)
        connection = _connection(header, _read(stream, data_pos, data_len), data_pos)
        connections[connection.id] = connection
    for _ in range(n_chunks):
        header, data_pos, data_len, pos = _record(stream, pos, size, _CHUNK_INFO)
        chunks.append(_chunk_info(header, _read(stream, data_pos, data_len), data_pos))
    chunks = [_with_times(stream, chunk, size) for chunk in sorted(chunks, key=lambda c: c.pos)]
    return Ros1Bag(path, size, connections, chunks)


def _chunk_info(header: dict[str, bytes], data: bytes, at: int) -> Ros1Chunk:
    """A chunk info record: the chunk's offset, time span and counts per connection."""
    if _u32(header, "ver", at) != 1:
        raise DamagedBagError(f"a chunk info record of an unknown version at byte {at}")
    count = _u32(header, "count", at)
    if len(data) != 8 * count:
        raise DamagedBagError(
            f"a chunk info record of {len(data)} bytes for {count} connections at byte {at}"
        )
    counts = dict(struct.iter_unpack("<II", data))
    return Ros1Chunk(
        _u64(header, "chunk_pos", at), _time(header, "start_time", at),
        _time(header, "end_time", at), counts,
    )  # fmt: skip


def _with_times(stream: BinaryIO, chunk: Ros1Chunk, size: int) -> Ros1Chunk:
    """The chunk with each connection's first and last time, from the index data records after
    it; as it was where they cannot be read (the chunk's own span then stands for them)."""
    try:
        _, data_pos, data_len, pos = _record(stream, chunk.pos, size, _CHUNK)
        times: dict[int, tuple[int, int]] = {}
        for _ in range(len(chunk.counts)):
            header, data_pos, data_len, pos = _record(stream, pos, size, _INDEX_DATA)
            connection, stamps = _index_data(header, _read(stream, data_pos, data_len), data_pos)
            if stamps:
                times[connection] = (min(stamps), max(stamps))
    except DamagedBagError:
        return chunk
    return Ros1Chunk(chunk.pos, chunk.start_ns, chunk.end_ns, chunk.counts, times)


def _index_data(header: dict[str, bytes], data: bytes, at: int) -> tuple[int, list[int]]:
    """An index data record: its connection and the times of its messages in the chunk [ns]."""
    if _u32(header, "ver", at) != 1:
        raise DamagedBagError(f"an index data record of an unknown version at byte {at}")
    count = _u32(header, "count", at)
    if len(data) != 12 * count:
        raise DamagedBagError(
            f"an index data record of {len(data)} bytes for {count} entries at byte {at}"
        )
    stamps = [sec * 1_000_000_000 + nsec for sec, nsec, _ in struct.iter_unpack("<III", data)]
    return _u32(header, "conn", at), stamps


def _connection(header: dict[str, bytes], data: bytes, at: int) -> Ros1Connection:
    """A connection record: its id and topic in the header, its type in the data (a header)."""
    from rosbags.typesys.msg import normalize_msgtype

    fields = _fields(data, at)
    try:
        topic = header["topic"].decode()
        msgtype = normalize_msgtype(fields["type"].decode())
        definition = fields.get("message_definition", b"").decode()
    except (KeyError, UnicodeDecodeError, ValueError) as error:
        raise DamagedBagError(
            f"a damaged connection record at byte {at} ({_why(error)})"
        ) from error
    return Ros1Connection(_u32(header, "conn", at), topic, msgtype, definition)


# --- the scan ------------------------------------------------------------------------------


def _from_scan(path: Path, stream: BinaryIO, size: int, why: str) -> Ros1Bag:
    """The bag as a scan of its records finds it, from the first chunk to the first damage
    (or the end); ``why`` is why its index was not used."""
    connections: dict[int, Ros1Connection] = {}
    chunks: list[Ros1Chunk] = []
    pos, stopped = _after_bag_header(stream, size), ""
    while pos < size:
        try:
            header, data_pos, data_len, end = _record(stream, pos, size)
            op = _op(header, pos)
            if op == _CHUNK:
                chunk, end = _scanned_chunk(stream, pos, end, size, connections)
                chunks.append(chunk)
            elif op == _CONNECTION:
                connection = _connection(header, _read(stream, data_pos, data_len), data_pos)
                connections[connection.id] = connection
        except DamagedBagError as damage:
            stopped = str(damage)
            break
        pos = end
    chunks = [c for c in chunks if c.counts]
    if not chunks:
        raise DamagedBagError(f"{why}; a scan of its records found no chunk ({stopped or 'none'})")
    return Ros1Bag(path, size, connections, chunks, why, stopped)


def _after_bag_header(stream: BinaryIO, size: int) -> int:
    """Where the records after the bag header record begin: its end, or rosbag's 4117 where
    the header itself is damaged."""
    try:
        return _record(stream, len(ROS1_MAGIC), size, _BAG_HEADER)[3]
    except DamagedBagError:
        return _FIRST_RECORD + 8


def _scanned_chunk(
    stream: BinaryIO, pos: int, end: int, size: int, connections: dict[int, Ros1Connection]
) -> tuple[Ros1Chunk, int]:
    """A chunk found by the scan, at ``pos`` (its record ending at ``end``), the connections
    defined inside it added to ``connections``. Its counts and times are its messages' where it
    reads whole, else those of the index data records after it (if they can be read, else those
    of the messages before the damage, so that none are counted lost). Returns the chunk and
    where the records after its index data end."""
    counts: Counter[int] = Counter()
    times: dict[int, tuple[int, int]] = {}
    while end < size:
        try:
            header, data_pos, data_len, after = _record(stream, end, size)
            if _op(header, end) != _INDEX_DATA:
                break
            connection, stamps = _index_data(header, _read(stream, data_pos, data_len), data_pos)
        except DamagedBagError:
            break  # the next record is the scan's to judge
        if stamps:
            counts[connection] = len(stamps)
            times[connection] = (min(stamps), max(stamps))
        end = after
    read: Counter[int] = Counter()
    spans: dict[int, list[int]] = {}
    try:
        data = _chunk_data(stream, pos, size)
        for op, header, start, stop in _records(data, pos):
            if op == _CONNECTION:
                defined = _connection(header, data[start:stop], pos)
                connections.setdefault(defined.id, defined)
            elif op == _MESSAGE:
                connection_id = _u32(header, "conn", pos)
                read[connection_id] += 1
                spans.setdefault(connection_id, []).append(_time(header, "time", pos))
    except DamagedBagError:
        if not counts:
            counts, times = read, {c: (min(t), max(t)) for c, t in spans.items()}
    else:
        counts, times = read, {c: (min(t), max(t)) for c, t in spans.items()}
    first = min((t for t, _ in times.values()), default=0)
    last = max((t for _, t in times.values()), default=0)
    return Ros1Chunk(pos, first, last, dict(counts), times), end


def lost_counts(chunk: Ros1Chunk, found: Counter[int], wanted: Collection[int]) -> dict[int, int]:
    """Connection id -> how many of its messages a chunk held that were not read from it."""
    return {c: n - found[c] for c, n in chunk.counts.items() if c in wanted and n > found[c]}


# --- records -------------------------------------------------------------------------------


def _record(
    stream: BinaryIO, pos: int, size: int, expect: int | None = None
) -> tuple[dict[str, bytes], int, int, int]:
    """The record at ``pos``: its header fields, where its data starts, its length, and where
    the next record starts. Both lengths are checked against the file before reading.

    Raises:
        DamagedBagError: a length running past the file, a damaged header, or another op than
            ``expect``.
    """
    if pos + 4 > size:
        raise DamagedBagError(f"a record past the end of the file at byte {pos}")
    (header_len,) = _U32.unpack(_read(stream, pos, 4))
    if header_len > MAX_HEADER_BYTES or pos + 8 + header_len > size:
        raise DamagedBagError(f"a record header claiming {header_len} bytes at byte {pos}")
    header = _fields(_read(stream, pos + 4, header_len), pos)
    (data_len,) = _U32.unpack(_read(stream, pos + 4 + header_len, 4))
    data_pos = pos + 8 + header_len
    if data_pos + data_len > size:
        raise DamagedBagError(f"a record claiming {data_len} bytes of data at byte {pos}")
    if expect is not None and _op(header, pos) != expect:
        raise DamagedBagError(
            f"a record of op {_op(header, pos)} where {expect} belongs at byte {pos}"
        )
    return header, data_pos, data_len, data_pos + data_len


def _records(data: bytes, at: int) -> list[tuple[int, dict[str, bytes], int, int]]:
    """The records inside a chunk's data: (op, header, data start, data end) each.

    Raises:
        DamagedBagError: a length running past the chunk, or a damaged header (naming the chunk's
            offset ``at`` and the record's within it).
    """
    found, pos, size = [], 0, len(data)
    while pos < size:
        if pos + 4 > size:
            raise DamagedBagError(
                f"a damaged chunk at byte {at}: a record cut short at {pos} in it"
            )
        (header_len,) = _U32.unpack_from(data, pos)
        if pos + 8 + header_len > size:
            raise DamagedBagError(
                f"a damaged chunk at byte {at}: a record header of {header_len} bytes"
            )
        header = _fields(data[pos + 4 : pos + 4 + header_len], at)
        (data_len,) = _U32.unpack_from(data, pos + 4 + header_len)
        start = pos + 8 + header_len
        if start + data_len > size:
            raise DamagedBagError(f"a damaged chunk at byte {at}: a record of {data_len} bytes")
        found.append((_op(header, at), header, start, start + data_len))
        pos = start + data_len
    return found


def _chunk_data(stream: BinaryIO, pos: int, size: int) -> bytes:
    """A chunk's records, decompressed to the size its header gives, never beyond it.

    Raises:
        DamagedBagError: a damaged record, an unknown compression, data that does not decompress
            or decompresses to another size.
    """
    header, data_pos, data_len, _ = _record(stream, pos, size, _CHUNK)
    compression = header.get("compression", b"?")
    expected = _u32(header, "size", pos)
    bound = data_len if compression == b"none" else min(MAX_CHUNK_BYTES, _LZ4_RATIO * data_len)
    if compression != b"bz2" and expected > bound:
        raise DamagedBagError(f"a chunk claiming {expected} bytes of {data_len} at byte {pos}")
    if expected > MAX_CHUNK_BYTES:
        raise DamagedBagError(f"a chunk claiming {expected} bytes at byte {pos}")
    raw = _read(stream, data_pos, data_len)
    try:
        if compression == b"none":
            data = raw
        elif compression == b"lz4":
            data = lz4.frame.LZ4FrameDecompressor().decompress(raw, max_length=expected)
        elif compression == b"bz2":
            data = bz2.BZ2Decompressor().decompress(raw, max_length=expected)
        else:
            raise DamagedBagError(f"a chunk compressed with {compression!r} at byte {pos}")
    except (RuntimeError, OSError, ValueError, EOFError) as error:  # lz4's, bz2's
        raise DamagedBagError(f"a damaged chunk at byte {pos}: {_why(error)}") from error
    if len(data) != expected:
        raise DamagedBagError(f"a damaged chunk at byte {pos} ({len(data)} of {expected} bytes)")
    return data


def _fields(header: bytes, at: int) -> dict[str, bytes]:
    """A record header's ``name=value`` fields.

    Raises:
        DamagedBagError: a field running past the header, or one without ``=``.
    """
    fields: dict[str, bytes] = {}
    pos, size = 0, len(header)
    while pos < size:
        if pos + 4 > size:
            raise DamagedBagError(f"a damaged record header at byte {at}")
        (length,) = _U32.unpack_from(header, pos)
        pos += 4
        if pos + length > size:
            raise DamagedBagError(
                f"a damaged record header at byte {at} (a field of {length} bytes)"
            )
        name, sep, value = header[pos : pos + length].partition(b"=")
        if not sep:
            raise DamagedBagError(f"a damaged record header at byte {at} (a field without '=')")
        fields[name.decode("latin-1")] = value
        pos += length
    return fields


def _read(stream: BinaryIO, pos: int, n: int) -> bytes:
    """``n`` bytes at ``pos`` (already checked to lie within the file)."""
    stream.seek(pos)
    data = stream.read(n)
    if len(data) != n:  # the file shrank under us
        raise DamagedBagError(f"only {len(data)} of {n} bytes at byte {pos}")
    return data


def _op(header: dict[str, bytes], at: int) -> int:
    value = header.get("op", b"")
    if len(value) != 1:
        raise DamagedBagError(f"a damaged record header at byte {at} (no op)")
    return value[0]


def _u32(header: dict[str, bytes], name: str, at: int) -> int:
    value = header.get(name, b"")
    if len(value) != 4:
        raise DamagedBagError(f"a damaged record header at byte {at} (its {name})")
    return int(_U32.unpack(value)[0])


def _u64(header: dict[str, bytes], name: str, at: int) -> int:
    value = header.get(name, b"")
    if len(value) != 8:
        raise DamagedBagError(f"a damaged record header at byte {at} (its {name})")
    return int(struct.unpack("<Q", value)[0])


def _time(header: dict[str, bytes], name: str, at: int) -> int:
    value = header.get(name, b"")
    if len(value) != 8:
        raise DamagedBagError(f"a damaged record header at byte {at} (its {name})")
    sec, nsec = _TIME.unpack(value)
    return sec * 1_000_000_000 + nsec


def _why(error: BaseException) -> str:
    """An error as a reason; its type name where its text is empty."""
    return f"{type(error).__name__}: {error}" if str(error) else type(error).__name__
