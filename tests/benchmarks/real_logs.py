"""Every method on TagSLAM's real recordings, against TagSLAM's own map after a 2-D rigid
alignment: prints the marker RMSE per method (README, "Real robots' logs").

    python tests/benchmarks/real_logs.py [--data ../shared/data/tagslam-test/tests]
"""

from __future__ import annotations

import argparse
import math
import tempfile
from pathlib import Path

import markergraph as mg
from markergraph.datasets.tagslam import reference_wall_tags, settings_for, unpacked
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


if __name__ == "__main__":
    main()
