"""An MCAP file read defensively: a stream whose reads never ask for more than the file holds
(a damaged length field of 2^63 must not allocate 2^63 bytes), chunks decompressed only to the
size they and their frames agree on, and a summary rebuilt by reading the data section record by
record when the file's own is missing or damaged (a recording cut short by a power loss, a
damaged index)."""

from __future__ import annotations

import io
import os
import struct
import zlib
from collections import Counter
from collections.abc import Iterator
from typing import IO, BinaryIO, cast

import lz4.frame
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, ChunkIndex, Schema, Statistics
from mcap.summary import Summary

from markergraph.frontend.logs.records import McapDamageError

__all__ = [
    "MAX_CHUNK_BYTES",
    "BoundedFile",
    "chunk_at",
    "decompress",
    "read_summary",
    "records_in",
    "scan_summary",
    "summary_problem",
]

MAX_CHUNK_BYTES = 256 * 2**20
"""The most a chunk may hold uncompressed: writers make chunks of about 1 MB; a single message
as large as this (a 4K raw image is 25 MB) is still far within it."""

_HEADER = struct.Struct("<BQ")  # a record's opcode and content length


class BoundedFile:
    """A binary file whose reads and seeks stay within its size, so that a length or an offset
    read from damaged bytes costs an end-of-file error, never an allocation of that length (a
    buffered ``read(n)`` allocates ``n`` bytes first) or ``[Errno 22]`` from a seek past 2^63.
    Not an ``io.RawIOBase``: mcap would wrap one in a buffer that closes it when dropped.
    """

    def __init__(self, stream: BinaryIO) -> None:
        self._stream = stream
        self.size = os.fstat(stream.fileno()).st_size

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def read(self, size: int | None = -1) -> bytes:
        left = max(self.size - self._stream.tell(), 0)
        return self._stream.read(left if size is None or size < 0 else min(size, left))

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        base = {io.SEEK_SET: 0, io.SEEK_CUR: self._stream.tell(), io.SEEK_END: self.size}[whence]
        return self._stream.seek(min(max(base + offset, 0), self.size))

    def tell(self) -> int:
        return self._stream.tell()


class _Bytes:
    """A record's bytes read as a stream whose reads never ask past their end: a field of
    2^63 inside it gets what is left (``io.BytesIO.read`` raises OverflowError on it)."""

    def __init__(self, data: bytes) -> None:
        self._data, self._position = data, 0

    def read(self, size: int = -1) -> bytes:
        end = len(self._data) if size < 0 else self._position + size
        data = self._data[self._position : end]
        self._position += len(data)
        return data


def _within(data: bytes) -> ReadDataStream:
    """A record's fields read from its own bytes, within them."""
    return ReadDataStream(cast(IO[bytes], _Bytes(data)))


def read_summary(stream: BoundedFile) -> Summary | None:
    """The file's own summary section (None: it has none), no record in it larger than the
    file.

    Raises:
        McapError, struct.error, ValueError, EOFError: a damaged footer or summary.
    """
    stream.seek(0)  # the reader checks the magic where the stream is
    reader = SeekingReader(cast(IO[bytes], stream), record_size_limit=stream.size)
    return reader.get_summary()


def chunk_at(stream: BoundedFile, offset: int) -> Chunk:
    """The chunk record at ``offset``, read whole into memory once its length is checked
    against the file, then parsed there (so no field inside it can ask for more).

    Raises:
        McapError: no chunk there, or one that runs past the end of the file.
    """
    stream.seek(offset)
    header = stream.read(_HEADER.size)
    if len(header) < _HEADER.size:
        raise McapDamageError(f"no record at byte {offset} (the file ends first)")
    opcode, length = _HEADER.unpack(header)
    if opcode != Opcode.CHUNK:
        raise McapDamageError(f"no chunk at byte {offset} (a record of type {opcode:#04x})")
    if length > stream.size - offset - _HEADER.size:
        raise McapDamageError(
            f"the chunk at byte {offset} claims {length:,} bytes, past the file's end"
        )
    return Chunk.read(_within(stream.read(length)))


