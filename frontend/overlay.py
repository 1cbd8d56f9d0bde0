"""The corrected map over the original log: an MCAP file of ROS 2 messages for Foxglove.

Topics: ``/markergraph/markers`` (``visualization_msgs/MarkerArray``, in ``map``: each marker's
normal as an arrow, its id, and its 2-sigma position ellipse as a flat cylinder),
``/markergraph/path`` (``nav_msgs/Path``, the estimated trajectory) and ``/tf`` (``map`` to
``odom`` at each estimated pose, so the log's own odom frame lands on the map). Play it beside
the original log.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import gtsam
import numpy as np
from mcap_ros2.writer import Writer

from markergraph.estimator.types import Estimate, OdometrySample
from markergraph.frontend.files import written_whole
from markergraph.frontend.ros2 import (
    MESSAGE_DEFINITIONS,
    header,
    quaternion_from_yaw,
    transform_stamped,
)

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
    path: Path,
    estimate: Estimate,
    odometry: Sequence[OdometrySample],
    heights_m: dict[int, float] | None = None,
) -> None:
    """Write the overlay MCAP, whole or not at all."""
    heights = heights_m or {}
    stamps = estimate.trajectory_t_ns
    start = int(stamps[0]) if len(stamps) else (odometry[0].t_ns if odometry else 0)
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
        for marker_id, marker in sorted(estimate.markers.items()):
            T = marker.T_map_marker
            z = heights.get(marker_id, 0.0)
            markers.append(
                _marker(
                    start,
                    marker_id,
                    "normals",
                    ARROW,
                    _pose(T.x(), T.y(), z, T.theta()),
                    (0.3, 0.04, 0.04),
                    (0.1, 0.4, 0.9, 1.0),
                )
            )
            markers.append(
                _marker(
                    start,
                    marker_id,
                    "ids",
                    TEXT,
                    _pose(T.x(), T.y(), z + 0.25, 0.0),
                    (0.0, 0.0, 0.2),
                    (1.0, 1.0, 1.0, 1.0),
                    str(marker_id),
                )
            )
            if marker.covariance is not None:
                c, s = math.cos(T.theta()), math.sin(T.theta())
                R = np.array([[c, -s], [s, c]])
                values, vectors = np.linalg.eigh(R @ marker.covariance[:2, :2] @ R.T)
                axis_yaw = math.atan2(vectors[1, 1], vectors[0, 1])  # the larger axis
                diameters = 4.0 * np.sqrt(np.maximum(values[::-1], 1e-12))  # 2 sigma
                markers.append(
                    _marker(
                        start,
                        marker_id,
                        "ellipses",
                        CYLINDER,
                        _pose(T.x(), T.y(), z, axis_yaw),
                        (float(diameters[0]), float(diameters[1]), 0.01),
                        (0.1, 0.4, 0.9, 0.3),
                    )
                )
        writer.write_message(
            MARKER_TOPIC,
            schemas["visualization_msgs/msg/MarkerArray"],
            {"markers": markers},
            log_time=start,
            publish_time=start,
        )
        odometry_stamps = np.array([s.t_ns for s in odometry], dtype=np.int64)
        for t_ns, (x, y, yaw) in zip(stamps, estimate.trajectory, strict=True):
            if not len(odometry_stamps):
                break
            i = int(np.argmin(np.abs(odometry_stamps - t_ns)))
            T_map_odom = gtsam.Pose2(x, y, yaw).compose(odometry[i].pose().inverse())
            writer.write_message(
                TF_TOPIC,
                schemas["tf2_msgs/msg/TFMessage"],
                {
                    "transforms": [
                        transform_stamped(
                            int(t_ns),
                            "map",
                            "odom",
                            (T_map_odom.x(), T_map_odom.y(), 0.0),
                            quaternion_from_yaw(T_map_odom.theta()),
                        )
                    ]
                },
                log_time=int(t_ns),
                publish_time=int(t_ns),
            )
        end = int(stamps[-1]) if len(stamps) else start
        poses = [
            {"header": header(int(t), "map"), "pose": _pose(x, y, 0.0, yaw)}
            for t, (x, y, yaw) in zip(stamps, estimate.trajectory, strict=True)
        ]
        writer.write_message(
            PATH_TOPIC,
            schemas["nav_msgs/msg/Path"],
            {"header": header(end, "map"), "poses": poses},
            log_time=end,
            publish_time=end,
        )
        writer.finish()
