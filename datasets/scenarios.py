"""The named scenarios: a world and the route the robot drives in it."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from markergraph.datasets.route import GoTo, Look, Route
from markergraph.datasets.world import Marker, Wall, World

__all__ = ["SCENARIOS", "scenario"]

Point = tuple[float, float]


def _cross(u: np.ndarray, v: np.ndarray) -> float:
    return float(u[0] * v[1] - u[1] * v[0])


def _walls_with_doors(start: Point, end: Point, doors: Sequence[float], width: float) -> list[Wall]:
    """A wall split by doorways centred ``doors`` metres from ``start``."""
    length = math.dist(start, end)
    cuts = [0.0]
    for centre in sorted(doors):
        cuts += [centre - width / 2.0, centre + width / 2.0]
    cuts.append(length)
    direction = (np.array(end) - np.array(start)) / length
    points = [tuple(float(v) for v in np.array(start) + c * direction) for c in cuts]
    return [Wall(points[i], points[i + 1]) for i in range(0, len(points), 2)]  # type: ignore[arg-type]


def _rectangle(x0: float, y0: float, x1: float, y1: float) -> list[Wall]:
    """Four walls, counter-clockwise, so the inside is on each wall's left."""
    return [
        Wall((x0, y0), (x1, y0)),
        Wall((x1, y0), (x1, y1)),
        Wall((x1, y1), (x0, y1)),
        Wall((x0, y1), (x0, y0)),
    ]


def _marker_at(
    walls: Sequence[Wall], marker_id: int, point: Point, facing: Point, **options: object
) -> Marker:
    """A marker centred at ``point`` on whichever wall holds it, facing toward ``facing``."""
    p = np.array(point)
    for index, wall in enumerate(walls):
        a, b = np.array(wall.start), np.array(wall.end)
        along = float(np.dot(p - a, b - a) / wall.length)
        off = abs(_cross(b - a, p - a)) / wall.length
        if off < 1e-9 and 0.15 <= along <= wall.length - 0.15:
            side = 1 if _cross(b - a, np.array(facing) - p) > 0 else -1
            return Marker(id=marker_id, wall=index, position_m=along, side=side, **options)  # type: ignore[arg-type]
    raise ValueError(f"marker {marker_id}: no wall holds {point} at least 0.15 m from its ends")


def paper_room() -> tuple[World, Route]:
    """One 6 x 4 m room, three markers on three consecutive walls; marker 2 marks a charger."""
    walls = _rectangle(0.0, 0.0, 6.0, 4.0)
    markers = (
        _marker_at(walls, 0, (0.0, 1.5), (1.0, 1.5), label="home"),
        _marker_at(walls, 1, (2.5, 4.0), (2.5, 3.0)),
        _marker_at(walls, 2, (6.0, 2.6), (5.0, 2.6), label="charging station"),
    )
    world = World("paper-room", tuple(walls), markers, home_id=0)
    steps = (
        Look(0),
        GoTo(2.2, 1.8),
        Look(1),
        GoTo(4.2, 1.6),
        Look(2),
        GoTo(4.9, 2.6),
        Look(2),
        GoTo(3.0, 1.2),
        Look(1),
        GoTo(1.8, 1.5),
    )
    return world, Route(start=(1.8, 1.5, math.pi), steps=steps, laps=3)


def corridor_loop() -> tuple[World, Route]:
    """A 2.5 m wide corridor around an 13 x 7 m block, 50 m a lap, 12 markers, two laps."""
    walls = _rectangle(0.0, 0.0, 18.0, 12.0) + _rectangle(2.5, 2.5, 15.5, 9.5)
    mid = 1.25  # the corridor's centreline is 1.25 m from the outer walls
    top = 12.0 - mid
    right = 18.0 - mid
    # (point on a wall, the centreline point facing it), in the order the robot meets them.
    placements = [
        ((0.0, 6.0), (mid, 6.0)),
        ((4.0, 0.0), (4.0, mid)),
        ((6.5, 2.5), (6.5, mid)),
        ((9.0, 0.0), (9.0, mid)),
        ((11.5, 2.5), (11.5, mid)),
        ((14.0, 0.0), (14.0, mid)),
        ((18.0, 6.0), (right, 6.0)),
        ((14.0, 12.0), (14.0, top)),
        ((11.0, 9.5), (11.0, top)),
        ((9.0, 12.0), (9.0, top)),
        ((6.0, 9.5), (6.0, top)),
        ((4.0, 12.0), (4.0, top)),
    ]
    markers = tuple(
        _marker_at(walls, i, point, facing, label="home" if i == 0 else "")
        for i, (point, facing) in enumerate(placements)
    )
    world = World("corridor-loop", tuple(walls), markers, home_id=0)
    corner_before = {1: (mid, mid), 6: (right, mid), 7: (right, top)}
    steps: list[GoTo | Look] = [Look(0)]
    for i, (_, facing) in enumerate(placements[1:], start=1):
        if i in corner_before:
            steps.append(GoTo(*corner_before[i]))
        steps += [GoTo(*facing), Look(i)]
    steps += [GoTo(mid, top), GoTo(mid, 6.0), Look(0)]
    return world, Route(start=(mid, 4.5, math.pi), steps=tuple(steps), laps=2)


