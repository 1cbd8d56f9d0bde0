"""The fast paths of ``map``'s own work against the computations they replace: frames built in
one numpy pass against the frame-by-frame loop, and the delay and scale searches (a downhill
walk of loosely converged solves) against solving every grid value to full convergence."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import replace

import gtsam
import numpy as np
import pytest

from markergraph.datasets import scenario, simulate_fast
from markergraph.datasets.simulate import SimulatedRun
from markergraph.estimator import (
    Method,
    Observation,
    OdometryNoise,
    Robust,
    SlamInputs,
    Trajectory,
    build_frames,
    camera_delay_by_residuals,
    estimate_frames,
    odometry_scale_by_residuals,
    retimed,
)
from markergraph.estimator.frames import RELEASED_MOTION_COVARIANCE, motion_covariance
from markergraph.estimator.odometry_scale import SCALES
from markergraph.estimator.slam import build_slam_graph
from markergraph.estimator.solution import optimise
from markergraph.estimator.timing import DELAYS_S

EXACT_ALGEBRA = 1e-12  # the same sums in another order
# The searches' costs stop within about 0.01 of the optimum's (SEARCH_RELATIVE_ERROR_TOL), which
# moves a parabola through grid costs 5-100 apart by under a microsecond and 1e-5 of a scale
# (seen: 3-5 ns and 3e-8; solves stopped at 1e-3 instead are 2-8 us off).
DELAY_TOL_NS = 1_000
SCALE_TOL = 1e-5
MAP_TOL_M = 1e-3  # the maps at either choice
MAP_TOL_RAD = 1e-4
TRUE_DELAY_NS = 25_000_000  # the camera's stamps trail its captures by this
TRUE_SCALE = 1.02  # the odometry reads distances this much long


def _frames_one_by_one(
    observations: Sequence[Observation],
    odometry: Trajectory,
    noise: OdometryNoise,
    breaks: Sequence[int],
) -> tuple[list[int], list[gtsam.Pose2], list[np.ndarray], int]:
    """The frame-by-frame loop the numpy pass replaced: each frame's pose by ``Trajectory.at``,
    its motion's covariance by :func:`motion_covariance` over the samples since the previous
    frame; (stamps, poses, covariances, how many released)."""
    stamps, poses, covariances, released = [], [], [], 0
    for t_ns in sorted({o.t_ns for o in observations}):
        pose = odometry.at(t_ns)
        if pose is None:
            continue
        if stamps:
            first = int(np.searchsorted(odometry.t_ns, stamps[-1], "right"))
            last = int(np.searchsorted(odometry.t_ns, t_ns, "left"))
            before = poses[-1]
            along = np.vstack([
                [before.x(), before.y(), before.theta()],
                odometry.poses[first:last],
                [pose.x(), pose.y(), pose.theta()],
            ])  # fmt: skip
            covariance = motion_covariance(along, noise)
            if any(stamps[-1] < t <= t_ns for t in breaks):
                covariance = covariance + RELEASED_MOTION_COVARIANCE
                released += 1
        else:
            covariance = np.zeros((3, 3))
        stamps.append(t_ns)
        poses.append(pose)
        covariances.append(covariance)
    return stamps, poses, covariances, released


@pytest.fixture(scope="module")
def run() -> SimulatedRun:
    return simulate_fast(*scenario("corridor-loop"), seed=7, duration_s=40.0)


def test_frames_in_one_pass_equal_the_frame_by_frame_loop(run: SimulatedRun) -> None:
    """Exact algebra: every frame's stamp, odometry pose and motion covariance, frames before
    and after the odometry's span skipped and two gaps released across a jump, as the loop
    gives them, on stamps that fall on, between and outside the odometry's samples."""
    odometry = Trajectory.from_samples(run.odometry)
    rng = np.random.default_rng(3)
    shifted = [replace(o, t_ns=o.t_ns + int(rng.integers(-5, 5)) * 10**7) for o in run.observations]
    on_samples = [replace(o, t_ns=int(odometry.t_ns[100 + k])) for k, o in enumerate(shifted[:5])]
    outside = [replace(shifted[0], t_ns=int(odometry.t_ns[-1]) + k * 10**8) for k in (0, 1, 5)]
    observations = shifted + on_samples + outside
    breaks = [int(odometry.t_ns[400]), int(odometry.t_ns[1200]) + 1]
    noise = OdometryNoise()
    frames = build_frames(observations, odometry, odometry_noise=noise, odometry_breaks=breaks)
    stamps, poses, covariances, released = _frames_one_by_one(observations, odometry, noise, breaks)
    assert [f.t_ns for f in frames.frames] == stamps
    assert released == 2
    assert [n.figure for n in frames.notes] == [
        2,
        len({o.t_ns for o in observations}) - len(stamps),
    ]
    for frame, pose, covariance in zip(frames.frames, poses, covariances, strict=True):
        assert frame.T_odom_base.equals(pose, EXACT_ALGEBRA)
        np.testing.assert_allclose(
            frame.odometry_covariance, covariance, rtol=EXACT_ALGEBRA, atol=1e-18
        )


def test_poses_at_many_stamps_equal_the_pose_at_each() -> None:
    """Exact algebra: the numpy interpolation at many stamps equals ``Trajectory.at`` at each,
    turning or straight, inside, on and beyond the samples (NaN where ``at`` gives None)."""
    rng = np.random.default_rng(5)
    t_ns = np.cumsum(rng.integers(10**7, 3 * 10**7, 200))
    poses = np.cumsum(rng.normal(0.0, [0.05, 0.05, 0.2], (200, 3)), axis=0)
    poses[50:60, 2] = poses[50, 2]  # a straight stretch: the small-turn branch
    odometry = Trajectory(t_ns, poses, "odom")
    stamps = np.concatenate([
        rng.integers(t_ns[0] - 2 * 10**8, t_ns[-1] + 2 * 10**8, 500), t_ns[::7], t_ns[50:60] + 5
    ])  # fmt: skip
    found = odometry.xy_yaw_at(stamps)
    for t, row in zip(stamps, found, strict=True):
        pose = odometry.at(int(t))
        if pose is None:
            assert np.isnan(row).all()
        else:
            assert gtsam.Pose2(*row).equals(pose, EXACT_ALGEBRA)


