"""A log to observations and odometry: pair colour with depth, detect, observe, in one process or
in workers that each read a stretch of the log.

Streams: only a few frames are held while colour waits for its depth, however long the log.
Nothing is dropped silently: every skipped frame is counted with its reason, and one bad message
costs its frame, not the run.
"""

from __future__ import annotations

import itertools
import math
import multiprocessing
import os
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.estimator.timing import turn_rate
from markergraph.estimator.trajectory import Trajectory
from markergraph.estimator.types import Observation, OdometrySample
from markergraph.frontend.camera import Camera, CameraMount
from markergraph.frontend.config import FrontendConfig
from markergraph.frontend.decode import (
    decode_depth,
    decode_image,
    frame_id,
    odometry_sample,
    stamp_ns,
)
from markergraph.frontend.detect import Detector, DetectorMode
from markergraph.frontend.inputs import CameraJudgement, judge_camera_info, odd_stamps
from markergraph.frontend.marker_size import SIZE_NOT_DEPTH, SizeByDepth, marker_sizes_by_depth
from markergraph.frontend.observe import Flags, observe_detections, robust_least_squares
from markergraph.frontend.odometry_kind import OdometryEvidence, odometry_evidence
from markergraph.frontend.posed import (
    LEVEL_TOLERANCE_RAD,
    MAX_ATTITUDE_GAP_NS,
    LevelledCamera,
    LevelledFrame,
    MarkerDetections,
    drop_notes,
    levelled_view,
    observe_levelled_frame,
    tally_detections,
)
from markergraph.frontend.ros2 import yaw_from_quaternion
from markergraph.frontend.sizes import MarkerSizes
from markergraph.frontend.sources import (
    DecodeFailures,
    LogError,
    Message,
    log_time_range,
    log_topics,
    messages,
    read_ahead,
)
from markergraph.frontend.tagged import DetectionLog, read_detection_log
from markergraph.frontend.tf import (
    mount_from_transforms,
    odometry_from_tf,
    rotation_of,
    transforms_of,
)
from markergraph.frontend.topics import (
    COLOR_TOPICS,
    TRUE_MARKERS,
    TRUE_POSE,
    TopicChoice,
    choose_topics,
)

__all__ = ["Extraction", "available_cores", "extract"]

MAX_ATTITUDES = 64  # the latest odometry attitudes kept to level frames with
SPANS_PER_WORKER = 4  # stretches of the log per worker: balances load, moves the progress bar


@dataclass
class Extraction:
    """What a log gave.

    Attributes:
        observations: every marker observation, in time order.
        odometry: ``T_odom_base``, its bad samples dropped (see ``notes``).
        camera, mount: the intrinsics and mount used.
        topics: the topics read.
        frames: colour frames read; frames_with_depth: of them, paired with depth.
        skipped: reason -> frames skipped for it.
        notes: what was assumed or dropped.
        warnings: damaged stretches skipped (unreadable messages, per file and topic).
        true_markers: ground truth ``T_map_marker`` when the log carries it (simulated logs).
        true_path: the true base pose in ``map``, when the log carries it.
        undecodable_frames: colour frames skipped because their image does not decode.
        unusable_depth: depth images skipped (undecodable, empty, or not the colour's size).
        ids_left_out: detections dropped by the allowed ids, by marker id.
        depth_misses: observations in frames with depth whose marker held no valid depth
            pixel (0, NaN, negative or beyond the depth model's range), of ``depth_tries``.
        levelled_frames: frames observed through the odometry's attitude (a tilted base or a
            rolled camera) rather than as level.
        levelled: those frames' detections, kept and dropped, until they are tallied.
        marker_detections: per marker observed from its full pose, its detections and how many
            were dropped (off a wall, no pose) or read with their corners reversed.
        depth_ratios: each well-placed marker's stamp, depth and PnP distance.
        size_ratios: each well-placed marker's id and depth over PnP distance, also where they
            disagree by more than observe's gate (a wrong marker size).
        depth_scale: what depth was taken to read per true metre, as set or measured; the
            ranges from depth are divided by it.
        measured_depth_scale: what the markers' known size measured it to be, if enough
            markers were seen with depth.
        marker_sizes_used: the markers' sizes the observations were made with, None until
            :func:`extract` sets them [m].
        marker_size_m_by_depth: the markers' size depth measures (the given size times
            ``marker_size_ratio_by_depth`` where that clearly disagrees; see
            :mod:`~markergraph.frontend.marker_size`), None without enough depth [m];
            marker_sizes_m_by_depth: markers apart from the rest, by id [m].
        marker_size_ratio_by_depth: depth over PnP's range with the given size, None without
            enough depth.
        odometry_evidence: what the odometry's first messages show of its kind (3-D motion,
            rate, covariance); None for odometry from /tf.
        odometry_model_reason: what chose the odometry's noise model (set when it is chosen).
        dropped_odometry_samples: odometry samples dropped as corrupt or with stamps their
            neighbours contradict (see ``notes``).
        worst_odometry_stamp_offset_s: the largest distance between a dropped odometry stamp
            and where the other stamps put it [s]; 0 when none was dropped for its stamp.
        frames_dropped_by_stamp: colour frames whose stamp their neighbours contradict; their
            observations are dropped.
        camera_infos_set_aside: camera_info messages not believed (see
            ``camera_info_reasons``), of ``camera_infos_judged``.
        camera_info_reasons: why they were set aside -> how many.
    """

    observations: list[Observation]
    odometry: Trajectory
    camera: Camera | None
    mount: CameraMount
    topics: TopicChoice
    frames: int = 0
    frames_with_depth: int = 0
    skipped: Counter[str] = field(default_factory=Counter)
    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    true_markers: dict[int, gtsam.Pose2] = field(default_factory=dict)
    true_path: Trajectory = field(default_factory=lambda: Trajectory.from_samples([], "map"))
    undecodable_frames: int = 0
    unusable_depth: int = 0
    ids_left_out: Counter[int] = field(default_factory=Counter)
    depth_misses: int = 0
    depth_tries: int = 0
    levelled_frames: int = 0
    levelled: list[LevelledFrame] = field(default_factory=list, repr=False)
    marker_detections: dict[int, MarkerDetections] = field(default_factory=dict)
    depth_ratios: list[tuple[int, float, float]] = field(default_factory=list)
    size_ratios: list[tuple[int, float]] = field(default_factory=list)
    depth_scale: float = 1.0
    measured_depth_scale: float | None = None
    dropped_odometry_samples: int = 0
    worst_odometry_stamp_offset_s: float = 0.0
    frames_dropped_by_stamp: int = 0
    camera_infos_judged: int = 0
    camera_infos_set_aside: int = 0
    camera_info_reasons: dict[str, int] = field(default_factory=dict)
    marker_sizes_used: MarkerSizes | None = None
    marker_size_m_by_depth: float | None = None
    marker_sizes_m_by_depth: dict[int, float] = field(default_factory=dict)
    marker_size_ratio_by_depth: float | None = None
    odometry_evidence: OdometryEvidence | None = None
    odometry_model_reason: str | None = None

    def input_evidence(self) -> dict[str, Any]:
        """What the front end judged of its inputs, JSON-ready (report.json's ``inputs``): what
        it set aside and what it measured, for a verdict to weigh."""
        evidence = self.odometry_evidence
        used = self.marker_sizes_used
        used_by_id = used.by_id if used is not None else {}
        return {
            "dropped_odometry_samples": self.dropped_odometry_samples,
            "worst_odometry_stamp_offset_s": self.worst_odometry_stamp_offset_s,
            "frames_dropped_by_stamp": self.frames_dropped_by_stamp,
            "camera_infos_judged": self.camera_infos_judged,
            "camera_infos_set_aside": self.camera_infos_set_aside,
            "camera_info_reasons": dict(self.camera_info_reasons),
            "marker_size_m_used": used.default_m if used is not None else 0.0,
            "marker_sizes_m_used": {str(k): v for k, v in used_by_id.items()},
            "marker_size_m_by_depth": self.marker_size_m_by_depth,
            "marker_size_ratio_by_depth": self.marker_size_ratio_by_depth,
            "marker_sizes_m_by_depth": {str(k): v for k, v in self.marker_sizes_m_by_depth.items()},
            "odometry_evidence": None if evidence is None else asdict(evidence),
            "odometry_model_reason": self.odometry_model_reason,
        }


