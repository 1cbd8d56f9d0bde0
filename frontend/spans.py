"""Reading one stretch of a log: colour frames paired with the depth image nearest in time,
the odometry's attitude to level them with, and each frame to observations.

Streams: only a few frames are held while colour waits for its depth, however long the log.
Nothing is dropped silently: every skipped frame is counted with its reason, and one bad message
costs its frame, not the run.
"""

from __future__ import annotations

import bisect
import math
from collections import Counter, deque
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from operator import itemgetter
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from markergraph.common.notes import Note
from markergraph.estimator.trajectory import Trajectory
from markergraph.estimator.types import OdometrySample
from markergraph.frontend.config import FrontendConfig
from markergraph.frontend.decode import (
    decode_depth,
    frame_id,
    odometry_sample,
    stamp_ns,
)
from markergraph.frontend.detect import DetectorMode
from markergraph.frontend.detectors import DetectorChoice, MarkerDetector
from markergraph.frontend.dictionary_check import CHECK_EVERY
from markergraph.frontend.extraction import Extraction, Part
from markergraph.frontend.logs import DecodeFailures, Log, LogError, Message, read_ahead
from markergraph.frontend.observe import Flags
from markergraph.frontend.odometry_kind import OdometryJudge
from markergraph.frontend.posed import (
    MAX_ATTITUDE_GAP_NS,
    LevelledCamera,
    levelled_view,
)
from markergraph.frontend.ros2 import yaw_from_quaternion
from markergraph.frontend.seeing import Observed, SeeingPool, Seen, ToObserve
from markergraph.frontend.tf import (
    is_rotation,
    mount_from_transforms,
    odometry_from_tf,
    rotation_of,
    transforms_of,
)
from markergraph.frontend.topics import TRUE_MARKERS, TRUE_POSE, TopicChoice

__all__ = [
    "ColourFrame",
    "Pairing",
    "Span",
    "SpanReader",
    "detector_for",
    "one_opencv_thread",
    "read_span",
]

MAX_ATTITUDES = 64  # the latest odometry attitudes kept to level frames with
# Frames paired with their depth wait this many a thread for the pool to see them before the
# reader waits: the pool keeps working while the reader pairs and observes.
IN_FLIGHT_PER_THREAD = 4


@dataclass(frozen=True, slots=True)
class ColourFrame:
    """A colour message and what its image shows, once the pool has seen it."""

    message: Message
    """The colour message as read."""
    seen: Future[Seen]
    """Its image decoded and its markers detected, in the pool (:class:`SeeingPool`)."""


_Job = tuple[int, ColourFrame, "NDArray | None"]  # (stamp, colour frame, paired depth)


class Pairing:
    """Colour frames wait here for the depth image with the nearest stamp."""

    def __init__(self, tolerance_ns: int) -> None:
        self.tolerance = tolerance_ns
        self.colour: deque[tuple[int, ColourFrame]] = deque()
        self.depth: deque[tuple[int, NDArray]] = deque(maxlen=16)

    def matched_depth(self, t_ns: int) -> NDArray | None:
        """The waiting depth image nearest ``t_ns``, if within the tolerance."""
        best = min(self.depth, key=lambda d: abs(d[0] - t_ns), default=None)
        return best[1] if best is not None and abs(best[0] - t_ns) <= self.tolerance else None

    def ready(self, latest_ns: int, flush: bool = False) -> list[_Job]:
        """Colour frames that have their depth, or can no longer get it. Each frame is judged
        on its own, so one with a wrong stamp (far in the future) waits alone instead of
        holding up the frames behind it."""
        out, waiting = [], deque[tuple[int, ColourFrame]]()
        for t_ns, frame in self.colour:
            depth = self.matched_depth(t_ns)
            if depth is None and not flush and latest_ns - t_ns <= 3 * self.tolerance:
                waiting.append((t_ns, frame))
            else:
                out.append((t_ns, frame, depth))
        self.colour = waiting
        return out


_DetectorKey = tuple[str, tuple[int, ...] | None, DetectorMode, DetectorChoice]
_DETECTORS: dict[_DetectorKey, MarkerDetector] = {}


def detector_for(config: FrontendConfig) -> MarkerDetector:
    """One detector per process and configuration (building one costs more than a frame)."""
    key = (config.dictionary, config.allowed_ids, config.detector_mode, config.detector)
    if key not in _DETECTORS:
        _DETECTORS[key] = config.new_detector()
    return _DETECTORS[key]


