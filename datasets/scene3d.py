"""A seeded 3-D world for the 3-D tag map: a rig of one to four cameras carried through a room,
a corridor or in front of a board, among AprilTags at any pose, and the log a real rig records
there (ROS 2 MCAP, readable with no ROS installed) with its truth beside it.

Frames: the world has z up; the rig (``base_link``) has x forward, y left, z up; each camera's
optical frame has x right, y down, z forward; a tag's frame is the AprilTag / OpenCV one (z out
of the print toward whoever can see it, corners in OpenCV's order, see
:func:`~markergraph.estimator.tags3d.tag_corners`). Poses are ``T_a_b`` (frame b in frame a).

Topics written (header stamps are the frames' capture times; MCAP log times add a latency):

- ``/<cam>/tags``: ``apriltag_msgs/msg/AprilTagDetectionArray`` (corners in AprilTag order,
  OpenCV's reversed), one message per frame and camera, empty where it sees no tag
- ``/<cam>/camera_info``: ``sensor_msgs/msg/CameraInfo`` (plumb_bob, rational_polynomial or
  equidistant)
- ``/tf_static``: ``base_link`` -> ``<cam>_optical_frame`` (with ``mounts=Mounts.TF_STATIC``)
- ``/odom``: ``nav_msgs/msg/Odometry``, odom -> base_link with drift (with ``odometry=True``)
- ``/ground_truth/tags``: ``tf2_msgs/msg/TFMessage``, world -> ``tag_<id>``
- ``/ground_truth/rig``: ``geometry_msgs/msg/PoseStamped``, the rig in the world at each frame
- ``/ground_truth/world3d``: ``std_msgs/msg/String``, the whole :class:`Scene3dTruth` as JSON

Tags are not occluded by one another or by the walls (the rooms are convex), only by the boards
they are not printed on.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any

import cv2
import gtsam
import numpy as np
import yaml
from numpy.typing import NDArray

from markergraph.common.errors import MarkerGraphError
from markergraph.common.files import written_whole
from markergraph.datasets.bag import Bag
from markergraph.estimator.tags3d import KnownTag, SceneCamera, TagScene, TagView, tag_corners
from markergraph.frontend.camera import EQUIDISTANT, Camera, CameraMount
from markergraph.frontend.logs import open_log
from markergraph.frontend.ros2 import header, quaternion_from_matrix
from markergraph.frontend.tag_scene import ray_per_px, seed_poses

__all__ = [
    "CAMERA_PRESETS",
    "OUTLIER_PX",
    "TRUE_RIG3D",
    "TRUE_TAGS3D",
    "TRUE_WORLD3D",
    "Board",
    "Mounts",
    "OdometryDrift",
    "Scene3dError",
    "Scene3dTruth",
    "SceneKind",
    "SimulatedCamera",
    "TagDetection3d",
    "Visibility3d",
    "detections",
    "make_scene3d",
    "odometry3d",
    "read_scene3d_truth",
    "tag_scene",
    "write_rig_files",
    "write_scene3d_log",
]

TRUE_TAGS3D = "/ground_truth/tags"
TRUE_RIG3D = "/ground_truth/rig"
TRUE_WORLD3D = "/ground_truth/world3d"
RIG_FRAME = "base_link"
WORLD_FRAME = "world"
START_NS = 1_700_000_000 * 10**9  # a plausible epoch for the first frame
CAMERA_LATENCY_NS = 30_000_000  # capture to recording, for the MCAP log time
ODOMETRY_LATENCY_NS = 2_000_000
DETECTION_SCHEMA = "apriltag_msgs/msg/AprilTagDetectionArray"
JSON_VERSION = 1


class Scene3dError(MarkerGraphError, ValueError):
    """A log or JSON text that holds no readable 3-D scene; the message names it."""


class SceneKind(str, Enum):
    """The kinds of world :func:`make_scene3d` builds."""

    ROOM = "room"
    """A box room: tags on the four walls at different heights, on the floor and ceiling, and
    on a tilted board; the rig walks a loop looking around."""
    BOARD = "board"
    """One tilted board of tags; a handheld rig moves in an arc in front of it."""
    CORRIDOR = "corridor"
    """A long corridor: tags on both long walls, the end walls, floor and ceiling; the rig
    walks to the far end and back."""


class Mounts(str, Enum):
    """Where a log gives the cameras' mounts on the rig."""

    TF_STATIC = "tf_static"
    """``/tf_static``: base_link -> each camera's optical frame."""
    NONE = "none"
    """Nowhere: the mounts are to be estimated, or read from ``camera_poses.yaml``."""


@dataclass(frozen=True, slots=True)
class SimulatedCamera:
    """One camera of the simulated rig.

    Attributes:
        name: its name (``cam0``): topics ``/<name>/tags`` and ``/<name>/camera_info``, optical
            frame ``<name>_optical_frame``.
        camera: its intrinsics and lens model.
        T_rig_camera: its optical frame on the rig.
    """

    name: str
    camera: Camera
    T_rig_camera: gtsam.Pose3

    @property
    def frame_id(self) -> str:
        """Its optical frame's name in the log."""
        return f"{self.name}_optical_frame"


@dataclass(frozen=True, slots=True)
class Board:
    """A flat board in the world: it carries tags and hides what is behind it.

    Attributes:
        T_world_board: its centre, in a frame like a tag's (z out of the face with the tags).
        width_m, height_m: its size along its x and y [m].
    """

    T_world_board: gtsam.Pose3
    width_m: float
    height_m: float


