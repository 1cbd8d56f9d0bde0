"""The corrected map over the original log: an MCAP file of ROS 2 messages for Foxglove.

Topics (frame names are :func:`write_overlay`'s ``map_frame`` and ``odom_frame``, by default
``map`` and ``odom``):

- ``/markergraph/markers`` (``visualization_msgs/msg/MarkerArray``, in the map frame, once at
  the start): each marker's normal as an arrow, its id, and its 2-sigma position ellipse as a
  flat cylinder, at the marker's height where the map knows it (else on the floor).
- ``/tf_static`` (``tf2_msgs/msg/TFMessage``, once at the start): the map frame to
  ``marker_<id>`` at each marker's pose (x, y, height, yaw), so each marker shows as an axis.
- ``/markergraph/path`` (``nav_msgs/msg/Path``): the estimated trajectory so far, every
  half second of log time (:data:`PATH_PERIOD_NS`; long paths thinned to :data:`MAX_PATH_POSES`)
  and once more at its last stamp with every pose, so the path grows as the log plays.
- ``/markergraph/pose`` (``geometry_msgs/msg/PoseStamped``): each estimated pose at its stamp;
  ``evo_traj mcap overlay.mcap /markergraph/pose`` reads it.
- ``/tf`` (``tf2_msgs/msg/TFMessage``): the map frame to the odom frame at each estimated pose
  the odometry reaches, so the log's own odom frame lands on the map.

Play it beside the original log. ``overlay.layout.json`` beside it is a Foxglove layout of these
topics and the log's camera (:mod:`markergraph.foxglove_layout`).
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Iterable, Iterator
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import BinaryIO

import numpy as np
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter

from markergraph.common.files import written_whole
from markergraph.estimator.trajectory import Trajectory, map_to_odom
from markergraph.formats.cdr import ENCAPSULATION, CdrWriter, fill_string, layout, string_fields
from markergraph.foxglove_layout import layout_path, overlay_layout, write_layout
from markergraph.frontend.ros2 import MESSAGE_DEFINITIONS
from markergraph.markermap import MapMarker, MarkerMap

__all__ = [
    "MARKER_TOPIC",
    "MAX_PATH_POSES",
    "PATH_PERIOD_NS",
    "PATH_TOPIC",
    "POSE_TOPIC",
    "TF_STATIC_TOPIC",
    "TF_TOPIC",
    "write_overlay",
]

ARROW, CYLINDER, TEXT = 0, 3, 9
MARKER_TOPIC, PATH_TOPIC, POSE_TOPIC = (
    "/markergraph/markers",
    "/markergraph/path",
    "/markergraph/pose",
)
TF_TOPIC, TF_STATIC_TOPIC = "/tf", "/tf_static"

PATH_PERIOD_NS = 500_000_000
"""Log time between two ``/markergraph/path`` messages [ns]; a period without a new pose
publishes nothing (the previous message still holds)."""
MAX_PATH_POSES = 1000
"""Poses at most in a ``/markergraph/path`` message before the last: each message repeats the
path so far, so K messages of a path of N poses write about K N / 2 poses. Longer paths keep every
k-th pose (the same ones in every message, so the drawn line only grows) and the newest one. A
10-minute path of 18,000 poses (30 Hz) makes a 3.1 MB overlay this way."""

# The order of messages that share a stamp: what is drawn with a pose comes after the pose.
_STATIC, _TF, _POSE, _PATH = range(4)

_Event = tuple[int, int, str, str, bytes]  # (t_ns, order, topic, schema, CDR message)
_Quaternion = tuple[float, float, float, float]  # (x, y, z, w)


def _yaw_quaternion(yaw: float) -> _Quaternion:
    return 0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0)


def _marker(
    cdr: CdrWriter,
    t_ns: int,
    frame: str,
    marker_id: int,
    ns: str,
    kind: int,
    pose: tuple[float, float, float, float],
    scale: tuple[float, float, float],
    color: tuple[float, float, float, float],
    text: str = "",
) -> None:
    """One ``visualization_msgs/Marker`` (Humble's fields) appended: added, forever, at ``pose``
    (x, y, z, yaw)."""
    x, y, z, yaw = pose
    cdr.header(t_ns, frame).string(ns).int32(marker_id, kind, 0)
    cdr.float64(x, y, z, *_yaw_quaternion(yaw)).float64(*scale).float32(*color)
    cdr.time(0).boolean(False)  # lifetime 0: forever; not frame-locked
    cdr.sequence(0).sequence(0).string(text).string("").boolean(False)  # no points, colours, mesh


def _height_m(marker: MapMarker) -> float:
    """The marker centre's height [m]; 0 (the floor) where the map does not know it."""
    z_m = getattr(marker, "z_m", None)
    return 0.0 if z_m is None else float(z_m)


def _transform(
    cdr: CdrWriter, t_ns: int, parent: str, child: str, xyz: tuple[float, float, float], yaw: float
) -> None:
    """One ``geometry_msgs/TransformStamped`` appended."""
    cdr.header(t_ns, parent).string(child).float64(*xyz, *_yaw_quaternion(yaw))


def _map_messages(marker_map: MarkerMap, t_ns: int, map_frame: str, prefix: str) -> list[_Event]:
    """The MarkerArray and the static marker frames, both at ``t_ns``."""
    markers = []  # (id, ns, kind, pose, scale, colour, text)
    for marker_id, marker in marker_map.markers.items():
        T = marker.T_map_marker
        z = _height_m(marker)
        markers.append((marker_id, "normals", ARROW, (T.x(), T.y(), z, T.theta()),
                        (0.3, 0.04, 0.04), (0.1, 0.4, 0.9, 1.0), ""))  # fmt: skip
        markers.append((marker_id, "ids", TEXT, (T.x(), T.y(), z + 0.25, 0.0),
                        (0.0, 0.0, 0.2), (1.0, 1.0, 1.0, 1.0), str(marker_id)))  # fmt: skip
        ellipse = marker.position_ellipse(2.0)
        if ellipse is not None:
            (major, minor), heading = ellipse
            size = (float(major), float(minor), 0.01)
            markers.append((marker_id, "ellipses", CYLINDER, (T.x(), T.y(), z, heading),
                            size, (0.1, 0.4, 0.9, 0.3), ""))  # fmt: skip
    array = CdrWriter().sequence(len(markers))
    for marker_id, ns, kind, pose, scale, color, text in markers:
        _marker(array, t_ns, map_frame, marker_id, ns, kind, pose, scale, color, text)
    transforms = CdrWriter().sequence(len(marker_map.markers))
    for marker_id, marker in marker_map.markers.items():
        T = marker.T_map_marker
        xyz = (T.x(), T.y(), _height_m(marker))
        _transform(transforms, t_ns, map_frame, f"{prefix}{marker_id}", xyz, T.theta())
    return [
        (t_ns, _STATIC, MARKER_TOPIC, "visualization_msgs/msg/MarkerArray", array.data()),
        (t_ns, _STATIC, TF_STATIC_TOPIC, "tf2_msgs/msg/TFMessage", transforms.data()),
    ]


def _tf_messages(
    trajectory: Trajectory, odometry: Trajectory, map_frame: str, odom_frame: str
) -> Iterator[_Event]:
    """``map -> odom`` at each estimated pose the odometry reaches."""
    corrections = map_to_odom(trajectory, odometry)
    fields = [("transforms", "<u4"), *_HEADER, *string_fields("frame_id", map_frame),
              *string_fields("child_frame_id", odom_frame), ("transform", "(7,)<f8")]  # fmt: skip
    records = np.zeros(len(corrections), layout(fields))
    records["transforms"] = 1  # one TransformStamped in each
    _fill_stamped(records, corrections, map_frame, "transform")
    fill_string(records, "child_frame_id", odom_frame)
    size, data = records.dtype.itemsize, records.tobytes()
    for k, t in enumerate(corrections.t_ns.tolist()):
        message = ENCAPSULATION + data[k * size : (k + 1) * size]
        yield t, _TF, TF_TOPIC, "tf2_msgs/msg/TFMessage", message


_HEADER = [("sec", "<i4"), ("nanosec", "<u4")]  # a header's stamp; its frame_id follows


def _fill_stamped(records: np.ndarray, poses: Trajectory, frame: str, field: str) -> None:
    """Stamps, frame names and poses (x, y, 0, then the yaw's quaternion) into records."""
    records["sec"], records["nanosec"] = np.divmod(poses.t_ns, 1_000_000_000)
    fill_string(records, "frame_id", frame)
    half = poses.poses[:, 2] / 2.0
    zeros = np.zeros(len(poses))
    records[field] = np.column_stack(
        [poses.poses[:, 0], poses.poses[:, 1], zeros, zeros, zeros, np.sin(half), np.cos(half)]
    )


def _pose_records(trajectory: Trajectory, map_frame: str, start: int = 0) -> np.ndarray:
    """Each pose as a ``geometry_msgs/PoseStamped`` record laid out from the offset ``start``
    (mod 8; at 0 they follow one another)."""
    fields = [*_HEADER, *string_fields("frame_id", map_frame), ("pose", "(7,)<f8")]
    records = np.zeros(len(trajectory), layout(fields, start))
    _fill_stamped(records, trajectory, map_frame, "pose")
    return records


def _path_messages(
    trajectory: Trajectory, rows: np.ndarray, map_frame: str, period_ns: int, max_poses: int
) -> Iterator[_Event]:
    """The path so far every ``period_ns`` from the first stamp (where it gained a pose), and
    the whole path at the last stamp; each message holds the poses stamped at or before its
    own stamp (``rows``: the bytes of :func:`_pose_records`, one row a pose, encoded once)."""
    stamps = trajectory.t_ns
    if not len(stamps):
        return
    first, last = int(stamps[0]), int(stamps[-1])
    stride = max(1, math.ceil(len(stamps) / max_poses))
    published = 0
    for t_ns in range(first, last, period_ns):
        count = int(np.searchsorted(stamps, t_ns, side="right"))
        if count == published:  # no new pose since the last message: it still holds
            continue
        published = count
        kept = np.arange(0, count, stride)
        if (count - 1) % stride:  # the newest pose, so the line reaches the robot
            kept = np.append(kept, count - 1)
        data = _path(trajectory, rows, kept, t_ns, map_frame)
        yield t_ns, _PATH, PATH_TOPIC, "nav_msgs/msg/Path", data
    data = _path(trajectory, rows, np.arange(len(stamps)), last, map_frame)
    yield last, _PATH, PATH_TOPIC, "nav_msgs/msg/Path", data


def _path(
    trajectory: Trajectory, rows: np.ndarray, kept: np.ndarray, t_ns: int, map_frame: str
) -> bytes:
    """A ``nav_msgs/Path`` of the poses ``kept`` (indices, never empty)."""
    cdr = CdrWriter().header(t_ns, map_frame).sequence(len(kept))
    start = cdr.offset % 8
    if start:  # the rows were laid out from a multiple of 8: the first pose is not there
        first = Trajectory(trajectory.t_ns[kept[:1]], trajectory.poses[kept[:1]])
        cdr.encoded(_pose_records(first, map_frame, start).tobytes(), start)
        kept = kept[1:]
    # Rows of bytes, not records: a record array's copy leaves its padding unset.
    return cdr.encoded(rows[kept].tobytes()).data()


def _check_frame(name: str, value: str) -> None:
    if not isinstance(value, str) or not value or value.startswith("/") or value != value.strip():
        raise ValueError(
            f"{name} must be a frame name without a leading '/' or spaces, not {value!r}"
        )


def _write_layout(
    path: Path, map_frame: str, image_topic: str | None, calibration_topic: str | None
) -> None:
    """The overlay's Foxglove layout beside it."""
    scene = [MARKER_TOPIC, PATH_TOPIC, POSE_TOPIC]  # the markers first: also drawn on the image
    layout = overlay_layout(map_frame, scene, image_topic, calibration_topic)
    write_layout(layout_path(path), layout)


def write_overlay(
    path: Path,
    marker_map: MarkerMap,
    trajectory: Trajectory,
    odometry: Trajectory,
    *,
    map_frame: str = "map",
    odom_frame: str = "odom",
    marker_frame_prefix: str = "marker_",
    path_period_ns: int = PATH_PERIOD_NS,
    max_path_poses: int = MAX_PATH_POSES,
    image_topic: str | None = None,
    calibration_topic: str | None = None,
) -> None:
    """Write the overlay MCAP, whole or not at all (topics: the module's docstring), and its
    Foxglove layout beside it (``overlay.mcap`` -> ``overlay.layout.json``).

    The map (``/markergraph/markers`` and the marker frames on ``/tf_static``) is stamped at the
    earliest stamp of ``trajectory`` and ``odometry``, so it shows from the start of the log.

    Args:
        path: the file to write.
        marker_map: the corrected map; markers are drawn at their height ``z_m`` where known.
        trajectory: the estimated path, ``T_map_base``.
        odometry: the log's odometry, ``T_odom_base``, for ``map -> odom`` on ``/tf``.
        map_frame: the frame of the map, the path, the poses and the parent of the marker
            frames. Rename it (e.g. ``markergraph_map``) when the overlay plays beside a log of a
            robot that publishes its own ``map`` (nav2's AMCL or SLAM publish ``map -> odom``):
            two parents of ``odom`` would fight in the TF tree.
        odom_frame: the log's odometry frame, the child of ``map_frame`` on ``/tf``. Set it to
            the ``frame_id`` of the log's odometry when that is not ``odom``.
        marker_frame_prefix: marker ``i``'s frame on ``/tf_static`` is ``f"{prefix}{i}"``.
        path_period_ns: log time between two ``/markergraph/path`` messages [ns]; shorter
            grows the path more smoothly and makes the file bigger.
        max_path_poses: poses at most in each path message but the last (which holds every
            pose); the file grows with ``max_path_poses`` times the number of messages.
        image_topic: the log's colour topic, for the layout's Image panel (None: left empty).
        calibration_topic: its camera_info topic, which projects the markers onto the image.

    Raises:
        ValueError: an empty or ``/``-prefixed frame name, the map and odom frames the same,
            or a period or pose limit below 1.
    """
    for name, value in (("map_frame", map_frame), ("odom_frame", odom_frame)):
        _check_frame(name, value)
    if map_frame == odom_frame:
        raise ValueError(f"map_frame and odom_frame are both {map_frame!r}")
    _check_frame("marker_frame_prefix", marker_frame_prefix)
    if path_period_ns < 1 or max_path_poses < 1:
        raise ValueError(
            f"path_period_ns ({path_period_ns}) and max_path_poses ({max_path_poses}) must be"
            " at least 1"
        )
    firsts = [int(t.t_ns[0]) for t in (trajectory, odometry) if len(t)]
    start = min(firsts) if firsts else 0
    records = _pose_records(trajectory, map_frame)
    size, data = records.dtype.itemsize, records.tobytes()
    rows = np.frombuffer(data, np.uint8).reshape(len(trajectory), size)  # padding included
    poses = (
        (t, _POSE, POSE_TOPIC, "geometry_msgs/msg/PoseStamped",
         ENCAPSULATION + data[k * size : (k + 1) * size])
        for k, t in enumerate(trajectory.t_ns.tolist())
    )  # fmt: skip
    events = heapq.merge(
        _map_messages(marker_map, start, map_frame, marker_frame_prefix),
        _tf_messages(trajectory, odometry, map_frame, odom_frame),
        poses,
        _path_messages(trajectory, rows, map_frame, path_period_ns, max_path_poses),
        key=lambda event: event[:2],
    )
    with written_whole(path) as partial, open(partial, "wb") as stream:
        _write_events(stream, events)
    _write_layout(Path(path), map_frame, image_topic, calibration_topic)


def _write_events(stream: BinaryIO, events: Iterable[_Event]) -> None:
    """The messages into an MCAP stream of the ``ros2`` profile, each topic's schema the full
    ``ros2msg`` definition (as mcap_ros2's writer does, with its default zstd chunks)."""
    writer = McapWriter(stream, compression=CompressionType.ZSTD)
    writer.start(profile="ros2", library=f"markergraph {_version()}")
    schemas: dict[str, int] = {}
    channels: dict[str, int] = {}
    for t_ns, _, topic, schema, data in events:
        if schema not in schemas:
            text = MESSAGE_DEFINITIONS[schema].encode()
            schemas[schema] = writer.register_schema(schema, SchemaEncoding.ROS2, text)
        if topic not in channels:
            channels[topic] = writer.register_channel(topic, MessageEncoding.CDR, schemas[schema])
        writer.add_message(channels[topic], log_time=t_ns, data=data, publish_time=t_ns)
    writer.finish()


def _version() -> str:
    try:
        return version("markergraph")
    except PackageNotFoundError:  # run from a source tree that was never installed
        return "unknown"
