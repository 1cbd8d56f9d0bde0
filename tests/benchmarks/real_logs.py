"""Every method on TagSLAM's real recordings, against TagSLAM's own map after a 2-D rigid
alignment: prints the marker RMSE per method (README, "Real robots' logs").

    python tests/benchmarks/real_logs.py [--data ../shared/data/tagslam-test/tests]
"""

from __future__ import annotations

import argparse
import bz2
import math
import tempfile
from pathlib import Path

import gtsam

import markergraph as mg
from markergraph.estimator import map_error
from markergraph.frontend import messages

SIZES = {"test_21": 0.16, "test_22": 0.42}


def reference_wall_tags(bag: Path) -> dict[int, gtsam.Pose2]:
    """TagSLAM's tags on /tf whose normal is within 45 degrees of horizontal, as 2-D poses."""
    last = {}
    for message in messages(bag, ["/tf"]):
        for transform in message.decoded.transforms:
            last[transform.child_frame_id] = transform.transform
    tags = {}
    for name, transform in last.items():
        if name.startswith("tag_"):
            q = transform.rotation
            normal = gtsam.Rot3.Quaternion(q.w, q.x, q.y, q.z).matrix()[:, 2]
            if abs(normal[2]) < math.sin(math.radians(45.0)):
                t = transform.translation
                tags[int(name[4:])] = gtsam.Pose2(t.x, t.y, math.atan2(normal[1], normal[0]))
    return tags


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = Path(__file__).resolve().parents[3] / "shared" / "data" / "tagslam-test" / "tests"
    parser.add_argument("--data", type=Path, default=default)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        for test, size in SIZES.items():
            folder = args.data / test
            bags = {}
            for name in ("tag_detections", "reference"):
                bags[name] = Path(scratch) / f"{test}-{name}.bag"
                bags[name].write_bytes(bz2.decompress((folder / f"{name}.bag.bz2").read_bytes()))
            config = mg.MapConfig.from_values(
                {
                    "dictionary": "DICT_APRILTAG_36h11",
                    "marker_size": size,
                    "method": "all",
                    "rig.cameras": str(folder / "cameras.yaml"),
                    "rig.camera_poses": str(folder / "camera_poses.yaml"),
                    "rig.tagslam": str(folder / "tagslam.yaml"),
                }
            )
            run = mg.map_log(bags["tag_detections"], config)
            reference = reference_wall_tags(bags["reference"])
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
