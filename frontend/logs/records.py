"""What reading a log gives and raises: its topics, its decoded messages, the messages skipped,
and the error that names what cannot be read."""

from __future__ import annotations

import struct
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zstandard
from mcap.exceptions import (
    DecoderNotFoundError,
    EndOfFile,
    InvalidMagic,
    McapError,
    RecordLengthLimitExceeded,
    UnsupportedCompressionError,
)

from markergraph.common.errors import MarkerGraphError

__all__ = ["DecodeFailures", "LogError", "LogTopic", "McapDamageError", "Message", "why"]


class LogError(MarkerGraphError):
    """A log that cannot be read, or a message that cannot be decoded; the message names it."""


@dataclass(frozen=True)
class LogTopic:
    """One topic of a log: its name, message type and number of messages."""

    topic: str
    """The topic's name."""
    schema: str
    """Its message type (``sensor_msgs/msg/Image``); "" where the log gives none."""
    count: int
    """Its number of messages, over all the log's files."""


@dataclass(frozen=True)
class Message:
    """A decoded message with where it came from."""

    topic: str
    """The topic it was logged on."""
    schema: str
    """Its message type."""
    log_time_ns: int
    """When it was logged [ns]."""
    decoded: Any
    """The message itself (attribute access by its ROS or protobuf field names)."""


@dataclass
class DecodeFailures:
    """Messages that could not be read and were skipped: (file, topic) -> count, and the first
    reason of each, for one warning line apiece."""

    counts: Counter[tuple[str, str]] = field(default_factory=Counter)
    """(file, topic) -> messages skipped."""
    first_error: dict[tuple[str, str], str] = field(default_factory=dict)
    """(file, topic) -> why the first of them was."""
    reasons: dict[tuple[str, str], set[str]] = field(default_factory=dict)
    """(file, topic) -> every different reason (each damaged chunk is one: its byte)."""
    notes: list[str] = field(default_factory=list)
    """What was lost or recovered of a whole file (a cut tail, an index rebuilt, a loss that
    cannot be counted), one line each."""

    def add(self, file: Path, topic: str, reason: str, n: int = 1) -> None:
        """Count ``n`` skipped messages of ``topic`` in ``file``, for ``reason``."""
        key = (str(file), topic)
        self.counts[key] += n
        self.first_error.setdefault(key, reason)
        self.reasons.setdefault(key, set()).add(reason)

    def note(self, file: Path, text: str) -> None:
        """Say once what happened to a whole file."""
        line = f"{file}: {text}"
        if line not in self.notes:
            self.notes.append(line)

    def merge(self, other: DecodeFailures) -> None:
        """Add another reader's failures: counts summed, each first reason and note kept
        once (every stretch of a log reads the same damaged index and says so)."""
        self.counts.update(other.counts)
        for key, reason in other.first_error.items():
            self.first_error.setdefault(key, reason)
        for key, reasons in other.reasons.items():
            self.reasons.setdefault(key, set()).update(reasons)
        self.notes += [line for line in other.notes if line not in self.notes]

    @classmethod
    def merged(cls, many: Iterable[DecodeFailures]) -> DecodeFailures:
        """Several readers' failures as one (:meth:`merge`)."""
        joined = cls()
        for failures in many:
            joined.merge(failures)
        return joined

    def warnings(self) -> list[str]:
        """The files' notes, then one line per (file, topic): how many were skipped, and the
        first reason."""
        return self.notes + [
            f"{file}: skipped {n} unreadable message(s) on {topic} "
            f"({self.first_error[(file, topic)]}{self._more((file, topic))})"
            for (file, topic), n in sorted(self.counts.items())
        ]

    def _more(self, key: tuple[str, str]) -> str:
        """How many other places (damaged chunks, records) cost messages of the topic."""
        more = len(self.reasons.get(key, ())) - 1
        return f"; and {more} other place{'s' if more > 1 else ''}" if more > 0 else ""


class McapDamageError(McapError):
    """Damage our own reading found in an MCAP file; its text is ours, naming the byte."""


def why(error: BaseException) -> str:
    """A reading error as a reason in a message, in our words: the mcap package's and the
    decompressors' own texts name their internals (opcodes, limits, frames), not the file."""
    if isinstance(error, McapDamageError):
        return str(error)
    if isinstance(error, OSError) and error.strerror:
        return error.strerror
    for kinds, words in _IN_WORDS:
        if isinstance(error, kinds):
            return words
    return "a damaged record"


# What each error a read raises means for the file, most specific first.
_IN_WORDS: tuple[tuple[type[BaseException] | tuple[type[BaseException], ...], str], ...] = (
    (RecordLengthLimitExceeded, "a record claims more bytes than the file holds"),
    (InvalidMagic, "it does not end as an MCAP file ends (cut short, or never closed)"),
    ((EndOfFile, EOFError, struct.error), "the file ends inside a record"),
    (UnsupportedCompressionError, "a chunk in a compression this reader does not know"),
    (DecoderNotFoundError, "messages in an encoding this reader does not know"),
    ((zstandard.ZstdError, RuntimeError), "a chunk whose compressed data does not decompress"),
)
