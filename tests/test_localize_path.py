"""localize's trajectory.tum at the odometry's rate: the localised poses where markers were
seen, the odometry between them, against the simulator's truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from markergraph.results import write_localization
from markergraph.run import localize_log, map_log
from markergraph.scoring import path_error, truth_in_home_frame


def test_the_path_runs_at_the_odometrys_rate_through_the_localised_poses(
    log: Path, tmp_path: Path
) -> None:
    """The paper room localised in its own map: the path holds every odometry stamp between
    the first and last localised frame (50 Hz, the frames 5 Hz), passes through each localised
    pose (within 1 mm and 1 mrad, between two odometry stamps), and is as close to the truth
    (rigidly aligned) as the localised poses, within 5 mm; trajectory.tum and ground_truth.tum
    hold the same stamps."""
    saved = map_log(log).results[0].marker_map
    map_path = tmp_path / "map.json"
    saved.save(map_path)
    run = localize_log(log, saved, map_path)
    solved, path = run.localization.trajectory, run.path
    assert path is not None
    odometry = run.extraction.odometry
    inside = (odometry.t_ns >= solved.t_ns[0]) & (odometry.t_ns <= solved.t_ns[-1])
    assert len(path) >= int(np.count_nonzero(inside)) > 8 * len(solved)
    through = path.at_stamps(solved.t_ns)  # interpolated between the odometry's stamps
    assert np.array_equal(through.t_ns, solved.t_ns)
    difference = through.poses - solved.poses
    difference[:, 2] = np.remainder(difference[:, 2] + np.pi, 2.0 * np.pi) - np.pi  # yaw wraps
    np.testing.assert_allclose(difference, 0.0, atol=1e-3)
    _, truth = truth_in_home_frame(run.extraction, saved.home_id)
    solved_error, _ = path_error(solved, truth)
    path_error_, _ = path_error(path, truth)
    assert solved_error is not None and path_error_ is not None
    assert path_error_.ate_aligned_rmse_m < solved_error.ate_aligned_rmse_m + 0.005
    out = tmp_path / "loc"
    write_localization(run, out, plots=False)
    tum = np.loadtxt(out / "trajectory.tum", ndmin=2)
    true_tum = np.loadtxt(out / "ground_truth.tum", ndmin=2)
    assert len(tum) == len(path) and np.array_equal(tum[:, 0], true_tum[:, 0])
