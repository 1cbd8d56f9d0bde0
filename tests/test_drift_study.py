"""The drift study's expected shape on seeded fast-mode runs, and the EKF's consistency."""

from __future__ import annotations

import numpy as np
import pytest

from markergraph.datasets import WheelErrors, scenario, simulate_fast
from markergraph.datasets.study import drift_study, summarise
from markergraph.estimator import (
    Form,
    Method,
    OdometryNoise,
    build_frames,
    chi2_interval,
    estimate_frames,
    nees,
)


@pytest.mark.slow
def test_optimised_maps_beat_the_papers_closed_form_on_the_corridor_loop() -> None:
    """Marker RMSE: SLAM at least 3x better than the closed form; the marker graph between."""
    methods = [
        (Method.CLOSED_FORM, Form.SIGNED),
        (Method.MARKER_GRAPH, Form.SIGNED),
        (Method.SLAM, Form.SIGNED),
    ]
    summary = summarise(drift_study(["corridor-loop"], range(3), methods))
    closed = summary[("corridor-loop", "closed-form/signed")]["marker_rmse_m"]
    graph = summary[("corridor-loop", "marker-graph")]["marker_rmse_m"]
    slam = summary[("corridor-loop", "slam")]["marker_rmse_m"]
    assert closed > 3 * slam
    assert closed > graph > slam


@pytest.mark.slow
def test_ekf_is_consistent_when_its_odometry_model_is_true() -> None:
    """Average NEES over seeded runs lies in its 95% chi-square band when the simulated wheel
    errors are exactly the random walk the filter assumes (no systematic errors)."""
    wheel = WheelErrors(0.0, 0.0, 0.0, distance_noise=0.005, yaw_noise=0.004)
    model = OdometryNoise(per_m=0.005, yaw_per_m=0.004, yaw_per_rad=0.004)
    world, route = scenario("office")
    seeds = range(6)
    run_means = []
    for seed in seeds:
        run = simulate_fast(world, route, seed, wheel=wheel)
        frames = build_frames(run.observations, run.odometry, 0, odometry_noise=model)
        result = estimate_frames(frames, Method.EKF, run.mount.T_base_camera)
        true_by_stamp = dict(zip(run.frame_t_ns.tolist(), run.true_trajectory(), strict=True))
        truth = np.array([true_by_stamp[int(t)] for t in result.trajectory.t_ns])
        run_means.append(nees(result.trajectory.poses, result.trajectory_covariance, truth).mean())
        assert 1.5 < result.nis.mean() < 4.5  # 3 dof innovations, averaged over ~2000 updates
    low, high = (bound / len(seeds) for bound in chi2_interval(3 * len(seeds)))
    assert low < np.mean(run_means) < high