@dataclass
class _Part:
    """One stretch's result before the stretches are joined: odometry and truth as read, in
    log order (bad samples are dropped only once all are joined)."""

    extraction: Extraction
    odometry: list[OdometrySample] = field(default_factory=list)
    odometry_log_ns: list[int] = field(default_factory=list)  # each sample's log time
    true_poses: list[OdometrySample] = field(default_factory=list)
    true_pose_log_ns: list[int] = field(default_factory=list)
    frame_stamps: list[tuple[int, int]] = field(default_factory=list)  # (stamp, log time)
    observation_frames: list[tuple[int, int]] = field(default_factory=list)  # each one's frame


@dataclass(frozen=True)
class _Frame:
    """A colour message with its grey image, or why the image does not decode."""

    message: Message
    image: NDArray[np.uint8] | LogError


_Job = tuple[int, _Frame, "NDArray | None"]  # (stamp, colour frame, paired depth)


class _Pairing:
    """Colour frames wait here for the depth image with the nearest stamp."""

    def __init__(self, tolerance_ns: int) -> None:
        self.tolerance = tolerance_ns
        self.colour: deque[tuple[int, _Frame]] = deque()
        self.depth: deque[tuple[int, NDArray]] = deque(maxlen=16)

    def matched_depth(self, t_ns: int) -> NDArray | None:
        best = min(self.depth, key=lambda d: abs(d[0] - t_ns), default=None)
        return best[1] if best is not None and abs(best[0] - t_ns) <= self.tolerance else None

    def ready(self, latest_ns: int, flush: bool = False) -> list[_Job]:
        """Colour frames that have their depth, or can no longer get it. Each frame is judged
        on its own, so one with a wrong stamp (far in the future) waits alone instead of
        holding up the frames behind it."""
        out, waiting = [], deque[tuple[int, _Frame]]()
        for t_ns, frame in self.colour:
            depth = self.matched_depth(t_ns)
            if depth is None and not flush and latest_ns - t_ns <= 3 * self.tolerance:
                waiting.append((t_ns, frame))
            else:
                out.append((t_ns, frame, depth))
        self.colour = waiting
        return out


_DETECTORS: dict[tuple[str, tuple[int, ...] | None, DetectorMode], Detector] = {}


def _detector(config: FrontendConfig) -> Detector:
    """One detector per process and configuration (building one costs more than a frame)."""
    key = (config.dictionary, config.allowed_ids, config.detector_mode)
    if key not in _DETECTORS:
        _DETECTORS[key] = Detector(
            config.dictionary, mode=config.detector_mode, allowed_ids=config.allowed_ids
        )
    return _DETECTORS[key]


