"""The corrected map over the original log: an MCAP file of ROS 2 messages for Foxglove.

Topics: ``/markergraph/markers`` (``visualization_msgs/MarkerArray``, in ``map``: each marker's
normal as an arrow, its id, and its 2-sigma position ellipse as a flat cylinder),
``/markergraph/path`` (``nav_msgs/Path``, the estimated trajectory) and ``/tf`` (``map`` to
``odom`` at each estimated pose, so the log's own odom frame lands on the map). Play it beside
the original log.
"""

from __future__ import annotations

from pathlib import Path

from mcap_ros2.writer import Writer

from markergraph.estimator.trajectory import Trajectory
from markergraph.frontend.files import written_whole
from markergraph.frontend.ros2 import (
    MESSAGE_DEFINITIONS,
    header,
    quaternion_from_yaw,
    transform_stamped,
)
from markergraph.markermap import MarkerMap

__all__ = ["write_overlay"]

ARROW, CYLINDER, TEXT = 0, 3, 9
MARKER_TOPIC, PATH_TOPIC, TF_TOPIC = "/markergraph/markers", "/markergraph/path", "/tf"


def _marker(
    t_ns: int,
    marker_id: int,
    ns: str,
    kind: int,
    pose: dict,
    scale: tuple,
    color: tuple,
    text: str = "",
) -> dict:
    return {
        "header": header(t_ns, "map"),
        "ns": ns,
        "id": marker_id,
        "type": kind,
        "action": 0,
        "pose": pose,
        "scale": dict(zip("xyz", scale, strict=True)),
        "color": dict(zip("rgba", color, strict=True)),
        "lifetime": {"sec": 0, "nanosec": 0},
        "frame_locked": False,
        "points": [],
        "colors": [],
        "text": text,
        "mesh_resource": "",
        "mesh_use_embedded_materials": False,
    }


def _pose(x: float, y: float, z: float, yaw: float) -> dict:
    return {"position": {"x": x, "y": y, "z": z}, "orientation": quaternion_from_yaw(yaw)}


def write_overlay(
    path: Path, marker_map: MarkerMap, trajectory: Trajectory, odometry: Trajectory
) -> None:
    """Write the overlay MCAP, whole or not at all: the map, the estimated path and
    ``map -> odom`` at each estimated pose (where odometry reaches)."""
    stamps = trajectory.t_ns
    start = int(stamps[0]) if len(stamps) else (int(odometry.t_ns[0]) if len(odometry) else 0)
    with written_whole(path) as partial, open(partial, "wb") as stream:
        writer = Writer(stream)
        schemas = {
            name: writer.register_msgdef(name, MESSAGE_DEFINITIONS[name])
            for name in (
                "visualization_msgs/msg/MarkerArray",
                "nav_msgs/msg/Path",
                "tf2_msgs/msg/TFMessage",
            )
        }
        markers = []
        for marker_id, marker in marker_map.markers.items():
            T = marker.T_map_marker
            z = marker.z_m or 0.0
            markers.append(
                _marker(start, marker_id, "normals", ARROW, _pose(T.x(), T.y(), z, T.theta()),
                        (0.3, 0.04, 0.04), (0.1, 0.4, 0.9, 1.0))
            )  # fmt: skip
            markers.append(
                _marker(start, marker_id, "ids", TEXT, _pose(T.x(), T.y(), z + 0.25, 0.0),
                        (0.0, 0.0, 0.2), (1.0, 1.0, 1.0, 1.0), str(marker_id))
            )  # fmt: skip
            ellipse = marker.position_ellipse(2.0)
            if ellipse is not None:
                (major, minor), heading = ellipse
                markers.append(
                    _marker(start, marker_id, "ellipses", CYLINDER,
                            _pose(T.x(), T.y(), z, heading), (float(major), float(minor), 0.01),
                            (0.1, 0.4, 0.9, 0.3))
                )  # fmt: skip
        writer.write_message(
            MARKER_TOPIC,
            schemas["visualization_msgs/msg/MarkerArray"],
            {"markers": markers},
            log_time=start,
            publish_time=start,
        )
        for t_ns in stamps:
            T_map_odom = trajectory.T_self_other(odometry, int(t_ns))
            if T_map_odom is None:
                continue
            transform = transform_stamped(
                int(t_ns),
                "map",
                "odom",
                (T_map_odom.x(), T_map_odom.y(), 0.0),
                quaternion_from_yaw(T_map_odom.theta()),
            )
            writer.write_message(
                TF_TOPIC,
                schemas["tf2_msgs/msg/TFMessage"],
                {"transforms": [transform]},
                log_time=int(t_ns),
                publish_time=int(t_ns),
            )
        end = int(stamps[-1]) if len(stamps) else start
        poses = [
            {"header": header(int(t), "map"), "pose": _pose(x, y, 0.0, yaw)}
            for t, (x, y, yaw) in zip(stamps, trajectory.poses, strict=True)
        ]
        writer.write_message(
            PATH_TOPIC,
            schemas["nav_msgs/msg/Path"],
            {"header": header(end, "map"), "poses": poses},
            log_time=end,
            publish_time=end,
        )
        writer.finish()
