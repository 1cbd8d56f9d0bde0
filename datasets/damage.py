"""Damaged copies of a log, for fuzzing the readers: seeded mutations of an MCAP file, a ROS 1
bag or a rosbag2 SQLite folder, each aimed at one way real files break (a flipped bit, a cut
file, a length field holding a huge value, a record zeroed, repeated or lost, a message whose
bytes are garbage inside a file that is otherwise valid).

Every mutation is a function of (the file's bytes, a seeded generator) and returns the new
bytes and a short description; the same seed gives the same damage.
"""

from __future__ import annotations

import shutil
import sqlite3
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

__all__ = ["DAMAGE_KINDS", "Damaged", "damage_log"]

MCAP_MAGIC = b"\x89MCAP0\r\n"
ROS1_MAGIC = b"#ROSBAG V2.0\n"
_CHUNK = 0x06
# Values a damaged length field holds: past any file, past memory, past an index, one byte off.
_HUGE = (2**63 - 1, 2**64 - 1, 2**40, 2**32 - 1, 2**31)

Rng = np.random.Generator


@dataclass(frozen=True)
class Damaged:
    """One damaged copy of a log."""

    path: Path
    """The copy (a file, or a rosbag2 folder for a SQLite bag)."""
    kind: str
    """The mutation's name (one of :data:`DAMAGE_KINDS`)."""
    what: str
    """What was done, with offsets, to reproduce it by hand."""


@dataclass(frozen=True)
class _Record:
    """Where one record lies in a file: its start, its length fields, its end."""

    start: int
    lengths: tuple[tuple[int, str], ...]
    """(offset, struct format) of each length field in the record."""
    end: int


def _mcap_records(data: bytes) -> Iterator[_Record]:
    """MCAP records (opcode u8, length u64, content), with a chunk's own size fields."""
    position = len(MCAP_MAGIC)
    while position + 9 <= len(data) - len(MCAP_MAGIC):
        opcode, length = struct.unpack_from("<BQ", data, position)
        end = position + 9 + length
        if end > len(data):
            return
        fields = [(position + 1, "<Q")]
        if opcode == _CHUNK and length >= 32:
            content = position + 9
            fields.append((content + 16, "<Q"))  # uncompressed size
            name_length = struct.unpack_from("<I", data, content + 28)[0]
            records_length = content + 32 + name_length
            if records_length + 8 <= end:
                fields.append((records_length, "<Q"))
        yield _Record(position, tuple(fields), end)
        position = end


def _ros1_records(data: bytes) -> Iterator[_Record]:
    """ROS 1 bag records (header length u32, header, data length u32, data)."""
    position = len(ROS1_MAGIC)
    while position + 4 <= len(data):
        header_length = struct.unpack_from("<I", data, position)[0]
        data_at = position + 4 + header_length
        if data_at + 4 > len(data):
            return
        data_length = struct.unpack_from("<I", data, data_at)[0]
        end = data_at + 4 + data_length
        if end > len(data):
            return
        yield _Record(position, ((position, "<I"), (data_at, "<I")), end)
        position = end


def _records(data: bytes) -> list[_Record]:
    if data.startswith(MCAP_MAGIC):
        return list(_mcap_records(data))
    if data.startswith(ROS1_MAGIC):
        return list(_ros1_records(data))
    return []


def _flip(data: bytes, rng: Rng) -> tuple[bytes, str]:
    out = bytearray(data)
    offsets = sorted(int(o) for o in rng.integers(8, len(data), int(rng.integers(1, 9))))
    for offset in offsets:
        out[offset] ^= 1 << int(rng.integers(0, 8))
    return bytes(out), f"bits flipped at bytes {offsets}"


def _truncate(data: bytes, rng: Rng) -> tuple[bytes, str]:
    at = int(rng.integers(8, len(data)))
    return data[:at], f"cut at byte {at} of {len(data)}"


def _huge_length(data: bytes, rng: Rng) -> tuple[bytes, str]:
    records = _records(data)
    if not records:
        return _flip(data, rng)
    sized = [r for r in records if len(r.lengths) > 1]  # chunks and bag records: half the time
    pool = sized if sized and rng.random() < 0.5 else records
    record = pool[int(rng.integers(len(pool)))]
    offset, form = record.lengths[int(rng.integers(len(record.lengths)))]
    limit = 2 ** (8 * struct.calcsize(form)) - 1
    value = min(int(rng.choice(_HUGE)), limit)
    if rng.random() < 0.3:  # a near miss: just past the file's end
        value = min(len(data) - offset + int(rng.integers(1, 64)), limit)
    out = bytearray(data)
    struct.pack_into(form, out, offset, value)
    return bytes(out), f"length field at byte {offset} set to {value}"


def _zero_record(data: bytes, rng: Rng) -> tuple[bytes, str]:
    records = _records(data)
    if not records:
        return _truncate(data, rng)
    record = records[int(rng.integers(len(records)))]
    out = bytearray(data)
    out[record.start : record.end] = bytes(record.end - record.start)
    return bytes(out), f"record at bytes {record.start}-{record.end} zeroed"


