"""Simulated runs as ROS 2 bags in MCAP: the topics realsense-ros 4.x and a diff-drive base publish,
plus ground truth, readable by ``mcap`` with ``mcap-ros2-support`` and no ROS installed.

Topics (header stamps are capture times; MCAP log times add a fixed transport latency):

- ``/camera/camera/color/image_raw``: ``sensor_msgs/msg/Image``, rgb8; or, compressed,
  ``/camera/camera/color/image_raw/compressed``: ``sensor_msgs/msg/CompressedImage``, JPEG
- ``/camera/camera/aligned_depth_to_color/image_raw``: ``sensor_msgs/msg/Image``, 16UC1 in mm
- ``/camera/camera/color/camera_info`` and ``.../aligned_depth_to_color/camera_info``
- ``/odom``: ``nav_msgs/msg/Odometry`` and ``/tf``: odom -> base_link, at the odometry rate
- ``/tf_static``: base_link -> camera_link -> camera_color_optical_frame
- ``/ground_truth/pose``: ``geometry_msgs/msg/PoseStamped``, the true base pose in ``map``
- ``/ground_truth/markers``: ``tf2_msgs/msg/TFMessage``, map -> ``aruco_<id>`` for each marker
- ``/ground_truth/world``: ``std_msgs/msg/String``, the world as JSON

The map frame is the home marker's frame, as everywhere in markergraph.
"""

from __future__ import annotations

import functools
import math
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import gtsam
import numpy as np
from mcap.writer import CompressionType
from numpy.typing import NDArray

from markergraph.common.files import written_whole
from markergraph.datasets.bag import Bag
from markergraph.datasets.capture import capture, draw_capture_noise
from markergraph.datasets.render import RenderedFrame, Renderer
from markergraph.datasets.route import Drive, Route, WheelErrors, drive
from markergraph.datasets.sensors import SensorEffects
from markergraph.datasets.simulate import SIMULATED_MOUNT
from markergraph.datasets.world import World
from markergraph.estimator.trajectory import Trajectory
from markergraph.frontend.camera import Camera, CameraMount
from markergraph.frontend.ros2 import (
    header,
    quaternion_from_matrix,
    quaternion_from_yaw,
    transform_stamped,
)
from markergraph.frontend.topics import TRUE_MARKERS, TRUE_POSE, TRUE_WORLD

__all__ = ["LogSummary", "Topics", "write_log"]

IMAGE_LATENCY_NS = 30_000_000  # capture to recording, for the MCAP log time
ODOMETRY_LATENCY_NS = 2_000_000


@dataclass(frozen=True)
class Topics:
    """Topic names; realsense-ros 4.x defaults."""

    color: str = "/camera/camera/color/image_raw"
    color_compressed: str = "/camera/camera/color/image_raw/compressed"
    depth: str = "/camera/camera/aligned_depth_to_color/image_raw"
    color_info: str = "/camera/camera/color/camera_info"
    depth_info: str = "/camera/camera/aligned_depth_to_color/camera_info"
    odom: str = "/odom"
    tf: str = "/tf"
    tf_static: str = "/tf_static"
    true_pose: str = TRUE_POSE
    true_markers: str = TRUE_MARKERS
    world: str = TRUE_WORLD


OPTICAL_FRAME = "camera_color_optical_frame"
BASE_FOOTPRINT = "base_footprint"
BASE_LINK_HEIGHT_M = 0.1  # base_link above base_footprint, with the realsense TF tree
COLOR_OFFSET_M = 0.015  # the colour imager left of camera_link's origin


@dataclass
class LogSummary:
    """What was written.

    Attributes:
        path: the log.
        frames: camera frames written.
        messages: topic -> number of messages.
        bytes: the file's size.
    """

    path: Path
    frames: int
    messages: dict[str, int] = field(default_factory=dict)
    bytes: int = 0