@dataclass(frozen=True)
class _Span:
    """A stretch of a log: the colour frames, odometry and ground truth whose log times fall in
    [start_ns, end_ns); None for an open end."""

    start_ns: int | None = None
    end_ns: int | None = None

    def holds(self, t_ns: int) -> bool:
        return (self.start_ns is None or t_ns >= self.start_ns) and (
            self.end_ns is None or t_ns < self.end_ns
        )


def _with_images(
    stream: Iterator[Message], color: str | None, span: _Span
) -> Iterator[Message | _Frame]:
    """The stream, its colour messages inside ``span`` as frames with their images decoded.
    Run in the reading thread (:func:`read_ahead`), so decoding JPEG (0.6 ms a 640x480 frame,
    which releases the GIL) overlaps detection in the main thread: on bench_frontend's log the
    reading thread then spends 1.3-1.6 ms of CPU a frame and the main thread 1.8-2.0 ms.
    Closing it closes ``stream`` (and the log's file) in the thread that closes it."""
    try:
        for message in stream:
            if message.topic == color and span.holds(message.log_time_ns):
                try:
                    yield _Frame(message, decode_image(message))
                except LogError as error:
                    yield _Frame(message, error)
            else:
                yield message
    finally:
        close = getattr(stream, "close", None)
        if close is not None:
            close()


class _SpanReader:
    """One process's work: observations, odometry and ground truth of one stretch of the log."""

    def __init__(
        self, path: Path, config: FrontendConfig, choice: TopicChoice, counts: dict[str, int]
    ) -> None:
        self.path, self.config, self.choice, self.counts = path, config, choice, counts
        mount = config.mount or config.default_mount
        self.part = _Part(Extraction([], Trajectory.from_samples([]), config.camera, mount, choice))
        # Two books, one per thread: the reading thread's (messages) and this one's (_take).
        self.failures, self.read_failures = DecodeFailures(), DecodeFailures()
        self.static: list[Any] = []
        self.image_frame: str | None = None
        self.odometry_frame: str | None = None
        self.mount_known = config.mount is not None
        self.pairing = _Pairing(config.pair_tolerance_ns)
        self.detector = _detector(config)
        self.model = config.observation_model
        self.attitudes: deque[tuple[int, NDArray[np.float64]]] = deque(maxlen=MAX_ATTITUDES)

    def read(self, span: _Span, progress: Callable[[int, int], None] | None) -> _Part:
        left_out_before = Counter(self.detector.left_out)
        self._read_once_topics()
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
        stream = messages(self.path, streamed, self.read_failures, start, end)
        for item in read_ahead(_with_images(stream, color, span)):
            if isinstance(item, _Frame):
                done += 1
                if progress is not None and done % 10 == 0:
                    progress(done, total)
                self._take_frame(item)
            else:
                self._take(item, span.holds(item.log_time_ns))
        self._drain(0, flush=True)
        if progress is not None:
            progress(total, total)
        result = self.part.extraction
        result.warnings = self.read_failures.warnings() + self.failures.warnings()
        result.ids_left_out = self.detector.left_out - left_out_before
        return self.part

    def _read_once_topics(self) -> None:
        """Topics published once at the start: static transforms and true marker poses."""
        once = [t for t in (self.choice.tf_static, TRUE_MARKERS) if t and t in self.counts]
        for message in messages(self.path, once, self.failures):
            if message.topic == self.choice.tf_static:
                self.static += transforms_of(message.decoded)
                continue
            for transform in message.decoded.transforms:
                if transform.child_frame_id.startswith("aruco_"):
                    q, t = transform.transform.rotation, transform.transform.translation
                    pose = (t.x, t.y, yaw_from_quaternion(q.x, q.y, q.z, q.w))
                    if not all(math.isfinite(v) for v in pose):
                        self.part.extraction.notes.append(
                            f"ignored the non-finite true pose of {transform.child_frame_id} "
                            f"on {TRUE_MARKERS}"
                        )
                        continue
                    marker_id = int(transform.child_frame_id[6:])
                    self.part.extraction.true_markers[marker_id] = gtsam.Pose2(*pose)

    def _take_frame(self, frame: _Frame) -> None:
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
                self.pairing.depth.append((stamp_ns(decoded), decode_depth(message)))
            except LogError as error:  # the frame waiting for it goes on without depth
                result.unusable_depth += 1
                self.failures.add(self.path, topic, str(error))
            self._drain(stamp_ns(decoded))
        elif topic == choice.odom:
            if message.schema.endswith("TFMessage"):
                if inside:
                    samples = odometry_from_tf(decoded, self.config.base_frame)
                    self.part.odometry += samples
                    self.part.odometry_log_ns += [message.log_time_ns] * len(samples)
                return
            if inside:
                self.part.odometry.append(odometry_sample(message))
                self.part.odometry_log_ns.append(message.log_time_ns)
            self.odometry_frame = self.odometry_frame or getattr(decoded, "child_frame_id", None)
            pose = decoded.pose.pose if hasattr(decoded.pose, "pose") else decoded.pose
            R = rotation_of(pose.orientation)
            if R is not None:  # its attitude levels the frames about it
                self.attitudes.append((stamp_ns(decoded), R))
        elif topic == TRUE_POSE and inside:
            q, p = decoded.pose.orientation, decoded.pose.position
            self.part.true_poses.append(
                OdometrySample(stamp_ns(decoded), p.x, p.y, yaw_from_quaternion(q.x, q.y, q.z, q.w))
            )
            self.part.true_pose_log_ns.append(message.log_time_ns)

    def _drain(self, latest_ns: int, flush: bool = False) -> None:
        ready = self.pairing.ready(latest_ns, flush)
        if ready:
            self._settle_mount()
        for job in ready:
            self._observe(*job)

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
            except LogError as error:
                result.notes.append(f"{error}; assuming the configured camera mount")
        else:
            result.notes.append(
                f"no /tf_static: assuming the configured camera mount ({result.mount.describe()})"
            )

    def _levelled_view(self, t_ns: int) -> LevelledCamera | None:
        """The camera levelled with the odometry's attitude nearest ``t_ns``; None when level."""
        result = self.part.extraction
        assert result.camera is not None
        nearest = min(self.attitudes, key=lambda a: abs(a[0] - t_ns), default=None)
        if nearest is None or abs(nearest[0] - t_ns) > MAX_ATTITUDE_GAP_NS:
            nearest = (t_ns, np.eye(3))  # no attitude: a level base
        return levelled_view(result.camera, result.mount, nearest[1])

    def _observe(self, t_ns: int, frame: _Frame, depth: NDArray | None) -> None:
        """One colour frame with its depth (if any) to observations; a bad frame costs itself."""
        result, choice, image = self.part.extraction, self.choice, frame.image
        assert result.camera is not None  # extract judged it before reading
        key = (t_ns, frame.message.log_time_ns)
        if isinstance(image, LogError):
            result.undecodable_frames += 1
            result.skipped[f"colour image does not decode ({image})"] += 1
            return
        if depth is not None and depth.shape[:2] != image.shape[:2]:
            result.unusable_depth += 1
            result.skipped[
                f"depth on {choice.depth} is {depth.shape[1]}x{depth.shape[0]}, colour "
                f"{image.shape[1]}x{image.shape[0]}: not aligned (used without depth)"
            ] += 1
            depth = None
        elif depth is not None:
            result.frames_with_depth += 1
        elif choice.depth:
            result.skipped["no depth within the pairing tolerance (used without)"] += 1
        detections = self.detector.detect(image)
        view = self._levelled_view(t_ns)
        if view is not None:
            # A tilted base (a ramp, a hand-held rig) or a rolled camera: each marker's full
            # pose from its corners, turned into the level frame.
            levelled = observe_levelled_frame(detections, view, self.model, t_ns)
            observations = levelled.observations
            result.levelled_frames += 1
            result.levelled.append(levelled)  # tallied once the log is read: drop_notes
            result.observations += observations
            self.part.observation_frames += [key] * len(observations)
            return
        observations = observe_detections(
            detections, result.camera, self.model, depth=depth, mount=result.mount, t_ns=t_ns,
            depth_ratios=result.depth_ratios, size_ratios=result.size_ratios,
        )  # fmt: skip
        if depth is not None:
            result.depth_tries += len(observations)
            result.depth_misses += sum(Flags.NO_DEPTH in o.flags for o in observations)
        result.observations += observations
        self.part.observation_frames += [key] * len(observations)


