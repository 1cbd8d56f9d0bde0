"""Verdicts: each check's evidence against exact algebra or the simulator's truth, and each
reason raised by the fault it names and by nothing on a clean run."""

from __future__ import annotations

import dataclasses
import json
import math
from collections import Counter
from typing import Any

import gtsam
import numpy as np
import pytest
from scipy import stats

from markergraph.cli import main
from markergraph.cli._map import EXIT_NOT_OK
from markergraph.datasets import scenario, simulate_fast
from markergraph.datasets.rewrite import rewrite_log
from markergraph.estimator import (
    Estimate,
    MarkerEstimate,
    Method,
    Robust,
    Trajectory,
    estimate,
)
from markergraph.estimator.evidence import (
    chi2_upper,
    marker_disagreement,
    position_covariance,
    residual_fit,
)
from markergraph.estimator.odometry_scale import SCALES
from markergraph.estimator.timing import DELAYS_S
from markergraph.frontend import Extraction
from markergraph.frontend.camera import CameraMount
from markergraph.frontend.topics import TopicChoice
from markergraph.verdicts import Verdict, judge_run

SEED = 7
METHODS = (Method.SLAM, Method.ISAM2, Method.EKF, Method.MARKER_GRAPH, Method.CLOSED_FORM)


@pytest.fixture(scope="module")
def clean():
    """A simulated paper room whose noise is what the estimators assume: every method's
    estimate, and the run's observations as an extraction."""
    world, route = scenario("paper-room")
    run = simulate_fast(world, route, SEED, duration_s=90.0)
    estimates = {
        m: estimate(run.observations, run.odometry, m, T_base_camera=run.mount.T_base_camera,
                    odometry_noise=run.odometry_noise, home_id=world.home_id)
        for m in METHODS
    }  # fmt: skip
    extraction = Extraction(
        run.observations,
        Trajectory.from_samples(run.odometry),
        None,
        CameraMount(),
        TopicChoice(None, None, None, "/odom", None),
        frames=len(run.frame_t_ns),
    )
    return run, estimates, extraction


def judged(estimates, extraction, **kwargs):
    run_judgement, per_method = judge_run(list(estimates.values()), extraction, **kwargs)
    return run_judgement, per_method


def checks(judgement) -> set[str]:
    return {reason.check for reason in judgement.reasons}


def test_chi2_upper_matches_scipy() -> None:
    """Wilson-Hilferty's 99.9 % quantile is within 1 % of the exact one at 10 dof and 0.2 %
    from 48 up."""
    for dof, tolerance in ((10, 1e-2), (48, 2e-3), (300, 2e-3), (1296, 2e-3), (20_000, 2e-3)):
        exact = stats.chi2.ppf(0.999, dof)
        assert chi2_upper(dof) == pytest.approx(exact, rel=tolerance)


def test_disagreement_is_the_mahalanobis_length_under_the_summed_covariances() -> None:
    """Exact algebra: a marker 0.3 m apart along x, each estimate's position sigma 0.1 m
    along its own axes (one turned 90 degrees), is 0.3 / sqrt(0.02) apart."""
    cov_a = np.diag([0.01, 0.04, 0.001])  # its x is the map's x
    cov_b = np.diag([0.04, 0.01, 0.001])  # turned 90 deg: its y is the map's x
    a = _estimate({1: (gtsam.Pose2(1.0, 2.0, 0.0), cov_a)})
    b = _estimate({1: (gtsam.Pose2(1.3, 2.0, math.pi / 2), cov_b)})
    distance, d2 = marker_disagreement(a, b)[1]
    assert distance == pytest.approx(0.3, abs=1e-12)
    np.testing.assert_allclose(position_covariance(math.pi / 2, cov_b), np.diag([0.01, 0.04]),
                               atol=1e-15)  # fmt: skip
    assert d2 == pytest.approx(0.09 / 0.02, rel=1e-12)


@pytest.mark.slow
def test_honest_noise_gives_residuals_inside_their_chi_square_range(clean) -> None:
    """With the simulator's noise equal to the model's, SLAM's chi-square per degree of
    freedom lies within its 99.9 % range (and far below the suspect line)."""
    _, estimates, _ = clean
    fit = residual_fit(estimates[Method.SLAM])
    assert fit is not None and fit.dof > 500
    low, high = stats.chi2.ppf([0.0005, 0.9995], fit.dof) / fit.dof
    # The odometry steps between keyframes are nearly but not exactly linear: allow 20 %.
    assert 0.8 * low < fit.ratio < 1.2 * high


