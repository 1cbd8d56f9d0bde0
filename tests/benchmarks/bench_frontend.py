"""Front-end speed on a simulated 640x480 JPEG log: observations per second against the floor.

The floor is measured in the same run: JPEG decode to grey plus ``ArucoDetector.detectMarkers``
alone, with the same settings, on the frames already in memory. The pipeline reads the MCAP
log (zstd chunks, CDR), pairs colour with depth, detects, and computes observations.

Usage: python tests/benchmarks/bench_frontend.py
Targets (issue 4): at least 0.8 of the floor; at least 1.8x with two worker processes.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from markergraph.datasets import scenario
from markergraph.datasets.write import write_log
from markergraph.frontend.detect import Detector
from markergraph.frontend.log import messages
from markergraph.frontend.pipeline import FrontendConfig, extract

TOPIC = "/camera/camera/color/image_raw/compressed"


def main() -> None:
    cv2.setNumThreads(1)
    print(f"cores: {os.cpu_count()}")
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "office.mcap"
        world, route = scenario("office")
        write_log(world, route, path, seed=3, duration_s=60.0, compressed=True)
        jpegs = [bytes(m.decoded.data) for m in messages(path, [TOPIC])]
        detector = Detector("DICT_4X4_50")
        start = time.perf_counter()
        for jpeg in jpegs:
            detector.detect(cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_GRAYSCALE))
        floor = len(jpegs) / (time.perf_counter() - start)
        print(f"floor (JPEG decode + detectMarkers): {floor:.0f} frames/s over {len(jpegs)}")
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


if __name__ == "__main__":
    main()
