"""What a preflight reports of a log (:func:`~markergraph.frontend.preflight.preflight`): its
topics, its first images, the camera's intrinsics and mount, and the verdict."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from markergraph.frontend.camera import Camera
from markergraph.frontend.topics import TopicChoice

__all__ = ["DetectionTopic", "ImageStats", "Intrinsics", "Mount", "Preflight", "TopicStats"]


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
