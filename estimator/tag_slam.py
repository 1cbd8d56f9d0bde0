"""The 3-D tag map: rig poses, tag poses and unknown camera mounts in SE(3), in one GTSAM graph
of corner reprojection factors, odometry (or a weak motion prior where there is none) and the
surveyed tags' priors, solved in batch (Levenberg-Marquardt) or incrementally (iSAM2).

The gauge: surveyed tags fix the map frame where there are any, else the home tag (the first
tag seen unless named) sits at the identity; a camera whose mount is given holds the rig's frame,
else the first camera is taken as the rig's frame (said in a note). Views whose corners stay
far from the solution (a PnP flip, a misdetection) are dropped and the graph solved again.
"""

from __future__ import annotations

import itertools
from collections import Counter, defaultdict

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.common.errors import EstimationError
from markergraph.common.notes import Note
from markergraph.estimator.corner_factor import FrameViews, frame_errors, frame_factor
from markergraph.estimator.solution import first_line, lm_params, marginals_or_note
from markergraph.estimator.tag_frames import map_framing
from markergraph.estimator.tag_init import Placed, place
from markergraph.estimator.tags3d import Camera3d, Tag3d, TagMap3d, TagScene

__all__ = ["map_tags"]

MOTION_SIGMA = (0.1, 0.1)
"""The motion prior's standard deviations at no time apart (rotation [rad], translation [m])."""
MOTION_RATE = (2.0, 2.0)
"""Their growth per second apart [rad/s, m/s]: a hand or a robot turning and moving briskly."""
ODOMETRY_SIGMA = (0.01, 0.01)
"""Odometry's standard deviations per step (rotation [rad], translation [m]) ..."""
ODOMETRY_RATE = (0.05, 0.05)
"""... plus this share of the step's own rotation and translation."""
OUTLIER_PX = 3.0
"""A view whose corners stay farther than this (RMS) from the solution, and farther than
:data:`OUTLIER_SHARE` times the median view's, is dropped."""
OUTLIER_SHARE = 4.0
FIRST_TOLERANCE = 1e-5
"""The first solve's relative error tolerance: with its outliers still in, the last steps only
trade one outlier's error for another's."""
FINAL_TOLERANCE = 1e-7


def _X(i: int) -> int:
    return gtsam.symbol("x", i)


def _T(i: int) -> int:
    return gtsam.symbol("t", i)


def _C(i: int) -> int:
    return gtsam.symbol("c", i)


def _home(scene: TagScene) -> int | None:
    if scene.known_tags:
        return None
    if scene.home_id is not None:
        if all(v.tag_id != scene.home_id for v in scene.views):
            raise EstimationError(f"home tag {scene.home_id} is never seen")
        return scene.home_id
    first = min(scene.views, key=lambda v: (v.frame, v.tag_id))
    return first.tag_id


def _mounts(scene: TagScene, notes: list[Note]) -> tuple[dict[int, gtsam.Pose3], set[int]]:
    """The mounts known before the search, and the cameras whose mount is estimated."""
    known = {i: c.T_rig_camera for i, c in enumerate(scene.cameras) if c.T_rig_camera is not None}
    estimated = {
        i for i, c in enumerate(scene.cameras) if c.T_rig_camera is None or c.sigmas is not None
    }
    if not any(c.T_rig_camera is not None and c.sigmas is None for c in scene.cameras):
        known[0] = known.get(0, gtsam.Pose3())
        estimated.discard(0)
        notes.append(
            Note(
                "rig.first_camera",
                f"no camera's mount is given: the rig's frame is {scene.cameras[0].name}'s",
                scene.cameras[0].topic,
            )
        )
    return known, estimated


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


