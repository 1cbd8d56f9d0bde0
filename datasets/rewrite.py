"""A ROS 2 MCAP log rewritten message by message: faults and effects put into a recorded or
simulated log (a NaN, a dropped frame, an odometry reset), for tests and studies."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer

from markergraph.common.files import written_whole

__all__ = ["rewrite_log"]


def rewrite_log(source: Path, target: Path, change: Callable[[str, int, Any], Any | None]) -> None:
    """A copy of a ROS 2 MCAP log with messages changed, written whole or not at all.

    Args:
        change: called as ``change(topic, index, decoded)`` for each message (``index`` counts
            the messages of that topic from 0); returns the message to write (changed in place
            or not), or None to drop it.
    """
    seen: dict[str, int] = {}
    with open(source, "rb") as stream, written_whole(target) as partial, open(partial, "wb") as out:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        writer = Writer(out)
        schemas: dict[int, Any] = {}
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            index = seen.get(channel.topic, 0)
            seen[channel.topic] = index + 1
            kept = change(channel.topic, index, decoded)
            if kept is None:
                continue
            if schema is None:  # decoded, so it had one; mcap's types allow for none
                raise ValueError(f"{source}: topic {channel.topic} has no schema")
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_msgdef(schema.name, schema.data.decode())
            writer.write_message(
                channel.topic, schemas[schema.id], kept, message.log_time, message.publish_time
            )
        writer.finish()
