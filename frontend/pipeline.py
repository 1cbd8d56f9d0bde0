"""A log to observations and odometry: pick topics, pair colour with depth, detect, observe.

Streams: only a few frames are held while colour waits for its depth, however long the log.
Nothing is dropped silently: every skipped frame is counted with its reason.
"""

from __future__ import annotations

import itertools
import math
import multiprocessing
import os
import re
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Mapping
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.estimator.types import Observation, OdometrySample
from markergraph.frontend.camera import Camera, CameraMount
from markergraph.frontend.detect import Detector
from markergraph.frontend.log import (
    DecodeFailures,
    LogError,
    LogTopic,
    Message,
    decode_depth,
    decode_image,
    frame_id,
    log_time_range,
    log_topics,
    messages,
    mount_from_transforms,
    odometry_from_tf,
    odometry_sample,
    stamp_ns,
    transforms_of,
)
from markergraph.frontend.observe import DepthModel, observe_detections
from markergraph.frontend.ros2 import yaw_from_quaternion
from markergraph.frontend.yaw import YawMethod

__all__ = ["Extraction", "FrontendConfig", "TopicChoice", "choose_topics", "extract"]

# realsense-ros 4.x first, then the older single namespace.
COLOR_TOPICS = (
    "/camera/camera/color/image_raw/compressed",
    "/camera/camera/color/image_raw",
    "/camera/color/image_raw/compressed",
    "/camera/color/image_raw",
)
DEPTH_TOPICS = (
    "/camera/camera/aligned_depth_to_color/image_raw",
    "/camera/camera/aligned_depth_to_color/image_raw/compressedDepth",
    "/camera/aligned_depth_to_color/image_raw",
    "/camera/aligned_depth_to_color/image_raw/compressedDepth",
)
TRUE_MARKERS, TRUE_POSE = "/ground_truth/markers", "/ground_truth/pose"
# ROS 2 and Foxglove (protobuf) message types, by role.
IMAGE_SCHEMAS = (
    "sensor_msgs/msg/Image",
    "sensor_msgs/msg/CompressedImage",
    "foxglove.CompressedImage",
    "foxglove.RawImage",
)
CALIBRATION_SCHEMAS = ("sensor_msgs/msg/CameraInfo", "foxglove.CameraCalibration")
ODOMETRY_SCHEMAS = ("nav_msgs/msg/Odometry", "foxglove.PoseInFrame")
TRANSFORM_SCHEMAS = ("foxglove.FrameTransforms", "foxglove.FrameTransform")
MAX_WAITING_FRAMES = 30
SPANS_PER_WORKER = 4  # stretches of the log per worker: balances load, moves the progress bar


@dataclass(frozen=True)
class FrontendConfig:
    """How to read a log. Topics left as None are chosen automatically.

    Attributes:
        dictionary: the markers' dictionary.
        marker_length_m: side of the markers' black square [m].
        marker_lengths_m: the sides of markers whose size differs, by id [m].
        method: how theta is computed.
        allowed_ids: if given, only these marker ids are kept.
        color_topic, depth_topic, camera_info_topic, odom_topic: topics to read.
        base_frame: the robot's base frame in /tf_static.
        mount: the camera's mount; None reads it from /tf_static.
        default_mount: the mount assumed when /tf_static does not give it.
        camera: intrinsics; None reads them from the camera info topic.
        pair_tolerance_ns: largest stamp difference between a colour frame and its depth.
        depth_model: the depth camera's error model.
        corner_sigma_px: the corners' noise after sub-pixel refinement [px].
    """

    dictionary: str = "DICT_4X4_50"
    marker_length_m: float = 0.2
    marker_lengths_m: Mapping[int, float] = field(default_factory=dict)
    method: YawMethod = YawMethod.PNP
    allowed_ids: tuple[int, ...] | None = None
    color_topic: str | None = None
    depth_topic: str | None = None
    camera_info_topic: str | None = None
    odom_topic: str | None = None
    base_frame: str = "base_link"
    mount: CameraMount | None = None
    default_mount: CameraMount = CameraMount()
    camera: Camera | None = None
    pair_tolerance_ns: int = 20_000_000
    depth_model: DepthModel = DepthModel()
    corner_sigma_px: float = 0.3