def office() -> tuple[World, Route]:
    """Six 5 x 4 m rooms in a 3 x 2 grid joined by doorways, five markers a room (30)."""
    door = 1.0
    walls = [
        Wall((0.0, 0.0), (15.0, 0.0)),
        Wall((15.0, 0.0), (15.0, 8.0)),
        Wall((15.0, 8.0), (0.0, 8.0)),
        Wall((0.0, 8.0), (0.0, 0.0)),
    ]
    walls += _walls_with_doors((5.0, 0.0), (5.0, 8.0), [2.0, 6.0], door)
    walls += _walls_with_doors((10.0, 0.0), (10.0, 8.0), [2.0, 6.0], door)
    walls += _walls_with_doors((0.0, 4.0), (15.0, 4.0), [2.5, 7.5, 12.5], door)
    markers: list[Marker] = []
    room_order = [(0, 0), (1, 0), (2, 0), (2, 1), (1, 1), (0, 1)]
    for col, row in room_order:
        x0, y0 = 5.0 * col, 4.0 * row
        centre = (x0 + 2.5, y0 + 2.0)
        for point in [
            (x0 + 1.0, y0),
            (x0 + 4.0, y0),
            (x0 + 5.0, y0 + 3.2),
            (x0 + 4.0, y0 + 4.0),
            (x0, y0 + 3.2),
        ]:
            markers.append(
                _marker_at(walls, len(markers), point, centre, label="home" if not markers else "")
            )
    world = World("office", tuple(walls), tuple(markers), home_id=0)
    steps: list[GoTo | Look] = []
    doors_between = {
        ((0, 0), (1, 0)): (5.0, 2.0),
        ((1, 0), (2, 0)): (10.0, 2.0),
        ((2, 0), (2, 1)): (12.5, 4.0),
        ((2, 1), (1, 1)): (10.0, 6.0),
        ((1, 1), (0, 1)): (5.0, 6.0),
        ((0, 1), (0, 0)): (2.5, 4.0),
    }
    for index, room in enumerate(room_order):
        col, row = room
        steps.append(GoTo(5.0 * col + 2.5, 4.0 * row + 2.0))
        steps += [Look(i) for i in range(5 * index, 5 * index + 5)]
        following = room_order[(index + 1) % len(room_order)]
        steps.append(GoTo(*doors_between[(room, following)]))
    steps += [GoTo(2.5, 2.0), Look(0)]
    return world, Route(start=(2.5, 2.0, -math.pi / 2), steps=(Look(0), *steps), laps=1)


def warehouse() -> tuple[World, Route]:
    """A 40 x 30 m hall with six rows of racks, 230 markers on racks and walls."""
    walls = _rectangle(0.0, 0.0, 40.0, 30.0)
    rack_y = [5.0, 9.0, 13.0, 17.0, 21.0, 25.0]
    for y in rack_y:
        walls += _rectangle(5.0, y, 35.0, y + 1.0)
    markers: list[Marker] = []

    def add(point: Point, facing: Point) -> None:
        markers.append(
            _marker_at(
                walls,
                len(markers),
                point,
                facing,
                dictionary="DICT_4X4_250",
                label="home" if not markers else "",
            )
        )

    for x in np.arange(2.5, 40.0, 2.5):
        add((float(x), 0.0), (float(x), 1.0))
        add((float(x), 30.0), (float(x), 29.0))
    for y in np.arange(2.5, 30.0, 2.5):
        add((0.0, float(y)), (1.0, float(y)))
        add((40.0, float(y)), (39.0, float(y)))
    for y in rack_y:
        for x in np.arange(6.0, 35.0, 2.0):
            add((float(x), y), (float(x), y - 1.0))
            add((float(x), y + 1.0), (float(x), y + 2.0))
    world = World("warehouse", tuple(walls), tuple(markers), home_id=0)
    steps: list[GoTo | Look] = [Look(0)]
    aisles = [3.0, 7.0, 11.0, 15.0, 19.0, 23.0, 27.5]
    for index, y in enumerate(aisles):
        xs = (3.0, 37.0) if index % 2 == 0 else (37.0, 3.0)
        steps += [GoTo(xs[0], y), GoTo(xs[1], y)]
    steps += [GoTo(37.0, 3.0), GoTo(3.0, 3.0), GoTo(2.5, 1.5), Look(0)]
    return world, Route(start=(2.5, 1.5, -math.pi / 2), steps=tuple(steps), laps=1)


SCENARIOS: dict[str, Callable[[], tuple[World, Route]]] = {
    "paper-room": paper_room,
    "corridor-loop": corridor_loop,
    "office": office,
    "warehouse": warehouse,
}


def scenario(name: str) -> tuple[World, Route]:
    """The world and route of a named scenario."""
    try:
        return SCENARIOS[name]()
    except KeyError:
        raise ValueError(
            f"unknown scenario {name!r}; choose one of {', '.join(SCENARIOS)}"
        ) from None
