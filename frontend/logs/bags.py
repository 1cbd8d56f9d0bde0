"""ROS 1 bags (``.bag``) and ROS 2 SQLite bags (a rosbag2 folder of ``.db3`` files): the same
topics and decoded messages as the MCAP reader gives. A ROS 1 bag's records are read by
:mod:`~markergraph.frontend.logs.ros1` (chunk by chunk, so that a damaged chunk costs only its
own messages), a SQLite bag's by the ``rosbags`` library; both decode through ``rosbags``.

Messages decode to rosbags' dataclasses, whose fields carry the ROS names (``header.stamp.sec``,
``nanosec``; ROS 1's ``CameraInfo`` has ``K`` and ``D``), and types are named ROS 2 style
(``nav_msgs/msg/Odometry``, ROS 1's ``tf/msg/tfMessage``). A type the library does not know,
such as TagSLAM's ``apriltag_msgs/ApriltagArrayStamped``, is registered from the definition the
bag carries with its connection; a Humble SQLite bag carries none, and the detection types are
then registered from :data:`~markergraph.frontend.detections.DETECTION_DEFINITIONS`.
"""

from __future__ import annotations

import heapq
import sqlite3
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from markergraph.frontend.detections import DETECTION_DEFINITIONS
from markergraph.frontend.logs.records import DecodeFailures, LogError, LogTopic, Message
from markergraph.frontend.logs.ros1 import DamagedBagError, Ros1Bag, lost_counts, open_ros1

__all__ = ["BagSummary", "bag_messages", "bag_summary", "bag_topic_spans"]


def _why(error: BaseException) -> str:
    """An error as a reason: its type and its text, or where the text is empty (an
    ``AssertionError`` inside a library) its type alone."""
    return f"{type(error).__name__}: {error}" if str(error) else type(error).__name__


def _types(path: Path, ros1: bool, connections: list[tuple[str, str, str]]) -> Any:
    """The type store a bag's messages decode with: rosbags' own types, and those the bag
    defines for itself (or markergraph's detection types where it defines none).

    Args:
        connections: (topic, type, definition as the bag carries it) of each connection.

    Raises:
        LogError: a type definition that cannot be parsed, naming the topic.
    """
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    types = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    for topic, msgtype, definition in connections:
        if msgtype in types.fielddefs:
            continue
        definition = definition or DETECTION_DEFINITIONS.get(msgtype, "")
        if definition:
            try:
                types.register(get_types_from_msg(definition, msgtype))
            except Exception as error:  # rosbags' parser raises its own types, and others
                raise LogError(
                    f"{path}: topic {topic} has a type definition that cannot be parsed "
                    f"({_why(error)})"
                ) from error
    return types


def _decode(path: Path, types: Any, ros1: bool, topic: str, msgtype: str, raw: bytes) -> Any:
    """A message decoded.

    Raises:
        LogError: its type is defined nowhere.
        Exception: rosbags' deserialisers' own, for a damaged message.
    """
    if msgtype not in types.fielddefs:
        raise LogError(
            f"{path}: no definition of {msgtype} (topic {topic}) in the bag or in rosbags' "
            "type store"
        )
    if ros1:
        return types.deserialize_ros1(raw, msgtype)
    return types.deserialize_cdr(raw, msgtype)


def _open_ros1(path: Path) -> Ros1Bag:
    """A ROS 1 bag's index (or a scan of its records).

    Raises:
        LogError: not a readable bag, with the reason and the byte where it lies.
    """
    try:
        return open_ros1(path)
    except DamagedBagError as error:
        raise LogError(f"{path}: not a readable bag ({error})") from error
    except OSError as error:
        raise LogError(f"{path}: cannot be read ({error.strerror or _why(error)})") from error


def _open_sqlite(path: Path) -> Any:
    """A rosbag2 SQLite folder opened with rosbags' reader.

    Raises:
        LogError: not a readable bag (a damaged database among others), with the reason.
    """
    from rosbags.rosbag2 import Reader

    try:
        reader = Reader(path)
        reader.open()
    except Exception as error:  # rosbags raises ReaderError and friends, sqlite3 its own
        raise LogError(f"{path}: not a readable bag ({_why(error)})") from error
    return reader


@dataclass(frozen=True)
class BagSummary:
    """What a bag's index says, read in one opening of it."""

    topics: list[LogTopic]
    """Every topic with its type and message count, by name."""
    message_count: int
    """Messages in all."""
    start_ns: int
    """The first message's time [ns]."""
    end_ns: int
    """The last message's time [ns]."""


