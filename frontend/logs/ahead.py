"""Reading ahead of the consumer, in a thread: a log's reading (file reads, zstd, record parsing)
overlaps the work done on what it has read."""

from __future__ import annotations

import queue
import threading
from collections.abc import Iterator
from typing import Any

__all__ = ["READ_AHEAD_BATCH", "read_ahead"]

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
