"""A marker map scored against a reference, as ``evo_ape`` scores a path: the markers in common,
each one's error after a rigid alignment and after fixing the frame on one marker, and how the
map's covariances cover those errors.

The reference is any survey :func:`~markergraph.frontend.survey.read_survey` reads (a
``map.json``, a CSV survey, TagSLAM's ``tagslam.yaml``, an ArUco MarkerMap). Everything below
:func:`read_reference` is pure: arrays in, records out.

Frames: ``T_ref_map`` takes the map's frame into the reference's (``p_ref = s R p_map + t``).
Marker rotations are in markergraph's marker frame (x the normal into the room).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.common.errors import MarkerGraphError
from markergraph.estimator.angles import angle_diff
from markergraph.estimator.tags3d import R_TAG_MARKER
from markergraph.frontend.posed import WALL_TILT_RAD
from markergraph.frontend.survey import (
    SIGMA_UNKNOWN_M,
    SIGMA_UNKNOWN_RAD,
    Survey,
    SurveyKind,
    read_survey,
)
from markergraph.markermap import MapMarker, MarkerMap

__all__ = [
    "CHI2_95",
    "PINNED_SIGMA_M",
    "Alignment",
    "CompareError",
    "Comparison",
    "Figures",
    "MapPoint",
    "RefMarker",
    "Scored",
    "align",
    "compare",
    "errors",
    "map_points",
    "read_reference",
    "reference_markers",
]

CHI2_95 = {1: 3.841458820694124, 2: -2.0 * math.log(0.05), 3: 7.814727903251178}
"""The 95 % quantile of chi-square with 1, 2 and 3 dof: a Gaussian's 95 % interval, ellipse
and ellipsoid."""
_MIN_COMMON = {2: 2, 3: 3}
PINNED_SIGMA_M = 1e-3
"""A home marker whose position sigma is below this is the map frame pinned by a prior (the
2-D graph's is 1e-4 m), not a measured marker: it gets no NEES. A 3-D map fixed by surveyed
tags has a home with a real covariance, which counts."""
_DEGENERATE = 1e-12  # relative size of a singular value that leaves a rotation undetermined


class CompareError(MarkerGraphError):
    """A map and a reference that cannot be compared; the message names the file or marker."""


@dataclass(frozen=True, slots=True)
class RefMarker:
    """One reference marker.

    Attributes:
        marker_id: its id.
        p_ref: (3,) its centre in the reference frame [m] (z 0 where not known).
        R_ref_marker: (3, 3) its rotation, marker frame (x the normal).
        z_known: the reference gives its height.
        yaw_known: the reference gives the heading of its normal.
        rotation_known: the reference gives its full 3-D rotation.
    """

    marker_id: int
    p_ref: NDArray[np.float64]
    R_ref_marker: NDArray[np.float64]
    z_known: bool
    yaw_known: bool
    rotation_known: bool


@dataclass(frozen=True, slots=True)
class MapPoint:
    """One marker of the map being scored.

    Attributes:
        marker_id: its id.
        p_map: (3,) its centre in the map frame [m] (z 0 where not known).
        R_map_marker: (3, 3) its rotation, marker frame (x the normal).
        wall: its normal is horizontal (its yaw is defined).
        cov_p_map: (3, 3) its position covariance in the map's axes [m^2] (z row and column 0
            in a 2-D map), or None.
        cov_p_relative: the same with the map's common rigid motion removed (a 2-D map's
            ``relative_covariance``), or None: what an aligned error is measured against.
        var_yaw_map, var_yaw_relative: its yaw's variance, in the map and relative to it
            [rad^2], or None.
    """

    marker_id: int
    p_map: NDArray[np.float64]
    R_map_marker: NDArray[np.float64]
    wall: bool
    cov_p_map: NDArray[np.float64] | None
    cov_p_relative: NDArray[np.float64] | None = None
    var_yaw_map: float | None = None
    var_yaw_relative: float | None = None


@dataclass(frozen=True, slots=True)
class Alignment:
    """A similarity ``p_ref = scale * R @ p_map + t`` in ``dimensions`` axes.

    Attributes:
        R: (3, 3) the rotation (about z alone for a 2-D alignment).
        t: (3,) the translation [m] (z 0 for a 2-D alignment).
        scale: 1 unless a scale was fitted.
        how: in words, what fixed it.
    """

    R: NDArray[np.float64]
    t: NDArray[np.float64]
    scale: float
    how: str

    @property
    def angle_deg(self) -> float:
        """The rotation's angle [deg]."""
        return math.degrees(float(np.linalg.norm(gtsam.Rot3.Logmap(gtsam.Rot3(self.R)))))


