"""The 3-D map's fast batch solve (every corner linearised in one numpy call, GTSAM's step rules)
against the reference solve through GTSAM's own optimiser over Python factors: the same poses
to within 1e-6 m and 1e-6 rad, the same views kept, the same covariances, on simulated rigs
(unknown mounts, odometry and surveyed tags) and on TagSLAM's recordings. No timings here:
tests/benchmarks/bench_rig3d.py prints them."""

from __future__ import annotations

from dataclasses import replace

import gtsam
import numpy as np
import pytest
from tagslam_helpers import DATA, recorded_scene

from markergraph.datasets.scene3d import detections, make_scene3d, odometry3d, tag_scene
from markergraph.estimator.tag_slam import Solver, map_tags
from markergraph.estimator.tag_solver import CornerViews, LmSettings, solve_lm
from markergraph.estimator.tags3d import TagMap3d, TagScene

SAME_M = 1e-6
"""The fast and reference solves' largest difference in any position [m] ..."""
SAME_RAD = 1e-6
"""... and in any rotation [rad]: the issue's bound (rounding alone leaves about 1e-13)."""
SAME_COVARIANCE = 1e-6
"""Covariances agree to this share of their largest entry."""


def _largest_differences(a: TagMap3d, b: TagMap3d) -> tuple[float, float]:
    """The largest position [m] and rotation [rad] differences over every tag, rig pose and
    estimated mount of two maps of one scene."""
    assert set(a.tags) == set(b.tags) and len(a.rig_poses) == len(b.rig_poses)
    pairs = [(a.tags[i].T_map_tag, b.tags[i].T_map_tag) for i in a.tags]
    pairs += list(zip(a.rig_poses, b.rig_poses, strict=True))
    pairs += [(a.cameras[n].T_rig_camera, b.cameras[n].T_rig_camera) for n in a.cameras]
    position = max(float(np.linalg.norm(p.translation() - q.translation())) for p, q in pairs)
    rotation = max(
        float(np.linalg.norm(gtsam.Rot3.Logmap(p.rotation().between(q.rotation()))))
        for p, q in pairs
    )
    return position, rotation


def _assert_same(scene: TagScene) -> TagMap3d:
    """Map ``scene`` both ways and check they agree; the fast map."""
    fast = map_tags(scene)
    reference = map_tags(scene, solver=Solver.GTSAM)
    position, rotation = _largest_differences(fast, reference)
    assert position < SAME_M and rotation < SAME_RAD
    assert fast.views_used == reference.views_used
    assert fast.views_dropped == reference.views_dropped
    assert fast.converged == reference.converged
    for i, tag in reference.tags.items():
        if tag.covariance is None:
            assert fast.tags[i].covariance is None
            continue
        ours = fast.tags[i].covariance
        assert ours is not None
        assert np.abs(ours - tag.covariance).max() < SAME_COVARIANCE * np.abs(tag.covariance).max()
    return fast


def test_fast_solve_matches_gtsam_on_unknown_mounts():
    """Three cameras, two mounts estimated from the tags: the same map both ways."""
    truth = make_scene3d(0, cameras=3, tag_size_m=0.3, frames=50)
    scene = tag_scene(truth, detections(truth, 0, 0.5), pixel_noise_px=0.5, mounts_for=["cam0"])
    fast = _assert_same(scene)
    assert sum(c.estimated for c in fast.cameras.values()) == 2


def test_fast_solve_matches_gtsam_with_odometry_and_surveyed_tags():
    """Odometry between frames and three surveyed wall tags (built-in GTSAM factors beside the
    corners): the same map both ways."""
    truth = make_scene3d(1, cameras=1, tag_size_m=0.3, frames=80)
    walls = [i for i, s in sorted(truth.surfaces.items()) if s == "wall"][:3]
    scene = tag_scene(
        truth,
        detections(truth, 1, 0.5),
        pixel_noise_px=0.5,
        odometry=odometry3d(truth, 1),
        surveyed=walls,
        survey_sigmas=(0.001, 0.001),
    )
    _assert_same(scene)


