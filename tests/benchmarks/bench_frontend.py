"""Front-end speed on a simulated 640x480 JPEG log: observations per second against the floor.

The floor is measured in the same run: JPEG decode to grey plus ``ArucoDetector.detectMarkers``
alone, with the same settings, on the frames already in memory. The pipeline reads the MCAP
log (zstd chunks, CDR), pairs colour with depth, detects, and computes observations; with two
workers each reads and processes its own stretches of the log. Three minutes at 15 Hz, so
the workers' start-up (about a second each) weighs as it would on a real log.

Usage: python tests/benchmarks/bench_frontend.py
Targets (issue 4): at least 0.8 of the floor; at least 1.8x with two worker processes.
"""

from __future__ import annotations

import multiprocessing
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import cv2
import numpy as np

from markergraph.datasets import scenario
from markergraph.datasets.write import write_log
from markergraph.frontend import FrontendConfig, extract, messages
from markergraph.frontend.detect import Detector

TOPIC = "/camera/camera/color/image_raw/compressed"


def floor_seconds(jpegs: list[bytes]) -> float:
    """JPEG decode plus detection alone over the frames, in this process."""
    cv2.setNumThreads(1)
    detector = Detector("DICT_4X4_50")
    start = time.perf_counter()
    for jpeg in jpegs:
        detector.detect(cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_GRAYSCALE))
    return time.perf_counter() - start


def main() -> None:
    cv2.setNumThreads(1)
    print(f"cores: {os.cpu_count()}")
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "office.mcap"
        world, route = scenario("office")
        write_log(world, route, path, seed=3, duration_s=180.0, compressed=True)
        jpegs = [bytes(m.decoded.data) for m in messages(path, [TOPIC])]
        floor = len(jpegs) / floor_seconds(jpegs)
        print(f"floor (JPEG decode + detectMarkers): {floor:.0f} frames/s over {len(jpegs)}")
        # What the machine gives two processes on this work: the floor loop twice at once.
        halves = [jpegs[: len(jpegs) // 2], jpegs[len(jpegs) // 2 :]]
        with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as pool:
            list(pool.map(floor_seconds, [h[:5] for h in halves]))  # start-up not counted
            start = time.perf_counter()
            list(pool.map(floor_seconds, halves))
            floor_two = len(jpegs) / (time.perf_counter() - start)
        print(
            f"floor in two processes at once: {floor_two:.0f} frames/s "
            f"({floor_two / floor:.2f}x: the ceiling for any two-process pipeline here)"
        )
        rates = {}
        for workers in (1, 2):
            start = time.perf_counter()
            result = extract(path, FrontendConfig(), workers=workers)
            rates[workers] = result.frames / (time.perf_counter() - start)
            print(
                f"pipeline, {workers} process(es): {rates[workers]:.0f} frames/s "
                f"({rates[workers] / floor:.2f} of the floor), "
                f"{len(result.observations)} observations"
            )
        print(f"two workers / one process: {rates[2] / rates[1]:.2f}x")
        start = time.perf_counter()
        subprocess.run([sys.executable, "-c", "import markergraph.frontend.pipeline"], check=True)
        print(f"a worker's start-up (spawn, imports): {time.perf_counter() - start:.2f} s")


if __name__ == "__main__":
    main()
