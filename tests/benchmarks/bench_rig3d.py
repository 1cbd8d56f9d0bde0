"""The 3-D estimator's pace on TagSLAM's regression suite (``../shared/data/tagslam-test``), in
milliseconds a rig frame, next to TagSLAM's own published figure.

Per test it prints the rig frames (distinct detection stamps over the cameras' tag topics, as
TagSLAM counts a stereo pair as one frame), the whole `markergraph map --dimensions 3` process
(start-up, reading the bag, the map, writing the folder; plots off), the estimator alone
(``map_tags`` on the scene read once, best of ``--repeats``) and, with ``--reference``, the
same estimator driven through GTSAM's own optimiser over Python factors (the path before the
vectorised solve), run interleaved with it so that their ratio holds under a shared machine's
load. TagSLAM publishes no per-test times: its figure is 15,595 stereo frames in 188 s on an
i9-9900K (about 12 ms a frame, arXiv 1910.00679), printed beside each row for scale.

    python tests/benchmarks/bench_rig3d.py [--tests 1,2] [--repeats 3] [--reference 1,16]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from markergraph.datasets import tagslam
from markergraph.estimator.tag_slam import Solver, map_tags
from markergraph.estimator.tags3d import TagScene
from markergraph.frontend import open_log
from markergraph.frontend.decode import stamp_ns
from markergraph.frontend.rig import read_kalibr_cameras
from markergraph.frontend.survey import read_survey
from markergraph.frontend.tag_scene import read_tag_scene
from markergraph.frontend.topics import choose_topics
from markergraph.settings import MapConfig

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "tagslam-test" / "tests"
TAGSLAM_MS_PER_FRAME = 188_000 / 15_595
"""TagSLAM's published pace: 15,595 stereo frames in 188 s on an i9-9900K (its paper)."""


def frames_of(folder: Path, bag: Path) -> int:
    """The bag's rig frames: distinct header stamps over the cameras' tag topics."""
    topics = [c.tag_topic for c in read_kalibr_cameras(folder / "cameras.yaml") if c.tag_topic]
    return len({stamp_ns(m.decoded) for m in open_log(bag).messages(topics)})


def scene_of(folder: Path, bag: Path) -> TagScene:
    """The test's scene, read as `markergraph map` reads it (its surveyed tags included)."""
    config = MapConfig.from_values(tagslam.settings_for(folder, method="slam"))
    log = open_log(bag)
    choice = choose_topics(log.path, log.topics, config.frontend)
    survey = read_survey(folder / "tagslam.yaml")
    read = read_tag_scene(
        log, config.frontend, choice, list(survey.tags), survey.ignored_ids, None, survey.remaps
    )
    return read.scene


def _compiled_env() -> dict[str, str]:
    """The environment without PYTHONDONTWRITEBYTECODE: a process runs as from an installed
    package, its bytecode compiled once (with it set, as on the machine measured, each process
    compiled about 250 modules again)."""
    return {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}


def process_seconds(folder: Path, bag: Path, out: Path) -> float:
    """The whole `markergraph map` process on one test [s] (it must leave a map)."""
    command = [sys.executable, "-m", "markergraph.cli", "map", str(bag),
               "--dictionary", "DICT_APRILTAG_36h11", "--cameras", str(folder / "cameras.yaml"),
               "--camera-poses", str(folder / "camera_poses.yaml"),
               "--tagslam", str(folder / "tagslam.yaml"), "--dimensions", "3",
               "--out", str(out), "--force", "--no-plots", "-q"]  # fmt: skip
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, check=False, env=_compiled_env())
    seconds = time.perf_counter() - start
    if done.returncode not in (0, 4):  # 4: a verdict that is not ok still leaves a map
        sys.exit(f"{folder.name}: markergraph map failed: {done.stderr.strip()[:300]}")
    return seconds


def estimator_seconds(scene: TagScene, repeats: int, reference: bool) -> tuple[float, float | None]:
    """``map_tags``'s best time [s] over ``repeats`` runs, and (``reference``) the GTSAM-driven
    path's, the two run in turn."""
    fast: list[float] = []
    slow: list[float] = []
    for _ in range(repeats):
        start = time.perf_counter()
        map_tags(scene)
        fast.append(time.perf_counter() - start)
        if reference:
            start = time.perf_counter()
            map_tags(scene, solver=Solver.GTSAM)
            slow.append(time.perf_counter() - start)
    return min(fast), (min(slow) if slow else None)


def chosen(names: str | None) -> list[Path]:
    """Test folders in number order: all, or those named (``1,2``)."""
    folders = sorted(
        (f for f in DATA.iterdir() if f.is_dir()), key=lambda f: int(f.name.split("_")[1])
    )
    if not names:
        return folders
    wanted = {f"test_{n.strip().removeprefix('test_')}" for n in names.split(",")}
    return [f for f in folders if f.name in wanted]


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--tests", help="only these tests: 1,2,21 (default: all)")
    parser.add_argument("--repeats", type=int, default=3, help="estimator runs, best kept")
    parser.add_argument("--reference", default="", help="tests also run the GTSAM-driven way")
    arguments = parser.parse_args()
    if not DATA.is_dir():
        sys.exit(f"{DATA} is absent: this benchmark reads TagSLAM's shared test suite")
    reference = {f"test_{n.strip()}" for n in arguments.reference.split(",") if n.strip()}
    load = os.getloadavg()[0]
    print(f"load average {load:.2f} on {os.cpu_count()} cores; TagSLAM's published pace "
          f"{TAGSLAM_MS_PER_FRAME:.1f} ms a frame (i9-9900K, 15,595 frames)")  # fmt: skip
    warm = "import markergraph.cli._map, markergraph.run3d, markergraph.results3d, scipy.linalg"
    subprocess.run([sys.executable, "-c", warm], check=False, env=_compiled_env())
    print(f"{'test':<8} {'frames':>6} {'process s':>9} {'ms/frame':>8} {'estimator ms/frame':>18} "
          f"{'GTSAM-driven ms/frame':>21} {'speed-up':>8}")  # fmt: skip
    total_frames, total_process = 0, 0.0
    with tempfile.TemporaryDirectory() as scratch:
        work = Path(scratch)
        for folder in chosen(arguments.tests):
            bag = tagslam.unpacked(folder, "tag_detections", work)
            frames = frames_of(folder, bag)
            process = process_seconds(folder, bag, work / f"map-{folder.name}")
            fast, slow = estimator_seconds(
                scene_of(folder, bag), arguments.repeats, folder.name in reference
            )
            total_frames, total_process = total_frames + frames, total_process + process
            slow_text = f"{1000 * slow / frames:21.1f}" if slow is not None else f"{'-':>21}"
            ratio = f"{slow / fast:7.1f}x" if slow is not None else f"{'-':>8}"
            print(f"{folder.name:<8} {frames:6d} {process:9.1f} {1000 * process / frames:8.1f} "
                  f"{1000 * fast / frames:18.1f} {slow_text} {ratio}", flush=True)  # fmt: skip
    print(f"{'all':<8} {total_frames:6d} {total_process:9.1f} "
          f"{1000 * total_process / max(total_frames, 1):8.1f}")  # fmt: skip
    print(f"load average {os.getloadavg()[0]:.2f} at the end")


if __name__ == "__main__":
    main()
