"""Worlds, routes, wheel odometry and the fast observation simulator against exact geometry."""

from __future__ import annotations

import itertools
import math

import gtsam
import numpy as np
import pytest

from markergraph.datasets import (
    SCENARIOS,
    GoTo,
    Look,
    Route,
    Wall,
    WheelErrors,
    World,
    WorldFileError,
    plan,
    scenario,
    simulate_fast,
    visible_markers,
)
from markergraph.datasets.route import wheel_odometry
from markergraph.datasets.world import Marker
from markergraph.estimator import angle_diff
from markergraph.frontend.camera import Camera, CameraMount

SCENARIO_MINIMUM_MARKERS = {"paper-room": 3, "corridor-loop": 12, "office": 25, "warehouse": 200}


@pytest.mark.parametrize("name", SCENARIOS)
def test_scenario_is_sound(name: str) -> None:
    """Enough markers, every marker on its wall facing into free space, no route through a wall."""
    world, route = scenario(name)
    assert len(world.markers) >= SCENARIO_MINIMUM_MARKERS[name]
    points = [np.array(route.start[:2])] + [
        np.array([s.x, s.y]) for s in route.steps if isinstance(s, GoTo)
    ]
    for p, q in itertools.pairwise(points):
        assert not world.blocked(p, q), (p, q)
    for marker in world.markers:
        T = world.T_world_marker(marker.id)
        # 0.5 m in front of the marker is free space: not inside a wall.
        front = T.transformFrom(np.array([0.5, 0.0]))
        assert not world.blocked(np.array([T.x(), T.y()]), front), marker.id


def test_world_round_trips_through_json(tmp_path) -> None:
    """A saved world loads back equal; a file of another schema is refused with its name."""
    world, _ = scenario("office")
    path = tmp_path / "office.json"
    world.save(path)
    assert World.load(path) == world
    path.write_text('{"schema": "something/9"}')
    with pytest.raises(WorldFileError, match=r"office\.json"):
        World.load(path)


def test_marker_corners_follow_opencv_order() -> None:
    """A marker on the far wall of a room, seen from its front: TL, TR, BR, BL as pixels go."""
    world = World("box", (Wall((0.0, 0.0), (4.0, 0.0)),), (Marker(0, 0, 2.0, side=1),), 0)
    T = world.T_world_marker(0)
    assert T.equals(gtsam.Pose2(2.0, 0.0, math.pi / 2), 1e-12)
    base = gtsam.Pose2(2.0, 2.0, -math.pi / 2)  # facing the marker from 2 m
    mount = CameraMount(x_m=0.0, height_m=1.0, pitch_rad=0.0)
    pixels = Camera().project(mount.world_to_optical(base, world.marker_corners(0)))
    tl, tr, br, bl = pixels
    assert tl[0] < tr[0] and bl[0] < br[0]  # left to right
    assert tl[1] < bl[1] and tr[1] < br[1]  # top to bottom
    np.testing.assert_allclose((tl + br) / 2, [320.0, 240.0], atol=1e-9)
    np.testing.assert_allclose(tr[0] - tl[0], 615.0 * 0.2 / 2.0, rtol=1e-12)


def test_occluded_and_back_facing_markers_are_not_seen() -> None:
    """A wall between camera and marker hides it; so does standing behind the marker's wall."""
    walls = (Wall((0.0, 0.0), (4.0, 0.0)), Wall((1.0, 1.0), (3.0, 1.0)))
    world = World("screen", walls, (Marker(0, 0, 2.0, side=1),), 0)
    camera, mount = Camera(), CameraMount(x_m=0.0, height_m=1.0, pitch_rad=0.0)
    assert visible_markers(world, camera, mount, gtsam.Pose2(2.0, 0.8, -math.pi / 2)) == [0]
    assert visible_markers(world, camera, mount, gtsam.Pose2(2.0, 2.0, -math.pi / 2)) == []
    assert visible_markers(world, camera, mount, gtsam.Pose2(2.0, -1.0, math.pi / 2)) == []


