"""Speed as a user meets it: ``markergraph detect`` and ``markergraph map --method slam`` as whole
processes (start-up, log reading, workers included) against a plain OpenCV loop, and start-up.

The plain loop decodes each JPEG of the log straight to grey (``cv2.imdecode``) and calls OpenCV's
default ``ArucoDetector.detectMarkers``, on frames already read into memory in this process: no
start-up, no log reading, which is the strictest floor. The commands run as the user runs them
(Python's bytecode cache on, as an installed package has it: :func:`installed_environment`),
one process each, side by side with the loop in every round (this machine's speed drifts from
minute to minute); each figure is the best of ``--rounds``. Recall is the default detector's
share of the plain loop's detections over every frame (``detection_agreement``: same id, corners
within 5 px). Each row also gives the CPU its best run took (user and system, threads and
workers included): the plain loop's default detector runs OpenCV's own threads, which keep
both cores busy (5.1-5.4 s of CPU in 2.7-2.9 s on either log), so the loop is not a
one-core floor. Start-up: ``--help``, ``info LOG`` and ``detect --help`` as processes, beside
``python -c pass`` (the interpreter alone).

The logs: ``--log PATH``, else the corridor loop rendered once by ``markergraph simulate`` (100 s
at 15 Hz, 640x480 JPEG, the D435i preset: 1,500 frames; about 2 minutes on 2 idle cores, kept in
the temporary folder), and its twin without depth (:func:`without_depth`). The D435i's raw depth
is 0.6 MB a frame: zstd alone takes 1.2-1.5 s of CPU to read past it, a floor the plain loop,
which reads nothing, never meets.

``detect`` runs with its default workers (auto), ``--workers 1`` and each ``--workers N`` given;
``map --method slam`` runs on the log and on ``detect``'s output (``o.jsonl``, written earlier in
the same round): the second is everything ``map`` does besides reading the log. ``--detect-only``
leaves out ``map`` and start-up.

Usage: python tests/benchmarks/bench_process.py [--log PATH] [--rounds N] [--workers N ...]
    [--detect-only]
Targets (issue 30): both commands at >= 1.5x the plain loop's frames/s at >= 99 % recall;
start-up under 0.25 s.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from markergraph.frontend import open_log
from markergraph.frontend.detect import Detection, Detector, detection_agreement

TOPIC = "/camera/camera/color/image_raw/compressed"
CACHED_LOG = Path(tempfile.gettempdir()) / "markergraph-bench" / "corridor-1500-d435i.mcap"
COMMAND = [str(Path(sys.executable).with_name("markergraph"))]
PACKAGES = ("markergraph", *(f"markergraph.{p}" for p in ("cli", "common", "estimator", "frontend",
                                                         "datasets")))  # fmt: skip


def rendered_log() -> Path:
    """The benchmark's log, rendered once by ``markergraph simulate``."""
    if not CACHED_LOG.exists():
        CACHED_LOG.parent.mkdir(parents=True, exist_ok=True)
        print(f"rendering {CACHED_LOG} (once) ...", flush=True)
        subprocess.run(
            [*COMMAND, "simulate", "--scenario", "corridor-loop", "--compressed", "--sensors",
             "d435i", "--duration", "100", "--frame-rate", "15", "--seed", "1", "--out",
             str(CACHED_LOG)],
            check=True,
        )  # fmt: skip
    return CACHED_LOG


def plain_loop(jpegs: list[bytes]) -> tuple[float, float, list[list[Detection]]]:
    """(seconds, CPU seconds, detections per frame) of the plain loop: decode to grey, default
    detector (whose own threads OpenCV counts in the CPU)."""
    detector = cv2.aruco.ArucoDetector(
        cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50), cv2.aruco.DetectorParameters()
    )
    found = []
    start, cpu = time.perf_counter(), time.process_time()
    for jpeg in jpegs:
        grey = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
        corners, ids, _ = detector.detectMarkers(grey)
        found.append((corners, ids))
    seconds, cpu = time.perf_counter() - start, time.process_time() - cpu
    detections = [
        []
        if ids is None
        else [
            Detection(int(i), np.asarray(c, np.float64).reshape(4, 2))
            for c, i in zip(corners, ids.ravel(), strict=True)
        ]
        for corners, ids in found
    ]
    return seconds, cpu, detections


def default_detections(jpegs: list[bytes]) -> list[list[Detection]]:
    """The front end's default detector on every frame (for recall; not timed)."""
    detector = Detector()
    return [
        detector.detect(cv2.imdecode(np.frombuffer(j, np.uint8), cv2.IMREAD_GRAYSCALE))
        for j in jpegs
    ]


def installed_environment() -> dict[str, str]:
    """The commands' environment as an installed package meets it: Python's bytecode cache on
    (pip compiles a wheel's modules as it installs them; PYTHONDONTWRITEBYTECODE, where set,
    turns the cache off and costs every process 0.1-0.25 s compiling our modules), and our
    modules compiled now, before the first timed run."""
    import compileall
    import importlib.util

    for package in PACKAGES:
        spec = importlib.util.find_spec(package)
        for folder in (spec.submodule_search_locations or []) if spec else []:
            compileall.compile_dir(folder, quiet=1)
    return {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}


