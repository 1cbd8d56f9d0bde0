"""A fleet's day in small: the front end of many simulated warehouse logs, locally and on Ray.

Writes ``--logs`` logs in the warehouse scenario's world (232 markers, DICT_4X4_250) of
``--seconds`` each at 5 Hz with JPEG colour, different seeds, each down one of its seven aisles
between the racks, into a temporary folder; then reads them all with
:func:`markergraph.executors.extract_logs` in one process, in two processes, and as tasks on a
local Ray instance with 2 CPUs, every process with one OpenCV thread (one core's work). Each
executor runs in a fresh Python process of its own, so that its memory peaks are its own:

- driver peak: the process that calls ``extract_logs`` (``ru_maxrss``), holding every result;
- tree peak: the proportional set size (PSS: shared pages split between the processes sharing
  them) of that process and all its descendants, sampled every 0.2 s: local workers, or Ray's
  GCS, raylet and workers;
- result size: the pickled extractions, what travels from the workers to the driver;
- CPU seconds of the whole tree, so that frames per CPU-second, the figure a cluster's size
  follows, holds even when other work shares the machine and the wall time does not.

It also checks that every executor gives the same observations, and times SLAM on the driver on
one log's extraction (the estimation stays on the driver).

Usage: python tests/benchmarks/bench_fleet.py [--logs 20] [--seconds 30]
Set OPENBLAS_NUM_THREADS=1 on a 2-core machine (FACTS.md).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import multiprocessing
import os
import pickle
import resource
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

FRAME_HZ = 5.0
SCENARIO = "warehouse"
RUNS = ("local, 1 process", "local, 2 processes", "ray, 2 CPUs")  # each one OpenCV thread a process
SAMPLE_S = 0.2
CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


AISLES_Y = (3.0, 7.0, 11.0, 15.0, 19.0, 23.0, 27.5)  # the warehouse route's aisles [m]


def write_one(arguments: tuple[Path, int, float]) -> int:
    """One log, down an aisle of its own (the scenario's route would spend a short log by the
    home marker): log k drives aisle k mod 7, east or west by turns; its frame count."""
    from markergraph.datasets import scenario, write_log
    from markergraph.datasets.route import GoTo, Route

    path, seed, seconds = arguments
    world, _ = scenario(SCENARIO)
    y = AISLES_Y[seed % len(AISLES_Y)]
    x0, x1 = (3.0, 37.0) if (seed // len(AISLES_Y)) % 2 == 0 else (37.0, 3.0)
    route = Route(start=(x0, y, 0.0 if x1 > x0 else math.pi), steps=(GoTo(x1, y), GoTo(x0, y)))
    summary = write_log(
        world, route, path, seed=seed, duration_s=seconds, compressed=True, frame_hz=FRAME_HZ
    )
    return summary.frames


def _descendants(root: int) -> list[int]:
    """``root`` and every process below it, from /proc."""
    children: dict[int, list[int]] = {}
    for name in os.listdir("/proc"):
        if not name.isdigit():
            continue
        try:
            with open(f"/proc/{name}/stat") as stat:
                text = stat.read()
        except OSError:
            continue
        ppid = int(text[text.rindex(")") + 2 :].split()[1])
        children.setdefault(ppid, []).append(int(name))
    found, stack = [], [root]
    while stack:
        pid = stack.pop()
        found.append(pid)
        stack += children.get(pid, [])
    return found


def _cpu_s(pid: int) -> float | None:
    """User plus system CPU seconds the process has used so far."""
    try:
        with open(f"/proc/{pid}/stat") as stat:
            text = stat.read()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2 :].split()
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS  # utime, stime


def _pss_bytes(pid: int) -> int:
    try:
        with open(f"/proc/{pid}/smaps_rollup") as rollup:
            for line in rollup:
                if line.startswith("Pss:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


class ProcessTree:
    """This process and its descendants, sampled in a thread: the peak of their summed PSS, and
    the CPU seconds they used meanwhile (each process's last sample less its first; a process
    that ends loses at most one sampling interval)."""

    def __init__(self) -> None:
        self.peak = 0
        self.processes = 0
        self._first: dict[int, float] = {}
        self._last: dict[int, float] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    @property
    def cpu_s(self) -> float:
        return sum(self._last[pid] - self._first[pid] for pid in self._last)

    def _sample(self, start: bool = False) -> None:
        pids = _descendants(os.getpid())
        for pid in pids:
            cpu = _cpu_s(pid)
            if cpu is not None:
                # A process born after the start counts from zero.
                self._first.setdefault(pid, cpu if start else 0.0)
                self._last[pid] = cpu
        total = sum(_pss_bytes(pid) for pid in pids)
        if total > self.peak:
            self.peak, self.processes = total, len(pids)

    def _run(self) -> None:
        while not self._stop.wait(SAMPLE_S):
            self._sample()

    def __enter__(self) -> ProcessTree:
        self._sample(start=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        self._sample()


def digest(extractions: list[Any]) -> str:
    """A hash of every observation's values (NaN-safe through repr)."""
    h = hashlib.sha256()
    for extraction in extractions:
        for o in extraction.observations:
            h.update(repr((o.t_ns, o.marker_id, o.bearing, o.theta, o.range_m)).encode())
        h.update(extraction.odometry.poses.tobytes())
    return h.hexdigest()[:16]


