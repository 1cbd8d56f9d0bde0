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
from collections.abc import Callable
from dataclasses import dataclass, field

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.estimator.corner_factor import residuals
from markergraph.estimator.tags3d import TagScene, TagView, tag_corners

__all__ = ["CHI2_CAP", "Consensus", "Placed", "agree", "place"]

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
    ``("c", camera)``."""


def _cost(view: TagView, size_m: float) -> float:
    depth = float(np.linalg.norm(view.T_camera_tag.translation()))
    return float(np.mean(view.sigma)) * depth * depth / size_m + 1e-9


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
                self.extend(view, cost)
            if kind == "f":
                self._odometry(key, cost)
        return self.placed

    def _table(self, kind: str) -> dict[int, gtsam.Pose3]:
        return {"f": self.placed.frames, "t": self.placed.tags, "c": self.placed.cameras}[kind]

    def extend(self, view: TagView, cost: float) -> None:
        rig = self.placed.frames.get(view.frame)
        mount = self.placed.cameras.get(view.camera)
        tag = self.placed.tags.get(view.tag_id)
        cost += _cost(view, self.scene.tag_sizes[view.tag_id])
        if rig is not None and mount is not None and tag is None:
            self.push(cost, "t", view.tag_id, rig.compose(mount).compose(view.T_camera_tag))
        elif tag is not None and mount is not None and rig is None:
            camera = tag.compose(view.T_camera_tag.inverse())
            self.push(cost, "f", view.frame, camera.compose(mount.inverse()))

    def _odometry(self, frame: int, cost: float) -> None:
        odometry = self.scene.odometry
        if not odometry or odometry[frame] is None:
            return
        here = odometry[frame]
        for neighbour in (frame - 1, frame + 1):
            there = odometry[neighbour] if 0 <= neighbour < len(odometry) else None
            if here is not None and there is not None:
                step = here.between(there)
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
    search.run()
    consensus = Consensus(scene, search.placed, set())
    while True:  # each unknown mount from all it saw of the map so far, then on from it
        mounts = {c: consensus.mount(c) for c in {v.camera for v in scene.views}}
        found = {
            c: m for c, m in mounts.items() if m is not None and c not in search.placed.cameras
        }
        if not found:
            return search.placed
        for camera, mount in found.items():
            search.placed.cameras[camera] = mount
            search.placed.order.append(("c", camera))
            for view in search.by["c", camera]:
                search.extend(view, 0.0)
        search.run()


CHI2_CAP = 25.0
"""A view's mean squared corner error (in its sigmas) counts at most this much when choosing
between guesses: a misdetection or a flipped view cannot outvote the rest."""
TURN_SCALE_RAD = 0.2
"""A rig frame seen through one view is also scored by how far it turns from its placed
neighbour in time, in units of this (the flip of a far tag is a turn of tens of degrees)."""
MAX_CANDIDATES = 8
"""Views whose PnP solutions are tried for one pose (the nearest tags')."""
MAX_MOUNT_CANDIDATES = 100
"""A mount is tried from this many of its views (spread through them): one camera's views all
hang on it, so it is worth the search."""
MAX_SCORED = 40
"""Views a candidate is scored on (spread through the pose's views)."""


def _matrices(poses: list[gtsam.Pose3]) -> NDArray[np.float64]:
    return np.array([p.matrix() for p in poses])


class Consensus:
    """Each pose chosen again among the PnP solutions of all its views (both of each square's
    two), by how well it fits all of them, the others held: a flipped view placed first cannot
    stand against the views that disagree with it."""

    def __init__(self, scene: TagScene, placed: Placed, movable_cameras: set[int]) -> None:
        self.scene, self.placed, self.movable_cameras = scene, placed, movable_cameras
        self.by_frame: dict[int, list[TagView]] = defaultdict(list)
        self.by_tag: dict[int, list[TagView]] = defaultdict(list)
        self.by_camera: dict[int, list[TagView]] = defaultdict(list)
        for view in scene.views:
            self.by_frame[view.frame].append(view)
            self.by_tag[view.tag_id].append(view)
            self.by_camera[view.camera].append(view)
        self.corners = {i: tag_corners(s) for i, s in scene.tag_sizes.items()}
        self.fixed_tags = {k.tag_id for k in scene.known_tags}
        # Each view's arrays stacked once (a pose is chosen thousands of times over).
        self.row = {id(v): k for k, v in enumerate(scene.views)}
        self.view_corners = np.array([self.corners[v.tag_id] for v in scene.views]).reshape(
            -1, 4, 3
        )
        self.view_rays = np.array([v.rays for v in scene.views]).reshape(-1, 4, 2)
        self.view_sigmas = np.array([v.sigma for v in scene.views]).reshape(-1, 8)
        self.depth = np.array(
            [float(np.linalg.norm(v.T_camera_tag.translation())) for v in scene.views]
        )

    def rows(self, views: list[TagView]) -> NDArray[np.int64]:
        """The views' places in the scene's list."""
        return np.array([self.row[id(v)] for v in views], dtype=np.int64)

    allowed: Callable[[TagView], bool] | None = None
    """Where set, only the views it allows are weighed (iSAM2: those already entered)."""

    def usable(self, views: list[TagView]) -> list[TagView]:
        p = self.placed
        if self.allowed is not None:
            views = [v for v in views if self.allowed(v)]
        return [
            v for v in views if v.frame in p.frames and v.tag_id in p.tags and v.camera in p.cameras
        ]

    def chi2(
        self,
        views: list[TagView],
        rigs: NDArray[np.float64],
        mounts: NDArray[np.float64],
        tags: NDArray[np.float64],
        cap: float = CHI2_CAP,
    ) -> NDArray[np.float64]:
        """Mean squared errors (k candidates, n views) for (k, n, 4, 4) poses, capped."""
        k, n = rigs.shape[:2]
        rows = self.rows(views)
        corners = np.broadcast_to(self.view_corners[rows], (k, n, 4, 3))
        rays = np.broadcast_to(self.view_rays[rows], (k, n, 4, 2))
        residual, _, _ = residuals(
            (rigs @ mounts).reshape(-1, 4, 4),
            tags.reshape(-1, 4, 4),
            corners.reshape(-1, 4, 3),
            rays.reshape(-1, 4, 2),
        )
        sigma = self.view_sigmas[rows]  # (n, 8)
        chi2 = np.mean((residual.reshape(k, n, 8) / sigma) ** 2, axis=2)
        return np.minimum(np.nan_to_num(chi2, nan=cap), cap)

    def _pick(
        self,
        views: list[TagView],
        candidates: list[gtsam.Pose3],
        kind: str,
        extra: NDArray[np.float64] | None = None,
    ) -> gtsam.Pose3:
        p = self.placed
        scored = views[:: max(1, len(views) // MAX_SCORED)][:MAX_SCORED]
        rigs = _matrices([p.frames[v.frame] for v in scored])
        mounts = _matrices([p.cameras[v.camera] for v in scored])
        tags = _matrices([p.tags[v.tag_id] for v in scored])
        k = len(candidates)
        c = _matrices(candidates)[:, None]
        rigs, mounts, tags = (
            np.broadcast_to(a, (k, *a.shape)).copy() for a in (rigs, mounts, tags)
        )
        if kind == "f":
            rigs[:] = c
        elif kind == "t":
            tags[:] = c
        else:
            mounts[:] = c
        score = self.chi2(scored, rigs, mounts, tags).sum(axis=1)
        if extra is not None:
            score = score + extra
        return candidates[int(np.argmin(score))]

    @staticmethod
    def _seeds(view: TagView) -> list[gtsam.Pose3]:
        return [s for s in (view.T_camera_tag, view.T_camera_tag_alt) if s is not None]

    def _nearest(self, views: list[TagView]) -> list[TagView]:
        depth = self.depth[self.rows(views)]
        return [views[i] for i in np.argsort(depth)[:MAX_CANDIDATES]]

    def frame(self, frame: int) -> None:
        p = self.placed
        views = self.usable(self.by_frame[frame])
        if not views:
            return
        candidates = [p.frames[frame]] + [
            p.tags[v.tag_id].compose(seed.inverse()).compose(p.cameras[v.camera].inverse())
            for v in self._nearest(views)
            for seed in self._seeds(v)
        ]
        candidates += self._from_centres(views) + self._from_odometry(frame)
        extra = None
        if len(views) <= 2:
            neighbours = [p.frames[i] for i in (frame - 1, frame + 1) if i in p.frames]
            if neighbours:
                turns = np.array(
                    [
                        [
                            np.linalg.norm(gtsam.Rot3.Logmap(c.rotation().between(n.rotation())))
                            for n in neighbours
                        ]
                        for c in candidates
                    ]
                )
                extra = (turns.min(axis=1) / TURN_SCALE_RAD) ** 2
        p.frames[frame] = self._pick(views, candidates, "f", extra)

    def _from_centres(self, views: list[TagView]) -> list[gtsam.Pose3]:
        """The rig pose that best lays the tags' centres as seen (three or more tags; a centre's
        position does not flip with its tag's tilt) on their placed positions."""
        if len({v.tag_id for v in views}) < 3:
            return []
        p = self.placed
        seen = np.array(
            [p.cameras[v.camera].transformFrom(v.T_camera_tag.translation()) for v in views]
        )
        placed = np.array([p.tags[v.tag_id].translation() for v in views])
        ca, cb = seen.mean(axis=0), placed.mean(axis=0)
        U, _, Vt = np.linalg.svd((seen - ca).T @ (placed - cb))
        d = np.sign(np.linalg.det(Vt.T @ U.T))
        R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
        return [gtsam.Pose3(gtsam.Rot3(R), cb - R @ ca)]

    def _from_odometry(self, frame: int) -> list[gtsam.Pose3]:
        odometry, p = self.scene.odometry, self.placed
        here = odometry[frame] if odometry else None
        if here is None:
            return []
        return [
            p.frames[i].compose(there.between(here))
            for i in (frame - 1, frame + 1)
            if (there := odometry[i] if 0 <= i < len(odometry) else None) is not None
            if i in p.frames and 0 <= i < len(odometry) and odometry[i] is not None
        ]

    def tag(self, tag_id: int) -> None:
        p = self.placed
        views = self.usable(self.by_tag[tag_id])
        if not views or tag_id in self.fixed_tags:
            return
        candidates = [p.tags[tag_id]] + [
            p.frames[v.frame].compose(p.cameras[v.camera]).compose(seed)
            for v in self._nearest(views)
            for seed in self._seeds(v)
        ]
        p.tags[tag_id] = self._pick(views, candidates, "t")

    def mount(self, camera: int) -> gtsam.Pose3 | None:
        """An unplaced camera's mount from all its views of placed tags in placed frames (the
        candidate that fits most of them), None without any."""
        p = self.placed
        if camera in p.cameras:
            return None
        views = [v for v in self.by_camera[camera] if v.frame in p.frames and v.tag_id in p.tags]
        if not views:
            return None
        spread = views[:: max(1, len(views) // MAX_MOUNT_CANDIDATES)]
        candidates = [
            p.frames[v.frame].between(p.tags[v.tag_id].compose(seed.inverse()))
            for v in spread
            for seed in self._seeds(v)
        ]
        p.cameras[camera] = candidates[0]
        try:
            return self._pick(views, candidates, "c")
        finally:
            del p.cameras[camera]

    def camera(self, camera: int) -> None:
        p = self.placed
        views = self.usable(self.by_camera[camera])
        if not views or camera not in self.movable_cameras:
            return
        spread = views[:: max(1, len(views) // MAX_MOUNT_CANDIDATES)]
        candidates = [p.cameras[camera]] + [
            p.frames[v.frame].between(p.tags[v.tag_id].compose(seed.inverse()))
            for v in spread
            for seed in self._seeds(v)
        ]
        p.cameras[camera] = self._pick(views, candidates, "c")


def agree(scene: TagScene, placed: Placed, movable_cameras: set[int], rounds: int = 3) -> None:
    """Choose each placed pose again by consensus (:class:`Consensus`), ``rounds`` times over:
    frames, then tags, then the estimated mounts. The home tag and surveyed tags stay."""
    consensus = Consensus(scene, placed, movable_cameras)
    for _ in range(rounds):
        for frame in list(placed.frames):
            consensus.frame(frame)
        for tag_id in list(placed.tags):
            if placed.order and placed.order[0] == ("t", tag_id):
                continue  # the tag that fixed the frame
            consensus.tag(tag_id)
        for camera in sorted(movable_cameras & set(placed.cameras)):
            consensus.camera(camera)
