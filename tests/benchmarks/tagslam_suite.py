"""TagSLAM's own regression suite (``../shared/data/tagslam-test``) through `markergraph map`.

Each test's detections bag is mapped in 3-D by the command a user runs, in its own process, with
the test's Kalibr cameras, TagSLAM camera poses and tagslam.yaml as settings. Per test it prints:
the detection frames in the bag, the tags in TagSLAM's reference and those we mapped, our tags'
position error against TagSLAM's after a rigid 3-D alignment fitted on the positions (median and
max, cm), their rotation error (median, deg), the wall-clock seconds of the whole process, and
the exit code (with the first line of stderr when the map could not be made). Tests 21 and 22,
which have odometry, are also mapped in 2-D as before (wall tags against TagSLAM's, aligned in
the plane).

    python tests/benchmarks/tagslam_suite.py [--work DIR] [--tests 1,2,21] [--json FIGURES.json]
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import gtsam
import numpy as np

from markergraph.datasets import tagslam
from markergraph.estimator.tags3d import R_TAG_MARKER
from markergraph.frontend import open_log
from markergraph.frontend.decode import stamp_ns
from markergraph.frontend.rig import read_kalibr_cameras
from markergraph.markermap import MarkerMap

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "tagslam-test" / "tests"
TESTS_2D = ("test_21", "test_22")
"""The tests with odometry, also mapped in 2-D as before the 3-D map."""
EXIT_MAPPED = (0, 4)
"""`markergraph map`'s exit codes that leave a map (4: a method's verdict is not ok)."""


@dataclass
class Row:
    """One test's figures in one dimension (None where not measured)."""

    test: str
    dimensions: int
    exit_code: int
    seconds: float
    frames: int
    reference_tags: int
    mapped_tags: int | None = None
    common_tags: int | None = None
    median_cm: float | None = None
    max_cm: float | None = None
    median_rotation_deg: float | None = None
    error: str | None = None
    source: str = "--dimensions 2"
    """What made a 2-D row: the 2-D estimators, or the wall tags of the 3-D map."""

    def line(self) -> str:
        """The row as one printed line."""
        head = (
            f"{self.test:<8} {self.dimensions}-D"
            + (f" ({self.source})" if self.dimensions == 2 else "")
            + f" exit {self.exit_code} {self.seconds:6.1f} s "
            f"{self.frames:5d} frames; TagSLAM {self.reference_tags:3d} "
            f"{'tags' if self.dimensions == 3 else 'wall tags'}"
        )
        if self.error is not None:
            return f"{head}  {self.error}"
        share = 100 * (self.common_tags or 0) / max(self.reference_tags, 1)
        line = f"{head}, we map {self.mapped_tags:3d} ({self.common_tags} of its, {share:.0f} %)"
        if self.median_cm is None:
            return line
        angle = "rotation" if self.dimensions == 3 else "yaw"
        return (
            f"{line}; {self.median_cm:.1f} cm median, {self.max_cm:.1f} cm max, "
            f"{angle} {self.median_rotation_deg:.2f} deg median"
        )


def detection_frames(folder: Path, bag: Path) -> int:
    """The bag's detection frames: distinct header stamps over the cameras' tag topics."""
    topics = [c.tag_topic for c in read_kalibr_cameras(folder / "cameras.yaml") if c.tag_topic]
    return len({stamp_ns(m.decoded) for m in open_log(bag).messages(topics)})


def run_map(folder: Path, bag: Path, out: Path, dimensions: int) -> tuple[int, float, str]:
    """`markergraph map` on one test: its exit code, seconds, and stderr's first line."""
    # The flags a TagSLAM user gives: the test's rig files and its tag family.
    command = [sys.executable, "-m", "markergraph.cli", "map", str(bag),
               "--dictionary", "DICT_APRILTAG_36h11", "--cameras", str(folder / "cameras.yaml"),
               "--camera-poses", str(folder / "camera_poses.yaml"),
               "--tagslam", str(folder / "tagslam.yaml"),
               "--out", str(out), "--force", "--no-plots", "-q"]  # fmt: skip
    command += (
        ["--dimensions", "3"] if dimensions == 3 else ["--dimensions", "2", "--method", "all"]
    )
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    lines = (done.stderr.strip() or done.stdout.strip()).splitlines()
    if lines and lines[0].startswith("usage:"):  # argparse's: its last line says what was wrong
        lines = [line for line in lines if "error:" in line] or lines
    return done.returncode, seconds, lines[0] if lines else "(no message)"


def tags_3d(map_json: Path) -> dict[int, gtsam.Pose3]:
    """The 3-D tags of a map.json (entries with a ``quaternion`` of T_map_marker), each turned
    to the tag frame (T_map_tag = T_map_marker * R_TAG_MARKER^T)."""
    to_tag = gtsam.Pose3(gtsam.Rot3(R_TAG_MARKER.T), np.zeros(3))
    tags = {}
    for entry in json.loads(map_json.read_text())["markers"]:
        if entry.get("quaternion") is None:
            continue
        w, x, y, z = entry["quaternion"]
        T_map_marker = gtsam.Pose3(
            gtsam.Rot3.Quaternion(w, x, y, z), np.array([entry["x"], entry["y"], entry["z"]])
        )
        tags[int(entry["id"])] = T_map_marker.compose(to_tag)
    return tags


