"""ROS 2 message definitions (for writing and reading MCAP without ROS) and small message builders.

Definitions are the ``ros2msg`` texts rosbag2 stores as MCAP schemas: the type's own fields, then
each dependency after a line of 80 ``=`` and ``MSG: pkg/Type``. Field names, order and types
follow the ROS 2 (Humble to Jazzy) ``.msg`` files; comments are left out.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "MESSAGE_DEFINITIONS",
    "header",
    "quaternion_from_matrix",
    "quaternion_from_yaw",
    "stamp",
    "transform_stamped",
    "yaw_from_quaternion",
]

_SEPARATOR = "=" * 80

_BASE = {
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec",
    "builtin_interfaces/Duration": "int32 sec\nuint32 nanosec",
    "std_msgs/ColorRGBA": "float32 r\nfloat32 g\nfloat32 b\nfloat32 a",
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id",
    "std_msgs/String": "string data",
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1",
    "geometry_msgs/Pose": "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation",
    "geometry_msgs/PoseStamped": "std_msgs/Header header\ngeometry_msgs/Pose pose",
    "geometry_msgs/PoseWithCovariance": "geometry_msgs/Pose pose\nfloat64[36] covariance",
    "geometry_msgs/Twist": "geometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular",
    "geometry_msgs/TwistWithCovariance": "geometry_msgs/Twist twist\nfloat64[36] covariance",
    "geometry_msgs/Transform": "geometry_msgs/Vector3 translation\n"
    "geometry_msgs/Quaternion rotation",
    "geometry_msgs/TransformStamped": "std_msgs/Header header\nstring child_frame_id\n"
    "geometry_msgs/Transform transform",
    "tf2_msgs/TFMessage": "geometry_msgs/TransformStamped[] transforms",
    # visualization_msgs/Marker as in Humble (Iron and later append texture and mesh fields).
    "visualization_msgs/Marker": "std_msgs/Header header\nstring ns\nint32 id\nint32 type\n"
    "int32 action\ngeometry_msgs/Pose pose\ngeometry_msgs/Vector3 scale\n"
    "std_msgs/ColorRGBA color\nbuiltin_interfaces/Duration lifetime\nbool frame_locked\n"
    "geometry_msgs/Point[] points\nstd_msgs/ColorRGBA[] colors\nstring text\n"
    "string mesh_resource\nbool mesh_use_embedded_materials",
    "visualization_msgs/MarkerArray": "visualization_msgs/Marker[] markers",
    "geometry_msgs/PoseWithCovarianceStamped": "std_msgs/Header header\n"
    "geometry_msgs/PoseWithCovariance pose",
    # Marker detections, for logs that carry no definitions (a Humble SQLite bag). apriltag_msgs
    # as Humble ships it (Point[4] corners; the newer float64[8] serialises to the same bytes).
    "apriltag_msgs/Point": "float64 x\nfloat64 y",
    "apriltag_msgs/AprilTagDetection": "string family\nint32 id\nint32 hamming\n"
    "float32 goodness\nfloat32 decision_margin\napriltag_msgs/Point centre\n"
    "apriltag_msgs/Point[4] corners\nfloat64[9] homography",
    "apriltag_msgs/AprilTagDetectionArray": "std_msgs/Header header\n"
    "apriltag_msgs/AprilTagDetection[] detections",
    "isaac_ros_apriltag_interfaces/AprilTagDetection": "string family\nint32 id\n"
    "geometry_msgs/Point center\ngeometry_msgs/Point[4] corners\n"
    "geometry_msgs/PoseWithCovarianceStamped pose",
    "isaac_ros_apriltag_interfaces/AprilTagDetectionArray": "std_msgs/Header header\n"
    "isaac_ros_apriltag_interfaces/AprilTagDetection[] detections",
    "nav_msgs/Path": "std_msgs/Header header\ngeometry_msgs/PoseStamped[] poses",
    "nav_msgs/Odometry": "std_msgs/Header header\nstring child_frame_id\n"
    "geometry_msgs/PoseWithCovariance pose\ngeometry_msgs/TwistWithCovariance twist",
    "sensor_msgs/Image": "std_msgs/Header header\nuint32 height\nuint32 width\n"
    "string encoding\nuint8 is_bigendian\nuint32 step\nuint8[] data",
    "sensor_msgs/CompressedImage": "std_msgs/Header header\nstring format\nuint8[] data",
    "sensor_msgs/RegionOfInterest": "uint32 x_offset\nuint32 y_offset\nuint32 height\n"
    "uint32 width\nbool do_rectify",
    "sensor_msgs/CameraInfo": "std_msgs/Header header\nuint32 height\nuint32 width\n"
    "string distortion_model\nfloat64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\n"
    "uint32 binning_x\nuint32 binning_y\nsensor_msgs/RegionOfInterest roi",
}


def _dependencies(name: str, found: list[str]) -> list[str]:
    """Every message type ``name`` uses, depth first, each once."""
    for line in _BASE[name].splitlines():
        field_type = line.split()[0].split("[")[0]
        if "/" in field_type and field_type not in found:
            found.append(field_type)
            _dependencies(field_type, found)
    return found


def _full_definition(name: str) -> str:
    parts = [_BASE[name]]
    for dependency in _dependencies(name, []):
        parts.append(f"{_SEPARATOR}\nMSG: {dependency}\n{_BASE[dependency]}")
    return "\n".join(parts) + "\n"


def _schema_name(name: str) -> str:
    package, message = name.split("/")
    return f"{package}/msg/{message}"


MESSAGE_DEFINITIONS: dict[str, str] = {
    _schema_name(name): _full_definition(name)
    for name in _BASE
    if not name.startswith("builtin_interfaces/")
}
"""Schema name (``sensor_msgs/msg/Image``) -> full ``ros2msg`` definition text."""


def stamp(t_ns: int) -> dict[str, int]:
    """A ``builtin_interfaces/Time`` from integer nanoseconds."""
    return {"sec": t_ns // 1_000_000_000, "nanosec": t_ns % 1_000_000_000}


def header(t_ns: int, frame_id: str) -> dict[str, object]:
    return {"stamp": stamp(t_ns), "frame_id": frame_id}


def quaternion_from_yaw(yaw: float) -> dict[str, float]:
    return {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2.0), "w": math.cos(yaw / 2.0)}


def yaw_from_quaternion(x: float, y: float, z: float, w: float) -> float:
    """Heading of a rotation about the vertical (roll and pitch ignored); NaN when a component
    is not finite or the quaternion is zero (atan2 would turn either into a plausible angle)."""
    if not all(math.isfinite(v) for v in (x, y, z, w)) or x * x + y * y + z * z + w * w < 1e-12:
        return math.nan
    # w^2 + x^2 - y^2 - z^2 instead of 1 - 2(y^2 + z^2): the same for a unit quaternion, and
    # right for one that is not normalised.
    return math.atan2(2.0 * (w * z + x * y), w * w + x * x - y * y - z * z)


def quaternion_from_matrix(R: NDArray[np.float64]) -> dict[str, float]:
    """A unit quaternion of a 3x3 rotation matrix (Shepperd's method, stable everywhere)."""
    trace = float(np.trace(R))
    if trace > 0.0:
        s = 2.0 * math.sqrt(trace + 1.0)
        return {
            "w": 0.25 * s,
            "x": (R[2, 1] - R[1, 2]) / s,
            "y": (R[0, 2] - R[2, 0]) / s,
            "z": (R[1, 0] - R[0, 1]) / s,
        }
    i = int(np.argmax(np.diag(R)))
    j, k = (i + 1) % 3, (i + 2) % 3
    s = 2.0 * math.sqrt(1.0 + R[i, i] - R[j, j] - R[k, k])
    q = [0.0, 0.0, 0.0]
    q[i] = 0.25 * s
    q[j] = (R[j, i] + R[i, j]) / s
    q[k] = (R[k, i] + R[i, k]) / s
    return {"x": q[0], "y": q[1], "z": q[2], "w": (R[k, j] - R[j, k]) / s}


def transform_stamped(
    t_ns: int, parent: str, child: str, xyz: tuple[float, float, float], rotation: dict[str, float]
) -> dict[str, object]:
    return {
        "header": header(t_ns, parent),
        "child_frame_id": child,
        "transform": {"translation": dict(zip("xyz", xyz, strict=True)), "rotation": rotation},
    }
