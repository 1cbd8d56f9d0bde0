"""A log of tag detections (or of images, detected here) as the 3-D estimator's scene: each
detection topic (or the image topic) with its camera
(intrinsics as :mod:`.tagged` finds them) and its mount where given (else estimated), the
detections grouped into rig frames by stamp, each tag's corners undistorted through its camera's
lens model to rays with a PnP seed, and the odometry's 3-D pose at each frame.

Cameras that share a stamp (to :data:`SYNC_NS`) are one rig frame, as a synchronised rig's
are; unsynchronised cameras make frames of their own.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import cv2
import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.common.notes import Note
from markergraph.estimator.tags3d import KnownTag, SceneCamera, TagScene, TagView, tag_corners
from markergraph.frontend.camera import Camera
from markergraph.frontend.config import FrontendConfig
from markergraph.frontend.decode import decode_image, frame_id, stamp_ns
from markergraph.frontend.detect import Detection
from markergraph.frontend.detections import TagFamilies, detections_of
from markergraph.frontend.logs import DecodeFailures, Log, LogError, Message
from markergraph.frontend.spans import detector_for
from markergraph.frontend.survey import TagRemap
from markergraph.frontend.tagged import (
    Rig,
    find_camera,
    find_mount,
    no_camera_text,
    odometry_body_text,
)
from markergraph.frontend.tf import rotation_of, transforms_of
from markergraph.frontend.topics import CALIBRATION_SCHEMAS, TopicChoice

__all__ = ["SceneRead", "ray_per_px", "read_tag_scene", "seed_poses"]

SYNC_NS = 1_000_000
"""Detections of different cameras this close in time belong to one rig frame."""
MAX_ODOMETRY_GAP_NS = 500_000_000
"""A frame's odometry is interpolated between samples at most this far apart."""
PIXEL_NOISE_PX = 1.0
"""The corners' noise on a real rig's detector (TagSLAM's default too) [px]."""


@dataclass
class SceneRead:
    """The scene and what reading it found."""

    scene: TagScene
    detection_messages: int = 0
    views_read: int = 0
    skipped: Counter[str] = field(default_factory=Counter)
    """Reason -> detections not made into views."""
    notes: list[Note] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


def seed_poses(
    rays: NDArray[np.float64], size_m: float
) -> tuple[gtsam.Pose3, gtsam.Pose3 | None] | None:
    """The tag's pose in the camera from its corners' rays: IPPE's two solutions, the better
    first (the second None where it is behind the camera), or None when neither is in front."""
    found, rotations, translations, errors = cv2.solvePnPGeneric(
        tag_corners(size_m), np.ascontiguousarray(rays.reshape(4, 1, 2)), np.eye(3), None,
        flags=cv2.SOLVEPNP_IPPE_SQUARE,
    )  # fmt: skip
    poses = []
    for k in np.argsort(np.asarray(errors).ravel())[:found]:
        t = np.asarray(translations[k], dtype=np.float64).ravel()
        if np.all(np.isfinite(t)) and t[2] > 0:
            R, _ = cv2.Rodrigues(rotations[k])
            poses.append(gtsam.Pose3(gtsam.Rot3(R), t))
    if not poses:
        return None
    return poses[0], (poses[1] if len(poses) > 1 else None)


def _wound(
    rays: NDArray[np.float64], size_m: float
) -> tuple[NDArray[np.float64], tuple[gtsam.Pose3, gtsam.Pose3 | None] | None, bool]:
    """(rays in the winding that faces the camera, their PnP seeds, whether they were
    reversed). Corners listed the other way round mirror the square: it would face away from
    the camera, or stand behind it."""
    if not np.all(np.isfinite(rays)):
        return rays, None, False
    seeds = seed_poses(rays, size_m)
    if seeds is not None and _faces_camera(seeds[0]):
        return rays, seeds, False
    reversed_rays = rays[::-1].copy()
    other = seed_poses(reversed_rays, size_m)
    if other is not None and _faces_camera(other[0]):
        return reversed_rays, other, True
    return rays, seeds, False


