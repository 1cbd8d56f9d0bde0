"""The cameras of a rig as calibration tools write them: Kalibr's ``cameras.yaml`` (intrinsics
and the topics each camera publishes), TagSLAM's ``camera_poses.yaml`` (each camera's pose on
the rig) and TagSLAM's ``tagslam.yaml`` (tag sizes, and where the odometry's body sits on the
rig).

Poses are ``T_parent_child`` as (R (3, 3), t (3,)); TagSLAM writes a rotation as a rotation
vector (axis times angle, radians) and a position in metres.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml
from numpy.typing import NDArray

from markergraph.common.documents import MAX_YAML_BYTES, DocumentError, read_text, yaml_document
from markergraph.common.errors import SettingsError
from markergraph.frontend.camera import Camera

__all__ = [
    "Pose3",
    "RigCamera",
    "TagslamConfig",
    "load_yaml",
    "read_camera_poses",
    "read_kalibr_cameras",
    "read_tagslam",
    "tagslam_pose",
]


@dataclass(frozen=True)
class Pose3:
    """A rigid transform ``T_parent_child``: x_parent = R x_child + t."""

    R: NDArray[np.float64]
    t: NDArray[np.float64]

    @classmethod
    def identity(cls) -> Pose3:
        return cls(np.eye(3), np.zeros(3))

    def compose(self, other: Pose3) -> Pose3:
        return Pose3(self.R @ other.R, self.R @ other.t + self.t)

    def inverse(self) -> Pose3:
        return Pose3(self.R.T, -self.R.T @ self.t)


@dataclass(frozen=True)
class RigCamera:
    """One camera of a Kalibr file: its name (``cam0``), intrinsics and topics."""

    name: str
    camera: Camera
    image_topic: str | None
    tag_topic: str | None


def _load(path: Path, what: str) -> Any:
    # Bounded: the size checked before reading, aliases and deep nesting before building (a
    # 327-byte billion-laughs expands to gigabytes).
    try:
        return yaml_document(read_text(path, MAX_YAML_BYTES))
    except (OSError, UnicodeDecodeError, DocumentError, yaml.YAMLError) as error:
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise SettingsError(f"{path}: not a readable {what} ({reason})") from None


def read_kalibr_cameras(path: Path) -> list[RigCamera]:
    """The cameras of a Kalibr ``cameras.yaml`` (``cam0``, ``cam1``, ...).

    Raises:
        SettingsError: unreadable, or a camera without usable intrinsics; naming the file.
    """
    document = _load(path, "Kalibr cameras.yaml")
    if not isinstance(document, dict) or not document:
        raise SettingsError(f"{path}: not a Kalibr cameras.yaml (no cam0, cam1, ...)")
    cameras = []
    for name, entry in document.items():
        if not isinstance(entry, dict):
            raise SettingsError(f"{path}: {name} is not a camera")
        try:
            camera = Camera.from_kalibr(entry, f"{path}: {name}")
        except ValueError as error:
            raise SettingsError(str(error)) from None
        cameras.append(RigCamera(str(name), camera, entry.get("rostopic"), entry.get("tagtopic")))
    return cameras


def _pose(entry: Any, where: str) -> Pose3:
    try:
        position = [float(entry["position"][k]) for k in "xyz"]
        rotation = [float(entry["rotation"][k]) for k in "xyz"]
    except (KeyError, TypeError, ValueError) as error:
        raise SettingsError(f"{where}: not a pose with position and rotation ({error})") from None
    if not np.all(np.isfinite([*position, *rotation])):
        raise SettingsError(f"{where}: a pose with a non-finite value")
    R, _ = cv2.Rodrigues(np.array(rotation))
    return Pose3(np.asarray(R, dtype=np.float64), np.array(position))


def read_camera_poses(path: Path) -> dict[str, Pose3]:
    """TagSLAM's ``camera_poses.yaml``: camera name -> ``T_rig_camera`` (the camera's optical
    frame on the rig).

    Raises:
        SettingsError: unreadable, or a camera without a pose; naming the file.
    """
    document = _load(path, "TagSLAM camera_poses.yaml")
    if not isinstance(document, dict):
        raise SettingsError(f"{path}: not a TagSLAM camera_poses.yaml")
    return {
        str(name): _pose(entry.get("pose") if isinstance(entry, dict) else None, f"{path}: {name}")
        for name, entry in document.items()
    }


@dataclass(frozen=True)
class TagslamConfig:
    """What markergraph takes from a ``tagslam.yaml``.

    Attributes:
        default_tag_size_m: the static body's default tag size [m], if given.
        tag_sizes_m: tag id -> size [m] where the file gives one.
        T_rig_odom: the odometry's body on the rig (TagSLAM's ``T_body_odom`` of the rig body
            that names the odometry topic), if given.
        odom_topic: that odometry topic.
    """

    default_tag_size_m: float | None
    tag_sizes_m: dict[int, float]
    T_rig_odom: Pose3 | None
    odom_topic: str | None


def _board_sizes(body: dict[str, Any], where: str) -> dict[int, float]:
    """The tag sizes of a board body (``board`` or ``staggered_board``): ``tag_rows`` x
    ``tag_columns`` ids from ``tag_start_id``, each ``tag_size`` on a side."""
    board = body.get("board") or body.get("staggered_board")
    if not isinstance(board, dict) or board.get("tag_size") is None:
        return {}
    try:
        start, size = int(board["tag_start_id"]), float(board["tag_size"])
        count = int(board.get("tag_rows", 1)) * int(board.get("tag_columns", 1))
    except (KeyError, TypeError, ValueError) as error:
        raise SettingsError(f"{where}: a board without a readable layout ({error})") from None
    if not (0 < size < 100 and start >= 0 and 0 < count <= 10_000):
        raise SettingsError(f"{where}: a board of {count} tags of {size} m from id {start}")
    return {start + k: size for k in range(count)}


def read_tagslam(path: Path) -> TagslamConfig:
    """Tag sizes and the rig's odometry body from a TagSLAM ``tagslam.yaml``.

    Raises:
        SettingsError: unreadable, or a malformed body; naming the file.
    """
    document = _load(path, "TagSLAM tagslam.yaml")
    bodies = document.get("bodies") if isinstance(document, dict) else None
    if not isinstance(bodies, list):
        raise SettingsError(f"{path}: not a tagslam.yaml (no bodies list)")
    default_size, sizes, T_rig_odom, odom_topic = None, {}, None, None
    for item in bodies:
        for name, body in (item or {}).items():
            if not isinstance(body, dict):
                raise SettingsError(f"{path}: body {name} is not a table")
            if body.get("is_static") and body.get("default_tag_size") is not None:
                default_size = default_size or float(body["default_tag_size"])
            for tag in body.get("tags") or []:
                if isinstance(tag, dict) and "id" in tag and tag.get("size") is not None:
                    sizes[int(tag["id"])] = float(tag["size"])
            sizes.update(_board_sizes(body, f"{path}: {name}"))
            if body.get("odom_topic"):
                odom_topic = str(body["odom_topic"])
                if body.get("T_body_odom") is not None:
                    T_rig_odom = _pose(body["T_body_odom"], f"{path}: {name}.T_body_odom")
    return TagslamConfig(default_size, sizes, T_rig_odom, odom_topic)


def load_yaml(path: Path, what: str) -> Any:
    """A YAML file's document (``what`` names the kind of file in the error).

    Raises:
        SettingsError: unreadable or not YAML; one line naming the file.
    """
    return _load(path, what)


def tagslam_pose(entry: Any, where: str) -> Pose3:
    """A TagSLAM pose (``position`` x, y, z [m], ``rotation`` x, y, z a rotation vector [rad]).

    Raises:
        SettingsError: not such a pose, or a non-finite value; naming ``where``.
    """
    return _pose(entry, where)