def process_seconds(argv: list[str], cwd: Path, env: dict[str, str]) -> tuple[float, float]:
    """Wall-clock and CPU seconds (user and system, its workers' included) of one
    ``markergraph`` process, to its exit."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run([*COMMAND, *argv], cwd=cwd, check=True, stdout=subprocess.DEVNULL, env=env)
    seconds = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return seconds, after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--log", type=Path, help="a 640x480 JPEG log (default: rendered once)")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--workers", type=int, action="append", default=[],
                        help="detect also with this --workers (repeatable)")  # fmt: skip
    parser.add_argument("--detect-only", action="store_true", help="no map, no start-up")
    args = parser.parse_args()
    logs = [args.log] if args.log else [rendered_log(), without_depth(rendered_log())]
    for i, log in enumerate(logs):
        bench_log(log, args.rounds, args.workers, args.detect_only, start_up=i == 0)
        print()


def without_depth(log: Path) -> Path:
    """``log``'s twin without its depth topics (a camera with no depth, or depth left out of
    the recording), written once beside it: every other message as it was, zstd chunks."""
    twin = log.with_name(log.stem + "-no-depth.mcap")
    if twin.exists():
        return twin
    partial = twin.with_suffix(".partial")
    with open(log, "rb") as source, open(partial, "wb") as out:
        reader = make_reader(source)
        summary = reader.get_summary()
        assert summary is not None
        writer = Writer(out, compression=CompressionType.ZSTD)
        writer.start()
        for schema in summary.schemas.values():
            writer.register_schema(schema.name, schema.encoding, schema.data)
        kept = {
            c.id: writer.register_channel(c.topic, c.message_encoding, c.schema_id, c.metadata)
            for c in summary.channels.values()
            if "depth" not in c.topic
        }
        for _, channel, m in reader.iter_messages():
            if channel.id in kept:
                writer.add_message(kept[channel.id], m.log_time, m.data, m.publish_time,
                                   m.sequence)  # fmt: skip
        writer.finish()
    partial.rename(twin)
    return twin


def bench_log(
    log: Path, rounds: int, workers: list[int], detect_only: bool, start_up: bool
) -> None:
    """The table for one log: the plain loop, detect (and map), start-up."""
    jpegs = [bytes(m.decoded.data) for m in open_log(log).messages([TOPIC])]
    frames = len(jpegs)
    print(f"log {log}: {frames} frames, {os.cpu_count()} cores, load {os.getloadavg()[0]:.2f}")
    detect = ["detect", str(log), "--out", "o.jsonl", "--force", "--quiet"]
    runs = {"detect (auto workers)": detect}
    for n in sorted({1, *workers}):
        runs[f"detect --workers {n}"] = [*detect, "--workers", str(n)]
    starts: dict[str, list[str]] = {}
    if not detect_only:
        runs["map --method slam"] = ["map", str(log), "--method", "slam", "--no-cache",
                                     "--no-plots", "--out", "m", "--force", "--quiet"]  # fmt: skip
        runs["map o.jsonl (no log read)"] = ["map", "o.jsonl", "--method", "slam", "--no-cache",
                                             "--no-plots", "--out", "m", "--force",
                                             "--quiet"]  # fmt: skip
    if not detect_only and start_up:
        starts = {
            "python -c pass": [sys.executable, "-c", "pass"],
            "markergraph --help": [*COMMAND, "--help"],
            "markergraph detect --help": [*COMMAND, "detect", "--help"],
            "markergraph info LOG": [*COMMAND, "info", str(log)],
        }
    best: dict[str, tuple[float, float]] = {}
    env = installed_environment()
    work = Path(tempfile.mkdtemp(prefix="bench-process-"))
    reference: list[list[Detection]] = []
    try:
        for r in range(rounds):
            seconds, cpu, reference = plain_loop(jpegs)
            keep_best(best, "plain loop", (seconds, cpu))
            for name, argv in runs.items():
                keep_best(best, name, process_seconds(argv, work, env))
            for name, argv in starts.items():
                start = time.perf_counter()
                subprocess.run(argv, check=False, stdout=subprocess.DEVNULL, cwd=work, env=env)
                keep_best(best, name, (time.perf_counter() - start, 0.0))
            print(f"round {r + 1}: load {os.getloadavg()[0]:.2f}", flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    total, recall, _ = detection_agreement(reference, default_detections(jpegs))
    plain_rate = frames / best["plain loop"][0]
    print(f"\nbest of {rounds} rounds, load {os.getloadavg()[0]:.2f} at the end")
    print(f"{'':28}{'seconds':>9}{'frames/s':>10}{'x plain':>9}{'CPU s':>8}")
    for name in ("plain loop", *runs):
        seconds, cpu = best[name]
        rate = frames / seconds
        print(f"{name:28}{seconds:9.2f}{rate:10.0f}{rate / plain_rate:9.2f}{cpu:8.2f}")
    print(
        "CPU s: user and system of the best run, threads and workers included: on 2 cores a "
        "command cannot take less wall clock than half its CPU"
    )
    print(f"recall: the default detector finds {recall:.1%} of the plain loop's {total} detections")
    if starts:
        print("\nstart-up (whole process, seconds)")
    for name in starts:
        print(f"  {name:30}{best[name][0]:6.3f}")


def keep_best(best: dict[str, tuple[float, float]], name: str, run: tuple[float, float]) -> None:
    """``run`` (seconds, CPU seconds) kept as ``name``'s best if it took less wall clock."""
    if name not in best or run[0] < best[name][0]:
        best[name] = run


if __name__ == "__main__":
    main()
