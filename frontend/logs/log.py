"""A log opened once: its kind, its files, its MCAP summaries, and from them its topics, time
range and messages. Everything that reads a log reads it through a :class:`Log`."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

from markergraph.frontend.logs.files import LogKind, log_kind, mcap_files
from markergraph.frontend.logs.mcap import (
    McapFile,
    mcap_messages,
    mcap_time_range,
    mcap_topics,
    open_mcap_file,
)
from markergraph.frontend.logs.records import DecodeFailures, LogError, LogTopic, Message
from markergraph.frontend.logs.times import mcap_topic_spans

if TYPE_CHECKING:  # bags' readers (rosbags, ROS 1 records) load where a bag is opened
    from markergraph.frontend.logs.bags import BagSummary

__all__ = ["Log", "open_log"]


@dataclass(frozen=True, eq=False)
class Log:
    """An open log: where it is, what kind, which files, and their MCAP summaries.

    What is read from the summaries (topics, time range) is read once, when first asked for;
    a summary that could not be read raises there, naming the file, as it would have when the
    log was opened, so that a log which can still be read message by message (an unindexed
    file) can be. A ``Log`` pickles as its path: a process given one opens the log itself.
    Build one with :func:`open_log`.
    """

    path: Path
    """The log as given: an ``.mcap`` file, a rosbag2 folder or a ROS 1 ``.bag``."""
    kind: LogKind
    """How it is stored, and so which reader reads it."""
    mcap: tuple[McapFile, ...] = ()
    """Its MCAP files with their summaries, in order (none for a ROS 1 or SQLite bag)."""

    def __reduce__(self) -> tuple[Any, tuple[Path]]:
        return (open_log, (self.path,))

    @property
    def files(self) -> tuple[Path, ...]:
        """The files that hold it: its MCAP files, or the bag itself."""
        return tuple(f.path for f in self.mcap) if self.mcap else (self.path,)

    @property
    def notes(self) -> list[str]:
        """What reading its files had to work around, one line each (an index rebuilt, files
        joined with nothing to say they belong together)."""
        joined = [f"{self.path}: {self.joined}"] if self.joined else []
        return joined + [f"{f.path}: {f.recovered}" for f in self.mcap if f.recovered]

    @property
    def joined(self) -> str:
        """Where a folder without ``metadata.yaml`` holds several MCAP files, that they are read
        as one recording (three unrelated logs in one folder were joined without a word)."""
        if len(self.mcap) < 2 or (self.path / "metadata.yaml").is_file():
            return ""
        names = ", ".join(f.path.name for f in self.mcap[:4]) + (
            ", ..." if len(self.mcap) > 4 else ""
        )
        return (
            f"no metadata.yaml: its {len(self.mcap)} .mcap files ({names}) read as one recording, "
            "in name order; give one file to map it alone"
        )

    @cached_property
    def topics(self) -> list[LogTopic]:
        """Every topic with its type and message count over all the files, by name.

        Raises:
            LogError: a file without a complete summary, or a bag that cannot be read.
        """
        if self.kind is LogKind.MCAP:
            return mcap_topics(self.mcap)
        return self._bag.topics

    @cached_property
    def counts(self) -> dict[str, int]:
        """Topic -> its number of messages."""
        return {t.topic: t.count for t in self.topics}

    @cached_property
    def time_range(self) -> tuple[int, int]:
        """The first and last message log times over all the files [ns].

        Raises:
            LogError: no messages, or a summary that cannot be read.
        """
        if self.kind is LogKind.MCAP:
            return mcap_time_range(self.path, self.mcap)
        if not self._bag.message_count:
            raise LogError(f"{self.path}: no messages")
        return self._bag.start_ns, self._bag.end_ns

    @cached_property
    def topic_times(self) -> dict[str, tuple[int, int]]:
        """The first and last log time of each topic that has messages [ns].

        An indexed MCAP file answers from its message indexes, a ROS 1 bag from its index
        records, without decompressing a message; other files are read message by message,
        undecoded.

        Raises:
            LogError: a log that cannot be read, naming the file.
        """
        if self.kind is LogKind.MCAP:
            found = [s for f in self.mcap for s in mcap_topic_spans(f.path, f.summary, f.error)]
        else:
            from markergraph.frontend.logs.bags import bag_topic_spans

            found = bag_topic_spans(self.path)
        spans: dict[str, list[int]] = {}
        for topic, first, last in found:  # a topic may span several files
            spans.setdefault(topic, []).extend((first, last))
        return {topic: (min(times), max(times)) for topic, times in spans.items()}

    def messages(
        self,
        topics: list[str],
        failures: DecodeFailures | None = None,
        start_ns: int | None = None,
        end_ns: int | None = None,
    ) -> Iterator[Message]:
        """Decoded messages of the given topics, file after file, in log-time order within each.

        A few high-rate types use fixed-layout readers (:mod:`~markergraph.frontend.logs.cdr`);
        the rest go through mcap-ros2-support (or mcap-protobuf-support for Foxglove schemas),
        or rosbags for a bag; with ``start_ns``/``end_ns`` only log times in [start, end) are
        read, from the chunks holding them. With ``failures``, a message that does not decode
        is skipped and counted there, and so are a damaged chunk's messages (a damaged stretch
        of a long log costs that stretch); without it, either raises. Each call opens the files
        anew (the summaries are not read again), so that several can be read at once; close
        the iterator (a generator) to close them before it ends.

        Raises:
            LogError: an unreadable file, a channel whose encoding or schema cannot be decoded,
                or (without ``failures``) an undecodable message or a damaged chunk.
        """
        if self.kind is LogKind.MCAP:
            if failures is not None and self.joined:
                failures.note(self.path, self.joined)
            return mcap_messages(self.mcap, topics, failures, start_ns, end_ns)
        from markergraph.frontend.logs.bags import bag_messages

        return bag_messages(self.path, topics, failures, start_ns, end_ns)

    @cached_property
    def _bag(self) -> BagSummary:
        """A ROS 1 or SQLite bag's topics, message count and time range, read once."""
        from markergraph.frontend.logs.bags import bag_summary

        return bag_summary(self.path)


def open_log(path: Path | str) -> Log:
    """A log opened: its kind decided, its files found and each MCAP file's summary read.

    Raises:
        LogError: no such log, a broken rosbag2 ``metadata.yaml``, a listed file missing, or a
            file that is not MCAP (or cannot be read); the message names the file.
    """
    path = Path(path)
    kind = log_kind(path)
    if kind is not LogKind.MCAP:
        return Log(path, kind)
    files = mcap_files(path)
    return Log(path, kind, tuple(open_mcap_file(file) for file in files))