@dataclass(frozen=True, slots=True)
class Figures:
    """RMSE, median and max of one error over the markers that have it (NaN with none)."""

    n: int
    rmse: float
    median: float
    max: float


@dataclass(frozen=True, slots=True)
class Scored:
    """The common markers' errors under one alignment (arrays in the order of the ids).

    Attributes:
        alignment: the alignment applied to the map.
        position_m: (N,) position errors [m].
        yaw_deg: (N,) absolute yaw errors [deg], NaN where either side gives no yaw.
        rotation_deg: (N,) 3-D rotation error angles [deg], NaN where either is not 3-D.
        nees: (N,) each position error's squared Mahalanobis distance under the map's
            covariance (carried through the alignment), NaN without one.
        p_map_aligned: (N, 3) the map's centres in the reference frame [m].
        cov_aligned: (N, 3, 3) their covariances there [m^2] (NaN without one).
        position, yaw, rotation: their figures.
        n_nees, n_within: markers with a covariance, and those within their 95 % ellipse.
        n_yaw_nees, n_yaw_within: markers with a yaw error and its variance, and those within
            its 95 % interval (1.96 sigma).
    """

    alignment: Alignment
    position_m: NDArray[np.float64]
    yaw_deg: NDArray[np.float64]
    rotation_deg: NDArray[np.float64]
    nees: NDArray[np.float64]
    p_map_aligned: NDArray[np.float64]
    cov_aligned: NDArray[np.float64]
    position: Figures
    yaw: Figures
    rotation: Figures
    n_nees: int
    n_within: int
    n_yaw_nees: int = 0
    n_yaw_within: int = 0


@dataclass(frozen=True, slots=True)
class Comparison:
    """A map scored against a reference.

    Attributes:
        dimensions: 2 (positions on the floor) or 3.
        ids: (N,) the markers in common, ascending.
        only_map, only_reference: ids in one alone.
        p_ref: (N, 3) the reference's centres [m].
        aligned: after the rigid (or, with scale, similarity) alignment.
        home_fixed: after fixing the frame on the home marker; None where the reference
            does not give that marker's yaw (the map's frame rests on it: a translation alone
            would score the frame's turn as the map's error).
        home_id: that marker.
        notes: what a reader should know (why home-fixed is not scored).
    """

    dimensions: int
    ids: NDArray[np.int64]
    only_map: tuple[int, ...]
    only_reference: tuple[int, ...]
    p_ref: NDArray[np.float64]
    aligned: Scored
    home_fixed: Scored | None
    home_id: int
    notes: tuple[str, ...] = ()


# --- reading -------------------------------------------------------------------------------


def _yaw(R_marker: NDArray[np.float64]) -> float:
    """The heading of a marker's normal (its x axis) [rad]."""
    return math.atan2(float(R_marker[1, 0]), float(R_marker[0, 0]))


def _is_horizontal(R_marker: NDArray[np.float64]) -> bool:
    return abs(float(R_marker[2, 0])) <= math.sin(WALL_TILT_RAD)


def reference_markers(survey: Survey, full_rotation: bool) -> dict[int, RefMarker]:
    """A survey's tags as reference markers. What it states is read from the sigmas the reader
    gave what the file left out (:data:`SIGMA_UNKNOWN_M`, :data:`SIGMA_UNKNOWN_RAD`).

    Args:
        survey: as read by :func:`read_survey`.
        full_rotation: the file gives full 3-D rotations (TagSLAM, ArUco, a 3-D map.json).
    """
    markers = {}
    for tag in survey.tags:
        R_ref_marker = np.asarray(tag.T_map_tag.rotation().matrix()) @ R_TAG_MARKER
        sigmas = np.asarray(tag.sigmas)
        yaw_known = bool(np.max(sigmas[:3]) < SIGMA_UNKNOWN_RAD / 2)
        markers[tag.tag_id] = RefMarker(
            tag.tag_id,
            np.asarray(tag.T_map_tag.translation(), dtype=np.float64),
            R_ref_marker,
            z_known=bool(np.max(sigmas[3:]) < SIGMA_UNKNOWN_M / 2),
            yaw_known=yaw_known and (full_rotation or _is_horizontal(R_ref_marker)),
            rotation_known=full_rotation,
        )
    return markers


