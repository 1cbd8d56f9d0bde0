"""The ArUco library's MarkerMap file (``%YAML:1.0``, each marker's four corners in metres, as
``markergraph export --format aruco-yaml`` writes) read into
:class:`~markergraph.estimator.tags3d.KnownTag` records, as :mod:`markergraph.frontend.survey`
reads the other survey files.

A marker's pose comes from its corners in OpenCV's order (top-left, top-right, bottom-right,
bottom-left): the centre is their mean, x runs top-left to top-right, y bottom-left to
top-left, z out of the print (the tag frame). The file states no uncertainty, so the sigmas are
the survey defaults.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import gtsam
import numpy as np
import yaml
from numpy.typing import NDArray

from markergraph.common.errors import SettingsError
from markergraph.estimator.tags3d import KnownTag

__all__ = ["ARUCO_MARKERS_KEY", "SQUARE_TOLERANCE", "is_aruco_map", "read_aruco_tags"]

ARUCO_MARKERS_KEY = "aruco_bc_markers"
"""The key of the marker list in an ArUco MarkerMap."""
SQUARE_TOLERANCE = 1e-3
"""Relative tolerance on the corners making a square (sides equal, right angles): an exported
map's are exact to the last digit printed."""


def is_aruco_map(path: Path) -> bool:
    """Whether a ``.yml``/``.yaml`` file is an ArUco MarkerMap (OpenCV's ``%YAML:1.0`` header,
    or the ``aruco_bc_markers`` key) rather than a TagSLAM file."""
    try:
        with Path(path).open(encoding="utf-8-sig", errors="replace") as stream:
            head = stream.read(4096)
    except OSError:
        return False  # the TagSLAM reader names the file and the reason
    return head.lstrip().startswith("%YAML:") or ARUCO_MARKERS_KEY in head


def _document(path: Path) -> Any:
    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as error:
        raise SettingsError(f"{path}: not a readable ArUco map ({error})") from None
    # OpenCV writes "%YAML:1.0", which no YAML parser takes as a directive: drop that line.
    lines = text.splitlines()
    if lines and lines[0].startswith("%YAML:"):
        lines = lines[1:]
    try:
        return yaml.safe_load("\n".join(lines))
    except yaml.YAMLError as error:
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise SettingsError(f"{path}: not a readable ArUco map ({reason})") from None


def _corners(value: Any, where: str) -> NDArray[np.float64]:
    try:
        corners = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise SettingsError(f"{where}.corners: not four [x, y, z] corners") from None
    if corners.shape != (4, 3):
        raise SettingsError(f"{where}.corners: not four [x, y, z] corners (shape {corners.shape})")
    if not np.all(np.isfinite(corners)):
        raise SettingsError(f"{where}.corners: a corner is not a finite number")
    return corners


def _T_map_tag(corners: NDArray[np.float64], where: str) -> gtsam.Pose3:
    """The tag's pose from its corners (see the module's docstring); a shape that is not a
    square is refused."""
    across = corners[1] - corners[0]
    up = corners[0] - corners[3]
    side = float(np.linalg.norm(across))
    sides = [float(np.linalg.norm(corners[(k + 1) % 4] - corners[k])) for k in range(4)]
    if side <= 0.0 or max(abs(s - side) for s in sides) > SQUARE_TOLERANCE * side:
        raise SettingsError(f"{where}.corners: not a square (sides {sides})")
    if abs(float(across @ up)) > SQUARE_TOLERANCE * side * side:
        raise SettingsError(f"{where}.corners: not a square (no right angle at the top-left)")
    x_axis = across / side
    z_axis = np.cross(across, up)
    z_axis /= np.linalg.norm(z_axis)
    R = np.column_stack([x_axis, np.cross(z_axis, x_axis), z_axis])
    return gtsam.Pose3(gtsam.Rot3(R), corners.mean(axis=0))


def read_aruco_tags(path: Path, sigma_rot_rad: float, sigma_xyz_m: float) -> list[KnownTag]:
    """Every marker of an ArUco MarkerMap as a known tag, in the file's order.

    Args:
        path: the map file.
        sigma_rot_rad, sigma_xyz_m: the sigmas given every tag (the file states none).

    Raises:
        SettingsError: unreadable, no marker list, or a marker without an id or four corners
            that make a square; one line naming the file and the marker.
    """
    document = _document(path)
    markers = document.get(ARUCO_MARKERS_KEY) if isinstance(document, dict) else None
    if not isinstance(markers, list):
        raise SettingsError(f"{path}: not an ArUco map (no {ARUCO_MARKERS_KEY} list)")
    sigmas = np.array([sigma_rot_rad] * 3 + [sigma_xyz_m] * 3)
    tags = []
    for i, entry in enumerate(markers):
        where = f"{path}: {ARUCO_MARKERS_KEY}[{i}]"
        if not isinstance(entry, dict):
            raise SettingsError(f"{where}: not a table")
        marker_id = entry.get("id")
        if isinstance(marker_id, float) and math.isfinite(marker_id) and marker_id.is_integer():
            marker_id = int(marker_id)  # OpenCV may write ids as reals
        if isinstance(marker_id, bool) or not isinstance(marker_id, int) or marker_id < 0:
            raise SettingsError(f"{where}.id: not a marker id ({marker_id!r})")
        T_map_tag = _T_map_tag(_corners(entry.get("corners"), where), where)
        tags.append(KnownTag(marker_id, T_map_tag, sigmas.copy()))
    return tags
