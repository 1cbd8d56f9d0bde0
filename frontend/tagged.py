"""Logs of marker detections (no images): each detection topic with its camera and mount, the
odometry's attitude at each stamp, observations from the markers' full poses in the level frame.

Detection logs are small, so the whole log is read first and observed after, with all of its
odometry at hand. Each detection topic finds its intrinsics in a Kalibr ``cameras.yaml`` (its
``tagtopic``) or in the log's ``camera_info`` (by namespace, then by frame id), and its mount on
the odometry's body from ``/tf_static`` (any chain from the odometry's child frame, or the base
frame, to the detections' frame) or from TagSLAM's ``camera_poses.yaml`` and ``tagslam.yaml``.
The 2-D odometry these observations go with has the heading of the first camera's optical axis
projected on the floor, so that a body whose own x axis points up (an IMU, a camera) still has
a well-defined heading.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from markergraph.common.notes import Note
from markergraph.estimator.types import Observation, OdometrySample, OdometryTrack
from markergraph.frontend.camera import Camera
from markergraph.frontend.config import FrontendConfig
from markergraph.frontend.decode import frame_id, stamp_ns
from markergraph.frontend.detections import TagFamilies, detections_of
from markergraph.frontend.logs import DecodeFailures, Log, LogError
from markergraph.frontend.posed import (
    MAX_ATTITUDE_GAP_NS,
    LevelledCamera,
    LevelledFrame,
    MarkerDetections,
    drop_notes,
    observe_levelled_frame,
    tally_detections,
)
from markergraph.frontend.rig import (
    Pose3,
    RigCamera,
    TagslamConfig,
    read_camera_poses,
    read_kalibr_cameras,
    read_tagslam,
)
from markergraph.frontend.tf import (
    planar_pose,
    rot_z,
    rotation_of,
    transform_between,
    transforms_of,
)
from markergraph.frontend.topics import CALIBRATION_SCHEMAS, TopicChoice

__all__ = [
    "DetectionLog",
    "FoundCamera",
    "FoundMount",
    "Rig",
    "find_camera",
    "find_mount",
    "no_camera_text",
    "no_mount_text",
    "odometry_body_text",
    "read_detection_log",
]


@dataclass(frozen=True)
class Rig:
    """The rig files a detection log's cameras are found in, each read once."""

    config: FrontendConfig
    """The settings that name the files."""
    kalibr: list[RigCamera]
    """The Kalibr ``cameras.yaml``'s cameras (empty without one)."""
    camera_poses: dict[str, Pose3]
    """TagSLAM's ``camera_poses.yaml``: camera name -> its pose on the rig (empty without one)."""
    tagslam: TagslamConfig | None
    """What ``tagslam.yaml`` gives, if read."""

    @classmethod
    def read(cls, config: FrontendConfig, tagslam: bool = True) -> Rig:
        """The files ``config`` names (errors name the file before the log is read).

        Args:
            tagslam: read ``tagslam.yaml`` too (the mount's pose needs it, its chain not).

        Raises:
            SettingsError: a file that cannot be read.
        """
        return cls(
            config,
            read_kalibr_cameras(config.kalibr_cameras) if config.kalibr_cameras else [],
            read_camera_poses(config.camera_poses) if config.camera_poses else {},
            read_tagslam(config.tagslam) if tagslam and config.tagslam else None,
        )


@dataclass(frozen=True, slots=True)
class FoundCamera:
    """A detection topic's intrinsics and where they come from."""

    camera: Camera
    """The intrinsics."""
    source: str
    """The camera_info topic, or ``<cameras.yaml>: <camera name>``."""
    model_name: str
    """The name the front end reads the model by (the message's distortion model)."""
    kalibr_name: str | None = None
    """The Kalibr camera's name, when from a ``cameras.yaml``."""


@dataclass(frozen=True, slots=True)
class FoundMount:
    """A detection camera's mount on the odometry's body and where it comes from."""

    T_body_optical: Pose3
    """The optical frame (x right, y down, z forward) in the body's."""
    from_static: bool
    """From the static transforms (else from TagSLAM's camera poses)."""
    odometry_body: str = "given"
    """How the odometry's body stands on the rig: ``given`` (a static chain from it,
    tagslam.yaml's ``T_body_odom``, or the detections' own frame), ``convention`` (not given:
    a ROS body frame, x forward and z up, taken to hold the camera's optical frame as REP 103
    puts it) or ``assumed`` (not given: taken as the rig's frame)."""