@dataclass(frozen=True)
class TopicChoice:
    """The topics a log will be read from (None where the log has none)."""

    color: str | None
    depth: str | None
    camera_info: str | None
    odom: str | None
    tf_static: str | None


def _camera_info_for(color: str) -> str:
    namespace = re.sub(r"/image_raw(/compressed)?$", "", color)
    return f"{namespace}/camera_info"


def choose_topics(path: Path, topics: list[LogTopic], config: FrontendConfig) -> TopicChoice:
    """The colour, depth, camera info, odometry and tf_static topics to use.

    Raises:
        LogError: a configured topic is not in the log.
    """
    by_name = {t.topic: t for t in topics}
    for role, name, schemas in (
        ("--color-topic", config.color_topic, IMAGE_SCHEMAS),
        ("--depth-topic", config.depth_topic, IMAGE_SCHEMAS),
        ("--camera-info-topic", config.camera_info_topic, CALIBRATION_SCHEMAS),
        ("--odom-topic", config.odom_topic, (*ODOMETRY_SCHEMAS, "tf2_msgs/msg/TFMessage")),
    ):
        if name is None:
            continue
        if name not in by_name:
            raise LogError(f"{path}: no topic {name}; it has {', '.join(sorted(by_name))}")
        if not by_name[name].schema.endswith(schemas):
            raise LogError(
                f"{path}: {role} {name} carries {by_name[name].schema or 'untyped messages'}, "
                f"not {' or '.join(schemas)}"
            )
    images = [t.topic for t in topics if t.schema.endswith(IMAGE_SCHEMAS)]
    color = config.color_topic or next((t for t in COLOR_TOPICS if t in by_name), None)
    if color is None:
        plain = [t for t in images if "depth" not in t.lower()]
        color = plain[0] if plain else None
    depth = config.depth_topic or next((t for t in DEPTH_TOPICS if t in by_name), None)
    if depth is None:
        depths = [t for t in images if "depth" in t.lower()]
        depth = depths[0] if len(depths) == 1 else None
    info = config.camera_info_topic or (_camera_info_for(color) if color else None)
    if info not in by_name:  # not beside the image: the colour camera's, else the only one
        infos = [
            t.topic
            for t in topics
            if t.schema in CALIBRATION_SCHEMAS and "depth" not in t.topic.lower()
        ]
        info = infos[0] if len(infos) == 1 else None
    odom = config.odom_topic or next(
        (t.topic for t in topics if t.schema in ODOMETRY_SCHEMAS), None
    )
    if odom is None and "/tf" in by_name:  # no odometry topic: the odom -> base transform
        odom = "/tf"
    static = (
        "/tf_static"
        if "/tf_static" in by_name
        else next((t.topic for t in topics if t.schema in TRANSFORM_SCHEMAS), None)
    )
    if depth is not None and depth == color:
        raise LogError(f"{path}: the depth topic {depth} is the colour topic; pass --depth-topic")
    return TopicChoice(color, depth, info, odom, static)


@dataclass
class Extraction:
    """What a log gave.

    Attributes:
        observations: every marker observation, in time order.
        odometry: ``T_odom_base`` samples.
        camera, mount: the intrinsics and mount used.
        topics: the topics read.
        frames: colour frames read; frames_with_depth: of them, paired with depth.
        skipped: reason -> frames skipped for it.
        notes: what was assumed.
        warnings: damaged stretches skipped (undecodable messages, per file and topic).
        true_markers: ground truth ``T_map_marker`` when the log carries it (simulated logs).
        true_poses: (N, 4) rows (t_ns, x, y, yaw) of the true base pose in ``map``, if carried.
        undecodable_frames: colour frames skipped because their image does not decode.
        unusable_depth: depth images skipped (undecodable, empty, or not the colour's size).
        ids_left_out: detections dropped by the allowed ids, by marker id.
    """

    observations: list[Observation]
    odometry: list[OdometrySample]
    camera: Camera | None
    mount: CameraMount
    topics: TopicChoice
    frames: int = 0
    frames_with_depth: int = 0
    skipped: Counter[str] = field(default_factory=Counter)
    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    true_markers: dict[int, gtsam.Pose2] = field(default_factory=dict)
    true_poses: NDArray[np.float64] = field(default_factory=lambda: np.empty((0, 4)))
    undecodable_frames: int = 0
    unusable_depth: int = 0
    ids_left_out: Counter[int] = field(default_factory=Counter)


