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
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, BinaryIO

from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import MessageIndex

from markergraph.frontend.bags import is_bag
from markergraph.frontend.camera import Camera
from markergraph.frontend.config import FrontendConfig
from markergraph.frontend.decode import decode_depth, decode_image, frame_id
from markergraph.frontend.detect import Detector
from markergraph.frontend.inputs import judge_camera_info
from markergraph.frontend.rig import read_kalibr_cameras
from markergraph.frontend.sources import (
    DecodeFailures,
    LogError,
    Message,
    log_files,
    log_topics,
    messages,
)
from markergraph.frontend.tf import (
    mount_from_transforms,
    odometry_from_tf,
    transform_between,
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
    "topic_times",
]

FIRST_MESSAGES = 5  # messages of a topic tried before it counts as undecodable
TF_MESSAGES = 200  # /tf messages searched for the odom -> base transform


@dataclass(frozen=True, slots=True)
class TopicStats:
    """One topic of a log.

    Attributes:
        topic: its name.
        schema: its message type.
        count: its number of messages.
        first_ns, last_ns: log times of its first and last message [ns]; None without messages.
    """

    topic: str
    schema: str
    count: int
    first_ns: int | None = None
    last_ns: int | None = None

    @property
    def rate_hz(self) -> float | None:
        """Messages per second over the topic's own span [Hz]; None under two messages."""
        if self.first_ns is None or self.last_ns is None or self.last_ns <= self.first_ns:
            return None
        return (self.count - 1) / ((self.last_ns - self.first_ns) * 1e-9)


@dataclass(frozen=True, slots=True)
class ImageStats:
    """The first decodable image of a topic.

    Attributes:
        topic: its topic.
        width, height: its size [px].
        encoding: ``Image``'s encoding (``rgb8``, ``16UC1``) or ``CompressedImage``'s format.
        frame_id: its header's frame.
    """

    topic: str
    width: int
    height: int
    encoding: str
    frame_id: str


@dataclass(frozen=True, slots=True)
class Intrinsics:
    """A camera's intrinsics and where they come from.

    Attributes:
        source: the camera info topic, or ``FILE: cam0`` for a Kalibr camera.
        camera: the intrinsics as the front end reads them.
        model_name: the distortion model as the source names it (``plumb_bob``, ``radtan``).
    """

    source: str
    camera: Camera
    model_name: str


@dataclass(frozen=True, slots=True)
class Mount:
    """Where the camera's mount comes from.

    Attributes:
        source: ``/tf_static`` (or the log's transform topic), a camera poses file, or
            ``settings`` (assumed: the log does not give it).
        frames: the chain of frames from the base to the camera's frame, base first; empty
            where the mount does not come from the log's transforms.
        pose: the camera's pose on the base it gives, in words (height, pitch...), or "".
    """

    source: str
    frames: tuple[str, ...] = ()
    pose: str = ""


@dataclass(frozen=True, slots=True)
class DetectionTopic:
    """A topic of marker detections (a log without images) and its camera.

    Attributes:
        topic: its topic.
        frame_id: the frame its first message is in.
        intrinsics: its camera's intrinsics; None when neither the log nor a Kalibr file has them.
        mount: its camera's mount on the odometry's body; None when nothing gives it.
    """

    topic: str
    frame_id: str
    intrinsics: Intrinsics | None
    mount: Mount | None


