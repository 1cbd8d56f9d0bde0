"""A log to observations and odometry: the topics chosen, the camera judged, the log read in one
process or in workers that each read a stretch of it (:mod:`~markergraph.frontend.spans`), then
cleaned (:mod:`~markergraph.frontend.cleaning`), its depth's scale measured
(:mod:`~markergraph.frontend.depth_scale`), and read again with the markers' size depth
measures where that clearly disagrees with the given one.
"""

from __future__ import annotations

import itertools
import math
from array import array
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from markergraph.common.notes import Note
from markergraph.common.pool import available_cores, choose_workers, process_pool
from markergraph.estimator.trajectory import Trajectory
from markergraph.frontend.camera import CameraMount
from markergraph.frontend.cleaning import clean_path, drop_frames_by_stamp
from markergraph.frontend.config import FrontendConfig
from markergraph.frontend.depth_scale import correct_depth_scale
from markergraph.frontend.dictionary_check import beyond_note
from markergraph.frontend.extraction import Extraction, Part, merge_parts
from markergraph.frontend.inputs import CameraJudgement, judge_camera_info
from markergraph.frontend.logs import DecodeFailures, Log, LogError, open_log
from markergraph.frontend.marker_size import SizeByDepth, marker_sizes_by_depth
from markergraph.frontend.odometry_kind import odometry_evidence
from markergraph.frontend.posed import (
    LEVEL_TOLERANCE_RAD,
    MarkerDetections,
    drop_notes,
    tally_detections,
)
from markergraph.frontend.sizes import MarkerSizes
from markergraph.frontend.spans import (
    Span,
    SpanReader,
    detector_for,
    one_opencv_thread,
    read_span,
)
from markergraph.frontend.tagged import DetectionLog, read_detection_log
from markergraph.frontend.topics import COLOR_TOPICS, TRUE_POSE, TopicChoice, choose_topics

__all__ = ["extract"]

SPANS_PER_WORKER = 4  # stretches of the log per worker: balances load, moves the progress bar


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
    log, given_m = open_log(Path(path)), config.marker_sizes.default_m
    result = _extract_once(log, config, progress, workers)
    size = marker_sizes_by_depth(
        result.size_ratios, config.marker_sizes.default_m, config.marker_sizes.by_id,
        config.depth_scale or 1.0,
    )  # fmt: skip
    notes = []
    if size is not None and size.use:
        notes = _size_notes(size, config)
        sizes = MarkerSizes(size.size_m, config.marker_sizes.by_id).with_sizes(size.sizes_m)
        config = replace(config, marker_sizes=sizes)
        result = _extract_once(log, config, progress, workers)
    elif size is None and result.observations:
        notes.append(_given_size_note(result, config))
    result.notes += notes
    result.marker_sizes_used = config.marker_sizes
    if size is not None:
        result.marker_size_m_by_depth = given_m * size.ratio
        result.marker_size_ratio_by_depth = size.ratio
        result.marker_sizes_m_by_depth = dict(size.sizes_m)
    return result


def _given_size_note(result: Extraction, config: FrontendConfig) -> Note:
    """That the map's scale rests on the given marker size, depth being too scarce to measure
    it (its figure: the markers seen with depth, None without depth)."""
    topic = result.topics.depth
    text = (
        f"the map's scale rests on the given marker size ({config.marker_sizes.default_m:g} m; "
        "--marker-size sets it): "
        + (
            f"too few markers seen with depth on {topic} ({len(result.size_ratios)}) to measure it"
            if topic
            else "no depth to measure it"
        )
    )
    figure = len(result.size_ratios) if topic else None
    return Note("marker_size.given", text, topic, figure)


def _size_notes(size: SizeByDepth, config: FrontendConfig) -> list[Note]:
    """What depth measured of the markers' size, and what is used (each note's figure: the
    size used [m])."""
    notes = []
    given_m = config.marker_sizes.default_m
    if size.size_m != given_m:
        short = 100 * (1 - 1 / size.ratio)
        text = (
            f"markers measure {size.size_m:.3f} m by depth (the given {given_m:g}"
            f" m would put every range {abs(short):.0f} % {'short' if short > 0 else 'long'}; "
            f"depth over PnP's range in {size.sightings} sightings, "
            f"{100 * size.ratio_sigma:.2f} % error): using {size.size_m:.3f} m. A depth camera "
            f"is seldom this far off, a marker size often is; if {given_m:g} m is right, "
            f"--depth-scale {size.ratio * (config.depth_scale or 1.0):.3f} (depth reads that "
            "much per true metre) keeps it"
        )
        notes.append(Note("marker_size.measured", text, figure=size.size_m))
    for marker_id, size_m in sorted(size.sizes_m.items()):
        given = config.marker_sizes.of(marker_id)
        text = (
            f"marker {marker_id} measures {size_m:.3f} m by depth, apart from the others "
            f"(given {given:g} m): using {size_m:.3f} m for it"
        )
        notes.append(Note("marker_size.apart", text, figure=size_m))
    return notes