class _Pairing:
    """Colour frames wait here for the depth image with the nearest stamp."""

    def __init__(self, tolerance_ns: int) -> None:
        self.tolerance = tolerance_ns
        self.colour: deque[tuple[int, Message]] = deque()
        self.depth: deque[tuple[int, NDArray]] = deque(maxlen=16)

    def matched_depth(self, t_ns: int) -> NDArray | None:
        best = min(self.depth, key=lambda d: abs(d[0] - t_ns), default=None)
        return best[1] if best is not None and abs(best[0] - t_ns) <= self.tolerance else None

    def ready(self, latest_ns: int, flush: bool = False) -> list[_Job]:
        """Colour frames that have their depth, or can no longer get it."""
        out = []
        while self.colour:
            t_ns, image = self.colour[0]
            depth = self.matched_depth(t_ns)
            if depth is None and not flush and latest_ns - t_ns <= 3 * self.tolerance:
                break
            self.colour.popleft()
            out.append((t_ns, image, depth))
        return out


_Job = tuple[int, Message, "NDArray | None"]  # (stamp, colour message, paired depth)
_DETECTORS: dict[tuple[str, tuple[int, ...] | None], Detector] = {}


def _detector(config: FrontendConfig) -> Detector:
    """One detector per process and configuration (building one costs more than a frame)."""
    key = (config.dictionary, config.allowed_ids)
    if key not in _DETECTORS:
        _DETECTORS[key] = Detector(config.dictionary, allowed_ids=config.allowed_ids)
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


def _once_topics(choice: TopicChoice, counts: dict[str, int]) -> list[str]:
    """Topics published once at the start (static transforms, true marker poses)."""
    return [t for t in (choice.tf_static, TRUE_MARKERS) if t and t in counts]