def bag_summary(path: Path) -> BagSummary:
    """The topics, message count and time range of a bag.

    Raises:
        LogError: not a readable bag, or a type definition that cannot be parsed.
    """
    if path.is_file():
        return _ros1_summary(path)
    reader = _open_sqlite(path)
    try:
        _types(path, False, [(c.topic, c.msgtype, _definition(c)) for c in reader.connections])
        counts: dict[str, LogTopic] = {}
        for connection in reader.connections:
            previous = counts.get(connection.topic)
            counts[connection.topic] = LogTopic(
                connection.topic,
                connection.msgtype,
                connection.msgcount + (previous.count if previous else 0),
            )
        topics = sorted(counts.values(), key=lambda t: t.topic)
        count = int(reader.message_count or 0)
        if not count:
            return BagSummary(topics, 0, 0, 0)
        return BagSummary(topics, count, int(reader.start_time), int(reader.end_time) - 1)
    except sqlite3.Error as error:
        raise LogError(f"{path}: not a readable bag ({_why(error)})") from error
    finally:
        reader.close()


def _definition(connection: Any) -> str:
    """The type definition a rosbag2 connection carries ("" where none)."""
    return str(getattr(getattr(connection, "msgdef", None), "data", "") or "")


def _ros1_summary(path: Path) -> BagSummary:
    """A ROS 1 bag's summary, from its index (or a scan of its records)."""
    bag = _open_ros1(path)
    _types(path, True, [(c.topic, c.msgtype, c.definition) for c in bag.connections.values()])
    totals: Counter[int] = Counter()
    for chunk in bag.chunks:
        totals.update(chunk.counts)
    counts: dict[str, LogTopic] = {}
    for connection in bag.connections.values():
        previous = counts.get(connection.topic)
        counts[connection.topic] = LogTopic(
            connection.topic,
            connection.msgtype,
            totals[connection.id] + (previous.count if previous else 0),
        )
    topics = sorted(counts.values(), key=lambda t: t.topic)
    count = sum(t.count for t in topics)
    held = [c for c in bag.chunks if any(n and i in bag.connections for i, n in c.counts.items())]
    if not count or not held:
        return BagSummary(topics, 0, 0, 0)
    start_ns = min(c.start_ns for c in held)
    return BagSummary(topics, count, start_ns, max(c.end_ns for c in held))


def bag_messages(
    path: Path,
    topics: list[str],
    failures: DecodeFailures | None,
    start_ns: int | None,
    end_ns: int | None,
) -> Iterator[Message]:
    """Decoded messages of the given topics in time order; see
    :meth:`markergraph.frontend.logs.Log.messages`."""
    if path.is_file():
        yield from _ros1_messages(path, topics, failures, start_ns, end_ns)
        return
    reader = _open_sqlite(path)
    try:
        connections = [c for c in reader.connections if c.topic in topics]
        if not connections:
            return
        types = _types(path, False, [(c.topic, c.msgtype, _definition(c)) for c in connections])
        try:
            for connection, t_ns, raw in reader.messages(
                connections=connections, start=start_ns, stop=end_ns
            ):
                decoded = _decoded(path, types, False, connection.topic, connection.msgtype, raw,
                                   failures)  # fmt: skip
                if decoded is not None:
                    yield Message(connection.topic, connection.msgtype, int(t_ns), decoded)
        except LogError:
            raise
        except Exception as error:  # sqlite3's "database disk image is malformed", and others
            raise LogError(f"{path}: damaged ({_why(error)})") from error
    finally:
        reader.close()


def _decoded(
    path: Path,
    types: Any,
    ros1: bool,
    topic: str,
    msgtype: str,
    raw: bytes,
    failures: DecodeFailures | None,
) -> Any:
    """A message decoded, or None where it does not decode and is counted in ``failures``.

    Raises:
        LogError: its type is defined nowhere, or (without ``failures``) it does not decode.
    """
    try:
        return _decode(path, types, ros1, topic, msgtype, raw)
    except LogError:
        raise
    except Exception as error:  # rosbags' deserialisers raise their own types, and others
        if failures is None:
            raise LogError(f"{path}: cannot decode a message on {topic} ({_why(error)})") from error
        failures.add(path, topic, _why(error))
        return None


