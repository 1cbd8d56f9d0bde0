"""Which way is up in a 3-D tag map, and the map frame that follows.

The solver works in the surveyed tags' frame, or in the home tag's. Up is the odometry frame's
z (odometry is gravity-aligned: wheel odometry, VIO, a T265), else the surveyed frame's z, else
the direction the tags on walls all lie level with (their normals span a horizontal plane; its
sign is the cameras' image up, cameras being held upright). With up known, the map frame has z
up, its origin at the home tag's centre and x along the home tag's normal on the floor, so that
its wall tags make markergraph's 2-D map; without it the map frame is the home tag's marker
frame. A surveyed frame is never moved.
"""

from __future__ import annotations

import math

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.common.notes import Note
from markergraph.estimator.tag_graph import rig_key, tag_key
from markergraph.estimator.tag_init import Placed
from markergraph.estimator.tags3d import R_TAG_MARKER, TagScene

__all__ = ["map_framing"]

WALL_LIMIT_RAD = math.radians(45.0)
"""A tag whose normal is within this of level (for the cameras' up) is taken as on a wall."""
LEVEL_RAD = math.radians(15.0)
"""Tags on walls must lie within this of level for the up they give to be believed..."""
LEVEL_SHARE = 0.8
"""... this share of them at least."""
SPREAD_RAD = math.radians(20.0)
"""Two walls at least this far apart in heading are needed to find up from walls."""


def _unit(v: NDArray[np.float64]) -> NDArray[np.float64]:
    return v / np.linalg.norm(v)


def _up_from_odometry(
    scene: TagScene, values: gtsam.Values, frames: list[int]
) -> NDArray[np.float64] | None:
    pairs = [
        (values.atPose3(rig_key(i)).rotation().matrix(), odometry.rotation().matrix())
        for i in frames
        if scene.odometry and (odometry := scene.odometry[i]) is not None
    ]
    if not pairs:
        return None
    total = np.sum([R_map_rig @ R_odom_rig.T for R_map_rig, R_odom_rig in pairs], axis=0)
    U, _, Vt = np.linalg.svd(total)
    return np.asarray((U @ Vt)[:, 2])  # the odometry frame's z in the map


def _cameras_up(
    scene: TagScene, placed: Placed, values: gtsam.Values, frames: list[int]
) -> NDArray[np.float64]:
    """The mean of each placed frame's cameras' image up (minus the optical y) in the map."""
    total = np.zeros(3)
    for i in frames:
        R_map_rig = values.atPose3(rig_key(i)).rotation().matrix()
        for mount in placed.cameras.values():
            total -= R_map_rig @ mount.rotation().matrix()[:, 1]
    return _unit(total)


def _up_from_walls(
    normals: NDArray[np.float64], prior: NDArray[np.float64]
) -> NDArray[np.float64] | None:
    """The direction most normals lie level with: the tags within 45 degrees of level for the
    cameras' up first, then (twice) those within :data:`LEVEL_RAD` of the up they give, so
    that a board leaning back or a tag on a ramp does not tilt it."""
    up, limit = prior, WALL_LIMIT_RAD
    for _ in range(3):
        walls = normals[np.abs(normals @ up) < math.sin(limit)]
        if len(walls) < 2:
            return None
        spread = np.linalg.norm(np.cross(walls[:, None, :], walls[None, :, :]), axis=2)
        if spread.max() < math.sin(SPREAD_RAD):
            return None  # one wall (or one board): its normal leaves up free about it
        up = np.linalg.eigh(walls.T @ walls)[1][:, 0]
        up = up if up @ prior > 0 else -up
        limit = LEVEL_RAD
    level = np.abs(normals @ up) < math.sin(LEVEL_RAD)
    return up if level.sum() >= LEVEL_SHARE * len(walls) else None


def map_framing(
    scene: TagScene, placed: Placed, values: gtsam.Values, frames: list[int], home: int | None
) -> tuple[gtsam.Pose3, bool, list[Note]]:
    """``G`` taking the solver's frame to the map frame, whether the map's z is up, and a note
    on where up came from."""
    if scene.known_tags:
        return (
            gtsam.Pose3(),
            True,
            [Note("map.frame", "the map frame is the surveyed tags' (z up)")],
        )
    assert home is not None
    up = _up_from_odometry(scene, values, frames)
    source = "the odometry's vertical"
    doubt: list[Note] = []
    if up is not None and scene.odometry_body != "given":
        doubt = _doubted_up(scene, placed, values, frames, up)
    if up is None:
        tags = [values.atPose3(tag_key(i)).rotation().matrix()[:, 2] for i in placed.tags]
        up = _up_from_walls(np.array(tags), _cameras_up(scene, placed, values, frames))
        source = "the tags on walls (level normals), its sign from the cameras' image up"
    if up is None:
        text = (
            f"up is not known (no odometry, no survey, and the tags do not lie on two walls): "
            f"the map frame is home tag {home}'s, x along its normal, and there is no 2-D map"
        )
        return (
            gtsam.Pose3(gtsam.Rot3(R_TAG_MARKER), np.zeros(3)).inverse(),
            False,
            [Note("map.no_up", text)],
        )
    normal = np.array([0.0, 0.0, 1.0])  # the home tag's, at the identity
    heading = normal - (normal @ up) * up
    if np.linalg.norm(heading) < 0.1:  # a home tag on the floor: its x on the floor instead
        heading = np.array([1.0, 0.0, 0.0]) - up[0] * up
    x = _unit(heading)
    R_out_map = np.vstack([x, np.cross(up, x), up])
    text = f"the map frame has z up (from {source}), its origin at home tag {home}'s centre"
    return gtsam.Pose3(gtsam.Rot3(R_out_map), np.zeros(3)), True, [Note("map.frame", text), *doubt]


def _doubted_up(
    scene: TagScene, placed: Placed, values: gtsam.Values, frames: list[int],
    up: NDArray[np.float64],
) -> list[Note]:  # fmt: skip
    """A note (kind ``map.up_doubted``) where the odometry's up, through an odometry body whose
    place on the rig was not given, disagrees with what the map itself shows: the cameras'
    image up (cameras are held upright) more than :data:`WALL_LIMIT_RAD` away, and no tag
    level for that up although some are for the cameras'."""
    cameras = _cameras_up(scene, placed, values, frames)
    apart = math.degrees(math.acos(float(np.clip(up @ cameras, -1.0, 1.0))))
    if apart <= math.degrees(WALL_LIMIT_RAD):
        return []
    normals = np.array([values.atPose3(tag_key(i)).rotation().matrix()[:, 2] for i in placed.tags])
    level = int(np.sum(np.abs(normals @ up) < math.sin(WALL_LIMIT_RAD)))
    level_for_cameras = int(np.sum(np.abs(normals @ cameras) < math.sin(WALL_LIMIT_RAD)))
    how = {"convention": "taken by REP 103's convention", "assumed": "taken as the rig's frame"}
    text = (
        f"up is in doubt: the odometry's vertical, through its body {how[scene.odometry_body]} "
        f"(not given), is {apart:.0f} deg from the cameras' image up; {level} of "
        f"{len(normals)} tags lie level (on walls) for it, {level_for_cameras} for the cameras' "
        "up. Give the odometry's body on the rig (tagslam.yaml's T_body_odom with --tagslam, "
        "or a /tf_static chain)"
    )
    return [Note("map.up_doubted", text, figure=apart)]