def _extract_span(
    path: Path,
    config: FrontendConfig,
    choice: TopicChoice,
    counts: dict[str, int],
    span: _Span,
    progress: Callable[[int, int], None] | None = None,
) -> Extraction:
    """One process's work: observations, odometry and ground truth of one stretch of the log."""
    result = Extraction([], [], config.camera, config.mount or config.default_mount, choice)
    failures = DecodeFailures()
    static: list[Any] = []
    for message in messages(path, _once_topics(choice, counts), failures):
        if message.topic == choice.tf_static:
            static += transforms_of(message.decoded)
        else:
            for transform in message.decoded.transforms:
                if transform.child_frame_id.startswith("aruco_"):
                    q, t = transform.transform.rotation, transform.transform.translation
                    result.true_markers[int(transform.child_frame_id[6:])] = gtsam.Pose2(
                        t.x, t.y, yaw_from_quaternion(q.x, q.y, q.z, q.w)
                    )
    streamed = [
        t
        for t in (choice.color, choice.depth, choice.camera_info, choice.odom, TRUE_POSE)
        if t and t in counts
    ]
    total = sum(counts[t] for t in streamed)
    image_frame: str | None = None
    mount_known = config.mount is not None
    pairing = _Pairing(config.pair_tolerance_ns)
    true_poses: list[tuple[int, float, float, float]] = []
    detector = _detector(config)
    left_out_before = Counter(detector.left_out)

    def process(ready: list[_Job]) -> None:
        nonlocal mount_known
        camera = result.camera
        if not ready or camera is None:  # drain() waits for the camera
            return
        if not mount_known:
            mount_known = True
            if static and image_frame:
                try:
                    result.mount = mount_from_transforms(static, config.base_frame, image_frame)
                except LogError as error:
                    result.notes.append(f"{error}; assuming the configured camera mount")
            else:
                result.notes.append(
                    f"no /tf_static: assuming the configured camera mount ({result.mount})"
                )
        for t_ns, message, depth in ready:
            try:
                image = decode_image(message)
            except LogError as error:  # one bad frame costs that frame
                result.undecodable_frames += 1
                result.skipped[f"colour image does not decode ({error})"] += 1
                continue
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
            result.observations += observe_detections(
                detector.detect(image),
                camera,
                config.marker_length_m,
                depth=depth,
                method=config.method,
                mount=result.mount,
                t_ns=t_ns,
                corner_sigma_px=config.corner_sigma_px,
                depth_model=config.depth_model,
                marker_lengths_m=config.marker_lengths_m,
            )

    def drain(latest_ns: int, flush: bool = False) -> None:
        # Frames wait for the camera info (it may come a message later), but not forever.
        if result.camera is None:
            while len(pairing.colour) > MAX_WAITING_FRAMES or (flush and pairing.colour):
                pairing.colour.popleft()
                result.skipped["no camera info before it"] += 1
            return
        process(pairing.ready(latest_ns, flush))

    # Read a margin either side so frames at the span's edges still find their depth.
    margin = 3 * config.pair_tolerance_ns
    start = None if span.start_ns is None else span.start_ns - margin
    end = None if span.end_ns is None else span.end_ns + margin
    for done, message in enumerate(messages(path, streamed, failures, start, end), start=1):
        if progress is not None and done % 50 == 0:
            progress(done, total)
        topic, decoded = message.topic, message.decoded
        inside = span.holds(message.log_time_ns)
        if topic == choice.color and inside:
            result.frames += 1
            image_frame = image_frame or frame_id(decoded)
            pairing.colour.append((stamp_ns(decoded), message))
            drain(stamp_ns(decoded))
        elif topic == choice.depth:
            try:
                pairing.depth.append((stamp_ns(decoded), decode_depth(message)))
            except LogError as error:  # the frame waiting for it goes on without depth
                result.unusable_depth += 1
                failures.add(path, topic, str(error))
            drain(stamp_ns(decoded))
        elif topic == choice.camera_info and result.camera is None:
            try:
                result.camera = config.camera or Camera.from_camera_info(decoded)
            except ValueError as error:  # a later message may be whole
                failures.add(path, topic, str(error))
                continue
            drain(stamp_ns(decoded))
        elif topic == choice.odom and inside:
            if message.schema.endswith("TFMessage"):
                result.odometry += odometry_from_tf(decoded, config.base_frame)
            else:
                result.odometry.append(odometry_sample(message))
        elif topic == TRUE_POSE and inside:
            q, p = decoded.pose.orientation, decoded.pose.position
            true_poses.append(
                (stamp_ns(decoded), p.x, p.y, yaw_from_quaternion(q.x, q.y, q.z, q.w))
            )
    drain(0, flush=True)
    if progress is not None:
        progress(total, total)
    result.true_poses = np.array(true_poses, dtype=np.float64).reshape(-1, 4)
    result.warnings = failures.warnings()
    result.ids_left_out = detector.left_out - left_out_before
    return result


def _start_worker(parent_pid: int) -> None:
    """In each worker: one OpenCV thread (a worker is one core; more would only contend), and a
    watchdog that ends the worker when its parent dies (a killed run must not leave workers
    waiting forever for work)."""
    cv2.setNumThreads(1)

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watch, daemon=True).start()


def _extract_span_in_worker(
    arguments: tuple[Path, FrontendConfig, TopicChoice, dict[str, int], _Span],
) -> Extraction:
    return _extract_span(*arguments)