@dataclass(frozen=True)
class Preflight:
    """What a log holds and whether ``markergraph map`` can map it.

    Attributes:
        path: the log.
        start_ns, end_ns: log times of its first and last message [ns]; None when it has none.
        topics: every topic, by name.
        choice: the topics the front end would read.
        color, depth: the first decodable colour and depth images; None where there are none.
        intrinsics: the colour camera's intrinsics (logs of images).
        mount: the colour camera's mount (logs of images).
        odometry_frame: the odometry's child frame (the body it moves).
        detections: each detection topic with its camera (logs of detections).
        blockers: why it cannot be mapped, one reason each (empty: it can).
        warnings: what the map will do without (depth, the log's mount).
    """

    path: Path
    start_ns: int | None
    end_ns: int | None
    topics: tuple[TopicStats, ...]
    choice: TopicChoice
    color: ImageStats | None = None
    depth: ImageStats | None = None
    intrinsics: Intrinsics | None = None
    mount: Mount | None = None
    odometry_frame: str | None = None
    detections: tuple[DetectionTopic, ...] = ()
    blockers: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()

    @property
    def can_map(self) -> bool:
        """No blocker."""
        return not self.blockers

    @property
    def duration_s(self) -> float:
        """From the first message to the last [s]."""
        if self.start_ns is None or self.end_ns is None:
            return 0.0
        return (self.end_ns - self.start_ns) * 1e-9

    def rate_hz(self, topic: str | None) -> float | None:
        """A topic's rate [Hz] (None: no such topic, or under two messages)."""
        return next((t.rate_hz for t in self.topics if t.topic == topic), None)


# --- message times, from the indexes ------------------------------------------------------------


def topic_times(path: Path) -> dict[str, tuple[int, int]]:
    """The first and last log time of each topic that has messages [ns].

    An indexed MCAP file answers from its message indexes, a ROS 1 bag from its index records,
    without decompressing a message; other files are read message by message, undecoded.

    Raises:
        LogError: a log that cannot be read, naming the file.
    """
    path = Path(path)
    if is_bag(path):
        found = _bag_times(path)
    else:
        found = [span for file in log_files(path) for span in _mcap_times(file)]
    spans: dict[str, list[int]] = {}
    for topic, first, last in found:  # a topic may span several files
        spans.setdefault(topic, []).extend((first, last))
    return {topic: (min(times), max(times)) for topic, times in spans.items()}


def _mcap_times(file: Path) -> list[tuple[str, int, int]]:
    with open(file, "rb") as stream:
        return _mcap_stream_times(file, stream)


def _mcap_stream_times(file: Path, stream: BinaryIO) -> list[tuple[str, int, int]]:
    reader = make_reader(stream)
    try:
        summary = reader.get_summary()
    except (McapError, ValueError, EOFError, OSError) as error:
        raise LogError(f"{file}: not a complete MCAP file ({error})") from error
    spans: dict[str, list[int]] = {}
    indexed = bool(
        summary is not None
        and summary.chunk_indexes
        and all(c.message_index_offsets for c in summary.chunk_indexes)
    )
    if indexed:
        assert summary is not None  # for the type checker: ``indexed`` says so
        try:
            for chunk in summary.chunk_indexes:
                for channel_id, offset in chunk.message_index_offsets.items():
                    stream.seek(offset + 1 + 8)  # past the record's opcode and length
                    times = [t for t, _ in MessageIndex.read(ReadDataStream(stream)).records]
                    if times:
                        topic = summary.channels[channel_id].topic
                        spans.setdefault(topic, []).extend((min(times), max(times)))
        except (McapError, ValueError, EOFError, KeyError):  # a damaged index: read instead
            spans, indexed = {}, False
            stream.seek(0)
            reader = make_reader(stream)
    if not indexed:
        try:
            for _, channel, message in reader.iter_messages(log_time_order=False):
                spans.setdefault(channel.topic, []).append(message.log_time)
        except (McapError, ValueError, EOFError) as error:
            raise LogError(f"{file}: damaged ({type(error).__name__}: {error})") from error
    return [(topic, min(times), max(times)) for topic, times in spans.items()]