def read_reference(path: Path) -> tuple[dict[int, RefMarker], str]:
    """A reference file's markers and its kind in words.

    Raises:
        SettingsError: unreadable or a bad field (one line naming the file and the field).
    """
    survey = read_survey(Path(path))
    full = survey.kind in (SurveyKind.TAGSLAM, SurveyKind.ARUCO)
    kind = survey.kind.value
    if survey.kind is SurveyKind.MAP_JSON:
        # read_survey checked the document; only its dimensions are read here.
        document = json.loads(Path(path).read_text(encoding="utf-8"))
        full = document.get("dimensions", 2) == 3
        kind = f"map.json, {3 if full else 2}-D"
    return reference_markers(survey, full), kind


def _map_point(m: MapMarker) -> MapPoint:
    if m.T_map_marker3 is not None:
        R = np.asarray(m.T_map_marker3.rotation().matrix())
        covariance = None
        if m.covariance6 is not None:  # over the marker frame's tangent: rotate to the map's
            covariance = R @ m.covariance6[3:, 3:] @ R.T
        p = np.asarray(m.T_map_marker3.translation(), dtype=np.float64)
        return MapPoint(m.marker_id, p, R, m.wall, covariance, None, _yaw_variance(m.covariance))
    R = np.asarray(gtsam.Rot3.Rz(m.T_map_marker.theta()).matrix())
    p = np.array([m.T_map_marker.x(), m.T_map_marker.y(), m.z_m or 0.0])
    covariance, relative = (_in_map_axes(R, c) for c in (m.covariance, m.relative_covariance))
    return MapPoint(m.marker_id, p, R, True, covariance, relative,
                    _yaw_variance(m.covariance), _yaw_variance(m.relative_covariance))  # fmt: skip


def _yaw_variance(covariance3: NDArray[np.float64] | None) -> float | None:
    """The yaw's variance in a marker's (x, y, yaw) covariance (a 3-D map's wall tags carry
    one too), or None."""
    return None if covariance3 is None else float(covariance3[2, 2])


def _in_map_axes(
    R: NDArray[np.float64], covariance3: NDArray[np.float64] | None
) -> NDArray[np.float64] | None:
    """A 2-D marker's position covariance (its own tangent, x and y) in the map's axes, as a
    3x3 with a nil z."""
    if covariance3 is None:
        return None
    covariance = np.zeros((3, 3))
    covariance[:2, :2] = R[:2, :2] @ covariance3[:2, :2] @ R[:2, :2].T
    return covariance


def map_points(marker_map: MarkerMap) -> dict[int, MapPoint]:
    """Every marker of a map (a 3-D map's tags, walls or not) as a :class:`MapPoint`."""
    return {i: _map_point(m) for i, m in marker_map.every_marker.items()}


# --- the pure part -------------------------------------------------------------------------


def align(
    p_map: NDArray[np.float64], p_ref: NDArray[np.float64], with_scale: bool = False
) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """Umeyama's least-squares similarity (Umeyama 1991, eqs. 40-42) taking ``p_map`` onto
    ``p_ref``; the scale is 1 unless ``with_scale``. In 2-D it is the closed form of Kabsch's
    rotation.

    Args:
        p_map, p_ref: (n, d) matching points, d 2 or 3.

    Returns:
        (R (d, d), t (d,), scale) with ``p_ref ~ scale * R @ p_map + t``.

    Raises:
        CompareError: points all at one place, or (3-D) on one line: the rotation is not
            determined.
    """
    mean_map, mean_ref = p_map.mean(axis=0), p_ref.mean(axis=0)
    d_map, d_ref = p_map - mean_map, p_ref - mean_ref
    covariance = d_ref.T @ d_map / len(p_map)
    U, singular, Vt = np.linalg.svd(covariance)
    d = p_map.shape[1]
    needed = d - 2  # 2-D: one direction suffices; 3-D: two
    if singular[needed] <= _DEGENERATE * max(singular[0], 1e-300):
        where = "at one place" if needed == 0 else "on one line"
        raise CompareError(f"the common markers lie {where}: the rotation is not determined")
    # The sign fix keeps a proper rotation where the best orthogonal fit is a reflection.
    S = np.eye(d)
    S[-1, -1] = float(np.sign(np.linalg.det(U) * np.linalg.det(Vt)) or 1.0)
    R = U @ S @ Vt
    scale = 1.0
    if with_scale:
        variance_map = float(np.mean(np.sum(d_map**2, axis=1)))
        scale = float(np.trace(np.diag(singular) @ S)) / variance_map
    return R, mean_ref - scale * R @ mean_map, scale


