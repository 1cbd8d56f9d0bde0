"""Reading logs without ROS: a single ``.mcap`` or a rosbag2 folder of them (read here, chunk by
chunk, so that damage costs only the damaged stretch), a ROS 1 ``.bag`` or a rosbag2 SQLite
folder (read through ``rosbags``, in :mod:`markergraph.frontend.bags`); their topics and their
messages, decoded."""

from __future__ import annotations

import heapq
import queue
import struct
import threading
from collections import Counter
from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import lz4.frame
import yaml
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Chunk, MessageIndex
from mcap.records import Message as McapMessage
from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoderFactory
from mcap_ros2.decoder import DecoderFactory

from markergraph.common.errors import MarkerGraphError
from markergraph.frontend.cdr import FAST_DECODERS

__all__ = [
    "DecodeFailures",
    "LogError",
    "LogTopic",
    "Message",
    "log_files",
    "log_time_range",
    "log_topics",
    "messages",
    "read_ahead",
]

MCAP_MAGIC = b"\x89MCAP0\r\n"


class LogError(MarkerGraphError):
    """A log that cannot be read, or a message that cannot be decoded; the message names it."""


@dataclass(frozen=True)
class LogTopic:
    """One topic of a log: its name, message type and number of messages."""

    topic: str
    schema: str
    count: int


@dataclass(frozen=True)
class Message:
    """A decoded message with where it came from."""

    topic: str
    schema: str
    log_time_ns: int
    decoded: Any


def log_files(path: Path) -> list[Path]:
    """The MCAP files of a log: the file itself, or a rosbag2 folder's files in order.

    A rosbag2 folder lists its files in ``metadata.yaml`` (``relative_file_paths``); without
    one, its ``.mcap`` files are read in name order. A ``metadata.yaml`` that cannot be read is
    an error, never a silent fallback to whatever ``.mcap`` files the folder holds.

    Raises:
        LogError: no such log, a broken ``metadata.yaml``, a listed file missing, or a file
            that is not MCAP; the message names the file.
    """
    path = Path(path)
    if path.is_dir():
        metadata = path / "metadata.yaml"
        if metadata.is_file():
            files = [_bag_file(path, name) for name in _relative_file_paths(metadata)]
        else:
            files = sorted(path.glob("*.mcap"))
        if not files:
            raise LogError(f"{path}: a folder with no .mcap files and no metadata.yaml listing any")
        missing = [f for f in files if not f.is_file()]
        if missing:
            raise LogError(f"{path}: metadata.yaml lists {missing[0].name}, which is missing")
    elif path.is_file():
        files = [path]
    else:
        raise LogError(f"{path}: no such file or folder")
    for file in files:
        try:
            with open(file, "rb") as stream:
                magic = stream.read(len(MCAP_MAGIC))
        except OSError as error:
            raise LogError(f"{file}: cannot read it ({error.strerror})") from None
        if magic != MCAP_MAGIC:
            raise LogError(f"{file}: not an MCAP file")
    return files


def _bag_file(folder: Path, name: str) -> Path:
    """A file a rosbag2 ``metadata.yaml`` lists, inside the bag's folder.

    Raises:
        LogError: the name leads outside the folder (an absolute path or ``..``).
    """
    file = folder / name
    parts = Path(name).parts
    if not file.exists() and len(parts) > 1 and parts[0] == folder.name:
        file = folder.joinpath(*parts[1:])  # Foxy wrote the names under the bag's own folder
    if not file.resolve().is_relative_to(folder.resolve()):
        raise LogError(f"{folder / 'metadata.yaml'}: lists {name}, outside the bag's folder")
    return file


def _relative_file_paths(metadata: Path) -> list[str]:
    """``rosbag2_bagfile_information.relative_file_paths`` of a rosbag2 ``metadata.yaml``.

    Raises:
        LogError: the file is not such a metadata file, naming it.
    """
    try:
        document = yaml.safe_load(metadata.read_text(encoding="utf-8"))
        names = document["rosbag2_bagfile_information"]["relative_file_paths"]
    except (OSError, UnicodeDecodeError, yaml.YAMLError, KeyError, TypeError) as error:
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise LogError(
            f"{metadata}: not a rosbag2 metadata file ({reason}); fix or remove it"
        ) from None
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise LogError(f"{metadata}: relative_file_paths is not a list of file names")
    return names


def _bags() -> Any:
    """The ROS 1 / SQLite reader, imported where a log needs it (it loads rosbags)."""
    from markergraph.frontend import bags

    return bags


