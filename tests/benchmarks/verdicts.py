"""Can a user tell a right map from a wrong one? Traps and clean logs through `markergraph map`.

Every log is rendered by the simulator (ideal, or with a D435i's effects on a differential
drive); each trap is one of them with one fault put in
(or one wrong flag); each is mapped by the command a user runs, in its own process, and scored
against the simulator's truth. It prints:

- for each trap, SLAM's marker error (in the home marker's frame) against the same log's clean
  map, and whether the map came out right, was flagged (a verdict other than ok, or one clear
  error line), or was wrong without a word;
- for each clean log, every method's verdict (SLAM's must be ok);
- each method's share of true markers inside its 95 % ellipse over the clean logs.

    python tests/benchmarks/verdicts.py [--work DIR] [--full]

``--full`` adds the 8-minute corridor loop of seed 1 (about 4 minutes more), where the paper's
marker graph once collapsed to 5 m.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gtsam
import numpy as np

from markergraph.datasets import scenario, write_log
from markergraph.datasets.rewrite import rewrite_log
from markergraph.datasets.samples import SAMPLES, sample_log
from markergraph.datasets.sensors import D435I_ON_DIFF_DRIVE, SensorEffects
from markergraph.estimator.evidence import position_covariance

CHI2_95_2DOF = 5.991
RIGHT_WITHIN_M = 0.05  # a trap's map is right when it is this close to the clean map's error
CLEAN = (  # scenario, seed, seconds, a D435i's effects: seeds no test or tuning used
    ("paper-room", 21, 60.0, False),
    ("office", 22, 60.0, False),
    ("corridor-loop", 23, 90.0, False),
    ("paper-room", 24, 60.0, True),
    ("office", 25, 60.0, True),
    ("warehouse", 26, 90.0, True),
)
TRAP_LOG = ("paper-room", 21, 60.0, False)  # the clean log most traps are made from
WAREHOUSE = ("warehouse", 26, 90.0, True)  # its markers are DICT_4X4_250


@dataclass(frozen=True)
class Trap:
    name: str
    change: Callable[[str, int, Any], Any] | None = None
    flags: tuple[str, ...] = ()
    base: tuple[str, int, float, bool] = TRAP_LOG


def _late_odometry(seconds: float, index: int) -> Callable[[str, int, Any], Any]:
    def change(topic: str, i: int, message: Any) -> Any:
        if topic == "/odom" and i == index:
            message.header.stamp.sec += int(seconds)
        return message

    return change


def _first_camera_info(edit: Callable[[Any], None]) -> Callable[[str, int, Any], Any]:
    def change(topic: str, i: int, message: Any) -> Any:
        if topic.endswith("color/camera_info") and i == 0:
            edit(message)
        return message

    return change


def _distortion(message: Any) -> None:
    message.d = [1e30] * len(message.d)


def _focal(message: Any) -> None:
    k = list(message.k)
    k[0] = k[4] = 1e300
    message.k = k


TRAPS = (
    Trap("one /odom stamp 1000 s late", _late_odometry(1000.0, 300)),
    Trap("the first /odom stamp 5 s late", _late_odometry(5.0, 0)),
    Trap("first camera_info: distortion 1e30", _first_camera_info(_distortion)),
    Trap("first camera_info: focal length 1e300", _first_camera_info(_focal)),
    Trap("--marker-size 0.15 (markers are 0.20)", flags=("--marker-size", "0.15")),
    Trap("warehouse read as DICT_4X4_50 (is _250)", flags=("--dictionary", "DICT_4X4_50"),
         base=WAREHOUSE),
)  # fmt: skip


def simulate(name: str, seed: int, seconds: float | None, d435i: bool, work: Path) -> Path:
    """A rendered log (``seconds`` None: the whole route; 0: the bundled sample)."""
    if seconds == 0:
        return sample_log(name)
    length = "whole" if seconds is None else f"{seconds:.0f}s"
    log = work / f"{name}-{seed}-{length}{'-d435i' if d435i else ''}.mcap"
    if not log.exists():
        world, route = scenario(name)
        effects = D435I_ON_DIFF_DRIVE if d435i else SensorEffects()
        write_log(world, route, log, seed, duration_s=seconds, compressed=True, sensors=effects)
    return log


def dictionary_of(name: str) -> str:
    world, _ = scenario(name)
    return world.markers[0].dictionary


def map_log(log: Path, out: Path, *flags: str) -> tuple[int, str, dict[str, Any] | None]:
    """`markergraph map` in its own process: exit code, its error line, report.json."""
    command = ["markergraph", "map", str(log), "--out", str(out), "--force", "--no-plots", "-q"]
    run = subprocess.run([*command, *flags], capture_output=True, text=True)
    report = out / "report.json"
    error = run.stderr.strip().splitlines()[-1] if run.returncode else ""
    return run.returncode, error, json.loads(report.read_text()) if run.returncode == 0 else None


def true_markers(name: str, home_id: int) -> dict[int, gtsam.Pose2]:
    world, _ = scenario(name)
    T_home_world = world.T_world_marker(home_id).inverse()
    return {m.id: T_home_world.compose(world.T_world_marker(m.id)) for m in world.markers}


def coverage(map_json: Path, truth: dict[int, gtsam.Pose2]) -> tuple[int, int]:
    """(markers inside their 95 % ellipse, markers with an ellipse), the home marker aside; a
    marker the world does not hold is outside."""
    document = json.loads(map_json.read_text())
    inside = total = 0
    for marker in document["markers"]:
        if marker["id"] == document["home_id"] or marker.get("covariance") is None:
            continue
        total += 1
        if marker["id"] not in truth:  # a marker the world does not hold: a misread id
            continue
        S = position_covariance(marker["yaw"], np.array(marker["covariance"]))
        error = truth[marker["id"]].translation() - np.array([marker["x"], marker["y"]])
        inside += bool(error @ np.linalg.solve(S, error) <= CHI2_95_2DOF)
    return inside, total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, default=None, help="keep logs and maps here")
    parser.add_argument("--full", action="store_true", help="add the full corridor loop")
    args = parser.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="markergraph-verdicts-"))
    work.mkdir(parents=True, exist_ok=True)
    sample = ("corridor-loop", SAMPLES["corridor-loop"][1], 0.0, False)
    clean = [sample, *CLEAN] + ([("corridor-loop", 1, None, False)] if args.full else [])

    print("clean logs (--method all): each method's verdict, marker RMSE in the home frame")
    covered: dict[str, list[int]] = {}  # method -> inside, total; and the same where ok
    clean_error: dict[Path, float] = {}
    for name, seed, seconds, d435i in clean:
        log = simulate(name, seed, seconds, d435i, work)
        out = work / f"map-{log.stem}"
        code, error, report = map_log(
            log, out, "--method", "all", "--dictionary", dictionary_of(name)
        )
        if report is None:
            print(f"  {log.name}: exit {code}: {error}")
            continue
        truth = true_markers(name, json.loads((out / "map.json").read_text())["home_id"])
        cells = []
        for method, entry in report["methods"].items():
            cells.append(f"{method} {entry['verdict']} {100 * entry['marker_rmse_m']:.1f} cm")
            inside, total = coverage(out / "methods" / method / "map.json", truth)
            ok = entry["verdict"] == "ok"
            tally = covered.setdefault(method, [0, 0, 0, 0])
            tally[0] += inside
            tally[1] += total
            tally[2] += inside if ok else 0
            tally[3] += total if ok else 0
        clean_error[log] = report["methods"]["slam"]["marker_rmse_m"]
        slam_ok = report["methods"]["slam"]["verdict"] == "ok"
        print(f"  {log.name:<28} SLAM {'ok' if slam_ok else 'NOT OK'}: {'; '.join(cells)}")
        for reason in report["verdict_reasons"]:
            print(f"      - {reason}")

    print("\neach method's true markers inside its 95 % ellipse: over every clean log, and over")
    print("the maps whose verdict is ok")
    for method, (inside, total, inside_ok, total_ok) in covered.items():
        every = f"{inside:>3} of {total:<3} {100 * inside / total if total else math.nan:5.1f} %"
        where_ok = inside_ok / total_ok if total_ok else math.nan
        print(f"  {method:<13} {every}   {inside_ok:>3} of {total_ok:<3} {100 * where_ok:5.1f} %")

    print("\ntraps (SLAM): marker RMSE in the home frame, against the clean log's")
    for n, trap in enumerate(TRAPS):
        base = simulate(*trap.base, work)
        log = base
        if trap.change is not None:
            log = work / f"trap-{n}.mcap"
            if not log.exists():
                rewrite_log(base, log, trap.change)
        flags = ("--dictionary", dictionary_of(trap.base[0]), *trap.flags)  # the trap's last
        code, error, report = map_log(log, work / f"map-trap-{n}", *flags)
        clean_m = clean_error.get(base, math.nan)
        if report is None:
            outcome, figure = f"flagged: exit {code}: {error}", "-"
        else:
            rmse = report["methods"]["slam"]["marker_rmse_m"]
            figure = f"{100 * rmse:.1f} cm (clean {100 * clean_m:.1f})"
            right = abs(rmse - clean_m) <= RIGHT_WITHIN_M
            verdict = report["methods"]["slam"]["verdict"]
            outcome = (
                "right" + (f", verdict {verdict}" if verdict != "ok" else "")
                if right
                else (f"flagged ({verdict})" if verdict != "ok" else "WRONG WITHOUT A WORD")
            )
        print(f"  {trap.name:<40} {figure:<24} {outcome}")
        if report is not None:
            for reason in report["methods"]["slam"]["verdict_reasons"]:
                print(f"      - {reason}")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
