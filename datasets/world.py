"""Worlds: 2-D floor plans (walls as segments) with ArUco markers hung on the walls."""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.common.errors import MarkerGraphError

__all__ = ["Marker", "Wall", "World", "WorldFileError"]

WORLD_SCHEMA = "markergraph.world/1"


class WorldFileError(MarkerGraphError):
    """A world file that cannot be read."""


@dataclass(frozen=True, slots=True)
class Wall:
    """A straight wall from ``start`` to ``end`` (top view) [m]."""

    start: tuple[float, float]
    end: tuple[float, float]

    @property
    def length(self) -> float:
        return math.dist(self.start, self.end)


@dataclass(frozen=True, slots=True)
class Marker:
    """A square marker on a wall, facing into the room.

    Attributes:
        id: the marker's id in ``dictionary``.
        wall: index of the wall it hangs on.
        position_m: its centre's distance from the wall's ``start`` along the wall [m].
        side: +1 if it faces the left of the wall's start-to-end direction, -1 the right.
        height_m: its centre's height above the floor [m].
        size_m: side length of the black square [m].
        dictionary: an OpenCV predefined dictionary name, e.g. ``"DICT_4X4_50"``.
        label: a free-form note (``"home"``, ``"charging station"``).
    """

    id: int
    wall: int
    position_m: float
    side: int = 1
    height_m: float = 1.0
    size_m: float = 0.2
    dictionary: str = "DICT_4X4_50"
    label: str = ""


@dataclass(frozen=True)
class World:
    """A floor plan with markers; the home marker's frame is the map frame.

    Attributes:
        name: the scenario's name.
        walls: the walls.
        markers: the markers, ids unique.
        home_id: the id of the home marker.
    """

    name: str
    walls: tuple[Wall, ...]
    markers: tuple[Marker, ...]
    home_id: int

    def __post_init__(self) -> None:
        ids = [m.id for m in self.markers]
        if len(set(ids)) != len(ids):
            raise WorldFileError(f"world {self.name!r}: marker ids are not unique")
        if self.home_id not in ids:
            raise WorldFileError(f"world {self.name!r}: home marker {self.home_id} is not a marker")
        for m in self.markers:
            if not 0 <= m.wall < len(self.walls):
                raise WorldFileError(f"world {self.name!r}: marker {m.id} is on no wall ({m.wall})")

    def marker(self, marker_id: int) -> Marker:
        for m in self.markers:
            if m.id == marker_id:
                return m
        raise KeyError(marker_id)

    def T_world_marker(self, marker_id: int) -> gtsam.Pose2:
        """A marker's pose in the world: on its wall, +x along the normal it faces."""
        m = self.marker(marker_id)
        wall = self.walls[m.wall]
        start, end = np.array(wall.start), np.array(wall.end)
        centre = start + (end - start) * (m.position_m / wall.length)
        along = math.atan2(end[1] - start[1], end[0] - start[0])
        return gtsam.Pose2(centre[0], centre[1], along + m.side * math.pi / 2.0)

    def T_map_markers(self) -> dict[int, gtsam.Pose2]:
        """Every marker's true pose in the map frame (the home marker's frame)."""
        T_map_world = self.T_world_marker(self.home_id).inverse()
        return {m.id: T_map_world.compose(self.T_world_marker(m.id)) for m in self.markers}

    def marker_corners(self, marker_id: int) -> NDArray[np.float64]:
        """(4, 3) world corners of the black square in OpenCV's order: top-left, top-right,
        bottom-right, bottom-left of the printed marker as a viewer facing it sees it."""
        m = self.marker(marker_id)
        T = self.T_world_marker(marker_id)
        # A viewer facing the marker looks along -x; their right is the marker's +y.
        right = np.array([-math.sin(T.theta()), math.cos(T.theta()), 0.0]) * m.size_m / 2.0
        up = np.array([0.0, 0.0, m.size_m / 2.0])
        centre = np.array([T.x(), T.y(), m.height_m])
        return np.array(
            [centre - right + up, centre + right + up, centre + right - up, centre - right - up]
        )

    def wall_array(self) -> NDArray[np.float64]:
        """(W, 4) walls as rows (x0, y0, x1, y1)."""
        return np.array([[*w.start, *w.end] for w in self.walls], dtype=np.float64)

    def blocked(self, p_xy: NDArray[np.float64], q_xy: NDArray[np.float64]) -> bool:
        """Whether a wall crosses the open segment from ``p`` to ``q``, ends excluded by 1 mm."""
        walls = self.wall_array()
        a, b = walls[:, :2], walls[:, 2:]
        r, s = q_xy - p_xy, b - a
        denominator = r[0] * s[:, 1] - r[1] * s[:, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((a[:, 0] - p_xy[0]) * s[:, 1] - (a[:, 1] - p_xy[1]) * s[:, 0]) / denominator
            u = ((a[:, 0] - p_xy[0]) * r[1] - (a[:, 1] - p_xy[1]) * r[0]) / denominator
        margin = 1e-3 / max(float(np.hypot(*r)), 1e-9)
        hits = (np.abs(denominator) > 1e-12) & (t > margin) & (t < 1 - margin) & (u >= 0) & (u <= 1)
        return bool(np.any(hits))

    # --- files ---------------------------------------------------------------------------

    def to_json(self) -> str:
        return json.dumps(
            {
                "schema": WORLD_SCHEMA,
                "name": self.name,
                "home_id": self.home_id,
                "walls": [[*w.start, *w.end] for w in self.walls],
                "markers": [asdict(m) for m in self.markers],
            },
            indent=1,
        )

    def save(self, path: Path) -> None:
        Path(path).write_text(self.to_json() + "\n")

    @classmethod
    def from_json(cls, text: str, source: str = "<string>") -> World:
        try:
            data = json.loads(text)
            if data.get("schema") != WORLD_SCHEMA:
                raise WorldFileError(
                    f"{source}: not a {WORLD_SCHEMA} file (schema {data.get('schema')!r})"
                )
            walls = tuple(Wall((w[0], w[1]), (w[2], w[3])) for w in data["walls"])
            markers = tuple(Marker(**m) for m in data["markers"])
            return cls(data["name"], walls, markers, int(data["home_id"]))
        except (json.JSONDecodeError, KeyError, TypeError, IndexError) as error:
            raise WorldFileError(f"{source}: not a readable world file ({error})") from error

    @classmethod
    def load(cls, path: Path) -> World:
        return cls.from_json(Path(path).read_text(), source=str(path))