@dataclass(frozen=True, slots=True)
class Scene3dTruth:
    """A simulated world and the rig's path through it.

    Attributes:
        kind: the kind of world (a :class:`SceneKind` value).
        seed: the seed it was made from.
        tags: tag id -> ``T_world_tag`` (the tag frame: z out of the print).
        tag_sizes: tag id -> the side of its black square [m].
        surfaces: tag id -> what it is on: ``wall``, ``floor``, ``ceiling`` or ``board``.
        cameras: the rig's cameras.
        frame_times: (n,) each frame's capture time [ns], ascending; every camera takes a
            picture at each.
        T_world_rig: (n,) the rig's pose at each frame (roll and pitch not zero).
        boards: the boards (they hide tags behind them).
        extent_m: the room's size along the world's x, y, z [m] (origin at a floor corner).
    """

    kind: str
    seed: int
    tags: dict[int, gtsam.Pose3]
    tag_sizes: dict[int, float]
    surfaces: dict[int, str]
    cameras: tuple[SimulatedCamera, ...]
    frame_times: NDArray[np.int64]
    T_world_rig: tuple[gtsam.Pose3, ...]
    boards: tuple[Board, ...] = ()
    extent_m: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def T_world_camera(self, frame: int, camera: int) -> gtsam.Pose3:
        """Camera ``camera``'s optical frame in the world at frame ``frame``."""
        return self.T_world_rig[frame].compose(self.cameras[camera].T_rig_camera)

    def to_json(self) -> str:
        """The whole truth as JSON (poses as 3x3 rotation and translation; exact floats)."""
        document = {
            "version": JSON_VERSION,
            "kind": self.kind,
            "seed": self.seed,
            "extent_m": list(self.extent_m),
            "tags": [
                {
                    "id": i,
                    "size_m": self.tag_sizes[i],
                    "surface": self.surfaces[i],
                    "T_world_tag": _pose_json(T),
                }
                for i, T in sorted(self.tags.items())
            ],
            "cameras": [_camera_json(c) for c in self.cameras],
            "boards": [
                {
                    "T_world_board": _pose_json(b.T_world_board),
                    "width_m": b.width_m,
                    "height_m": b.height_m,
                }
                for b in self.boards
            ],
            "frame_times_ns": [int(t) for t in self.frame_times],
            "T_world_rig": [_pose_json(T) for T in self.T_world_rig],
        }
        return json.dumps(document)

    @classmethod
    def from_json(cls, text: str, source: str = "JSON") -> Scene3dTruth:
        """The truth :meth:`to_json` wrote.

        Raises:
            Scene3dError: not such a document; the message names ``source``.
        """
        try:
            d = json.loads(text)
            if d.get("version") != JSON_VERSION:
                raise ValueError(f"version {d.get('version')!r}, not {JSON_VERSION}")
            tags = {int(t["id"]): t for t in d["tags"]}
            return cls(
                kind=str(d["kind"]),
                seed=int(d["seed"]),
                tags={i: _pose_of(t["T_world_tag"]) for i, t in tags.items()},
                tag_sizes={i: float(t["size_m"]) for i, t in tags.items()},
                surfaces={i: str(t["surface"]) for i, t in tags.items()},
                cameras=tuple(_camera_of(c) for c in d["cameras"]),
                frame_times=np.array(d["frame_times_ns"], dtype=np.int64),
                T_world_rig=tuple(_pose_of(T) for T in d["T_world_rig"]),
                boards=tuple(
                    Board(_pose_of(b["T_world_board"]), float(b["width_m"]), float(b["height_m"]))
                    for b in d["boards"]
                ),
                extent_m=tuple(float(v) for v in d["extent_m"]),  # type: ignore[arg-type]
            )
        except (ValueError, KeyError, TypeError, AttributeError) as error:
            raise Scene3dError(f"{source}: not a 3-D scene's truth ({error})") from None


def _pose_json(T: gtsam.Pose3) -> dict[str, list[float]]:
    return {"R": T.rotation().matrix().tolist(), "t": np.asarray(T.translation()).tolist()}


def _pose_of(d: dict[str, Any]) -> gtsam.Pose3:
    return gtsam.Pose3(gtsam.Rot3(np.array(d["R"], dtype=np.float64)), np.array(d["t"], float))


def _camera_json(c: SimulatedCamera) -> dict[str, Any]:
    k = c.camera
    intrinsics = [k.fx, k.fy, k.cx, k.cy, k.width, k.height]
    return {
        "name": c.name,
        "model": k.model,
        "intrinsics": intrinsics,
        "distortion": list(k.distortion),
        "T_rig_camera": _pose_json(c.T_rig_camera),
    }


def _camera_of(d: dict[str, Any]) -> SimulatedCamera:
    fx, fy, cx, cy, width, height = d["intrinsics"]
    camera = Camera(
        float(fx),
        float(fy),
        float(cx),
        float(cy),
        int(width),
        int(height),
        tuple(float(v) for v in d["distortion"]),
        str(d["model"]),
    )
    return SimulatedCamera(str(d["name"]), camera, _pose_of(d["T_rig_camera"]))


# --- the rig's cameras -------------------------------------------------------------------------


def _mount(
    x: float, y: float, z: float, yaw_deg: float, pitch_deg: float, roll_deg: float
) -> gtsam.Pose3:
    """``T_rig_camera`` of an optical frame turned ``yaw`` left, pitched up, rolled."""
    mount = CameraMount(
        x, y, z, math.radians(yaw_deg), math.radians(pitch_deg), math.radians(roll_deg)
    )
    return gtsam.Pose3(gtsam.Rot3(mount.R_base_optical), mount.t_base_optical)


CAMERA_PRESETS: tuple[SimulatedCamera, ...] = (
    # A 640x480 pinhole with mild barrel distortion, forward, tilted down and rolled a little.
    SimulatedCamera(
        "cam0",
        Camera(420.0, 421.0, 322.5, 238.0, 640, 480, (-0.12, 0.03, 0.0004, -0.0002, 0.0)),
        _mount(0.05, 0.0, 0.0, 0.0, -6.0, 2.0),
    ),
    # A T265-like equidistant fisheye, turned 70 deg left and up.
    SimulatedCamera(
        "cam1",
        Camera(
            286.7, 286.8, 420.9, 396.9, 848, 800, (-0.0067, 0.0393, -0.0356, 0.0055), EQUIDISTANT
        ),
        _mount(0.03, 0.06, 0.02, 70.0, 10.0, 0.0),
    ),
    # A 1280x720 camera with OpenCV's rational polynomial, turned 70 deg right.
    SimulatedCamera(
        "cam2",
        Camera(
            640.0,
            640.0,
            641.0,
            359.0,
            1280,
            720,
            (0.3, 0.05, 0.0003, -0.0002, 0.0, 0.35, 0.06, 0.0),
        ),
        _mount(0.03, -0.06, 0.02, -70.0, 0.0, -3.0),
    ),
    # An ideal pinhole (no distortion), looking back and up.
    SimulatedCamera(
        "cam3",
        Camera(500.0, 500.0, 320.0, 240.0, 640, 480),
        _mount(-0.05, 0.0, 0.05, 180.0, 15.0, 0.0),
    ),
)
"""The cameras :func:`make_scene3d` mounts, in order: ``cameras=n`` takes the first n."""


