"""TagSLAM's regression recordings as a peer to compare with (``../shared/data/tagslam-test``):
their bags unpacked, their settings as markergraph's, and TagSLAM's own map of the wall tags.

TagSLAM (a GTSAM-based fiducial SLAM for ROS 1) publishes its optimised tags on ``/tf`` as
``tag_<id>`` frames of its gravity-aligned map; they are its estimate, not surveyed truth.
"""

from __future__ import annotations

import bz2
import math
import re
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
    "align_rigid_3d",
    "aligned_errors",
    "aligned_errors_3d",
    "observation_errors",
    "odometry_and_reference",
    "reference_path_3d",
    "reference_tags_3d",
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


def _last_transforms(bag: Path) -> dict[str, tuple[str, gtsam.Pose3]]:
    """Each /tf child frame's last transform: child -> (parent, T_parent_child)."""
    last = {}
    for message in open_log(bag).messages(["/tf"]):
        for transform in message.decoded.transforms:
            q, t = transform.transform.rotation, transform.transform.translation
            pose = gtsam.Pose3(gtsam.Rot3.Quaternion(q.w, q.x, q.y, q.z), np.array([t.x, t.y, t.z]))
            parent = transform.header.frame_id.lstrip("/")
            last[transform.child_frame_id.lstrip("/")] = (parent, pose)
    return last


def _in_frame(
    child: str, last: Mapping[str, tuple[str, gtsam.Pose3]], frame: str | None
) -> gtsam.Pose3 | None:
    """``T_frame_child`` walked up the tree (to its root when ``frame`` is None); None when
    ``frame`` is not an ancestor."""
    pose, node, seen = gtsam.Pose3(), child, {child}
    while node in last and node != frame:
        parent, T_parent_node = last[node]
        pose = T_parent_node.compose(pose)
        if parent in seen:  # a loop in /tf: no root to reach
            return None
        seen.add(parent)
        node = parent
    return pose if frame is None or node == frame else None


def reference_tags_3d(
    bag: Path, frame: str | None = None, prefix: str = "tag_"
) -> dict[int, gtsam.Pose3]:
    """TagSLAM's final tag poses (the tag frame: AprilTag's, z out of the print), each its last
    /tf value composed up the tree: to the tree's root (TagSLAM's ``map``) by default, or to
    ``frame`` (a static body's name) if given, leaving out tags not under it.

    TagSLAM hangs a tag under its body's frame (``perch``, ``lab``, ``board_60``, ...), and the
    body under ``map``, at an offset where the body has a pose (test 16's ``lab`` is 1 m up).
    Frames named ``<prefix><id>`` are read: ``tag_`` its optimised tags, ``o_tag_`` the surveyed
    poses it was given (a body named ``tag_board`` matches neither).
    """
    pattern = re.compile(rf"^{re.escape(prefix)}(\d+)$")
    last = _last_transforms(bag)
    tags = {}
    for name in last:
        match = pattern.match(name)
        pose = _in_frame(name, last, frame) if match else None
        if match and pose is not None:
            tags[int(match.group(1))] = pose
    return dict(sorted(tags.items()))


def reference_path_3d(
    bag: Path, body: str | None = None
) -> tuple[NDArray[np.int64], list[gtsam.Pose3]]:
    """TagSLAM's optimised path of a body, ``T_map_body`` at each header stamp [ns], from
    ``/tagslam/odom/body_<body>`` (the message's child frame says ``odom``, but the pose is the
    body in the map). Without ``body``: the bag's one such topic, or ``rig`` among several.

    Raises:
        ValueError: no such topic, or several and none of them the rig's.
    """
    prefix = "/tagslam/odom/body_"
    topics = sorted(t.topic for t in open_log(bag).topics if t.topic.startswith(prefix))
    if body is not None:
        chosen = f"{prefix}{body}"
    elif len(topics) == 1 or f"{prefix}rig" in topics:
        chosen = topics[0] if len(topics) == 1 else f"{prefix}rig"
    else:
        raise ValueError(f"{bag}: body paths {topics}: name the body")
    if chosen not in topics:
        raise ValueError(f"{bag}: no {chosen} (it has {topics})")
    times, poses = [], []
    for message in open_log(bag).messages([chosen]):
        pose = message.decoded.pose.pose
        q, p = pose.orientation, pose.position
        times.append(stamp_ns(message.decoded))
        poses.append(
            gtsam.Pose3(gtsam.Rot3.Quaternion(q.w, q.x, q.y, q.z), np.array([p.x, p.y, p.z]))
        )
    return np.array(times, dtype=np.int64), poses