def _inputs(run: SimulatedRun) -> SlamInputs:
    """The run with late camera stamps and long-reading odometry, as the searches get it."""
    late = [replace(o, t_ns=o.t_ns + TRUE_DELAY_NS) for o in run.observations]
    odometry = Trajectory.from_samples(run.odometry).scaled(TRUE_SCALE)
    return SlamInputs(
        late, odometry, run.world.home_id, run.mount.T_base_camera, run.odometry_noise,
        robust=Robust.HUBER,
    )  # fmt: skip


def _full_cost(inputs: SlamInputs) -> float:
    """Batch SLAM's cost solved to full convergence from its pose-graph start."""
    frames = build_frames(
        inputs.observations, inputs.odometry, inputs.home_id,
        odometry_noise=inputs.odometry_noise, odometry_breaks=inputs.odometry_breaks,
    )  # fmt: skip
    builder = build_slam_graph(frames, inputs.T_base_camera, inputs.robust)
    result, _ = optimise(builder, {})
    return float(builder.graph.error(result))


def _every_grid_value(grid: Sequence[float], cost: Callable[[float], float]) -> float | None:
    """The reference: every grid value solved, the least refined by a parabola."""
    costs = [cost(value) for value in grid]
    best = int(np.argmin(costs))
    if best in (0, len(grid) - 1):
        return None
    c0, c1, c2 = costs[best - 1 : best + 2]
    return grid[best] + 0.5 * (grid[best + 1] - grid[best]) * (c0 - c2) / (c0 - 2 * c1 + c2)


def test_the_searches_choose_what_solving_every_grid_value_chooses(run: SimulatedRun) -> None:
    """The delay's and the scale's downhill walks of loosely converged solves choose what
    solving all 16 delays and 11 scales to full convergence chooses (within 1 us and 1e-5),
    with fewer than half the solves; the maps at either choice agree within 1 mm and 0.1 mrad,
    their marginal covariances within 1 %."""
    inputs = _inputs(run)

    def at_delay(delay_ns: float) -> SlamInputs:
        return replace(inputs, observations=retimed(inputs.observations, round(delay_ns)))

    delays = [round(d * 1e9) for d in DELAYS_S]
    reference_delay = _every_grid_value(delays, lambda d: _full_cost(at_delay(d)))
    found = camera_delay_by_residuals(inputs)
    assert reference_delay is not None and found.delay_ns is not None
    assert abs(found.delay_ns - reference_delay) < DELAY_TOL_NS
    assert abs(found.delay_ns - TRUE_DELAY_NS) < 5_000_000  # and the truth is near
    assert len(found.delays_ns) < len(delays) / 2
    reference_scale = _every_grid_value(
        SCALES,
        lambda s: _full_cost(
            replace(at_delay(reference_delay), odometry=inputs.odometry.scaled(s))
        ),
    )
    scale = odometry_scale_by_residuals(at_delay(found.delay_ns), found.solution)
    assert reference_scale is not None and scale.chosen is not None
    assert abs(scale.chosen - reference_scale) < SCALE_TOL
    assert abs(scale.chosen - 1 / TRUE_SCALE) < 0.004
    assert len(scale.tried) < len(SCALES) / 2 + 1
    maps = [
        estimate_frames(
            build_frames(
                at_delay(delay).observations, inputs.odometry.scaled(factor), inputs.home_id,
                odometry_noise=inputs.odometry_noise,
            ),
            Method.SLAM, inputs.T_base_camera,
        ).markers
        for delay, factor in ((reference_delay, reference_scale), (found.delay_ns, scale.chosen))
    ]  # fmt: skip
    for marker_id, reference in maps[0].items():
        fast = maps[1][marker_id]
        offset = reference.T_map_marker.between(fast.T_map_marker)
        assert math.hypot(offset.x(), offset.y()) < MAP_TOL_M
        assert abs(offset.theta()) < MAP_TOL_RAD
        assert reference.covariance is not None and fast.covariance is not None
        np.testing.assert_allclose(fast.covariance, reference.covariance, rtol=0.01, atol=1e-12)


def test_the_grid_walk_finds_what_every_grid_value_finds_on_a_bowl() -> None:
    """On 200 seeded bowl-shaped costs (any minimum, in or outside the grid; steep or flat
    sides) the downhill walk chooses exactly what solving every grid value chooses, and
    solves at most 9 of 16 values; with every cost infinite it chooses None after 5."""
    from markergraph.estimator.residual_search import cheapest_on_grid

    grid = [float(v) for v in range(-50, 101, 10)]
    coarse = sorted({*range(0, len(grid), 3), len(grid) - 1})
    rng = np.random.default_rng(11)
    for _ in range(200):
        centre, power = rng.uniform(-70, 120), rng.uniform(1.2, 3.0)

        def bowl(value: float, near: object, centre: float = centre, power: float = power):
            return abs(value - centre) ** power, None

        found = cheapest_on_grid(grid, bowl, coarse, 6)
        assert found.chosen == _every_grid_value(grid, lambda v: bowl(v, None)[0])
        assert len(found.tried) <= 9
    nothing = cheapest_on_grid(grid, lambda value, near: (math.inf, None), coarse, 6)
    assert nothing.chosen is None and len(nothing.tried) <= 5
