"""The marker map in peer tools' formats: ArUco's MarkerMap, fiducial_slam, TagSLAM and CSV."""

from __future__ import annotations

import math
from enum import Enum
from pathlib import Path

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.common.files import written_whole
from markergraph.common.numbers import denoised
from markergraph.estimator.tags3d import R_TAG_MARKER, quaternion_wxyz
from markergraph.markermap import MapMarker, MarkerMap

__all__ = ["ExportFormat", "export_map"]


class ExportFormat(Enum):
    """Formats ``markergraph export`` writes."""

    ARUCO_YAML = "aruco-yaml"  # the ArUco library's MarkerMap (corners in metres)
    FIDUCIAL_SLAM = "fiducial-slam"  # UbiquityRobotics fiducial_slam map.txt (degrees)
    TAGSLAM = "tagslam"  # a TagSLAM static body of tags (rotation vectors)
    CSV = "csv"


def _number(value: float) -> str:
    """A value as text, exact (``repr``), with float noise such as the home marker's
    ``-4.2e-21`` written as 0.0."""
    return repr(denoised(value))


def _R_map_tag(yaw: float) -> NDArray[np.float64]:
    """A wall marker's rotation in OpenCV's marker convention (x to the viewer's right, y up,
    z out of the marker) from its top-view yaw (the normal's heading)."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[-s, 0.0, c], [c, 0.0, s], [0.0, 1.0, 0.0]])


def _R_tag(m: MapMarker) -> NDArray[np.float64]:
    """A marker's rotation in OpenCV's marker convention: a 3-D map's real one, else that of
    a marker upright on a wall."""
    if m.T_map_marker3 is not None:
        return np.asarray(m.T_map_marker3.rotation().matrix()) @ R_TAG_MARKER.T
    return _R_map_tag(m.T_map_marker.theta())


def _centre(m: MapMarker) -> NDArray[np.float64]:
    if m.T_map_marker3 is not None:
        return np.asarray(m.T_map_marker3.translation(), dtype=float)
    T = m.T_map_marker
    return np.array([T.x(), T.y(), m.z_m or 0.0])


def _sigmas3(m: MapMarker) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """A 3-D map's marker: the position's sigmas along the map's axes [m] and the rotation's
    about the tag's own axes (OpenCV's convention) [rad]; None without a covariance."""
    if m.T_map_marker3 is None or m.covariance6 is None:
        return None
    R = np.asarray(m.T_map_marker3.rotation().matrix())
    position = R @ m.covariance6[3:, 3:] @ R.T
    rotation = R_TAG_MARKER @ m.covariance6[:3, :3] @ R_TAG_MARKER.T  # marker axes to tag axes
    return (np.sqrt(np.maximum(np.diag(position), 0.0)),
            np.sqrt(np.maximum(np.diag(rotation), 0.0)))  # fmt: skip


def _corners(m: MapMarker) -> NDArray[np.float64]:
    """The black square's corners in the map, OpenCV's order (top-left first)."""
    R = _R_tag(m)
    centre = _centre(m)
    right, up = R[:, 0] * m.size_m / 2.0, R[:, 1] * m.size_m / 2.0
    return np.array(
        [centre - right + up, centre + right + up, centre + right - up, centre - right - up]
    )


_CSV_2D = "id,x_m,y_m,z_m,yaw_rad,sigma_x_m,sigma_y_m,sigma_yaw_rad,sigma_z_m,n_observations"
# A 3-D map's CSV: the 2-D columns first (so a reader by name of either takes it), sigma_x,
# sigma_y and sigma_z along the map's axes, sigma_yaw a wall tag's heading sigma (empty for a
# tag not on a wall); then the quaternion [w, x, y, z] of T_map_marker (x the normal, as in
# map.json), the rotation's sigmas about the marker's own axes, and whether it is a wall tag.
_CSV_3D = _CSV_2D + ",qw,qx,qy,qz,sigma_rx_rad,sigma_ry_rad,sigma_rz_rad,wall"


def _csv(marker_map: MarkerMap) -> list[str]:
    if marker_map.dimensions == 3:
        return _csv_3d(marker_map)
    lines = [_CSV_2D]
    for m in marker_map.markers.values():
        values = (*_centre(m), m.T_map_marker.theta(), *m.sigmas(), m.sigma_z_m or 0.0)
        lines.append(",".join([str(m.marker_id), *(_number(v) for v in values),
                               str(m.n_observations)]))  # fmt: skip
    return lines


def _csv_3d(marker_map: MarkerMap) -> list[str]:
    lines = [_CSV_3D]
    for m in marker_map.markers3d.values():
        assert m.T_map_marker3 is not None  # a 3-D map's markers all have one
        q = quaternion_wxyz(m.T_map_marker3.rotation())
        sigma_p, sigma_r = np.zeros(3), np.zeros(3)
        if m.covariance6 is not None:
            R = np.asarray(m.T_map_marker3.rotation().matrix())
            sigma_p = np.sqrt(np.maximum(np.diag(R @ m.covariance6[3:, 3:] @ R.T), 0.0))
            sigma_r = np.sqrt(np.maximum(np.diag(m.covariance6[:3, :3]), 0.0))
        sigma_yaw = repr(m.sigmas()[2]) if m.wall else ""
        cells = [
            str(m.marker_id),
            *(_number(v) for v in (*_centre(m), m.T_map_marker.theta(), *sigma_p[:2])),
            sigma_yaw,
            repr(float(sigma_p[2])),
            str(m.n_observations),
            *(repr(v) for v in q),
            *(_number(v) for v in sigma_r),
            "true" if m.wall else "false",
        ]
        lines.append(",".join(cells))
    return lines


# OpenCV's names for the dictionaries the ArUco library knows by its own name; the rest (4x4 to
# 7x7) it reads as OpenCV's name without the ``DICT_`` prefix.
_ARUCO_NAMES = {
    "DICT_ARUCO_ORIGINAL": "ARUCO",
    "DICT_ARUCO_MIP_36h12": "ARUCO_MIP_36h12",
    "DICT_APRILTAG_16h5": "TAG16h5",
    "DICT_APRILTAG_25h9": "TAG25h9",
    "DICT_APRILTAG_36h10": "TAG36h10",
    "DICT_APRILTAG_36h11": "TAG36h11",
}


def aruco_dictionary_name(dictionary: str) -> str:
    """The ArUco library's name for an OpenCV dictionary (``DICT_APRILTAG_36h11`` ->
    ``TAG36h11``, ``DICT_4X4_50`` -> ``4X4_50``); a custom dictionary's name as it is."""
    return _ARUCO_NAMES.get(dictionary, dictionary.removeprefix("DICT_"))