def test_clean_run_every_method_ok(clean) -> None:
    """On a clean run no check fires: every method's verdict is ok (no crying wolf)."""
    _, estimates, extraction = clean
    run_judgement, per_method = judged(estimates, extraction)
    assert {m: j.verdict for m, j in per_method.items()} == dict.fromkeys(METHODS, Verdict.OK), [
        r.text for j in per_method.values() for r in j.reasons
    ]
    assert run_judgement.verdict is Verdict.OK


def test_residuals_flag_odometry_that_disagrees_with_the_observations(clean) -> None:
    """Odometry read 20 % long against the same observations: SLAM's residuals exceed their
    range (2.0 times, against 0.9 with the true odometry) and say so with the figure."""
    run, _, extraction = clean
    long_odometry = [
        dataclasses.replace(s, x=1.2 * s.x, y=1.2 * s.y) for s in run.odometry
    ]  # the route starts at the origin: scaling positions scales every step
    slam = estimate(run.observations, long_odometry, Method.SLAM,
                    T_base_camera=run.mount.T_base_camera, odometry_noise=run.odometry_noise,
                    home_id=run.world.home_id)  # fmt: skip
    _, per_method = judged({Method.SLAM: slam}, extraction)
    reasons = [r for r in per_method[Method.SLAM].reasons if r.check == "residuals"]
    assert per_method[Method.SLAM].verdict is Verdict.SUSPECT and reasons
    assert reasons[0].figure > 1.8 and "times the size its noise model allows" in reasons[0].text


def test_one_markers_biased_observations_are_named_by_its_residuals(clean) -> None:
    """Every range to one marker read twice as long (its size given as twice what is printed):
    its observations stand out from the others' and the reason names it; the whole solution's
    residuals and the EKF's innovations exceed their chi-square too."""
    run, _, extraction = clean
    counts = Counter(o.marker_id for o in run.observations)
    biased_id = max(counts, key=counts.__getitem__)
    biased = [
        dataclasses.replace(o, range_m=2.0 * o.range_m) if o.marker_id == biased_id else o
        for o in run.observations
    ]
    found = {
        m: estimate(biased, run.odometry, m, T_base_camera=run.mount.T_base_camera,
                    odometry_noise=run.odometry_noise, home_id=run.world.home_id)
        for m in (Method.SLAM, Method.EKF)
    }  # fmt: skip
    _, per_method = judged(found, extraction)
    texts = [r.text for r in per_method[Method.SLAM].reasons if r.check == "residuals"]
    assert any(t.startswith("its residuals are") for t in texts), texts
    assert any(f"the observations of marker {biased_id} disagree" in t for t in texts), texts
    ekf = [r for r in per_method[Method.EKF].reasons if r.check == "residuals"]
    assert any("innovations" in r.text and r.figure > 1.5 for r in ekf), ekf


def test_robust_kernel_overruling_many_factors_is_a_reason(clean) -> None:
    """A fifth of the observations replaced by garbage ranges: the Huber kernel overrules
    most of them, and the share is the reason's figure."""
    run, _, extraction = clean
    rng = np.random.default_rng(SEED)
    garbage = [
        dataclasses.replace(o, range_m=float(rng.uniform(0.5, 6.0))) if rng.random() < 0.2 else o
        for o in run.observations
    ]
    slam = estimate(garbage, run.odometry, Method.SLAM, T_base_camera=run.mount.T_base_camera,
                    odometry_noise=run.odometry_noise, home_id=run.world.home_id,
                    robust=Robust.HUBER)  # fmt: skip
    _, per_method = judged({Method.SLAM: slam}, extraction)
    overruled = [r for r in per_method[Method.SLAM].reasons if "overruled" in r.text]
    assert overruled and 10.0 < overruled[0].figure <= 20.0


def test_an_optimiser_that_stopped_and_depth_that_misses_are_reasons(clean) -> None:
    """Not converged: suspect, saying so. Depth found on no marker in over half the tries:
    suspect, with the share."""
    _, estimates, extraction = clean
    stopped = dataclasses.replace(estimates[Method.SLAM], converged=False)
    _, per_method = judged({Method.SLAM: stopped}, extraction)
    assert checks(per_method[Method.SLAM]) == {"converged"}
    missing = dataclasses.replace(extraction, depth_tries=200, depth_misses=150)
    _, per_method = judged({Method.SLAM: estimates[Method.SLAM]}, missing)
    reason = next(r for r in per_method[Method.SLAM].reasons if r.check == "depth")
    assert reason.figure == pytest.approx(75.0)


