"""Colour frames decoded and their markers detected in a pool of threads, results in order.

JPEG decoding and OpenCV's detection release the GIL, so threads in one process keep every core
busy without a process's start-up or the copying of images between processes: on
bench_process.py's 640x480 log, two threads decoded and detected 2.0x as many frames a second as
one (this machine's 2 cores). Each thread has its own detector: a detector is not safe to share
(FAST mode sets its window detector's parameters per window; ``left_out`` counts).
"""

from __future__ import annotations

import threading
from collections import Counter
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from types import TracebackType

import numpy as np
from numpy.typing import NDArray

from markergraph.frontend.config import FrontendConfig
from markergraph.frontend.decode import decode_image
from markergraph.frontend.detect import Detection
from markergraph.frontend.detectors import MarkerDetector, make_detector
from markergraph.frontend.logs import LogError, Message

__all__ = ["SeeingPool", "Seen"]


@dataclass(frozen=True, slots=True)
class Seen:
    """What one colour frame shows: its markers, or why its image does not decode."""

    shape: tuple[int, ...] | LogError
    """The grey image's shape, or why it does not decode."""
    detections: list[Detection]
    """The markers found, sorted by id (none where the image does not decode)."""


class SeeingPool:
    """``threads`` threads that decode colour frames and detect their markers, each with its
    own detector; used as a context manager (leaving it stops the threads, dropping work not
    started)."""

    def __init__(
        self, config: FrontendConfig, threads: int, camera_size: tuple[int, int] | None
    ) -> None:
        self.config, self.camera_size = config, camera_size
        self._local = threading.local()
        self._detectors: list[MarkerDetector] = []
        self._lock = threading.Lock()
        self._executor = ThreadPoolExecutor(max(1, threads), thread_name_prefix="markergraph-see")

    def submit(self, message: Message) -> Future[Seen]:
        """The frame of ``message`` decoded and detected, in a thread of the pool."""
        return self._executor.submit(self._see, message)

    def left_out(self) -> Counter[int]:
        """Detections of ids outside the allowed ones, over every thread's detector."""
        with self._lock:
            return sum((Counter(d.left_out) for d in self._detectors), Counter())

    def _see(self, message: Message) -> Seen:
        try:
            image: NDArray[np.uint8] = decode_image(message, self.camera_size)
        except LogError as error:
            return Seen(error, [])
        return Seen(image.shape, self._detector().detect(image))

    def _detector(self) -> MarkerDetector:
        """This thread's detector, made on its first frame."""
        detector: MarkerDetector | None = getattr(self._local, "detector", None)
        if detector is None:
            c = self.config
            detector = make_detector(
                c.dictionary, c.detector, mode=c.detector_mode, allowed_ids=c.allowed_ids
            )
            self._local.detector = detector
            with self._lock:
                self._detectors.append(detector)
        return detector

    def __enter__(self) -> SeeingPool:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self._executor.shutdown(wait=True, cancel_futures=True)
