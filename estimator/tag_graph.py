"""The 3-D tag map's factor graph over what the first guess placed: one corner factor a rig
frame (:mod:`.corner_factor`), odometry between consecutive frames (or a weak motion prior where
there is none), the surveyed tags' priors, the home tag's and the seeded mounts'.

Keys: ``x<frame>`` the rig's poses, ``t<id>`` the tags', ``c<camera>`` the estimated mounts.
"""

from __future__ import annotations

import itertools
from collections import defaultdict

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.estimator.corner_factor import FrameViews, frame_factor
from markergraph.estimator.tag_init import Placed
from markergraph.estimator.tag_solver import CornerViews, corner_residuals
from markergraph.estimator.tags3d import TagScene

__all__ = ["TagGraph", "camera_key", "rig_key", "tag_key", "view_errors_px"]

MOTION_SIGMA = (0.1, 0.1)
"""The motion prior's standard deviations at no time apart (rotation [rad], translation [m])."""
MOTION_RATE = (2.0, 2.0)
"""Their growth per second apart [rad/s, m/s]: a hand or a robot turning and moving briskly."""
ODOMETRY_SIGMA = (0.01, 0.01)
"""Odometry's standard deviations per step (rotation [rad], translation [m]) ..."""
ODOMETRY_RATE = (0.05, 0.05)
"""... plus this share of the step's own rotation and translation."""


def rig_key(i: int) -> int:
    return gtsam.symbol("x", i)


def tag_key(i: int) -> int:
    return gtsam.symbol("t", i)


def camera_key(i: int) -> int:
    return gtsam.symbol("c", i)


def _noise(sigmas: tuple[float, float] | NDArray[np.float64]) -> gtsam.noiseModel.Base:
    values = np.asarray(sigmas, dtype=np.float64)
    if values.size == 2:
        values = np.repeat(values, 3)
    return gtsam.noiseModel.Diagonal.Sigmas(values)


def _step_noise(step: gtsam.Pose3, dt_s: float, odometry: bool) -> gtsam.noiseModel.Base:
    if odometry:
        angle = float(np.linalg.norm(gtsam.Rot3.Logmap(step.rotation())))
        distance = float(np.linalg.norm(step.translation()))
        return _noise(
            (
                ODOMETRY_SIGMA[0] + ODOMETRY_RATE[0] * angle,
                ODOMETRY_SIGMA[1] + ODOMETRY_RATE[1] * distance,
            )
        )
    return _noise(
        (MOTION_SIGMA[0] + MOTION_RATE[0] * dt_s, MOTION_SIGMA[1] + MOTION_RATE[1] * dt_s)
    )