# --- worlds -----------------------------------------------------------------------------------

_UP = np.array([0.0, 0.0, 1.0])
Extent = tuple[float, float, float]  # a room's size along x, y, z [m]


def _facing(normal: NDArray[np.float64], x_hint: NDArray[np.float64]) -> NDArray[np.float64]:
    """R_world_tag of a tag whose z is ``normal`` and x as near ``x_hint`` as it can be."""
    z = normal / np.linalg.norm(normal)
    x = x_hint - (x_hint @ z) * z
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def _upright(normal: NDArray[np.float64]) -> NDArray[np.float64]:
    """R_world_tag of a tag printed upright on a surface facing ``normal`` (not vertical)."""
    return _facing(normal, np.cross(_UP, normal))


def _jitter(
    R: NDArray[np.float64], rng: np.random.Generator, spin_rad: float, tilt_rad: float
) -> NDArray[np.float64]:
    """R turned about its own z by up to ``spin_rad`` and tilted off its plane by ``tilt_rad``."""
    spin = gtsam.Rot3.Rz(float(rng.uniform(-spin_rad, spin_rad)))
    about_x, about_y = (float(a) for a in rng.uniform(-tilt_rad, tilt_rad, 2))
    tilt = gtsam.Rot3.RzRyRx(about_x, about_y, 0.0)
    return (gtsam.Rot3(R) * tilt * spin).matrix()


@dataclass
class _World:
    """Tags placed so far (id order)."""

    tags: dict[int, gtsam.Pose3]
    sizes: dict[int, float]
    surfaces: dict[int, str]
    boards: list[Board]

    def add(self, R: NDArray[np.float64], p: NDArray[np.float64], size: float, on: str) -> None:
        tag_id = len(self.tags)
        self.tags[tag_id] = gtsam.Pose3(gtsam.Rot3(R), np.asarray(p, dtype=np.float64))
        self.sizes[tag_id], self.surfaces[tag_id] = size, on


def _walls(
    extent: Extent,
) -> list[tuple[NDArray[np.float64], NDArray[np.float64], float]]:
    """Each wall of a box room: (its inward normal, a point at its floor's left end as seen
    from inside, its length along the tag's x)."""
    W, D, _ = extent
    return [
        (np.array([0.0, 1.0, 0.0]), np.array([W, 0.0, 0.0]), W),  # south wall, y = 0
        (np.array([-1.0, 0.0, 0.0]), np.array([W, D, 0.0]), D),  # east wall, x = W
        (np.array([0.0, -1.0, 0.0]), np.array([0.0, D, 0.0]), W),  # north wall, y = D
        (np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 0.0]), D),  # west wall, x = 0
    ]


def _wall_tags(
    world: _World, extent: Extent, n: int, size: float, rng: np.random.Generator
) -> None:
    """``n`` upright tags spread along the walls' perimeter at heights 0.5 .. 2.3 m."""
    walls = _walls(extent)
    perimeter = sum(length for _, _, length in walls)
    along = (np.arange(n) + rng.uniform(0.3, 0.7, n)) * perimeter / n
    ends = np.cumsum([length for _, _, length in walls])
    for s in along:
        k = min(int(np.searchsorted(ends, s, side="right")), len(walls) - 1)
        normal, start, length = walls[k]
        s = float(np.clip(s - (ends[k] - length), 0.4, length - 0.4))
        R = _upright(normal)
        p = start + s * R[:, 0] + _UP * rng.uniform(0.5, min(2.3, extent[2] - 0.4))
        world.add(_jitter(R, rng, math.radians(8.0), math.radians(2.0)), p, size, "wall")


def _flat_tags(
    world: _World, extent: Extent, n: int, size: float, ceiling: bool, rng: np.random.Generator
) -> None:
    """``n`` tags on the floor (or ceiling) away from the walls, each turned any way."""
    W, D, H = extent
    normal = -_UP if ceiling else _UP
    for _ in range(n):
        yaw = rng.uniform(-math.pi, math.pi)
        R = _facing(normal, np.array([math.cos(yaw), math.sin(yaw), 0.0]))
        p = np.array([rng.uniform(0.8, W - 0.8), rng.uniform(0.8, D - 0.8), H if ceiling else 0.0])
        world.add(R, p, size, "ceiling" if ceiling else "floor")


