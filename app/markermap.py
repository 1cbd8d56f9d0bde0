"""The corrected marker map as a type, and its file ``map.json`` (schema ``markergraph.map/2``;
``markergraph.map/1`` files still read).

A :class:`MarkerMap` is what ``markergraph map`` writes and what ``export``, ``heading``, the
plots and the overlay take: each marker's pose in the map frame (the home marker's), its
covariance, side and height where known; the links between markers with the paper's edge
values; and where the map came from.

A 3-D map (``dimensions`` 3, :meth:`MarkerMap.from_tag_map`) holds every tag's full pose and
6x6 covariance in :attr:`MarkerMap.markers3d` and the rig's cameras; its :attr:`~MarkerMap.markers`
are its wall tags alone as a 2-D map (the tags whose normal is within
:data:`~markergraph.frontend.posed.WALL_TILT_RAD` of horizontal, in a map whose z is up), so
that everything that reads a 2-D map (localisation, ``--prior``, ``heading``, the 2-D plots and
the overlay) takes a 3-D map unchanged and sees only what it can use.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
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
from markergraph.common.errors import MarkerGraphError
from markergraph.common.files import written_whole
from markergraph.common.numbers import denoised, denoised_matrix
from markergraph.estimator.estimate import Estimate
from markergraph.estimator.heights import MarkerHeight
from markergraph.estimator.paper import Edge, Form, edge_from_pose2, heading
from markergraph.estimator.tags3d import Camera3d, TagMap3d, quaternion_wxyz
from markergraph.frontend.posed import WALL_TILT_RAD
from markergraph.frontend.sizes import MarkerSizes

__all__ = [
    "MAP_SCHEMA",
    "MAP_SCHEMAS_READ",
    "MapLink",
    "MapMarker",
    "MarkerMap",
    "MarkerMapError",
    "heading_jacobian",
    "is_wall",
]

MAP_SCHEMA = "markergraph.map/2"
MAP_SCHEMAS_READ = ("markergraph.map/1", MAP_SCHEMA)  # /1 is /2 without "dimensions" (2-D)


class MarkerMapError(MarkerGraphError):
    """A map.json that cannot be used; the message names the file and the field."""


@dataclass(frozen=True)
class MapMarker:
    """One marker of the map.

    Attributes:
        marker_id: its id in the dictionary.
        T_map_marker: its pose in the map frame; x is the normal into the room [m, rad].
        covariance: 3x3 over (x, y, yaw) in the marker's own tangent space, or None.
        n_observations: how many observations placed it.
        size_m: the side of its black square [m].
        z_m: the height of its centre above the base frame's origin (the floor, for a base
            on it) [m], where known.
        sigma_z_m: the height's standard deviation [m], where known.
        relative_covariance: ``covariance`` with the map's common rigid motion removed (the
            marker's uncertainty relative to the map as a whole), or None.
        T_map_marker3: its full pose (3-D maps only; x the normal into the room, z up for an
            upright tag on a wall), else None. ``T_map_marker`` is then its trace on the floor:
            the position's x, y and the heading of the normal.
        covariance6: 6x6 over ``T_map_marker3``'s tangent (rotation [rad], then translation
            [m], in the marker's own frame), or None.
        wall: on a wall (always, in a 2-D map): in a 3-D map, its normal is within
            ``WALL_TILT_RAD`` of horizontal and the map's z is up.
        known: held by a survey prior (3-D maps).
    """

    marker_id: int
    T_map_marker: gtsam.Pose2
    covariance: NDArray[np.float64] | None
    n_observations: int
    size_m: float
    z_m: float | None = None
    sigma_z_m: float | None = None
    relative_covariance: NDArray[np.float64] | None = None
    T_map_marker3: gtsam.Pose3 | None = None
    covariance6: NDArray[np.float64] | None = None
    wall: bool = True
    known: bool = False

    def position_ellipse(self, n_sigma: float = 2.0) -> tuple[NDArray[np.float64], float] | None:
        """The ``n_sigma`` position ellipse in the map frame: (diameters (major, minor) [m],
        heading of the major axis [rad]); None without a covariance."""
        if self.covariance is None:
            return None
        c, s = math.cos(self.T_map_marker.theta()), math.sin(self.T_map_marker.theta())
        R = np.array([[c, -s], [s, c]])  # the covariance is in the marker's frame
        values, vectors = np.linalg.eigh(R @ self.covariance[:2, :2] @ R.T)
        diameters = 2.0 * n_sigma * np.sqrt(np.maximum(values[::-1], 0.0))
        return diameters, math.atan2(vectors[1, 1], vectors[0, 1])

    def sigmas(self) -> tuple[float, float, float]:
        """Standard deviations of x and y along the map's axes, and of yaw (0 without a
        covariance): the covariance is in the marker's own frame, turned by its yaw."""
        if self.covariance is None:
            return (0.0, 0.0, 0.0)
        c, s = math.cos(self.T_map_marker.theta()), math.sin(self.T_map_marker.theta())
        R = np.array([[c, -s], [s, c]])
        position = np.diag(R @ self.covariance[:2, :2] @ R.T)
        x, y = np.sqrt(np.maximum(position, 0.0))
        return (float(x), float(y), math.sqrt(max(float(self.covariance[2, 2]), 0.0)))