def _duplicate_record(data: bytes, rng: Rng) -> tuple[bytes, str]:
    records = _records(data)
    if not records:
        return _flip(data, rng)
    record = records[int(rng.integers(len(records)))]
    copy = data[record.start : record.end]
    return data[: record.end] + copy + data[record.end :], f"record at byte {record.start} doubled"


def _delete_record(data: bytes, rng: Rng) -> tuple[bytes, str]:
    records = _records(data)
    if not records:
        return _truncate(data, rng)
    record = records[int(rng.integers(len(records)))]
    return data[: record.start] + data[record.end :], f"record at byte {record.start} removed"


_BYTE_KINDS: dict[str, Callable[[bytes, Rng], tuple[bytes, str]]] = {
    "flip": _flip,
    "truncate": _truncate,
    "huge-length": _huge_length,
    "zero-record": _zero_record,
    "duplicate-record": _duplicate_record,
    "delete-record": _delete_record,
}
DAMAGE_KINDS = (*_BYTE_KINDS, "bad-payload")
"""Every mutation: the byte-level ones, then garbage message bytes in an otherwise valid file."""


def _garble(payload: bytes, rng: Rng) -> bytes:
    """A message's bytes damaged as a sender's bug would: bytes flipped, a length made huge,
    or the tail cut."""
    out = bytearray(payload)
    choice = int(rng.integers(3))
    if choice == 0 and out:
        for offset in rng.integers(0, len(out), int(rng.integers(1, 6))):
            out[int(offset)] = int(rng.integers(256))
    elif choice == 1 and len(out) >= 8:
        offset = int(rng.integers(0, len(out) - 3))
        struct.pack_into("<I", out, offset, int(rng.choice([2**31 - 1, 2**32 - 1, 2**24])))
    else:
        out = out[: int(rng.integers(0, max(len(out), 1)))]
    return bytes(out)


def _bad_mcap_payloads(source: Path, target: Path, rng: Rng) -> str:
    """A valid MCAP (its own summary and indexes) whose chosen messages hold garbage."""
    with open(source, "rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert summary is not None
        total = summary.statistics.message_count if summary.statistics else 0
        chosen = set(int(i) for i in rng.integers(0, max(total, 1), int(rng.integers(1, 6))))
        with open(target, "wb") as out:
            writer = Writer(out, compression=CompressionType.ZSTD)
            writer.start()
            for schema in summary.schemas.values():
                writer.register_schema(schema.name, schema.encoding, schema.data)
            for channel in summary.channels.values():
                writer.register_channel(
                    channel.topic, channel.message_encoding, channel.schema_id, channel.metadata
                )
            for index, (_, channel, message) in enumerate(reader.iter_messages()):
                data = _garble(message.data, rng) if index in chosen else message.data
                writer.add_message(
                    channel.id, message.log_time, data, message.publish_time, message.sequence
                )
            writer.finish()
    return f"messages {sorted(chosen)} garbled in a valid MCAP"


def _bad_sqlite_payloads(folder: Path, rng: Rng) -> str:
    """A valid SQLite bag whose chosen messages hold garbage."""
    database = next(folder.glob("*.db3"))
    with sqlite3.connect(database) as connection:
        rows = connection.execute("SELECT id, data FROM messages").fetchall()
        chosen = [rows[int(i)] for i in rng.integers(0, len(rows), int(rng.integers(1, 6)))]
        for row_id, payload in chosen:
            connection.execute(
                "UPDATE messages SET data = ? WHERE id = ?", (_garble(payload, rng), row_id)
            )
    return f"messages {sorted(r[0] for r in chosen)} garbled in a valid SQLite bag"


def damage_log(source: Path, target: Path, kind: str, seed: int) -> Damaged:
    """A damaged copy of a log at ``target`` (a file, or a folder for a rosbag2 source).

    For a rosbag2 SQLite folder the byte-level kinds damage its ``.db3`` file; ``bad-payload``
    garbles messages of an MCAP or SQLite bag and is a byte flip for a ROS 1 bag.

    Raises:
        ValueError: an unknown kind.
    """
    if kind not in DAMAGE_KINDS:
        raise ValueError(f"unknown damage {kind!r}: one of {', '.join(DAMAGE_KINDS)}")
    rng = np.random.default_rng(seed)
    if source.is_dir():
        shutil.copytree(source, target)
        if kind == "bad-payload":
            return Damaged(target, kind, _bad_sqlite_payloads(target, rng))
        file = next(target.glob("*.db3"))
    else:
        if kind == "bad-payload" and source.read_bytes().startswith(MCAP_MAGIC):
            return Damaged(target, kind, _bad_mcap_payloads(source, target, rng))
        shutil.copyfile(source, target)
        file = target
    mutate = _BYTE_KINDS.get(kind, _flip)
    data, what = mutate(file.read_bytes(), rng)
    file.write_bytes(data)
    return Damaged(target, kind, what)
