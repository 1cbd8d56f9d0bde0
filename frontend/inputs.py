"""Judging a log's inputs against each other rather than believing the first or the odd one: the
camera model most camera_info messages agree on, and the stamps that disagree with their
neighbours."""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from markergraph.common.notes import Note
from markergraph.frontend.camera import Camera, majority_camera
from markergraph.frontend.logs import DecodeFailures, Log
from markergraph.frontend.observe import robust_least_squares

__all__ = ["CameraJudgement", "OddStamps", "judge_camera_info", "odd_stamps"]

# camera_info messages read before choosing: a majority of this many outvotes a few bad ones,
# and they lie in the log's first seconds (most cameras publish one per frame).
CAMERA_INFOS_JUDGED = 25


@dataclass(frozen=True)
class CameraJudgement:
    """The camera model a topic's camera_info messages agree on.

    Attributes:
        camera: the majority's model; None when no message gave a believable one.
        read: messages judged (the first :data:`CAMERA_INFOS_JUDGED`).
        agreeing: of them, those that gave the chosen model.
        set_aside: reason -> messages set aside for it.
    """

    camera: Camera | None
    read: int
    agreeing: int
    set_aside: dict[str, int] = field(default_factory=dict)

    def note(self, topic: str) -> Note | None:
        """What was set aside and why, for the run's notes (its figure: the messages set
        aside); None when nothing was."""
        if not self.set_aside:
            return None
        reasons = "; ".join(f"{n}: {why}" for why, n in self.set_aside.items())
        set_aside = sum(self.set_aside.values())
        text = (
            f"camera_info: {set_aside} of {self.read} messages on {topic} set "
            f"aside ({reasons}); using the model the other {self.agreeing} agree on"
        )
        return Note("camera_info.set_aside", text, topic, set_aside)


def judge_camera_info(log: Log, topic: str, failures: DecodeFailures) -> CameraJudgement:
    """The model most of the first :data:`CAMERA_INFOS_JUDGED` messages on ``topic`` give,
    among those that can be a camera (:meth:`Camera.implausible`); messages that do not
    decode are counted in ``failures``."""
    models: list[Camera | str] = []
    stream = log.messages([topic], failures)
    try:
        for message in stream:
            try:
                models.append(Camera.from_camera_info(message.decoded))
            except ValueError as error:
                models.append(str(error))
            if len(models) >= CAMERA_INFOS_JUDGED:
                break
    finally:
        close = getattr(stream, "close", None)  # a generator: its file closed now, not at gc
        if close is not None:
            close()
    camera, set_aside = majority_camera(models)
    return CameraJudgement(camera, len(models), len(models) - sum(set_aside.values()), set_aside)


# A stamp this far from what the topic's other stamps say of its place in the log is a wrong
# stamp, not a late message: a recorder's queue on a loaded machine delays messages by tens of
# milliseconds, at worst a few tenths of a second.
MIN_STAMP_OFFSET_S = 1.0
STAMP_OFFSET_SIGMAS = 20.0


@dataclass(frozen=True)
class OddStamps:
    """Which of a topic's messages carry stamps their neighbours contradict.

    Attributes:
        kept: per message, in log order: True where its stamp is believed.
        worst_offset_s: the largest difference between a dropped stamp and where its
            neighbours put it [s]; 0 when none was dropped.
    """

    kept: NDArray[np.bool_]
    worst_offset_s: float

    @property
    def dropped(self) -> int:
        return int(np.count_nonzero(~self.kept))


# Stamps beyond this many fit the lead over log time on an evenly spaced sample of them.
MAX_STAMP_FIT_ROWS = 100_000


def odd_stamps(stamps_ns: NDArray[np.int64], log_ns: NDArray[np.int64]) -> OddStamps:
    """The stamps of one topic that disagree with their neighbours, judged two ways, each by
    the majority:

    1. Order: the stamps should rise in the order the messages were logged. The longest
       strictly rising run through them (not necessarily contiguous) is the majority's
       clock; a stamp off it (one stamped 1000 s late, after which every good stamp would
       seem to go backwards; a repeat) is dropped, not the many it would outvote.
    2. Offset: a stamp's lead over its log time should match the others' (a robust line in
       log time, for clocks that drift). Beyond :data:`MIN_STAMP_OFFSET_S` and
       :data:`STAMP_OFFSET_SIGMAS` robust sigmas from it, it is dropped (a first sample
       stamped 5 s early, which order alone cannot see). Skipped where a log's times are all
       equal (a detection log read without them).

    Args:
        stamps_ns: each message's header stamp, in log order [ns].
        log_ns: each message's log (receive) time, the same order [ns].
    """
    n = len(stamps_ns)
    kept = np.zeros(n, dtype=bool)
    kept[_longest_rising(stamps_ns)] = True
    if np.count_nonzero(kept) >= 3 and np.ptp(log_ns) > 0:
        # The lead over log time as a line in log time: a camera's own clock drifts against
        # the recorder's by up to a few seconds an hour, which a constant would read as odd.
        offset_s = (stamps_ns - log_ns).astype(np.float64) * 1e-9
        log_s = (log_ns - log_ns[0]).astype(np.float64) * 1e-9
        rows = np.flatnonzero(kept)
        # A line needs no millions of rows: evenly spaced ones fit it as well, in memory that
        # does not grow with the log.
        rows = rows[:: -(-len(rows) // MAX_STAMP_FIT_ROWS)]
        A = np.column_stack([np.ones(len(rows)), log_s[rows]])
        line, _, sigma = robust_least_squares(A, offset_s[rows], passes=3)
        del A, rows
        residual = np.abs(offset_s - (line[0] + line[1] * log_s))
        kept &= residual <= max(MIN_STAMP_OFFSET_S, STAMP_OFFSET_SIGMAS * sigma)
    worst = 0.0
    if n and not kept.all() and kept.any():
        # Where the kept stamps put each message: interpolated by its place in the log.
        order = np.arange(n)
        expected = np.interp(order, order[kept], stamps_ns[kept].astype(np.float64))
        worst = float(np.max(np.abs(stamps_ns[~kept] - expected[~kept]))) * 1e-9
    return OddStamps(kept, worst)


def _longest_rising(values: NDArray[np.int64]) -> NDArray[np.intp]:
    """Indices of a longest strictly rising subsequence (patience sorting, O(n log n)). In
    arrays and read in blocks: a topic may hold millions of stamps, which as Python lists of
    ints took some 130 bytes each."""
    n = len(values)
    if n < 2 or bool(np.all(values[1:] > values[:-1])):
        return np.arange(n)  # the usual case: already rising, nothing to search
    tails: list[int] = []  # tails[k]: the smallest last value of a rising run of length k + 1
    tail_index: list[int] = []
    previous = np.full(n, -1, dtype=np.intp)
    block = 1 << 16
    for start in range(0, n, block):
        for i, value in enumerate(values[start : start + block].tolist(), start):
            k = bisect.bisect_left(tails, value)
            if k == len(tails):
                tails.append(value)
                tail_index.append(i)
            else:
                tails[k], tail_index[k] = value, i
            previous[i] = tail_index[k - 1] if k else -1
    run = np.empty(len(tails), dtype=np.intp)
    i = tail_index[-1]
    for k in range(len(run) - 1, -1, -1):
        run[k] = i
        i = int(previous[i])
    return run