class TagGraph:
    """The graph over what the first guess placed: its views, factors and first values."""

    def __init__(self, scene: TagScene, placed: Placed, estimated: set[int], home: int | None):
        self.scene, self.placed, self.estimated, self.home = scene, placed, estimated, home
        self.views = [
            v
            for v in scene.views
            if v.frame in placed.frames and v.tag_id in placed.tags and v.camera in placed.cameras
        ]

    def layout(self, indices: list[int]) -> FrameViews:
        """Views of one frame (their indices in :attr:`views`) laid out for its factor."""
        views = [self.views[k] for k in indices]
        estimated = [v.camera in self.estimated for v in views]
        return FrameViews(
            rig_key(views[0].frame),
            [tag_key(v.tag_id) for v in views],
            np.array([self.scene.tag_sizes[v.tag_id] for v in views]),
            np.array([v.rays for v in views]),
            np.array([v.sigma for v in views]),
            np.array([np.eye(4) if e else self.placed.cameras[v.camera].matrix()
                      for v, e in zip(views, estimated, strict=True)]),
            [camera_key(v.camera) if e else None for v, e in zip(views, estimated, strict=True)],
        )  # fmt: skip

    def frame_views(self) -> list[tuple[list[int], FrameViews]]:
        """Each frame's views (their indices in :attr:`views`) laid out for its factor."""
        by_frame: dict[int, list[int]] = defaultdict(list)
        for k, view in enumerate(self.views):
            by_frame[view.frame].append(k)
        return [(indices, self.layout(indices)) for _, indices in sorted(by_frame.items())]

    def tag_prior(self, tag_id: int) -> gtsam.PriorFactorPose3 | None:
        """A surveyed tag's prior, or the home tag's at the identity."""
        for known in self.scene.known_tags:
            if known.tag_id == tag_id:
                return gtsam.PriorFactorPose3(
                    tag_key(tag_id), known.T_map_tag, _noise(known.sigmas)
                )
        if tag_id == self.home:
            return gtsam.PriorFactorPose3(tag_key(tag_id), gtsam.Pose3(), _noise((1e-6, 1e-6)))
        return None

    def camera_prior(self, camera: int) -> gtsam.PriorFactorPose3 | None:
        """A seeded mount's prior."""
        given = self.scene.cameras[camera]
        if camera not in self.estimated or given.T_rig_camera is None or given.sigmas is None:
            return None
        return gtsam.PriorFactorPose3(camera_key(camera), given.T_rig_camera, _noise(given.sigmas))

    def step(self, a: int, b: int) -> gtsam.BetweenFactorPose3:
        """Odometry from frame a to frame b, or the motion prior where there is none."""
        odometry = self.scene.odometry
        dt_s = (int(self.scene.frame_times[b]) - int(self.scene.frame_times[a])) * 1e-9
        start, end = (odometry[a], odometry[b]) if odometry else (None, None)
        measured = start is not None and end is not None
        step = start.between(end) if start is not None and end is not None else gtsam.Pose3()
        noise = _step_noise(step, dt_s, measured)
        return gtsam.BetweenFactorPose3(rig_key(a), rig_key(b), step, noise)

    def warm(self, values: gtsam.Values) -> None:
        """Start the next solve from ``values`` (the poses a solve gave)."""
        placed = self.placed
        placed.frames = {i: values.atPose3(rig_key(i)) for i in placed.frames}
        placed.tags = {i: values.atPose3(tag_key(i)) for i in placed.tags}
        for i in self.estimated & set(placed.cameras):
            placed.cameras[i] = values.atPose3(camera_key(i))

    def values(self) -> gtsam.Values:
        values = gtsam.Values()
        for i, pose in self.placed.frames.items():
            values.insert(rig_key(i), pose)
        for i, pose in self.placed.tags.items():
            values.insert(tag_key(i), pose)
        for i in self.estimated & set(self.placed.cameras):
            values.insert(camera_key(i), self.placed.cameras[i])
        return values

    def builtin_graph(self) -> gtsam.NonlinearFactorGraph:
        """GTSAM's built-in factors: the priors and the steps between frames."""
        graph = gtsam.NonlinearFactorGraph()
        for tag_id in self.placed.tags:
            prior = self.tag_prior(tag_id)
            if prior is not None:
                graph.add(prior)
        for camera in self.placed.cameras:
            camera_prior = self.camera_prior(camera)
            if camera_prior is not None:
                graph.add(camera_prior)
        for a, b in itertools.pairwise(sorted(self.placed.frames)):
            graph.add(self.step(a, b))
        return graph

    def corner_views(self, robust_k: float | None = None) -> CornerViews:
        """Every view's corners laid out for the vectorised solve (:mod:`.tag_solver`)."""
        eye = np.eye(4)
        return CornerViews.of(
            [
                (
                    rig_key(v.frame),
                    tag_key(v.tag_id),
                    camera_key(v.camera) if v.camera in self.estimated else None,
                    eye if v.camera in self.estimated else self.placed.cameras[v.camera].matrix(),
                    self.scene.tag_sizes[v.tag_id],
                    np.asarray(v.rays),
                    np.asarray(v.sigma),
                )
                for v in self.views
            ],
            robust_k,
        )

    def graph(self, robust_k: float | None = None) -> gtsam.NonlinearFactorGraph:
        """The whole graph; with ``robust_k``, one factor a view under a Cauchy kernel (a first
        solve that outliers cannot drag; a frame's factor would share one weight among its
        views), else one factor a frame."""
        graph = self.builtin_graph()
        if robust_k is not None:
            for k in range(len(self.views)):
                graph.add(frame_factor(self.layout([k]), robust_k))
            return graph
        for _, views in self.frame_views():
            graph.add(frame_factor(views))
        return graph


def view_errors_px(problem: TagGraph, values: gtsam.Values) -> NDArray[np.float64]:
    """Each view's RMS corner reprojection error [px]."""
    if not problem.views:
        return np.empty(0)
    residual = corner_residuals(problem.corner_views(), values)
    per_px = np.array([v.ray_per_px for v in problem.views]).reshape(-1, 8)
    return np.sqrt(np.mean((residual / per_px) ** 2, axis=1))
