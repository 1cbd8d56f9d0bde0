"""Decoding the messages a log's roles carry: stamps, frames, images, depth and odometry."""

from __future__ import annotations

import struct
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from markergraph.estimator.types import OdometrySample
from markergraph.frontend._opencv import MAX_IMAGE_PIXELS
from markergraph.frontend.logs.records import LogError, Message
from markergraph.frontend.ros2 import yaw_from_quaternion

__all__ = [
    "MAX_IMAGE_PIXELS",
    "MAX_IMAGE_SIDE_PX",
    "MAX_SIZE_OVER_CAMERA",
    "declared_size",
    "decode_depth",
    "decode_image",
    "frame_id",
    "odometry_sample",
    "stamp_ns",
]

# A header that claims more than MAX_IMAGE_PIXELS (8192 x 8192), or more than this a side, is a
# decompression bomb (a 875 KB PNG can claim 30,000 x 30,000): refused before OpenCV allocates it.
MAX_IMAGE_SIDE_PX = 16384
# A frame wider or taller than its camera_info by more than this is not that camera's: the
# margin lets intrinsics calibrated at a lower resolution still be used (and judged elsewhere).
MAX_SIZE_OVER_CAMERA = 2

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# JPEG start-of-frame markers (SOF0-SOF15) carry the size; C4, C8 and CC share the range but
# are DHT, JPG and DAC.
_JPEG_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}


def stamp_ns(decoded: Any) -> int:
    """A message's capture stamp in nanoseconds: a ROS header's, or a Foxglove ``timestamp``."""
    if hasattr(decoded, "header"):
        stamp = decoded.header.stamp
        return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
    return int(decoded.timestamp.seconds) * 1_000_000_000 + int(decoded.timestamp.nanos)


def frame_id(decoded: Any) -> str:
    """The frame a message is in: a ROS header's, or a Foxglove ``frame_id``."""
    return str(decoded.header.frame_id if hasattr(decoded, "header") else decoded.frame_id)


def declared_size(data: bytes | bytearray | memoryview) -> tuple[int, int] | None:
    """The (width, height) a PNG's IHDR or a JPEG's start-of-frame header declares, read
    without decoding; None for other formats, or a header too damaged to say.

    Args:
        data: the compressed image's bytes.
    """
    head = bytes(data[:24])
    if head.startswith(_PNG_SIGNATURE) and head[12:16] == b"IHDR":
        width, height = struct.unpack(">II", head[16:24])
        return int(width), int(height)
    if head.startswith(b"\xff\xd8"):
        return _jpeg_size(data)
    return None


def _jpeg_size(data: bytes | bytearray | memoryview) -> tuple[int, int] | None:
    """A JPEG's (width, height) from its first start-of-frame segment; None if none is found
    before the scan starts (libjpeg then fails on it without allocating the frame)."""
    view = memoryview(data)
    i = 2
    while i + 4 <= len(view):
        if view[i] != 0xFF:
            return None
        marker = view[i + 1]
        if marker == 0xFF:  # fill bytes may pad a marker
            i += 1
            continue
        if marker in (0x01, *range(0xD0, 0xD8)):  # standalone markers: no length
            i += 2
            continue
        if marker == 0xDA:  # start of scan: no size came before it
            return None
        (length,) = struct.unpack(">H", view[i + 2 : i + 4])
        if marker in _JPEG_SOF and i + 9 <= len(view):
            height, width = struct.unpack(">HH", view[i + 5 : i + 9])
            return int(width), int(height)
        i += 2 + length
    return None


def _check_size(
    topic: str,
    data: bytes | bytearray | memoryview,
    camera_size: tuple[int, int] | None,
    what: str = "image",
) -> None:
    """Refuse a compressed image whose header declares more pixels than decoding should cost.

    Args:
        topic: named in the error.
        data: the compressed bytes.
        camera_size: the camera_info's (width, height), when the caller knows it (0 for
            unknown).
        what: ``image`` or ``compressedDepth image``, for the error.

    Raises:
        LogError: the declared size is beyond :data:`MAX_IMAGE_SIDE_PX` or
            :data:`MAX_IMAGE_PIXELS`, or beyond :data:`MAX_SIZE_OVER_CAMERA` times the camera's.
    """
    size = declared_size(data)
    if size is None:  # another format: OPENCV_IO_MAX_IMAGE_PIXELS is its bound
        return
    width, height = size
    if max(width, height) > MAX_IMAGE_SIDE_PX or width * height > MAX_IMAGE_PIXELS:
        raise LogError(
            f"{topic}: a compressed {what} declaring {width}x{height} pixels (more than "
            f"{MAX_IMAGE_PIXELS:,} pixels or {MAX_IMAGE_SIDE_PX} a side): not decoded"
        )
    if camera_size is None or min(camera_size) <= 0:
        return
    cam_width, cam_height = camera_size
    if width > MAX_SIZE_OVER_CAMERA * cam_width or height > MAX_SIZE_OVER_CAMERA * cam_height:
        raise LogError(
            f"{topic}: a compressed {what} declaring {width}x{height} pixels, its camera_info "
            f"{cam_width}x{cam_height}: not decoded"
        )


def decode_image(message: Message, camera_size: tuple[int, int] | None = None) -> NDArray[np.uint8]:
    """A grey image from ``sensor_msgs/msg/Image`` (rgb8, bgr8, mono8) or ``CompressedImage``.

    Args:
        message: the image message.
        camera_size: the camera_info's (width, height), when known: a compressed image whose
            header declares far more is refused before it is decoded.

    Raises:
        LogError: the image is empty, damaged, of an unknown encoding, or declares a size
            beyond reason (:func:`_check_size`).
    """
    msg = message.decoded
    if "CompressedImage" in message.schema:
        if len(msg.data) == 0:
            raise LogError(f"{message.topic}: an empty compressed image")
        _check_size(message.topic, msg.data, camera_size)
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


def decode_depth(message: Message, camera_size: tuple[int, int] | None = None) -> NDArray:
    """Aligned depth: 16UC1 in millimetres or 32FC1 in metres (``Image``), or a
    ``compressedDepth`` ``CompressedImage`` (12-byte header, then a 16-bit PNG).

    Args:
        message: the depth message.
        camera_size: the colour camera_info's (width, height), when known: a compressed depth
            image whose header declares far more is refused before it is decoded.

    Raises:
        LogError: the image is empty, damaged, of an unknown encoding, or declares a size
            beyond reason.
    """
    msg = message.decoded
    if "CompressedImage" in message.schema:
        if len(msg.data) <= 12:
            raise LogError(f"{message.topic}: an empty compressedDepth image")
        _check_size(message.topic, msg.data[12:], camera_size, "compressedDepth image")
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