@dataclass(frozen=True)
class MapLink:
    """Two linked markers: the paper's edge of the estimated map, and how often it was measured.

    Attributes:
        marker_a, marker_b: the markers.
        n_measurements: how many measurements link them.
        edge: ``E_ab`` of the estimated poses.
        covariance: of the relative pose ``T_a_b`` (markers taken as independent), or None.
    """

    marker_a: int
    marker_b: int
    n_measurements: int
    edge: Edge
    covariance: NDArray[np.float64] | None


@dataclass(frozen=True)
class MarkerMap:
    """A corrected marker map and where it came from.

    Attributes:
        markers: marker id -> marker, in id order.
        links: the links between markers.
        home_id: the marker whose frame is the map frame.
        dictionary: the markers' dictionary.
        marker_size_m: the default side of a marker [m].
        method: the method that made it.
        log: the log it was made from.
        converged: whether the method's optimiser converged.
        unplaced: marker id -> why it could not be placed.
        dimensions: 2 for a floor map, 3 for a map of full tag poses.
        up: (3-D) the map frame's z is up, so that its wall tags make a 2-D map.
        cameras: (3-D) the rig's cameras with their mounts ``T_rig_camera``.
        markers3d: (3-D) every tag with its full pose, in id order; ``markers`` holds the wall
            tags among them (the 2-D map). Empty in a 2-D map.
        frame: (3-D) what fixed the map frame, in words (map.json's ``frame``).
    """

    markers: Mapping[int, MapMarker]
    links: tuple[MapLink, ...]
    home_id: int
    dictionary: str
    marker_size_m: float
    method: str
    log: str
    converged: bool = True
    unplaced: Mapping[int, str] = field(default_factory=dict)
    dimensions: int = 2
    up: bool = False
    cameras: tuple[Camera3d, ...] = ()
    markers3d: Mapping[int, MapMarker] = field(default_factory=dict)
    frame: str = ""

    @property
    def every_marker(self) -> Mapping[int, MapMarker]:
        """Every marker of the map: a 3-D map's tags (walls or not), a 2-D map's markers."""
        return self.markers3d if self.dimensions == 3 else self.markers

    @classmethod
    def from_tag_map(
        cls, tag_map: TagMap3d, *, log: str, dictionary: str, marker_size_m: float, method: str
    ) -> MarkerMap:
        """A 3-D tag map as a map: every tag in ``markers3d`` with its full pose and 6x6
        covariance in the marker frame, its wall tags also in ``markers`` with (x, y, yaw) and
        the 3x3 covariance propagated from the 6x6 (:func:`heading_jacobian`).

        The home id is the estimator's home tag, or (when surveyed tags fixed the frame) the
        lowest surveyed tag's id.
        """
        tags = {
            i: _marker_of(i, tag.T_map_marker, tag.marker_covariance, tag.n_views, tag.size_m,
                          up=tag_map.up, known=tag.known)
            for i, tag in sorted(tag_map.tags.items())
        }  # fmt: skip
        home = tag_map.home_id
        anchor = f"home tag {home}"
        if home is None:
            known = [i for i, tag in tags.items() if tag.known]
            home = min(known or list(tags) or [0])
            anchor = "the surveyed tags"
        level = "z up" if tag_map.up else "z not known to be up"
        return cls(
            {i: m for i, m in tags.items() if m.wall},
            (),
            home,
            dictionary,
            marker_size_m,
            method,
            log,
            tag_map.converged,
            dimensions=3,
            up=tag_map.up,
            cameras=tuple(tag_map.cameras[name] for name in sorted(tag_map.cameras)),
            markers3d=tags,
            frame=f"map: fixed by {anchor}, {level}; each tag's marker frame has x along its "
            "normal",
        )

    @classmethod
    def from_estimate(
        cls,
        estimate: Estimate,
        *,
        log: str,
        dictionary: str,
        marker_sizes: MarkerSizes,
        heights: Mapping[int, MarkerHeight] | None = None,
    ) -> MarkerMap:
        """An estimate's map; each marker's side from ``marker_sizes``; heights
        (:func:`~markergraph.estimator.marker_heights`) where given."""
        heights = heights or {}
        markers = {}
        for i, m in sorted(estimate.markers.items()):
            height = heights.get(i)
            markers[i] = MapMarker(
                i,
                m.T_map_marker,
                m.covariance,
                m.n_observations,
                marker_sizes.of(i),
                None if height is None else height.z_m,
                None if height is None else height.sigma_m,
                m.relative_covariance,
            )
        links = []
        for link in estimate.links:
            a, b = markers.get(link.marker_a), markers.get(link.marker_b)
            if a is None or b is None:
                continue
            T_a_b = a.T_map_marker.between(b.T_map_marker)
            covariance = None
            if a.covariance is not None and b.covariance is not None:
                ad = T_a_b.inverse().AdjointMap()
                covariance = ad @ a.covariance @ ad.T + b.covariance
            links.append(
                MapLink(
                    link.marker_a,
                    link.marker_b,
                    link.n_measurements,
                    edge_from_pose2(T_a_b),
                    covariance,
                )
            )
        return cls(
            markers,
            tuple(links),
            estimate.home_id,
            dictionary,
            marker_sizes.default_m,
            estimate.method.value,
            log,
            estimate.converged,
            dict(sorted(estimate.unplaced.items())),
        )

    def heading(
        self, source: int, d: float, theta: float, target: int, form: Form = Form.EXACT
    ) -> tuple[float, float]:
        """The paper's target heading: from a robot localised on marker ``source`` at its
        centred observation (distance ``d`` [m], theta [rad]), the distance to drive and the
        turn from facing ``source`` toward marker ``target`` (counter-clockwise positive).

        Raises:
            MarkerMapError: a marker not in the map, or ``source`` equal to ``target``.
        """
        for marker_id in (source, target):
            if marker_id not in self.markers:
                known = ", ".join(map(str, self.markers))
                raise MarkerMapError(f"no marker {marker_id} in the map (it has {known})")
        if source == target:
            raise MarkerMapError(f"the start and the target are both marker {target}")
        T_a_c = self.markers[source].T_map_marker.between(self.markers[target].T_map_marker)
        return heading(edge_from_pose2(T_a_c), d, theta, form)

    # --- map.json ---------------------------------------------------------------------------

    def to_document(self) -> dict[str, Any]:
        """The map as a JSON-ready document (schema ``markergraph.map/2``): a 2-D map as in
        ``markergraph.map/1`` plus ``"dimensions": 2``; a 3-D map with every tag's full pose
        (``x, y, z``, ``quaternion`` [w, x, y, z] of ``T_map_marker``, ``covariance_6x6``,
        ``wall``, ``known``), ``up`` and the rig's ``cameras``."""
        if self.dimensions == 3:
            markers = [_marker3_entry(m) for m in self.markers3d.values()]
        else:
            markers = [_marker2_entry(m) for m in self.markers.values()]
        links = [
            {
                "a": link.marker_a,
                "b": link.marker_b,
                "n_measurements": link.n_measurements,
                "phi": denoised(link.edge.phi),
                "theta_ab": denoised(link.edge.theta_ab),
                "theta_ba": denoised(link.edge.theta_ba),
                "d": denoised(link.edge.d),
                "covariance": _matrix(link.covariance),
            }
            for link in self.links
        ]
        document: dict[str, Any] = {
            "schema": MAP_SCHEMA,
            "dimensions": self.dimensions,
            "frame": _frame_text(self),
            "units": {"length": "m", "angle": "rad"},
            "home_id": self.home_id,
            "dictionary": self.dictionary,
            "marker_size_m": self.marker_size_m,
            "method": self.method,
            "log": self.log,
            "converged": self.converged,
        }
        if self.dimensions == 3:
            document["up"] = self.up
            document["cameras"] = [_camera_entry(c) for c in self.cameras]
        return {
            **document,
            "markers": markers,
            "links": links,
            "unplaced": {str(k): v for k, v in self.unplaced.items()},
        }

    @classmethod
    def from_document(cls, document: Any, source: str = "the map") -> MarkerMap:
        """A map from a ``markergraph.map/2`` (or ``/1``) document, every field checked: ids
        within the dictionary's range (a predefined one's; else up to 2^31 - 1), no more
        markers than it holds, covariances symmetric and positive semi-definite (rounding's
        small negative eigenvalues clipped), every key and value of ``unplaced``, the home and
        each link's markers in the map.

        Raises:
            MarkerMapError: one line naming ``source`` and the first bad field.
        """
        if not isinstance(document, dict) or document.get("schema") not in MAP_SCHEMAS_READ:
            found = document.get("schema") if isinstance(document, dict) else document
            raise MarkerMapError(f"{source}: not a {MAP_SCHEMA} document (schema {found!r})")
        dimensions = document.get("dimensions", 2)
        if dimensions not in (2, 3) or isinstance(dimensions, bool):
            raise _Reader(source).fail("dimensions", "2 or 3", dimensions)
        dictionary = document.get("dictionary")
        if not isinstance(dictionary, str) or not dictionary.isprintable() or not dictionary:
            raise MarkerMapError(f"{source}: dictionary must be a name, got {dictionary!r}")
        read = _Reader(source, *_id_bounds(dictionary, dimensions))
        size = read.number("marker_size_m", document.get("marker_size_m"), positive=True)
        up = dimensions == 3 and read.boolean("up", document.get("up"))
        markers = _read_markers(read, document.get("markers"), dimensions, size, up)
        links = _read_links(read, document.get("links", []), markers)
        home = read.marker_id("home_id", document.get("home_id", min(markers, default=0)))
        if markers and home not in markers:
            raise read.fail("home_id", "a marker of the map", home)
        cameras: tuple[Camera3d, ...] = ()
        if dimensions == 3:
            cameras = tuple(
                _read_camera(read, f"cameras[{i}]", entry)
                for i, entry in enumerate(read.items("cameras", document.get("cameras", [])))
            )
        return cls(
            {i: m for i, m in markers.items() if m.wall},
            links,
            home,
            dictionary,
            size,
            read.text("method", document.get("method", "")),
            read.text("log", document.get("log", "")),
            read.boolean("converged", document.get("converged", True)),
            _read_unplaced(read, document.get("unplaced")),
            dimensions=dimensions,
            up=up,
            cameras=cameras,
            markers3d=markers if dimensions == 3 else {},
            frame=read.text("frame", document.get("frame", "")) if dimensions == 3 else "",
        )

    def save(self, path: Path) -> None:
        """Write ``map.json``, whole or not at all; strict JSON (no NaN or infinity)."""
        write_json(path, self.to_document())

    @classmethod
    def load(cls, path: Path) -> MarkerMap:
        """Read a ``map.json`` written by ``markergraph map``.

        Raises:
            MarkerMapError: unreadable, not strict JSON, or a bad field; the message names the
                file and the field.
        """
        path = Path(path)
        try:  # the size checked before reading, the nesting before parsing
            document = json_document(read_text(path))
        except OSError as error:
            raise MarkerMapError(f"{path}: cannot read it ({error.strerror})") from None
        except UnicodeDecodeError:
            raise MarkerMapError(f"{path}: not UTF-8 text, so not a map.json") from None
        except DocumentError as error:
            raise MarkerMapError(f"{path}: {error}") from None
        except ValueError as error:
            raise MarkerMapError(f"{path}: not a JSON document ({error})") from None
        return cls.from_document(document, str(path))


