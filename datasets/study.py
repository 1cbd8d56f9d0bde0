"""Monte Carlo drift studies: every method on many seeded fast-mode runs of a scenario."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from markergraph.datasets.route import WheelErrors
from markergraph.datasets.scenarios import scenario
from markergraph.datasets.simulate import ObservationNoise, SimulatedRun, simulate_fast
from markergraph.estimator import (
    ELLIPSE_95_D2,
    Form,
    Method,
    OdometryNoise,
    build_frames,
    ellipse_coverage,
    estimate_frames,
    map_error,
    nees,
    trajectory_error,
)

__all__ = ["StudyRow", "drift_study", "summarise"]


@dataclass(frozen=True)
class StudyRow:
    """One method on one seeded run.

    Attributes:
        scenario, seed, method: what ran (``method`` is the Method's value, with the form for
            the closed form, e.g. ``"closed-form/signed"``).
        marker_rmse_m, marker_rmse_aligned_m, marker_yaw_rmse_rad: map error against truth.
        ate_m, rpe_m_per_m: trajectory error (the marker graph's trajectory is the robot
            localised on its nearest marker in each frame).
        mean_nees: the run's average NEES of the robot pose (EKF only, else NaN).
        seconds: the method's run time.
        markers_checked, markers_inside_95: markers (home aside) whose covariance was checked
            against the truth, and how many of them lie inside their 95 % position ellipse
            (:func:`~markergraph.estimator.metrics.ellipse_coverage`; 0 and 0 for the closed
            form, which has no covariance).
    """

    scenario: str
    seed: int
    method: str
    marker_rmse_m: float
    marker_rmse_aligned_m: float
    marker_yaw_rmse_rad: float
    ate_m: float
    rpe_m_per_m: float
    mean_nees: float
    seconds: float
    markers_checked: int = 0
    markers_inside_95: int = 0


DEFAULT_METHODS: tuple[tuple[Method, Form], ...] = (
    (Method.CLOSED_FORM, Form.SIGNED),
    (Method.MARKER_GRAPH, Form.SIGNED),
    (Method.SLAM, Form.SIGNED),
    (Method.ISAM2, Form.SIGNED),
    (Method.EKF, Form.SIGNED),
)


def _row(
    run: SimulatedRun, name: str, seed: int, method: Method, form: Form, assumed: OdometryNoise
) -> StudyRow:
    frames = build_frames(run.observations, run.odometry, run.world.home_id, odometry_noise=assumed)
    result = estimate_frames(frames, method, run.mount.T_base_camera, form=form)
    truth = run.true_markers()
    error, aligned = map_error(result, truth), map_error(result, truth, align=True)
    ate = rpe = mean_nees = float("nan")
    if len(result.trajectory):
        true_by_stamp = dict(zip(run.frame_t_ns.tolist(), run.true_trajectory(), strict=True))
        true_path = np.array([true_by_stamp[int(t)] for t in result.trajectory.t_ns])
        trajectory = trajectory_error(result.trajectory.poses, true_path)
        ate, rpe = trajectory.ate_rmse_m, trajectory.rpe_rmse_m_per_m
        if result.trajectory_covariance is not None:
            mean_nees = float(
                np.mean(nees(result.trajectory.poses, result.trajectory_covariance, true_path))
            )
    coverage = ellipse_coverage(result, truth)
    label = method.value if method is not Method.CLOSED_FORM else f"{method.value}/{form.value}"
    return StudyRow(
        name,
        seed,
        label,
        error.rmse_position_m,
        aligned.rmse_position_m,
        error.rmse_yaw_rad,
        ate,
        rpe,
        mean_nees,
        sum(result.timings_s.values()),
        len(coverage.d2),
        int(np.sum(coverage.d2 <= ELLIPSE_95_D2)),
    )


def drift_study(
    scenarios: Iterable[str],
    seeds: Iterable[int],
    methods: Iterable[tuple[Method, Form]] = DEFAULT_METHODS,
    *,
    noise: ObservationNoise = ObservationNoise(),
    wheel: WheelErrors = WheelErrors(),
    duration_s: float | None = None,
    odometry_noise: OdometryNoise | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[StudyRow]:
    """Run every method on one fast-mode run per (scenario, seed).

    Args:
        odometry_noise: the odometry noise the estimators assume (default: the run's model).
        progress: called with (runs done, runs in all) after each run.
    """
    names, seed_list, method_list = list(scenarios), list(seeds), list(methods)
    total, rows = len(names) * len(seed_list), []
    for name in names:
        world, route = scenario(name)
        for seed in seed_list:
            run = simulate_fast(world, route, seed, noise=noise, wheel=wheel, duration_s=duration_s)
            assumed = odometry_noise or run.odometry_noise
            rows += [_row(run, name, seed, m, form, assumed) for m, form in method_list]
            if progress is not None:
                progress(len(rows) // len(method_list), total)
    return rows


def summarise(rows: list[StudyRow]) -> dict[tuple[str, str], dict[str, float]]:
    """(scenario, method) -> the mean of each figure over seeds, and ``ellipse_coverage``: the
    share of every checked marker over the seeds inside its 95 % ellipse (NaN with none)."""
    groups: dict[tuple[str, str], list[StudyRow]] = {}
    for row in rows:
        groups.setdefault((row.scenario, row.method), []).append(row)
    figures = (
        "marker_rmse_m",
        "marker_rmse_aligned_m",
        "marker_yaw_rmse_rad",
        "ate_m",
        "rpe_m_per_m",
        "mean_nees",
        "seconds",
    )
    summary = {
        key: {f: float(np.mean([getattr(r, f) for r in group])) for f in figures}
        for key, group in groups.items()
    }
    for key, group in groups.items():
        checked = sum(r.markers_checked for r in group)
        inside = sum(r.markers_inside_95 for r in group)
        summary[key]["ellipse_coverage"] = inside / checked if checked else float("nan")
    return summary
