"""MCAP logs (one ``.mcap`` file or a rosbag2 folder of them): each file's summary read once,
and from it the topics, the time range and the decoded messages."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcap.exceptions import McapError
from mcap.summary import Summary
from mcap_ros2.decoder import DecoderFactory

from markergraph.frontend.logs.cdr import FAST_DECODERS
from markergraph.frontend.logs.chunks import DAMAGE, summary_records
from markergraph.frontend.logs.files import MCAP_MAGIC
from markergraph.frontend.logs.records import (
    DecodeFailures,
    LogError,
    LogTopic,
    McapDamageError,
    Message,
    why,
)
from markergraph.frontend.logs.scan import BoundedFile, read_summary, scan_summary, summary_problem

__all__ = ["McapFile", "mcap_messages", "mcap_time_range", "mcap_topics", "open_mcap_file"]

# What reading a summary raises that says the file is incomplete (truncated, being written).
_INCOMPLETE = (McapError, ValueError, EOFError, OSError)


@dataclass(frozen=True, eq=False)
class McapFile:
    """One MCAP file of a log and its summary, read once when the log is opened."""

    path: Path
    """The file."""
    summary: Summary | None
    """Its summary section; None when it has none or it could not be read."""
    error: BaseException | None = None
    """Why the summary could not be read (raised, as a :class:`LogError`, where it is needed)."""
    recovered: str | None = None
    """Set when the summary was rebuilt from the data section: why, and what was found."""

    def complete_summary(self) -> Summary:
        """The summary, with its statistics.

        Raises:
            LogError: an incomplete file, or one without a summary or statistics.
        """
        if isinstance(self.error, _INCOMPLETE):
            raise LogError(
                f"{self.path}: not a complete MCAP file (truncated, or still being written): "
                f"{why(self.error)}"
            ) from self.error
        if self.error is not None:
            raise self.error
        if self.summary is None or self.summary.statistics is None:
            raise LogError(f"{self.path}: no summary section (a truncated or unfinished recording)")
        return self.summary


# What a file given as a log most often is instead, by its first bytes (eight are read).
_LOGS = "markergraph reads MCAP files, rosbag2 folders and ROS 1 bags"
_OTHER_FILES = {
    b"\xff\xd8\xff": f"a JPEG image, not a recording: {_LOGS}",
    b"\x89PNG": f"a PNG image, not a recording: {_LOGS}",
    b"SQLite f": "a SQLite database: give the rosbag2 folder that holds it with its metadata.yaml",
}


def _what_instead(magic: bytes) -> str:
    return next((f" ({what})" for head, what in _OTHER_FILES.items() if magic.startswith(head)), "")


def open_mcap_file(file: Path) -> McapFile:
    """A file's magic checked and its summary read, in one opening of it; a summary that is
    missing or damaged is rebuilt from the data section where it holds chunked messages.

    Raises:
        LogError: it cannot be read, or it is not an MCAP file.
    """
    try:
        with open(file, "rb") as raw:
            magic = raw.read(len(MCAP_MAGIC))
            if magic != MCAP_MAGIC:
                raise LogError(f"{file}: not an MCAP file{_what_instead(magic)}")
            stream = BoundedFile(raw)
            summary, error = None, None
            try:
                summary = read_summary(stream)
                problem = summary_problem(summary)
            except (*DAMAGE, OSError) as raised:
                error, problem = raised, f"its summary cannot be read ({why(raised)})"
            if problem is None:
                return McapFile(file, summary)
            rebuilt = scan_summary(stream)
            if rebuilt is None:  # nothing chunked to rebuild from
                unusable = McapDamageError(problem) if summary is not None else None
                return McapFile(file, None, error or unusable)
            return McapFile(file, rebuilt[0], recovered=f"{problem}; {rebuilt[1]}")
    except OSError as error:
        raise LogError(f"{file}: cannot read it ({error.strerror})") from None


def mcap_topics(files: tuple[McapFile, ...]) -> list[LogTopic]:
    """Every topic with its type and message count, over all the files.

    Raises:
        LogError: a file without a complete summary.
    """
    counts: dict[str, LogTopic] = {}
    for file in files:
        summary = file.complete_summary()
        assert summary.statistics is not None  # for the type checker: complete_summary says so
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


def mcap_time_range(path: Path, files: tuple[McapFile, ...]) -> tuple[int, int]:
    """The first and last message log times over all the files [ns].

    Raises:
        LogError: a file without a complete summary, or no messages in any.
    """
    first, last = None, None
    for file in files:
        statistics = file.complete_summary().statistics
        if statistics is not None and statistics.message_count:
            start, end = statistics.message_start_time, statistics.message_end_time
            first = start if first is None else min(first, start)
            last = end if last is None else max(last, end)
    if first is None or last is None:
        raise LogError(f"{path}: no messages")
    return int(first), int(last)


def mcap_messages(
    files: tuple[McapFile, ...],
    topics: list[str],
    failures: DecodeFailures | None = None,
    start_ns: int | None = None,
    end_ns: int | None = None,
) -> Iterator[Message]:
    """Decoded messages of the given topics, file after file, in log-time order within each;
    see :meth:`markergraph.frontend.logs.Log.messages`."""
    factory = DecoderFactory()
    for file in files:
        if file.error is not None:
            raise LogError(
                f"{file.path}: not a complete MCAP file ({why(file.error)})"
            ) from file.error
        if file.recovered and failures is not None:
            failures.note(file.path, file.recovered)
        with open(file.path, "rb") as stream:
            decoders: dict[int, Callable[[bytes | memoryview], Any]] = {}
            for schema, channel, message in summary_records(
                file.path, stream, file.summary, topics, start_ns, end_ns, failures
            ):
                decode = decoders.get(channel.id)
                if decode is None:
                    decode = _decoder_for(file.path, channel, schema, factory)
                    decoders[channel.id] = decode
                try:
                    decoded = decode(message.data)
                except Exception as error:  # decoders raise types of their own
                    if failures is None:
                        raise LogError(
                            f"{file.path}: cannot decode a message on {channel.topic} "
                            f"({_undecodable(schema)})"
                        ) from error
                    failures.add(file.path, channel.topic, _undecodable(schema))
                    continue
                yield Message(
                    channel.topic, schema.name if schema else "", message.log_time, decoded
                )


def _undecodable(schema: Any) -> str:
    """Why a message was skipped, in our words: the decoder's own text names its internals."""
    return f"its bytes do not decode as {schema.name}" if schema else "its bytes do not decode"


def _decoder_for(
    file: Path, channel: Any, schema: Any, factory: DecoderFactory
) -> Callable[[bytes | memoryview], Any]:
    """The fast reader for the channel's type if there is one, else mcap-ros2-support's."""
    if channel.message_encoding not in ("cdr", "protobuf"):
        raise LogError(
            f"{file}: topic {channel.topic} has message encoding "
            f"{channel.message_encoding!r}; ROS 2 CDR and protobuf are read"
        )
    if channel.message_encoding == "cdr" and schema is not None and schema.name in FAST_DECODERS:
        return FAST_DECODERS[schema.name]
    if channel.message_encoding == "cdr":
        chosen: Any = factory
    else:  # Foxglove's schemas alone: protobuf's 30 ms of imports wait for one
        from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoderFactory

        chosen = ProtobufDecoderFactory()
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
    found: Callable[[bytes | memoryview], Any] = decoder
    return lambda data: found(bytes(data))  # a chunk's message is a view; these want bytes