def _is_bag(path: Path) -> bool:
    from markergraph.frontend.bags import is_bag

    return is_bag(path)


def log_topics(path: Path) -> list[LogTopic]:
    """Every topic with its type and message count, over all the log's files."""
    if _is_bag(path):
        return list(_bags().log_topics(path))
    counts: dict[str, LogTopic] = {}
    for file in log_files(path):
        with open(file, "rb") as stream:
            try:
                summary = make_reader(stream).get_summary()
            except (McapError, ValueError, EOFError, OSError) as error:
                raise LogError(
                    f"{file}: not a complete MCAP file (truncated, or still being written): {error}"
                ) from error
            if summary is None or summary.statistics is None:
                raise LogError(f"{file}: no summary section (a truncated or unfinished recording)")
            for channel in summary.channels.values():
                schema = summary.schemas.get(channel.schema_id)
                n = summary.statistics.channel_message_counts.get(channel.id, 0)
                previous = counts.get(channel.topic)
                counts[channel.topic] = LogTopic(
                    channel.topic,
                    schema.name if schema else "",
                    n + (previous.count if previous else 0),
                )
    return sorted(counts.values(), key=lambda t: t.topic)


@dataclass
class DecodeFailures:
    """Messages that could not be read and were skipped: (file, topic) -> count, and the first
    reason of each, for one warning line apiece."""

    counts: Counter[tuple[str, str]] = field(default_factory=Counter)
    first_error: dict[tuple[str, str], str] = field(default_factory=dict)

    def add(self, file: Path, topic: str, reason: str, n: int = 1) -> None:
        key = (str(file), topic)
        self.counts[key] += n
        self.first_error.setdefault(key, reason)

    def warnings(self) -> list[str]:
        return [
            f"{file}: skipped {n} unreadable message(s) on {topic} "
            f"({self.first_error[(file, topic)]})"
            for (file, topic), n in sorted(self.counts.items())
        ]


def _why(error: BaseException) -> str:
    return f"{type(error).__name__}: {error}"


def messages(
    path: Path,
    topics: list[str],
    failures: DecodeFailures | None = None,
    start_ns: int | None = None,
    end_ns: int | None = None,
) -> Iterator[Message]:
    """Decoded messages of the given topics, file after file, in log-time order within each.

    A few high-rate types use fixed-layout readers (:mod:`markergraph.frontend.cdr`); the rest
    go through mcap-ros2-support (or mcap-protobuf-support for Foxglove schemas); with
    ``start_ns``/``end_ns`` only log times in [start, end) are read, from the chunks holding
    them. With ``failures``, a message that does not decode is skipped and counted there, and
    so are a damaged chunk's messages (a damaged stretch of a long log costs that stretch);
    without it, either raises.

    Raises:
        LogError: an unreadable file, a channel whose encoding or schema cannot be decoded, or
            (without ``failures``) an undecodable message or a damaged chunk.
    """
    if _is_bag(path):
        yield from _bags().messages(path, topics, failures, start_ns, end_ns)
        return
    factory = DecoderFactory()
    for file in log_files(path):
        with open(file, "rb") as stream:
            decoders: dict[int, Callable[[bytes], Any]] = {}
            for schema, channel, message in _raw_messages(
                file, stream, topics, start_ns, end_ns, failures
            ):
                decode = decoders.get(channel.id)
                if decode is None:
                    decode = _decoder_for(file, channel, schema, factory)
                    decoders[channel.id] = decode
                try:
                    decoded = decode(message.data)
                except Exception as error:  # decoders raise types of their own
                    if failures is None:
                        raise LogError(
                            f"{file}: cannot decode a message on {channel.topic} ({_why(error)})"
                        ) from error
                    failures.add(file, channel.topic, _why(error))
                    continue
                yield Message(
                    channel.topic, schema.name if schema else "", message.log_time, decoded
                )


READ_AHEAD_BATCH = 8