class _Problem:
    """The graph over what the search placed."""

    def __init__(self, scene: TagScene, placed: Placed, estimated: set[int], home: int | None):
        self.scene, self.placed, self.estimated, self.home = scene, placed, estimated, home
        self.views = [
            v
            for v in scene.views
            if v.frame in placed.frames and v.tag_id in placed.tags and v.camera in placed.cameras
        ]

    def frame_views(self) -> list[tuple[list[int], FrameViews]]:
        """Each frame's views (their indices in :attr:`views`) laid out for its factor."""
        by_frame: dict[int, list[int]] = defaultdict(list)
        for k, view in enumerate(self.views):
            by_frame[view.frame].append(k)
        laid_out = []
        for frame, indices in sorted(by_frame.items()):
            views = [self.views[k] for k in indices]
            fixed = [
                np.eye(4) if v.camera in self.estimated else self.placed.cameras[v.camera].matrix()
                for v in views
            ]
            laid_out.append(
                (
                    indices,
                    FrameViews(
                        _X(frame),
                        [_T(v.tag_id) for v in views],
                        np.array([self.scene.tag_sizes[v.tag_id] for v in views]),
                        np.array([v.rays for v in views]),
                        np.array([v.sigma for v in views]),
                        np.array(fixed),
                        [_C(v.camera) if v.camera in self.estimated else None for v in views],
                    ),
                )
            )
        return laid_out

    def priors(self) -> gtsam.NonlinearFactorGraph:
        graph = gtsam.NonlinearFactorGraph()
        for known in self.scene.known_tags:
            if known.tag_id in self.placed.tags:
                graph.add(
                    gtsam.PriorFactorPose3(_T(known.tag_id), known.T_map_tag, _noise(known.sigmas))
                )
        if self.home is not None:
            graph.add(gtsam.PriorFactorPose3(_T(self.home), gtsam.Pose3(), _noise((1e-6, 1e-6))))
        for i in sorted(self.estimated & set(self.placed.cameras)):
            camera = self.scene.cameras[i]
            if camera.T_rig_camera is not None and camera.sigmas is not None:
                graph.add(gtsam.PriorFactorPose3(_C(i), camera.T_rig_camera, _noise(camera.sigmas)))
        return graph

    def steps(self) -> gtsam.NonlinearFactorGraph:
        """Odometry between consecutive placed frames, or the motion prior without it."""
        graph = gtsam.NonlinearFactorGraph()
        frames = sorted(self.placed.frames)
        odometry = self.scene.odometry
        times = self.scene.frame_times
        for a, b in itertools.pairwise(frames):
            dt_s = (int(times[b]) - int(times[a])) * 1e-9
            if odometry and odometry[a] is not None and odometry[b] is not None:
                step = odometry[a].between(odometry[b])
                graph.add(
                    gtsam.BetweenFactorPose3(_X(a), _X(b), step, _step_noise(step, dt_s, True))
                )
            else:
                step = gtsam.Pose3()
                graph.add(
                    gtsam.BetweenFactorPose3(_X(a), _X(b), step, _step_noise(step, dt_s, False))
                )
        return graph

    def values(self) -> gtsam.Values:
        values = gtsam.Values()
        for i, pose in self.placed.frames.items():
            values.insert(_X(i), pose)
        for i, pose in self.placed.tags.items():
            values.insert(_T(i), pose)
        for i in self.estimated & set(self.placed.cameras):
            values.insert(_C(i), self.placed.cameras[i])
        return values

    def graph(self) -> gtsam.NonlinearFactorGraph:
        graph = self.priors()
        graph.push_back(self.steps())
        for _, views in self.frame_views():
            graph.add(frame_factor(views))
        return graph


def _view_errors_px(problem: _Problem, values: gtsam.Values) -> NDArray[np.float64]:
    """Each view's RMS corner reprojection error [px]."""
    errors = np.empty(len(problem.views))
    for indices, views in problem.frame_views():
        residual = frame_errors(views, values)
        focal = np.array([problem.scene.cameras[problem.views[k].camera].focal_px for k in indices])
        errors[indices] = np.sqrt(np.mean(residual**2, axis=1)) * focal
    return errors


def _optimise(
    graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, tolerance: float
) -> tuple[gtsam.Values, bool]:
    params = lm_params()
    params.setRelativeErrorTol(tolerance)
    try:
        optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
        result = optimizer.optimize()
    except RuntimeError as error:
        raise EstimationError(f"the 3-D graph could not be solved: {first_line(error)}") from None
    return result, optimizer.iterations() < params.getMaxIterations()


