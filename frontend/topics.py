"""Which topics of a log play which role: colour, depth, camera info, odometry, transforms and
the simulator's ground truth."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from markergraph.frontend.config import FrontendConfig
from markergraph.frontend.detections import DETECTION_SCHEMAS
from markergraph.frontend.logs.records import LogError, LogTopic

__all__ = [
    "COLOR_TOPICS",
    "DEPTH_TOPICS",
    "TRUE_MARKERS",
    "TRUE_POSE",
    "TRUE_WORLD",
    "TopicChoice",
    "choose_topics",
]

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
# The simulator's ground truth (markergraph.datasets writes it, the front end reads it back).
TRUE_MARKERS, TRUE_POSE = "/ground_truth/markers", "/ground_truth/pose"
TRUE_WORLD = "/ground_truth/world"
# ROS 2 and Foxglove (protobuf) message types, by role.
IMAGE_SCHEMAS = (
    "sensor_msgs/msg/Image",
    "sensor_msgs/msg/CompressedImage",
    "foxglove.CompressedImage",
    "foxglove.RawImage",
)
CALIBRATION_SCHEMAS = ("sensor_msgs/msg/CameraInfo", "foxglove.CameraCalibration")
ODOMETRY_SCHEMAS = ("nav_msgs/msg/Odometry", "foxglove.PoseInFrame")
TF_SCHEMAS = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
TRANSFORM_SCHEMAS = ("foxglove.FrameTransforms", "foxglove.FrameTransform")


@dataclass(frozen=True)
class TopicChoice:
    """The topics a log will be read from (None where the log has none)."""

    color: str | None
    depth: str | None
    camera_info: str | None
    odom: str | None
    tf_static: str | None
    detections: tuple[str, ...] = ()
    """Topics of marker detections (AprilTag messages): read instead of images when present
    and no colour topic is set."""


def _camera_info_for(color: str) -> str:
    namespace = re.sub(r"/image_raw(/compressed)?$", "", color)
    return f"{namespace}/camera_info"


def choose_topics(path: Path, topics: list[LogTopic], config: FrontendConfig) -> TopicChoice:
    """The colour, depth, camera info, odometry and tf_static topics to use.

    Raises:
        LogError: a configured topic is not in the log or of the wrong type, or the depth
            topic is the colour topic.
    """
    by_name = {t.topic: t for t in topics}
    _check_configured(path, by_name, config)
    images = [t.topic for t in topics if t.schema.endswith(IMAGE_SCHEMAS)]
    color = config.color_topic or _color_topic(by_name, images)
    depth = config.depth_topic or _depth_topic(by_name, images)
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
    detections = tuple(sorted(t.topic for t in topics if t.schema in DETECTION_SCHEMAS))
    if config.color_topic is not None:
        detections = ()
    if depth is not None and depth == color:
        raise LogError(f"{path}: the depth topic {depth} is the colour topic; pass --depth-topic")
    return TopicChoice(color, depth, info, odom, static, detections)


def _check_configured(path: Path, by_name: dict[str, LogTopic], config: FrontendConfig) -> None:
    """Each topic the settings name is in the log and carries a type its role reads.

    Raises:
        LogError: one is not, naming it.
    """
    for role, name, schemas in (
        ("--color-topic", config.color_topic, IMAGE_SCHEMAS),
        ("--depth-topic", config.depth_topic, IMAGE_SCHEMAS),
        ("--camera-info-topic", config.camera_info_topic, CALIBRATION_SCHEMAS),
        ("--odom-topic", config.odom_topic, (*ODOMETRY_SCHEMAS, *TF_SCHEMAS)),
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


def _color_topic(by_name: dict[str, LogTopic], images: list[str]) -> str | None:
    """realsense-ros's colour topic, else the first image topic not named depth."""
    color = next((t for t in COLOR_TOPICS if t in by_name), None)
    if color is None:
        plain = [t for t in images if "depth" not in t.lower()]
        color = plain[0] if plain else None
    return color


def _depth_topic(by_name: dict[str, LogTopic], images: list[str]) -> str | None:
    """realsense-ros's aligned depth topic, else the only image topic named depth."""
    depth = next((t for t in DEPTH_TOPICS if t in by_name), None)
    if depth is None:
        depths = [t for t in images if "depth" in t.lower()]
        depth = depths[0] if len(depths) == 1 else None
    return depth