def _bag_times(path: Path) -> list[tuple[str, int, int]]:
    """Through ``rosbags``: a ROS 1 bag's index records, a SQLite bag's message stamps."""
    try:
        if path.is_file():
            from rosbags.rosbag1 import Reader as Ros1Reader

            reader: Any = Ros1Reader(path)
        else:
            from rosbags.rosbag2 import Reader as Ros2Reader

            reader = Ros2Reader(path)
        reader.open()
    except Exception as error:  # rosbags raises ReaderError and friends
        raise LogError(f"{path}: not a readable bag ({type(error).__name__}: {error})") from error
    spans: dict[str, list[int]] = {}
    try:
        indexes = getattr(reader, "indexes", None)  # ROS 1: connection id -> index records
        if isinstance(indexes, dict):
            for connection in reader.connections:
                times = [int(entry.time) for entry in indexes.get(connection.id, ())]
                if times:
                    spans.setdefault(connection.topic, []).extend((min(times), max(times)))
        else:
            for connection, t_ns, _ in reader.messages():
                spans.setdefault(connection.topic, []).append(int(t_ns))
    except Exception as error:  # a damaged bag: rosbags cannot go on past it
        raise LogError(f"{path}: damaged ({type(error).__name__}: {error})") from error
    finally:
        reader.close()
    return [(topic, min(times), max(times)) for topic, times in spans.items()]


# --- the checks ---------------------------------------------------------------------------------


@contextlib.contextmanager
def _reading(path: Path, topic: str) -> Iterator[Iterator[Message]]:
    """A topic's messages that decode (the others skipped), the log closed when the block ends
    however little of it was read."""
    stream = messages(path, [topic], DecodeFailures())
    try:
        yield stream
    finally:
        getattr(stream, "close", lambda: None)()  # a generator: closing it closes the file


def _first(path: Path, topic: str, n: int = FIRST_MESSAGES) -> list[Message]:
    """The first ``n`` messages of a topic that decode (those that do not are skipped)."""
    with _reading(path, topic) as stream:
        return list(itertools.islice(stream, n))


def _parent(transform: Any) -> str:
    """A ROS ``TransformStamped``'s or a Foxglove ``FrameTransform``'s parent frame."""
    if hasattr(transform, "transform"):
        return str(transform.header.frame_id)
    return str(transform.parent_frame_id)


def _chain(static: list[Any], bases: tuple[str | None, ...], frame: str) -> tuple[str, ...]:
    """The frames from the first of ``bases`` the static transforms join to ``frame``, base
    first: the chain :func:`transform_between` composes.

    Raises:
        LogError: as :func:`transform_between`: not joined, a loop, or a value that is not a
            transform.
    """
    errors = []
    for base in dict.fromkeys(b for b in bases if b):
        try:
            transform_between(static, base, frame)
        except LogError as error:
            errors.append(str(error))
            continue
        parents = {str(t.child_frame_id): _parent(t) for t in static}  # the last one wins
        frames = [frame]
        while frames[-1] != base:
            frames.append(parents[frames[-1]])
        return tuple(reversed(frames))
    raise LogError("; ".join(errors) or f"no base frame to join {frame} to")


def _intrinsics_of(path: Path, topic: str, blockers: list[str]) -> Intrinsics | None:
    """The intrinsics the front end will use: the model most of the topic's first camera_info
    messages agree on (:func:`judge_camera_info`), else a blocker saying why none is."""
    judgement = judge_camera_info(path, topic, DecodeFailures())
    if judgement.camera is None:
        reasons = "; ".join(judgement.set_aside) or f"no message on {topic} decodes"
        blockers.append(f"no camera intrinsics ({reasons} on {topic})")
        return None
    name = judgement.camera.model  # the name the front end reads it by
    for message in _first(path, topic):
        try:
            if Camera.from_camera_info(message.decoded) == judgement.camera:
                name = str(getattr(message.decoded, "distortion_model", "") or "") or "none"
                break
        except ValueError:
            continue
    return Intrinsics(topic, judgement.camera, name)


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


def _first_image(path: Path, topic: str, depth: bool) -> tuple[ImageStats | None, str]:
    """The first of a topic's first messages that decodes, or the first reason none did."""
    reasons = []
    for message in _first(path, topic):
        try:
            return _image(message, depth), ""
        except LogError as error:
            reasons.append(str(error))
    return None, reasons[0] if reasons else f"no message on {topic} decodes"


