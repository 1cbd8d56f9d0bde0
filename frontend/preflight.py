"""A log's preflight: what it holds, what the front end would read from it, and whether it can
be mapped; read from the log's indexes and the first messages of the topics chosen, with no
marker detected.

Each check follows the front end's own rule (topics from :func:`choose_topics`, intrinsics as
:mod:`~markergraph.frontend.pipeline` and :mod:`~markergraph.frontend.tagged` find them, the
camera's mount through the chain :func:`transform_between` finds), so that a log that passes
here fails in ``markergraph map`` only for what a preflight cannot see: no marker in any frame,
or every odometry sample unusable.
"""

from __future__ import annotations

import contextlib
import itertools
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

from markergraph.frontend.camera import Camera
from markergraph.frontend.config import FrontendConfig
from markergraph.frontend.decode import decode_depth, decode_image, frame_id
from markergraph.frontend.detect import Detector
from markergraph.frontend.detections import TagFamilies, detections_of
from markergraph.frontend.inputs import judge_camera_info
from markergraph.frontend.logs import DecodeFailures, Log, LogError, Message, open_log
from markergraph.frontend.preflight_report import (
    DetectionTopic,
    ImageStats,
    Intrinsics,
    Mount,
    Preflight,
    TopicStats,
)
from markergraph.frontend.tagged import (
    Rig,
    find_camera,
    find_mount,
    no_camera_text,
)
from markergraph.frontend.tf import (
    chain_between,
    mount_from_transforms,
    odometry_from_tf,
    transforms_of,
)
from markergraph.frontend.topics import CALIBRATION_SCHEMAS, TF_SCHEMAS, TopicChoice, choose_topics

__all__ = [
    "DetectionTopic",
    "ImageStats",
    "Intrinsics",
    "Mount",
    "Preflight",
    "TopicStats",
    "preflight",
]

FIRST_MESSAGES = 5  # messages of a topic tried before it counts as undecodable
TF_MESSAGES = 200  # /tf messages searched for the odom -> base transform, detections for a tag


# --- reading the first messages -----------------------------------------------------------------


@contextlib.contextmanager
def _reading(log: Log, topic: str) -> Iterator[Iterator[Message]]:
    """A topic's messages that decode (the others skipped), the log closed when the block ends
    however little of it was read."""
    stream = log.messages([topic], DecodeFailures())
    try:
        yield stream
    finally:
        getattr(stream, "close", lambda: None)()  # a generator: closing it closes the file


def _first(log: Log, topic: str, n: int = FIRST_MESSAGES) -> list[Message]:
    """The first ``n`` messages of a topic that decode (those that do not are skipped)."""
    with _reading(log, topic) as stream:
        return list(itertools.islice(stream, n))


def _static_transforms(log: Log, topic: str | None) -> list[Any]:
    """Every transform on the static transforms' topic (published once, so read whole)."""
    if topic is None:
        return []
    found: list[Any] = []
    with _reading(log, topic) as stream:
        for message in stream:
            found += transforms_of(message.decoded)
    return found


def _image(message: Message, depth: bool) -> ImageStats:
    """An image's size and encoding, once it decodes.

    Raises:
        LogError: it does not decode.
    """
    pixels = decode_depth(message) if depth else decode_image(message)
    msg = message.decoded
    encoding = getattr(msg, "encoding", None) or getattr(msg, "format", None) or "?"
    return ImageStats(
        message.topic, int(pixels.shape[1]), int(pixels.shape[0]), str(encoding), frame_id(msg)
    )


def _first_image(log: Log, topic: str, depth: bool) -> tuple[ImageStats | None, str]:
    """The first of a topic's first messages that decodes, or the first reason none did."""
    reasons = []
    for message in _first(log, topic):
        try:
            return _image(message, depth), ""
        except LogError as error:
            reasons.append(str(error))
    return None, reasons[0] if reasons else f"no message on {topic} decodes"


# --- the odometry -------------------------------------------------------------------------------


