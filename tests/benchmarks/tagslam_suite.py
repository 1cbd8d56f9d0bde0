"""TagSLAM's own regression suite (``../shared/data/tagslam-test``) through `markergraph map`.

Each test's detections bag is mapped by the command a user runs, in its own process, with the
test's Kalibr cameras, TagSLAM camera poses and tagslam.yaml as settings. It prints, per test:
the exit code (and the error line when the map could not be made), the frames read, TagSLAM's
tags, the wall tags in its result and those we mapped, our wall tags' position error against
TagSLAM's after a rigid 2-D alignment (median and max, cm) and their yaw error (median, deg),
and the wall-clock seconds of the whole process.

    python tests/benchmarks/tagslam_suite.py [--work DIR] [--tests test_21 test_22 ...]
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from markergraph.datasets import tagslam
from markergraph.markermap import MarkerMap

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "tagslam-test" / "tests"


def reference_tags(bag: Path) -> int:
    """How many tags TagSLAM placed (every tag frame on its final /tf)."""
    from markergraph.frontend import open_log

    names = {
        transform.child_frame_id
        for message in open_log(bag).messages(["/tf"])
        for transform in message.decoded.transforms
    }
    return sum(name.startswith("tag_") for name in names)


def run_test(folder: Path, work: Path) -> str:
    """One test mapped and scored, as one printed line."""
    bag = tagslam.unpacked(folder, "tag_detections", work)
    reference = tagslam.unpacked(folder, "reference", work)
    out = work / f"map-{folder.name}"
    # The flags a TagSLAM user gives: the test's rig files and its tag family.
    command = [sys.executable, "-m", "markergraph.cli", "map", str(bag), "--method", "all",
               "--dictionary", "DICT_APRILTAG_36h11", "--cameras", str(folder / "cameras.yaml"),
               "--camera-poses", str(folder / "camera_poses.yaml"),
               "--tagslam", str(folder / "tagslam.yaml"),
               "--out", str(out), "--force", "--no-plots", "-q"]  # fmt: skip
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    head = f"{folder.name:<8} exit {done.returncode} {seconds:6.1f} s"
    if done.returncode not in (0, 4):
        lines = (done.stderr.strip() or done.stdout.strip()).splitlines()
        return f"{head}  {lines[-1] if lines else '(no message)'}"
    report = json.loads((out / "report.json").read_text())
    walls = tagslam.reference_wall_tags(reference)
    marker_map = MarkerMap.load(out / "map.json")
    ours = {i: m.T_map_marker for i, m in marker_map.markers.items()}
    common = set(ours) & set(walls)
    line = (
        f"{head}  {report['frames']:5d} frames; TagSLAM {reference_tags(reference):3d} tags, "
        f"{len(walls):3d} on walls; we map {len(ours):3d} ({len(common)} of its wall tags); "
        f"verdict {report['verdict']}"
    )
    if len(common) < 2:
        return line
    error = tagslam.aligned_errors(ours, walls)
    return (
        f"{line}; wall tags {100 * float(np.median(error.position_m)):.1f} cm median, "
        f"{100 * float(error.position_m.max()):.1f} cm max, yaw "
        f"{math.degrees(float(np.median(error.yaw_rad))):.1f} deg median"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, help="keep the unpacked bags and maps here")
    parser.add_argument("--tests", nargs="*", help="only these tests (default: every one)")
    arguments = parser.parse_args()
    if not DATA.is_dir():
        sys.exit(f"{DATA} is absent: this benchmark reads TagSLAM's shared test suite")
    folders = sorted(
        (
            f
            for f in DATA.iterdir()
            if f.is_dir() and (not arguments.tests or f.name in arguments.tests)
        ),
        key=lambda f: int(f.name.split("_")[1]),
    )
    with tempfile.TemporaryDirectory() as scratch:
        work = arguments.work or Path(scratch)
        work.mkdir(parents=True, exist_ok=True)
        for folder in folders:
            print(run_test(folder, work), flush=True)


if __name__ == "__main__":
    main()