def _from_detections(log: DetectionLog, choice: TopicChoice) -> _Part:
    """A detection log's reading as one stretch: observations made from the body origin, so
    the estimators' camera mount is the identity."""
    level = CameraMount(0.0, 0.0, 0.0, 0.0, 0.0)
    extraction = Extraction(
        log.observations,
        Trajectory.from_samples([]),
        log.camera,
        level,
        choice,
        frames=log.frames,
        skipped=log.skipped,
        notes=log.notes,
        warnings=log.warnings,
        ids_left_out=log.ids_left_out,
        marker_detections=log.marker_detections,
    )
    # A detection log's odometry carries no log times: its stamps are judged by order alone.
    return _Part(extraction, log.odometry, [0] * len(log.odometry))


def _read_span(
    arguments: tuple[Path, FrontendConfig, TopicChoice, dict[str, int], _Span],
) -> _Part:
    path, config, choice, counts, span = arguments
    return _SpanReader(path, config, choice, counts).read(span, None)


def _start_worker(parent_pid: int) -> None:
    """In each worker: one OpenCV thread (a worker's reading and main threads already keep about
    one and a half cores busy; more would only contend), and a watchdog that ends the worker
    when its parent dies (a killed run must not leave workers waiting forever for work)."""
    cv2.setNumThreads(1)

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watch, daemon=True).start()


def available_cores() -> int:
    """The cores this process may run on."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return os.cpu_count() or 1


def busy_cores(seconds: float = 0.2) -> float | None:
    """How many of the cores this process may run on other work keeps busy now: their share
    not idle over ``seconds``, from Linux's per-core counters in ``/proc/stat`` (time the host
    steals counts as busy: a core lent elsewhere is no help). None where there are no such
    counters. Unlike the load average, which trails by a minute, it sees a core freed a moment
    ago, such as by a run of ours that has just ended."""

    def counters() -> dict[int, tuple[int, int]]:
        with open("/proc/stat") as stat:
            return core_ticks(stat.read())

    try:
        before = counters()
        time.sleep(seconds)
        after = counters()
    except (OSError, ValueError, IndexError):
        return None
    mine = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else set(after)
    busy, seen = 0.0, 0
    for core in mine & set(before) & set(after):
        idle, total = (a - b for a, b in zip(after[core], before[core], strict=True))
        if total > 0:
            busy += 1.0 - idle / total
            seen += 1
    return busy if seen else None


def core_ticks(proc_stat: str) -> dict[int, tuple[int, int]]:
    """Each core's (idle and iowait, all) clock ticks since boot from ``/proc/stat``'s text:
    its ``cpuN`` lines' first eight fields, user to steal (guest time is already in user)."""
    ticks = {}
    for line in proc_stat.splitlines():
        name, *fields = line.split() or [""]
        if name.startswith("cpu") and name[3:].isdigit():
            values = [int(v) for v in fields[:8]]
            ticks[int(name[3:])] = (values[3] + values[4], sum(values))
    return ticks