def test_fast_solve_keeps_the_reference_solves_outliers():
    """A tenth of the views' corners shifted by 20 px: both solves leave out the same views
    after the robust first solve and agree on the rest."""
    truth = make_scene3d(2, cameras=1, tag_size_m=0.3, frames=80)
    scene = tag_scene(truth, detections(truth, 2, 0.5), pixel_noise_px=0.5)
    rng = np.random.default_rng(2)
    bad = rng.choice(len(scene.views), len(scene.views) // 10, replace=False)
    views = list(scene.views)
    for k in bad:
        view = views[k]
        shift = 20.0 * view.ray_per_px.reshape(4, 2) * rng.choice([-1.0, 1.0], size=(4, 2))
        views[k] = replace(view, rays=view.rays + shift)
    damaged = replace(scene, views=views)
    fast = _assert_same(damaged)
    assert fast.views_dropped > 0


def test_one_step_rule_matches_gtsam_on_a_robust_graph():
    """The step rules alone: a graph of one view per tag under a Cauchy kernel from a poor
    start, solved by GTSAM's optimiser over Python factors and by the vectorised loop, lands
    on the same poses after the same number of iterations."""
    from markergraph.estimator.corner_factor import FrameViews, frame_factor
    from markergraph.estimator.tags3d import tag_corners

    rng = np.random.default_rng(4)
    size = 0.2
    rig = gtsam.Pose3()
    values = gtsam.Values()
    values.insert(gtsam.symbol("x", 0), rig)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(
        gtsam.PriorFactorPose3(gtsam.symbol("x", 0), rig, gtsam.noiseModel.Isotropic.Sigma(6, 1e-3))
    )
    rows = []
    for i in range(6):
        T = gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(0, 0.3, 3)), np.array([i - 2.5, 0.3, 3.0]))
        p = np.array([T.transformFrom(c) for c in tag_corners(size)])
        rays = p[:, :2] / p[:, 2:] + rng.normal(0, 0.002, (4, 2))
        if i == 0:
            rays += 0.05  # an outlier the kernel holds down
        sigma = np.full(8, 0.001)
        key = gtsam.symbol("t", i)
        values.insert(key, T.retract(rng.normal(0, 0.05, 6)))
        layout = FrameViews(
            gtsam.symbol("x", 0), [key], np.array([size]), rays[None], sigma[None],
            np.eye(4)[None], [None],
        )  # fmt: skip
        graph.add(frame_factor(layout, 3.0))
        rows.append((gtsam.symbol("x", 0), key, None, np.eye(4), size, rays, sigma))
    builtin = gtsam.NonlinearFactorGraph()
    builtin.add(graph.at(0))
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-7)
    params.setAbsoluteErrorTol(1e-12)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    reference = optimizer.optimize()
    settings = LmSettings(1e-7, 1e-12, 100)
    ours, iterations = solve_lm(CornerViews.of(rows, 3.0), builtin, values, settings)
    assert iterations == optimizer.iterations()
    assert abs(graph.error(ours) - graph.error(reference)) < 1e-9 * graph.error(reference)
    for i in range(6):
        a, b = ours.atPose3(gtsam.symbol("t", i)), reference.atPose3(gtsam.symbol("t", i))
        assert np.linalg.norm(a.translation() - b.translation()) < SAME_M
        assert np.linalg.norm(gtsam.Rot3.Logmap(a.rotation().between(b.rotation()))) < SAME_RAD


@pytest.mark.skipif(not DATA.is_dir(), reason="../shared/data/tagslam-test is absent")
@pytest.mark.parametrize("test", ["test_1", "test_7"])
def test_fast_solve_matches_gtsam_on_tagslam_recordings(test, tmp_path):
    """TagSLAM's test 1 (one fisheye) and test 7 (four fisheyes, three mounts estimated): the
    same map both ways."""
    scene = recorded_scene(DATA / test, tmp_path)
    _assert_same(scene)