def decompress(chunk: Chunk) -> bytes:
    """A chunk's records, decompressed to the size the chunk states, once that size is
    plausible and the compressed frame agrees with it, and checked against the chunk's CRC
    where the writer gave one: damage that still decompresses (a flipped byte in a JPEG)
    would otherwise pass as data. zlib's CRC runs at about 4 GB/s without holding the GIL.

    Raises:
        McapError: an implausible size, a disagreeing frame, a failed CRC or an unknown
            compression.
        zstandard.ZstdError, RuntimeError (lz4): damaged compressed data.
    """
    data = _decompressed(chunk)
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise McapDamageError("a chunk whose records fail its CRC")
    return data


def _decompressed(chunk: Chunk) -> bytes:
    size = chunk.uncompressed_size
    if size > MAX_CHUNK_BYTES:
        raise McapDamageError(
            f"a chunk claims {size:,} bytes uncompressed "
            f"(more than {MAX_CHUNK_BYTES / 1e6:,.0f} MB)"
        )
    if chunk.compression == "":
        return chunk.data
    if chunk.compression == "zstd":
        claimed = zstandard.frame_content_size(chunk.data)
        if claimed not in (-1, size):
            raise McapDamageError(f"a chunk of {size} bytes whose zstd frame claims {claimed}")
        data: bytes = zstandard.ZstdDecompressor().decompress(chunk.data, max_output_size=size)
        return data
    if chunk.compression == "lz4":
        claimed = lz4.frame.get_frame_info(chunk.data).get("content_size") or size
        if claimed != size:
            raise McapDamageError(f"a chunk of {size} bytes whose lz4 frame claims {claimed}")
        decompressor = lz4.frame.LZ4FrameDecompressor()
        return bytes(decompressor.decompress(chunk.data, max_length=size))
    raise McapDamageError(f"unsupported chunk compression {chunk.compression!r}")


def records_in(data: bytes) -> Iterator[tuple[int, int, int]]:
    """(opcode, start, end) of each record in a chunk's decompressed data.

    Raises:
        McapError: a record running past its chunk.
        struct.error: a record header cut short.
    """
    position, size = 0, len(data)
    while position < size:
        opcode, length = _HEADER.unpack_from(data, position)
        start, position = position + _HEADER.size, position + _HEADER.size + length
        if position > size:
            raise McapDamageError(f"a record of {length} bytes runs past its chunk")
        yield opcode, start, position


_MESSAGE_TIME = struct.Struct("<HIQ")  # channel, sequence, log time


