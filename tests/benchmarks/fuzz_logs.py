"""Fuzz the log readers through the commands a user runs: seeded damaged copies of a small
simulated MCAP, a ROS 1 bag (plain and lz4) and a rosbag2 SQLite bag, each run through
``markergraph info`` and ``markergraph map``, checked for what README promises of bad input.

    python tests/benchmarks/fuzz_logs.py [--cases 160] [--seed 0] [--work DIR] [--jobs 2]

Each case must end with exit 0 or 1 (never 2, a crash), within the time limit, with no
traceback, an error in one line, no hidden or partial folder, and a result folder that is whole
(map.json strict JSON) or absent; the worker processes' peak memory must stay under 1 GB. The
cases run in worker processes that import markergraph once (a fresh process per case would
spend most of the time starting); a worker that dies or hangs is named with the case it was
running, and a new worker goes on from the next case. ``MARKERGRAPH_FUZZ_CASES`` sets the
default number of cases. Prints one line per failing case and a summary; with ``--json``, the
summary as JSON (tests/test_fuzz.py reads it). Exit 1 when any case fails.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

CASE_SECONDS = 60  # a case that runs longer has hung (an undamaged one takes about 1 s)
PEAK_LIMIT_MB = 1024
MAP_FLAGS = ["--workers", "1", "--no-plots", "--camera-delay", "0", "--odometry-scale", "1"]


def make_bases(work: Path) -> list[Path]:
    """The undamaged logs: 8 s of the paper room (24 JPEG frames with depth, 20 Hz odometry) as
    MCAP, and converted by rosbags to a ROS 1 bag (plain and lz4) and a SQLite rosbag2 folder."""
    from rosbags.convert.converter import convert
    from rosbags.typesys import Stores, get_typestore

    from markergraph.datasets import scenario, write_log

    work.mkdir(parents=True, exist_ok=True)
    mcap = work / "room.mcap"
    if not mcap.exists():
        world, route = scenario("paper-room")
        write_log(world, route, mcap, seed=3, duration_s=8.0, compressed=True, frame_hz=3.0,
                  odometry_hz=20.0)  # fmt: skip
    bases = [mcap]
    ros2, ros1 = get_typestore(Stores.ROS2_HUMBLE), get_typestore(Stores.ROS1_NOETIC)
    for target, compression in ((work / "room.bag", None), (work / "room-lz4.bag", "lz4"),
                                (work / "room_db3", None)):  # fmt: skip
        if not target.exists():
            storage, store = ("sqlite3", None) if target.suffix != ".bag" else ("", ros1)
            with contextlib.redirect_stdout(io.StringIO()):  # rosbags' notes on types copied
                convert([mcap], target, storage, 8, compression, "file", ros2, store,
                        [], [], [], [])  # fmt: skip
        bases.append(target)
    return bases


def cases(bases: list[Path], count: int, seed: int) -> list[dict[str, Any]]:
    """``count`` cases, the formats and damage kinds taken in turn."""
    from markergraph.datasets.damage import DAMAGE_KINDS

    return [
        {
            "id": i,
            "base": str(bases[i % len(bases)]),
            "kind": DAMAGE_KINDS[(i // len(bases)) % len(DAMAGE_KINDS)],
            "seed": seed * 100_000 + i,
        }
        for i in range(count)
    ]


class _Hung(BaseException):
    """A case ran past its time (BaseException: nothing of ours may swallow it)."""


def _on_alarm(signum: int, frame: Any) -> None:
    raise _Hung


def _command(arguments: list[str]) -> tuple[int | str, str]:
    """One markergraph command in this process: its exit code (or why it broke) and stderr."""
    from markergraph.cli import main

    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            code: int | str = main(arguments)
    except _Hung:
        code = "hung"
    except SystemExit as exit_:
        code = exit_.code if isinstance(exit_.code, int) else 1
    except BaseException as error:  # a crash past main's own handlers
        code = f"raised {error!r}"
    return code, err.getvalue()


def _problems(command: str, code: int | str, err: str, path: Path) -> list[str]:
    """What a command's ending breaks of README's promises (``info`` exits 3 on a log it
    finds cannot be mapped)."""
    found = []
    if code not in ((0, 1, 3) if command == "info" else (0, 1)):
        found.append(f"exit {code}: {err.strip()[-300:]!r}")
    if "Traceback" in err:
        found.append("a traceback")
    if code == 1:
        errors = [line for line in err.splitlines() if not line.startswith(("note:", "  "))]
        if len(errors) != 1:
            found.append(f"{len(errors)} error lines: {errors[:3]!r}")
        elif path.name not in errors[0]:
            found.append(f"the error does not name the log: {errors[0]!r}")
        elif errors[0].rstrip().endswith((":", "()", ": )")):
            found.append(f"the error gives no reason: {errors[0]!r}")
    return found


def _output_problems(code: int | str, out: Path) -> list[str]:
    """A result folder whole (strict JSON) after exit 0, absent otherwise; nothing hidden."""
    found = [f"left {p.name}" for p in out.parent.iterdir() if p.name.startswith(".")]
    if code == 0:
        try:
            json.loads((out / "map.json").read_text(), parse_constant=_refuse)
        except (OSError, ValueError) as error:
            found.append(f"map.json not whole strict JSON ({error})")
    elif out.exists():
        found.append("a result folder after a failure")
    return found


def _refuse(name: str) -> None:
    raise ValueError(f"{name} in JSON")


def run_case(case: dict[str, Any], scratch: Path) -> dict[str, Any]:
    """One case: the damaged copy made, ``info`` and ``map`` run on it, their endings checked."""
    from markergraph.datasets.damage import damage_log

    base = Path(case["base"])
    folder = scratch / f"case{case['id']}"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    damaged = damage_log(base, folder / base.name, case["kind"], case["seed"])
    result: dict[str, Any] = {**case, "what": damaged.what, "problems": []}
    start = time.perf_counter()
    for name, arguments in (
        ("info", ["info", str(damaged.path)]),
        ("map", ["map", str(damaged.path), "--out", str(folder / "out"), *MAP_FLAGS]),
    ):
        signal.alarm(CASE_SECONDS)
        code, err = _command(arguments)
        signal.alarm(0)
        result[name] = code
        result[f"{name}_error"] = err.strip().splitlines()[-1] if code and err.strip() else ""
        if name == "info":
            result["can_map"] = "can map: yes" in err or None
        result["problems"] += [f"{name}: {p}" for p in _problems(name, code, err, damaged.path)]
    result["problems"] += [f"map: {p}" for p in _output_problems(result["map"], folder / "out")]
    result["seconds"] = round(time.perf_counter() - start, 2)
    result["peak_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
    shutil.rmtree(folder, ignore_errors=True)
    return result


def worker(case_file: Path, scratch: Path) -> None:
    """Run the cases of a file, one JSON line as each starts and one as each ends."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    signal.signal(signal.SIGALRM, _on_alarm)
    for case in json.loads(case_file.read_text()):
        print(json.dumps({"start": case["id"]}), flush=True)
        print(json.dumps(run_case(case, scratch)), flush=True)