def read_ahead(items: Iterator[Any], size: int = 32) -> Iterator[Any]:
    """``items``, produced by a thread of their own about ``size`` ahead of the consumer.

    Reading a log (file reads, zstd, record parsing; the front end decodes images there too)
    then overlaps detecting them: zstd, the JPEG decoder and OpenCV release the GIL, so one
    process keeps a second core busy. Items cross in batches of :data:`READ_AHEAD_BATCH`, so
    up to ``size`` items wait in the queue besides the batch each thread holds. An error raised
    while producing is raised here, after the items before it; a consumer that stops early
    stops the thread at its next batch. MCAP chunks arrive in bursts: before batching, one
    process read 374-407 frames/s on bench_frontend holding 8 messages, 461-503 holding 32 or
    64 (a few tens of MB of images and depth).
    """
    # Items cross in batches: a lock handed between threads per item cost the consumer more
    # than the items themselves on a log of small messages.
    batch = max(1, min(READ_AHEAD_BATCH, size))
    buffer: queue.Queue[tuple[str, Any]] = queue.Queue(max(1, size // batch))
    stop = threading.Event()

    def offer(entry: tuple[str, Any]) -> bool:
        """Put ``entry`` when there is room; False once the consumer has stopped."""
        while not stop.is_set():
            try:
                buffer.put(entry, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def produce() -> None:
        pending: list[Any] = []
        try:
            for item in items:
                pending.append(item)
                if len(pending) == batch:
                    if not offer(("items", pending)):
                        return
                    pending = []
            offer(("items", pending))
            offer(("end", None))
        except BaseException as error:  # handed to the consumer, which raises it
            if offer(("items", pending)):
                offer(("error", error))
        finally:
            close = getattr(items, "close", None)
            if close is not None:  # a generator: its files are closed here, in its thread
                close()

    thread = threading.Thread(target=produce, name="markergraph-read-ahead", daemon=True)
    thread.start()
    try:
        while True:
            kind, value = buffer.get()
            if kind == "end":
                return
            if kind == "error":
                raise value
            yield from value
    finally:
        stop.set()
        thread.join()


# What a damaged chunk raises: the record parser's errors, and the decompressors' own types.
_DAMAGE = (McapError, EOFError, struct.error, ValueError, zstandard.ZstdError, RuntimeError)


def _raw_messages(
    file: Path,
    stream: BinaryIO,
    topics: list[str],
    start_ns: int | None,
    end_ns: int | None,
    failures: DecodeFailures | None,
) -> Iterator[tuple[Any, Any, Any]]:
    """(schema, channel, message) records in log-time order, read chunk by chunk through the
    summary's chunk index, so that a chunk that does not decompress or parse costs only its own
    messages. The chunks are merged as mcap's own reader merges them (by log time)."""
    reader = make_reader(stream)
    try:
        summary = reader.get_summary()
    except (*_DAMAGE, OSError) as error:
        raise LogError(f"{file}: not a complete MCAP file ({_why(error)})") from error
    if summary is None or not summary.chunk_indexes:  # unindexed: mcap reads it linearly
        try:
            yield from reader.iter_messages(
                topics=topics, start_time=start_ns, end_time=end_ns, log_time_order=True
            )
        except _DAMAGE as error:
            raise LogError(f"{file}: damaged ({_why(error)})") from error
        return
    wanted = {cid for cid, channel in summary.channels.items() if channel.topic in topics}
    chunks = sorted(
        (
            c
            for c in summary.chunk_indexes
            if (start_ns is None or c.message_end_time >= start_ns)
            and (end_ns is None or c.message_start_time < end_ns)
            and (not c.message_index_offsets or wanted & set(c.message_index_offsets))
        ),
        key=lambda c: (c.message_start_time, c.chunk_start_offset),
    )
    pending: list[tuple[int, int, int, Any]] = []  # (log time, chunk, index, message)
    next_chunk = 0
    while next_chunk < len(chunks) or pending:
        # A chunk is opened once no pending message can come after its first one.
        while next_chunk < len(chunks) and (
            not pending or chunks[next_chunk].message_start_time <= pending[0][0]
        ):
            index = chunks[next_chunk]
            try:
                stream.seek(index.chunk_start_offset + 1 + 8)
                records = _chunk_messages(Chunk.read(ReadDataStream(stream)), wanted)
            except _DAMAGE as error:
                if failures is None:
                    raise LogError(f"{file}: damaged chunk ({_why(error)})") from error
                for topic, n in _indexed_counts(stream, summary, index, wanted).items():
                    failures.add(file, topic, f"a damaged chunk: {_why(error)}", n)
                records = []
            for position, record in enumerate(records):
                if (start_ns is None or record.log_time >= start_ns) and (
                    end_ns is None or record.log_time < end_ns
                ):
                    heapq.heappush(pending, (record.log_time, next_chunk, position, record))
            next_chunk += 1
        if pending:
            record = heapq.heappop(pending)[3]
            channel = summary.channels[record.channel_id]
            yield summary.schemas.get(channel.schema_id), channel, record


_RECORD = struct.Struct("<BQ")  # opcode, content length
_MESSAGE = struct.Struct("<HIQQ")  # channel, sequence, log time, publish time
_MESSAGE_OPCODE = 0x05


def _chunk_messages(chunk: Chunk, wanted: Collection[int]) -> list[McapMessage]:
    """The messages of the wanted channels in a chunk, in the chunk's order.

    mcap's ``breakup_chunk`` parses every record through a stream object: on a robot's log
    (ten messages a frame, raw depth) that cost 0.6 ms a frame of Python holding the GIL,
    more than zstd's decompression (which releases it); this reads the records in place, about
    18x cheaper (0.09 s against 1.6 s over bench_frontend's 1,351 chunks). Other records
    (schemas and channels repeated in chunks) are passed over: the summary's are used.

    Raises:
        McapError: a compression this reader lacks, or a record running past the chunk.
        zstandard.ZstdError, RuntimeError (lz4), struct.error: damaged data.
    """
    if chunk.compression == "zstd":
        data = zstandard.decompress(chunk.data, chunk.uncompressed_size)
    elif chunk.compression == "lz4":
        data = lz4.frame.decompress(chunk.data)
    elif chunk.compression == "":
        data = chunk.data
    else:
        raise McapError(f"unsupported chunk compression {chunk.compression!r}")
    found, position, size = [], 0, len(data)
    while position < size:
        opcode, length = _RECORD.unpack_from(data, position)
        start, position = position + _RECORD.size, position + _RECORD.size + length
        if position > size:
            raise McapError(f"a record of {length} bytes runs past its chunk")
        if opcode != _MESSAGE_OPCODE:
            continue
        if length < _MESSAGE.size:
            raise McapError(f"a message record of {length} bytes")
        channel, sequence, log_time, publish_time = _MESSAGE.unpack_from(data, start)
        if channel in wanted:
            found.append(
                McapMessage(channel, log_time, data[start + _MESSAGE.size : position],
                            publish_time, sequence)
            )  # fmt: skip
    return found


def _indexed_counts(stream: BinaryIO, summary: Any, index: Any, wanted: set[int]) -> Counter[str]:
    """How many messages of each wanted topic a chunk held, from its message indexes (which
    lie outside the chunk's compressed data); empty where they cannot be read."""
    counts: Counter[str] = Counter()
    for channel_id, offset in index.message_index_offsets.items():
        if channel_id not in wanted:
            continue
        try:
            stream.seek(offset + 1 + 8)
            entries = MessageIndex.read(ReadDataStream(stream)).records
        except _DAMAGE:
            continue
        counts[summary.channels[channel_id].topic] += len(entries)
    return counts


def _decoder_for(
    file: Path, channel: Any, schema: Any, factory: DecoderFactory
) -> Callable[[bytes], Any]:
    """The fast reader for the channel's type if there is one, else mcap-ros2-support's."""
    if channel.message_encoding not in ("cdr", "protobuf"):
        raise LogError(
            f"{file}: topic {channel.topic} has message encoding "
            f"{channel.message_encoding!r}; ROS 2 CDR and protobuf are read"
        )
    if channel.message_encoding == "cdr" and schema is not None and schema.name in FAST_DECODERS:
        return FAST_DECODERS[schema.name]
    chosen = factory if channel.message_encoding == "cdr" else ProtobufDecoderFactory()
    try:
        decoder = chosen.decoder_for(channel.message_encoding, schema)
    except Exception as error:  # the vendored rosidl parser raises its own types
        raise LogError(
            f"{file}: topic {channel.topic} has a schema that cannot be parsed "
            f"({type(error).__name__}: {error})"
        ) from error
    if decoder is None:
        raise LogError(
            f"{file}: no decoder for topic {channel.topic} "
            f"(schema {schema.name if schema else None!r})"
        )
    return decoder


def log_time_range(path: Path) -> tuple[int, int]:
    """The first and last message log times over all the log's files [ns]."""
    if _is_bag(path):
        first, last = _bags().log_time_range(path)
        return int(first), int(last)
    first, last = None, None
    for file in log_files(path):
        with open(file, "rb") as stream:
            statistics = make_reader(stream).get_summary().statistics  # type: ignore[union-attr]
        if statistics is not None and statistics.message_count:
            first = (
                statistics.message_start_time
                if first is None
                else min(first, statistics.message_start_time)
            )
            last = (
                statistics.message_end_time
                if last is None
                else max(last, statistics.message_end_time)
            )
    if first is None or last is None:
        raise LogError(f"{path}: no messages")
    return int(first), int(last)