def _marker2_entry(m: MapMarker) -> dict[str, Any]:
    """A 2-D map's marker in map.json (as in ``markergraph.map/1``)."""
    T = m.T_map_marker
    entry: dict[str, Any] = {
        "id": m.marker_id,
        "x": denoised(T.x()),
        "y": denoised(T.y()),
        "yaw": denoised(T.theta()),
        "size_m": m.size_m,
        "covariance": _matrix(m.covariance),
        "n_observations": m.n_observations,
    }
    if m.z_m is not None:
        entry["z"] = denoised(m.z_m)
    if m.sigma_z_m is not None:
        entry["sigma_z"] = denoised(m.sigma_z_m)
    if m.relative_covariance is not None:
        entry["relative_covariance"] = _matrix(m.relative_covariance)
    return entry


def _read_marker2(read: _Reader, where: str, entry: dict[str, Any], size: float) -> MapMarker:
    """A 2-D map's marker from map.json."""
    pose = [read.number(f"{where}.{k}", entry.get(k)) for k in ("x", "y", "yaw")]
    return MapMarker(
        read.marker_id(f"{where}.id", entry.get("id")),
        gtsam.Pose2(*pose),
        read.covariance(f"{where}.covariance", entry.get("covariance")),
        read.whole(f"{where}.n_observations", entry.get("n_observations")),
        read.number(f"{where}.size_m", entry.get("size_m", size), positive=True),
        None if "z" not in entry else read.number(f"{where}.z", entry["z"]),
        None
        if "sigma_z" not in entry
        else read.number(f"{where}.sigma_z", entry["sigma_z"], positive=True),
        None
        if "relative_covariance" not in entry
        else read.covariance(f"{where}.relative_covariance", entry["relative_covariance"]),
    )