def _odometry(
    log: Log, choice: TopicChoice, config: FrontendConfig, stats: dict[str, TopicStats],
    detections: bool, blockers: list[str],
) -> str | None:  # fmt: skip
    """The odometry's child frame, or a blocker saying why there is no odometry."""
    topic = choice.odom
    if topic is None:
        blockers.append(
            "no odometry (no nav_msgs/Odometry topic, and no odom -> base transforms on /tf)"
        )
        return None
    if not stats[topic].count:
        blockers.append(f"no odometry (no messages on {topic})")
        return None
    if stats[topic].schema.endswith(TF_SCHEMAS):
        return _odometry_on_tf(log, topic, config, detections, blockers)
    found = _first(log, topic, 1)
    if not found:
        blockers.append(f"no odometry (no message on {topic} decodes)")
        return None
    child = getattr(found[0].decoded, "child_frame_id", None)
    return str(child) if child else None


def _odometry_on_tf(
    log: Log, topic: str, config: FrontendConfig, detections: bool, blockers: list[str]
) -> str | None:
    """The base frame when /tf carries odom -> base transforms, or a blocker saying why not."""
    if detections:  # a detection is levelled with the odometry's attitude: /tf has none
        blockers.append(
            f"no odometry (a log of detections needs a nav_msgs/Odometry topic; {topic} "
            "is not read for it)"
        )
        return None
    found = _first(log, topic, TF_MESSAGES)
    if any(odometry_from_tf(m.decoded, config.base_frame) for m in found):
        return config.base_frame
    blockers.append(
        f"no odometry ({topic} carries no odom -> {config.base_frame} transform in its first "
        f"{len(found)} messages: pass --base-frame or --odom-topic)"
    )
    return None


# --- logs of detections -------------------------------------------------------------------------


def _detection_topics(
    log: Log, choice: TopicChoice, config: FrontendConfig, stats: dict[str, TopicStats],
    static: list[Any], body_frame: str | None, warnings: list[str],
) -> tuple[DetectionTopic, ...]:  # fmt: skip
    """Each detection topic's camera and mount, found as :mod:`.tagged` finds them
    (:func:`~.tagged.find_camera`, :func:`~.tagged.find_mount`); its tags' family held to the
    dictionary (a note of ids beyond it goes to ``warnings``)."""
    rig = Rig.read(config, tagslam=False)  # the mount's chain is shown, not its pose
    infos = {
        t.topic: found[0].decoded
        for t in stats.values()
        if t.schema in CALIBRATION_SCHEMAS and t.count and (found := _first(log, t.topic, 1))
    }
    bases = (body_frame, config.base_frame)
    result = []
    families = TagFamilies()
    for topic in choice.detections:
        first = _first_with_family(log, topic, families)
        frame = frame_id(first.decoded) if first else ""
        camera = find_camera(topic, frame, rig, infos)
        intrinsics = None
        if camera is not None:
            intrinsics = Intrinsics(camera.source, camera.camera, camera.model_name)
        placed, _ = find_mount(static, bases, frame, camera, rig)
        mount = None
        if placed is not None and placed.from_static:
            frames = chain_between(static, bases, frame)
            mount = Mount(choice.tf_static or "/tf_static", frames)
        elif placed is not None and camera is not None:
            mount = Mount(f"{config.camera_poses}: {camera.kalibr_name}")
        result.append(DetectionTopic(topic, frame, intrinsics, mount))
    warnings += [note.text for note in families.check(log.path, config.dictionary)]
    return tuple(result)


def _first_with_family(log: Log, topic: str, families: TagFamilies) -> Message | None:
    """A detection topic's first message that decodes, in the one reading that also takes the
    tag family of the first of its first :data:`TF_MESSAGES` messages to carry a tag (a camera
    may see none for a while)."""
    first = None
    with _reading(log, topic) as stream:
        for message in itertools.islice(stream, TF_MESSAGES):
            first = first or message
            with contextlib.suppress(ValueError, AttributeError, TypeError):  # map says why
                families.take(topic, message.decoded, detections_of(message.decoded))
            if topic in families.first:
                break
    return first