def find_camera(
    topic: str, frame: str, rig: Rig, infos: dict[str, Any],
    rejected: Callable[[str, str], None] | None = None,
) -> FoundCamera | None:  # fmt: skip
    """A detection topic's intrinsics: from the Kalibr file (by ``tagtopic``), else the first
    camera_info message that gives a camera, by namespace, then by frame id.

    Args:
        infos: camera_info topic -> its first message.
        rejected: called with (camera_info topic, why) for each message that gives no camera.
    """
    for entry in rig.kalibr:
        if entry.tag_topic == topic:
            source = f"{rig.config.kalibr_cameras}: {entry.name}"
            return FoundCamera(entry.camera, source, entry.camera.model, entry.name)
    namespace = topic.rsplit("/", 1)[0]
    by_namespace = [t for t in infos if t.rsplit("/", 1)[0] == namespace]
    by_frame = [t for t, info in infos.items() if frame_id(info) == frame]
    for candidate in (*by_namespace, *by_frame):
        try:
            camera = Camera.from_camera_info(infos[candidate])
        except ValueError as error:
            if rejected is not None:
                rejected(candidate, str(error))
            continue
        name = str(getattr(infos[candidate], "distortion_model", "") or "none")
        return FoundCamera(camera, candidate, name)
    return None


def find_mount(
    static: list[Any], bases: tuple[str | None, ...], frame: str, camera: FoundCamera | None,
    rig: Rig,
) -> tuple[FoundMount | None, str]:  # fmt: skip
    """``T_body_optical`` of a camera: the static transforms' chain from the first of ``bases``
    they reach, else TagSLAM's camera poses (by the Kalibr camera's name).

    Returns:
        The mount (None: neither gives it), and why the static transforms did not ("" if they
        did or there are none).
    """
    why = ""
    if static:
        try:
            R, t = transform_between(static, bases, frame)
            return FoundMount(Pose3(R, t), from_static=True), ""
        except LogError as error:
            why = str(error)
    name = camera.kalibr_name if camera is not None else None
    if name is not None and name in rig.camera_poses:
        T_rig_camera = rig.camera_poses[name]
        T_rig_odom, how = rig.tagslam and rig.tagslam.T_rig_odom, "given"
        body = bases[0]
        if T_rig_odom is None and body and body != frame:
            # Nothing says where the odometry's body stands on the rig. A ROS body frame
            # (x forward, z up) beside a camera's optical frame (z forward, y down) is REP 103's
            # pair: the camera looks along the body's x, its image up the body's z.
            if _optical(frame) and not _optical(body):
                T_rig_odom = T_rig_camera.compose(Pose3(R_BODY_OPTICAL, np.zeros(3)).inverse())
                how = "convention"
            else:
                how = "assumed"
        T_rig_odom = T_rig_odom or Pose3.identity()
        mount = T_rig_odom.inverse().compose(T_rig_camera)
        return FoundMount(mount, False, how), why
    return None, why


R_BODY_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
"""REP 103's optical frame (x right, y down, z forward) in its body frame (x forward, y left,
z up): the columns are the optical axes."""


def _optical(frame: str) -> bool:
    """Whether a frame is named as an optical frame (``*_optical_frame``, ``*_optical``)."""
    return "optical" in frame.lower()


def odometry_body_text(topic: str, body: str, frame: str, how: str) -> str:
    """What was taken for the odometry's body on the rig when nothing gave it."""
    if how == "convention":
        return (
            f"{topic}: the odometry's body {body!r} is not placed on the rig (no /tf_static "
            f"chain to {frame!r}, no T_body_odom in a tagslam.yaml): taken as REP 103's body "
            f"frame of the optical frame {frame!r} (x forward along the camera's axis, z up "
            "along its image up, no offset); --tagslam or /tf_static gives it"
        )
    return (
        f"{topic}: the odometry's body {body!r} is not placed on the rig (no /tf_static chain "
        f"to {frame!r}, no T_body_odom in a tagslam.yaml): taken as the rig's own frame; its "
        "attitude, and the up it gives, hold only if the two coincide (--tagslam or /tf_static "
        "gives it)"
    )


def no_camera_text(topic: str) -> str:
    """Why a detection topic is left out: no intrinsics."""
    return (
        f"detections on {topic} left out: no camera intrinsics (no camera_info by "
        "namespace or frame id, and no --cameras file naming it as tagtopic)"
    )