def align_rigid_3d(source_xyz: NDArray[np.float64], target_xyz: NDArray[np.float64]) -> gtsam.Pose3:
    """The rotation and translation (no scale) taking ``source_xyz`` (n, 3) onto
    ``target_xyz`` (n, 3) in least squares: Kabsch's SVD of the centred cross-covariance, with
    the reflection removed (Umeyama 1991, eq. 39-42 with c = 1).

    Raises:
        ValueError: fewer than three points, or shapes that differ.
    """
    source, target = np.asarray(source_xyz, float), np.asarray(target_xyz, float)
    if source.shape != target.shape or source.ndim != 2 or source.shape[1] != 3:
        raise ValueError(f"shapes {source.shape} and {target.shape}: need two (n, 3) arrays")
    if source.shape[0] < 3:
        raise ValueError(f"{source.shape[0]} points: a 3-D alignment needs at least three")
    mu_s, mu_t = source.mean(axis=0), target.mean(axis=0)
    U, _, Vt = np.linalg.svd((target - mu_t).T @ (source - mu_s))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    R = U @ D @ Vt
    return gtsam.Pose3(gtsam.Rot3(R), mu_t - R @ mu_s)


COLLINEAR_RATIO = 1e-3
"""Positions whose second principal spread is below this share of the first lie on a line: a
fit on them cannot fix the rotation about it."""


def _fit_points(poses: list[gtsam.Pose3], reach_m: float) -> NDArray[np.float64]:
    """Each pose's position, and where its tag lies on a line (or is alone), also the tips of
    its axes at ``reach_m``."""
    return np.array(
        [p.transformFrom(np.asarray(v) * reach_m) for p in poses for v in np.eye(3)]
        + [p.translation() for p in poses]
    )


def aligned_errors_3d(
    ours: Mapping[int, gtsam.Pose3], reference: Mapping[int, gtsam.Pose3]
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
    """Each tag's position error [m] and rotation error [rad] (the angle of
    ``R_ref^T R_ours``) against the reference after the rigid 3-D alignment fitted on the
    positions of the tags in common (so a tag turned round shows, not aligned away). Where
    those positions lie on a line (TagSLAM's test 16) or are fewer than three, the fit also
    takes points on each tag's axes at the tags' spread (a rotation error is then shared out).

    Returns:
        (ids (n,), position errors (n,) [m], rotation errors (n,) [rad]), in id order.

    Raises:
        ValueError: fewer than two tags in common.
    """
    ids = np.array(sorted(set(ours) & set(reference)), dtype=np.int64)
    if ids.size < 2:
        raise ValueError(f"{ids.size} tags in common with the reference: no 3-D alignment")
    mine = [ours[int(i)] for i in ids]
    theirs = [reference[int(i)] for i in ids]
    source = np.array([p.translation() for p in mine])
    target = np.array([p.translation() for p in theirs])
    spread = np.linalg.svd(target - target.mean(axis=0), compute_uv=False)
    if ids.size < 3 or spread[1] < COLLINEAR_RATIO * spread[0]:
        reach = max(float(spread[0]) / math.sqrt(ids.size), 0.1)
        source, target = _fit_points(mine, reach), _fit_points(theirs, reach)
    T = align_rigid_3d(source, target)
    pairs = [(T.compose(p), q) for p, q in zip(mine, theirs, strict=True)]
    position = np.array([np.linalg.norm(a.translation() - b.translation()) for a, b in pairs])
    rotation = np.array(
        [np.linalg.norm(gtsam.Rot3.Logmap(b.rotation().between(a.rotation()))) for a, b in pairs]
    )
    return ids, position, rotation
