"""Result files: the corrected marker map as JSON, trajectories as TUM, the pose graph as g2o,
and the map in peer tools' formats.

All writers write whole files or nothing (:func:`markergraph.frontend.files.written_whole`), and
none writes a NaN or an infinity: JSON is strict, and a non-finite value is an error.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from enum import Enum
from pathlib import Path
from typing import Any

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X
from numpy.typing import NDArray

from markergraph.estimator.paper import edge_from_pose2
from markergraph.estimator.types import Estimate, MarkerGraphError
from markergraph.frontend.files import written_whole

__all__ = [
    "MAP_SCHEMA",
    "MARKER_VERTEX_OFFSET",
    "ExportFormat",
    "MapFileError",
    "check_map_document",
    "estimate_values",
    "export_map",
    "map_document",
    "read_map",
    "read_tum",
    "write_g2o",
    "write_json",
    "write_tum",
]

MAP_SCHEMA = "markergraph.map/1"
# g2o has one id space: marker vertices start here so they never meet robot poses.
MARKER_VERTEX_OFFSET = 1_000_000


class MapFileError(MarkerGraphError):
    """A map.json that cannot be used; the message names the file and the field."""


def _write_text(path: Path, text: str) -> None:
    with written_whole(path) as partial:
        partial.write_text(text, encoding="utf-8")


def _covariance(matrix: NDArray[np.float64] | None) -> list[list[float]] | None:
    return None if matrix is None else [[float(v) for v in row] for row in matrix]


def map_document(
    estimate: Estimate,
    *,
    log: str,
    dictionary: str,
    marker_length_m: float,
    marker_lengths_m: Mapping[int, float] | None = None,
    marker_heights_m: Mapping[int, float] | None = None,
) -> dict[str, Any]:
    """The corrected marker graph as a JSON-ready document (schema ``markergraph.map/1``).

    Markers carry their pose in the map frame (the home marker's), their side (``size_m``:
    ``marker_lengths_m``'s where given, else ``marker_length_m``), a 3x3 covariance over
    (x, y, yaw) in the marker's own tangent space or null, and their observation count. Each
    link between markers carries the paper's edge values (phi, theta_ab, theta_ba, d) of the
    estimated map and the covariance of the relative pose ``T_a_b`` (markers taken as
    independent, which slightly overstates it where they are correlated).
    """
    heights, sides = marker_heights_m or {}, marker_lengths_m or {}
    markers = []
    for marker_id in sorted(estimate.markers):
        marker = estimate.markers[marker_id]
        T = marker.T_map_marker
        entry: dict[str, Any] = {
            "id": marker_id,
            "x": T.x(),
            "y": T.y(),
            "yaw": T.theta(),
            "size_m": sides.get(marker_id, marker_length_m),
            "covariance": _covariance(marker.covariance),
            "n_observations": marker.n_observations,
        }
        if marker_id in heights:
            entry["z"] = heights[marker_id]
        markers.append(entry)
    links = []
    for link in estimate.links:
        a, b = estimate.markers.get(link.marker_a), estimate.markers.get(link.marker_b)
        if a is None or b is None:
            continue
        T_a_b = a.T_map_marker.between(b.T_map_marker)
        edge = edge_from_pose2(T_a_b)
        covariance = None
        if a.covariance is not None and b.covariance is not None:
            ad = T_a_b.inverse().AdjointMap()
            covariance = ad @ a.covariance @ ad.T + b.covariance
        links.append(
            {
                "a": link.marker_a,
                "b": link.marker_b,
                "n_measurements": link.n_measurements,
                "phi": edge.phi,
                "theta_ab": edge.theta_ab,
                "theta_ba": edge.theta_ba,
                "d": edge.d,
                "covariance": _covariance(covariance),
            }
        )
    return {
        "schema": MAP_SCHEMA,
        "frame": f"map: the frame of home marker {estimate.home_id} (x along its normal)",
        "units": {"length": "m", "angle": "rad"},
        "home_id": estimate.home_id,
        "dictionary": dictionary,
        "marker_size_m": marker_length_m,
        "method": estimate.method.value,
        "log": log,
        "converged": estimate.converged,
        "markers": markers,
        "links": links,
        "unplaced": {str(k): v for k, v in sorted(estimate.unplaced.items())},
    }


def write_json(path: Path, document: dict[str, Any]) -> None:
    """A JSON document, indented, written atomically."""
    try:
        text = json.dumps(document, indent=1, allow_nan=False)
    except ValueError as error:  # a NaN got this far: a bug, never a file with NaN in it
        raise MarkerGraphError(f"{path}: refusing to write a non-finite value ({error})") from None
    _write_text(path, text + "\n")


def write_tum(path: Path, t_ns: NDArray[np.int64], poses: NDArray[np.float64]) -> None:
    """A trajectory in TUM format (``t tx ty tz qx qy qz qw``, seconds) for evo, atomically.

    Args:
        t_ns: (N,) stamps [ns]; poses: (N, 3) rows (x, y, yaw).
    """
    if not np.all(np.isfinite(poses)):
        raise MarkerGraphError(f"{path}: refusing to write a trajectory with non-finite poses")
    lines = []
    for t, (x, y, yaw) in zip(t_ns, poses, strict=True):
        seconds = f"{int(t) // 1_000_000_000}.{int(t) % 1_000_000_000:09d}"
        half = float(yaw) / 2.0
        lines.append(
            f"{seconds} {float(x)!r} {float(y)!r} 0.0 0.0 0.0 "
            f"{math.sin(half)!r} {math.cos(half)!r}\n"
        )
    _write_text(path, "".join(lines))


def read_tum(path: Path) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Stamps [ns] and (x, y, yaw) rows of a TUM trajectory (roll and pitch ignored).

    Raises:
        MarkerGraphError: a line that is not ``t tx ty tz qx qy qz qw``; it is named.
    """
    stamps, rows = [], []
    with open(path) as stream:
        for number, line in enumerate(stream, start=1):
            if not line.strip() or line.startswith("#"):
                continue
            fields = line.split()
            if len(fields) != 8:
                raise MarkerGraphError(
                    f"{path}:{number}: a TUM line has 8 fields, not {len(fields)}"
                )
            whole, _, fraction = fields[0].partition(".")
            stamps.append(int(whole) * 1_000_000_000 + int((fraction + "000000000")[:9]))
            x, y, _, qx, qy, qz, qw = map(float, fields[1:])
            rows.append([x, y, math.atan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz))])
    return np.array(stamps, dtype=np.int64), np.array(rows).reshape(-1, 3)