def test_a_method_apart_from_the_others_is_named(clean) -> None:
    """One marker of the marker graph moved 2 m: the marker graph alone is suspect, naming
    that marker and the distance; the methods that agree stay ok."""
    _, estimates, extraction = clean
    moved = dict(estimates)
    graph = estimates[Method.MARKER_GRAPH]
    marker_id = max(graph.markers)
    markers = dict(graph.markers)
    T = markers[marker_id].T_map_marker
    markers[marker_id] = dataclasses.replace(
        markers[marker_id], T_map_marker=gtsam.Pose2(T.x() + 2.0, T.y(), T.theta())
    )
    moved[Method.MARKER_GRAPH] = dataclasses.replace(graph, markers=markers)
    _, per_method = judged(moved, extraction)
    assert per_method[Method.MARKER_GRAPH].verdict is Verdict.SUSPECT
    reason = next(r for r in per_method[Method.MARKER_GRAPH].reasons if r.check == "disagreement")
    assert f"marker {marker_id}" in reason.text and reason.figure == pytest.approx(2.0, abs=0.2)
    for method in (Method.SLAM, Method.ISAM2, Method.EKF):
        assert "disagreement" not in checks(per_method[method])


def test_markers_turned_round_face_away_from_the_path(clean) -> None:
    """Every marker's yaw turned by 180 degrees (the path kept): the robot saw each from behind
    its face, and the map fails; one marker turned: suspect, naming it."""
    _, estimates, extraction = clean
    slam = estimates[Method.SLAM]

    def turned(ids) -> Estimate:
        markers = {
            i: dataclasses.replace(m, T_map_marker=gtsam.Pose2(
                m.T_map_marker.x(), m.T_map_marker.y(), m.T_map_marker.theta() + math.pi))
            if i in ids else m
            for i, m in slam.markers.items()
        }  # fmt: skip
        return dataclasses.replace(slam, markers=markers)

    _, per_method = judged({Method.SLAM: turned(set(slam.markers))}, extraction)
    reason = next(r for r in per_method[Method.SLAM].reasons if r.check == "facing")
    assert per_method[Method.SLAM].verdict is Verdict.FAILED
    assert reason.figure == len(slam.markers) and "100 % of the sightings" in reason.text
    one = max(slam.markers)
    _, per_method = judged({Method.SLAM: turned({one})}, extraction)
    reason = next(r for r in per_method[Method.SLAM].reasons if r.check == "facing")
    assert per_method[Method.SLAM].verdict is Verdict.SUSPECT
    assert reason.text.startswith(f"marker {one} faces away")


def test_ellipses_longer_than_the_map_are_flagged(clean) -> None:
    """A covariance inflated to 100 m sigma makes an ellipse longer than the 6 m room."""
    _, estimates, extraction = clean
    slam = estimates[Method.SLAM]
    marker_id = max(slam.markers)
    markers = dict(slam.markers)
    markers[marker_id] = dataclasses.replace(
        markers[marker_id], covariance=np.diag([1e4, 1e4, 1.0])
    )
    _, per_method = judged({Method.SLAM: dataclasses.replace(slam, markers=markers)}, extraction)
    reason = next(r for r in per_method[Method.SLAM].reasons if r.check == "ellipses")
    assert reason.figure == pytest.approx(2 * 100 * math.sqrt(5.991), rel=1e-6)


def test_unplaced_markers_are_suspect_and_only_home_is_failed(clean) -> None:
    """A marker missing: suspect, naming it; only the home marker placed: failed."""
    _, estimates, extraction = clean
    slam = estimates[Method.SLAM]
    assert len(slam.markers) >= 3
    missing = max(slam.markers)
    fewer = {i: m for i, m in slam.markers.items() if i != missing}
    _, per_method = judged({Method.SLAM: dataclasses.replace(slam, markers=fewer)}, extraction)
    reason = next(r for r in per_method[Method.SLAM].reasons if r.check == "unplaced")
    assert per_method[Method.SLAM].verdict is Verdict.SUSPECT and reason.figure == 1
    assert f"marker {missing} is missing" in reason.text
    home_only = {slam.home_id: slam.markers[slam.home_id]}
    _, per_method = judged({Method.SLAM: dataclasses.replace(slam, markers=home_only)}, extraction)
    assert per_method[Method.SLAM].verdict is Verdict.FAILED