def _judge_detections(
    found: tuple[DetectionTopic, ...], blockers: list[str], warnings: list[str]
) -> None:
    """A blocker when no detection topic has both a camera and a mount, else a warning for
    each topic left out."""
    if not any(d.intrinsics for d in found):
        blockers.append(
            "no camera intrinsics (no camera_info for the detection topics: pass --cameras, a "
            "Kalibr cameras.yaml)"
        )
    elif not any(d.intrinsics and d.mount for d in found):
        blockers.append(
            "no camera mount (no /tf_static chain to the detections' frames: pass "
            "--camera-poses, a TagSLAM camera_poses.yaml)"
        )
    else:  # mapped without the others: say which, and why
        for d in found:
            if d.intrinsics is None:
                warnings.append(no_camera_text(d.topic))
            elif d.mount is None:
                warnings.append(
                    f"{d.topic} has no mount for frame {d.frame_id!r} (not in /tf_static, and no "
                    "--camera-poses file naming the camera): in 3-D its mount is estimated from "
                    "the tags it shares with the others, a 2-D map leaves it out"
                )


# --- logs of images -----------------------------------------------------------------------------


def _intrinsics(
    log: Log, choice: TopicChoice, config: FrontendConfig, blockers: list[str]
) -> Intrinsics | None:
    """The intrinsics the front end will use: the settings', else the model most of the
    camera info topic's first messages agree on (:func:`judge_camera_info`), else a blocker
    saying why none is."""
    if config.camera is not None:
        return Intrinsics("settings", config.camera, config.camera.model)
    topic = choice.camera_info
    if topic is None:
        blockers.append(
            "no camera intrinsics (no camera info topic found: pass --camera-info-topic)"
        )
        return None
    judgement = judge_camera_info(log, topic, DecodeFailures())
    if judgement.camera is None:
        reasons = "; ".join(judgement.set_aside) or f"no message on {topic} decodes"
        blockers.append(f"no camera intrinsics ({reasons} on {topic})")
        return None
    name = judgement.camera.model  # the name the front end reads it by
    for message in _first(log, topic):
        try:
            if Camera.from_camera_info(message.decoded) == judgement.camera:
                name = str(getattr(message.decoded, "distortion_model", "") or "") or "none"
                break
        except ValueError:
            continue
    return Intrinsics(topic, judgement.camera, name)


def _depth(
    log: Log, choice: TopicChoice, color: ImageStats | None, blockers: list[str],
    warnings: list[str],
) -> ImageStats | None:  # fmt: skip
    """The first depth image, with a blocker when it does not decode or is not the colour
    image's size, and a warning when there is none or it is in another frame."""
    if choice.depth is None:
        warnings.append("no depth (ranges from marker size)")
        return None
    depth, why = _first_image(log, choice.depth, depth=True)
    if depth is None:
        blockers.append(f"no usable depth ({why}: pass --depth-topic with the aligned depth topic)")
    elif color is not None and (depth.width, depth.height) != (color.width, color.height):
        blockers.append(
            f"depth not aligned to colour ({choice.depth} is {depth.width}x{depth.height}, "
            f"{choice.color} {color.width}x{color.height}: pass --depth-topic with the "
            "aligned depth topic)"
        )
    elif color is not None and depth.frame_id != color.frame_id:
        warnings.append(
            f"depth is in frame {depth.frame_id!r}, colour in {color.frame_id!r}: the same "
            "size, but is it aligned to colour?"
        )
    return depth


