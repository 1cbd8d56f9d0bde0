"""Decoding the messages a log's roles carry: stamps, frames, images, depth and odometry."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from markergraph.estimator.types import OdometrySample
from markergraph.frontend.logs.records import LogError, Message
from markergraph.frontend.ros2 import yaw_from_quaternion

__all__ = ["decode_depth", "decode_image", "frame_id", "odometry_sample", "stamp_ns"]


def stamp_ns(decoded: Any) -> int:
    """A message's capture stamp in nanoseconds: a ROS header's, or a Foxglove ``timestamp``."""
    if hasattr(decoded, "header"):
        stamp = decoded.header.stamp
        return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
    return int(decoded.timestamp.seconds) * 1_000_000_000 + int(decoded.timestamp.nanos)


def frame_id(decoded: Any) -> str:
    """The frame a message is in: a ROS header's, or a Foxglove ``frame_id``."""
    return str(decoded.header.frame_id if hasattr(decoded, "header") else decoded.frame_id)


def decode_image(message: Message) -> NDArray[np.uint8]:
    """A grey image from ``sensor_msgs/msg/Image`` (rgb8, bgr8, mono8) or ``CompressedImage``."""
    msg = message.decoded
    if "CompressedImage" in message.schema:
        if len(msg.data) == 0:
            raise LogError(f"{message.topic}: an empty compressed image")
        try:
            image = cv2.imdecode(np.frombuffer(msg.data, np.uint8), cv2.IMREAD_GRAYSCALE)
        except cv2.error:  # OpenCV raises on some damaged streams, returns None on others
            image = None
        if image is None:
            raise LogError(
                f"{message.topic}: a compressed image OpenCV cannot decode (format {msg.format!r})"
            )
        return np.asarray(image, dtype=np.uint8)
    encoding = msg.encoding.lower()
    channels = {"rgb8": 3, "bgr8": 3, "mono8": 1, "8uc1": 1, "rgba8": 4, "bgra8": 4}.get(encoding)
    if channels is None:
        raise LogError(
            f"{message.topic}: unsupported image encoding {msg.encoding!r} (rgb8, bgr8, mono8 are)"
        )
    data = np.frombuffer(msg.data, np.uint8)
    if msg.height == 0 or msg.width == 0:
        raise LogError(f"{message.topic}: an empty image")
    if data.size < msg.step * msg.height or msg.step < msg.width * channels:
        raise LogError(f"{message.topic}: image data shorter than height x step")
    rows = data[: msg.step * msg.height].reshape(msg.height, msg.step)
    pixels = rows[:, : msg.width * channels].reshape(msg.height, msg.width, channels)
    if channels == 1:
        return np.ascontiguousarray(pixels[..., 0])
    code = {
        "rgb8": cv2.COLOR_RGB2GRAY,
        "bgr8": cv2.COLOR_BGR2GRAY,
        "rgba8": cv2.COLOR_RGBA2GRAY,
        "bgra8": cv2.COLOR_BGRA2GRAY,
    }[encoding]
    return np.asarray(cv2.cvtColor(np.ascontiguousarray(pixels), code), dtype=np.uint8)


def decode_depth(message: Message) -> NDArray:
    """Aligned depth: 16UC1 in millimetres or 32FC1 in metres (``Image``), or a
    ``compressedDepth`` ``CompressedImage`` (12-byte header, then a 16-bit PNG)."""
    msg = message.decoded
    if "CompressedImage" in message.schema:
        if len(msg.data) <= 12:
            raise LogError(f"{message.topic}: an empty compressedDepth image")
        try:
            depth = cv2.imdecode(
                np.frombuffer(bytes(msg.data[12:]), np.uint8), cv2.IMREAD_UNCHANGED
            )
        except cv2.error:
            depth = None
        if depth is None or depth.dtype != np.uint16:
            raise LogError(f"{message.topic}: compressedDepth that is not a 16-bit PNG")
        return depth
    encoding = msg.encoding.upper()
    dtype: np.dtype[Any]
    if encoding in ("16UC1", "MONO16"):
        dtype = np.dtype(np.uint16)
    elif encoding == "32FC1":
        dtype = np.dtype(np.float32)
    else:
        raise LogError(
            f"{message.topic}: unsupported depth encoding {msg.encoding!r} (16UC1 and 32FC1 "
            "are; is it a colour topic?)"
        )
    dtype = dtype.newbyteorder(">" if getattr(msg, "is_bigendian", 0) else "<")
    data = np.frombuffer(msg.data, np.uint8)
    if msg.height == 0 or msg.width == 0:
        raise LogError(f"{message.topic}: an empty depth image")
    if data.size < msg.step * msg.height or msg.step < msg.width * dtype.itemsize:
        raise LogError(f"{message.topic}: depth data shorter than height x step")
    rows = data[: msg.step * msg.height].reshape(msg.height, msg.step)
    width_bytes = int(msg.width) * dtype.itemsize
    return np.ascontiguousarray(rows[:, :width_bytes]).view(dtype).reshape(msg.height, msg.width)


def odometry_sample(message: Message) -> OdometrySample:
    """``T_odom_base`` from ``nav_msgs/msg/Odometry`` or a Foxglove ``PoseInFrame``."""
    pose = message.decoded.pose
    pose = pose.pose if hasattr(pose, "pose") else pose
    q = pose.orientation
    return OdometrySample(
        stamp_ns(message.decoded),
        float(pose.position.x),
        float(pose.position.y),
        yaw_from_quaternion(q.x, q.y, q.z, q.w),
    )
