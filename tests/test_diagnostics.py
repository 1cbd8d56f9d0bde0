"""report.json's diagnostics name what the robust kernel gave up on: an observation planted 2 m
off is listed with its stamp, marker and residual, and its marker's residuals stand out."""

from __future__ import annotations

import dataclasses

import pytest

from markergraph.datasets import scenario, simulate_fast
from markergraph.diagnostics import diagnostics
from markergraph.estimator import Method, Robust, build_frames, estimate_frames

PLANTED = 150  # the observation that lies


@pytest.fixture(scope="module")
def planted():
    world, route = scenario("paper-room")
    run = simulate_fast(world, route, seed=4, duration_s=60.0)
    observations = list(run.observations)
    liar = dataclasses.replace(observations[PLANTED], range_m=observations[PLANTED].range_m + 2.0)
    observations[PLANTED] = liar
    frames = build_frames(observations, run.odometry, 0, odometry_noise=run.odometry_noise)
    return liar, frames, run.mount.T_base_camera


@pytest.mark.parametrize("method", [Method.SLAM, Method.ISAM2])
def test_the_planted_outlier_is_listed_with_its_stamp_and_marker(planted, method) -> None:
    liar, frames, T_base_camera = planted
    estimate = estimate_frames(frames, method, T_base_camera, robust=Robust.HUBER)
    report = diagnostics(estimate, frames)
    listed = [d for d in report["downweighted"] if d["kind"] == "observation"]
    assert {"t_ns": liar.t_ns, "marker_ids": [liar.marker_id]} in [
        {"t_ns": d["t_ns"], "marker_ids": d["marker_ids"]} for d in listed
    ]
    # 2 m against a range sigma of centimetres: tens of sigmas, the largest of all.
    mine = next(d for d in listed if d["t_ns"] == liar.t_ns)
    assert mine["whitened_error"] > 20
    assert mine["whitened_error"] == max(d["whitened_error"] for d in report["downweighted"])
    assert len(listed) <= 3  # honest observations are not swept up with it
    markers = report["markers"]
    assert markers[str(liar.marker_id)]["whitened_max"] == pytest.approx(mine["whitened_error"])
    assert markers[str(liar.marker_id)]["downweighted"] >= 1
    others = [m["whitened_median"] for i, m in markers.items() if i != str(liar.marker_id)]
    assert max(others) < 3


def test_the_closed_form_says_it_has_no_residuals_and_the_ekf_has_innovations(planted) -> None:
    liar, frames, T_base_camera = planted
    closed = diagnostics(estimate_frames(frames, Method.CLOSED_FORM, T_base_camera), frames)
    assert closed["residuals"] == "none" and "markers" not in closed
    ekf = diagnostics(estimate_frames(frames, Method.EKF, T_base_camera), frames)
    # No robust kernel: nothing down-weighted, but the lie is the marker's largest innovation.
    assert ekf["downweighted"] == []
    assert ekf["markers"][str(liar.marker_id)]["whitened_max"] > 20