def run_one(run: str, folder: Path) -> dict[str, Any]:
    """One executor over every log in ``folder``, in this (fresh) process."""
    import cv2

    from markergraph.datasets import scenario
    from markergraph.estimator import Method, build_frames, estimate_frames
    from markergraph.executors import extract_logs
    from markergraph.frontend import FrontendConfig, MarkerSizes

    world, _ = scenario(SCENARIO)
    marker = world.markers[0]
    config = FrontendConfig(dictionary=marker.dictionary, marker_sizes=MarkerSizes(marker.size_m))
    logs = sorted(folder.glob("*.mcap"))
    out: dict[str, Any] = {"run": run, "logs": len(logs)}
    # One OpenCV thread in the driver too, as in every worker: each process is one core's work.
    cv2.setNumThreads(1)
    ray: Any = None
    if run.startswith("ray"):
        import ray

        os.environ.setdefault("RAY_AUTH_MODE", "disabled")
        start = time.perf_counter()
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
        out["startup_s"] = time.perf_counter() - start
    out["load_before"] = os.getloadavg()[0]
    with ProcessTree() as tree:
        start = time.perf_counter()
        if run.startswith("ray"):
            results = extract_logs(logs, config, executor="ray")
        else:
            results = extract_logs(logs, config, workers=1 if "1 process" in run else 2)
        out["seconds"] = time.perf_counter() - start
    if ray is not None:
        ray.shutdown()
    out["load_after"] = os.getloadavg()[0]
    out["cpu_s"] = tree.cpu_s
    out["tree_peak_mb"] = tree.peak / 2**20
    out["tree_processes"] = tree.processes
    out["driver_peak_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    out["child_peak_mb"] = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    out["frames"] = sum(r.frames for r in results)
    out["observations"] = sum(len(r.observations) for r in results)
    out["markers_seen"] = len({o.marker_id for r in results for o in r.observations})
    out["result_mb"] = len(pickle.dumps(results)) / 2**20
    out["digest"] = digest(results)
    if run == RUNS[0]:  # the driver's share: every log merged into one map by SLAM
        from markergraph.estimator import OdometryNoise
        from markergraph.estimator.sessions import solve_sessions

        start = time.perf_counter()
        seen = [r for r in results if r.observations]  # a log that saw no marker adds nothing
        frames = [build_frames(r.observations, r.odometry, odometry_noise=OdometryNoise())
                  for r in seen]  # fmt: skip
        home = frames[0].home_id
        merged = solve_sessions(frames, [r.mount.T_base_camera for r in seen])
        out["merge_s"] = time.perf_counter() - start
        out["merge_peak_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        out["merge_markers"] = len(merged.markers)
        out["merge_placed"] = sum(t is not None for t in merged.trajectories)
        single = estimate_frames(
            build_frames(seen[0].observations, seen[0].odometry, home),
            Method.SLAM, seen[0].mount.T_base_camera,
        )  # fmt: skip
        out["single_markers"] = len(single.markers)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", type=int, default=20)
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--run", choices=RUNS, help=argparse.SUPPRESS)  # a child's one run
    parser.add_argument("--folder", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.run:
        print(json.dumps(run_one(args.run, args.folder)))
        return

    print(f"cores: {os.cpu_count()}, OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        jobs = [(folder / f"{SCENARIO}-{seed:03d}.mcap", seed, args.seconds)
                for seed in range(1, args.logs + 1)]  # fmt: skip
        start = time.perf_counter()
        with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as pool:
            list(pool.map(write_one, jobs))
        size_mb = sum(p.stat().st_size for p, _, _ in jobs) / 2**20
        print(
            f"wrote {args.logs} {SCENARIO} logs of {args.seconds:g} s at {FRAME_HZ:g} Hz "
            f"({size_mb:.0f} MB) in {time.perf_counter() - start:.0f} s (2 processes)"
        )
        rows = []
        for run in RUNS:
            child = subprocess.run(
                [sys.executable, __file__, "--run", run, "--folder", str(folder)],
                check=True,
                capture_output=True,
                text=True,
            )
            rows.append(json.loads(child.stdout.strip().splitlines()[-1]))
    first = rows[0]
    print(
        f"{first['frames']} frames, {first['observations']} observations of "
        f"{first['markers_seen']} markers; results {first['result_mb']:.1f} MB pickled"
    )
    print(
        f"{'executor':<20} {'s':>7} {'frames/s':>9} {'s/log':>7} {'vs 1':>6} {'CPU s':>7} "
        f"{'frames/CPU s':>12} {'driver MB':>10} {'tree MB':>8} {'procs':>6} {'load':>9} "
        f"{'same':>5}"
    )
    for row in rows:
        print(
            f"{row['run']:<20} {row['seconds']:>7.1f} {row['frames'] / row['seconds']:>9.1f} "
            f"{row['seconds'] / row['logs']:>7.2f} {first['seconds'] / row['seconds']:>5.2f}x "
            f"{row['cpu_s']:>7.1f} {row['frames'] / row['cpu_s']:>12.1f} "
            f"{row['driver_peak_mb']:>10.0f} {row['tree_peak_mb']:>8.0f} "
            f"{row['tree_processes']:>6} {row['load_before']:>4.1f}-{row['load_after']:<4.1f} "
            f"{'yes' if row['digest'] == first['digest'] else 'NO':>5}"
        )
    print(
        "CPU s: user + system of the driver and its descendants (Ray: GCS, raylet, workers); "
        "load: the 1-minute load average before and after"
    )
    ray_row = rows[-1]
    print(f"ray start-up (ray.init, 2 CPUs, not in the times above): {ray_row['startup_s']:.1f} s")
    print(
        f"driver: every log merged into one map by SLAM in {first['merge_s']:.1f} s (build, "
        f"solve, marginals; peak memory {first['merge_peak_mb']:.0f} MB): "
        f"{first['merge_markers']} markers from {first['merge_placed']} of {first['logs']} logs "
        f"(one log alone: {first['single_markers']}); logs that share no marker with the map "
        "are left apart"
    )


if __name__ == "__main__":
    main()
