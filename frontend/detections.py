"""Marker detections a robot recorded instead of images: AprilTag detection messages to
:class:`~markergraph.frontend.detect.Detection` records with corners in OpenCV's order.

Types read, by name: ROS 2 ``apriltag_msgs/msg/AprilTagDetectionArray`` (apriltag_ros for ROS 2,
both shapes of its corners field: ``Point[4]`` and ``float64[8]``),
``isaac_ros_apriltag_interfaces/msg/AprilTagDetectionArray`` and TagSLAM's ROS 1
``apriltag_msgs/ApriltagArrayStamped``.

The AprilTag library lists a tag's corners counter-clockwise in the image from the tag's
bottom-left; OpenCV's ArUco lists them clockwise from the top-left. Reversing the order turns
one into the other up to where the list starts, which only rotates the marker in its own plane:
the estimators use the marker's normal, which the winding alone decides (checked on TagSLAM's
recordings: reversed, every tag faces the camera; as listed, none does).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from markergraph.frontend.detect import Detection
from markergraph.frontend.ros2 import MESSAGE_DEFINITIONS

__all__ = ["DETECTION_DEFINITIONS", "DETECTION_SCHEMAS", "detections_of"]

DETECTION_SCHEMAS = (
    "apriltag_msgs/msg/AprilTagDetectionArray",
    "isaac_ros_apriltag_interfaces/msg/AprilTagDetectionArray",
    "apriltag_msgs/msg/ApriltagArrayStamped",
)

# Their definitions, for logs that carry none (a Humble SQLite bag stores no definitions).
DETECTION_DEFINITIONS = {
    name: MESSAGE_DEFINITIONS[name] for name in DETECTION_SCHEMAS if name in MESSAGE_DEFINITIONS
}


def _corners(tag: Any) -> np.ndarray:
    """(4, 2) pixel corners of one detection, whichever shape its message has."""
    corners = tag.corners
    if len(corners) == 8 and not hasattr(corners[0], "x"):  # float64[8]: x0, y0, x1, y1, ...
        return np.asarray(corners, dtype=np.float64).reshape(4, 2)
    return np.array([[float(p.x), float(p.y)] for p in corners], dtype=np.float64)


def detections_of(decoded: Any) -> list[Detection]:
    """The detections one message carries, corners in OpenCV's order, sorted by id.

    Raises:
        ValueError: a detection without four corners.
    """
    tags = decoded.apriltags if hasattr(decoded, "apriltags") else decoded.detections
    found = []
    for tag in tags:
        corners = _corners(tag)
        if corners.shape != (4, 2):
            raise ValueError(f"a detection of tag {tag.id} has {len(tag.corners)} corners, not 4")
        found.append(Detection(int(tag.id), corners[::-1].copy()))
    return sorted(found, key=lambda d: d.marker_id)