def map_tags(scene: TagScene) -> TagMap3d:
    """The 3-D tag map of ``scene``.

    Raises:
        EstimationError: no views, a home tag never seen, or a graph that cannot be solved.
    """
    if not scene.views:
        raise EstimationError("no tag views to map")
    notes: list[Note] = []
    home = _home(scene)
    mounts, estimated = _mounts(scene, notes)
    placed = place(scene, home, mounts)
    problem = _Problem(scene, placed, estimated, home)
    values, converged = _optimise(problem.graph(), problem.values(), FIRST_TOLERANCE)
    errors = _view_errors_px(problem, values)
    limit = max(OUTLIER_PX, OUTLIER_SHARE * float(np.median(errors)))
    dropped = int(np.sum(errors > limit))
    if dropped:
        problem.views = [v for v, e in zip(problem.views, errors, strict=True) if e <= limit]
        notes.append(
            Note(
                "views.outliers",
                f"{dropped:,} tag views whose corners stayed more than "
                f"{limit:.1f} px from the map were left out and the map solved again",
                figure=dropped,
            )
        )
        values, converged = _optimise(problem.graph(), values, FINAL_TOLERANCE)
        errors = _view_errors_px(problem, values)
    graph = problem.graph()
    marginals = marginals_or_note(graph, values, notes)
    return _tag_map(scene, problem, values, marginals, errors, dropped, converged, notes)


def _tag_map(
    scene: TagScene,
    problem: _Problem,
    values: gtsam.Values,
    marginals: gtsam.Marginals | None,
    errors: NDArray[np.float64],
    dropped: int,
    converged: bool,
    notes: list[Note],
) -> TagMap3d:
    views_of = Counter(v.tag_id for v in problem.views)
    frames = sorted({v.frame for v in problem.views})
    rig_poses = [values.atPose3(_X(i)) for i in frames]
    G, up, framing_notes = map_framing(scene, problem.placed, values, frames, problem.home)
    notes += framing_notes

    def covariance(key: int) -> NDArray[np.float64] | None:
        return None if marginals is None else np.asarray(marginals.marginalCovariance(key))

    known = {k.tag_id for k in scene.known_tags}
    tags = {
        i: Tag3d(
            i,
            G.compose(values.atPose3(_T(i))),
            covariance(_T(i)),
            views_of[i],
            scene.tag_sizes[i],
            i in known,
        )
        for i in sorted(views_of)
    }
    views_by_camera = Counter(v.camera for v in problem.views)
    cameras = {}
    for i, camera in enumerate(scene.cameras):
        if i not in problem.placed.cameras:
            continue
        if i in problem.estimated:
            mount, cov = values.atPose3(_C(i)), covariance(_C(i))
        else:
            mount, cov = problem.placed.cameras[i], None
        cameras[camera.name] = Camera3d(
            camera.name, camera.topic, mount, cov, i in problem.estimated, views_by_camera[i]
        )
    notes += _left_out_notes(scene, problem, frames)
    return TagMap3d(
        tags,
        scene.frame_times[frames],
        [G.compose(p) for p in rig_poses],
        cameras,
        problem.home,
        up,
        len(scene.frame_times) - len(frames),
        len(problem.views),
        dropped,
        float(np.sqrt(np.mean(errors**2))) if errors.size else 0.0,
        converged,
        notes,
    )


def _left_out_notes(scene: TagScene, problem: _Problem, frames: list[int]) -> list[Note]:
    notes = []
    seen = {v.tag_id for v in scene.views}
    unplaced = sorted(seen - set(problem.placed.tags))
    if unplaced:
        shown = ", ".join(map(str, unplaced[:20])) + (" ..." if len(unplaced) > 20 else "")
        notes.append(
            Note(
                "tags.unplaced",
                f"{len(unplaced)} tags seen share no view chain with the "
                f"map and were left out: {shown}",
                figure=len(unplaced),
            )
        )
    for i, camera in enumerate(scene.cameras):
        if i not in problem.placed.cameras and any(v.camera == i for v in scene.views):
            notes.append(
                Note(
                    "camera.unplaced",
                    f"{camera.name}: its mount could not be estimated "
                    "(it never sees a mapped tag in a frame the rig's other cameras "
                    "place); its views were left out",
                    camera.topic,
                )
            )
    skipped = len(scene.frame_times) - len(frames)
    if skipped:
        notes.append(
            Note(
                "frames.unplaced",
                f"{skipped:,} of {len(scene.frame_times):,} rig frames "
                "saw no mapped tag and were skipped",
                figure=skipped,
            )
        )
    return notes
