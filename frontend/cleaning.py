"""Cleaning what a log says before it is believed: odometry and ground-truth paths without
their corrupted samples, and colour frames whose stamps their neighbours contradict."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from markergraph.common.notes import Note
from markergraph.estimator.trajectory import Trajectory
from markergraph.estimator.types import OdometrySample, OdometryTrack
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
    samples: Sequence[OdometrySample],
    log_ns: Sequence[int],
    topic: str | None,
    what: str,
    frame: str,
) -> CleanPath:
    """A path without its corrupted samples, each kind dropped with a note naming the topic:
    one bad sample must not poison the map. Dropped: non-finite values (NaN, inf, a zero
    quaternion), coordinates beyond 10,000 km, stamps their neighbours contradict (out of the
    order the others rise in, a repeat, or off the others' lead over their log times:
    :func:`odd_stamps`, which keeps the majority rather than the first), and single samples
    that jump away and back faster than 50 m/s. Judged in arrays: a log may hold millions.

    Args:
        samples: in log order (an :class:`OdometryTrack` is read in its columns);
            log_ns: each one's log time [ns].
        topic: where they were read, named in the notes.
        what: what they are (``odometry``, ``ground-truth``), in the notes' text and kind.
        frame: the path's frame.
    """
    track = samples if isinstance(samples, OdometryTrack) else OdometryTrack(samples)
    t_ns, poses = track.columns()
    logged = np.array(log_ns, dtype=np.int64)
    if len(logged) != len(t_ns):
        raise ValueError(f"{len(t_ns)} {what} samples for {len(logged)} log times")
    finite = np.asarray(np.isfinite(poses).all(axis=1), dtype=bool)
    finite[finite] = np.abs(poses[finite, :2]).max(axis=1, initial=0.0) <= MAX_COORDINATE_M
    absurd = len(t_ns) - int(np.count_nonzero(finite))
    if absurd:  # copies only when something is dropped: the columns are the bulk of a run
        t_ns, poses, logged = t_ns[finite], poses[finite], logged[finite]
    judged = odd_stamps(t_ns, logged)
    del logged
    if judged.dropped:
        t_ns, poses = t_ns[judged.kept], poses[judged.kept]
    spike = _spikes(t_ns, poses)
    spikes = int(np.count_nonzero(spike))
    if spikes:
        t_ns, poses = t_ns[~spike], poses[~spike]
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
    order = np.argsort(t_ns, kind="stable")  # sorted by stamp, as Trajectory.from_samples
    if np.any(order != np.arange(len(order))):
        t_ns, poses = t_ns[order], poses[order]
    path = Trajectory(t_ns, poses, frame)
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


def _spikes(t_ns: NDArray[np.int64], poses: NDArray[np.float64]) -> NDArray[np.bool_]:
    """(N,) bool: the samples that jump away from both neighbours and back faster than
    :data:`MAX_SPEED_MPS`, each judged against its neighbours as given (stamps rise)."""
    spike = np.zeros(len(t_ns), dtype=bool)
    if len(t_ns) < 3:
        return spike

    def speed(a: slice, b: slice) -> NDArray[np.float64]:
        step = np.hypot(poses[b, 0] - poses[a, 0], poses[b, 1] - poses[a, 1])
        return np.asarray(step / ((t_ns[b] - t_ns[a]) * 1e-9), dtype=np.float64)

    before, sample, after = slice(0, -2), slice(1, -1), slice(2, None)
    spike[1:-1] = (
        (speed(before, sample) > MAX_SPEED_MPS)
        & (speed(sample, after) > MAX_SPEED_MPS)
        & (speed(before, after) <= MAX_SPEED_MPS)
    )
    return spike
