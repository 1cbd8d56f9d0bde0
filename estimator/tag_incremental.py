"""The 3-D tag graph solved incrementally (iSAM2), as a rig's poses would arrive: each rig frame,
tag and unknown mount enters in the order the first guess placed them (so that each is tied to
what is already there), its pose chosen afresh against the current estimate of its neighbours
(among its views' PnP solutions, both of a square's two), and only the views that agree with
that pose enter with it: a flipped or misdetected view never reaches the solver.
"""

from __future__ import annotations

from collections import defaultdict

import gtsam
import numpy as np

from markergraph.common.errors import EstimationError
from markergraph.estimator.corner_factor import frame_factor
from markergraph.estimator.solution import first_line
from markergraph.estimator.tag_graph import TagGraph, camera_key, rig_key, tag_key
from markergraph.estimator.tag_init import Consensus
from markergraph.estimator.tags3d import TagView

__all__ = ["solve_incremental"]

ROBUST_K = 3.0
"""Each view enters under a Cauchy kernel this wide [sigmas] ..."""
READMISSIONS = 2
SETTLING_UPDATES = 5
"""... and the views left out are offered again this many times at the end."""
RELINEARIZE_THRESHOLD = 0.01
"""iSAM2 relinearises a pose whose update exceeds this (rotation [rad], translation [m])."""
GATE_CHI2 = 100.0
"""A view enters only if its mean squared corner error (in its sigmas) at the entering pose
is below this (ten sigmas: the entering pose is a guess, not yet the solution)."""


class _Feed:
    def __init__(self, graph: TagGraph) -> None:
        self.graph, self.placed = graph, graph.placed
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(RELINEARIZE_THRESHOLD)
        self.isam = gtsam.ISAM2(params)
        self.consensus = Consensus(graph.scene, self.placed, graph.estimated)
        self.present: set[tuple[str, int]] = set()
        self.consensus.allowed = self._entered_with
        self.views = list(graph.views)
        self.waiting: dict[tuple[str, int], list[int]] = defaultdict(list)
        for k, view in enumerate(self.views):
            for entity in _entities(view):
                self.waiting[entity].append(k)
        self.taken: set[int] = set()
        self.factors = gtsam.NonlinearFactorGraph()
        self.values = gtsam.Values()
        self.used: list[TagView] = []

    def _key(self, kind: str, key: int) -> int:
        return {"f": rig_key, "t": tag_key, "c": camera_key}[kind](key)

    def _refresh(self, views: list[TagView]) -> None:
        """The placed poses of these views' frames, tags and mounts from the current estimate."""
        p, graph = self.placed, self.graph
        for view in views:
            for kind, key, table in (("f", view.frame, p.frames), ("t", view.tag_id, p.tags)):
                if (kind, key) in self.present and self.isam.valueExists(self._key(kind, key)):
                    table[key] = self.isam.calculateEstimatePose3(self._key(kind, key))
            c = view.camera
            if c in graph.estimated and self.isam.valueExists(camera_key(c)):
                p.cameras[c] = self.isam.calculateEstimatePose3(camera_key(c))

    def _entered_with(self, view: TagView) -> bool:
        return all(e in self.present for e in _entities(view))

    def _ready(self, kind: str, key: int) -> list[TagView]:
        """The views this entity completes (its frame, tag and mount all present), each once."""
        ready = [k for k in self.waiting.pop((kind, key), [])
                 if k not in self.taken and self._entered_with(self.views[k])]  # fmt: skip
        self.taken.update(ready)
        return [self.views[k] for k in ready]

    def enter(self, kind: str, key: int) -> None:
        graph = self.graph
        self.present.add((kind, key))
        views = self._ready(kind, key)
        self._refresh(views)
        if views and not (kind == "t" and graph.tag_prior(key) is not None):
            getattr(self.consensus, {"f": "frame", "t": "tag", "c": "camera"}[kind])(key)
        if kind == "f":
            self.values.insert(rig_key(key), self.placed.frames[key])
            for neighbour in (key - 1, key + 1):
                if ("f", neighbour) in self.present:
                    self.factors.add(graph.step(min(key, neighbour), max(key, neighbour)))
        elif kind == "t":
            self.values.insert(tag_key(key), self.placed.tags[key])
            prior = graph.tag_prior(key)
            if prior is not None:
                self.factors.add(prior)
        elif key in graph.estimated:
            self.values.insert(camera_key(key), self.placed.cameras[key])
            prior = graph.camera_prior(key)
            if prior is not None:
                self.factors.add(prior)
        self._add(views)

    def _add(self, views: list[TagView]) -> None:
        """The views that agree with the poses they join, one factor a frame."""
        if not views:
            return
        p = self.placed
        chi2 = self.consensus.chi2(
            views,
            np.array([[p.frames[v.frame].matrix() for v in views]]),
            np.array([[p.cameras[v.camera].matrix() for v in views]]),
            np.array([[p.tags[v.tag_id].matrix() for v in views]]),
            cap=np.inf,
        )[0]
        by_frame: dict[int, list[int]] = defaultdict(list)
        for view, error in zip(views, chi2, strict=True):
            if error < GATE_CHI2:
                self.used.append(view)
                by_frame[view.frame].append(len(self.used) - 1)
        self.graph.views = self.used
        for indices in by_frame.values():
            for k in indices:
                self.factors.add(frame_factor(self.graph.layout([k]), ROBUST_K))

    def readmit(self) -> None:
        """The views left out at entry, offered again against the estimate as it now stands
        (a pose that entered wrong has since been pulled right by the views that came after)."""
        used = {id(v) for v in self.used}
        left = [k for k in sorted(self.taken) if id(self.views[k]) not in used]
        views = [self.views[k] for k in left]
        self._refresh(views)
        self._add(views)

    def update(self) -> None:
        if self.factors.size() or self.values.size():
            self.isam.update(self.factors, self.values)
            self.factors, self.values = gtsam.NonlinearFactorGraph(), gtsam.Values()


def _entities(view: TagView) -> tuple[tuple[str, int], ...]:
    return ("f", view.frame), ("t", view.tag_id), ("c", view.camera)


def solve_incremental(graph: TagGraph) -> tuple[gtsam.Values, gtsam.ISAM2]:
    """The graph's solution by iSAM2, and the iSAM2 instance (for marginals); ``graph.views``
    becomes the views that entered.

    Raises:
        EstimationError: an update iSAM2 cannot solve.
    """
    feed = _Feed(graph)
    searched = {key for kind, key in graph.placed.order if kind == "c"}
    try:
        for camera in sorted(set(graph.placed.cameras) - searched):
            feed.enter("c", camera)  # mounts known before the search: there from the start
        for kind, key in graph.placed.order:
            feed.enter(kind, key)
            if kind == "f":
                feed.update()
        feed.update()
        for _ in range(READMISSIONS):
            feed.readmit()
            feed.update()
        for _ in range(SETTLING_UPDATES):  # settle the last relinearisations
            feed.isam.update()
    except RuntimeError as error:
        raise EstimationError(f"iSAM2 could not solve the 3-D graph: {first_line(error)}") from None
    return feed.isam.calculateEstimate(), feed.isam
