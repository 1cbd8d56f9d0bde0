"""Colour frames decoded, their markers detected and observed in a pool of threads.

JPEG decoding and OpenCV's detection release the GIL, so threads in one process keep every core
busy without a process's start-up or the copying of images between processes: on
bench_process.py's 640x480 log, two threads decoded and detected 2.0x as many frames a second as
one (this machine's 2 cores). Each thread has its own detector: a detector is not safe to share
(FAST mode sets its window detector's parameters per window; ``left_out`` counts).

A frame is seen (decoded, detected) as soon as it is read, and observed (PnP, depth, sigmas)
once the reader has paired it with its depth and attitude; the reader, which takes every frame
in log order, only keeps the books. Observing in the reader's thread made it the bottleneck on
a log with a marker in most frames: each of the dozen OpenCV calls an observation makes waits
to take the GIL back from the pool's threads.
"""

from __future__ import annotations

import threading
from collections import Counter
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from types import TracebackType

import numpy as np
from numpy.typing import NDArray

from markergraph.estimator.types import Observation
from markergraph.frontend.camera import Camera, CameraMount
from markergraph.frontend.config import FrontendConfig
from markergraph.frontend.decode import decode_image
from markergraph.frontend.detect import Detection
from markergraph.frontend.detectors import MarkerDetector
from markergraph.frontend.dictionary_check import BeyondDictionary
from markergraph.frontend.logs import LogError, Message
from markergraph.frontend.observe import ObservationModel, observe_detections
from markergraph.frontend.posed import LevelledCamera, LevelledFrame, observe_levelled_frame

__all__ = ["Observed", "SeeingPool", "Seen", "ToObserve"]


@dataclass(frozen=True, slots=True)
class Seen:
    """What one colour frame shows: its markers, or why its image does not decode."""

    shape: tuple[int, ...] | LogError
    """The grey image's shape, or why it does not decode."""
    detections: list[Detection]
    """The markers found, sorted by id (none where the image does not decode)."""
    beyond: tuple[int, ...] | None = None
    """Where the frame was checked for a larger dictionary's markers, the ids it showed beyond
    the given dictionary's (:class:`~.dictionary_check.BeyondDictionary`); None: not checked
    (or the dictionary has no larger family)."""


@dataclass(frozen=True, slots=True)
class ToObserve:
    """A frame being seen, with what observing it takes besides."""

    seen: Future[Seen]
    """Its image decoded and its markers detected."""
    depth: NDArray | None
    """The depth image paired with it."""
    view: LevelledCamera | None
    """The camera levelled by the odometry's attitude, where the base was tilted."""
    t_ns: int
    """Its stamp [ns]."""
    camera: Camera
    mount: CameraMount


@dataclass(frozen=True, slots=True)
class Observed:
    """One frame's observations, and what the reader counts of it."""

    shape: tuple[int, ...] | LogError
    """The grey image's shape, or why it does not decode (then nothing else is set)."""
    detections: list[Detection]
    """The markers found."""
    observations: list[Observation]
    """Their observations."""
    depth_unaligned: bool = False
    """Depth was paired but is not the colour image's size: observed without it."""
    levelled: LevelledFrame | None = None
    """The frame as levelled by the odometry's attitude (its observations are those above)."""
    depth_ratios: list[tuple[int, float, float]] = field(default_factory=list)
    """Its well-placed markers' (stamp, depth, PnP distance)."""
    size_ratios: list[tuple[int, float]] = field(default_factory=list)
    """Its well-placed markers' (id, depth over PnP distance)."""


class SeeingPool:
    """``threads`` threads that decode colour frames and detect their markers, each with its
    own detector; used as a context manager (leaving it stops the threads, dropping work not
    started)."""

    def __init__(
        self, config: FrontendConfig, threads: int, camera_size: tuple[int, int] | None
    ) -> None:
        self.config, self.camera_size = config, camera_size
        self.model = config.observation_model
        self._local = threading.local()
        self._detectors: list[MarkerDetector] = []
        self._lock = threading.Lock()
        self._executor = ThreadPoolExecutor(max(1, threads), thread_name_prefix="markergraph-see")

    def submit(self, message: Message, check_dictionary: bool = False) -> Future[Seen]:
        """The frame of ``message`` decoded and detected, in a thread of the pool; also searched
        for a larger dictionary's markers if ``check_dictionary``."""
        return self._executor.submit(self._see, message, check_dictionary)

    def observe(self, frame: ToObserve) -> Future[Observed]:
        """A seen frame observed, in a thread of the pool. Its seeing was submitted first, so
        it has started by the time this does (the pool takes work in order): waiting for it
        cannot hold up the pool."""
        return self._executor.submit(_observed, frame, self.model)

    def left_out(self) -> Counter[int]:
        """Detections of ids outside the allowed ones, over every thread's detector."""
        with self._lock:
            return sum((Counter(d.left_out) for d in self._detectors), Counter())

    def _see(self, message: Message, check_dictionary: bool) -> Seen:
        try:
            image: NDArray[np.uint8] = decode_image(message, self.camera_size)
        except LogError as error:
            return Seen(error, [])
        beyond = self._beyond().ids(image) if check_dictionary else None
        return Seen(image.shape, self._detector().detect(image), beyond)

    def _detector(self) -> MarkerDetector:
        """This thread's detector, made on its first frame."""
        detector: MarkerDetector | None = getattr(self._local, "detector", None)
        if detector is None:
            detector = self.config.new_detector()
            self._local.detector = detector
            with self._lock:
                self._detectors.append(detector)
        return detector

    def _beyond(self) -> BeyondDictionary:
        """This thread's search for a larger dictionary's markers, made on first use."""
        beyond: BeyondDictionary | None = getattr(self._local, "beyond", None)
        if beyond is None:
            beyond = self._local.beyond = BeyondDictionary(self.config.dictionary)
        return beyond

    def __enter__(self) -> SeeingPool:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self._executor.shutdown(wait=True, cancel_futures=True)


def _observed(frame: ToObserve, model: ObservationModel) -> Observed:
    """A seen frame's observations (:meth:`SeeingPool.observe`)."""
    seen = frame.seen.result()
    shape, detections, depth, t_ns = seen.shape, seen.detections, frame.depth, frame.t_ns
    if isinstance(shape, LogError):
        return Observed(shape, [], [])
    unaligned = depth is not None and depth.shape[:2] != shape[:2]
    if frame.view is not None:
        # A tilted base (a ramp, a hand-held rig) or a rolled camera: each marker's full pose
        # from its corners, turned into the level frame.
        levelled = observe_levelled_frame(detections, frame.view, model, t_ns)
        return Observed(shape, detections, levelled.observations, unaligned, levelled)
    depth_ratios: list[tuple[int, float, float]] = []
    size_ratios: list[tuple[int, float]] = []
    observations = observe_detections(
        detections, frame.camera, model, depth=None if unaligned else depth, mount=frame.mount,
        t_ns=t_ns, depth_ratios=depth_ratios, size_ratios=size_ratios,
    )  # fmt: skip
    return Observed(shape, detections, observations, unaligned, None, depth_ratios, size_ratios)
