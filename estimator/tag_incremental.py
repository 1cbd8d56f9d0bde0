"""The 3-D tag graph solved incrementally (iSAM2), in the order the first guess placed its
poses: each rig frame, tag and mount enters with the factors that tie it to what is already
there, so that every update is determined; views whose tag or mount comes later enter with it.
"""

from __future__ import annotations

from collections import defaultdict

import gtsam

from markergraph.common.errors import EstimationError
from markergraph.estimator.corner_factor import frame_factor
from markergraph.estimator.solution import first_line
from markergraph.estimator.tag_graph import TagGraph, camera_key, rig_key, tag_key

__all__ = ["solve_incremental"]

RELINEARIZE_THRESHOLD = 0.01
"""iSAM2 relinearises a pose whose update exceeds this (rotation [rad], translation [m])."""


class _Feed:
    def __init__(self, graph: TagGraph) -> None:
        self.graph = graph
        self.isam = gtsam.ISAM2(self._params())
        self.present: set[tuple[str, int]] = set()
        self.factors = gtsam.NonlinearFactorGraph()
        self.values = gtsam.Values()
        self.waiting: dict[tuple[str, int], list[int]] = defaultdict(list)
        for k, view in enumerate(graph.views):
            for entity in (("f", view.frame), ("t", view.tag_id), ("c", view.camera)):
                self.waiting[entity].append(k)
        self.added: set[int] = set()

    @staticmethod
    def _params() -> gtsam.ISAM2Params:
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(RELINEARIZE_THRESHOLD)
        params.setFactorization("QR")  # a far tag seen once is poorly conditioned for Cholesky
        return params

    def enter(self, kind: str, key: int) -> None:
        graph, placed = self.graph, self.graph.placed
        self.present.add((kind, key))
        if kind == "f":
            self.values.insert(rig_key(key), placed.frames[key])
            for neighbour in (key - 1, key + 1):
                if ("f", neighbour) in self.present:
                    self.factors.add(graph.step(min(key, neighbour), max(key, neighbour)))
        elif kind == "t":
            self.values.insert(tag_key(key), placed.tags[key])
            prior = graph.tag_prior(key)
            if prior is not None:
                self.factors.add(prior)
        elif key in graph.estimated:
            self.values.insert(camera_key(key), placed.cameras[key])
            prior = graph.camera_prior(key)
            if prior is not None:
                self.factors.add(prior)
        self._views(kind, key)

    def _views(self, kind: str, key: int) -> None:
        """The views that this entity completes, one factor a frame."""
        by_frame: dict[int, list[int]] = defaultdict(list)
        for k in self.waiting.pop((kind, key), []):
            view = self.graph.views[k]
            entities = (("f", view.frame), ("t", view.tag_id), ("c", view.camera))
            if k not in self.added and all(e in self.present for e in entities):
                by_frame[view.frame].append(k)
                self.added.add(k)
        for indices in by_frame.values():
            self.factors.add(frame_factor(self.graph.layout(indices)))

    def update(self) -> None:
        if self.factors.size() or self.values.size():
            self.isam.update(self.factors, self.values)
            self.factors, self.values = gtsam.NonlinearFactorGraph(), gtsam.Values()


def solve_incremental(graph: TagGraph) -> tuple[gtsam.Values, gtsam.ISAM2]:
    """The graph's solution by iSAM2, and the iSAM2 instance (for marginals).

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
        feed.isam.update()  # one more pass to settle the last relinearisations
    except RuntimeError as error:
        raise EstimationError(f"iSAM2 could not solve the 3-D graph: {first_line(error)}") from None
    return feed.isam.calculateEstimate(), feed.isam
