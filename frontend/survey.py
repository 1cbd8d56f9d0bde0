"""Surveyed tags as the 3-D map's priors: TagSLAM's ``tagslam.yaml``, a CSV survey, or a map
markergraph wrote (``map.json``), each read into :class:`~markergraph.estimator.tags3d.KnownTag`
records (the tag frame: AprilTag's, z out of the print).

Sigmas are over GTSAM's Pose3 tangent in the tag's own frame (rotation [rad], then translation
[m]), as TagSLAM's pose priors take its ``rotation_noise`` and ``position_noise``. A survey that
states its uncertainty in the map's axes (a CSV without heights) is turned into the tag's axes
and only the diagonal kept (``KnownTag`` holds no correlations).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.common.documents import (
    MAX_MARKER_ID,
    MAX_MARKERS,
    DocumentError,
    json_document,
    read_text,
)
from markergraph.common.errors import SettingsError
from markergraph.common.notes import Note
from markergraph.estimator.tags3d import R_TAG_MARKER, KnownTag
from markergraph.frontend.aruco_map import is_aruco_map, read_aruco_tags
from markergraph.frontend.rig import Pose3, load_yaml, tagslam_pose

__all__ = [
    "CSV_COLUMNS",
    "MIN_SIGMA",
    "SIGMA_ROT_RAD",
    "SIGMA_UNKNOWN_M",
    "SIGMA_UNKNOWN_RAD",
    "SIGMA_XYZ_M",
    "WALL_TILT_SIGMA_RAD",
    "Survey",
    "SurveyKind",
    "TagRemap",
    "read_known_tags",
    "read_survey",
]

SIGMA_XYZ_M = 0.01
"""A CSV survey's position sigma where it states none (and a map.json's without a covariance)."""
SIGMA_ROT_RAD = 0.01
"""A CSV survey's rotation sigma where it states none (and a map.json's without a covariance)."""
SIGMA_UNKNOWN_M = 10.0
"""The sigma of a coordinate a survey does not give (a CSV or a 2-D map without z): wide enough
that the tags seen decide it, narrow enough to keep the prior well conditioned."""
SIGMA_UNKNOWN_RAD = 10.0
"""The rotation sigma of a tag surveyed without a yaw (its position alone is known): a prior
this wide (a rotation error is at most pi) leaves the orientation to the tags seen."""
WALL_TILT_SIGMA_RAD = 0.02
"""Roll and pitch sigma of a 2-D map's wall tag, taken as vertical (a wall is plumb to about a
degree)."""
MIN_SIGMA = 1e-6
"""Smallest sigma passed on: a map's home marker may carry a zero covariance, which a prior
cannot take."""
CSV_COLUMNS = ("id", "x", "y", "z", "yaw", "sigma_xyz", "sigma_rot")
"""The columns a CSV survey may have (``id``, ``x``, ``y`` required)."""
_UNIT_NAMED = {"x_m": "x", "y_m": "y", "z_m": "z", "yaw_rad": "yaw"}
"""``export --format csv``'s names of those columns, units in them."""
_EXPORT_ONLY = frozenset(("sigma_x_m", "sigma_y_m", "sigma_yaw_rad", "sigma_z_m", "n_observations",
                          "qw", "qx", "qy", "qz", "sigma_rx_rad", "sigma_ry_rad", "sigma_rz_rad",
                          "wall"))  # fmt: skip
"""Its other columns, which a survey reads past."""
_MAP_SCHEMAS = ("markergraph.map/1", "markergraph.map/2")
SYMMETRY_TOLERANCE = 1e-9  # a covariance's asymmetry and negative eigenvalue rounding leaves
_BOARD_TYPES = ("board", "staggered_board")


class SurveyKind(Enum):
    """Which file a survey came from."""

    TAGSLAM = "tagslam.yaml"
    CSV = "csv"
    MAP_JSON = "map.json"
    ARUCO = "aruco"


@dataclass(frozen=True, slots=True)
class TagRemap:
    """TagSLAM's ``tag_id_remap``: detections of ``tag_id`` between the two times are tag
    ``remap_id`` (two tags printed with one id).

    Attributes:
        tag_id: the id detected.
        remap_id: the id it stands for in that span.
        start_ns, end_ns: the span [ns] (header stamps; float seconds in the file, so to about a
            microsecond).
    """

    tag_id: int
    remap_id: int
    start_ns: int
    end_ns: int


