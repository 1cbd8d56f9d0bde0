"""Odometry noise models against real data: basalt's VIO (TagSLAM test 21) and a T265 (test 22)
against TagSLAM's optimised path of the same body, over stretches of several lengths: the RMS
error, the model fitted to it, and the mean NEES of each preset (3 when the model is honest).

    python tests/benchmarks/odometry_noise.py [--data ../shared/data/tagslam-test/tests]
"""

from __future__ import annotations

import argparse
import math
import tempfile
from pathlib import Path

import numpy as np

from markergraph.datasets.tagslam import odometry_and_reference
from markergraph.estimator import (
    ODOMETRY_NOISE,
    fit_odometry_noise,
    odometry_nees,
    odometry_stretches,
)

TESTS = {"test_21": "basalt VIO", "test_22": "T265"}
STRETCHES_M = (0.25, 0.5, 1.0, 2.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = Path(__file__).resolve().parents[3] / "shared" / "data" / "tagslam-test" / "tests"
    parser.add_argument("--data", type=Path, default=default)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        for test, source in TESTS.items():
            odometry, reference = odometry_and_reference(args.data / test, Path(scratch))
            breaks = [t for t, _ in odometry.jumps()]
            print(f"{test} ({source}): {len(odometry)} odometry samples, {len(breaks)} jumps")
            for length in STRETCHES_M:
                stretches = odometry_stretches(odometry, reference, length, breaks)
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


if __name__ == "__main__":
    main()