def _information(model: Any) -> NDArray[np.float64]:
    """The information matrix of a Gaussian noise model (or a robust one's Gaussian part)."""
    gaussian: Any = model.noise() if isinstance(model, gtsam.noiseModel.Robust) else model
    R = np.asarray(gaussian.R())  # square-root information
    return np.asarray(R.T @ R)


def estimate_values(estimate: Estimate) -> gtsam.Values:
    """An estimate as GTSAM values: ``X(k)`` for its k-th trajectory pose, ``L(id)`` per marker."""
    values = gtsam.Values()
    for k, (x, y, yaw) in enumerate(estimate.trajectory):
        values.insert(X(k), gtsam.Pose2(x, y, yaw))
    for marker_id, marker in estimate.markers.items():
        values.insert(L(marker_id), marker.T_map_marker)
    return values


def write_g2o(path: Path, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> None:
    """The optimised pose graph in g2o's text format, atomically.

    Robot poses ``X(k)`` become ``VERTEX_SE2 k`` and markers ``L(id)`` become
    ``VERTEX_SE2 1000000+id``; every between factor an ``EDGE_SE2`` with its full information
    matrix; full float precision. There is no header comment and no ``FIX`` line, because
    ``gtsam.readG2o`` returns no factors for such files (the home prior is left out with them:
    fix the home vertex when re-optimising). Unlike ``gtsam.writeG2o``, ids of robot poses and
    markers never collide and nothing is rounded.
    """

    def vertex(key: int) -> int:
        symbol = gtsam.Symbol(key)
        index = int(symbol.index())
        return index + MARKER_VERTEX_OFFSET if chr(symbol.chr()) == "l" else index

    lines = []
    for key in sorted(values.keys(), key=vertex):
        pose = values.atPose2(key)
        if not all(math.isfinite(v) for v in (pose.x(), pose.y(), pose.theta())):
            raise MarkerGraphError(f"{path}: refusing to write a non-finite pose ({pose})")
        lines.append(f"VERTEX_SE2 {vertex(key)} {pose.x()!r} {pose.y()!r} {pose.theta()!r}")
    for index in range(graph.size()):
        factor: Any = graph.at(index)
        if not isinstance(factor, gtsam.BetweenFactorPose2):
            continue
        measured = factor.measured()
        info = _information(factor.noiseModel())
        keys = factor.keys()  # a gtsam KeyVector
        first, second = vertex(keys[0]), vertex(keys[1])
        upper = [info[0, 0], info[0, 1], info[0, 2], info[1, 1], info[1, 2], info[2, 2]]
        lines.append(
            f"EDGE_SE2 {first} {second} {measured.x()!r} {measured.y()!r} "
            f"{measured.theta()!r} " + " ".join(repr(float(v)) for v in upper)
        )
    _write_text(path, "\n".join(lines) + "\n")


# --- peer formats, from a map.json document ---------------------------------------------------


class ExportFormat(Enum):
    """Formats ``markergraph export`` writes."""

    ARUCO_YAML = "aruco-yaml"  # the ArUco library's MarkerMap (corners in metres)
    FIDUCIAL_SLAM = "fiducial-slam"  # UbiquityRobotics fiducial_slam map.txt (degrees)
    TAGSLAM = "tagslam"  # a TagSLAM static body of tags (rotation vectors)
    CSV = "csv"


def _R_map_tag(yaw: float) -> NDArray[np.float64]:
    """A wall marker's rotation in OpenCV's marker convention (x to the viewer's right, y up,
    z out of the marker) from its top-view yaw (the normal's heading)."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[-s, 0.0, c], [c, 0.0, s], [0.0, 1.0, 0.0]])


def _corners(marker: dict[str, Any], size: float) -> NDArray[np.float64]:
    """The black square's corners in the map, OpenCV's order (top-left first)."""
    R = _R_map_tag(marker["yaw"])
    centre = np.array([marker["x"], marker["y"], marker.get("z", 0.0)])
    right, up = R[:, 0] * size / 2.0, R[:, 1] * size / 2.0
    return np.array(
        [centre - right + up, centre + right + up, centre + right - up, centre - right - up]
    )


def _sigmas(marker: dict[str, Any]) -> tuple[float, float, float]:
    covariance = marker.get("covariance")
    if covariance is None:
        return (0.0, 0.0, 0.0)
    diagonal = np.sqrt(np.maximum(np.diag(np.array(covariance)), 0.0))
    return (float(diagonal[0]), float(diagonal[1]), float(diagonal[2]))


def _reject_constant(name: str) -> None:
    raise ValueError(f"{name} is not a number JSON allows")


def _finite(where: str, value: Any, *, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise MapFileError(f"{where} must be a finite number, got {value!r}")
    if positive and value <= 0:
        raise MapFileError(f"{where} must be positive, got {value!r}")
    return float(value)


def _whole(where: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise MapFileError(f"{where} must be a whole number >= 0, got {value!r}")
    return value


def check_map_document(document: Any, source: str) -> None:
    """Check that a document is a usable ``markergraph.map/1`` map.

    Raises:
        MapFileError: one line naming ``source`` and the first bad field.
    """
    if not isinstance(document, dict) or document.get("schema") != MAP_SCHEMA:
        found = document.get("schema") if isinstance(document, dict) else type(document).__name__
        raise MapFileError(f"{source}: not a {MAP_SCHEMA} document (schema {found!r})")
    _finite(f"{source}: marker_size_m", document.get("marker_size_m"), positive=True)
    if not isinstance(document.get("dictionary"), str):
        raise MapFileError(
            f"{source}: dictionary must be a name, got {document.get('dictionary')!r}"
        )
    markers = document.get("markers")
    if not isinstance(markers, list):
        raise MapFileError(f"{source}: markers must be a list, got {markers!r}")
    for i, marker in enumerate(markers):
        where = f"{source}: markers[{i}]"
        if not isinstance(marker, dict):
            raise MapFileError(f"{where} must be an object, got {marker!r}")
        _whole(f"{where}.id", marker.get("id"))
        for name in ("x", "y", "yaw"):
            _finite(f"{where}.{name}", marker.get(name))
        if "z" in marker:
            _finite(f"{where}.z", marker["z"])
        if "size_m" in marker:
            _finite(f"{where}.size_m", marker["size_m"], positive=True)
        _whole(f"{where}.n_observations", marker.get("n_observations"))
        covariance = marker.get("covariance")
        if covariance is not None:
            matrix = np.asarray(covariance, dtype=object)
            if matrix.shape != (3, 3):
                raise MapFileError(f"{where}.covariance must be 3x3 or null")
            for v in matrix.ravel():
                _finite(f"{where}.covariance", v)


def read_map(path: Path) -> dict[str, Any]:
    """A ``map.json`` written by ``markergraph map``, checked (see :func:`check_map_document`).

    Raises:
        MapFileError: the file cannot be read, is not strict JSON, or is not a usable map;
            the message names the file and the field.
    """
    path = Path(path)
    try:
        document = json.loads(path.read_text(encoding="utf-8"), parse_constant=_reject_constant)
    except OSError as error:
        raise MapFileError(f"{path}: cannot read it ({error.strerror})") from None
    except UnicodeDecodeError:
        raise MapFileError(f"{path}: not UTF-8 text, so not a map.json") from None
    except ValueError as error:
        raise MapFileError(f"{path}: not a JSON document ({error})") from None
    check_map_document(document, str(path))
    return document


def export_map(document: dict[str, Any], fmt: ExportFormat, path: Path) -> None:
    """Write a ``markergraph.map/1`` document in another tool's format, atomically.

    Marker heights come from the document's ``z`` (0 where unknown); orientations are those of
    markers on vertical walls.

    Raises:
        MapFileError: the document is not a usable markergraph map.
    """
    check_map_document(document, "the map")
    default_size = float(document["marker_size_m"])
    markers = document["markers"]

    def size(marker: dict[str, Any]) -> float:
        return float(marker.get("size_m", default_size))

    lines: list[str] = []
    if fmt is ExportFormat.CSV:
        lines.append("id,x_m,y_m,z_m,yaw_rad,sigma_x_m,sigma_y_m,sigma_yaw_rad,n_observations")
        for m in markers:
            sx, sy, syaw = _sigmas(m)
            lines.append(
                f"{m['id']},{m['x']!r},{m['y']!r},{float(m.get('z', 0.0))!r},"
                f"{m['yaw']!r},{sx!r},{sy!r},{syaw!r},{m['n_observations']}"
            )
    elif fmt is ExportFormat.ARUCO_YAML:
        lines += [
            "%YAML:1.0",
            f"aruco_bc_dict: {document['dictionary']}",
            f"aruco_bc_nmarkers: {len(markers)}",
            "aruco_bc_mInfoType: 1",
            "aruco_bc_markers:",
        ]
        for m in markers:
            corners = ", ".join(
                "[" + ", ".join(repr(float(v)) for v in corner) + "]"
                for corner in _corners(m, size(m))
            )
            lines.append(f"   - {{ id: {m['id']}, corners: [ {corners} ] }}")
    elif fmt is ExportFormat.FIDUCIAL_SLAM:
        for m in markers:
            roll, pitch, yaw = (float(a) for a in gtsam.Rot3(_R_map_tag(m["yaw"])).rpy())
            sx, sy, _ = _sigmas(m)
            angles = " ".join(f"{math.degrees(a)!r}" for a in (roll, pitch, yaw))
            lines.append(
                f"{m['id']} {m['x']!r} {m['y']!r} {float(m.get('z', 0.0))!r} {angles} "
                f"{sx * sx + sy * sy!r} {m['n_observations']}"
            )
    else:
        lines += [
            "bodies:",
            " - map:",
            "     is_static: true",
            "     type: simple",
            f"     default_tag_size: {default_size!r}",
            "     tags:",
        ]
        for m in markers:
            rotation = [float(v) for v in gtsam.Rot3.Logmap(gtsam.Rot3(_R_map_tag(m["yaw"])))]
            sx, sy, syaw = _sigmas(m)
            lines += [
                f"       - id: {m['id']}",
                f"         size: {size(m)!r}",
                "         pose:",
                f"           position: {{x: {m['x']!r}, y: {m['y']!r}, "
                f"z: {float(m.get('z', 0.0))!r}}}",
                f"           rotation: {{x: {rotation[0]!r}, y: {rotation[1]!r}, "
                f"z: {rotation[2]!r}}}",
                f"           position_noise: {{x: {sx!r}, y: {sy!r}, z: {max(sx, sy)!r}}}",
                f"           rotation_noise: {{x: {syaw!r}, y: {syaw!r}, z: {syaw!r}}}",
            ]
    _write_text(path, "\n".join(lines) + "\n")
