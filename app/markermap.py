"""The corrected marker map as a type, and its file ``map.json`` (schema ``markergraph.map/1``).

A :class:`MarkerMap` is what ``markergraph map`` writes and what ``export``, ``heading``, the
plots and the overlay take: each marker's pose in the map frame (the home marker's), its
covariance, side and height where known; the links between markers with the paper's edge
values; and where the map came from.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.common.errors import MarkerGraphError
from markergraph.common.files import written_whole
from markergraph.estimator.estimate import Estimate
from markergraph.estimator.heights import MarkerHeight
from markergraph.estimator.paper import Edge, Form, edge_from_pose2, heading
from markergraph.frontend.sizes import MarkerSizes

__all__ = ["MAP_SCHEMA", "MapLink", "MapMarker", "MarkerMap", "MarkerMapError"]

MAP_SCHEMA = "markergraph.map/1"


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
    """

    marker_id: int
    T_map_marker: gtsam.Pose2
    covariance: NDArray[np.float64] | None
    n_observations: int
    size_m: float
    z_m: float | None = None
    sigma_z_m: float | None = None
    relative_covariance: NDArray[np.float64] | None = None

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
        """Standard deviations of x, y and yaw (0 without a covariance)."""
        if self.covariance is None:
            return (0.0, 0.0, 0.0)
        diagonal = np.sqrt(np.maximum(np.diag(self.covariance), 0.0))
        return (float(diagonal[0]), float(diagonal[1]), float(diagonal[2]))


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
        """The map as a JSON-ready document (schema ``markergraph.map/1``)."""
        markers = []
        for m in self.markers.values():
            T = m.T_map_marker
            entry: dict[str, Any] = {
                "id": m.marker_id,
                "x": T.x(),
                "y": T.y(),
                "yaw": T.theta(),
                "size_m": m.size_m,
                "covariance": _matrix(m.covariance),
                "n_observations": m.n_observations,
            }
            if m.z_m is not None:
                entry["z"] = m.z_m
            if m.sigma_z_m is not None:
                entry["sigma_z"] = m.sigma_z_m
            if m.relative_covariance is not None:
                entry["relative_covariance"] = _matrix(m.relative_covariance)
            markers.append(entry)
        links = [
            {
                "a": link.marker_a,
                "b": link.marker_b,
                "n_measurements": link.n_measurements,
                "phi": link.edge.phi,
                "theta_ab": link.edge.theta_ab,
                "theta_ba": link.edge.theta_ba,
                "d": link.edge.d,
                "covariance": _matrix(link.covariance),
            }
            for link in self.links
        ]
        return {
            "schema": MAP_SCHEMA,
            "frame": f"map: the frame of home marker {self.home_id} (x along its normal)",
            "units": {"length": "m", "angle": "rad"},
            "home_id": self.home_id,
            "dictionary": self.dictionary,
            "marker_size_m": self.marker_size_m,
            "method": self.method,
            "log": self.log,
            "converged": self.converged,
            "markers": markers,
            "links": links,
            "unplaced": {str(k): v for k, v in self.unplaced.items()},
        }

    @classmethod
    def from_document(cls, document: Any, source: str = "the map") -> MarkerMap:
        """A map from a ``markergraph.map/1`` document, every field checked.

        Raises:
            MarkerMapError: one line naming ``source`` and the first bad field.
        """
        if not isinstance(document, dict) or document.get("schema") != MAP_SCHEMA:
            found = document.get("schema") if isinstance(document, dict) else document
            raise MarkerMapError(f"{source}: not a {MAP_SCHEMA} document (schema {found!r})")
        read = _Reader(source)
        size = read.number("marker_size_m", document.get("marker_size_m"), positive=True)
        markers = {}
        for i, entry in enumerate(read.items("markers", document.get("markers"))):
            where = f"markers[{i}]"
            marker_id = read.whole(f"{where}.id", entry.get("id"))
            if marker_id in markers:
                raise MarkerMapError(f"{source}: {where}.id {marker_id} appears twice")
            pose = [read.number(f"{where}.{k}", entry.get(k)) for k in ("x", "y", "yaw")]
            markers[marker_id] = MapMarker(
                marker_id,
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
        links = []
        for i, entry in enumerate(read.items("links", document.get("links", []))):
            where = f"links[{i}]"
            edge = Edge(*(read.number(f"{where}.{k}", entry.get(k)) for k in _EDGE_KEYS))
            links.append(
                MapLink(
                    read.whole(f"{where}.a", entry.get("a")),
                    read.whole(f"{where}.b", entry.get("b")),
                    read.whole(f"{where}.n_measurements", entry.get("n_measurements")),
                    edge,
                    read.covariance(f"{where}.covariance", entry.get("covariance")),
                )
            )
        home = document.get("home_id", min(markers, default=0))
        dictionary = document.get("dictionary")
        if not isinstance(dictionary, str) or not dictionary.isprintable() or not dictionary:
            raise MarkerMapError(f"{source}: dictionary must be a name, got {dictionary!r}")
        unplaced = document.get("unplaced") or {}
        return cls(
            markers,
            tuple(links),
            read.whole("home_id", home),
            dictionary,
            size,
            str(document.get("method", "")),
            str(document.get("log", "")),
            bool(document.get("converged", True)),
            {int(k): str(v) for k, v in unplaced.items()} if isinstance(unplaced, dict) else {},
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
        try:
            document = json.loads(path.read_text(encoding="utf-8"), parse_constant=_refuse)
        except OSError as error:
            raise MarkerMapError(f"{path}: cannot read it ({error.strerror})") from None
        except UnicodeDecodeError:
            raise MarkerMapError(f"{path}: not UTF-8 text, so not a map.json") from None
        except ValueError as error:
            raise MarkerMapError(f"{path}: not a JSON document ({error})") from None
        return cls.from_document(document, str(path))


_EDGE_KEYS = ("phi", "theta_ab", "theta_ba", "d")
# Bounds on what a map may hold: any coordinate beyond 10,000 km, or a variance whose square
# root squared would overflow in a peer format, is a corrupted file, not a map.
MAX_VALUE = 1e7
MAX_VARIANCE = 1e100


def _matrix(matrix: NDArray[np.float64] | None) -> list[list[float]] | None:
    return None if matrix is None else [[float(v) for v in row] for row in matrix]


def _refuse(name: str) -> None:
    raise ValueError(f"{name} is not a number JSON allows")


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
    """Checks a document's fields, naming the source and the field in every error."""

    source: str

    def fail(self, where: str, what: str, value: Any) -> MarkerMapError:
        text = repr(value)
        shown = text if len(text) <= 40 else f"{text[:20]}... ({len(text)} characters)"
        return MarkerMapError(f"{self.source}: {where} must be {what}, got {shown}")

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

    def whole(self, where: str, value: Any) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise self.fail(where, "a whole number >= 0", value)
        return value

    def items(self, where: str, value: Any) -> list[dict[str, Any]]:
        if not isinstance(value, list):
            raise self.fail(where, "a list", value)
        for i, item in enumerate(value):
            if not isinstance(item, dict):
                raise self.fail(f"{where}[{i}]", "an object", item)
        return value

    def covariance(self, where: str, value: Any) -> NDArray[np.float64] | None:
        if value is None:
            return None
        if (
            not isinstance(value, list)
            or len(value) != 3
            or not all(isinstance(row, list) and len(row) == 3 for row in value)
        ):
            raise self.fail(where, "a 3x3 matrix or null", value)
        return np.array([[self.number(where, v, limit=MAX_VARIANCE) for v in row] for row in value])
