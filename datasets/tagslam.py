"""TagSLAM's regression recordings as a peer to compare with (``../shared/data/tagslam-test``):
their bags unpacked, their settings as markergraph's, and TagSLAM's own map of the wall tags.

TagSLAM (a GTSAM-based fiducial SLAM for ROS 1) publishes its optimised tags on ``/tf`` as
``tag_<id>`` frames of its gravity-aligned map; they are its estimate, not surveyed truth.
"""

from __future__ import annotations

import bz2
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.estimator import MapError, Observation, OdometrySample, Trajectory
from markergraph.estimator.angles import angle_diff
from markergraph.estimator.metrics import align_rigid_2d
from markergraph.frontend import open_log
from markergraph.frontend.decode import stamp_ns
from markergraph.frontend.posed import WALL_TILT_RAD
from markergraph.frontend.rig import Pose3, read_camera_poses, read_tagslam
from markergraph.frontend.tf import planar_pose, rotation_of

__all__ = [
    "aligned_errors",
    "observation_errors",
    "odometry_and_reference",
    "reference_wall_tags",
    "settings_for",
    "unpacked",
]


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
    in its map, in markergraph's convention (x along the normal into the room).

    TagSLAM's tag frame has its z axis out of the print, toward whoever can see it (every tag
    of recording 21 agrees with markergraph's normal to within a degree): that z, projected
    on the floor, is our x.
    """
    last = {}
    for message in open_log(bag).messages(["/tf"]):
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


def aligned_errors(
    poses: Mapping[int, gtsam.Pose2], reference: Mapping[int, gtsam.Pose2]
) -> MapError:
    """Each marker's position and yaw error against TagSLAM's map after the rigid 2-D alignment
    fitted on the positions alone (so a yaw turned round shows as 180 degrees, not aligned away),
    for any id -> pose map (an ``Estimate``'s markers, a ``map.json``'s)."""
    ids = np.array(sorted(set(poses) & set(reference)), dtype=np.int64)
    if ids.size < 2:
        raise ValueError(f"{ids.size} markers in common with the reference: no 2-D alignment")
    ours = [poses[int(i)] for i in ids]
    theirs = [reference[int(i)] for i in ids]
    T = align_rigid_2d(
        np.array([[p.x(), p.y()] for p in ours]), np.array([[p.x(), p.y()] for p in theirs])
    )
    aligned = [T.compose(p) for p in ours]
    position = np.array(
        [np.hypot(a.x() - b.x(), a.y() - b.y()) for a, b in zip(aligned, theirs, strict=True)]
    )
    yaw = np.array(
        [abs(angle_diff(a.theta(), b.theta())) for a, b in zip(aligned, theirs, strict=True)]
    )
    return MapError(
        ids, position, yaw, float(np.sqrt(np.mean(position**2))),
        float(np.sqrt(np.mean(yaw**2))), True,
    )  # fmt: skip


def odometry_and_reference(folder: Path, into: Path) -> tuple[Trajectory, Trajectory]:
    """A test's odometry and TagSLAM's optimised path of the same body, both on the floor with
    the heading of the first camera's optical axis (as the front end levels them), in their own
    frames: what an odometry noise model is measured against."""
    folder = Path(folder)
    tagslam = read_tagslam(folder / "tagslam.yaml")
    if tagslam.odom_topic is None:
        raise ValueError(f"{folder}: tagslam.yaml names no odometry topic")
    T_rig_odom = tagslam.T_rig_odom or Pose3.identity()
    T_rig_camera = next(iter(read_camera_poses(folder / "camera_poses.yaml").values()))
    forward = T_rig_odom.inverse().compose(T_rig_camera).R[:, 2]

    def path(bag: Path, topic: str, T_pose_body: Pose3, frame: str) -> Trajectory:
        samples = []
        for message in open_log(bag).messages([topic]):
            pose = message.decoded.pose.pose
            R = rotation_of(pose.orientation)
            if R is None:
                continue
            p = pose.position
            T = Pose3(R, np.array([p.x, p.y, p.z])).compose(T_pose_body)
            samples.append(
                OdometrySample(stamp_ns(message.decoded), *planar_pose(T.t, T.R, forward))
            )
        return Trajectory.from_samples(samples, frame)

    odometry = path(
        unpacked(folder, "tag_detections", into), tagslam.odom_topic, Pose3.identity(), "odom"
    )
    reference = path(
        unpacked(folder, "reference", into), "/tagslam/odom/body_rig", T_rig_odom, "map"
    )
    return odometry, reference


def observation_errors(
    observations: list[Observation], reference: Trajectory, tags: dict[int, gtsam.Pose2]
) -> NDArray[np.float64]:
    """Each observation of a reference tag against what TagSLAM's path and map predict, as rows
    (range error [m], theta error [rad], sigma_range, sigma_theta, predicted range [m]).

    Range (horizontal, body origin to tag centre) and theta (the line of sight against the tag's
    normal) do not depend on how a heading is defined, so they compare across conventions.
    """
    rows = []
    for o in observations:
        tag = tags.get(o.marker_id)
        body = reference.at(o.t_ns, max_extrapolation_ns=50_000_000)
        if tag is None or body is None:
            continue
        dx, dy = tag.x() - body.x(), tag.y() - body.y()
        theta = math.remainder(math.atan2(dy, dx) + math.pi - tag.theta(), math.tau)
        range_m = math.hypot(dx, dy)
        rows.append((o.range_m - range_m, math.remainder(o.theta - theta, math.tau),
                     o.sigma_range, o.sigma_theta, range_m))  # fmt: skip
    return np.array(rows, dtype=np.float64).reshape(-1, 5)