@dataclass(frozen=True, slots=True)
class Span:
    """A stretch of a log: the colour frames, odometry and ground truth whose log times fall in
    [start_ns, end_ns); None for an open end."""

    start_ns: int | None = None
    """The first log time in it [ns]; None: from the log's start."""
    end_ns: int | None = None
    """The first log time after it [ns]; None: to the log's end."""

    def holds(self, t_ns: int) -> bool:
        """Whether log time ``t_ns`` falls inside."""
        return (self.start_ns is None or t_ns >= self.start_ns) and (
            self.end_ns is None or t_ns < self.end_ns
        )


@dataclass(frozen=True, slots=True)
class _Paired:
    """A colour frame with its depth, being observed in the pool."""

    t_ns: int
    frame: ColourFrame
    depth: NDArray | None
    observed: Future[Observed]


class SpanReader:
    """One process's work: observations, odometry and ground truth of one stretch of the log.

    Three kinds of thread share it: one reads the log ahead (:func:`read_ahead`: file reads,
    zstd), the pool's decode images, detect markers and observe them (:class:`SeeingPool`), and
    the caller's pairs frames with depth and odometry and keeps the books, in log order."""

    def __init__(
        self,
        log: Log,
        config: FrontendConfig,
        choice: TopicChoice,
        counts: dict[str, int],
        threads: int = 1,
    ) -> None:
        self.log, self.path = log, log.path
        self.config, self.choice, self.counts = config, choice, counts
        mount = config.mount or config.default_mount
        self.part = Part(Extraction([], Trajectory.from_samples([]), config.camera, mount, choice))
        # Two books, one per thread: the reading thread's (messages) and this one's (_take).
        self.failures, self.read_failures = DecodeFailures(), DecodeFailures()
        self.static: list[Any] = []
        self.image_frame: str | None = None
        self.odometry_frame: str | None = None
        self.mount_known = config.mount is not None
        self.pairing = Pairing(config.pair_tolerance_ns)
        self.threads = max(1, threads)
        self.odometry_judge: OdometryJudge | None = None  # set while reading from the log's start
        self.paired: deque[_Paired] = deque()
        self.pool: SeeingPool | None = None  # while reading
        # (stamp, orientation) in stamp order; turned into a rotation only for a frame's nearest.
        self.attitudes: deque[tuple[int, Any]] = deque(maxlen=MAX_ATTITUDES)

    def read(self, span: Span, progress: Callable[[int, int], None] | None) -> Part:
        """The stretch's observations, odometry and truth; ``progress`` called with (colour
        frames read, frames in all)."""
        self._read_once_topics()
        self.odometry_judge = OdometryJudge() if span.start_ns is None else None
        streamed = [
            t
            for t in (self.choice.color, self.choice.depth, self.choice.odom, TRUE_POSE)
            if t and t in self.counts
        ]
        # Progress counts colour frames: what a person knows the log by.
        total, done, color = self.counts.get(self.choice.color or "", 0), 0, self.choice.color
        # Read a margin either side so frames at the span's edges still find their depth.
        margin = 3 * self.config.pair_tolerance_ns
        start = None if span.start_ns is None else span.start_ns - margin
        end = None if span.end_ns is None else span.end_ns + margin
        stream = self.log.messages(streamed, self.read_failures, start, end)
        with SeeingPool(self.config, self.threads, self._camera_size()) as pool:
            self.pool = pool
            for message in read_ahead(stream):
                if message.topic == color and span.holds(message.log_time_ns):
                    done += 1
                    if progress is not None and done % 10 == 0:
                        progress(done, total)
                    check = done % CHECK_EVERY == 1  # the first frame, then one in CHECK_EVERY
                    self._take_frame(ColourFrame(message, pool.submit(message, check)))
                else:
                    self._take(message, span.holds(message.log_time_ns))
            self._drain(0, flush=True)
            left_out = pool.left_out()
        if progress is not None:
            progress(total, total)
        result = self.part.extraction
        # Both readers meet the same damaged index: its note is said once.
        result.read_failures = DecodeFailures.merged([self.read_failures, self.failures])
        result.warnings = result.read_failures.warnings()
        result.ids_left_out = left_out
        if self.odometry_judge is not None:
            result.odometry_evidence = self.odometry_judge.evidence()
        return self.part

    def _camera_size(self) -> tuple[int, int] | None:
        """The camera's (width, height), which no frame's declared size may far exceed."""
        camera = self.config.camera
        return None if camera is None else (camera.width, camera.height)

    def _read_once_topics(self) -> None:
        """Topics published once at the start: static transforms and true marker poses."""
        once = [t for t in (self.choice.tf_static, TRUE_MARKERS) if t and t in self.counts]
        for message in self.log.messages(once, self.failures):
            if message.topic == self.choice.tf_static:
                self.static += transforms_of(message.decoded)
                continue
            for transform in message.decoded.transforms:
                if transform.child_frame_id.startswith("aruco_"):
                    q, t = transform.transform.rotation, transform.transform.translation
                    pose = (t.x, t.y, yaw_from_quaternion(q.x, q.y, q.z, q.w))
                    if not all(math.isfinite(v) for v in pose):
                        self.part.extraction.notes.append(
                            Note(
                                "truth.marker_not_finite",
                                f"ignored the non-finite true pose of {transform.child_frame_id}"
                                f" on {TRUE_MARKERS}",
                                TRUE_MARKERS,
                            )
                        )
                        continue
                    marker_id = int(transform.child_frame_id[6:])
                    self.part.extraction.true_marker_poses[marker_id] = pose

    def _take_frame(self, frame: ColourFrame) -> None:
        """A colour frame inside the span."""
        decoded, t_ns = frame.message.decoded, stamp_ns(frame.message.decoded)
        self.part.extraction.frames += 1
        self.part.frame_stamps.append((t_ns, frame.message.log_time_ns))
        self.image_frame = self.image_frame or frame_id(decoded)
        self.pairing.colour.append((t_ns, frame))
        self._drain(t_ns)

    def _take(self, message: Message, inside: bool) -> None:
        """One streamed message, by its role."""
        choice, result, decoded = self.choice, self.part.extraction, message.decoded
        topic = message.topic
        if topic == choice.depth:
            try:
                self.pairing.depth.append(
                    (stamp_ns(decoded), decode_depth(message, self._camera_size()))
                )
            except LogError as error:  # the frame waiting for it goes on without depth
                result.unusable_depth += 1
                self.failures.add(self.path, topic, str(error))
            self._drain(stamp_ns(decoded))
        elif topic == choice.odom:
            if self.odometry_judge is not None and self.odometry_judge.wants_more:
                self.odometry_judge.add(message.log_time_ns, decoded)
            if message.schema.endswith("TFMessage"):
                if inside:
                    samples = odometry_from_tf(decoded, self.config.base_frame)
                    self.part.odometry.extend(samples)
                    self.part.odometry_log_ns.extend([message.log_time_ns] * len(samples))
                return
            if inside:
                self.part.odometry.append(odometry_sample(message))
                self.part.odometry_log_ns.append(message.log_time_ns)
            self.odometry_frame = self.odometry_frame or getattr(decoded, "child_frame_id", None)
            pose = decoded.pose.pose if hasattr(decoded.pose, "pose") else decoded.pose
            if is_rotation(pose.orientation):  # its attitude levels the frames about it
                self._keep_attitude(stamp_ns(decoded), pose.orientation)
        elif topic == TRUE_POSE and inside:
            q, p = decoded.pose.orientation, decoded.pose.position
            self.part.true_poses.append(
                OdometrySample(stamp_ns(decoded), p.x, p.y, yaw_from_quaternion(q.x, q.y, q.z, q.w))
            )
            self.part.true_pose_log_ns.append(message.log_time_ns)

    def _drain(self, latest_ns: int, flush: bool = False) -> None:
        """The colour frames paired (or past waiting for depth) sent to be observed, and those
        observed counted, in order: the reader waits only with too many in flight, or to
        finish."""
        ready = self.pairing.ready(latest_ns, flush)
        if ready:
            self._settle_mount()
        result, pool = self.part.extraction, self.pool
        assert pool is not None and result.camera is not None  # judged before reading
        for t_ns, frame, depth in ready:
            # Levelled now, while the odometry's attitudes about its stamp are at hand.
            view = self._levelled_view(t_ns)
            observed = pool.observe(
                ToObserve(frame.seen, depth, view, t_ns, result.camera, result.mount)
            )
            self.paired.append(_Paired(t_ns, frame, depth, observed))
        limit = 0 if flush else IN_FLIGHT_PER_THREAD * self.threads
        while self.paired and (len(self.paired) > limit or self.paired[0].observed.done()):
            self._observe(self.paired.popleft())

    def _settle_mount(self) -> None:
        """The camera's mount from /tf_static, once, else the configured one (with a note)."""
        if self.mount_known:
            return
        self.mount_known = True
        result = self.part.extraction
        if self.static and self.image_frame:
            # The odometry's own body first (base_footprint on most diff-drive bases), so the
            # camera's height is above the floor the odometry moves on.
            bases = (self.odometry_frame, self.config.base_frame)
            try:
                result.mount = mount_from_transforms(self.static, bases, self.image_frame)
                base = " or ".join(b for b in dict.fromkeys(bases) if b)
                result.mount_source = f"{self.choice.tf_static} ({base} to {self.image_frame})"
            except LogError as error:
                text = f"{error}; assuming the configured camera mount"
                result.notes.append(Note("mount.not_in_tf", text, self.choice.tf_static))
        else:
            result.notes.append(
                Note(
                    "mount.no_tf_static",
                    "no /tf_static: assuming the configured camera mount "
                    f"({result.mount.describe()})",
                )
            )

    def _keep_attitude(self, t_ns: int, orientation: Any) -> None:
        """An odometry attitude kept in stamp order (a late stamp goes in its place), the
        oldest dropped once :data:`MAX_ATTITUDES` are kept."""
        if len(self.attitudes) == MAX_ATTITUDES:
            self.attitudes.popleft()
        bisect.insort(self.attitudes, (t_ns, orientation), key=itemgetter(0))

    def _levelled_view(self, t_ns: int) -> LevelledCamera | None:
        """The camera levelled with the odometry's attitude nearest ``t_ns``; None when level."""
        result = self.part.extraction
        assert result.camera is not None
        after = bisect.bisect_left(self.attitudes, t_ns, key=itemgetter(0))
        around = (self.attitudes[i] for i in (after - 1, after) if 0 <= i < len(self.attitudes))
        nearest = min(around, key=lambda a: abs(a[0] - t_ns), default=None)
        R = None
        if nearest is not None and abs(nearest[0] - t_ns) <= MAX_ATTITUDE_GAP_NS:
            R = rotation_of(nearest[1])
        # No attitude near it: a level base.
        return levelled_view(result.camera, result.mount, np.eye(3) if R is None else R)

    def _observe(self, paired: _Paired) -> None:
        """One frame's observations (made in the pool) and its counts kept; a bad frame costs
        itself."""
        result, choice, depth = self.part.extraction, self.choice, paired.depth
        key = (paired.t_ns, paired.frame.message.log_time_ns)
        observed = paired.observed.result()
        beyond = paired.frame.seen.result().beyond  # seen before it was observed
        if beyond is not None:
            result.dictionary_checks += 1
            result.ids_beyond_dictionary.update(beyond)
        shape, observations = observed.shape, observed.observations
        if isinstance(shape, LogError):
            result.undecodable_frames += 1
            result.skipped[f"colour image does not decode ({shape})"] += 1
            return
        if depth is not None and observed.depth_unaligned:
            result.unusable_depth += 1
            result.skipped[
                f"depth on {choice.depth} is {depth.shape[1]}x{depth.shape[0]}, colour "
                f"{shape[1]}x{shape[0]}: not aligned (used without depth)"
            ] += 1
            depth = None
        elif depth is not None:
            result.frames_with_depth += 1
        elif choice.depth:
            result.skipped["no depth within the pairing tolerance (used without)"] += 1
        result.observations += observations
        self.part.observation_frames += [key] * len(observations)
        if observed.levelled is not None:
            result.levelled_frames += 1
            result.levelled.append(observed.levelled)  # tallied once the log is read
            return
        result.depth_ratios += observed.depth_ratios
        result.size_ratios += observed.size_ratios
        if depth is not None:
            result.depth_tries += len(observations)
            result.depth_misses += sum(Flags.NO_DEPTH in o.flags for o in observations)
        seen = Counter(d.marker_id for d in observed.detections)
        result.level_detections += seen
        result.level_no_yaw += seen - Counter(o.marker_id for o in observations)


def read_span(
    arguments: tuple[Log, FrontendConfig, TopicChoice, dict[str, int], Span, int],
) -> Part:
    """One worker's stretch (:class:`SpanReader`), its arguments in one tuple for
    ``pool.map``."""
    log, config, choice, counts, span, threads = arguments
    return SpanReader(log, config, choice, counts, threads).read(span, None)


def one_opencv_thread() -> None:
    """A worker's set-up (:func:`~markergraph.common.pool.process_pool`): one OpenCV thread. The
    workers share the cores among them (each its share of threads, :func:`read_span`); OpenCV's
    own threads on top would only contend."""
    cv2.setNumThreads(1)