def available_cores() -> int:
    """The cores this process may run on."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return os.cpu_count() or 1


def _merge(parts: list[Extraction]) -> Extraction:
    """Spans' results joined in log order."""
    first = parts[0]
    merged = Extraction(
        [],
        [],
        next((p.camera for p in parts if p.camera), None),
        first.mount,
        first.topics,
        true_markers=first.true_markers,
    )
    for part in parts:
        merged.observations += part.observations
        merged.odometry += part.odometry
        merged.frames += part.frames
        merged.frames_with_depth += part.frames_with_depth
        merged.skipped.update(part.skipped)
        merged.notes += [n for n in part.notes if n not in merged.notes]
        merged.warnings += part.warnings
        merged.undecodable_frames += part.undecodable_frames
        merged.unusable_depth += part.unusable_depth
        merged.ids_left_out.update(part.ids_left_out)
    merged.true_poses = np.concatenate([p.true_poses for p in parts])
    return merged


def _check_usable(path: Path, choice: TopicChoice, result: Extraction) -> None:
    """Bad messages cost their frames; but a topic of which nothing could be used is an error.

    Raises:
        LogError: no colour frame decodes, or depth was chosen and none of it is usable.
    """
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


def _clean_odometry(
    samples: list[OdometrySample], topic: str | None, notes: list[str]
) -> list[OdometrySample]:
    """Odometry without non-finite samples and without stamps that repeat or go backwards (a
    clock reset, a replayed stretch), each dropped with a note: one bad sample must not
    poison the map."""
    kept: list[OdometrySample] = []
    non_finite = backwards = 0
    for sample in samples:
        if not all(math.isfinite(v) for v in (sample.x, sample.y, sample.yaw)):
            non_finite += 1
        elif kept and sample.t_ns <= kept[-1].t_ns:
            backwards += 1
        else:
            kept.append(sample)
    if non_finite:
        notes.append(f"dropped {non_finite} odometry sample(s) on {topic} with NaN or inf values")
    if backwards:
        notes.append(
            f"dropped {backwards} odometry sample(s) on {topic} whose stamps repeat or go backwards"
        )
    return kept


def extract(
    path: Path,
    config: FrontendConfig = FrontendConfig(),
    progress: Callable[[int, int], None] | None = None,
    workers: int = 1,
) -> Extraction:
    """Observations and odometry from a ROS 2 or Foxglove MCAP log (file or rosbag2 folder).

    Args:
        progress: called with (units done, units in all): messages, or stretches with workers.
        workers: processes (``spawn``ed: forking after OpenCV has run can deadlock). With more
            than one, the log is cut into stretches of time that the workers read and process
            whole, each from its own chunks; the results are joined in log order.

    Raises:
        LogError: the log cannot be read, has no camera, or is damaged beyond a message.
    """
    path = Path(path)
    topics = log_topics(path)
    choice = choose_topics(path, topics, config)
    if choice.color is None:
        raise LogError(
            f"{path}: no camera image topic (looked for {', '.join(COLOR_TOPICS)} "
            "and any image message)"
        )
    counts = {t.topic: t.count for t in topics}
    _detector(config)  # a bad dictionary or --ids fails here, before any worker starts
    notes = []
    if workers > available_cores():
        notes.append(f"--workers {workers} capped at the {available_cores()} cores available")
        workers = available_cores()
    if workers <= 1:
        result = _extract_span(path, config, choice, counts, _Span(), progress)
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
            for done, part in enumerate(pool.map(_extract_span_in_worker, jobs), start=1):
                parts.append(part)
                if progress is not None:
                    progress(done, len(spans))
        result = _merge(parts)
    result.notes = notes + result.notes
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
    _check_usable(path, choice, result)
    result.odometry = _clean_odometry(result.odometry, choice.odom, result.notes)
    if result.ids_left_out:
        ids = ", ".join(str(i) for i in sorted(result.ids_left_out))
        result.notes.append(
            f"{sum(result.ids_left_out.values())} detection(s) of marker(s) {ids} were left out "
            "by the allowed ids (--ids)"
        )
    return result