def test_fast_mode_is_deterministic_per_seed() -> None:
    """The same seed gives the same run; another seed another."""
    world, route = scenario("paper-room")
    first = simulate_fast(world, route, seed=3, duration_s=30.0)
    again = simulate_fast(world, route, seed=3, duration_s=30.0)
    other = simulate_fast(world, route, seed=4, duration_s=30.0)
    assert first.observations == again.observations and first.odometry == again.odometry
    assert first.observations != other.observations


def test_route_executes_rotate_translate_goals_exactly() -> None:
    """The planned trajectory reaches every GoTo and faces every Look's marker."""
    world, _ = scenario("paper-room")
    route = Route(
        start=(1.0, 1.0, 0.0), steps=(GoTo(3.0, 1.0), Look(1, pause_s=2.0), GoTo(3.0, 3.0))
    )
    trajectory = plan(world, route)
    # 2 m at 0.35 m/s, then a turn to marker 1 at (2.5, 4), a 2 s pause, a turn, 2 m.
    to_marker = math.atan2(3.0, -0.5)
    expected = 2.0 / 0.35 + to_marker / 0.6 + 2.0 + abs(to_marker - math.pi / 2) / 0.6 + 2.0 / 0.35
    assert trajectory.duration_s == pytest.approx(expected, rel=1e-12)
    np.testing.assert_allclose(
        trajectory.poses(np.array([2.0 / 0.35]))[0], [3.0, 1.0, 0.0], atol=1e-12
    )
    np.testing.assert_allclose(
        trajectory.poses(np.array([1e9]))[0], [3.0, 3.0, math.pi / 2], atol=1e-12
    )


def test_noise_free_wheel_odometry_is_exact() -> None:
    """With every error zero, odometry integrates the true trajectory (relative to its start)."""
    world, route = scenario("corridor-loop")
    truth = plan(world, route).poses(np.arange(0.0, 200.0, 0.02))
    odom = wheel_odometry(truth, WheelErrors(0.0, 0.0, 0.0, 0.0, 0.0), np.random.default_rng(0))
    T_world_odom = gtsam.Pose2(*truth[0])
    for row, pose in zip(odom[::500], truth[::500], strict=True):
        assert T_world_odom.compose(gtsam.Pose2(*row)).equals(gtsam.Pose2(*pose), 1e-9)


def test_wheel_odometry_drifts_with_its_systematic_errors() -> None:
    """A 1% scale error makes a straight 10 m drive read 10.1 m."""
    truth = np.column_stack([np.linspace(0.0, 10.0, 501), np.zeros(501), np.zeros(501)])
    errors = WheelErrors(1.0, 0.0, 0.0, 0.0, 0.0)  # scale drawn as 1 + N(0, 1)
    rng = np.random.default_rng(5)
    scale = 1.0 + np.random.default_rng(5).normal(0.0, 1.0)
    odom = wheel_odometry(truth, errors, rng)
    assert odom[-1, 0] == pytest.approx(10.0 * scale, rel=1e-12)


def test_fast_observations_match_geometry_within_their_noise() -> None:
    """Normalised errors against the exact values are standard normal (chi-square, 3 dof)."""
    world, route = scenario("office")
    run = simulate_fast(world, route, seed=11)
    truth = {
        pose_t: pose for pose_t, pose in zip(run.frame_t_ns, run.T_world_base_frames, strict=True)
    }
    squared = []
    for obs in run.observations:
        T_world_camera = gtsam.Pose2(*truth[obs.t_ns]).compose(run.mount.T_base_camera)
        T_marker = world.T_world_marker(obs.marker_id)
        p_cam = T_world_camera.transformTo(T_marker.translation())
        p_marker = T_marker.transformTo(T_world_camera.translation())
        errors = (
            angle_diff(obs.bearing, math.atan2(p_cam[1], p_cam[0])) / obs.sigma_bearing,
            angle_diff(obs.theta, math.atan2(p_marker[1], p_marker[0])) / obs.sigma_theta,
            (obs.range_m - float(np.hypot(*p_cam))) / obs.sigma_range,
        )
        squared.append(sum(e * e for e in errors))
    n = len(squared)
    assert n > 1000
    # Mean of n chi-square(3) draws: 3 +- 3.3 * sqrt(6 / n) (99.9%).
    assert abs(np.mean(squared) - 3.0) < 3.3 * math.sqrt(6.0 / n)