def scored_3d(row: Row, out: Path, reference: dict[int, gtsam.Pose3]) -> Row:
    """The row with our 3-D tags scored against TagSLAM's."""
    ours = tags_3d(out / "map.json")
    row.mapped_tags, row.common_tags = len(ours), len(set(ours) & set(reference))
    if row.common_tags >= 2:
        _, position, rotation = tagslam.aligned_errors_3d(ours, reference)
        row.median_cm = 100 * float(np.median(position))
        row.max_cm = 100 * float(position.max())
        row.median_rotation_deg = math.degrees(float(np.median(rotation)))
    return row


def scored_2d(row: Row, out: Path, reference_bag: Path) -> Row:
    """The row with our 2-D wall tags scored against TagSLAM's wall tags (as before)."""
    walls = tagslam.reference_wall_tags(reference_bag)
    marker_map = MarkerMap.load(out / "map.json")
    ours = {i: m.T_map_marker for i, m in marker_map.markers.items()}
    row.reference_tags = len(walls)
    row.mapped_tags, row.common_tags = len(ours), len(set(ours) & set(walls))
    if row.common_tags >= 2:
        error = tagslam.aligned_errors(ours, walls)
        row.median_cm = 100 * float(np.median(error.position_m))
        row.max_cm = 100 * float(error.position_m.max())
        row.median_rotation_deg = math.degrees(float(np.median(error.yaw_rad)))
    return row


def run_test(folder: Path, work: Path, dimensions: int) -> Row:
    """One test mapped in ``dimensions`` and scored."""
    bag = tagslam.unpacked(folder, "tag_detections", work)
    reference_bag = tagslam.unpacked(folder, "reference", work)
    reference = tagslam.reference_tags_3d(reference_bag)
    out = work / f"map-{folder.name}-{dimensions}d"
    code, seconds, first_line = run_map(folder, bag, out, dimensions)
    row = Row(folder.name, dimensions, code, seconds, detection_frames(folder, bag), len(reference))
    if code not in EXIT_MAPPED or not (out / "map.json").is_file():
        row.error = first_line
        return row
    if dimensions == 3:
        return scored_3d(row, out, reference)
    return scored_2d(row, out, reference_bag)


def walls_of_3d(row_3d: Row, folder: Path, work: Path) -> Row:
    """The 3-D run's wall tags (map.json's ``markers``, the 2-D map ``markergraph map`` gives
    by default for a log of detections) scored in 2-D against TagSLAM's wall tags."""
    row = Row(row_3d.test, 2, row_3d.exit_code, row_3d.seconds, row_3d.frames, 0,
              source="walls of the 3-D map")  # fmt: skip
    return scored_2d(
        row, work / f"map-{folder.name}-3d", tagslam.unpacked(folder, "reference", work)
    )


def chosen(tests: list[str] | None) -> list[Path]:
    """The test folders to run, in number order: all, or those named (``1,2`` or ``test_1``)."""
    wanted = {
        name if name.startswith("test_") else f"test_{name}"
        for item in tests or []
        for name in item.replace(",", " ").split()
    }
    folders = [f for f in DATA.iterdir() if f.is_dir() and (not wanted or f.name in wanted)]
    missing = wanted - {f.name for f in folders}
    if missing:
        sys.exit(f"no such test in {DATA}: {', '.join(sorted(missing))}")
    return sorted(folders, key=lambda f: int(f.name.split("_")[1]))


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--work", type=Path, help="keep the unpacked bags and maps here")
    parser.add_argument("--tests", nargs="*", help="only these tests: 1,2,21 (default: all)")
    parser.add_argument("--json", type=Path, help="also write the figures to this JSON file")
    arguments = parser.parse_args()
    if not DATA.is_dir():
        sys.exit(f"{DATA} is absent: this benchmark reads TagSLAM's shared test suite")
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as scratch:
        work = arguments.work or Path(scratch)
        work.mkdir(parents=True, exist_ok=True)
        for folder in chosen(arguments.tests):
            for dimensions in (3, 2) if folder.name in TESTS_2D else (3,):
                row = run_test(folder, work, dimensions)
                print(row.line(), flush=True)
                rows.append(asdict(row))
                if dimensions == 3 and folder.name in TESTS_2D and row.error is None:
                    walls = walls_of_3d(row, folder, work)
                    print(walls.line(), flush=True)
                    rows.append(asdict(walls))
    if arguments.json:
        arguments.json.write_text(json.dumps({"tests": rows}, indent=2) + "\n")


if __name__ == "__main__":
    main()