@dataclass(frozen=True, slots=True)
class Survey:
    """What a survey file gives the 3-D map.

    Attributes:
        kind: the file's kind.
        tags: the surveyed tags, in id order (poses in the map frame, the tag frame).
        ignored_ids: tags the file says to leave out (TagSLAM's ``ignore_tags``).
        remaps: TagSLAM's id remaps.
        notes: what was read but not used (boards, tags on moving bodies), and defaults taken.
    """

    kind: SurveyKind
    tags: tuple[KnownTag, ...]
    ignored_ids: frozenset[int] = frozenset()
    remaps: tuple[TagRemap, ...] = ()
    notes: tuple[Note, ...] = ()


def read_known_tags(path: Path) -> list[KnownTag]:
    """The surveyed tags of a ``tagslam.yaml``, a CSV survey or a ``map.json`` (by suffix);
    :func:`read_survey` also gives the ignored ids, remaps and notes.

    Raises:
        SettingsError: unreadable, or a bad field; one line naming the file and the field.
    """
    return list(read_survey(path).tags)


def read_survey(path: Path) -> Survey:
    """A survey file read by its suffix: ``.yaml``/``.yml`` TagSLAM's ``tagslam.yaml`` (or an
    ArUco MarkerMap, by its ``%YAML:1.0`` header: :mod:`~markergraph.frontend.aruco_map`),
    ``.csv`` a CSV survey (see :func:`_csv_survey`), ``.json`` markergraph's ``map.json``.

    Raises:
        SettingsError: an unknown suffix, an unreadable file or a bad field; one line naming
            the file and the field.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in (".yaml", ".yml"):
        if is_aruco_map(path):
            tags = read_aruco_tags(path, SIGMA_ROT_RAD, SIGMA_XYZ_M)
            return Survey(SurveyKind.ARUCO, _sorted_unique(tags, str(path)))
        return _tagslam_survey(path)
    if suffix == ".csv":
        return _csv_survey(path)
    if suffix == ".json":
        return _map_survey(path)
    raise SettingsError(
        f"{path}: not a survey (a tagslam.yaml, a .csv or a map.json; suffix {suffix!r})"
    )


# --- shared ------------------------------------------------------------------------------


def _gtsam_pose(pose: Pose3) -> gtsam.Pose3:
    return gtsam.Pose3(gtsam.Rot3(pose.R), np.asarray(pose.t, dtype=np.float64))


def _number(value: Any, where: str, positive: bool = False) -> float:
    """A finite float (strings such as ``1e-5``, which YAML 1.1 leaves as text, included)."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise SettingsError(f"{where}: not a number ({value!r})") from None
    if not math.isfinite(number) or (positive and number <= 0.0):
        raise SettingsError(f"{where}: {value!r} is not a {'positive ' if positive else ''}number")
    return number


def _whole(value: Any, where: str) -> int:
    """A tag id: a whole number from 0 to :data:`MAX_MARKER_ID` (GTSAM's keys and OpenCV's
    ids take no more), as a number or as decimal text."""
    if isinstance(value, bool) or not isinstance(value, (int, str)):
        raise SettingsError(f"{where}: not a tag id ({value!r})")
    text = value.strip() if isinstance(value, str) else None
    if text is not None and not (text.isascii() and text.isdigit() and len(text) <= 10):
        raise SettingsError(f"{where}: not a tag id ({_short(value)})")
    number = int(value)
    if not 0 <= number <= MAX_MARKER_ID:
        raise SettingsError(f"{where}: tag id {_short(number)} is not from 0 to {MAX_MARKER_ID:,}")
    return number


def _short(value: Any) -> str:
    """``repr(value)``, cut to 40 characters (a tampered file's 5,000-digit id)."""
    text = repr(value)
    return text if len(text) <= 40 else f"{text[:20]}... ({len(text)} characters)"


def _at_most(count: int, where: str) -> None:
    """A survey holds no more tags than :data:`MAX_MARKERS`."""
    if count > MAX_MARKERS:
        raise SettingsError(f"{where}: {count:,} surveyed tags, more than {MAX_MARKERS:,}")


def _read(path: Path, what: str) -> str:
    """A survey file's text, its size checked before it is read."""
    try:
        return read_text(path)
    except (OSError, UnicodeDecodeError, DocumentError) as error:
        raise SettingsError(f"{path}: not a readable {what} ({error})") from None


