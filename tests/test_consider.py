"""A parameter held fixed (a rolling shutter's readout no residual can choose) adds its share to
the markers' covariances: exact algebra on moves of known size, and the uniform range's second
moment by sampling."""

from __future__ import annotations

import math

import gtsam
import numpy as np
import pytest

from markergraph.estimator import Estimate, MarkerEstimate, Method, Trajectory
from markergraph.estimator.consider import AT_ONE_END, marker_moves, with_considered

POSES = {
    0: gtsam.Pose2(0.0, 0.0, 0.0),
    3: gtsam.Pose2(4.0, 1.0, 0.7),
    5: gtsam.Pose2(-2.0, 6.0, 2.9),
}


def estimate_at(poses: dict[int, gtsam.Pose2], covariance: float = 1e-4) -> Estimate:
    """Markers at ``poses`` (0 the home marker, without a covariance), each other with an
    isotropic covariance and the same as its relative covariance."""
    markers = {
        i: MarkerEstimate(
            i,
            T,
            None if i == 0 else covariance * np.eye(3),
            5,
            None if i == 0 else covariance * np.eye(3),
        )
        for i, T in poses.items()
    }
    return Estimate(Method.SLAM, 0, markers, Trajectory.from_samples([]))


def test_each_marker_grows_by_its_own_move_in_its_tangent_space() -> None:
    """Markers moved by known tangent steps: the moves are those steps, and each covariance
    grows by exactly ``fraction d d^T``; the home marker and the input are left as they were."""
    steps = {3: np.array([0.05, -0.02, 0.01]), 5: np.array([-0.03, 0.08, -0.02])}
    moved_poses = {i: T.compose(gtsam.Pose2.Expmap(steps[i])) if i in steps else T
                   for i, T in POSES.items()}  # fmt: skip
    base, moved = estimate_at(POSES), estimate_at(moved_poses)
    moves = marker_moves(base, moved)
    assert set(moves) == {3, 5}
    for i, step in steps.items():
        np.testing.assert_allclose(moves[i], step, atol=1e-12)
    grown = with_considered(base, moved, AT_ONE_END)
    for i, step in steps.items():
        np.testing.assert_allclose(
            grown.markers[i].covariance, 1e-4 * np.eye(3) + np.outer(step, step) / 3.0, atol=1e-15
        )
    assert grown.markers[0].covariance is None
    np.testing.assert_array_equal(base.markers[3].covariance, 1e-4 * np.eye(3))


def test_maps_on_different_home_markers_are_refused() -> None:
    """Two maps in different frames (another home marker) have no moves to compare."""
    other = estimate_at(POSES)
    other.home_id = 3
    with pytest.raises(ValueError, match="home markers 0 and 3"):
        with_considered(estimate_at(POSES), other, AT_ONE_END)


def test_a_rigid_motion_of_the_whole_map_leaves_the_relative_covariance() -> None:
    """The map turned and shifted as a whole (the home marker too is only a marker here):
    each covariance grows by its move, the relative covariances (the map's own shape) not at
    all; a move of one marker alone shows in both."""
    motion = gtsam.Pose2(0.3, -0.2, 0.05)
    base = estimate_at(POSES)
    base.home_id = -1  # no marker pinned: every one moves with the map
    rigid = estimate_at({i: motion.compose(T) for i, T in POSES.items()})
    rigid.home_id = -1
    grown = with_considered(base, rigid, 1.0)
    for i in (3, 5):
        move = marker_moves(base, rigid)[i]
        assert np.linalg.norm(move) > 0.05
        marker = grown.markers[i]
        np.testing.assert_allclose(marker.covariance, 1e-4 * np.eye(3) + np.outer(move, move))
        np.testing.assert_allclose(marker.relative_covariance, 1e-4 * np.eye(3), atol=1e-14)
    one = estimate_at({**POSES, 5: POSES[5].compose(gtsam.Pose2(0.1, 0.0, 0.0))})
    one.home_id = -1
    shape = with_considered(base, one, 1.0)
    assert shape.markers[5].relative_covariance[0, 0] > 1e-4 + 1e-3


def test_one_ends_share_is_the_uniform_ranges_second_moment() -> None:
    """A solution at one end of a parameter's range, the true value uniform over it: the error
    ``u d`` (u uniform on [0, 1]) has second moment ``d^2 / 3`` (sampled, seeded), and with it
    added a 95 % interval holds the truth 95 % of the time or more."""
    rng = np.random.default_rng(30)
    u = rng.uniform(0.0, 1.0, 200_000)
    assert np.mean(u**2) == pytest.approx(AT_ONE_END, rel=0.01)
    d, sigma = 0.3, 0.05  # the move across the range, the solution's own noise [m]
    errors = u * d + rng.normal(0.0, sigma, u.size)
    inside = np.abs(errors) <= 1.96 * math.sqrt(sigma**2 + AT_ONE_END * d**2)
    assert np.mean(inside) >= 0.95
    assert np.mean(np.abs(errors) <= 1.96 * sigma) < 0.5  # without the share: far too narrow