# --- 3-D maps -------------------------------------------------------------------------------

# The marker frame's normal is its x axis; [e1]x, so that d(R e1) = -R [e1]x omega.
_E1_CROSS = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
_VERTICAL = 1e-9  # a normal whose horizontal part is shorter than this has no heading


def is_wall(T_map_marker3: gtsam.Pose3, up: bool) -> bool:
    """Whether a tag is a wall tag: the map's z is up and its normal (the marker frame's x) is
    within :data:`~markergraph.frontend.posed.WALL_TILT_RAD` of horizontal."""
    normal = T_map_marker3.rotation().matrix()[:, 0]
    return up and abs(float(normal[2])) <= math.sin(WALL_TILT_RAD)


def floor_pose(T_map_marker3: gtsam.Pose3) -> gtsam.Pose2:
    """A tag's trace on the floor: its x, y and the heading of its normal (0 for a vertical
    normal)."""
    t = T_map_marker3.translation()
    normal = T_map_marker3.rotation().matrix()[:, 0]
    level = math.hypot(normal[0], normal[1])
    yaw = math.atan2(normal[1], normal[0]) if level > _VERTICAL else 0.0
    return gtsam.Pose2(float(t[0]), float(t[1]), yaw)


def heading_jacobian(T_map_marker3: gtsam.Pose3) -> NDArray[np.float64]:
    """(3, 6) the derivative of :func:`floor_pose`'s local coordinates (x, y along and across
    the normal's heading, yaw) by the Pose3 tangent (rotation, translation) in the marker's
    own frame, both perturbed on the right as GTSAM does.

    Position: ``t' = t + R v``, seen in the floor pose's frame. Heading: ``n' = n + R (w x
    e1)`` and ``d yaw = (n_x dn_y - n_y dn_x) / (n_x^2 + n_y^2)``: it grows without bound as the
    normal turns vertical (a floor tag has no heading); use it for wall tags.
    """
    R = T_map_marker3.rotation().matrix()
    normal = R[:, 0]
    level2 = float(normal[0] ** 2 + normal[1] ** 2)
    if level2 <= _VERTICAL**2:
        raise ValueError("a vertical normal has no heading to propagate a covariance to")
    yaw = math.atan2(normal[1], normal[0])
    c, s = math.cos(yaw), math.sin(yaw)
    J = np.zeros((3, 6))
    J[:2, 3:] = np.array([[c, s], [-s, c]]) @ R[:2, :]
    g = np.array([-normal[1], normal[0], 0.0]) / level2
    J[2, :3] = -g @ R @ _E1_CROSS
    return J