def run_all(todo: list[dict[str, Any]], work: Path, jobs: int) -> list[dict[str, Any]]:
    """Every case through worker processes; a worker that dies or hangs costs its case only."""
    results: dict[int, dict[str, Any]] = {}
    shares = [todo[j::jobs] for j in range(jobs)]
    running: list[tuple[subprocess.Popen[str], list[dict[str, Any]], Path]] = []
    for j, share in enumerate(shares):
        if share:
            running.append(_start(share, work / f"worker{j}"))
    while running:
        process, share, scratch = running.pop(0)
        started, peak = _collect(process, results)
        left = [c for c in share if c["id"] not in results]
        if left:  # the worker died or hung in the case it started last
            broken = next(c for c in left if c["id"] == started) if started is not None else left[0]
            results[broken["id"]] = {**broken, "problems": [f"worker ended ({process.returncode})"]}
            left = [c for c in left if c["id"] != broken["id"]]
            if left:
                running.append(_start(left, scratch))
        for case_id in (c["id"] for c in share if c["id"] in results):
            results[case_id].setdefault("worker_peak_mb", peak)
    return [results[c["id"]] for c in todo]


def _start(share: list[dict[str, Any]], scratch: Path) -> tuple[subprocess.Popen[str], Any, Path]:
    scratch.mkdir(parents=True, exist_ok=True)
    case_file = scratch / "cases.json"
    case_file.write_text(json.dumps(share))
    process = subprocess.Popen(
        [sys.executable, __file__, "--worker", str(case_file), "--work", str(scratch)],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        start_new_session=True,
    )
    return process, share, scratch


