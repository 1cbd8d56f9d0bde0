"""Every method on TagSLAM's real recordings, against TagSLAM's own map after a 2-D rigid
alignment: prints the marker RMSE per method, and the observations' range and theta errors
against TagSLAM's path and map with their sigmas' honesty (README, "Real robots' logs").

    python tests/benchmarks/real_logs.py [--data ../shared/data/tagslam-test/tests]
"""

from __future__ import annotations

import argparse
import math
import tempfile
from pathlib import Path

import numpy as np

import markergraph as mg
from markergraph.datasets.tagslam import (
    observation_errors,
    odometry_and_reference,
    reference_wall_tags,
    settings_for,
    unpacked,
)
from markergraph.estimator import map_error

SIZES = {"test_21": 0.16, "test_22": 0.42}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = Path(__file__).resolve().parents[3] / "shared" / "data" / "tagslam-test" / "tests"
    parser.add_argument("--data", type=Path, default=default)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        for test, size in SIZES.items():
            folder = args.data / test
            config = mg.MapConfig.from_values(settings_for(folder, marker_size=size))
            run = mg.map_log(unpacked(folder, "tag_detections", Path(scratch)), config)
            reference = reference_wall_tags(unpacked(folder, "reference", Path(scratch)))
            print(f"{test}: {len(reference)} wall tags in TagSLAM's map")
            for result in run.results:
                error = map_error(result.estimate, reference, align=True)
                yaw_deg = math.degrees(error.rmse_yaw_rad)
                print(
                    f"  {result.label:<13} {len(result.estimate.markers):>3} tags  RMSE "
                    f"{100 * error.rmse_position_m:5.1f} cm  yaw {yaw_deg:4.1f} deg  "
                    f"converged {result.estimate.converged}"
                )
            _, path = odometry_and_reference(folder, Path(scratch))
            errors = observation_errors(run.extraction.observations, path, reference)
            range_error, theta_error, sigma_range, sigma_theta, range_m = errors.T
            print(
                f"  {len(errors)} observations of those tags: range error "
                f"{100 * np.median(np.abs(range_error) / range_m):.2f} % median, theta error "
                f"{math.degrees(np.median(np.abs(theta_error))):.2f} deg median, "
                f"{math.degrees(np.percentile(np.abs(theta_error), 90)):.2f} deg p90"
            )
            for name, z in (
                ("range", range_error / sigma_range),
                ("theta", theta_error / sigma_theta),
            ):
                print(
                    f"  {name} error / sigma: median |z| {np.median(np.abs(z)):.2f} (0.67 if "
                    f"honest), within 2 sigma {100 * np.mean(np.abs(z) < 2):.0f} % (95)"
                )


if __name__ == "__main__":
    main()
