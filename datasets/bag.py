"""The simulators' ROS 2 MCAP writer: messages encoded and chunks compressed in a thread of their
own, while the caller renders the next frame.

CDR encoding is Python, but zstd and CRC32 release the GIL, and so does OpenCV's JPEG
encoding, which runs here too (:meth:`Bag.write` takes a function that makes a message): on 2
cores the bundled sample took 12.1-15.6 s to write against 14.0-15.7 s with one thread doing
both (five runs each, interleaved; before frames rendered in threads too). Messages are written
in the order given, so the file's bytes are those one thread writes.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable
from types import TracebackType
from typing import Any, BinaryIO

from mcap.records import Schema
from mcap.writer import CompressionType
from mcap_ros2.writer import Writer

from markergraph.frontend.ros2 import MESSAGE_DEFINITIONS

__all__ = ["Bag"]

# Messages waiting for the writing thread: a few frames' worth (a raw depth image is 0.6 MB, a
# raw colour one 0.9 MB), enough that neither thread waits on the other's every message.
WAITING_MESSAGES = 32

# topic, schema, message (or what makes it), stamp, log time
_Message = tuple[str, str, dict[str, Any] | Callable[[], dict[str, Any]], int, int]


class Bag:
    """An ``mcap_ros2`` writer, used as a context manager, that registers each schema once,
    counts messages per topic and writes them in a thread of its own. Leaving the ``with``
    normally writes everything and finishes the file; leaving it on an error drops what was
    still waiting, and the file is left unfinished (for ``written_whole`` to discard). An
    error in the writing thread is raised by the next :meth:`write`, or on leaving."""

    def __init__(
        self, stream: BinaryIO, compression: CompressionType = CompressionType.ZSTD
    ) -> None:
        self.writer = Writer(stream, compression=compression)
        self.counts: dict[str, int] = {}
        self._schemas: dict[str, Schema] = {}
        self._waiting: queue.Queue[_Message | None] = queue.Queue(maxsize=WAITING_MESSAGES)
        self._error: BaseException | None = None
        self._dropping = False
        self._thread = threading.Thread(target=self._work, name="markergraph-bag", daemon=True)

    def write(
        self,
        topic: str,
        schema: str,
        message: dict[str, Any] | Callable[[], dict[str, Any]],
        t_ns: int,
        log_time_ns: int,
    ) -> None:
        """Queue one message: a dict ``mcap_ros2`` encodes (not to be changed afterwards), or
        a function that makes it, called in the writing thread (JPEG encoding, say, which
        releases the GIL)."""
        if not self._thread.is_alive():
            raise RuntimeError("a Bag writes only inside its with statement")
        if self._error is not None:
            raise self._error
        self._waiting.put((topic, schema, message, t_ns, log_time_ns))
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def _work(self) -> None:
        """The writing thread: every message in order until told to stop; after an error, or
        once told to drop, it only empties the queue (so the caller never blocks on it)."""
        while (item := self._waiting.get()) is not None:
            if self._error is not None or self._dropping:
                continue
            topic, schema, message, t_ns, log_time_ns = item
            try:
                if callable(message):
                    message = message()
                if schema not in self._schemas:
                    definition = MESSAGE_DEFINITIONS[schema]
                    self._schemas[schema] = self.writer.register_msgdef(schema, definition)
                self.writer.write_message(
                    topic, self._schemas[schema], message, log_time=log_time_ns, publish_time=t_ns
                )
            except BaseException as error:  # raised in the caller's thread
                self._error = error

    def __enter__(self) -> Bag:
        self._thread.start()
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self._dropping = kind is not None
        self._waiting.put(None)
        self._thread.join()
        if kind is None:
            if self._error is not None:
                raise self._error
            self.writer.finish()