def _local_sigmas(
    R_map_tag: NDArray[np.float64],
    rot_cov_map: NDArray[np.float64],
    xyz_cov_map: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Six tag-frame sigmas (rotation, translation) from covariances stated in the map's axes
    (GTSAM's Pose3 tangent is in the pose's own frame: a vector v in the map is R^T v there)."""
    rotation = R_map_tag.T @ rot_cov_map @ R_map_tag
    translation = R_map_tag.T @ xyz_cov_map @ R_map_tag
    variances = np.concatenate([np.diag(rotation), np.diag(translation)])
    return np.maximum(np.sqrt(np.maximum(variances, 0.0)), MIN_SIGMA)


def _tag_from_marker_cov(covariance_marker: NDArray[np.float64]) -> NDArray[np.float64]:
    """Six tag-frame sigmas from a 6x6 over the marker frame's tangent (the inverse of
    :attr:`~markergraph.estimator.tags3d.Tag3d.marker_covariance`)."""
    A = np.zeros((6, 6))
    A[:3, :3] = A[3:, 3:] = R_TAG_MARKER.T
    covariance_tag = A.T @ covariance_marker @ A
    return np.maximum(np.sqrt(np.maximum(np.diag(covariance_tag), 0.0)), MIN_SIGMA)


def _R_map_tag_of_wall(yaw_rad: float) -> NDArray[np.float64]:
    """A wall tag's rotation: the marker frame turned by ``yaw_rad`` about the vertical (x the
    normal into the room, z up), expressed in the tag frame."""
    return gtsam.Rot3.Rz(yaw_rad).matrix() @ R_TAG_MARKER.T


def _sorted_unique(tags: Iterable[KnownTag], where: str) -> tuple[KnownTag, ...]:
    by_id: dict[int, KnownTag] = {}
    for tag in tags:
        if tag.tag_id in by_id:
            raise SettingsError(f"{where}: tag {tag.tag_id} is surveyed twice")
        by_id[tag.tag_id] = tag
    return tuple(by_id[i] for i in sorted(by_id))


# --- TagSLAM's tagslam.yaml ----------------------------------------------------------------


def _noise3(value: Any, where: str) -> NDArray[np.float64]:
    """A TagSLAM noise: a table x, y, z, or one number for all three."""
    if isinstance(value, Mapping):
        if not all(k in value for k in "xyz"):
            raise SettingsError(f"{where}: a noise needs x, y and z")
        return np.array([_number(value[k], f"{where}.{k}", positive=True) for k in "xyz"])
    return np.full(3, _number(value, where, positive=True))


def _tag_noise(
    tag_pose: Mapping[str, Any], body: Mapping[str, Any], defaults: Mapping[str, Any], where: str
) -> NDArray[np.float64]:
    """A surveyed tag's six sigmas: the body's ``override_tag_*_noise`` where given (they win,
    as in TagSLAM), else the tag's own ``rotation_noise`` / ``position_noise``, else
    ``body_defaults``."""
    sigmas = []
    for kind in ("rotation", "position"):
        key = f"override_tag_{kind}_noise"
        override = body.get(key)
        # TagSLAM's default for "no override" is -1: only a positive value overrides.
        if override is not None and _number(override, f"{where} {key}") > 0:
            sigmas.append(np.full(3, float(override)))
        elif tag_pose.get(f"{kind}_noise") is not None:
            sigmas.append(_noise3(tag_pose[f"{kind}_noise"], f"{where}.pose.{kind}_noise"))
        elif defaults.get(f"{kind}_noise") is not None:
            sigmas.append(_noise3(defaults[f"{kind}_noise"], f"body_defaults.{kind}_noise"))
        else:
            raise SettingsError(f"{where}.pose: no {kind}_noise (and none in body_defaults)")
    return np.concatenate(sigmas)


def _body_tags(
    name: str, body: Mapping[str, Any], defaults: Mapping[str, Any], where: str
) -> tuple[list[KnownTag], list[Note]]:
    """The surveyed tags of one body of a tagslam.yaml, composed into the map frame
    (T_map_tag = T_map_body * T_body_tag), and notes on what it holds but gives no pose for."""
    entries = body.get("tags") or []
    if not isinstance(entries, list):
        raise SettingsError(f"{where}.tags: not a list")
    posed = [t for t in entries if isinstance(t, Mapping) and t.get("pose") is not None]
    if str(body.get("type")) in _BOARD_TYPES:
        if body.get("pose") is not None or posed:
            text = (
                f"{where}: a {body.get('type')} with a surveyed pose; its tags' poses come from "
                "the board's layout, which is not read: no tag of it is a known tag"
            )
            return [], [Note("survey.board_not_read", text, name)]
        return [], []
    if not body.get("is_static"):
        if posed:
            text = f"{where}: {len(posed)} tag(s) with poses on a moving body: not map tags"
            return [], [Note("survey.moving_body", text, name, len(posed))]
        return [], []
    T_map_body = (
        _gtsam_pose(tagslam_pose(body["pose"], f"{where}.pose"))
        if body.get("pose") is not None
        else gtsam.Pose3()
    )
    tags = []
    for tag in posed:
        tag_id = _whole(tag.get("id"), f"{where}.tags[].id")
        here = f"{where}.tags[id {tag_id}]"
        T_body_tag = _gtsam_pose(tagslam_pose(tag["pose"], f"{here}.pose"))
        sigmas = _tag_noise(tag["pose"], body, defaults, here)
        tags.append(KnownTag(tag_id, T_map_body.compose(T_body_tag), sigmas))
    return tags, []


def _remaps(document: Mapping[str, Any], path: Path) -> list[TagRemap]:
    remaps = []
    for i, entry in enumerate(document.get("tag_id_remap") or []):
        where = f"{path}: tag_id_remap[{i}]"
        if not isinstance(entry, Mapping):
            raise SettingsError(f"{where}: not a table")
        tag_id = _whole(entry.get("id"), f"{where}.id")
        for j, remap in enumerate(entry.get("remaps") or []):
            here = f"{where}.remaps[{j}]"
            if not isinstance(remap, Mapping):
                raise SettingsError(f"{here}: not a table")
            start, end = (
                round(_number(remap.get(k), f"{here}.{k}") * 1e9)
                for k in ("start_time", "end_time")
            )
            remaps.append(
                TagRemap(tag_id, _whole(remap.get("remap_id"), f"{here}.remap_id"), start, end)
            )
    return remaps


def _tagslam_survey(path: Path) -> Survey:
    """Every tag with a ``pose`` in a static simple body of a tagslam.yaml."""
    document = load_yaml(path, "TagSLAM tagslam.yaml")
    bodies = document.get("bodies") if isinstance(document, Mapping) else None
    if not isinstance(bodies, list):
        raise SettingsError(f"{path}: not a tagslam.yaml (no bodies list)")
    defaults = document.get("body_defaults") or {}
    if not isinstance(defaults, Mapping):
        raise SettingsError(f"{path}: body_defaults is not a table")
    tags: list[KnownTag] = []
    notes: list[Note] = []
    ignored: set[int] = set()
    for item in bodies:
        if not isinstance(item, Mapping):
            raise SettingsError(f"{path}: bodies holds {item!r}, not a body")
        for name, body in item.items():
            where = f"{path}: bodies.{name}"
            if not isinstance(body, Mapping):
                raise SettingsError(f"{where}: not a table")
            ignore = body.get("ignore_tags") or []
            if not isinstance(ignore, list):
                raise SettingsError(f"{where}.ignore_tags: not a list")
            ignored.update(_whole(i, f"{where}.ignore_tags") for i in ignore)
            body_tags, body_notes = _body_tags(str(name), body, defaults, where)
            tags += body_tags
            notes += body_notes
    _at_most(len(tags), str(path))
    left_out = sorted(t.tag_id for t in tags if t.tag_id in ignored)
    if left_out:
        text = f"{path}: surveyed tag(s) {left_out} are in ignore_tags: left out"
        notes.append(Note("survey.ignored", text, str(path), len(left_out)))
    kept = _sorted_unique((t for t in tags if t.tag_id not in ignored), str(path))
    return Survey(SurveyKind.TAGSLAM, kept, frozenset(ignored), tuple(_remaps(document, path)),
                  tuple(notes))  # fmt: skip


# --- a CSV survey --------------------------------------------------------------------------


def _csv_row(row: Mapping[str, str], where: str) -> tuple[KnownTag, bool]:
    """One CSV row as a known tag, and whether it lacked z."""
    tag_id = _whole(row["id"].strip(), f"{where}.id")

    def value(column: str, default: float | None, positive: bool = False) -> float | None:
        text = (row.get(column) or "").strip()
        return default if not text else _number(text, f"{where}.{column}", positive)

    x, y = (_number(row[k], f"{where}.{k}") for k in ("x", "y"))
    z, yaw = value("z", None), value("yaw", None)
    sigma_xyz = value("sigma_xyz", SIGMA_XYZ_M, positive=True) or SIGMA_XYZ_M
    sigma_rot = value("sigma_rot", SIGMA_ROT_RAD, positive=True) or SIGMA_ROT_RAD
    R_map_tag = _R_map_tag_of_wall(0.0 if yaw is None else yaw)
    xyz_cov = np.diag([sigma_xyz, sigma_xyz, SIGMA_UNKNOWN_M if z is None else sigma_xyz]) ** 2
    rot_cov = np.eye(3) * (SIGMA_UNKNOWN_RAD if yaw is None else sigma_rot) ** 2
    pose = gtsam.Pose3(gtsam.Rot3(R_map_tag), np.array([x, y, 0.0 if z is None else z]))
    return KnownTag(tag_id, pose, _local_sigmas(R_map_tag, rot_cov, xyz_cov)), z is None


def _csv_survey(path: Path) -> Survey:
    """A CSV survey: a header row ``id,x,y[,z][,yaw][,sigma_xyz,sigma_rot]`` (metres,
    radians; or as ``export --format csv`` writes them, ``x_m`` ... ``yaw_rad``, its other
    columns read past), one wall tag a row, ``yaw`` the heading of its normal into the room
    (markergraph's marker frame: x the normal, z up), converted to the tag frame. Without z a
    tag is at z = 0 with a :data:`SIGMA_UNKNOWN_M` sigma in height; without yaw its rotation
    is free (:data:`SIGMA_UNKNOWN_RAD`); sigmas default to :data:`SIGMA_XYZ_M` and
    :data:`SIGMA_ROT_RAD`."""
    lines = _read(path, "CSV survey").splitlines()
    _at_most(sum(1 for line in lines if line.strip() and not line.startswith("#")) - 1, str(path))
    reader = csv.DictReader(line for line in lines if line.strip() and not line.startswith("#"))
    columns = [_UNIT_NAMED.get(c.strip(), c.strip()) for c in reader.fieldnames or []]
    reader.fieldnames = columns
    missing = [c for c in ("id", "x", "y") if c not in columns]
    unknown = [c for c in columns if c not in CSV_COLUMNS and c not in _EXPORT_ONLY]
    if missing or unknown:
        what = f"no column {missing[0]!r}" if missing else f"unknown column {unknown[0]!r}"
        raise SettingsError(f"{path}: {what} (a header row {','.join(CSV_COLUMNS)})")
    tags, flat = [], 0
    for n, row in enumerate(reader, start=2):
        if None in row or any(row.get(c) is None for c in ("id", "x", "y")):
            raise SettingsError(f"{path}: row {n} does not match the header")
        tag, no_z = _csv_row(row, f"{path}: row {n}")
        tags.append(tag)
        flat += no_z
    notes = []
    if flat:
        text = (
            f"{path}: {flat} surveyed tag(s) without z: placed at z = 0 with a "
            f"{SIGMA_UNKNOWN_M:g} m sigma in height"
        )
        notes.append(Note("survey.no_z", text, str(path), flat))
    return Survey(SurveyKind.CSV, _sorted_unique(tags, str(path)), notes=tuple(notes))


# --- markergraph's map.json ----------------------------------------------------------------


def _matrix(value: Any, n: int, where: str) -> NDArray[np.float64] | None:
    if value is None:
        return None
    try:
        matrix = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise SettingsError(f"{where}: not a {n}x{n} matrix") from None
    if matrix.shape != (n, n) or not np.all(np.isfinite(matrix)):
        raise SettingsError(f"{where}: not a finite {n}x{n} matrix")
    # A covariance: symmetric, no negative eigenvalue beyond rounding's (clipped to 0); a
    # negative variance would otherwise be held at MIN_SIGMA, the tightest of all.
    scale = max(float(np.max(np.abs(matrix))), 1e-300)
    if not np.all(np.abs(matrix - matrix.T) <= SYMMETRY_TOLERANCE * scale):
        raise SettingsError(f"{where}: not a symmetric matrix (a covariance)")
    values, vectors = np.linalg.eigh(0.5 * (matrix + matrix.T))
    if float(values[0]) < -SYMMETRY_TOLERANCE * scale:
        raise SettingsError(
            f"{where}: not positive semi-definite (a negative variance, {float(values[0]):.3g})"
        )
    return np.asarray((vectors * np.maximum(values, 0.0)) @ vectors.T, dtype=np.float64)


def _map_marker_sigmas(entry: Mapping[str, Any], where: str) -> NDArray[np.float64]:
    """A 2-D map marker's six tag-frame sigmas: its 3x3 over (x, y, yaw) in the marker's own
    tangent, roll and pitch :data:`WALL_TILT_SIGMA_RAD`, height ``sigma_z`` (else
    :data:`SIGMA_XYZ_M` with a z, :data:`SIGMA_UNKNOWN_M` without)."""
    covariance3 = _matrix(entry.get("covariance"), 3, f"{where}.covariance")
    if covariance3 is None:
        covariance3 = np.diag([SIGMA_XYZ_M**2, SIGMA_XYZ_M**2, SIGMA_ROT_RAD**2])
    if entry.get("sigma_z") is not None:
        sigma_z = _number(entry["sigma_z"], f"{where}.sigma_z", positive=True)
    else:
        sigma_z = SIGMA_XYZ_M if entry.get("z") is not None else SIGMA_UNKNOWN_M
    covariance = np.diag(
        [WALL_TILT_SIGMA_RAD**2, WALL_TILT_SIGMA_RAD**2, 0.0, 0.0, 0.0, sigma_z**2]
    )
    order = [3, 4, 2]  # (x, y, yaw) in GTSAM's Pose3 tangent (rx, ry, rz, tx, ty, tz)
    covariance[np.ix_(order, order)] = covariance3
    return _tag_from_marker_cov(covariance)


def _map_entry(entry: Any, where: str) -> KnownTag:
    """One map.json marker as a known tag: its ``quaternion`` and ``covariance_6x6`` (a 3-D
    map's) where present, else x, y, z and yaw of a wall tag."""
    if not isinstance(entry, Mapping):
        raise SettingsError(f"{where}: not a table")
    tag_id = _whole(entry.get("id"), f"{where}.id")
    x, y = (_number(entry.get(k), f"{where}.{k}") for k in ("x", "y"))
    z = 0.0 if entry.get("z") is None else _number(entry["z"], f"{where}.z")
    to_tag = gtsam.Rot3(R_TAG_MARKER.T)
    if entry.get("quaternion") is not None:
        q = entry["quaternion"]
        if not isinstance(q, list) or len(q) != 4:
            raise SettingsError(f"{where}.quaternion: not [w, x, y, z]")
        w, qx, qy, qz = (_number(v, f"{where}.quaternion") for v in q)
        norm = math.sqrt(w * w + qx * qx + qy * qy + qz * qz)
        if abs(norm - 1.0) > 1e-3:
            raise SettingsError(f"{where}.quaternion: not a unit quaternion (norm {norm:.6g})")
        R_map_marker = gtsam.Rot3.Quaternion(w / norm, qx / norm, qy / norm, qz / norm)
        covariance6 = _matrix(entry.get("covariance_6x6"), 6, f"{where}.covariance_6x6")
        sigmas = (
            _map_marker_sigmas(entry, where)
            if covariance6 is None
            else _tag_from_marker_cov(covariance6)
        )
    else:
        R_map_marker = gtsam.Rot3.Rz(_number(entry.get("yaw"), f"{where}.yaw"))
        sigmas = _map_marker_sigmas(entry, where)
    return KnownTag(tag_id, gtsam.Pose3(R_map_marker.compose(to_tag), np.array([x, y, z])), sigmas)


def _map_survey(path: Path) -> Survey:
    """markergraph's own ``map.json`` (``markergraph.map/1`` or ``/2``): every marker."""
    try:  # its nesting checked before it is parsed; strict: NaN refused
        document = json_document(_read(path, "map.json"))
    except ValueError as error:
        raise SettingsError(f"{path}: not a readable map.json ({error})") from None
    schema = document.get("schema") if isinstance(document, dict) else None
    if schema not in _MAP_SCHEMAS:
        raise SettingsError(f"{path}: schema {schema!r} is not one of {', '.join(_MAP_SCHEMAS)}")
    markers = document.get("markers")
    if not isinstance(markers, list):
        raise SettingsError(f"{path}: markers is not a list")
    _at_most(len(markers), str(path))
    tags = [_map_entry(entry, f"{path}: markers[{i}]") for i, entry in enumerate(markers)]
    return Survey(SurveyKind.MAP_JSON, _sorted_unique(tags, str(path)))