def _embed(
    R: NDArray[np.float64], t: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A 2-D rotation and translation as 3-D ones about z."""
    if R.shape == (3, 3):
        return R, t
    R3 = np.eye(3)
    R3[:2, :2] = R
    return R3, np.array([t[0], t[1], 0.0])


def _figures(values: NDArray[np.float64]) -> Figures:
    have = values[np.isfinite(values)]
    if have.size == 0:
        return Figures(0, math.nan, math.nan, math.nan)
    return Figures(int(have.size), float(np.sqrt(np.mean(have**2))), float(np.median(have)),
                   float(np.max(have)))  # fmt: skip


def errors(
    points: list[MapPoint],
    refs: list[RefMarker],
    alignment: Alignment,
    dimensions: int,
    gauge_id: int | None = None,
    relative: bool = False,
    with_nees: bool = True,
) -> Scored:
    """Each common marker's errors once the map is moved by ``alignment``.

    Position errors are over x, y (2-D) or x, y, z (3-D); the yaw error where both give a yaw
    (the map's marker on a wall, the reference's heading known); the rotation error where both
    are 3-D; the NEES over the same axes as the position error, for every marker with a
    covariance but ``gauge_id`` (the map's home marker pinned by a prior: the map frame
    itself). With ``relative`` the covariances with the map's rigid motion removed are used
    where the map has them (an aligned error has that motion fitted away), and every marker
    counts. Without ``with_nees`` no NEES (the covariances are not of this frame).
    """
    d = dimensions
    R, t, s = alignment.R, alignment.t, alignment.scale
    n = len(points)
    position, yaw, rotation, nees, yaw_nees = (np.full(n, np.nan) for _ in range(5))
    aligned = np.zeros((n, 3))
    covariances = np.full((n, 3, 3), np.nan)
    for k, (point, ref) in enumerate(zip(points, refs, strict=True)):
        aligned[k] = s * R @ point.p_map + t
        error = (ref.p_ref - aligned[k])[:d]
        position[k] = float(np.linalg.norm(error))
        R_aligned = R @ point.R_map_marker
        if point.wall and ref.yaw_known and _is_horizontal(ref.R_ref_marker):
            yaw[k] = abs(math.degrees(angle_diff(_yaw(R_aligned), _yaw(ref.R_ref_marker))))
        if d == 3 and ref.rotation_known:
            between = gtsam.Rot3(ref.R_ref_marker.T @ R_aligned)
            rotation[k] = math.degrees(float(np.linalg.norm(gtsam.Rot3.Logmap(between))))
        use_relative = relative and point.cov_p_relative is not None
        covariance = point.cov_p_relative if use_relative else point.cov_p_map
        if covariance is not None and with_nees:
            covariances[k] = s * s * R @ covariance @ R.T
            P = covariances[k][:d, :d]
            pinned = point.marker_id == gauge_id and not use_relative
            if not pinned and np.linalg.eigvalsh(P)[0] > 0.0:
                nees[k] = float(error @ np.linalg.solve(P, error))
            var_yaw = point.var_yaw_relative if use_relative else point.var_yaw_map
            if not pinned and var_yaw is not None and var_yaw > 0.0 and math.isfinite(yaw[k]):
                yaw_nees[k] = math.radians(yaw[k]) ** 2 / var_yaw
    have, have_yaw = np.isfinite(nees), np.isfinite(yaw_nees)
    return Scored(alignment, position, yaw, rotation, nees, aligned, covariances,
                  _figures(position), _figures(yaw), _figures(rotation), int(have.sum()),
                  int(np.sum(nees[have] <= CHI2_95[d])), int(have_yaw.sum()),
                  int(np.sum(yaw_nees[have_yaw] <= CHI2_95[1])))  # fmt: skip


def _home_alignment(
    point: MapPoint, ref: RefMarker, dimensions: int, yawed: list[int]
) -> tuple[Alignment | None, str]:
    """The map moved so that its home marker lands on the reference's: the full rotation
    where the reference gives one (3-D), else the yaw; None (with the reason) where it gives
    neither. ``yawed``: the common markers whose yaw the reference gives, for the reason."""
    if dimensions == 3 and ref.rotation_known:
        R = ref.R_ref_marker @ point.R_map_marker.T
        how = f"marker {point.marker_id}'s pose"
    elif ref.yaw_known and point.wall:
        turn = angle_diff(_yaw(ref.R_ref_marker), _yaw(point.R_map_marker))
        R = np.asarray(gtsam.Rot3.Rz(turn).matrix())
        how = f"marker {point.marker_id}'s position and yaw"
    else:
        other = f" (--home {yawed[0]} fixes it on one it does)" if yawed else ""
        return None, (
            f"home-fixed not scored: the reference gives marker {point.marker_id} no yaw (or it "
            f"is not on a wall), and the map's frame turns with that yaw{other}"
        )
    t = ref.p_ref - R @ point.p_map
    if dimensions == 2:
        t[2] = 0.0
    return Alignment(R, t, 1.0, how), ""


def _pinned_home(points: Mapping[int, MapPoint], home_id: int | None) -> int | None:
    """The map's home marker if a prior pins it (see :data:`PINNED_SIGMA_M`), else None."""
    point = points.get(home_id) if home_id is not None else None
    if point is None or point.cov_p_map is None:
        return None
    return home_id if np.linalg.eigvalsh(point.cov_p_map)[-1] < PINNED_SIGMA_M**2 else None


def compare(
    points: Mapping[int, MapPoint],
    refs: Mapping[int, RefMarker],
    *,
    map_dimensions: int,
    home_id: int | None = None,
    default_home: int | None = None,
    with_scale: bool = False,
) -> Comparison:
    """Score a map's markers against a reference's.

    In 3-D when the map is 3-D and the reference gives every common marker a height, else on
    the floor (x, y).

    Args:
        points: the map's markers (:func:`map_points`).
        refs: the reference's (:func:`reference_markers`).
        map_dimensions: the map's (2 or 3).
        home_id: the marker for the home-fixed figures; None: ``default_home`` if in common,
            else the smallest common id.
        default_home: the map's home marker.
        with_scale: fit a scale in the alignment (a similarity); never in the home-fixed one.

    Raises:
        CompareError: too few markers in common (2 in 2-D, 3 in 3-D), ``home_id`` not in
            common, or common markers that fix no rotation.
    """
    common = sorted(set(points) & set(refs))
    dimensions = 3 if map_dimensions == 3 and all(refs[i].z_known for i in common) else 2
    if len(common) < _MIN_COMMON[dimensions]:
        raise CompareError(
            f"{len(common)} marker(s) in common ({common or 'none'}); a {dimensions}-D comparison "
            f"needs {_MIN_COMMON[dimensions]} (the map has {sorted(points)}, the reference "
            f"{sorted(refs)})"
        )
    if home_id is not None and home_id not in common:
        raise CompareError(f"--home {home_id} is not a marker in common ({common})")
    home = home_id if home_id is not None else default_home
    home = home if home in common else common[0]
    ours, theirs = [points[i] for i in common], [refs[i] for i in common]
    p_map = np.array([p.p_map[:dimensions] for p in ours])
    p_ref = np.array([r.p_ref[:dimensions] for r in theirs])
    R, t, scale = align(p_map, p_ref, with_scale)
    group = ("Sim" if with_scale else "SE") + f"({dimensions})"
    rigid = Alignment(*_embed(R, t), scale, f"{group} on {len(common)} positions")
    yawed = [
        i
        for i in common
        if (dimensions == 3 and refs[i].rotation_known) or (refs[i].yaw_known and points[i].wall)
    ]
    fixed, note = _home_alignment(points[home], refs[home], dimensions, yawed)
    gauge = _pinned_home(points, default_home)
    # The map's covariances are in its home marker's frame: fixed on another, no NEES.
    mine = home == default_home
    return Comparison(
        dimensions,
        np.array(common, dtype=np.int64),
        tuple(sorted(set(points) - set(refs))),
        tuple(sorted(set(refs) - set(points))),
        np.array([r.p_ref for r in theirs]),
        errors(ours, theirs, rigid, dimensions, gauge, relative=True),
        None if fixed is None else errors(ours, theirs, fixed, dimensions, gauge, with_nees=mine),
        home,
        (note,) if note else (),
    )