def _faces_camera(T_camera_tag: gtsam.Pose3) -> bool:
    """Whether the tag's front (its z, out of the print) points toward the camera."""
    return float(T_camera_tag.rotation().matrix()[:, 2] @ T_camera_tag.translation()) < 0.0


def _interpolated(samples: list[tuple[int, gtsam.Pose3]], t_ns: int) -> gtsam.Pose3 | None:
    times = np.array([t for t, _ in samples], dtype=np.int64)
    k = int(np.searchsorted(times, t_ns))
    if k < len(times) and times[k] == t_ns:
        return samples[k][1]
    if k == 0 or k == len(times) or times[k] - times[k - 1] > MAX_ODOMETRY_GAP_NS:
        return None
    (ta, a), (tb, b) = samples[k - 1], samples[k]
    s = (t_ns - ta) / (tb - ta)
    rotation = a.rotation().slerp(s, b.rotation())
    return gtsam.Pose3(rotation, (1 - s) * a.translation() + s * b.translation())


class _Reader:
    def __init__(self, log: Log, config: FrontendConfig, choice: TopicChoice) -> None:
        self.log, self.config, self.choice = log, config, choice
        self.rig = Rig.read(config)
        self.failures = DecodeFailures()
        self.families = TagFamilies()
        self.notes: list[Note] = []  # what reading them noticed (ids beyond the dictionary)
        self.messages: list[tuple[str, int, str, list[Detection]]] = []
        self.infos: dict[str, Any] = {}
        self.static: list[Any] = []
        self.odometry: list[tuple[int, gtsam.Pose3]] = []
        self.body_frame: str | None = None
        self.odometry_body = "given"
        """How the odometry's body was put on the rig (:class:`~.tagged.FoundMount`)."""
        self.images = None if choice.detections else choice.color
        """The image topic detected here, for a log of images."""
        self.topics = choice.detections or ((choice.color,) if choice.color else ())

    def read(self) -> None:
        schemas = {t.topic: t.schema for t in self.log.topics}
        infos = [t for t, schema in schemas.items() if schema in CALIBRATION_SCHEMAS]
        wanted = [*self.topics, *infos]
        wanted += [t for t in (self.choice.odom, self.choice.tf_static) if t]
        for message in self.log.messages(wanted, self.failures):
            if message.topic == self.images:
                self._detect(message)
            else:
                self._take(message.topic, message.decoded)
        self.notes = self.families.check(self.log.path, self.config.dictionary)
        self.odometry.sort(key=lambda s: s[0])

    def _detect(self, message: Message) -> None:
        """An image's tags, found by the front end's detector."""
        try:
            grey = decode_image(message)
        except LogError as error:
            self.failures.add(self.log.path, message.topic, str(error))
            return
        found = sorted(detector_for(self.config).detect(grey), key=lambda d: d.marker_id)
        decoded = message.decoded
        self.messages.append((message.topic, stamp_ns(decoded), frame_id(decoded), found))

    def _take(self, topic: str, decoded: Any) -> None:
        if topic in self.choice.detections:
            try:
                found = detections_of(decoded)
            except (ValueError, AttributeError, TypeError) as error:
                self.failures.add(self.log.path, topic, f"not a detection array ({error})")
                return
            self.families.take(topic, decoded, found)
            self.messages.append((topic, stamp_ns(decoded), frame_id(decoded), found))
        elif topic == self.choice.tf_static:
            self.static += transforms_of(decoded)
        elif topic == self.choice.odom:
            pose = getattr(decoded, "pose", None)
            pose = getattr(pose, "pose", pose)
            R = rotation_of(pose.orientation) if pose is not None else None
            if pose is None or R is None:
                return
            p = np.array([pose.position.x, pose.position.y, pose.position.z], dtype=np.float64)
            if np.all(np.isfinite(p)):
                self.body_frame = self.body_frame or getattr(decoded, "child_frame_id", None)
                self.odometry.append((stamp_ns(decoded), gtsam.Pose3(gtsam.Rot3(R), p)))
        elif topic not in self.infos:
            self.infos[topic] = decoded

    def cameras(self, notes: list[Note]) -> tuple[list[SceneCamera], list[Camera]]:
        """Each detection topic with intrinsics, its mount where given (else None)."""
        scene_cameras, models = [], []
        bases = (self.body_frame, self.config.base_frame)
        for topic in self.topics:
            frame = next((f for t, _, f, _ in self.messages if t == topic), "")
            found = find_camera(topic, frame, self.rig, self.infos)
            if found is None:
                notes.append(Note("detections.no_camera", no_camera_text(topic), topic))
                continue
            mount, _ = find_mount(self.static, bases, frame, found, self.rig)
            if mount is not None and mount.odometry_body != "given" and self.body_frame:
                self.odometry_body = mount.odometry_body
                text = odometry_body_text(topic, self.body_frame, frame, mount.odometry_body)
                notes.append(Note("odometry.body_" + mount.odometry_body, text, topic))
            name = found.kalibr_name or topic
            pose = (
                None
                if mount is None
                else gtsam.Pose3(gtsam.Rot3(mount.T_body_optical.R), mount.T_body_optical.t)
            )
            if mount is None:
                notes.append(
                    Note(
                        "camera.mount_estimated",
                        f"{topic}: no mount given (no /tf_static "
                        "chain, not in camera_poses.yaml): estimated from the tags it sees "
                        "with the rig's other cameras",
                        topic,
                    )
                )
            scene_cameras.append(SceneCamera(name, topic, pose))
            models.append(found.camera)
        if not scene_cameras:
            raise LogError(
                f"{self.log.path}: no detection topic has its camera's intrinsics "
                f"({'; '.join(n.text for n in notes)})"
            )
        return scene_cameras, models