def _collect(process: subprocess.Popen[str], results: dict[int, Any]) -> tuple[int | None, int]:
    """A worker's results read to its end (killed if a case outlives its limit): the case it
    started last, and its peak memory [MB]."""
    import selectors

    started, deadline = None, time.monotonic() + 2 * CASE_SECONDS + 30
    assert process.stdout is not None
    selector = selectors.DefaultSelector()
    selector.register(process.stdout, selectors.EVENT_READ)
    while True:
        if not selector.select(timeout=max(deadline - time.monotonic(), 0)):
            os.killpg(process.pid, signal.SIGKILL)
            break
        line = process.stdout.readline()
        if not line:
            break
        record = json.loads(line)
        if "start" in record:
            started, deadline = record["start"], time.monotonic() + 2 * CASE_SECONDS + 30
        else:
            results[record["id"]] = record
    _, status, usage = os.wait4(process.pid, 0)
    process.returncode = os.waitstatus_to_exitcode(status)
    return started, round(usage.ru_maxrss / 1024)


def summary(results: list[dict[str, Any]], seconds: float) -> dict[str, Any]:
    failed = [r for r in results if r["problems"]]
    return {
        "cases": len(results),
        "failed": len(failed),
        "seconds": round(seconds, 1),
        "peak_mb": max(r.get("worker_peak_mb", r.get("peak_mb", 0)) for r in results),
        "map_exits": dict(Counter(str(r.get("map")) for r in results)),
        "info_can_map_but_map_failed": sum(
            1 for r in results if r.get("can_map") and r.get("map") == 1
        ),
        "by_kind": dict(Counter(r["kind"] for r in failed)),
        "failures": [
            {k: r.get(k) for k in ("id", "base", "kind", "seed", "what", "problems")}
            for r in failed
        ],
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    default_cases = int(os.environ.get("MARKERGRAPH_FUZZ_CASES", "160"))
    parser.add_argument("--cases", type=int, default=default_cases)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--work", type=Path, default=Path("/tmp/markergraph-fuzz"))
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    parser.add_argument("--worker", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(args.worker, args.work)
        return 0
    start = time.perf_counter()
    todo = cases(make_bases(args.work / "bases"), args.cases, args.seed)
    results = run_all(todo, args.work, args.jobs)
    report = summary(results, time.perf_counter() - start)
    (args.work / "results.json").write_text(json.dumps(results, indent=1))
    if args.json:
        print(json.dumps(report))
    else:
        for failure in report["failures"]:
            print(f"case {failure['id']} {Path(failure['base']).name} {failure['kind']} "
                  f"({failure['what']}): {'; '.join(failure['problems'])}")  # fmt: skip
        print(f"{report['cases']} cases in {report['seconds']} s, {report['failed']} failed; "
              f"peak {report['peak_mb']} MB; map exits {report['map_exits']}; "
              f"info said 'can map: yes' where map failed: "
              f"{report['info_can_map_but_map_failed']}")  # fmt: skip
    return 1 if report["failed"] else 0


if __name__ == "__main__":
    sys.exit(main())