# A worker costs 0.3-0.7 s to spawn and import, and a few hundred frames a second repay it: below
# this many frames each, one process is as fast.
MIN_FRAMES_PER_WORKER = 1500
# Cores one process keeps busy: its main thread, and its reading thread's zstd and JPEG decoding
# (bench_frontend: about 1.3 and 1.75 ms of CPU a frame in 2.1 ms).
CORES_PER_PROCESS = 1.5


def choose_workers(frames: int, asked: int | None) -> tuple[int, str | None]:
    """How many processes to read a log of ``frames`` colour frames with, and a note saying
    why. A number asked for is used, capped at the cores there are. ``None`` (auto) gives more
    than one only where each has :data:`MIN_FRAMES_PER_WORKER` frames and
    :data:`CORES_PER_PROCESS` idle cores now, measured over a fifth of a second
    (:func:`busy_cores`; elsewhere the 1-minute load average): a process's reading thread
    already keeps a second core busy, so on this 2-core machine a second process ran 0.81-1.33x
    one a round on bench_frontend's 3-minute log (slower whenever the host held part of a core)
    and 1.17x on a 10-minute log."""
    cores = available_cores()
    if asked is not None:
        if asked <= cores:
            return asked, None
        return cores, f"--workers {asked} capped at the {cores} cores available"
    by_length = max(1, frames // MIN_FRAMES_PER_WORKER)
    if by_length == 1 or cores < 2 * CORES_PER_PROCESS:
        return 1, (
            f"workers: 1 (auto: {frames} frames, {cores} cores; a process keeps about "
            f"{CORES_PER_PROCESS} busy, and each worker wants {MIN_FRAMES_PER_WORKER} frames)"
        )
    busy = busy_cores()
    if busy is not None:
        measured = f"{busy:.1f} busy over 0.2 s"
    else:
        busy = os.getloadavg()[0] if hasattr(os, "getloadavg") else 0.0
        measured = f"by the load average {busy:.1f}"
    idle = max(0.0, cores - busy)
    chosen = max(1, min(by_length, int(idle / CORES_PER_PROCESS)))
    return chosen, (
        f"workers: {chosen} (auto: {frames} frames, one worker per {MIN_FRAMES_PER_WORKER}; "
        f"{idle:.1f} of {cores} cores idle, {measured}; a process keeps about "
        f"{CORES_PER_PROCESS} busy)"
    )


def _merge(parts: list[_Part]) -> _Part:
    """Stretches' results joined in log order."""
    first = parts[0].extraction
    merged = _Part(
        Extraction(
            [],
            first.odometry,
            next((p.extraction.camera for p in parts if p.extraction.camera), None),
            first.mount,
            first.topics,
            true_markers=first.true_markers,
        )
    )
    result = merged.extraction
    for part in parts:
        piece = part.extraction
        result.observations += piece.observations
        merged.observation_frames += part.observation_frames
        merged.odometry += part.odometry
        merged.odometry_log_ns += part.odometry_log_ns
        merged.true_poses += part.true_poses
        merged.true_pose_log_ns += part.true_pose_log_ns
        merged.frame_stamps += part.frame_stamps
        result.frames += piece.frames
        result.frames_with_depth += piece.frames_with_depth
        result.skipped.update(piece.skipped)
        result.notes += [n for n in piece.notes if n not in result.notes]
        result.warnings += piece.warnings
        result.undecodable_frames += piece.undecodable_frames
        result.unusable_depth += piece.unusable_depth
        result.ids_left_out.update(piece.ids_left_out)
        result.depth_misses += piece.depth_misses
        result.depth_tries += piece.depth_tries
        result.levelled_frames += piece.levelled_frames
        result.levelled += piece.levelled
        result.depth_ratios += piece.depth_ratios
        result.size_ratios += piece.size_ratios
    return merged


MIN_DEPTH_RATIOS = 20  # markers seen with depth before a depth scale is estimated
# Depth over PnP's range is one ratio with two readings: the depth camera's scale, or the
# markers' size. Beyond SIZE_NOT_DEPTH (5 %) it is taken as the size, which extract measures
# and reads the log again with (marker_size.py says why); within it, as the depth's scale,
# applied by auto beyond the measurement's own error (DEPTH_SCALE_RESOLUTION). A depth scale is
# never set beyond it: a 25 % disagreement is a size, a 1 % one a depth camera.
MAX_DEPTH_SCALE_ERROR = SIZE_NOT_DEPTH
# A depth scale within this of 1 is left alone by auto: the measurement's own error. On the
# independent generator's eight logs it read within 0.07 % of the truth, on our paper room's
# within 0.1 %; on our office's ideal log of seed 4 -0.32 % (its markers seen from 2.4-6 m
# only, the far ones small and drawn without the lens blur that smooths a real camera's edges),
# and applied, SLAM was 1.7 cm off instead of 1.0.
DEPTH_SCALE_RESOLUTION = 0.004


def depth_scale_from_markers(
    pairs: list[tuple[int, float, float]], odometry: Trajectory
) -> tuple[float, int]:
    """What depth reads per true metre, and how many markers said so: the mean of depth over
    PnP's distance (which rests on the marker's known size; points beyond three robust sigmas
    dropped, twice), over markers seen while the robot turned slower than 0.2 rad/s (blur and
    a rolling shutter bend PnP).

    PnP is unbiased at every distance because the corners are (:func:`edge_refined`): with
    OpenCV's corners alone, a few tenths of a pixel inside the true ones, PnP read long by 0.3-0.6
    % a metre, and a line's intercept through depth / PnP had to stand in for the scale, 0.0 to
    +0.85 % off on ideal logs. Now depth / PnP shows no trend with distance (a line's slope
    within 0.09 % a metre), and its mean reads within 0.07 % of the truth on the independent
    generator's eight logs (exact depth, and a D435i's +1.2 %), 0.04-0.13 % low on ours.
    """
    steady = [(z, z_pnp) for t_ns, z, z_pnp in pairs if abs(turn_rate(odometry, t_ns)) < 0.2]
    if len(steady) < MIN_DEPTH_RATIOS:
        steady = [(z, z_pnp) for _, z, z_pnp in pairs]
    z, z_pnp = np.array(steady, dtype=np.float64).T
    ratio = z / z_pnp
    mean, _, _ = robust_least_squares(np.ones((ratio.size, 1)), ratio, passes=3)
    return float(mean[0]), len(steady)


def _correct_depth_scale(result: Extraction, configured: float | None, topic: str | None) -> None:
    """Measure the depth's scale against the markers' known size
    (:func:`depth_scale_from_markers`) and say it; divide the ranges from depth by the
    configured scale, or (``configured`` None: auto) by the measured one when it is further
    from 1 than the measurement's own error (:data:`DEPTH_SCALE_RESOLUTION`)."""
    measured = None
    if len(result.depth_ratios) >= MIN_DEPTH_RATIOS:
        scale, used = depth_scale_from_markers(result.depth_ratios, result.odometry)
        result.measured_depth_scale = measured = scale
        reads = f"depth on {topic} reads {100 * (scale - 1):+.2f} % against the markers' size"
        if abs(scale - 1.0) > MAX_DEPTH_SCALE_ERROR:
            result.notes.append(
                f"{reads}: too far off for a depth camera, so the marker size is more likely "
                "wrong; depth left as it is"
            )
            measured = None
        elif configured is not None:
            result.notes.append(
                f"{reads} ({used} markers); --depth-scale {configured:g} applied"
                if configured != 1.0
                else f"{reads} ({used} markers); depth taken as it is (--depth-scale 1)"
            )
        elif abs(scale - 1.0) <= DEPTH_SCALE_RESOLUTION:
            result.notes.append(
                f"{reads} ({used} markers): within the measurement's own "
                f"{100 * DEPTH_SCALE_RESOLUTION:g} % error, so depth is left as it is "
                "(--depth-scale K sets it)"
            )
            measured = None
        else:
            result.notes.append(f"{reads} ({used} markers): ranges from depth corrected")
    applied = configured if configured is not None else measured
    if applied is None or applied == 1.0:
        return
    result.depth_scale = scale = applied
    result.observations = [
        o if Flags.NO_DEPTH in o.flags
        else replace(o, range_m=o.range_m / scale, sigma_range=o.sigma_range / scale)
        for o in result.observations
    ]  # fmt: skip


def _judged_camera(path: Path, choice: TopicChoice, counts: dict[str, int]) -> CameraJudgement:
    """The camera model the log's camera_info messages agree on (:func:`judge_camera_info`).

    Raises:
        LogError: no camera info topic, or none of its messages gives a believable model.
    """
    topic = choice.camera_info
    if topic is None:
        raise LogError(
            f"{path}: no camera intrinsics: no camera info topic found (pass --camera-info-topic)"
        )
    if not counts.get(topic):
        raise LogError(f"{path}: no camera intrinsics: no messages on {topic}")
    failures = DecodeFailures()
    judgement = judge_camera_info(path, topic, failures)
    if judgement.camera is None:
        reasons = list(judgement.set_aside) + [w.partition(": ")[2] for w in failures.warnings()]
        raise LogError(
            f"{path}: no camera intrinsics: none of the first {judgement.read} messages on "
            f"{topic} is believable ({'; '.join(reasons) or 'none decodes'})"
        )
    return judgement


def _check_usable(path: Path, choice: TopicChoice, result: Extraction) -> None:
    """Bad messages cost their frames; but a topic of which nothing could be used is an error.

    Raises:
        LogError: no camera intrinsics, no colour frame decodes, or depth was chosen and none
            of it is usable.
    """
    if result.camera is None:
        bad_info = [w for w in result.warnings if choice.camera_info and choice.camera_info in w]
        raise LogError(
            f"{path}: no camera intrinsics: "
            + (
                bad_info[0].partition(": ")[2]
                if bad_info
                else f"no messages on {choice.camera_info}"
                if choice.camera_info
                else "no camera info topic found (pass --camera-info-topic)"
            )
        )
    if result.frames and result.undecodable_frames == result.frames:
        first = next(reason for reason in result.skipped if reason.startswith("colour image"))
        raise LogError(f"{path}: none of the {result.frames} frames on {choice.color}: {first}")
    if choice.depth and result.unusable_depth and not result.frames_with_depth:
        reasons = [r for r in result.skipped if "not aligned" in r] + [
            w for w in result.warnings if choice.depth in w
        ]
        raise LogError(
            f"{path}: no usable depth on {choice.depth} ({reasons[0] if reasons else 'unusable'});"
            " pass --depth-topic with the aligned depth topic"
        )


# No wheeled robot or hand-held rig moves this fast, and no floor is this far from its origin:
# a sample that says so is a corrupted message, not motion.
MAX_SPEED_MPS = 50.0
MAX_COORDINATE_M = 1e7


@dataclass(frozen=True)
class _CleanPath:
    """A path without its corrupted samples, and what was dropped."""

    path: Trajectory
    dropped: int
    worst_stamp_offset_s: float


def _clean_path(
    samples: list[OdometrySample],
    log_ns: list[int],
    topic: str | None,
    what: str,
    notes: list[str],
    frame: str,
) -> _CleanPath:
    """A path without its corrupted samples, each kind dropped with a note naming the topic:
    one bad sample must not poison the map. Dropped: non-finite values (NaN, inf, a zero
    quaternion), coordinates beyond 10,000 km, stamps their neighbours contradict (out of the
    order the others rise in, a repeat, or off the others' lead over their log times:
    :func:`odd_stamps`, which keeps the majority rather than the first), and single samples
    that jump away and back faster than 50 m/s.

    Args:
        samples: in log order; log_ns: each one's log time [ns].
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
    for n, why in (
        (absurd, "with NaN, infinite or absurd values"),
        (
            judged.dropped,
            "whose stamps their neighbours contradict (out of order, repeated, or off the "
            f"others' lead over their log times; the worst by {judged.worst_offset_s:.3g} s)",
        ),
        (spikes, f"that jump away and back faster than {MAX_SPEED_MPS:g} m/s"),
    ):
        if n:
            notes.append(f"dropped {n} {what} sample(s) on {topic} {why}")
    dropped = absurd + judged.dropped + spikes
    return _CleanPath(Trajectory.from_samples(kept, frame), dropped, judged.worst_offset_s)


def _drop_frames_by_stamp(part: _Part, topic: str | None) -> None:
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
    result.notes.append(
        f"dropped the observations of {judged.dropped} frame(s) on {topic} whose stamps their "
        "neighbours contradict (out of order, repeated, or off the others' lead over their log "
        f"times; the worst by {judged.worst_offset_s:.3g} s)"
    )


def _is_spike(before: OdometrySample, sample: OdometrySample, after: OdometrySample) -> bool:
    def speed(a: OdometrySample, b: OdometrySample) -> float:
        return math.hypot(b.x - a.x, b.y - a.y) / ((b.t_ns - a.t_ns) * 1e-9)

    return (
        speed(before, sample) > MAX_SPEED_MPS
        and speed(sample, after) > MAX_SPEED_MPS
        and speed(before, after) <= MAX_SPEED_MPS
    )


def extract(
    path: Path,
    config: FrontendConfig = FrontendConfig(),
    progress: Callable[[int, int], None] | None = None,
    workers: int | None = 1,
) -> Extraction:
    """Observations and odometry from a log (:func:`_extract_once`), read a second time with
    the markers' size that depth measures when it clearly disagrees with the given one
    (:func:`marker_sizes_by_depth`): a wrong size would scale every range from PnP and make
    observe set every depth aside as disagreeing with it.

    Args:
        progress: called with (colour frames read, frames in all); twice over with a size
            measured.
        workers: see :func:`_extract_once`.

    Raises:
        LogError: the log cannot be read, has no camera, or nothing usable on a topic.
        SettingsError: a bad dictionary, or allowed ids outside it.
    """
    path, given_m = Path(path), config.marker_sizes.default_m
    result = _extract_once(path, config, progress, workers)
    size = marker_sizes_by_depth(
        result.size_ratios, config.marker_sizes.default_m, config.marker_sizes.by_id,
        config.depth_scale or 1.0,
    )  # fmt: skip
    notes = []
    if size is not None and size.use:
        sizes = MarkerSizes(size.size_m, config.marker_sizes.by_id).with_sizes(size.sizes_m)
        notes = _size_notes(size, config)
        config = replace(config, marker_sizes=sizes)
        result = _extract_once(path, config, progress, workers)
    elif size is None and result.observations:
        topic = result.topics.depth
        notes.append(
            f"the map's scale rests on the given marker size ({config.marker_sizes.default_m:g} m; "
            "--marker-size sets it): "
            + (
                f"too few markers seen with depth on {topic} ({len(result.size_ratios)}) to "
                "measure it"
                if topic
                else "no depth to measure it"
            )
        )
    result.notes += notes
    result.marker_sizes_used = config.marker_sizes
    if size is not None:
        result.marker_size_m_by_depth = given_m * size.ratio
        result.marker_size_ratio_by_depth = size.ratio
        result.marker_sizes_m_by_depth = dict(size.sizes_m)
    return result


def _size_notes(size: SizeByDepth, config: FrontendConfig) -> list[str]:
    """What depth measured of the markers' size, and what is used."""
    notes = []
    given_m = config.marker_sizes.default_m
    if size.size_m != given_m:
        short = 100 * (1 - 1 / size.ratio)
        notes.append(
            f"markers measure {size.size_m:.3f} m by depth (the given {given_m:g}"
            f" m would put every range {abs(short):.0f} % {'short' if short > 0 else 'long'}; "
            f"depth over PnP's range in {size.sightings} sightings, "
            f"{100 * size.ratio_sigma:.2f} % error): using {size.size_m:.3f} m. A depth camera "
            "is not this far off, a marker size can be: --marker-size sets the size, "
            "--depth-scale K says depth reads K per true metre"
        )
    for marker_id, size_m in sorted(size.sizes_m.items()):
        given = config.marker_sizes.of(marker_id)
        notes.append(
            f"marker {marker_id} measures {size_m:.3f} m by depth, apart from the others "
            f"(given {given:g} m): using {size_m:.3f} m for it"
        )
    return notes


def _extract_once(
    path: Path,
    config: FrontendConfig = FrontendConfig(),
    progress: Callable[[int, int], None] | None = None,
    workers: int | None = 1,
) -> Extraction:
    """Observations and odometry from a ROS 2 or Foxglove MCAP log (file or rosbag2 folder).

    Args:
        progress: called with (colour frames read, frames in all).
        workers: processes (``spawn``ed: forking after OpenCV has run can deadlock); None: as
            many as help (:func:`choose_workers`, which also trims a number asked for). With
            more than one, the log is cut into stretches of time that the workers read and
            process whole, each from its own chunks; the results are joined in log order.

    Raises:
        LogError: the log cannot be read, has no camera, or nothing usable on a topic.
        SettingsError: a bad dictionary, or allowed ids outside it.
    """
    path = Path(path)
    topics = log_topics(path)
    choice = choose_topics(path, topics, config)
    if choice.color is None and not choice.detections:
        raise LogError(
            f"{path}: no camera image topic (looked for {', '.join(COLOR_TOPICS)} "
            "and any image message)"
        )
    counts = {t.topic: t.count for t in topics}
    _detector(config)  # a bad dictionary or --ids fails here, before any worker starts
    notes = []
    workers, why = choose_workers(counts.get(choice.color or "", 0), workers)
    if why is not None:
        notes.append(why)
    judgement = None
    if not choice.detections and config.camera is None:
        judgement = _judged_camera(path, choice, counts)
        config = replace(config, camera=judgement.camera)
    if choice.detections:
        part = _from_detections(read_detection_log(path, config, choice, topics), choice)
    elif workers <= 1:
        part = _SpanReader(path, config, choice, counts).read(_Span(), progress)
    else:
        first, last = log_time_range(path)
        edges = np.linspace(first, last + 1, SPANS_PER_WORKER * workers + 1).astype(np.int64)
        spans = [_Span(int(a), int(b)) for a, b in itertools.pairwise(edges)]
        parts = []
        with ProcessPoolExecutor(
            workers,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_start_worker,
            initargs=(os.getpid(),),
        ) as pool:
            jobs = [(path, config, choice, counts, span) for span in spans]
            for done, piece in enumerate(pool.map(_read_span, jobs), start=1):
                parts.append(piece)
                if progress is not None:  # in frames, as one process counts them
                    frames = counts.get(choice.color or "", 0)
                    progress(done * frames // len(spans), frames)
        part = _merge(parts)
    result = part.extraction
    if choice.odom and counts.get(choice.odom):
        result.odometry_evidence = odometry_evidence(path, choice.odom)
    if judgement is not None:
        result.camera_infos_judged = judgement.read
        result.camera_infos_set_aside = sum(judgement.set_aside.values())
        result.camera_info_reasons = judgement.set_aside
        note = judgement.note(choice.camera_info or "")
        if note is not None:
            notes.append(note)
    result.notes = notes + result.notes
    _check_usable(path, choice, result)
    _drop_frames_by_stamp(part, choice.color)
    odometry = _clean_path(
        part.odometry, part.odometry_log_ns, choice.odom, "odometry", result.notes, "odom"
    )
    result.odometry = odometry.path
    result.dropped_odometry_samples = odometry.dropped
    result.worst_odometry_stamp_offset_s = odometry.worst_stamp_offset_s
    result.true_path = _clean_path(
        part.true_poses, part.true_pose_log_ns, TRUE_POSE, "ground-truth", result.notes, "map"
    ).path
    _correct_depth_scale(result, config.depth_scale, choice.depth)
    if result.depth_misses:
        result.notes.append(
            f"{result.depth_misses} of {result.depth_tries} observations in frames with depth "
            f"found no valid depth on their marker in {choice.depth} (0, NaN, negative, beyond"
            " noise.depth_max_m, or 20 % from the marker's PnP distance): their range comes from"
            " the marker's pose (PnP)"
        )
    if result.levelled:
        result.marker_detections = tally_detections(result.levelled)
        result.notes += drop_notes(result.marker_detections)
        result.levelled = []
    if result.levelled_frames:
        result.notes.append(
            f"{result.levelled_frames} of {result.frames} frames were taken with the base tilted "
            f"or the camera rolled by more than {math.degrees(LEVEL_TOLERANCE_RAD):.1f} deg: "
            f"levelled with {choice.odom}'s attitude, their markers' range and theta from each "
            "marker's full pose (PnP), without depth"
        )
    if result.ids_left_out:
        ids = ", ".join(str(i) for i in sorted(result.ids_left_out))
        result.notes.append(
            f"{sum(result.ids_left_out.values())} detection(s) of marker(s) {ids} were left out "
            "by the allowed ids (--ids)"
        )
    return result
