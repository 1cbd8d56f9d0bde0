"""Each topic's first and last log time in an MCAP file, from its message indexes where they
can be read, else from its messages read undecoded."""

from __future__ import annotations

from pathlib import Path
from typing import IO, Any, cast

from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.records import MessageIndex

from markergraph.frontend.logs.chunks import summary_records
from markergraph.frontend.logs.records import DecodeFailures, LogError, why
from markergraph.frontend.logs.scan import BoundedFile

__all__ = ["mcap_topic_spans"]

# What reading a summary raises that says the file is incomplete.
_INCOMPLETE = (McapError, ValueError, EOFError, OSError)


def mcap_topic_spans(
    file: Path, summary: Any, error: BaseException | None
) -> list[tuple[str, int, int]]:
    """(topic, first, last log time [ns]) of each topic with messages in one MCAP file.

    Args:
        file: the file.
        summary: its summary as read when the log was opened (None: it has none).
        error: why that summary could not be read, if it could not.

    Raises:
        LogError: an incomplete file, or one damaged past its index.
    """
    if isinstance(error, _INCOMPLETE):
        raise LogError(f"{file}: not a complete MCAP file ({why(error)})") from error
    if error is not None:
        raise error
    with open(file, "rb") as raw:
        stream = BoundedFile(raw)
        spans = _indexed_spans(stream, summary)
        if spans is None:
            spans = _read_spans(file, stream, summary)
    return [(topic, min(times), max(times)) for topic, times in spans.items()]


def _indexed_spans(stream: BoundedFile, summary: Any) -> dict[str, list[int]] | None:
    """Topic -> its first and last times, from the message indexes; None where the file has
    none (some chunk unindexed) or they are damaged."""
    indexed = bool(
        summary is not None
        and summary.chunk_indexes
        and all(c.message_index_offsets for c in summary.chunk_indexes)
    )
    if not indexed:
        return None
    spans: dict[str, list[int]] = {}
    try:
        for chunk in summary.chunk_indexes:
            for channel_id, offset in chunk.message_index_offsets.items():
                stream.seek(offset + 1 + 8)  # past the record's opcode and length
                times = [
                    t for t, _ in MessageIndex.read(ReadDataStream(cast(IO[bytes], stream))).records
                ]
                if times:
                    topic = summary.channels[channel_id].topic
                    spans.setdefault(topic, []).extend((min(times), max(times)))
    except (McapError, ValueError, EOFError, KeyError):  # a damaged index: read instead
        return None
    return spans


def _read_spans(file: Path, stream: BoundedFile, summary: Any) -> dict[str, list[int]]:
    """Topic -> its messages' times, every message read (undecoded; a damaged chunk passed
    over, as when the messages are read to be decoded)."""
    spans: dict[str, list[int]] = {}
    records = summary_records(file, stream, summary, None, None, None, DecodeFailures())
    for _, channel, message in records:
        spans.setdefault(channel.topic, []).append(message.log_time)
    return spans