def _odometry(
    path: Path, choice: TopicChoice, config: FrontendConfig, stats: dict[str, TopicStats],
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
        if detections:  # a detection is levelled with the odometry's attitude: /tf has none
            blockers.append(
                f"no odometry (a log of detections needs a nav_msgs/Odometry topic; {topic} "
                "is not read for it)"
            )
            return None
        found = _first(path, topic, TF_MESSAGES)
        if any(odometry_from_tf(m.decoded, config.base_frame) for m in found):
            return config.base_frame
        blockers.append(
            f"no odometry ({topic} carries no odom -> {config.base_frame} transform in its first "
            f"{len(found)} messages: pass --base-frame or --odom-topic)"
        )
        return None
    found = _first(path, topic, 1)
    if not found:
        blockers.append(f"no odometry (no message on {topic} decodes)")
        return None
    child = getattr(found[0].decoded, "child_frame_id", None)
    return str(child) if child else None


def _static_transforms(path: Path, topic: str | None) -> list[Any]:
    """Every transform on the static transforms' topic (published once, so read whole)."""
    if topic is None:
        return []
    found: list[Any] = []
    with _reading(path, topic) as stream:
        for message in stream:
            found += transforms_of(message.decoded)
    return found


def _detection_topics(
    path: Path, choice: TopicChoice, config: FrontendConfig, stats: dict[str, TopicStats],
    static: list[Any], body_frame: str | None, blockers: list[str], warnings: list[str],
) -> tuple[DetectionTopic, ...]:  # fmt: skip
    """Each detection topic's camera and mount, found as :mod:`.tagged` finds them: intrinsics
    from a Kalibr file (by ``tagtopic``), else a camera info by namespace, then by frame id; the
    mount from a /tf_static chain, else from a camera poses file (by Kalibr camera name)."""
    from markergraph.frontend.rig import read_camera_poses

    kalibr = read_kalibr_cameras(config.kalibr_cameras) if config.kalibr_cameras else []
    poses = read_camera_poses(config.camera_poses) if config.camera_poses else {}
    infos = {
        t.topic: found[0].decoded
        for t in stats.values()
        if t.schema in CALIBRATION_SCHEMAS and t.count and (found := _first(path, t.topic, 1))
    }
    result = []
    for topic in choice.detections:
        first = _first(path, topic, 1)
        frame = frame_id(first[0].decoded) if first else ""
        entry = next((e for e in kalibr if e.tag_topic == topic), None)
        intrinsics = None
        if entry is not None:
            source = f"{config.kalibr_cameras}: {entry.name}"
            intrinsics = Intrinsics(source, entry.camera, entry.camera.model)
        else:
            namespace = topic.rsplit("/", 1)[0]
            candidates = [t for t in infos if t.rsplit("/", 1)[0] == namespace] + [
                t for t, info in infos.items() if frame_id(info) == frame
            ]
            for candidate in candidates:
                try:
                    camera = Camera.from_camera_info(infos[candidate])
                except ValueError:
                    continue
                name = str(getattr(infos[candidate], "distortion_model", "") or "none")
                intrinsics = Intrinsics(candidate, camera, name)
                break
        mount = None
        if static:
            with contextlib.suppress(LogError):
                mount = Mount(choice.tf_static or "/tf_static",
                              _chain(static, (body_frame, config.base_frame), frame))  # fmt: skip
        if mount is None and entry is not None and entry.name in poses:
            mount = Mount(f"{config.camera_poses}: {entry.name}")
        result.append(DetectionTopic(topic, frame, intrinsics, mount))
    if not any(d.intrinsics for d in result):
        blockers.append(
            "no camera intrinsics (no camera_info for the detection topics: pass --cameras, a "
            "Kalibr cameras.yaml)"
        )
    elif not any(d.intrinsics and d.mount for d in result):
        blockers.append(
            "no camera mount (no /tf_static chain to the detections' frames: pass "
            "--camera-poses, a TagSLAM camera_poses.yaml)"
        )
    else:  # mapped without the others: say which, and why
        for d in result:
            if d.intrinsics is None:
                warnings.append(
                    f"detections on {d.topic} left out: no camera intrinsics (no camera_info by "
                    "namespace or frame id, and no --cameras file naming it as tagtopic)"
                )
            elif d.mount is None:
                warnings.append(
                    f"detections on {d.topic} left out: no mount for frame {d.frame_id!r} (not "
                    "in /tf_static, and no --camera-poses file naming the camera)"
                )
    return tuple(result)


def preflight(path: Path, config: FrontendConfig = FrontendConfig()) -> Preflight:
    """What a log holds and whether it can be mapped, from its indexes and the first messages
    of the topics the front end would read.

    Blockers (each one fails ``markergraph map``): no camera (no image or detection topic, or
    no image on it decodes), no camera intrinsics, depth that does not decode or is not the
    colour image's size (not aligned), no odometry, and for logs of detections no camera
    mount. Warnings: no depth (ranges then come from the marker's size, PnP on its corners),
    depth in another frame than colour, no mount in the log (the configured one is assumed).

    Raises:
        LogError: the log cannot be read, or a topic set in ``config`` is not in it or of the
            wrong type.
        SettingsError: a bad dictionary, ids outside it, or a rig file that cannot be read.
    """
    path = Path(path)
    listed = log_topics(path)
    choice = choose_topics(path, listed, config)
    Detector(config.dictionary, allowed_ids=config.allowed_ids)  # as map would fail on them
    times = topic_times(path)
    topics = tuple(
        TopicStats(t.topic, t.schema, t.count, *times.get(t.topic, (None, None))) for t in listed
    )
    stats = {t.topic: t for t in topics}
    spans = list(times.values())
    start = min((s for s, _ in spans), default=None)
    end = max((e for _, e in spans), default=None)
    blockers: list[str] = []  # the camera's, then the odometry's
    warnings: list[str] = []
    no_odometry: list[str] = []
    detecting = bool(choice.detections)
    body_frame = _odometry(path, choice, config, stats, detecting, no_odometry)
    static = _static_transforms(path, choice.tf_static)
    report = Preflight(path, start, end, topics, choice, odometry_frame=body_frame)
    if detecting:
        found = _detection_topics(
            path, choice, config, stats, static, body_frame, blockers, warnings
        )
        return _with(report, blockers + no_odometry, warnings, detections=found)
    if choice.color is None:
        blockers.append("no camera (no image topic and no marker detection topic)")
        return _with(report, blockers + no_odometry, warnings)
    color, why = _first_image(path, choice.color, depth=False)
    if color is None:
        blockers.append(f"no camera ({why})")
    intrinsics = None
    if config.camera is not None:
        intrinsics = Intrinsics("settings", config.camera, config.camera.model)
    elif choice.camera_info is None:
        blockers.append(
            "no camera intrinsics (no camera info topic found: pass --camera-info-topic)"
        )
    else:
        intrinsics = _intrinsics_of(path, choice.camera_info, blockers)
    depth = None
    if choice.depth is None:
        warnings.append("no depth (ranges from marker size)")
    else:
        depth, why = _first_image(path, choice.depth, depth=True)
        if depth is None:
            blockers.append(
                f"no usable depth ({why}: pass --depth-topic with the aligned depth topic)"
            )
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
    mount = None
    assumed = config.default_mount.describe()
    if config.mount is not None:
        mount = Mount("settings")
    elif not static:
        warnings.append(f"no /tf_static: the configured camera mount is assumed ({assumed})")
    elif color is not None:  # the pipeline's bases: the odometry's body, then the base frame
        try:
            frames = _chain(static, (body_frame, config.base_frame), color.frame_id)
            pose = mount_from_transforms(static, frames[0], color.frame_id).describe()
            mount = Mount(choice.tf_static or "/tf_static", frames, pose)
        except LogError as error:
            warnings.append(f"{error}; the configured camera mount is assumed ({assumed})")
    blockers += no_odometry
    return _with(
        report, blockers, warnings, color=color, depth=depth, intrinsics=intrinsics, mount=mount
    )


def _with(report: Preflight, blockers: list[str], warnings: list[str], **found: Any) -> Preflight:
    return replace(report, blockers=tuple(blockers), warnings=tuple(warnings), **found)
