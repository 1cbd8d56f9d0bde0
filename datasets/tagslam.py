"""TagSLAM's regression recordings as a peer to compare with (``../shared/data/tagslam-test``):
their bags unpacked, their settings as markergraph's, and TagSLAM's own map of the wall tags.

TagSLAM (a GTSAM-based fiducial SLAM for ROS 1) publishes its optimised tags on ``/tf`` as
``tag_<id>`` frames of its gravity-aligned map; they are its estimate, not surveyed truth.
"""

from __future__ import annotations

import bz2
import math
from pathlib import Path
from typing import Any

import gtsam

from markergraph.frontend import messages
from markergraph.frontend.posed import WALL_TILT_RAD

__all__ = ["reference_wall_tags", "settings_for", "unpacked"]


def unpacked(folder: Path, name: str, into: Path) -> Path:
    """A test's ``<name>.bag.bz2`` decompressed into ``into`` (once; rosbags reads plain bags)."""
    target = Path(into) / f"{Path(folder).name}-{name}.bag"
    if not target.exists():
        target.write_bytes(bz2.decompress((Path(folder) / f"{name}.bag.bz2").read_bytes()))
    return target


def settings_for(folder: Path, **extra: Any) -> dict[str, Any]:
    """markergraph's settings for a test: its Kalibr cameras, TagSLAM camera poses and
    tagslam.yaml (tag sizes, the odometry's body on the rig), AprilTag 36h11, every method."""
    folder = Path(folder)
    return {
        "dictionary": "DICT_APRILTAG_36h11",
        "method": "all",
        "rig.cameras": str(folder / "cameras.yaml"),
        "rig.camera_poses": str(folder / "camera_poses.yaml"),
        "rig.tagslam": str(folder / "tagslam.yaml"),
        **extra,
    }


def reference_wall_tags(bag: Path) -> dict[int, gtsam.Pose2]:
    """TagSLAM's final tag poses whose normal is within 45 degrees of horizontal, as 2-D poses
    (x along the normal) in its map."""
    last = {}
    for message in messages(bag, ["/tf"]):
        for transform in message.decoded.transforms:
            last[transform.child_frame_id] = transform.transform
    tags = {}
    for name, transform in last.items():
        if not name.startswith("tag_"):
            continue
        q = transform.rotation
        normal = gtsam.Rot3.Quaternion(q.w, q.x, q.y, q.z).matrix()[:, 2]
        if abs(normal[2]) < math.sin(WALL_TILT_RAD):  # as the front end decides
            t = transform.translation
            tags[int(name[4:])] = gtsam.Pose2(t.x, t.y, math.atan2(normal[1], normal[0]))
    return tags