def _ros1_messages(
    path: Path,
    topics: list[str],
    failures: DecodeFailures | None,
    start_ns: int | None,
    end_ns: int | None,
) -> Iterator[Message]:
    """A ROS 1 bag's messages of the given topics in time order, read chunk by chunk, so that
    a damaged chunk costs only its own messages (counted in ``failures``, or raised without
    it). Chunks are merged as :func:`~markergraph.frontend.logs.chunks.summary_records` merges
    an MCAP file's: a chunk is opened once no pending message can come after its first one."""
    bag = _open_ros1(path)
    wanted = {i: c for i, c in bag.connections.items() if c.topic in topics}
    if not wanted:
        return
    types = _types(path, True, [(c.topic, c.msgtype, c.definition) for c in wanted.values()])
    chunks = sorted(
        (
            c
            for c in bag.chunks
            if (start_ns is None or c.end_ns >= start_ns)
            and (end_ns is None or c.start_ns < end_ns)
            and any(i in wanted for i in c.counts)
        ),
        key=lambda c: (c.start_ns, c.pos),
    )
    _note_cut(path, bag, wanted, failures, end_ns)
    pending: list[tuple[int, int, int, int, bytes]] = []  # (time, chunk, index, conn, raw)
    next_chunk = 0
    try:
        stream = open(path, "rb")  # noqa: SIM115 (closed in finally: this is a generator)
    except OSError as error:
        raise LogError(f"{path}: cannot be read ({error.strerror or _why(error)})") from error
    try:
        while next_chunk < len(chunks) or pending:
            while next_chunk < len(chunks) and (
                not pending or chunks[next_chunk].start_ns <= pending[0][0]
            ):
                chunk = chunks[next_chunk]
                found, damage = bag.chunk_messages(stream, chunk, wanted)
                if damage is not None:
                    _count_lost(path, bag, chunk, found, wanted, damage, failures)
                for position, (connection, t_ns, raw) in enumerate(found):
                    if (start_ns is None or t_ns >= start_ns) and (end_ns is None or t_ns < end_ns):
                        heapq.heappush(pending, (t_ns, next_chunk, position, connection, raw))
                next_chunk += 1
            if pending:
                t_ns, _, _, connection, raw = heapq.heappop(pending)
                topic, msgtype = wanted[connection].topic, wanted[connection].msgtype
                decoded = _decoded(path, types, True, topic, msgtype, raw, failures)
                if decoded is not None:
                    yield Message(topic, msgtype, t_ns, decoded)
    finally:
        stream.close()


def _note_cut(
    path: Path,
    bag: Ros1Bag,
    wanted: dict[int, Any],
    failures: DecodeFailures | None,
    end_ns: int | None,
) -> None:
    """Where a scan stopped short of the bag's end, a note in ``failures``, by the reader whose
    window reaches the end and whose topics the last chunk holds (the topics being recorded
    when the bag was cut), so that it is said once, not by every reader of a span."""
    if not bag.stopped or failures is None or not bag.chunks:
        return
    last = max(bag.chunks, key=lambda c: c.pos)
    if (end_ns is None or end_ns > last.end_ns) and any(i in wanted for i in last.counts):
        failures.note(
            path,
            f"read without its index ({bag.scanned}); the scan of its records stopped at "
            f"{bag.stopped}: the messages after that are lost",
        )


def _count_lost(
    path: Path,
    bag: Ros1Bag,
    chunk: Any,
    found: list[tuple[int, int, bytes]],
    wanted: dict[int, Any],
    damage: DamagedBagError,
    failures: DecodeFailures | None,
) -> None:
    """A damaged chunk's unread messages counted per topic in ``failures``.

    Raises:
        LogError: without ``failures``, naming the chunk's damage.
    """
    if failures is None:
        raise LogError(f"{path}: {damage}") from damage
    read = Counter(connection for connection, _, _ in found)
    for connection, n in lost_counts(chunk, read, wanted).items():
        failures.add(path, wanted[connection].topic, str(damage), n)


def bag_topic_spans(path: Path) -> list[tuple[str, int, int]]:
    """A ROS 1 bag's from its index (each connection's times in each chunk, or the chunk's
    span where they cannot be read), a SQLite bag's from its message stamps."""
    spans: dict[str, list[int]] = {}
    if path.is_file():
        bag = _open_ros1(path)
        for chunk in bag.chunks:
            for connection, n in chunk.counts.items():
                if n and connection in bag.connections:
                    first, last = chunk.times.get(connection, (chunk.start_ns, chunk.end_ns))
                    spans.setdefault(bag.connections[connection].topic, []).extend((first, last))
        return [(topic, min(times), max(times)) for topic, times in spans.items()]
    reader = _open_sqlite(path)
    try:
        for connection, t_ns, _ in reader.messages():
            spans.setdefault(connection.topic, []).append(int(t_ns))
    except Exception as error:  # sqlite3's "database disk image is malformed", and others
        raise LogError(f"{path}: damaged ({_why(error)})") from error
    finally:
        reader.close()
    return [(topic, min(times), max(times)) for topic, times in spans.items()]