def _marker_of(
    marker_id: int,
    T_map_marker3: gtsam.Pose3,
    covariance6: NDArray[np.float64] | None,
    n_observations: int,
    size_m: float,
    *,
    up: bool,
    known: bool,
    wall: bool | None = None,
) -> MapMarker:
    """A 3-D map's marker: its full pose, and its floor trace with the 3x3 covariance (a wall
    tag's) propagated from the 6x6; ``wall`` None decides it by :func:`is_wall`."""
    wall = is_wall(T_map_marker3, up) if wall is None else wall
    covariance = sigma_z = None
    if covariance6 is not None:
        R = T_map_marker3.rotation().matrix()
        sigma_z = math.sqrt(max(float((R @ covariance6[3:, 3:] @ R.T)[2, 2]), 0.0))
        if wall:
            J = heading_jacobian(T_map_marker3)
            covariance = J @ covariance6 @ J.T
            covariance = (covariance + covariance.T) / 2.0  # exactly symmetric, as written
    return MapMarker(
        marker_id,
        floor_pose(T_map_marker3),
        covariance,
        n_observations,
        size_m,
        float(T_map_marker3.translation()[2]),
        sigma_z,
        None,
        T_map_marker3,
        covariance6,
        wall,
        known,
    )


def _quaternion(rotation: gtsam.Rot3) -> list[float]:
    """[w, x, y, z], w >= 0."""
    return [denoised(v) for v in quaternion_wxyz(rotation)]


def _pose_fields(T: gtsam.Pose3) -> dict[str, Any]:
    t = T.translation()
    return {
        "x": denoised(t[0]),
        "y": denoised(t[1]),
        "z": denoised(t[2]),
        "quaternion": _quaternion(T.rotation()),
    }