def _mount(
    choice: TopicChoice, config: FrontendConfig, static: list[Any], body_frame: str | None,
    color: ImageStats | None, warnings: list[str],
) -> Mount | None:  # fmt: skip
    """The colour camera's mount: the settings', else the static transforms' chain from the
    pipeline's bases (the odometry's body, then the base frame), else a warning that the
    configured mount is assumed."""
    assumed = config.default_mount.describe()
    if config.mount is not None:
        return Mount("settings")
    if not static:
        warnings.append(f"no /tf_static: the configured camera mount is assumed ({assumed})")
        return None
    if color is None:
        return None
    try:
        frames = chain_between(static, (body_frame, config.base_frame), color.frame_id)
        pose = mount_from_transforms(static, frames[0], color.frame_id).describe()
        return Mount(choice.tf_static or "/tf_static", frames, pose)
    except LogError as error:
        warnings.append(f"{error}; the configured camera mount is assumed ({assumed})")
        return None


# --- the preflight ------------------------------------------------------------------------------


def preflight(path: Path, config: FrontendConfig = FrontendConfig()) -> Preflight:
    """What a log holds and whether it can be mapped, from its indexes and the first messages
    of the topics the front end would read.

    Blockers (each one fails ``markergraph map``): no camera (no image or detection topic, or
    no image on it decodes), no camera intrinsics, depth that does not decode or is not the
    colour image's size (not aligned), an odometry topic of which nothing is usable, and for
    logs of detections no camera mount. Warnings: no odometry topic, or none usable in a log of
    detections (``map`` then maps the tags in 3-D alone), no depth (ranges then come from the
    marker's size, PnP on its corners), depth in another frame than colour, no mount in the
    log (the configured one is assumed).

    Raises:
        LogError: the log cannot be read, or a topic set in ``config`` is not in it or of the
            wrong type.
        SettingsError: a bad dictionary, ids outside it, detections of another family than
            the dictionary's, or a rig file that cannot be read.
    """
    path = Path(path)
    log = open_log(path)
    choice = choose_topics(path, log.topics, config)
    Detector(config.dictionary, allowed_ids=config.allowed_ids)  # as map would fail on them
    report = _contents(log, choice)
    stats = {t.topic: t for t in report.topics}
    blockers: list[str] = []  # the camera's, then the odometry's
    warnings: list[str] = list(log.notes)
    no_odometry: list[str] = []
    detecting = bool(choice.detections)
    body_frame = _odometry(log, choice, config, stats, detecting, no_odometry)
    if detecting or choice.odom is None:  # map maps these in 3-D, from the tags alone
        warnings += [f"{why}: mapped in 3-D from the tags alone (--dimensions 2 needs odometry)"
                     for why in no_odometry]  # fmt: skip
        no_odometry = []
    static = _static_transforms(log, choice.tf_static)
    report = replace(report, odometry_frame=body_frame)
    if detecting:
        found = _detection_topics(log, choice, config, stats, static, body_frame, warnings)
        _judge_detections(found, blockers, warnings)
        return _with(report, blockers + no_odometry, warnings, detections=found)
    if choice.color is None:
        blockers.append("no camera (no image topic and no marker detection topic)")
        return _with(report, blockers + no_odometry, warnings)
    color, why = _first_image(log, choice.color, depth=False)
    if color is None:
        blockers.append(f"no camera ({why})")
    intrinsics = _intrinsics(log, choice, config, blockers)
    depth = _depth(log, choice, color, blockers, warnings)
    mount = _mount(choice, config, static, body_frame, color, warnings)
    return _with(
        report, blockers + no_odometry, warnings, color=color, depth=depth,
        intrinsics=intrinsics, mount=mount,
    )  # fmt: skip


def _contents(log: Log, choice: TopicChoice) -> Preflight:
    """What the log holds, from its indexes: its topics with their times, and its span."""
    times = log.topic_times
    topics = tuple(
        TopicStats(t.topic, t.schema, t.count, *times.get(t.topic, (None, None)))
        for t in log.topics
    )
    spans = list(times.values())
    start = min((s for s, _ in spans), default=None)
    end = max((e for _, e in spans), default=None)
    return Preflight(log.path, start, end, topics, choice)


def _with(report: Preflight, blockers: list[str], warnings: list[str], **found: Any) -> Preflight:
    return replace(report, blockers=tuple(blockers), warnings=tuple(warnings), **found)