def no_mount_text(topic: str, frame: str) -> str:
    """Why a detection topic is left out: no mount."""
    return (
        f"detections on {topic} left out: no mount for frame {frame!r} (not in "
        "/tf_static, and no --camera-poses file naming the camera)"
    )


@dataclass
class DetectionLog:
    """What a detection log gave, before it becomes an ``Extraction`` (filled as it is read)."""

    observations: list[Observation] = field(default_factory=list)
    """Observations from the markers' full poses, in the level frame."""
    odometry: OdometryTrack = field(default_factory=OdometryTrack)
    """2-D odometry, heading along the first camera's optical axis on the floor."""
    camera: Camera | None = None
    """The first detection topic's camera that has a mount."""
    frames: int = 0
    """Detection messages read."""
    skipped: Counter[str] = field(default_factory=Counter)
    """Reason -> detection messages not observed for it."""
    notes: list[Note] = field(default_factory=list)
    """What the reading noticed and did about it."""
    warnings: list[str] = field(default_factory=list)
    """Messages skipped as unreadable, one line per file and topic."""
    ids_left_out: Counter[int] = field(default_factory=Counter)
    """Marker id -> detections left out (not among the allowed ids)."""
    marker_detections: dict[int, MarkerDetections] = field(default_factory=dict)
    """Marker id -> how its detections fared (a verdict's evidence; Extraction lacks it)."""


@dataclass
class _Frame:
    topic: str
    t_ns: int
    frame_id: str
    detections: list[Any]