def test_closed_form_drift_beyond_its_share_of_the_map_is_flagged(clean) -> None:
    """The closed form has no covariance: one marker 1 m from SLAM's (over 5 % of the room
    and the 0.25 m floor) makes it suspect; as it came out of the clean run it is ok, unless no
    other method is sound."""
    _, estimates, extraction = clean
    closed = estimates[Method.CLOSED_FORM]
    marker_id = max(closed.markers)
    markers = dict(closed.markers)
    T = estimates[Method.SLAM].markers[marker_id].T_map_marker
    markers[marker_id] = dataclasses.replace(
        markers[marker_id], T_map_marker=gtsam.Pose2(T.x(), T.y() + 1.0, T.theta())
    )
    pair = {Method.SLAM: estimates[Method.SLAM],
            Method.CLOSED_FORM: dataclasses.replace(closed, markers=markers)}  # fmt: skip
    _, per_method = judged(pair, extraction)
    reason = next(r for r in per_method[Method.CLOSED_FORM].reasons if r.check == "disagreement")
    assert (
        reason.figure == pytest.approx(1.0, abs=1e-9) and "from where slam puts it" in reason.text
    )
    # SLAM itself unsound (its optimiser stopped): the closed form is still measured against
    # it, and nothing vouches for the closed form as it came out of the clean run.
    pair = {Method.SLAM: dataclasses.replace(estimates[Method.SLAM], converged=False),
            Method.CLOSED_FORM: closed}  # fmt: skip
    _, per_method = judged(pair, extraction)
    (reason,) = per_method[Method.CLOSED_FORM].reasons
    assert reason.text == "no other method vouches for it: slam is suspect"


def test_searches_at_the_end_of_their_range_and_dropped_frames_are_reasons(clean) -> None:
    """A delay, a scale or a turn scale chosen at its grid's end, or a fifth of the frames
    (undecodable, or stamps their neighbours contradict) or of the odometry samples dropped,
    make every method suspect with the figure; set by hand, the bound is no evidence."""
    _, estimates, extraction = clean
    slam_only = {Method.SLAM: estimates[Method.SLAM]}
    delay_ns = round(max(DELAYS_S) * 1e9)
    _, per_method = judged(slam_only, extraction, camera_delay_ns=delay_ns,
                           odometry_scale=min(SCALES), odometry_turn_scale=max(SCALES))  # fmt: skip
    assert {"delay", "odometry", "odometry_turns"} <= checks(per_method[Method.SLAM])
    _, per_method = judged(slam_only, extraction, camera_delay_ns=delay_ns,
                           odometry_scale=min(SCALES), odometry_turn_scale=max(SCALES),
                           delay_searched=False, scale_searched=False,
                           turn_searched=False)  # fmt: skip
    assert per_method[Method.SLAM].verdict is Verdict.OK
    for dropping in (
        dataclasses.replace(extraction, undecodable_frames=extraction.frames // 5),
        dataclasses.replace(extraction, frames_dropped_by_stamp=extraction.frames // 5),
        dataclasses.replace(extraction, dropped_odometry_samples=len(extraction.odometry) // 4),
    ):
        _, per_method = judged(slam_only, dropping)
        reason = next(r for r in per_method[Method.SLAM].reasons if r.check == "dropped")
        assert reason.figure == pytest.approx(20.0, abs=0.1), reason.text


def _estimate(markers: dict[int, tuple[gtsam.Pose2, np.ndarray]]) -> Estimate:
    return Estimate(
        Method.SLAM,
        min(markers),
        {i: MarkerEstimate(i, T, cov, 10) for i, (T, cov) in markers.items()},
        Trajectory.from_samples([], "map"),
    )


# --- through the command line ----------------------------------------------------------------

COLOR = "/camera/camera/color/image_raw/compressed"


@pytest.mark.slow
def test_cli_prints_verdicts_and_strict_exits_4_only_when_not_ok(log, tmp_path, capsys):
    """The clean log: SLAM ok in the summary, report.json and report.html, and --strict exits 0.
    A quarter of its colour frames undecodable: every method suspect with the share dropped,
    the folder still written, and --strict exits 4."""
    code = main(["map", str(log), "--out", str(tmp_path / "clean"), "--no-plots",
                 "--strict"])  # fmt: skip
    out = capsys.readouterr().out
    assert code == 0 and "verdict slam: ok" in out
    report = json.loads((tmp_path / "clean" / "report.json").read_text())
    assert report["verdict"] == "ok" and report["methods"]["slam"]["verdict"] == "ok"
    page = (tmp_path / "clean" / "report.html").read_text()
    assert page.index('id="verdict"') < page.index('id="summary"')

    def corrupt(topic: str, index: int, decoded: Any) -> Any:
        if topic == COLOR and index % 4 == 1:
            decoded.data = b"\x55" * 64
        return decoded

    damaged = tmp_path / "damaged.mcap"
    rewrite_log(log, damaged, corrupt)
    code = main(["map", str(damaged), "--out", str(tmp_path / "damaged"), "--no-plots",
                 "--strict"])  # fmt: skip
    out = capsys.readouterr().out
    assert code == EXIT_NOT_OK and "verdict slam: suspect" in out
    report = json.loads((tmp_path / "damaged" / "report.json").read_text())
    reason = report["methods"]["slam"]["verdict_reasons"][0]
    assert "25 % of the colour frames do not decode (25 of 100)" in reason
    assert report["verdict"] == "suspect" and report["verdict_reasons"] == [reason]