def _marker3_entry(m: MapMarker) -> dict[str, Any]:
    """A 3-D map's marker in map.json."""
    assert m.T_map_marker3 is not None  # a 3-D map's markers all have one
    T = m.T_map_marker
    return {
        "id": m.marker_id,
        **_pose_fields(m.T_map_marker3),
        "yaw": denoised(T.theta()),
        "size_m": m.size_m,
        "covariance": _matrix(m.covariance),
        "covariance_6x6": _matrix(m.covariance6),
        "n_observations": m.n_observations,
        "wall": m.wall,
        "known": m.known,
    }


def _camera_entry(camera: Camera3d) -> dict[str, Any]:
    return {
        "name": camera.name,
        "topic": camera.topic,
        **_pose_fields(camera.T_rig_camera),
        "covariance_6x6": _matrix(camera.covariance),
        "estimated": camera.estimated,
        "n_views": camera.n_views,
    }


def _frame_text(marker_map: MarkerMap) -> str:
    if marker_map.dimensions == 3 and marker_map.frame:
        return marker_map.frame
    return f"map: the frame of home marker {marker_map.home_id} (x along its normal)"


def _read_marker3(
    read: _Reader, where: str, entry: dict[str, Any], size: float, up: bool
) -> MapMarker:
    """A 3-D map's marker from map.json. ``wall`` is taken as written (a wall tag needs a map
    whose z is up and a normal that is not vertical); the floor trace and its 3x3 are derived
    again from the full pose and the 6x6, so ``yaw`` and ``covariance`` are checked, not used."""
    read.number(f"{where}.yaw", entry.get("yaw"))
    read.covariance(f"{where}.covariance", entry.get("covariance"))
    T = read.pose3(where, entry)
    wall = read.boolean(f"{where}.wall", entry.get("wall"))
    normal = T.rotation().matrix()[:, 0]
    if wall and (not up or math.hypot(normal[0], normal[1]) <= _VERTICAL):
        why = "the map's z is not up" if not up else "its normal is vertical"
        raise read.fail(f"{where}.wall", f"false ({why})", wall)
    return _marker_of(
        read.marker_id(f"{where}.id", entry.get("id")),
        T,
        read.covariance6(f"{where}.covariance_6x6", entry.get("covariance_6x6")),
        read.whole(f"{where}.n_observations", entry.get("n_observations")),
        read.number(f"{where}.size_m", entry.get("size_m", size), positive=True),
        up=up,
        known=read.boolean(f"{where}.known", entry.get("known", False)),
        wall=wall,
    )


def _read_camera(read: _Reader, where: str, entry: dict[str, Any]) -> Camera3d:
    name, topic = entry.get("name"), entry.get("topic")
    for key, value in (("name", name), ("topic", topic)):
        if not isinstance(value, str) or not value.isprintable():
            raise read.fail(f"{where}.{key}", "a name", value)
    return Camera3d(
        str(name),
        str(topic),
        read.pose3(where, entry),
        read.covariance6(f"{where}.covariance_6x6", entry.get("covariance_6x6")),
        read.boolean(f"{where}.estimated", entry.get("estimated")),
        read.whole(f"{where}.n_views", entry.get("n_views", 0)),
    )


def _id_bounds(dictionary: str, dimensions: int) -> tuple[int, int, str]:
    """(largest id, most markers, what bounds them) a map may hold: a predefined dictionary's
    own range for a 2-D map; else (a custom dictionary, whose file the map only names, or a
    3-D map, whose TagSLAM remaps may name ids of their own) :data:`MAX_MARKER_ID` and
    :data:`MAX_MARKERS`."""
    if dimensions == 2 and dictionary.startswith("DICT_") and hasattr(cv2.aruco, dictionary):
        held = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
        n = int(held.bytesList.shape[0])
        return n - 1, n, dictionary
    return MAX_MARKER_ID, MAX_MARKERS, "a map"


def _read_markers(
    read: _Reader, value: Any, dimensions: int, size: float, up: bool
) -> dict[int, MapMarker]:
    """The map's markers by id, their number checked before any is read."""
    entries = read.items("markers", value)
    if not entries and dimensions == 2:  # a 3-D map's tags may all be off the walls
        raise read.fail("markers", "a list of at least one marker", entries)
    if len(entries) > read.max_markers:
        raise MarkerMapError(
            f"{read.source}: {len(entries):,} markers, more than {read.bound} holds "
            f"({read.max_markers:,})"
        )
    markers: dict[int, MapMarker] = {}
    for i, entry in enumerate(entries):
        where = f"markers[{i}]"
        # Every later error about this entry names the marker by its id too.
        named = replace(read, marker=read.marker_id(f"{where}.id", entry.get("id")))
        if dimensions == 3:
            marker = _read_marker3(named, where, entry, size, up)
        else:
            marker = _read_marker2(named, where, entry, size)
        if marker.marker_id in markers:
            raise MarkerMapError(f"{read.source}: {where}.id {marker.marker_id} appears twice")
        markers[marker.marker_id] = marker
    return markers


