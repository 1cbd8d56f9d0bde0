"""A first guess of every rig pose, tag pose and unknown camera mount, from each view's own PnP
pose: the surveyed tags (or the home tag) are placed first, and from there, cheapest first, each
view places the one of its rig frame, camera and tag that is still missing (a Dijkstra search
over the views, a view's cost growing with the square of the tag's distance over its size, so
that a near tag places what a far one could only guess). Odometry places a rig frame from its
neighbour where no tag does. What no chain reaches stays unplaced."""

from __future__ import annotations

import heapq
import itertools
from collections import defaultdict
from dataclasses import dataclass, field

import gtsam
import numpy as np

from markergraph.estimator.tags3d import TagScene, TagView

__all__ = ["Placed", "place"]

ODOMETRY_COST = 0.05
"""A step of odometry's cost (about a view of a tag at 1 m at 1 px per focal length)."""


@dataclass
class Placed:
    """The first guess: what was placed, by index (frames, cameras) or id (tags)."""

    frames: dict[int, gtsam.Pose3] = field(default_factory=dict)
    tags: dict[int, gtsam.Pose3] = field(default_factory=dict)
    cameras: dict[int, gtsam.Pose3] = field(default_factory=dict)
    order: list[tuple[str, int]] = field(default_factory=list)
    """What was placed, in the order it was: ``("f", frame)``, ``("t", tag id)``,
    ``("c", camera)`` (each placed from what came before it)."""


def _cost(view: TagView, size_m: float) -> float:
    depth = float(np.linalg.norm(view.T_camera_tag.translation()))
    return view.sigma * depth * depth / size_m + 1e-9


class _Search:
    def __init__(self, scene: TagScene) -> None:
        self.scene = scene
        self.placed = Placed()
        self.heap: list[tuple[float, int, str, int, gtsam.Pose3]] = []
        self.order = itertools.count()
        self.by: dict[tuple[str, int], list[TagView]] = defaultdict(list)
        for view in scene.views:
            self.by["f", view.frame].append(view)
            self.by["t", view.tag_id].append(view)
            self.by["c", view.camera].append(view)

    def push(self, cost: float, kind: str, key: int, pose: gtsam.Pose3) -> None:
        heapq.heappush(self.heap, (cost, next(self.order), kind, key, pose))

    def run(self) -> Placed:
        while self.heap:
            cost, _, kind, key, pose = heapq.heappop(self.heap)
            table = self._table(kind)
            if key in table:
                continue
            table[key] = pose
            self.placed.order.append((kind, key))
            for view in self.by[kind, key]:
                self._extend(view, cost)
            if kind == "f":
                self._odometry(key, cost)
        return self.placed

    def _table(self, kind: str) -> dict[int, gtsam.Pose3]:
        return {"f": self.placed.frames, "t": self.placed.tags, "c": self.placed.cameras}[kind]

    def _extend(self, view: TagView, cost: float) -> None:
        rig = self.placed.frames.get(view.frame)
        mount = self.placed.cameras.get(view.camera)
        tag = self.placed.tags.get(view.tag_id)
        cost += _cost(view, self.scene.tag_sizes[view.tag_id])
        if rig is not None and mount is not None and tag is None:
            self.push(cost, "t", view.tag_id, rig.compose(mount).compose(view.T_camera_tag))
        elif tag is not None and mount is not None and rig is None:
            camera = tag.compose(view.T_camera_tag.inverse())
            self.push(cost, "f", view.frame, camera.compose(mount.inverse()))
        elif rig is not None and tag is not None and mount is None:
            camera = tag.compose(view.T_camera_tag.inverse())
            self.push(cost, "c", view.camera, rig.between(camera))

    def _odometry(self, frame: int, cost: float) -> None:
        odometry = self.scene.odometry
        if not odometry or odometry[frame] is None:
            return
        for neighbour in (frame - 1, frame + 1):
            if 0 <= neighbour < len(odometry) and odometry[neighbour] is not None:
                step = odometry[frame].between(odometry[neighbour])
                rig = self.placed.frames[frame].compose(step)
                self.push(cost + ODOMETRY_COST, "f", neighbour, rig)


def place(scene: TagScene, home_id: int | None, cameras: dict[int, gtsam.Pose3]) -> Placed:
    """The first guess, in the surveyed tags' frame, else in ``home_id``'s (at the identity).

    Args:
        cameras: camera index -> its mount, for the mounts known before the search (given,
            seeded, or the first camera taken as the rig's frame).
    """
    search = _Search(scene)
    search.placed.cameras.update(cameras)
    for known in scene.known_tags:
        search.push(0.0, "t", known.tag_id, known.T_map_tag)
    if not scene.known_tags and home_id is not None:
        search.push(0.0, "t", home_id, gtsam.Pose3())
    return search.run()