def _extract_once(
    log: Log,
    config: FrontendConfig,
    progress: Callable[[int, int], None] | None,
    workers: int | None,
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
    path = log.path
    topics = log.topics
    choice = choose_topics(path, topics, config)
    if choice.color is None and not choice.detections:
        raise LogError(
            f"{path}: no camera image topic (looked for {', '.join(COLOR_TOPICS)} "
            "and any image message)"
        )
    counts = {t.topic: t.count for t in topics}
    detector_for(config)  # a bad dictionary or --ids fails here, before any worker starts
    notes = []
    workers, why = choose_workers(counts.get(choice.color or "", 0), workers)
    if why is not None:
        notes.append(why)
    judgement = None
    if not choice.detections and config.camera is None:
        judgement = _judged_camera(log, choice, counts)
        config = replace(config, camera=judgement.camera)
    if choice.detections:
        part = _from_detections(read_detection_log(log, config, choice), choice)
    elif workers <= 1:
        threads = available_cores()
        # The pool's threads keep the cores busy: OpenCV's own threads on top only contend.
        with _opencv_threads(1 if threads > 1 else cv2.getNumThreads()):
            part = SpanReader(log, config, choice, counts, threads).read(Span(), progress)
    else:
        part = _read_in_workers(log, config, choice, counts, workers, progress)
    result = part.extraction
    if choice.odom and counts.get(choice.odom) and result.odometry_evidence is None:
        # Workers, or a log of detections, did not judge it while reading.
        result.odometry_evidence = odometry_evidence(log, choice.odom)
    if judgement is not None:
        notes += _camera_judged(result, judgement, choice)
    result.notes = notes + result.notes
    _check_usable(path, choice, result)
    _clean(part, choice)
    correct_depth_scale(result, config.depth_scale, choice.depth)
    _tally(result, choice)
    note = beyond_note(config.dictionary, result.ids_beyond_dictionary, result.dictionary_checks)
    if note is not None:
        result.notes.append(note)
    return result


def _read_in_workers(
    log: Log,
    config: FrontendConfig,
    choice: TopicChoice,
    counts: dict[str, int],
    workers: int,
    progress: Callable[[int, int], None] | None,
) -> Part:
    """The log cut into :data:`SPANS_PER_WORKER` stretches of time a process, each read whole
    (:func:`read_span`), joined in log order. This process is one of the ``workers``: while the
    others start (a spawned process imports for 0.3-0.7 s) and take stretches from the front,
    it takes them from the back, each one none of them has begun."""
    first, last = log.time_range
    edges = np.linspace(first, last + 1, SPANS_PER_WORKER * workers + 1).astype(np.int64)
    spans = [Span(int(a), int(b)) for a, b in itertools.pairwise(edges)]
    threads = max(1, available_cores() // workers)
    jobs = [(log, config, choice, counts, span, threads) for span in spans]
    frames = counts.get(choice.color or "", 0)
    parts: dict[int, Part] = {}

    def done(index: int, part: Part) -> None:
        parts[index] = part
        if progress is not None:  # in frames, as one process counts them
            progress(len(parts) * frames // len(spans), frames)

    with process_pool(workers - 1, one_opencv_thread) as pool, _opencv_threads(1):
        futures = [pool.submit(read_span, job) for job in jobs]
        for index in reversed(range(len(jobs))):
            if not futures[index].cancel():
                break  # the pool has it, and every stretch before it
            done(index, read_span(jobs[index]))
        for index, future in enumerate(futures):
            if index not in parts:
                done(index, future.result())
    return merge_parts([parts[i] for i in range(len(jobs))])


@contextmanager
def _opencv_threads(count: int) -> Iterator[None]:
    """OpenCV's own threads set to ``count`` for a while: beside the workers, this process's
    share is one core."""
    before = cv2.getNumThreads()
    cv2.setNumThreads(count)
    try:
        yield
    finally:
        cv2.setNumThreads(before)


def _camera_judged(
    result: Extraction, judgement: CameraJudgement, choice: TopicChoice
) -> list[Note]:
    """The camera_info messages judged, counted into ``result``; a note if some were set
    aside."""
    result.camera_infos_judged = judgement.read
    result.camera_infos_set_aside = sum(judgement.set_aside.values())
    result.camera_info_reasons = judgement.set_aside
    note = judgement.note(choice.camera_info or "")
    return [] if note is None else [note]


def _clean(part: Part, choice: TopicChoice) -> None:
    """Frames and odometry samples whose stamps or values cannot be believed dropped
    (:mod:`~markergraph.frontend.cleaning`), with their notes."""
    result = part.extraction
    drop_frames_by_stamp(part, choice.color)
    odometry = clean_path(part.odometry, part.odometry_log_ns, choice.odom, "odometry", "odom")
    result.odometry = odometry.path
    result.notes += odometry.notes
    result.dropped_odometry_samples = odometry.dropped
    result.worst_odometry_stamp_offset_s = odometry.worst_stamp_offset_s
    truth = clean_path(part.true_poses, part.true_pose_log_ns, TRUE_POSE, "ground-truth", "map")
    result.true_path = truth.path
    result.notes += truth.notes


def _marker_detections(result: Extraction) -> dict[int, MarkerDetections]:
    """Each marker's detections over the levelled frames and the level ones, and their drops."""
    levelled = tally_detections(result.levelled)
    level, no_yaw = result.level_detections, result.level_no_yaw
    counts = {}
    for i in sorted(set(levelled) | set(level)):
        c = levelled.get(i, MarkerDetections(i, 0, 0, 0, 0, math.nan))
        counts[i] = replace(c, detections=c.detections + level[i], no_pose=c.no_pose + no_yaw[i])
    return counts


def _tally(result: Extraction, choice: TopicChoice) -> None:
    """The log's counts said once it is read: depth missed, detections dropped, frames
    levelled, ids left out."""
    if result.depth_misses:
        text = (
            f"{result.depth_misses} of {result.depth_tries} observations in frames with depth "
            f"found no valid depth on their marker in {choice.depth} (0, NaN, negative, beyond"
            " noise.depth_max_m, or 20 % from the marker's PnP distance): their range comes from"
            " the marker's pose (PnP)"
        )
        result.notes.append(Note("depth.no_valid_pixel", text, choice.depth, result.depth_misses))
    if result.levelled or result.level_detections:  # a log of detections tallied its own
        result.marker_detections = _marker_detections(result)
        result.notes += drop_notes(result.marker_detections)
        result.levelled = []
    if result.levelled_frames:
        text = (
            f"{result.levelled_frames} of {result.frames} frames were taken with the base tilted "
            f"or the camera rolled by more than {math.degrees(LEVEL_TOLERANCE_RAD):.1f} deg: "
            f"levelled with {choice.odom}'s attitude, their markers' range and theta from each "
            "marker's full pose (PnP), without depth"
        )
        result.notes.append(Note("frames.levelled", text, choice.odom, result.levelled_frames))
    if result.ids_left_out:
        ids = ", ".join(str(i) for i in sorted(result.ids_left_out))
        left_out = sum(result.ids_left_out.values())
        text = (
            f"{left_out} detection(s) of marker(s) {ids} were left out by the allowed ids (--ids)"
        )
        result.notes.append(Note("detections.ids_left_out", text, figure=left_out))


def _from_detections(log: DetectionLog, choice: TopicChoice) -> Part:
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
        notes=list(log.notes),
        warnings=log.warnings,
        mount_source="none: each detection topic's own mount places its views on the body",
        ids_left_out=log.ids_left_out,
        marker_detections=log.marker_detections,
    )
    # A detection log's odometry carries no log times: its stamps are judged by order alone.
    return Part(extraction, log.odometry, array("q", bytes(8 * len(log.odometry))))


def _judged_camera(log: Log, choice: TopicChoice, counts: dict[str, int]) -> CameraJudgement:
    """The camera model the log's camera_info messages agree on (:func:`judge_camera_info`).

    Raises:
        LogError: no camera info topic, or none of its messages gives a believable model.
    """
    path = log.path
    topic = choice.camera_info
    if topic is None:
        raise LogError(
            f"{path}: no camera intrinsics: no camera info topic found (pass --camera-info-topic)"
        )
    if not counts.get(topic):
        raise LogError(f"{path}: no camera intrinsics: no messages on {topic}")
    failures = DecodeFailures()
    judgement = judge_camera_info(log, topic, failures)
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
        LogError: no frame could be read, no camera intrinsics, no colour frame decodes, or
            depth was chosen and none of it is usable.
    """
    if not result.frames:  # every message on the topic unreadable: a damaged log
        topics = (choice.color,) if choice.color else choice.detections
        lost = [w for w in result.warnings if any(t in w for t in topics)]
        raise LogError(
            f"{path}: no frame on {', '.join(topics)} could be read"
            + (f" ({lost[0].removeprefix(f'{path}: ')})" if lost else "")
        )
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