def _frames(
    messages: list[tuple[str, int, str, list[Detection]]],
) -> tuple[NDArray[np.int64], list[int]]:
    """Each message's rig frame: stamps within :data:`SYNC_NS` of a frame's first are one."""
    order = sorted(range(len(messages)), key=lambda k: messages[k][1])
    starts: list[int] = []
    index = [0] * len(messages)
    for k in order:
        t = messages[k][1]
        if not starts or t - starts[-1] > SYNC_NS:
            starts.append(t)
        index[k] = len(starts) - 1
    return np.array(starts, dtype=np.int64), index


def read_tag_scene(
    log: Log,
    config: FrontendConfig,
    choice: TopicChoice,
    known_tags: list[KnownTag] | None = None,
    ignored: frozenset[int] = frozenset(),
    home_id: int | None = None,
    remaps: tuple[TagRemap, ...] = (),
) -> SceneRead:
    """The 3-D scene of a log of tag detections.

    Raises:
        LogError: no detection topic has its camera's intrinsics, or no detection at all.
        SettingsError: a Kalibr, camera-poses or tagslam file that cannot be read.
    """
    reader = _Reader(log, config, choice)
    reader.read()
    empty = sum(1 for message in reader.messages if not message[3])
    reader.messages = [message for message in reader.messages if message[3]]
    notes: list[Note] = list(reader.notes)
    cameras, models = reader.cameras(notes)
    topics = {c.topic: i for i, c in enumerate(cameras)}
    sizes = config.marker_sizes
    if reader.rig.tagslam is not None:
        sizes = sizes.under(reader.rig.tagslam.tag_sizes_m)
    times, frame_of = _frames(reader.messages)
    read = SceneRead(TagScene(times, [], cameras, {}), len(reader.messages) + empty)
    if empty:
        read.skipped["detection messages with no tag"] = empty
    views: list[TagView] = []
    rewound: Counter[str] = Counter()
    allowed = config.allowed_ids
    for k, (topic, t_ns, _, detections) in enumerate(reader.messages):
        if topic not in topics:
            read.skipped[f"detections on {topic} without a camera"] += len(detections)
            continue
        camera, model = topics[topic], models[topics[topic]]
        for d in _remapped(detections, t_ns, remaps):
            read.views_read += 1
            if d.marker_id in ignored or (allowed is not None and d.marker_id not in allowed):
                read.skipped["tag ignored by the settings"] += 1
                continue
            rays = model.rays(d.corners)
            rays, seeds, reversed_ = _wound(rays, sizes.of(d.marker_id))
            rewound[topic] += int(reversed_)
            if seeds is None:
                read.skipped["corners with no pose in front of the camera"] += 1
                continue
            per_px = ray_per_px(model, d.corners)
            views.append(TagView(frame_of[k], camera, d.marker_id, rays,
                                 PIXEL_NOISE_PX * per_px, per_px, *seeds))  # fmt: skip
    if not views:
        raise LogError(f"{log.path}: no tag detection gives a pose: {_why_none(read, reader)}")
    for topic, count in (item for item in rewound.items() if item[1]):
        text = (
            f"{count:,} detections on {topic} had their corners wound the other way round "
            "(the tag would face away from the camera): read in reverse"
        )
        notes.append(Note("detections.rewound", text, topic, count))
    odometry = [_interpolated(reader.odometry, int(t)) for t in times] if reader.odometry else []
    tag_sizes = {v.tag_id: sizes.of(v.tag_id) for v in views}
    read.scene = TagScene(times, views, cameras, tag_sizes, odometry, known_tags or [], home_id,
                          reader.odometry_body if odometry else "given")  # fmt: skip
    read.notes = notes
    read.warnings = reader.failures.warnings()
    return read