def _read_links(read: _Reader, value: Any, markers: Mapping[int, MapMarker]) -> tuple[MapLink, ...]:
    """The links between the map's markers (each end a marker of the map)."""
    entries = read.items("links", value)
    pairs = len(markers) * (len(markers) - 1)
    if len(entries) > pairs:  # each link joins two of the map's markers, once each way at most
        raise read.fail("links", f"at most {pairs:,} links", f"{len(entries):,} of them")
    links = []
    for i, entry in enumerate(entries):
        where = f"links[{i}]"
        ends = [read.marker_id(f"{where}.{k}", entry.get(k)) for k in ("a", "b")]
        for key, end in zip(("a", "b"), ends, strict=True):
            if end not in markers:
                raise read.fail(f"{where}.{key}", "a marker of the map", end)
        edge = Edge(*(read.number(f"{where}.{k}", entry.get(k)) for k in _EDGE_KEYS))
        links.append(
            MapLink(
                ends[0],
                ends[1],
                read.whole(f"{where}.n_measurements", entry.get("n_measurements")),
                edge,
                read.covariance(f"{where}.covariance", entry.get("covariance")),
            )
        )
    return tuple(links)


def _read_unplaced(read: _Reader, value: Any) -> dict[int, str]:
    """``unplaced``: marker ids (as JSON keys: decimal text) -> why, every key and value
    checked."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise read.fail("unplaced", "an object of marker id -> reason", value)
    unplaced = {}
    for key, why in value.items():
        where = f"unplaced[{key!r}]" if len(key) <= 20 else "unplaced"
        # Short of int(): a key of 5,000 digits is a ValueError there, not a marker id.
        if not (key.isascii() and key.isdigit() and len(key) <= len(str(MAX_MARKER_ID))):
            raise read.fail(where, "keyed by a marker id", key)
        unplaced[read.marker_id(where, int(key))] = read.text(where, why)
    return dict(sorted(unplaced.items()))


_EDGE_KEYS = ("phi", "theta_ab", "theta_ba", "d")
# Bounds on what a map may hold: any coordinate beyond 10,000 km, or a variance whose square
# root squared would overflow in a peer format, is a corrupted file, not a map.
MAX_VALUE = 1e7
MAX_VARIANCE = 1e100
# A quaternion written by us is unit to rounding; one further off than this is not a rotation.
QUATERNION_TOLERANCE = 1e-6
# Asymmetry, and a negative eigenvalue, allowed in a 6x6 covariance relative to its largest
# entry: what rounding in an optimiser's marginals leaves, and no more.
SYMMETRY_TOLERANCE = 1e-9
# A count (observations, views, measurements) beyond this is no count but a corrupted file: it
# would overflow the int64 arrays it goes into.
MAX_COUNT = 2**63 - 1


def _matrix(matrix: NDArray[np.float64] | None) -> list[list[float]] | None:
    """A covariance as JSON holds it, its float noise (against its largest entry) as 0.0."""
    return None if matrix is None else denoised_matrix(matrix)


def write_json(path: Path, document: Mapping[str, Any]) -> None:
    """A JSON document, indented, written whole or not at all; a NaN or infinity in it is an
    error (a bug upstream), never a file that strict readers reject."""
    try:
        text = json.dumps(document, indent=1, allow_nan=False)
    except ValueError as error:
        raise MarkerGraphError(f"{path}: refusing to write a non-finite value ({error})") from None
    with written_whole(path) as partial:
        partial.write_text(text + "\n", encoding="utf-8")


@dataclass(frozen=True)
class _Reader:
    """Checks a document's fields, naming the source and the field in every error.

    Attributes:
        source: the file (or what the document came from).
        max_id: the largest marker id allowed.
        max_markers: the most markers allowed.
        bound: what sets those bounds, in words (the dictionary's name).
        marker: the id of the marker whose fields are read, named in every error; or None.
    """

    source: str
    max_id: int = MAX_MARKER_ID
    max_markers: int = MAX_MARKERS
    bound: str = "a map"
    marker: int | None = None

    def fail(self, where: str, what: str, value: Any) -> MarkerMapError:
        """The error naming the source, the field, what it must be and what it holds."""
        text = repr(value)
        shown = text if len(text) <= 40 else f"{text[:20]}... ({len(text)} characters)"
        of = "" if self.marker is None else f" (marker {self.marker})"
        return MarkerMapError(f"{self.source}: {where} must be {what}, got {shown}{of}")

    def number(
        self, where: str, value: Any, *, positive: bool = False, limit: float = MAX_VALUE
    ) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(where, "a number", value)
        try:
            number = float(value)
        except OverflowError:  # an integer of hundreds of digits
            number = math.inf
        if not abs(number) <= limit or (positive and number <= 0):
            what = "a positive number" if positive else "a number"
            raise self.fail(where, f"{what} of magnitude at most {limit:g}", value)
        return number

    def whole(self, where: str, value: Any, limit: int = MAX_COUNT) -> int:
        """A whole number from 0 to ``limit``."""
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= limit:
            raise self.fail(where, f"a whole number from 0 to {limit:,}", value)
        return value

    def marker_id(self, where: str, value: Any) -> int:
        """A marker id: a whole number within the dictionary's range (GTSAM's ``L()`` takes
        no more, and a map holds only the dictionary's markers)."""
        limit = self.max_id
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= limit:
            within = f"in {self.bound}" if self.bound != "a map" else "allowed"
            raise self.fail(where, f"a marker id from 0 to {limit:,} (the ids {within})", value)
        return value

    def text(self, where: str, value: Any) -> str:
        """A string (a name, a path, a reason)."""
        if not isinstance(value, str):
            raise self.fail(where, "a string", value)
        return value

    def items(self, where: str, value: Any) -> list[dict[str, Any]]:
        if not isinstance(value, list):
            raise self.fail(where, "a list", value)
        for i, item in enumerate(value):
            if not isinstance(item, dict):
                raise self.fail(f"{where}[{i}]", "an object", item)
        return value

    def boolean(self, where: str, value: Any) -> bool:
        if not isinstance(value, bool):
            raise self.fail(where, "true or false", value)
        return value

    def pose3(self, where: str, entry: dict[str, Any]) -> gtsam.Pose3:
        """``x, y, z`` and ``quaternion`` [w, x, y, z] (unit to 1e-6, normalised)."""
        t = [self.number(f"{where}.{k}", entry.get(k)) for k in ("x", "y", "z")]
        value = entry.get("quaternion")
        if not isinstance(value, list) or len(value) != 4:
            raise self.fail(f"{where}.quaternion", "[w, x, y, z]", value)
        q = np.array([self.number(f"{where}.quaternion", v) for v in value])
        norm = float(np.linalg.norm(q))
        if not abs(norm - 1.0) <= QUATERNION_TOLERANCE:
            raise self.fail(f"{where}.quaternion", "a unit quaternion [w, x, y, z]", value)
        w, x, y, z = q / norm
        return gtsam.Pose3(gtsam.Rot3.Quaternion(w, x, y, z), np.array(t))

    def covariance6(self, where: str, value: Any) -> NDArray[np.float64] | None:
        """A 6x6 covariance or null: symmetric and positive semi-definite to rounding."""
        if value is None:
            return None
        if (
            not isinstance(value, list)
            or len(value) != 6
            or not all(isinstance(row, list) and len(row) == 6 for row in value)
        ):
            raise self.fail(where, "a 6x6 matrix or null", value)
        P = np.array([[self.number(where, v, limit=MAX_VARIANCE) for v in row] for row in value])
        return self.semi_definite(where, P, value)

    def semi_definite(self, where: str, P: NDArray[np.float64], value: Any) -> NDArray[np.float64]:
        """``P`` made exactly symmetric with rounding's negative eigenvalues clipped to 0;
        refused where it is not symmetric, or has a negative eigenvalue beyond
        :data:`SYMMETRY_TOLERANCE` of its largest entry (a negative variance is no
        covariance: GTSAM refuses it, or takes its square root as NaN)."""
        scale = max(float(np.max(np.abs(P))), 1e-300)
        if not np.all(np.abs(P - P.T) <= SYMMETRY_TOLERANCE * scale):
            raise self.fail(where, "a symmetric matrix", value)
        P = 0.5 * (P + P.T)
        values, vectors = np.linalg.eigh(P)
        if float(values[0]) < -SYMMETRY_TOLERANCE * scale:
            raise self.fail(where, "positive semi-definite (a covariance)", value)
        if float(values[0]) < 0.0:
            P = (vectors * np.maximum(values, 0.0)) @ vectors.T
            P = 0.5 * (P + P.T)
        return P

    def covariance(self, where: str, value: Any) -> NDArray[np.float64] | None:
        if value is None:
            return None
        if (
            not isinstance(value, list)
            or len(value) != 3
            or not all(isinstance(row, list) and len(row) == 3 for row in value)
        ):
            raise self.fail(where, "a 3x3 matrix or null", value)
        P = np.array([[self.number(where, v, limit=MAX_VARIANCE) for v in row] for row in value])
        return self.semi_definite(where, P, value)