def _board(
    world: _World,
    centre: tuple[float, float, float],
    facing_yaw: float,
    lean_deg: float,
    n: int,
    size: float,
) -> None:
    """A board at ``centre`` facing ``facing_yaw``, leaning back ``lean_deg``, with ``n`` tags
    in a grid of two rows (its size follows from the tags)."""
    lean = math.radians(lean_deg)
    horizontal = np.array([math.cos(facing_yaw), math.sin(facing_yaw), 0.0])
    R = _upright(math.cos(lean) * horizontal + math.sin(lean) * _UP)
    columns = max(1, math.ceil(n / 2))
    rows = 1 if n == 1 else 2
    pitch = 1.6 * size
    board = Board(
        gtsam.Pose3(gtsam.Rot3(R), np.asarray(centre, float)), columns * pitch, rows * pitch
    )
    world.boards.append(board)
    for k in range(n):
        u = (k % columns - (columns - 1) / 2.0) * pitch
        v = ((rows - 1) / 2.0 - k // columns) * pitch
        world.add(
            R, np.asarray(centre) + u * R[:, 0] + v * R[:, 1] + 0.001 * R[:, 2], size, "board"
        )


def _room_world(n_tags: int, size: float, rng: np.random.Generator) -> tuple[_World, Extent]:
    extent = (8.0, 6.0, 3.0)
    world = _World({}, {}, {}, [])
    n_board = 4
    n_flat = max(2, (n_tags - n_board) // 6)
    n_wall = max(4, n_tags - n_board - 2 * n_flat)
    _wall_tags(world, extent, n_wall, size, rng)
    _flat_tags(world, extent, n_flat, 1.25 * size, False, rng)
    _flat_tags(world, extent, n_flat, 1.25 * size, True, rng)
    # A board in a corner, facing the room's centre, leaning back 35 deg.
    _board(world, (1.2, 1.2, 1.0), math.atan2(1.8, 2.8), 35.0, n_board, 0.7 * size)
    return world, extent


def _corridor_world(n_tags: int, size: float, rng: np.random.Generator) -> tuple[_World, Extent]:
    extent = (14.0, 2.4, 2.8)
    world = _World({}, {}, {}, [])
    n_flat = max(2, n_tags // 8)
    _wall_tags(world, extent, max(4, n_tags - 2 * n_flat), size, rng)
    _flat_tags(world, extent, n_flat, size, False, rng)
    _flat_tags(world, extent, n_flat, size, True, rng)
    return world, extent


def _board_world(n_tags: int, size: float) -> tuple[_World, Extent]:
    world = _World({}, {}, {}, [])
    _board(world, (0.0, 0.0, 1.0), -math.pi / 2.0, 20.0, n_tags, 0.6 * size)
    return world, (0.0, 0.0, 0.0)


# --- the rig's path ---------------------------------------------------------------------------


def _wobble(
    t_s: NDArray[np.float64], rng: np.random.Generator, periods_s: Sequence[float]
) -> NDArray[np.float64]:
    """A smooth seeded wobble of unit size: sines of the given periods at random phases."""
    out = np.zeros_like(t_s)
    for period in periods_s:
        out += np.sin(2.0 * math.pi * t_s / period + rng.uniform(0.0, 2.0 * math.pi))
    return out / len(periods_s)


def _attitude(yaw: float, pitch: float, roll: float) -> gtsam.Rot3:
    """R_world_rig of a rig turned ``yaw`` left, pitched ``pitch`` up, rolled ``roll``."""
    return gtsam.Rot3.Rz(yaw) * gtsam.Rot3.Ry(-pitch) * gtsam.Rot3.Rx(roll)


def _path(
    kind: SceneKind, extent: Extent, t_s: NDArray[np.float64], rng: np.random.Generator
) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """Positions (n, 3), the heading the rig's look-around swings about (n,) and the
    look-around's amplitude [rad]."""
    duration = float(t_s[-1] - t_s[0]) or 1.0
    phase = 2.0 * math.pi * (t_s - t_s[0]) / duration
    W, D, _ = extent
    if kind is SceneKind.ROOM:
        a, b = 0.28 * W, 0.28 * D
        wobble = 0.25 * _wobble(t_s, rng, (6.0, 11.0))
        xy = np.column_stack(
            [W / 2 + (a + wobble) * np.cos(phase), D / 2 + (b + wobble) * np.sin(phase)]
        )
        heading = phase + math.pi / 2.0
        return np.column_stack([xy, 1.4 + 0.1 * _wobble(t_s, rng, (5.0, 9.0))]), heading, 1.2
    if kind is SceneKind.CORRIDOR:
        there = np.minimum(phase, 2.0 * math.pi - phase) / math.pi  # 0 -> 1 -> 0
        x = 1.5 + (W - 3.0) * there
        y = D / 2 + 0.3 * _wobble(t_s, rng, (4.0, 7.0))
        heading = np.where(phase < math.pi, 0.0, math.pi)
        z = 1.4 + 0.1 * _wobble(t_s, rng, (5.0, 9.0))
        return np.column_stack([x, y, z]), heading, 1.1
    # A board at the origin facing -y: an arc in front of it at 0.7 .. 1.6 m.
    bearing = -math.pi / 2.0 + 0.9 * np.sin(phase)
    r = 1.15 + 0.45 * _wobble(t_s, rng, (7.0, 13.0))
    xyz = np.column_stack(
        [r * np.cos(bearing), r * np.sin(bearing), 1.0 + 0.3 * _wobble(t_s, rng, (6.0, 10.0))]
    )
    return xyz, bearing + math.pi, 0.2


def _rig_poses(
    kind: SceneKind, extent: Extent, t_s: NDArray[np.float64], rng: np.random.Generator
) -> tuple[gtsam.Pose3, ...]:
    """The rig's path: along :func:`_path`, looking around, pitched and rolled as in a hand."""
    xyz, heading, swing = _path(kind, extent, t_s, rng)
    yaw = heading + swing * _wobble(t_s, rng, (7.0, 12.0)) * 1.6
    pitch = 0.35 * _wobble(t_s, rng, (6.0, 9.5))
    roll = 0.12 * _wobble(t_s, rng, (4.0, 8.0)) + 0.05
    if kind is SceneKind.BOARD:
        pitch = pitch * 0.5 - 0.05
    return tuple(
        gtsam.Pose3(_attitude(float(y), float(p), float(r)), np.asarray(x, dtype=np.float64))
        for x, y, p, r in zip(xyz, yaw, pitch, roll, strict=True)
    )


_DEFAULT_TAGS = {SceneKind.ROOM: 30, SceneKind.CORRIDOR: 40, SceneKind.BOARD: 12}


def make_scene3d(
    seed: int,
    *,
    cameras: int = 1,
    tags: int | None = None,
    kind: SceneKind | str = SceneKind.ROOM,
    frames: int = 300,
    frame_hz: float = 10.0,
    tag_size_m: float = 0.16,
) -> Scene3dTruth:
    """A seeded world and the rig's path through it.

    Args:
        seed: the same seed gives the same world and path.
        cameras: how many of :data:`CAMERA_PRESETS` the rig carries (1-4).
        tags: how many tags (a room's: on the walls, a sixth of the rest on the floor and as
            many on the ceiling, four on a tilted board); None: 30, or 12 on a board.
        kind: a :class:`SceneKind` (or its value).
        frames: the rig's frames (all cameras take a picture at each).
        frame_hz: their rate [Hz].
        tag_size_m: a wall tag's side [m]; floor and ceiling tags are 1.25 times that, a
            room's board tags 0.7 times, a board's 0.6 times.

    Raises:
        ValueError: an argument out of range.
    """
    kind = SceneKind(kind)
    n_tags = _DEFAULT_TAGS[kind] if tags is None else int(tags)
    if not 1 <= cameras <= len(CAMERA_PRESETS):
        raise ValueError(f"cameras={cameras}: the rig carries 1 to {len(CAMERA_PRESETS)}")
    if n_tags < (1 if kind is SceneKind.BOARD else 12) or frames < 2 or frame_hz <= 0:
        raise ValueError(f"tags={tags}, frames={frames}, frame_hz={frame_hz}: too few or none")
    if not 0.01 <= tag_size_m <= 2.0:
        raise ValueError(f"tag_size_m={tag_size_m}: not a tag's size in metres")
    rng = np.random.default_rng([seed, 3])
    if kind is SceneKind.ROOM:
        world, extent = _room_world(n_tags, tag_size_m, rng)
    elif kind is SceneKind.CORRIDOR:
        world, extent = _corridor_world(n_tags, tag_size_m, rng)
    else:
        world, extent = _board_world(n_tags, tag_size_m)
    period_ns = round(1e9 / frame_hz)
    frame_times: NDArray[np.int64] = START_NS + period_ns * np.arange(frames, dtype=np.int64)
    t_s = (frame_times - START_NS) / 1e9
    return Scene3dTruth(
        kind=kind.value,
        seed=int(seed),
        tags=world.tags,
        tag_sizes=world.sizes,
        surfaces=world.surfaces,
        cameras=CAMERA_PRESETS[:cameras],
        frame_times=frame_times,
        T_world_rig=_rig_poses(kind, extent, t_s, rng),
        boards=tuple(world.boards),
        extent_m=extent,
    )


# --- detections -------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Visibility3d:
    """When a camera detects a tag.

    Attributes:
        max_view_angle_rad: the tag's normal within this of the line of sight to the camera.
        min_side_px: every side of the tag's image at least this long [px].
        margin_px: every corner at least this far inside the image [px].
        min_depth_m: every corner at least this far in front of the camera [m].
    """

    max_view_angle_rad: float = math.radians(75.0)
    min_side_px: float = 15.0
    margin_px: float = 1.0
    min_depth_m: float = 0.1


@dataclass(frozen=True, slots=True)
class TagDetection3d:
    """One tag detected by one camera in one frame.

    Attributes:
        frame: the frame's index in :attr:`Scene3dTruth.frame_times`.
        camera: the camera's index in :attr:`Scene3dTruth.cameras`.
        tag_id: the tag's id.
        corners_px: (4, 2) its corners as detected (with pixel noise), in OpenCV's order.
        true_corners_px: (4, 2) the same without noise.
        outlier: one corner was moved by a gross error (see :func:`detections`).
    """

    frame: int
    camera: int
    tag_id: int
    corners_px: NDArray[np.float64]
    true_corners_px: NDArray[np.float64]
    outlier: bool = False


def _hidden(board: Board, c: NDArray[np.float64], p: NDArray[np.float64]) -> NDArray[np.bool_]:
    """(N,) whether the segment from the camera's centre ``c`` (3,) to each point ``p``
    (N, 3) crosses the board (strictly between the two)."""
    T = board.T_world_board
    R, o = T.rotation().matrix(), np.asarray(T.translation())
    c_b, p_b = R.T @ (c - o), (p - o) @ R
    with np.errstate(divide="ignore", invalid="ignore"):
        s = c_b[2] / (c_b[2] - p_b[:, 2])  # where the segment meets the board's plane
    crossing = (s > 1e-6) & (s < 1.0 - 1e-3)
    hit = c_b + s[:, None] * (p_b - c_b)
    inside = (np.abs(hit[:, 0]) <= board.width_m / 2) & (np.abs(hit[:, 1]) <= board.height_m / 2)
    return crossing & inside


def _world_corners(truth: Scene3dTruth) -> tuple[list[int], NDArray[np.float64]]:
    """Tag ids and their corners (T, 4, 3) in the world, in OpenCV's order."""
    ids = sorted(truth.tags)
    corners = np.array(
        [
            (truth.tags[i].rotation().matrix() @ tag_corners(truth.tag_sizes[i]).T).T
            + np.asarray(truth.tags[i].translation())
            for i in ids
        ]
    )
    return ids, corners


def _seen(
    truth: Scene3dTruth,
    frame: int,
    camera: int,
    corners_w: NDArray[np.float64],
    visibility: Visibility3d,
) -> tuple[NDArray[np.bool_], NDArray[np.float64]]:
    """(T,) which tags camera ``camera`` detects at frame ``frame``, and their true pixels
    (T, 4, 2) (NaN where not detected)."""
    sim = truth.cameras[camera]
    T_wc = truth.T_world_camera(frame, camera)
    R_wc, c = T_wc.rotation().matrix(), np.asarray(T_wc.translation())
    p_cam = (corners_w - c) @ R_wc  # (T, 4, 3)
    normals = np.array([truth.tags[i].rotation().matrix()[:, 2] for i in sorted(truth.tags)])
    to_camera = c - corners_w.mean(axis=1)
    cos_view = np.sum(normals * to_camera, axis=1) / np.linalg.norm(to_camera, axis=1)
    ok = np.all(p_cam[:, :, 2] > visibility.min_depth_m, axis=1)
    ok &= cos_view > math.cos(visibility.max_view_angle_rad)
    pixels = np.full((*p_cam.shape[:2], 2), np.nan)
    if not ok.any():
        return ok, pixels
    rays = p_cam[ok, :, :2] / p_cam[ok, :, 2:]
    flat = rays.reshape(-1, 2)
    projected = sim.camera.distort(flat)
    # A lens model folds rays far outside its view back into the image: such a pixel does
    # not undistort to the ray it came from.
    back = sim.camera.rays(projected)
    folded = np.linalg.norm(back - flat, axis=1) > 1e-4 * (1.0 + np.linalg.norm(flat, axis=1))
    projected[folded] = np.nan
    pixels[ok] = projected.reshape(-1, 4, 2)
    k, m = sim.camera, visibility.margin_px
    with np.errstate(invalid="ignore"):
        inside = (pixels[..., 0] >= m) & (pixels[..., 0] <= k.width - 1 - m)
        inside &= (pixels[..., 1] >= m) & (pixels[..., 1] <= k.height - 1 - m)
        sides = np.linalg.norm(pixels - np.roll(pixels, -1, axis=1), axis=2)
        ok &= np.all(inside, axis=1) & (np.min(sides, axis=1) > visibility.min_side_px)
    for board in truth.boards:
        candidates = np.flatnonzero(ok)
        hidden = _hidden(board, c, corners_w[candidates].reshape(-1, 3)).reshape(-1, 4)
        ok[candidates[np.any(hidden, axis=1)]] = False
    pixels[~ok] = np.nan
    return ok, pixels


OUTLIER_PX = (5.0, 20.0)  # the range of an outlier's gross corner error [px]


def detections(
    truth: Scene3dTruth,
    seed: int,
    pixel_noise_px: float = 0.5,
    *,
    outliers: float = 0.0,
    visibility: Visibility3d = Visibility3d(),
) -> list[TagDetection3d]:
    """Every tag each camera detects in each frame: its corners through the camera's lens
    model, with Gaussian pixel noise of ``pixel_noise_px`` on each coordinate; sorted by frame,
    camera, tag id. Which tags are detected does not depend on the noise.

    Args:
        outliers: the fraction of detections with one corner moved by a gross error (a
            uniform :data:`OUTLIER_PX` in a random direction, as a corner caught on the wrong
            edge), drawn from a stream of their own (the rest stay as without outliers).

    Raises:
        ValueError: a negative noise, or a fraction outside [0, 1].
    """
    if not pixel_noise_px >= 0.0 or not 0.0 <= outliers <= 1.0:
        raise ValueError(f"pixel_noise_px={pixel_noise_px}, outliers={outliers}: out of range")
    rng, gross = np.random.default_rng([seed, 5]), np.random.default_rng([seed, 6])
    ids, corners_w = _world_corners(truth)
    found = []
    for frame in range(len(truth.frame_times)):
        for camera in range(len(truth.cameras)):
            ok, pixels = _seen(truth, frame, camera, corners_w, visibility)
            for k in np.flatnonzero(ok):
                noisy = pixels[k] + rng.normal(0.0, pixel_noise_px, (4, 2))
                outlier = bool(gross.random() < outliers)
                if outlier:
                    angle, size = gross.uniform(0.0, 2.0 * math.pi), gross.uniform(*OUTLIER_PX)
                    noisy[gross.integers(4)] += size * np.array([math.cos(angle), math.sin(angle)])
                found.append(
                    TagDetection3d(frame, camera, ids[k], noisy, pixels[k].copy(), outlier)
                )
    return found


# --- odometry ---------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class OdometryDrift:
    """How the simulated odometry drifts: each frame-to-frame motion is perturbed by noise
    whose sigmas grow with the motion.

    Attributes:
        translation_per_m: translation sigma per metre moved.
        rotation_per_rad: rotation sigma per radian turned [rad/rad].
        translation_floor_m, rotation_floor_rad: sigmas of a frame without motion.
    """

    translation_per_m: float = 0.02
    rotation_per_rad: float = 0.02
    translation_floor_m: float = 0.0005
    rotation_floor_rad: float = 0.0005


def odometry3d(
    truth: Scene3dTruth, seed: int, drift: OdometryDrift = OdometryDrift()
) -> list[gtsam.Pose3]:
    """``T_odom_rig`` at each frame: the true motion between frames with seeded noise,
    integrated from the identity at the first frame."""
    rng = np.random.default_rng([seed, 11])
    poses = [gtsam.Pose3()]
    for previous, current in zip(truth.T_world_rig[:-1], truth.T_world_rig[1:], strict=True):
        step = previous.between(current)
        moved = float(np.linalg.norm(step.translation()))
        turned = float(np.linalg.norm(gtsam.Rot3.Logmap(step.rotation())))
        sigma_rot = drift.rotation_floor_rad + drift.rotation_per_rad * turned
        sigma_t = drift.translation_floor_m + drift.translation_per_m * moved
        noise = np.concatenate([rng.normal(0, sigma_rot, 3), rng.normal(0, sigma_t, 3)])
        poses.append(poses[-1].compose(step.compose(gtsam.Pose3.Expmap(noise))))
    return poses


# --- the estimator's input, straight from the simulation ---------------------------------------


def tag_scene(
    truth: Scene3dTruth,
    found: Sequence[TagDetection3d],
    *,
    pixel_noise_px: float = 0.5,
    odometry: Sequence[gtsam.Pose3] | None = None,
    mounts_for: Sequence[str] | None = None,
    surveyed: Sequence[int] = (),
    survey_sigmas: tuple[float, float] = (0.001, 0.001),
    home_id: int | None = None,
) -> TagScene:
    """The 3-D estimator's input from simulated detections, without a log in between: each
    detection's corners undistorted to rays, with a PnP seed.

    Args:
        found: :func:`detections`' output.
        pixel_noise_px: the noise they were made with (each ray's sigma is it over fx).
        odometry: ``T_odom_rig`` per frame (:func:`odometry3d`), or None for none.
        mounts_for: the cameras whose true mounts are given (None: all; the others' are
            unknown).
        surveyed: tags given as known, at their true pose in the world (the map frame is then
            the world's), with ``survey_sigmas`` = (rotation [rad], translation [m]).
        home_id: the tag that fixes the map's frame (None: the first tag seen).

    Raises:
        ValueError: a camera name or tag id the scene does not have.
    """
    names = [c.name for c in truth.cameras]
    given = set(names if mounts_for is None else mounts_for)
    unknown = [n for n in given if n not in names] + [i for i in surveyed if i not in truth.tags]
    if unknown:
        raise ValueError(f"not in the scene: {unknown} (cameras {names})")
    cameras = [
        SceneCamera(
            c.name,
            f"/{c.name}/tags",
            c.T_rig_camera if c.name in given else None,
            None,
        )
        for c in truth.cameras
    ]
    views = []
    for d in found:
        camera = truth.cameras[d.camera].camera
        rays = camera.rays(d.corners_px)
        seeds = seed_poses(rays, truth.tag_sizes[d.tag_id])
        if seeds is not None:
            per_px = ray_per_px(camera, d.corners_px)
            sigma = pixel_noise_px * per_px
            views.append(TagView(d.frame, d.camera, d.tag_id, rays, sigma, per_px, *seeds))
    seen = {d.tag_id for d in found}
    sigmas: NDArray[np.float64] = np.repeat(np.array(survey_sigmas, dtype=np.float64), 3)
    return TagScene(
        frame_times=truth.frame_times.copy(),
        views=views,
        cameras=cameras,
        tag_sizes={i: s for i, s in truth.tag_sizes.items() if i in seen},
        odometry=list(odometry) if odometry is not None else [],
        known_tags=[KnownTag(i, truth.tags[i], sigmas.copy()) for i in surveyed],
        home_id=home_id,
    )


# --- the log ----------------------------------------------------------------------------------


def _transform(t_ns: int, parent: str, child: str, T: gtsam.Pose3) -> dict[str, Any]:
    return {
        "header": header(t_ns, parent),
        "child_frame_id": child,
        "transform": {
            "translation": dict(zip("xyz", map(float, T.translation()), strict=True)),
            "rotation": quaternion_from_matrix(T.rotation().matrix()),
        },
    }


def _pose_message(T: gtsam.Pose3) -> dict[str, Any]:
    return {
        "position": dict(zip("xyz", map(float, T.translation()), strict=True)),
        "orientation": quaternion_from_matrix(T.rotation().matrix()),
    }


def _info_model_name(camera: Camera) -> str:
    """The CameraInfo ``distortion_model`` of a camera."""
    if camera.model == EQUIDISTANT:
        return "equidistant"
    return "rational_polynomial" if len(camera.distortion) == 8 else "plumb_bob"


def _camera_info(t_ns: int, sim: SimulatedCamera) -> dict[str, Any]:
    k = sim.camera
    return {
        "header": header(t_ns, sim.frame_id),
        "height": k.height,
        "width": k.width,
        "distortion_model": _info_model_name(k),
        "d": list(k.distortion) or [0.0] * 5,
        "k": [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0],
        "r": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        "p": [k.fx, 0.0, k.cx, 0.0, 0.0, k.fy, k.cy, 0.0, 0.0, 0.0, 1.0, 0.0],
        "binning_x": 0,
        "binning_y": 0,
        "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False},
    }


def _centre(corners: NDArray[np.float64]) -> tuple[float, float]:
    """Where the tag's diagonals cross (as the AprilTag library reports its centre)."""
    a, c = corners[0], corners[2]
    b, d = corners[1], corners[3]
    M = np.column_stack([c - a, b - d])
    try:
        s = np.linalg.solve(M, b - a)[0]
    except np.linalg.LinAlgError:
        return float(corners[:, 0].mean()), float(corners[:, 1].mean())
    p = a + s * (c - a)
    return float(p[0]), float(p[1])


def _detection_array(t_ns: int, frame_id: str, found: list[TagDetection3d]) -> dict[str, Any]:
    """apriltag_ros's message: corners in the AprilTag library's order (OpenCV's reversed)."""
    tags = []
    for d in found:
        cx, cy = _centre(d.corners_px)
        tags.append(
            {
                "family": "tag36h11",
                "id": d.tag_id,
                "hamming": 0,
                "goodness": 0.0,
                "decision_margin": 50.0,
                "centre": {"x": cx, "y": cy},
                "corners": [{"x": float(u), "y": float(v)} for u, v in d.corners_px[::-1]],
                "homography": [0.0] * 9,
            }
        )
    return {"header": header(t_ns, frame_id), "detections": tags}


def _odometry_message(t_ns: int, T_odom_rig: gtsam.Pose3) -> dict[str, Any]:
    zero = {"x": 0.0, "y": 0.0, "z": 0.0}
    return {
        "header": header(t_ns, "odom"),
        "child_frame_id": RIG_FRAME,
        "pose": {"pose": _pose_message(T_odom_rig), "covariance": [0.0] * 36},
        "twist": {"twist": {"linear": zero, "angular": zero}, "covariance": [0.0] * 36},
    }


def _write_static(bag: Bag, truth: Scene3dTruth, mounts: Mounts) -> None:
    """The mounts, the true tags and the whole truth, once at the start."""
    t0 = int(truth.frame_times[0])
    if mounts is Mounts.TF_STATIC:
        chain = [_transform(t0, RIG_FRAME, c.frame_id, c.T_rig_camera) for c in truth.cameras]
        bag.write("/tf_static", "tf2_msgs/msg/TFMessage", {"transforms": chain}, t0, t0)
    tags = [_transform(t0, WORLD_FRAME, f"tag_{i}", T) for i, T in sorted(truth.tags.items())]
    bag.write(TRUE_TAGS3D, "tf2_msgs/msg/TFMessage", {"transforms": tags}, t0, t0)
    bag.write(TRUE_WORLD3D, "std_msgs/msg/String", {"data": truth.to_json()}, t0, t0)


def write_scene3d_log(
    truth: Scene3dTruth,
    path: Path | str,
    seed: int,
    *,
    odometry: bool = False,
    mounts: Mounts | str = Mounts.TF_STATIC,
    pixel_noise_px: float = 0.5,
    outliers: float = 0.0,
    drift: OdometryDrift = OdometryDrift(),
    visibility: Visibility3d = Visibility3d(),
) -> list[TagDetection3d]:
    """The log the simulated rig records, as a ROS 2 MCAP file (whole or not at all).

    Args:
        truth: the world and path (:func:`make_scene3d`).
        path: the file to write.
        seed: seeds the detections' noise and the odometry's drift; the same arguments give
            the same bytes.
        odometry: write ``/odom`` (:func:`odometry3d`) at each frame's time.
        mounts: where the cameras' mounts are given (:class:`Mounts`).
        pixel_noise_px, outliers, visibility: as in :func:`detections`.

    Returns:
        The detections written (corners in OpenCV's order).
    """
    mounts = Mounts(mounts)
    found = detections(truth, seed, pixel_noise_px, outliers=outliers, visibility=visibility)
    by_view: dict[tuple[int, int], list[TagDetection3d]] = {}
    for d in found:
        by_view.setdefault((d.frame, d.camera), []).append(d)
    odom = odometry3d(truth, seed, drift) if odometry else None
    path = Path(path)
    with written_whole(path) as partial, open(partial, "wb") as stream, Bag(stream) as bag:
        _write_static(bag, truth, mounts)
        for frame, t in enumerate(truth.frame_times):
            t_ns = int(t)
            if odom is not None:
                message = _odometry_message(t_ns, odom[frame])
                bag.write(
                    "/odom", "nav_msgs/msg/Odometry", message, t_ns, t_ns + ODOMETRY_LATENCY_NS
                )
            rig = {
                "header": header(t_ns, WORLD_FRAME),
                "pose": _pose_message(truth.T_world_rig[frame]),
            }
            bag.write(TRUE_RIG3D, "geometry_msgs/msg/PoseStamped", rig, t_ns, t_ns)
            for k, sim in enumerate(truth.cameras):
                log_ns = t_ns + CAMERA_LATENCY_NS
                info = _camera_info(t_ns, sim)
                bag.write(
                    f"/{sim.name}/camera_info", "sensor_msgs/msg/CameraInfo", info, t_ns, log_ns
                )
                array = _detection_array(t_ns, sim.frame_id, by_view.get((frame, k), []))
                bag.write(f"/{sim.name}/tags", DETECTION_SCHEMA, array, t_ns, log_ns)
    return found


def read_scene3d_truth(path: Path | str) -> Scene3dTruth:
    """The truth a :func:`write_scene3d_log` log carries on ``/ground_truth/world3d``.

    Raises:
        Scene3dError: the log has no such topic, or its text is not a scene's truth.
    """
    log = open_log(Path(path))
    if TRUE_WORLD3D not in {t.topic for t in log.topics}:
        raise Scene3dError(f"{path}: no {TRUE_WORLD3D} topic (not a simulated 3-D log)")
    for message in log.messages([TRUE_WORLD3D]):
        return Scene3dTruth.from_json(message.decoded.data, f"{path}: {TRUE_WORLD3D}")
    raise Scene3dError(f"{path}: {TRUE_WORLD3D} holds no message")


# --- rig files --------------------------------------------------------------------------------


def _kalibr_model(camera: Camera) -> str:
    if camera.model == EQUIDISTANT:
        return "equidistant"
    n = len(camera.distortion)
    return "radtan" if n in (0, 4) else ("rational_polynomial" if n == 8 else "plumb_bob")


def _rotation_vector(R: NDArray[np.float64]) -> dict[str, float]:
    rvec, _ = cv2.Rodrigues(np.asarray(R, dtype=np.float64))
    return dict(zip("xyz", map(float, rvec.ravel()), strict=True))


def _tagslam_pose(T: gtsam.Pose3, sigmas: tuple[float, float] | None = None) -> dict[str, Any]:
    pose: dict[str, Any] = {
        "position": dict(zip("xyz", map(float, T.translation()), strict=True)),
        "rotation": _rotation_vector(T.rotation().matrix()),
    }
    if sigmas is not None:
        pose["position_noise"] = dict.fromkeys("xyz", sigmas[0])
        pose["rotation_noise"] = dict.fromkeys("xyz", sigmas[1])
    return pose


def write_rig_files(
    truth: Scene3dTruth,
    folder: Path | str,
    mounts_for: Sequence[str] | None = None,
    *,
    surveyed: Sequence[int] = (),
    survey_sigmas: tuple[float, float] = (0.001, 0.001),
) -> dict[str, Path]:
    """The rig's calibration files as Kalibr and TagSLAM write them, each whole or not at all:
    ``cameras.yaml`` (every camera: intrinsics, lens, resolution, ``rostopic`` and
    ``tagtopic``), ``camera_poses.yaml`` (the mounts of the cameras named in ``mounts_for``;
    None: all) and ``tagslam.yaml`` (every tag's size; the poses of the ``surveyed`` tags in the
    world frame with ``survey_sigmas`` = (position [m], rotation [rad])).

    Returns:
        File name -> path written.

    Raises:
        ValueError: a name in ``mounts_for`` or an id in ``surveyed`` the scene does not have.
    """
    names = [c.name for c in truth.cameras]
    chosen = names if mounts_for is None else list(mounts_for)
    unknown = [n for n in chosen if n not in names] + [i for i in surveyed if i not in truth.tags]
    if unknown:
        raise ValueError(f"not in the scene: {unknown} (cameras {names})")
    cameras = {
        c.name: {
            "camera_model": "pinhole",
            "intrinsics": [c.camera.fx, c.camera.fy, c.camera.cx, c.camera.cy],
            "distortion_model": _kalibr_model(c.camera),
            "distortion_coeffs": list(c.camera.distortion) or [0.0, 0.0, 0.0, 0.0],
            "resolution": [c.camera.width, c.camera.height],
            "rostopic": f"/{c.name}/image_raw",
            "tagtopic": f"/{c.name}/tags",
            "rig_body": "rig",
        }
        for c in truth.cameras
    }
    poses = {
        c.name: {"pose": _tagslam_pose(c.T_rig_camera)} for c in truth.cameras if c.name in chosen
    }
    sizes = list(truth.tag_sizes.values())
    tags = []
    for i in sorted(truth.tags):
        entry: dict[str, Any] = {"id": i, "size": truth.tag_sizes[i]}
        if i in surveyed:
            entry["pose"] = _tagslam_pose(truth.tags[i], survey_sigmas)
        tags.append(entry)
    static = {
        "is_static": True,
        "default_tag_size": max(set(sizes), key=sizes.count),
        "pose": _tagslam_pose(gtsam.Pose3(), (1e-4, 1e-5)),
        "type": "simple",
        "tags": tags,
    }
    rig = {"is_static": False, "type": "simple", "ignore_tags": []}
    documents = {
        "cameras.yaml": cameras,
        "camera_poses.yaml": poses,
        "tagslam.yaml": {"bodies": [{"world": static}, {"rig": rig}]},
    }
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    written = {}
    for name, document in documents.items():
        with written_whole(folder / name) as partial:
            Path(partial).write_text(yaml.safe_dump(document, sort_keys=False), encoding="utf-8")
        written[name] = folder / name
    return written