def _why_none(read: SceneRead, reader: _Reader) -> str:
    """Why no detection gave a pose, in words: the messages that could not be read (a damaged
    log says where), then each reason detections were set aside, with its count."""
    unread = [line.partition(": ")[2] for line in reader.failures.warnings()]
    skipped = [f"{reason} ({count:,})" for reason, count in read.skipped.most_common()]
    return "; ".join(unread + skipped) or "no detection messages"


def _remapped(
    detections: list[Detection], t_ns: int, remaps: tuple[TagRemap, ...]
) -> list[Detection]:
    """Detections with TagSLAM's id remaps applied (two tags printed with one id, told apart by
    when they were seen)."""
    if not remaps:
        return detections
    out = []
    for d in detections:
        remap = next(
            (r for r in remaps if r.tag_id == d.marker_id and r.start_ns <= t_ns <= r.end_ns), None
        )
        out.append(d if remap is None else Detection(remap.remap_id, d.corners))
    return out


def ray_per_px(camera: Camera, corners_px: NDArray[np.float64]) -> NDArray[np.float64]:
    """(8,) how far each corner's ray coordinates (x/z, y/z) move for a pixel of noise there,
    through the lens model (the norm of each row of the pixels-to-ray Jacobian, by central
    differences): a fisheye's rim spreads a pixel over several times the angle its centre
    does."""
    corners = np.asarray(corners_px, dtype=np.float64).reshape(4, 2)
    h = 0.5
    steps = np.array([[h, 0.0], [-h, 0.0], [0.0, h], [0.0, -h]])
    shifted = (corners[None, :, :] + steps[:, None, :]).reshape(16, 2)
    rays = camera.rays(shifted).reshape(4, 4, 2)
    d_du, d_dv = (rays[0] - rays[1]) / (2 * h), (rays[2] - rays[3]) / (2 * h)
    per_px = np.hypot(d_du, d_dv)  # (4, 2): each ray coordinate's change per pixel
    if not np.all(np.isfinite(per_px)) or np.any(per_px <= 0):
        return np.full(8, 1.0 / float(np.sqrt(camera.fx * camera.fy)))
    return per_px.ravel()