def _camera_info(t_ns: int, camera: Camera) -> dict[str, object]:
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    return {
        "header": header(t_ns, OPTICAL_FRAME),
        "height": camera.height,
        "width": camera.width,
        "distortion_model": "plumb_bob",
        "d": list(camera.distortion) or [0.0] * 5,
        "k": [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
        "r": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        "p": [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
        "binning_x": 0,
        "binning_y": 0,
        "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False},
    }


def _pose(x: float, y: float, yaw: float) -> dict[str, object]:
    return {"position": {"x": x, "y": y, "z": 0.0}, "orientation": quaternion_from_yaw(yaw)}


def write_log(
    world: World,
    route: Route,
    out: Path,
    seed: int,
    *,
    duration_s: float | None = None,
    compressed: bool = False,
    frame_hz: float = 15.0,
    odometry_hz: float = 50.0,
    camera: Camera = Camera(),
    mount: CameraMount = SIMULATED_MOUNT,
    wheel: WheelErrors = WheelErrors(),
    topics: Topics = Topics(),
    sensors: SensorEffects = SensorEffects(),
    progress: Callable[[int, int], None] | None = None,
) -> LogSummary:
    """Drive a route, render every frame, and write the run as a ROS 2 MCAP bag.

    The file appears whole or not at all (``files.written_whole``). The same arguments give the
    same bytes.

    Args:
        compressed: JPEG colour on ``.../compressed`` instead of raw rgb8 (depth stays raw).
        sensors: the camera's and base's departures from ideal (see :mod:`.sensors`).
        progress: called with (frames done, frames in all).
    """
    rng = np.random.default_rng(seed)
    motion = drive(
        world,
        route,
        rng,
        wheel=wheel,
        frame_hz=frame_hz,
        odometry_hz=odometry_hz,
        duration_s=duration_s,
    )
    if sensors.distortion:
        camera = replace(camera, distortion=tuple(sensors.distortion))
    renderer = Renderer(world, camera, mount, texture_seed=seed)
    out = Path(out)
    T_map_world = world.T_world_marker(world.home_id).inverse()
    # zstd shrinks raw depth 4x (JPEG not at all) for a fifth of the writing speed.
    with (
        written_whole(out) as partial,
        open(partial, "wb") as stream,
        Bag(stream, CompressionType.ZSTD) as bag,
    ):
        start = int(min(motion.odometry_t_ns[0], motion.frame_t_ns[0]))
        _write_static(bag, world, mount, topics, start, T_map_world, sensors)
        _write_stream(
            _Recording(
                bag, motion, renderer, camera, topics, T_map_world, compressed, sensors, rng,
                progress,
            )
        )  # fmt: skip
    return LogSummary(out, len(motion.frame_t_ns), dict(bag.counts), out.stat().st_size)


def _write_static(
    bag: Bag,
    world: World,
    mount: CameraMount,
    topics: Topics,
    t_ns: int,
    T_map_world: gtsam.Pose2,
    sensors: SensorEffects,
) -> None:
    """The camera mount, the true marker poses and the world, once at the start."""
    R_base_link = mount.R_base_optical @ np.array(
        [[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]
    )  # camera_link: x forward, z up
    pitch_yaw = quaternion_from_matrix(R_base_link)
    optical_in_link = quaternion_from_matrix(
        np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    )
    level = quaternion_from_yaw(0.0)
    position = (mount.x_m, mount.y_m, mount.height_m)
    if sensors.realsense_tf_tree:
        link_m = (
            np.array(position)
            - R_base_link @ np.array([0.0, COLOR_OFFSET_M, 0.0])
            - np.array([0.0, 0.0, BASE_LINK_HEIGHT_M])
        )
        # realsense-ros and a diff-drive base: the camera's centre on camera_link, the colour
        # imager 15 mm to its left, base_link above the footprint.
        chain = [
            transform_stamped(t_ns, BASE_FOOTPRINT, "base_link", (0.0, 0.0, BASE_LINK_HEIGHT_M),
                              level),
            transform_stamped(t_ns, "base_link", "camera_link", tuple(link_m), pitch_yaw),
            transform_stamped(t_ns, "camera_link", "camera_color_frame", (0.0, COLOR_OFFSET_M, 0.0),
                              level),
            transform_stamped(t_ns, "camera_color_frame", OPTICAL_FRAME, (0.0, 0.0, 0.0),
                              optical_in_link),
        ]  # fmt: skip
    else:
        chain = [
            transform_stamped(t_ns, "base_link", "camera_link", position, pitch_yaw),
            transform_stamped(t_ns, "camera_link", OPTICAL_FRAME, (0.0, 0.0, 0.0), optical_in_link),
        ]
    bag.write(topics.tf_static, "tf2_msgs/msg/TFMessage", {"transforms": chain}, t_ns, t_ns)
    markers = []
    for marker in world.markers:
        T = T_map_world.compose(world.T_world_marker(marker.id))
        markers.append(
            transform_stamped(
                t_ns,
                "map",
                f"aruco_{marker.id}",
                (T.x(), T.y(), marker.height_m),
                quaternion_from_yaw(T.theta()),
            )
        )
    bag.write(topics.true_markers, "tf2_msgs/msg/TFMessage", {"transforms": markers}, t_ns, t_ns)
    bag.write(topics.world, "std_msgs/msg/String", {"data": world.to_json()}, t_ns, t_ns)


@dataclass(frozen=True, slots=True)
class _Recording:
    """What writing the stream of a log works from."""

    bag: Bag
    """The log being written."""
    motion: Drive
    """The drive: odometry and frame times, odometry and true poses."""
    renderer: Renderer
    """Renders the camera's frames."""
    camera: Camera
    """The camera's intrinsics (distortion included)."""
    topics: Topics
    """Topic names."""
    T_map_world: gtsam.Pose2
    """The world in the map (home marker's) frame, for the ground truth."""
    compressed: bool
    """JPEG colour on ``.../compressed`` instead of raw rgb8."""
    sensors: SensorEffects
    """The camera's and base's departures from ideal."""
    rng: np.random.Generator
    """The run's random stream (exposure, rendering noise)."""
    progress: Callable[[int, int], None] | None
    """Called with (frames done, frames in all), or None."""


@dataclass(frozen=True, slots=True)
class _Stamps:
    """The stamps the sensors put on their messages, and the frames they drop."""

    odometry: NDArray[np.int64]
    """(N,) each odometry sample's header stamp, jittered [ns]."""
    frames: NDArray[np.int64]
    """(M,) each camera frame's header stamp, late and jittered [ns]."""
    dropped: NDArray[np.bool_]
    """(M,) whether each frame is dropped."""


def _stamps(motion: Drive, sensors: SensorEffects, rng: np.random.Generator) -> _Stamps:
    """The sensors' stamps and dropped frames, drawn from a stream of their own so ideal logs
    stay as they were."""
    odometry_t, frame_t = motion.odometry_t_ns, motion.frame_t_ns
    sensor_rng = np.random.default_rng([int(rng.integers(2**31)), 7])
    odometry_stamps = odometry_t + np.rint(
        sensor_rng.normal(0.0, sensors.odometry_jitter_s * 1e9, len(odometry_t))
    ).astype(np.int64)
    frame_stamps = frame_t + np.rint(
        (sensors.camera_latency_s + sensor_rng.normal(0.0, sensors.stamp_jitter_s, len(frame_t)))
        * 1e9
    ).astype(np.int64)
    dropped = sensor_rng.random(len(frame_t)) < sensors.dropped_frames
    return _Stamps(odometry_stamps, frame_stamps, dropped)


def _write_stream(rec: _Recording) -> None:
    """Odometry, tf, ground truth and camera frames, in the order they would be recorded.

    Frames render in a pool of threads (:data:`RENDER_THREADS`; NumPy and OpenCV release the
    GIL over whole images) while the messages before them wait here; each frame's noise is
    drawn here in log order, so the bytes are the same whichever thread renders it."""
    waiting = _Waiting(rec, len(rec.motion.frame_t_ns))
    with ThreadPoolExecutor(RENDER_THREADS, thread_name_prefix="markergraph-render") as pool:
        try:
            _send_in_order(rec, waiting, pool)
        except BaseException:
            pool.shutdown(cancel_futures=True)  # frames not started yet are not rendered
            raise
        waiting.write(flush=True)
    if rec.progress is not None:  # the last frames may have been dropped, not rendered
        rec.progress(waiting.frames, waiting.frames)


def _send_in_order(rec: _Recording, waiting: _Waiting, pool: ThreadPoolExecutor) -> None:
    """Each message to ``waiting`` in log order, each frame's rendering to ``pool`` with the
    noise drawn for it."""
    motion = rec.motion
    odometry_t, frame_t = motion.odometry_t_ns, motion.frame_t_ns
    stamps = _stamps(motion, rec.sensors, rec.rng)
    truth = Trajectory(odometry_t, motion.odometry_truth, "world")
    i = j = 0
    exposure = 1.0
    while i < len(odometry_t) or j < len(frame_t):
        next_odometry = odometry_t[i] + ODOMETRY_LATENCY_NS if i < len(odometry_t) else math.inf
        next_frame = stamps.frames[j] + IMAGE_LATENCY_NS if j < len(frame_t) else math.inf
        if next_odometry <= next_frame:
            odometry = functools.partial(
                _write_odometry, rec, i, int(stamps.odometry[i]), int(next_odometry)
            )
            waiting.add(odometry)
            i += 1
            continue
        exposure = float(
            np.clip(exposure + rec.rng.normal(0.0, rec.renderer.effects.exposure_sigma), 0.8, 1.2)
        )
        if not stamps.dropped[j]:
            noise = draw_capture_noise(rec.renderer, rec.sensors, rec.rng)
            frame = pool.submit(
                capture, rec.renderer, truth, int(frame_t[j]), rec.sensors, noise, exposure
            )
            waiting.add(_Rendering(frame, int(stamps.frames[j]), int(next_frame), j + 1))
        j += 1


# Frames rendering at once: two threads rendered the corridor's frames 1.4-1.55x as fast as one
# (2 cores); more only hold more images (the bag's thread and this one share the same cores).
# Two at once hold more memory: 315 MB at the peak against 223 MB for an office D435i log, raw
# colour at 30 Hz (17 renders a frame for its rolling shutter).
RENDER_THREADS = 2
RENDERING_AHEAD = 2 * RENDER_THREADS


@dataclass(frozen=True, slots=True)
class _Rendering:
    """A frame being rendered, with where it goes in the log."""

    frame: Future[RenderedFrame]
    t_ns: int
    """Its header stamp [ns]."""
    log_time: int
    """Its log time [ns]."""
    number: int
    """Its number among the route's frames, from 1 (for progress)."""


class _Waiting:
    """Messages waiting to be written in log order: odometry (written as soon as it is at the
    front) and frames being rendered (written once rendered, or waited for once
    :data:`RENDERING_AHEAD` are)."""

    def __init__(self, rec: _Recording, frames: int) -> None:
        self.rec, self.frames = rec, frames
        self.queue: deque[Callable[[], None] | _Rendering] = deque()
        self.rendering = 0

    def add(self, item: Callable[[], None] | _Rendering) -> None:
        self.queue.append(item)
        self.rendering += isinstance(item, _Rendering)
        self.write()

    def write(self, flush: bool = False) -> None:
        """What is at the front and ready; everything with ``flush``."""
        rec = self.rec
        while self.queue:
            item = self.queue[0]
            if not isinstance(item, _Rendering):
                item()
            elif flush or item.frame.done() or self.rendering > RENDERING_AHEAD:
                _write_frame(rec, item.frame.result(), item.t_ns, item.log_time)
                self.rendering -= 1
                if rec.progress is not None:
                    rec.progress(item.number, self.frames)
            else:
                return
            self.queue.popleft()


def _write_odometry(rec: _Recording, i: int, t_ns: int, log_time: int) -> None:
    """Odometry sample ``i`` on the odometry topic and /tf at its (jittered) stamp ``t_ns``,
    and the true pose at its true time."""
    bag, topics = rec.bag, rec.topics
    base = BASE_FOOTPRINT if rec.sensors.realsense_tf_tree else "base_link"
    x, y, yaw = rec.motion.odometry[i]
    bag.write(
        topics.odom,
        "nav_msgs/msg/Odometry",
        {
            "header": header(t_ns, "odom"),
            "child_frame_id": base,
            "pose": {"pose": _pose(x, y, yaw), "covariance": [0.0] * 36},
            "twist": {
                "twist": {
                    "linear": {"x": 0.0, "y": 0.0, "z": 0.0},
                    "angular": {"x": 0.0, "y": 0.0, "z": 0.0},
                },
                "covariance": [0.0] * 36,
            },
        },
        t_ns,
        log_time,
    )
    bag.write(
        topics.tf,
        "tf2_msgs/msg/TFMessage",
        {
            "transforms": [
                transform_stamped(t_ns, "odom", base, (x, y, 0.0), quaternion_from_yaw(yaw))
            ]
        },
        t_ns,
        log_time,
    )
    t_ns = int(rec.motion.odometry_t_ns[i])  # the truth at its true time
    T_map_base = rec.T_map_world.compose(gtsam.Pose2(*rec.motion.odometry_truth[i]))
    bag.write(
        topics.true_pose,
        "geometry_msgs/msg/PoseStamped",
        {
            "header": header(t_ns, "map"),
            "pose": _pose(T_map_base.x(), T_map_base.y(), T_map_base.theta()),
        },
        t_ns,
        log_time,
    )


def _write_frame(rec: _Recording, frame: RenderedFrame, t_ns: int, log_time: int) -> None:
    """A camera frame: colour (raw or JPEG), depth and both camera infos."""
    bag, topics, camera = rec.bag, rec.topics, rec.camera
    if rec.compressed:
        # Encoded in the bag's thread, beside the next frame's rendering.
        jpeg = functools.partial(_jpeg_message, frame.rgb, t_ns)
        bag.write(topics.color_compressed, "sensor_msgs/msg/CompressedImage", jpeg, t_ns, log_time)
    else:
        color = _image(t_ns, camera, "rgb8", 3, frame.rgb.tobytes())
        bag.write(topics.color, "sensor_msgs/msg/Image", color, t_ns, log_time)
    depth = _image(t_ns, camera, "16UC1", 2, frame.depth_mm.tobytes())
    bag.write(topics.depth, "sensor_msgs/msg/Image", depth, t_ns, log_time)
    info = "sensor_msgs/msg/CameraInfo"
    bag.write(topics.color_info, info, _camera_info(t_ns, camera), t_ns, log_time)
    bag.write(topics.depth_info, info, _camera_info(t_ns, camera), t_ns, log_time)


def _jpeg_message(rgb: NDArray[np.uint8], t_ns: int) -> dict[str, object]:
    """A ``sensor_msgs/msg/CompressedImage`` of an RGB image, JPEG at quality 90."""
    ok, jpeg = cv2.imencode(
        ".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 90]
    )
    if not ok:
        raise RuntimeError(f"JPEG encoding failed for the frame at t_ns={t_ns}")
    return {
        "header": header(t_ns, OPTICAL_FRAME),
        "format": "rgb8; jpeg compressed bgr8",
        "data": jpeg.tobytes(),
    }


def _image(
    t_ns: int, camera: Camera, encoding: str, bytes_per_pixel: int, data: bytes
) -> dict[str, object]:
    """A ``sensor_msgs/msg/Image`` in the optical frame."""
    return {
        "header": header(t_ns, OPTICAL_FRAME),
        "height": camera.height,
        "width": camera.width,
        "encoding": encoding,
        "is_bigendian": 0,
        "step": bytes_per_pixel * camera.width,
        "data": data,
    }