def _aruco(marker_map: MarkerMap) -> list[str]:
    lines = [
        "%YAML:1.0",
        f'aruco_bc_dict: "{aruco_dictionary_name(marker_map.dictionary)}"',  # 4X4_50 is no number
        f"aruco_bc_nmarkers: {len(marker_map.markers)}",
        "aruco_bc_mInfoType: 1",
        "aruco_bc_markers:",
    ]
    for m in marker_map.every_marker.values():
        corners = ", ".join(
            "[" + ", ".join(_number(v) for v in corner) + "]" for corner in _corners(m)
        )
        lines.append(f"   - {{ id: {m.marker_id}, corners: [ {corners} ] }}")
    return lines


def _fiducial_slam(marker_map: MarkerMap) -> list[str]:
    """``id x y z roll pitch yaw variance n`` per marker, angles in degrees."""
    lines = []
    for m in marker_map.every_marker.values():
        rpy = gtsam.Rot3(_R_tag(m)).rpy()
        sx, sy, _ = m.sigmas()
        if (sigmas := _sigmas3(m)) is not None:
            sx, sy = float(sigmas[0][0]), float(sigmas[0][1])
        fields = [*_centre(m), *(math.degrees(float(a)) for a in rpy), sx * sx + sy * sy]
        lines.append(" ".join([str(m.marker_id), *(_number(v) for v in fields),
                               str(m.n_observations)]))  # fmt: skip
    return lines


def _tagslam(marker_map: MarkerMap) -> list[str]:
    lines = [
        "bodies:",
        " - map:",
        "     is_static: true",
        "     type: simple",
        f"     default_tag_size: {marker_map.marker_size_m!r}",
        "     tags:",
    ]
    for m in marker_map.every_marker.values():
        x, y, z = _centre(m)
        rotation = [float(v) for v in gtsam.Rot3.Logmap(gtsam.Rot3(_R_tag(m)))]
        sx, sy, syaw = m.sigmas()
        sz = m.sigma_z_m or max(sx, sy)
        srx = sry = srz = syaw
        if (sigmas := _sigmas3(m)) is not None:
            (sx, sy, sz), (srx, sry, srz) = (tuple(float(v) for v in s) for s in sigmas)
        lines += [
            f"       - id: {m.marker_id}",
            f"         size: {m.size_m!r}",
            "         pose:",
            f"           position: {{x: {_number(x)}, y: {_number(y)}, z: {_number(z)}}}",
            f"           rotation: {{x: {_number(rotation[0])}, y: {_number(rotation[1])}, "
            f"z: {_number(rotation[2])}}}",
            f"           position_noise: {{x: {sx!r}, y: {sy!r}, z: {sz!r}}}",
            f"           rotation_noise: {{x: {srx!r}, y: {sry!r}, z: {srz!r}}}",
        ]
    return lines


_WRITERS = {
    ExportFormat.CSV: _csv,
    ExportFormat.ARUCO_YAML: _aruco,
    ExportFormat.FIDUCIAL_SLAM: _fiducial_slam,
    ExportFormat.TAGSLAM: _tagslam,
}


def export_map(marker_map: MarkerMap, fmt: ExportFormat, path: Path) -> None:
    """Write a marker map in another tool's format, whole or not at all.

    A 2-D map: marker heights are the map's (0 where unknown); orientations are those of
    markers on vertical walls. A 3-D map: every tag with its full pose (the CSV gains the
    quaternion and the rotation's sigmas, the others write the real rotation and corners).
    """
    with written_whole(path) as partial:
        partial.write_text("\n".join(_WRITERS[fmt](marker_map)) + "\n", encoding="utf-8")
