"""Many sessions of the simulated office (README, "Several logs"): each 120 s session's marker
error alone and the two merged, for SLAM, iSAM2 and the marker graph; a third session localised
in the merged map (ATE, median position sigma, markers called moved); a fourth with marker 7
moved 0.3 m along its wall (what is called moved, by how much, and the ATE).

    python tests/benchmarks/sessions.py [--seconds 120]
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

from markergraph.datasets import scenario, simulate_fast
from markergraph.estimator import Method, build_frames, estimate_frames, map_error
from markergraph.estimator.localization import localize
from markergraph.estimator.sessions import MapPrior, solve_sessions

MOVED_ID, MOVED_BY_M = 7, 0.3


def frames_of(run, home: int | None = None):
    return build_frames(run.observations, run.odometry, home, odometry_noise=run.odometry_noise)


def ate_m(localization, run) -> float:
    rows = np.searchsorted(np.asarray(run.frame_t_ns), localization.trajectory.t_ns)
    error = localization.trajectory.poses[:, :2] - run.true_trajectory()[rows, :2]
    return float(np.sqrt(np.mean(np.sum(error**2, axis=1))))


def print_localisation(label: str, localization, run) -> None:
    covariances = localization.pose_covariances
    sigma = np.sqrt(covariances[:, 0, 0] + covariances[:, 1, 1])
    moved = ", ".join(
        f"{m.marker_id} by {100 * m.displacement_m:.1f} cm" for m in localization.moved
    )
    print(
        f"{label}: ATE {100 * ate_m(localization, run):.2f} cm, median position sigma "
        f"{100 * np.median(sigma):.2f} cm, moved: {moved or 'none'}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=120.0)
    seconds = parser.parse_args().seconds
    world, route = scenario("office")
    truth = world.T_map_markers()
    runs = [simulate_fast(world, route, seed=seed, duration_s=seconds) for seed in (1, 2)]
    mounts = [run.mount.T_base_camera for run in runs]
    merged_slam = None
    for method in (Method.SLAM, Method.ISAM2, Method.MARKER_GRAPH):
        alone = [
            map_error(estimate_frames(frames_of(r, 0), method, r.mount.T_base_camera), truth)
            for r in runs
        ]
        merged = solve_sessions([frames_of(runs[0], 0), frames_of(runs[1])], mounts, method=method)
        merged_slam = merged_slam or merged
        print(
            f"{method.value:13s} alone "
            + " / ".join(f"{100 * e.rmse_position_m:.1f}" for e in alone)
            + f" cm, merged {100 * map_error(merged, truth).rmse_position_m:.1f} cm"
        )
    assert merged_slam is not None
    saved = {
        i: MapPrior(m.T_map_marker, m.relative_covariance) for i, m in merged_slam.markers.items()
    }
    third = simulate_fast(world, route, seed=3, duration_s=seconds)
    print_localisation("third session", localize(frames_of(third), mounts[0], saved), third)
    markers = list(world.markers)
    index = next(i for i, m in enumerate(markers) if m.id == MOVED_ID)
    markers[index] = dataclasses.replace(
        markers[index], position_m=markers[index].position_m + MOVED_BY_M
    )
    moved_world = dataclasses.replace(world, markers=tuple(markers))
    fourth = simulate_fast(moved_world, route, seed=4, duration_s=seconds)
    print_localisation(
        f"marker {MOVED_ID} moved {100 * MOVED_BY_M:.0f} cm",
        localize(frames_of(fourth), mounts[0], saved),
        fourth,
    )


if __name__ == "__main__":
    main()
