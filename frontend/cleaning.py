"""Cleaning what a log says before it is believed: odometry and ground-truth paths without
their corrupted samples, and colour frames whose stamps their neighbours contradict."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from markergraph.common.notes import Note
from markergraph.estimator.trajectory import Trajectory
from markergraph.estimator.types import OdometrySample
from markergraph.frontend.extraction import Part
from markergraph.frontend.inputs import odd_stamps

__all__ = ["MAX_COORDINATE_M", "MAX_SPEED_MPS", "CleanPath", "clean_path", "drop_frames_by_stamp"]


# No wheeled robot or hand-held rig moves this fast, and no floor is this far from its origin:
# a sample that says so is a corrupted message, not motion.
MAX_SPEED_MPS = 50.0
MAX_COORDINATE_M = 1e7


@dataclass(frozen=True, slots=True)
class CleanPath:
    """A path without its corrupted samples, and what was dropped."""

    path: Trajectory
    """The samples kept."""
    dropped: int
    """Samples dropped, for every reason."""
    worst_stamp_offset_s: float
    """The furthest a dropped stamp was from where the others put it [s]; 0 when none was."""
    notes: list[Note] = field(default_factory=list)
    """One per reason that dropped samples (``<what>.dropped_*``), with the count."""


def clean_path(
    samples: list[OdometrySample],
    log_ns: list[int],
    topic: str | None,
    what: str,
    frame: str,
) -> CleanPath:
    """A path without its corrupted samples, each kind dropped with a note naming the topic:
    one bad sample must not poison the map. Dropped: non-finite values (NaN, inf, a zero
    quaternion), coordinates beyond 10,000 km, stamps their neighbours contradict (out of the
    order the others rise in, a repeat, or off the others' lead over their log times:
    :func:`odd_stamps`, which keeps the majority rather than the first), and single samples
    that jump away and back faster than 50 m/s.

    Args:
        samples: in log order; log_ns: each one's log time [ns].
        topic: where they were read, named in the notes.
        what: what they are (``odometry``, ``ground-truth``), in the notes' text and kind.
        frame: the path's frame.
    """
    finite: list[OdometrySample] = []
    finite_log_ns: list[int] = []
    absurd = 0
    for sample, logged in zip(samples, log_ns, strict=True):
        values = (sample.x, sample.y, sample.yaw)
        if not all(math.isfinite(v) for v in values) or max(abs(sample.x), abs(sample.y)) > (
            MAX_COORDINATE_M
        ):
            absurd += 1
        else:
            finite.append(sample)
            finite_log_ns.append(logged)
    judged = odd_stamps(
        np.array([s.t_ns for s in finite], dtype=np.int64),
        np.array(finite_log_ns, dtype=np.int64),
    )
    in_order = [s for s, kept in zip(finite, judged.kept, strict=True) if kept]
    kept = [
        sample
        for i, sample in enumerate(in_order)
        if not (0 < i < len(in_order) - 1 and _is_spike(in_order[i - 1], sample, in_order[i + 1]))
    ]
    spikes = len(in_order) - len(kept)
    kind = what.replace("-", "_")
    notes = [
        Note(f"{kind}.{reason}", f"dropped {n} {what} sample(s) on {topic} {why}", topic, n)
        for reason, n, why in (
            ("dropped_absurd", absurd, "with NaN, infinite or absurd values"),
            (
                "dropped_by_stamp",
                judged.dropped,
                "whose stamps their neighbours contradict (out of order, repeated, or off the "
                f"others' lead over their log times; the worst by {judged.worst_offset_s:.3g} s)",
            ),
            (
                "dropped_spikes",
                spikes,
                f"that jump away and back faster than {MAX_SPEED_MPS:g} m/s",
            ),
        )
        if n
    ]
    dropped = absurd + judged.dropped + spikes
    path = Trajectory.from_samples(kept, frame)
    return CleanPath(path, dropped, judged.worst_offset_s, notes)


def drop_frames_by_stamp(part: Part, topic: str | None) -> None:
    """Observations of colour frames whose stamps their neighbours contradict
    (:func:`odd_stamps`) dropped, with a note: a frame stamped seconds off would put its
    markers where the robot was not."""
    result = part.extraction
    if not part.frame_stamps:
        return
    stamps, logged = np.array(part.frame_stamps, dtype=np.int64).T
    judged = odd_stamps(stamps, logged)
    if not judged.dropped:
        return
    odd = {(int(t), int(g)) for t, g, k in zip(stamps, logged, judged.kept, strict=True) if not k}
    result.frames_dropped_by_stamp = judged.dropped
    if part.observation_frames:  # a detection log's observations carry no frames to judge
        result.observations = [
            o
            for o, frame in zip(result.observations, part.observation_frames, strict=True)
            if frame not in odd
        ]
    text = (
        f"dropped the observations of {judged.dropped} frame(s) on {topic} whose stamps their "
        "neighbours contradict (out of order, repeated, or off the others' lead over their log "
        f"times; the worst by {judged.worst_offset_s:.3g} s)"
    )
    result.notes.append(Note("frames.dropped_by_stamp", text, topic, judged.dropped))


def _is_spike(before: OdometrySample, sample: OdometrySample, after: OdometrySample) -> bool:
    def speed(a: OdometrySample, b: OdometrySample) -> float:
        return math.hypot(b.x - a.x, b.y - a.y) / ((b.t_ns - a.t_ns) * 1e-9)

    return (
        speed(before, sample) > MAX_SPEED_MPS
        and speed(sample, after) > MAX_SPEED_MPS
        and speed(before, after) <= MAX_SPEED_MPS
    )