class _Reader:
    def __init__(self, log: Log, config: FrontendConfig, choice: TopicChoice) -> None:
        self.source, self.path, self.config, self.choice = log, log.path, config, choice
        self.schemas = {t.topic: t.schema for t in log.topics}
        self.log = DetectionLog()
        self.failures = DecodeFailures()
        self.frames: list[_Frame] = []
        self.infos: dict[str, Any] = {}  # camera_info topic -> its first message
        self.poses: list[tuple[int, NDArray[np.float64], NDArray[np.float64]]] = []
        self.body_frame: str | None = None
        self.static: list[Any] = []
        self.families = TagFamilies()
        self.rig = Rig.read(config)  # before the log is read: errors name the file
        self.tagslam = self.rig.tagslam

    def read(self) -> DetectionLog:
        infos = [t for t, schema in self.schemas.items() if schema in CALIBRATION_SCHEMAS]
        wanted = [*self.choice.detections, *infos]
        wanted += [t for t in (self.choice.odom, self.choice.tf_static) if t]
        for message in self.source.messages(wanted, self.failures):
            self._take(message)
        self.log.notes += self.families.check(self.path, self.config.dictionary)
        self.log.warnings = self.failures.warnings()
        views = self._views()
        self._observe(views)
        return self.log

    def _take(self, message: Any) -> None:
        decoded, topic = message.decoded, message.topic
        if topic in self.choice.detections:
            try:
                found = detections_of(decoded)
            except (ValueError, AttributeError, TypeError) as error:
                self.failures.add(self.path, topic, f"not a detection array ({error})")
                return
            self.families.take(topic, decoded, found)
            self.frames.append(_Frame(topic, stamp_ns(decoded), frame_id(decoded), found))
        elif topic == self.choice.tf_static:
            self.static += transforms_of(decoded)
        elif topic == self.choice.odom:
            if not hasattr(decoded, "pose"):
                return  # odometry from /tf has no attitude to level with
            pose = decoded.pose.pose if hasattr(decoded.pose, "pose") else decoded.pose
            R = rotation_of(pose.orientation)
            p = np.array([pose.position.x, pose.position.y, pose.position.z], dtype=np.float64)
            if R is None or not np.all(np.isfinite(p)):  # dropped with a note, as NaN
                self.poses.append((stamp_ns(decoded), p * np.nan, np.eye(3)))
                return
            self.body_frame = self.body_frame or getattr(decoded, "child_frame_id", None)
            self.poses.append((stamp_ns(decoded), p, R))
        elif topic not in self.infos:
            self.infos[topic] = decoded

    # --- cameras and mounts -------------------------------------------------------------------

    def _views(self) -> dict[str, tuple[Camera, Pose3]]:
        """Each detection topic's camera and mount; topics without either are left out."""
        views = {}
        left_out: list[Note] = []  # topics without a camera or a mount, said in the notes
        bases = (self.body_frame, self.config.base_frame)
        for topic in self.choice.detections:
            frame = next((f.frame_id for f in self.frames if f.topic == topic), "")
            camera = find_camera(topic, frame, self.rig, self.infos, self._rejected)
            mount, why = None, ""
            if camera is not None:
                mount, why = find_mount(self.static, bases, frame, camera, self.rig)
            if why:
                self.log.notes.append(
                    Note(
                        "camera.mount_from_settings",
                        f"{why}; looking for the camera's pose in the settings",
                        topic,
                    )
                )
            if camera is None:
                left_out.append(Note("detections.no_camera", no_camera_text(topic), topic))
            elif mount is None:
                text = no_mount_text(topic, frame)
                left_out.append(Note("detections.no_mount", text, topic))
            else:
                views[topic] = (camera.camera, mount.T_body_optical)
                if mount.odometry_body != "given" and self.body_frame:
                    text = odometry_body_text(topic, self.body_frame, frame, mount.odometry_body)
                    self.log.notes.append(Note("odometry.body_" + mount.odometry_body, text, topic))
        self.log.notes += left_out
        if not views:
            raise LogError(
                f"{self.path}: no detection topic has both its camera and its mount "
                f"({'; '.join(note.text for note in left_out)})"
            )
        self.log.camera = next(iter(views.values()))[0]
        return views

    def _rejected(self, topic: str, why: str) -> None:
        self.failures.add(self.path, topic, why)

    # --- observations -------------------------------------------------------------------------

    def _observe(self, views: dict[str, tuple[Camera, Pose3]]) -> None:
        # The corners are the recording's own detector's, not refined here: the corner bias of
        # small markers (:func:`~markergraph.frontend.observe.theta_shared_sigma`) is ours.
        model = replace(self.config.observation_model, refined_corners=False)
        if self.tagslam is not None:
            sizes = model.marker_sizes.under(self.tagslam.tag_sizes_m)
            model = replace(model, marker_sizes=sizes)
        forward = next(iter(views.values()))[1].R[:, 2]  # the heading's axis on the body
        stamps = np.array([t for t, _, _ in self.poses], dtype=np.int64)
        for t_ns, p, R_world_body in self.poses:
            self.log.odometry.append(OdometrySample(t_ns, *planar_pose(p, R_world_body, forward)))
        allowed = self.config.allowed_ids
        frames: list[LevelledFrame] = []
        detections_by_topic: Counter[str] = Counter()
        rewound_by_topic: Counter[str] = Counter()
        for frame in self.frames:
            self.log.frames += 1
            if frame.topic not in views:
                self.log.skipped[f"detections on {frame.topic} without a camera or mount"] += 1
                continue
            camera, mount = views[frame.topic]
            if not len(stamps):
                R_world_body = np.eye(3)  # no attitude: a level body
            else:
                i = int(np.argmin(np.abs(stamps - frame.t_ns)))
                if abs(int(stamps[i]) - frame.t_ns) > MAX_ATTITUDE_GAP_NS:
                    self.log.skipped["no odometry within 100 ms for its attitude"] += 1
                    continue
                R_world_body = self.poses[i][2]
            f = R_world_body @ forward
            R_level_body = rot_z(-math.atan2(f[1], f[0])) @ R_world_body
            view = LevelledCamera(camera, R_level_body @ mount.R, R_level_body @ mount.t)
            detections = frame.detections
            if allowed is not None:
                self.log.ids_left_out.update(
                    d.marker_id for d in detections if d.marker_id not in allowed
                )
                detections = [d for d in detections if d.marker_id in allowed]
            levelled = observe_levelled_frame(detections, view, model, frame.t_ns)
            self.log.observations += levelled.observations
            frames.append(levelled)
            detections_by_topic[frame.topic] += len(detections)
            rewound_by_topic[frame.topic] += len(levelled.rewound)
        self.log.marker_detections = tally_detections(frames)
        self.log.notes += drop_notes(self.log.marker_detections)
        for topic, rewound in rewound_by_topic.items():
            if rewound:
                text = (
                    f"{rewound:,} of {detections_by_topic[topic]:,} detections on {topic} had "
                    "their corners wound the other way round (the tag would face away from the "
                    "camera, its yaw 180 deg off): read in reverse"
                )
                self.log.notes.append(Note("detections.rewound", text, topic, rewound))


def read_detection_log(log: Log, config: FrontendConfig, choice: TopicChoice) -> DetectionLog:
    """Observations and 2-D odometry from a log of marker detections.

    Raises:
        LogError: no detection topic has both a camera and a mount.
        SettingsError: a Kalibr, TagSLAM camera-poses or tagslam file that cannot be read.
    """
    return _Reader(log, config, choice).read()
