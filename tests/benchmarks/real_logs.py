"""Every method on TagSLAM's real recordings, against TagSLAM's own map and path (README, "Real
robots' logs"). Per recording it prints:

- each method's markers placed (of TagSLAM's wall tags), and their position and yaw RMSE after
  the rigid 2-D alignment fitted on positions alone (a yaw turned round shows as 180 deg); the
  closed form's longest dead-reckoning to a new marker;
- the observations' range and theta errors against TagSLAM's path and map, and how honest their
  sigmas are;
- the odometry's error over stretches of 0.25-2 m of TagSLAM's path, the noise model fitted to
  it, and each preset's mean NEES (3 when honest).

    python tests/benchmarks/real_logs.py [--data ../shared/data/tagslam-test/tests] [--method all]
"""

from __future__ import annotations

import argparse
import math
import tempfile
from pathlib import Path

import gtsam
import numpy as np

import markergraph as mg
from markergraph.datasets.tagslam import (
    aligned_errors,
    observation_errors,
    odometry_and_reference,
    reference_wall_tags,
    settings_for,
    unpacked,
)
from markergraph.estimator import (
    ODOMETRY_NOISE,
    Trajectory,
    fit_odometry_noise,
    odometry_nees,
    odometry_stretches,
)

TESTS = {"test_21": ("basalt VIO", 0.16), "test_22": ("T265", 0.42)}
STRETCHES_M = (0.25, 0.5, 1.0, 2.0)


def print_maps(run: mg.MapRun, reference: dict[int, gtsam.Pose2]) -> None:
    for result in run.results:
        estimate = result.estimate
        error = aligned_errors({i: m.T_map_marker for i, m in estimate.markers.items()}, reference)
        placed = len(set(estimate.markers) & set(reference))
        line = (
            f"  {result.label:<13} {placed:>3}/{len(reference)} wall tags  position RMSE "
            f"{100 * error.rmse_position_m:5.1f} cm  yaw RMSE "
            f"{math.degrees(error.rmse_yaw_rad):5.1f} deg (worst "
            f"{math.degrees(np.max(error.yaw_rad)):5.1f})  converged {estimate.converged}"
        )
        if estimate.placements:
            farthest = max(estimate.placements.values(), key=lambda p: p.dead_reckoned_m)
            line += (
                f"  longest dead-reckoning {farthest.dead_reckoned_m:.2f} m / "
                f"{farthest.dead_reckoned_s:.1f} s (to {farthest.marker_id})"
            )
        print(line)


def print_observations(run: mg.MapRun, path: Trajectory, reference: dict[int, gtsam.Pose2]) -> None:
    errors = observation_errors(run.extraction.observations, path, reference)
    range_error, theta_error, sigma_range, sigma_theta, range_m = errors.T
    print(
        f"  {len(errors)} observations of those tags: range error "
        f"{100 * np.median(np.abs(range_error) / range_m):.2f} % median, theta error "
        f"{math.degrees(np.median(np.abs(theta_error))):.2f} deg median, "
        f"{math.degrees(np.percentile(np.abs(theta_error), 90)):.2f} deg p90"
    )
    for name, z in (("range", range_error / sigma_range), ("theta", theta_error / sigma_theta)):
        print(
            f"  {name} error / sigma: median |z| {np.median(np.abs(z)):.2f} (0.67 if "
            f"honest), within 2 sigma {100 * np.mean(np.abs(z) < 2):.0f} % (95)"
        )


def print_odometry(odometry: Trajectory, path: Trajectory) -> None:
    breaks = [t for t, _ in odometry.jumps()]
    print(f"  odometry: {len(odometry)} samples, {len(breaks)} jumps")
    for length in STRETCHES_M:
        stretches = odometry_stretches(odometry, path, length, breaks)
        errors = np.array([s.error for s in stretches])
        fit = fit_odometry_noise(stretches)
        nees = "  ".join(
            f"{name} {np.mean(odometry_nees(stretches, noise)):6.2f}"
            for name, noise in ODOMETRY_NOISE.items()
        )
        rms_m = np.sqrt(np.mean(errors[:, :2] ** 2))
        rms_deg = math.degrees(np.sqrt(np.mean(errors[:, 2] ** 2)))
        print(
            f"  {length:4.2f} m x {len(stretches):2}: RMS {100 * rms_m:5.2f} cm "
            f"{rms_deg:5.2f} deg | fit "
            f"{100 * fit.per_m:5.2f} cm {math.degrees(fit.yaw_per_m):5.2f} deg/sqrt(m), "
            f"{math.degrees(fit.yaw_per_rad):5.2f} deg/sqrt(rad) | mean NEES {nees}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = Path(__file__).resolve().parents[3] / "shared" / "data" / "tagslam-test" / "tests"
    parser.add_argument("--data", type=Path, default=default)
    parser.add_argument("--method", default="all", help="the estimator(s): as markergraph map's")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        for test, (odometry_source, size) in TESTS.items():
            folder = args.data / test
            config = mg.MapConfig.from_values(
                settings_for(folder, marker_size=size, method=args.method)
            )
            run = mg.map_log(unpacked(folder, "tag_detections", Path(scratch)), config)
            reference = reference_wall_tags(unpacked(folder, "reference", Path(scratch)))
            odometry, path = odometry_and_reference(folder, Path(scratch))
            print(
                f"{test} ({odometry_source}): {len(reference)} wall tags in TagSLAM's map; "
                f"odometry model {run.odometry_source}, camera delay "
                f"{run.camera_delay_ns / 1e6:+.1f} ms, odometry scale {run.odometry_scale:.4f}"
            )
            print_maps(run, reference)
            print_observations(run, path, reference)
            print_odometry(odometry, path)


if __name__ == "__main__":
    main()
