"""A map scored against the ground truth a simulated log carries: marker errors, the share of
true markers inside the 95 % ellipses, and the path's ATE and RPE."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import gtsam
import numpy as np

from markergraph.estimator import (
    Trajectory,
    TrajectoryError,
    ellipse_coverage,
    map_error,
    trajectory_error,
)
from markergraph.frontend import Extraction

if TYPE_CHECKING:
    from markergraph.records import MethodResult

__all__ = ["path_error", "score", "truth_in_home_frame"]


def truth_in_home_frame(
    extraction: Extraction, home_id: int
) -> tuple[dict[int, gtsam.Pose2], Trajectory | None]:
    """A log's ground truth (markers, path) in the frame of the map's home marker, when it
    carries both; ``({}, None)`` otherwise."""
    true_markers = extraction.true_markers
    if home_id not in true_markers:
        return {}, None
    T_home_world = true_markers[home_id].inverse()
    truth = {i: T_home_world.compose(T) for i, T in true_markers.items()}
    path = extraction.true_path.in_frame(T_home_world, "map") if len(extraction.true_path) else None
    return truth, path


def score(result: MethodResult, truth: dict[int, gtsam.Pose2], path: Trajectory | None) -> None:
    """Fill a method's marker and trajectory errors against the logged truth, where it covers
    the estimate."""
    estimate = result.estimate
    if not truth or not set(estimate.markers) & set(truth):
        return
    result.map_error = map_error(estimate, truth)
    coverage = ellipse_coverage(estimate, truth)
    result.inside_95_ellipse = None if math.isnan(coverage.share) else coverage.share
    result.yaw_inside_95 = None if math.isnan(coverage.yaw_share) else coverage.yaw_share
    if len(estimate.markers) >= 2:
        result.map_error_aligned = map_error(estimate, truth, align=True)
    # At the odometry's rate where the corrected path is known: the whole path, not only the
    # frames with a detection.
    walked = result.path if result.path is not None else estimate.trajectory
    result.trajectory_error, result.true_path = path_error(walked, path)


def path_error(
    trajectory: Trajectory, path: Trajectory | None
) -> tuple[TrajectoryError | None, Trajectory | None]:
    """An estimated trajectory's error against the true path at its own stamps, and that true
    path (None where the truth does not cover two of them)."""
    if path is None or len(path) < 2:
        return None, None
    true_path = path.at_stamps(trajectory.t_ns)
    if len(true_path) < 2:
        return None, true_path
    covered = np.isin(trajectory.t_ns, true_path.t_ns)
    return trajectory_error(trajectory.poses[covered], true_path.poses), true_path