class _Recovered:
    """What a linear read of an MCAP file's data section has found so far."""

    def __init__(self) -> None:
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.chunks: list[ChunkIndex] = []
        self.counts: Counter[int] = Counter()
        self.times: list[int] = []
        self.lost_chunks = 0

    def record(self, opcode: int, content: bytes) -> None:
        """Keep a schema or channel record (messages are counted by :meth:`chunk`)."""
        if opcode == Opcode.SCHEMA:
            schema = Schema.read(_within(content))
            self.schemas[schema.id] = schema
        elif opcode == Opcode.CHANNEL:
            channel = Channel.read(_within(content))
            self.channels[channel.id] = channel

    def chunk(self, offset: int, length: int, content: bytes) -> None:
        """Index a chunk and keep the schemas, channels and message counts inside it."""
        chunk = Chunk.read(_within(content))
        data = decompress(chunk)
        counts: Counter[int] = Counter()
        first, last = None, None
        for opcode, start, end in records_in(data):
            if opcode == Opcode.MESSAGE:
                channel, _, log_time = _MESSAGE_TIME.unpack_from(data, start)
                counts[channel] += 1
                first = log_time if first is None else min(first, log_time)
                last = log_time if last is None else max(last, log_time)
            else:
                self.record(opcode, data[start:end])
        if first is None or last is None:
            return
        self.counts.update(counts)
        self.times += [first, last]
        self.chunks.append(
            ChunkIndex(
                message_start_time=first,
                message_end_time=last,
                chunk_start_offset=offset,
                chunk_length=_HEADER.size + length,
                message_index_offsets={},
                message_index_length=0,
                compression=chunk.compression,
                compressed_size=len(chunk.data),
                uncompressed_size=chunk.uncompressed_size,
            )
        )

    def summary(self) -> Summary:
        """The summary of what was found: chunk indexes without message indexes (each chunk
        is read whole), and statistics for the messages counted."""
        summary = Summary()
        summary.schemas, summary.channels = dict(self.schemas), dict(self.channels)
        summary.chunk_indexes = list(self.chunks)
        summary.statistics = Statistics(
            message_count=sum(self.counts.values()),
            schema_count=len(self.schemas),
            channel_count=len(self.channels),
            attachment_count=0,
            metadata_count=0,
            chunk_count=len(self.chunks),
            message_start_time=min(self.times, default=0),
            message_end_time=max(self.times, default=0),
            channel_message_counts=dict(self.counts),
        )
        return summary


# What a damaged chunk raises when it is decompressed and parsed.
_CHUNK_DAMAGE = (McapError, struct.error, ValueError, EOFError, zstandard.ZstdError, RuntimeError)


def scan_summary(stream: BoundedFile) -> tuple[Summary, str] | None:
    """A summary rebuilt from the data section, read record by record from the start, and a
    note of how far it got; None when no chunked message is found (a file of unchunked
    messages is read linearly without one).

    A damaged chunk is passed over (its messages lost); a record header that claims more than
    the file holds ends the read there, as a cut file does.
    """
    found, position = _Recovered(), 8
    stop = "to its end"
    while position + _HEADER.size <= stream.size:
        stream.seek(position)
        opcode, length = _HEADER.unpack(stream.read(_HEADER.size))
        if opcode in (Opcode.DATA_END, Opcode.FOOTER):
            break
        if length > stream.size - position - _HEADER.size:
            stop = (
                f"up to byte {position:,} of {stream.size:,} (a record there runs past the "
                "end: the file is cut short)"
            )
            break
        if opcode in (Opcode.CHUNK, Opcode.SCHEMA, Opcode.CHANNEL):
            content = stream.read(length)
            try:
                if opcode == Opcode.CHUNK:
                    found.chunk(position, length, content)
                else:
                    found.record(opcode, content)
            except _CHUNK_DAMAGE:
                found.lost_chunks += opcode == Opcode.CHUNK
        position += _HEADER.size + length
    if not found.chunks:
        return None
    summary = found.summary()
    lost = f", {found.lost_chunks} damaged chunk(s) passed over" if found.lost_chunks else ""
    assert summary.statistics is not None
    return summary, (
        f"read {stop} without its index: {summary.statistics.message_count:,} messages "
        f"in {len(found.chunks):,} chunks{lost}"
    )


def summary_problem(summary: Summary | None) -> str | None:
    """What makes a summary unusable (missing, without statistics, or naming channels and
    schemas it does not hold); None when it can be used."""
    if summary is None:
        return "it has no summary section"
    if summary.statistics is None:
        return "its summary has no statistics"
    channels = set(summary.channels)
    for index in summary.chunk_indexes:
        if not set(index.message_index_offsets) <= channels:
            return "its chunk index names channels its summary does not hold"
    if not set(summary.statistics.channel_message_counts) <= channels:
        return "its statistics name channels its summary does not hold"
    for channel in summary.channels.values():
        if channel.schema_id and channel.schema_id not in summary.schemas:
            return f"channel {channel.topic} names a schema its summary does not hold"
    return None
