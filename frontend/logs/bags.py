"""ROS 1 bags (``.bag``) and ROS 2 SQLite bags (a rosbag2 folder of ``.db3`` files), read with the
``rosbags`` library: the same topics and decoded messages as the MCAP reader gives.

Messages decode to rosbags' dataclasses, whose fields carry the ROS names (``header.stamp.sec``,
``nanosec``; ROS 1's ``CameraInfo`` has ``K`` and ``D``), and types are named ROS 2 style
(``nav_msgs/msg/Odometry``, ROS 1's ``tf/msg/tfMessage``). A type the library does not know,
such as TagSLAM's ``apriltag_msgs/ApriltagArrayStamped``, is registered from the definition the
bag carries with its connection; a Humble SQLite bag carries none, and the detection types are
then registered from :data:`~markergraph.frontend.detections.DETECTION_DEFINITIONS`.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from markergraph.frontend.detections import DETECTION_DEFINITIONS
from markergraph.frontend.logs.records import DecodeFailures, LogError, LogTopic, Message

__all__ = ["BagSummary", "bag_messages", "bag_summary", "bag_topic_spans"]


class _Bag:
    """An open bag: its reader, and the type store its messages decode with."""

    def __init__(self, path: Path) -> None:
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        self.path = Path(path)
        self.ros1 = self.path.is_file()
        try:
            if self.ros1:
                from rosbags.rosbag1 import Reader as Ros1Reader

                self.reader: Any = Ros1Reader(self.path)
            else:
                from rosbags.rosbag2 import Reader as Ros2Reader

                self.reader = Ros2Reader(self.path)
            self.reader.open()
        except Exception as error:  # rosbags raises ReaderError and friends
            raise LogError(
                f"{self.path}: not a readable bag ({type(error).__name__}: {error})"
            ) from error
        store = Stores.ROS1_NOETIC if self.ros1 else Stores.ROS2_HUMBLE
        self.types = get_typestore(store)
        for connection in self.reader.connections:
            if connection.msgtype in self.types.fielddefs:
                continue
            definition = getattr(getattr(connection, "msgdef", None), "data", "")
            definition = definition or DETECTION_DEFINITIONS.get(connection.msgtype)
            if definition:
                try:
                    self.types.register(get_types_from_msg(definition, connection.msgtype))
                except Exception as error:  # a definition rosbags cannot parse
                    raise LogError(
                        f"{self.path}: topic {connection.topic} has a type definition that "
                        f"cannot be parsed ({type(error).__name__}: {error})"
                    ) from error

    def close(self) -> None:
        self.reader.close()

    def decode(self, connection: Any, raw: bytes) -> Any:
        if connection.msgtype not in self.types.fielddefs:
            raise LogError(
                f"{self.path}: no definition of {connection.msgtype} (topic {connection.topic}) "
                "in the bag or in rosbags' type store"
            )
        if self.ros1:
            return self.types.deserialize_ros1(raw, connection.msgtype)
        return self.types.deserialize_cdr(raw, connection.msgtype)


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
    bag = _Bag(path)
    try:
        counts: dict[str, LogTopic] = {}
        for connection in bag.reader.connections:
            previous = counts.get(connection.topic)
            counts[connection.topic] = LogTopic(
                connection.topic,
                connection.msgtype,
                connection.msgcount + (previous.count if previous else 0),
            )
        topics = sorted(counts.values(), key=lambda t: t.topic)
        count = int(bag.reader.message_count or 0)
        if not count:
            return BagSummary(topics, 0, 0, 0)
        return BagSummary(topics, count, int(bag.reader.start_time), int(bag.reader.end_time) - 1)
    finally:
        bag.close()


def bag_messages(
    path: Path,
    topics: list[str],
    failures: DecodeFailures | None,
    start_ns: int | None,
    end_ns: int | None,
) -> Iterator[Message]:
    """Decoded messages of the given topics in time order; see
    :meth:`markergraph.frontend.logs.Log.messages`."""
    bag = _Bag(path)
    try:
        connections = [c for c in bag.reader.connections if c.topic in topics]
        if not connections:
            return
        try:
            for connection, t_ns, raw in bag.reader.messages(
                connections=connections, start=start_ns, stop=end_ns
            ):
                try:
                    decoded = bag.decode(connection, raw)
                except LogError:
                    raise
                except Exception as error:  # rosbags' deserialisers raise their own types
                    if failures is None:
                        raise LogError(
                            f"{path}: cannot decode a message on {connection.topic} "
                            f"({type(error).__name__}: {error})"
                        ) from error
                    failures.add(path, connection.topic, f"{type(error).__name__}: {error}")
                    continue
                yield Message(connection.topic, connection.msgtype, int(t_ns), decoded)
        except LogError:
            raise
        except Exception as error:  # a damaged chunk: rosbags cannot go on past it
            raise LogError(f"{path}: damaged ({type(error).__name__}: {error})") from error
    finally:
        bag.close()


def bag_topic_spans(path: Path) -> list[tuple[str, int, int]]:
    """Through ``rosbags``: a ROS 1 bag's index records, a SQLite bag's message stamps."""
    try:
        if path.is_file():
            from rosbags.rosbag1 import Reader as Ros1Reader

            reader: Any = Ros1Reader(path)
        else:
            from rosbags.rosbag2 import Reader as Ros2Reader

            reader = Ros2Reader(path)
        reader.open()
    except Exception as error:  # rosbags raises ReaderError and friends
        raise LogError(f"{path}: not a readable bag ({type(error).__name__}: {error})") from error
    spans: dict[str, list[int]] = {}
    try:
        indexes = getattr(reader, "indexes", None)  # ROS 1: connection id -> index records
        if isinstance(indexes, dict):
            for connection in reader.connections:
                times = [int(entry.time) for entry in indexes.get(connection.id, ())]
                if times:
                    spans.setdefault(connection.topic, []).extend((min(times), max(times)))
        else:
            for connection, t_ns, _ in reader.messages():
                spans.setdefault(connection.topic, []).append(int(t_ns))
    except Exception as error:  # a damaged bag: rosbags cannot go on past it
        raise LogError(f"{path}: damaged ({type(error).__name__}: {error})") from error
    finally:
        reader.close()
    return [(topic, min(times), max(times)) for topic, times in spans.items()]
