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
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from markergraph.estimator.types import Observation, OdometrySample
from markergraph.frontend.camera import Camera
from markergraph.frontend.config import FrontendConfig
from markergraph.frontend.decode import frame_id, stamp_ns
from markergraph.frontend.detections import detections_of
from markergraph.frontend.posed import (
    MAX_ATTITUDE_GAP_NS,
    LevelledCamera,
    LevelledFrame,
    MarkerDetections,
    drop_notes,
    observe_levelled_frame,
    tally_detections,
)
from markergraph.frontend.rig import Pose3, read_camera_poses, read_kalibr_cameras, read_tagslam
from markergraph.frontend.sources import DecodeFailures, LogError, LogTopic, messages
from markergraph.frontend.tf import (
    planar_pose,
    rot_z,
    rotation_of,
    transform_between,
    transforms_of,
)
from markergraph.frontend.topics import CALIBRATION_SCHEMAS, TopicChoice

__all__ = ["DetectionLog", "read_detection_log"]


@dataclass
class DetectionLog:
    """What a detection log gave, before it becomes an ``Extraction``."""

    observations: list[Observation] = field(default_factory=list)
    odometry: list[OdometrySample] = field(default_factory=list)
    camera: Camera | None = None
    frames: int = 0
    skipped: Counter[str] = field(default_factory=Counter)
    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    ids_left_out: Counter[int] = field(default_factory=Counter)
    # marker id -> how its detections fared (a verdict's evidence; Extraction lacks the field)
    marker_detections: dict[int, MarkerDetections] = field(default_factory=dict)


@dataclass
class _Frame:
    topic: str
    t_ns: int
    frame_id: str
    detections: list[Any]


class _Reader:
    def __init__(
        self, path: Path, config: FrontendConfig, choice: TopicChoice, topics: list[LogTopic]
    ) -> None:
        self.path, self.config, self.choice = path, config, choice
        self.schemas = {t.topic: t.schema for t in topics}
        self.log = DetectionLog()
        self.failures = DecodeFailures()
        self.frames: list[_Frame] = []
        self.infos: dict[str, Any] = {}  # camera_info topic -> its first message
        self.poses: list[tuple[int, NDArray[np.float64], NDArray[np.float64]]] = []
        self.body_frame: str | None = None
        self.static: list[Any] = []
        # The rig files, read once (errors name the file before the log is read).
        self.kalibr = read_kalibr_cameras(config.kalibr_cameras) if config.kalibr_cameras else []
        self.camera_poses = read_camera_poses(config.camera_poses) if config.camera_poses else {}
        self.tagslam = read_tagslam(config.tagslam) if config.tagslam else None

    def read(self) -> DetectionLog:
        infos = [t for t, schema in self.schemas.items() if schema in CALIBRATION_SCHEMAS]
        wanted = [*self.choice.detections, *infos]
        wanted += [t for t in (self.choice.odom, self.choice.tf_static) if t]
        for message in messages(self.path, wanted, self.failures):
            self._take(message)
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

    def _camera_for(self, topic: str, frame: str) -> tuple[str | None, Camera | None]:
        """(Kalibr camera name, intrinsics) of a detection topic."""
        for entry in self.kalibr:
            if entry.tag_topic == topic:
                return entry.name, entry.camera
        namespace = topic.rsplit("/", 1)[0]
        by_namespace = [t for t in self.infos if t.rsplit("/", 1)[0] == namespace]
        by_frame = [t for t, info in self.infos.items() if frame_id(info) == frame]
        for candidate in (*by_namespace, *by_frame):
            try:
                return None, Camera.from_camera_info(self.infos[candidate])
            except ValueError as error:
                self.failures.add(self.path, candidate, str(error))
        return None, None

    def _mount_for(self, name: str | None, frame: str) -> Pose3 | None:
        """``T_body_optical`` of a camera: /tf_static, else TagSLAM's camera poses."""
        if self.static:
            try:
                R, t = transform_between(
                    self.static, (self.body_frame, self.config.base_frame), frame
                )
                return Pose3(R, t)
            except LogError as error:
                self.log.notes.append(f"{error}; looking for the camera's pose in the settings")
        if name is not None and name in self.camera_poses:
            T_rig_odom = (self.tagslam and self.tagslam.T_rig_odom) or Pose3.identity()
            return T_rig_odom.inverse().compose(self.camera_poses[name])
        return None

    def _views(self) -> dict[str, tuple[Camera, Pose3]]:
        """Each detection topic's camera and mount; topics without either are left out."""
        views = {}
        for topic in self.choice.detections:
            frame = next((f.frame_id for f in self.frames if f.topic == topic), "")
            name, camera = self._camera_for(topic, frame)
            if camera is None:
                self.log.notes.append(
                    f"detections on {topic} left out: no camera intrinsics (no camera_info by "
                    "namespace or frame id, and no --cameras file naming it as tagtopic)"
                )
                continue
            mount = self._mount_for(name, frame)
            if mount is None:
                self.log.notes.append(
                    f"detections on {topic} left out: no mount for frame {frame!r} (not in "
                    "/tf_static, and no --camera-poses file naming the camera)"
                )
                continue
            views[topic] = (camera, mount)
        if not views:
            raise LogError(
                f"{self.path}: no detection topic has both its camera and its mount "
                f"({'; '.join(self.log.notes[-len(self.choice.detections) :])})"
            )
        self.log.camera = next(iter(views.values()))[0]
        return views

    # --- observations -------------------------------------------------------------------------

    def _observe(self, views: dict[str, tuple[Camera, Pose3]]) -> None:
        model = self.config.observation_model
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
                self.log.notes.append(
                    f"{rewound:,} of {detections_by_topic[topic]:,} detections on {topic} had "
                    "their corners wound the other way round (the tag would face away from the "
                    "camera, its yaw 180 deg off): read in reverse"
                )


def read_detection_log(
    path: Path, config: FrontendConfig, choice: TopicChoice, topics: list[LogTopic]
) -> DetectionLog:
    """Observations and 2-D odometry from a log of marker detections.

    Raises:
        LogError: no detection topic has both a camera and a mount.
        SettingsError: a Kalibr, TagSLAM camera-poses or tagslam file that cannot be read.
    """
    return _Reader(Path(path), config, choice, topics).read()
