"""Simulator speed: rendered frames per second (colour + depth, 640x480) and logged frames per
second (rendering, encoding and writing a ROS 2 MCAP log), one process.

Usage: python tests/benchmarks/bench_datasets.py
Target (issue 3): at least 100 rendered frames per second on one core.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import tempfile
import time
from pathlib import Path

import cv2
import gtsam
import numpy as np

from markergraph.datasets import scenario
from markergraph.datasets.render import Renderer
from markergraph.datasets.route import drive
from markergraph.datasets.simulate import simulate_fast
from markergraph.datasets.write import write_log

FRAMES = 450  # 30 s at 15 Hz


def main() -> None:
    cv2.setNumThreads(1)  # one core, as the target says
    print("scenario        rendered fps   logged fps (raw)   logged fps (JPEG)   fast-mode fps")
    for name in ("paper-room", "corridor-loop", "office", "warehouse"):
        world, route = scenario(name)
        rng = np.random.default_rng(0)
        poses = drive(world, route, rng, duration_s=FRAMES / 15.0).frame_poses
        renderer = Renderer(world)
        renderer.render(gtsam.Pose2(*poses[0]), rng)  # warm up
        start = time.perf_counter()
        for pose in poses:
            renderer.render(gtsam.Pose2(*pose), rng)
        rendered = len(poses) / (time.perf_counter() - start)
        logged = []
        with tempfile.TemporaryDirectory() as folder:
            for compressed in (False, True):
                start = time.perf_counter()
                summary = write_log(
                    world,
                    route,
                    Path(folder) / "run.mcap",
                    0,
                    duration_s=FRAMES / 15.0,
                    compressed=compressed,
                )
                logged.append(summary.frames / (time.perf_counter() - start))
        start = time.perf_counter()
        run = simulate_fast(world, route, 0)
        fast = len(run.frame_t_ns) / (time.perf_counter() - start)
        print(f"{name:<15} {rendered:>12.0f} {logged[0]:>18.0f} {logged[1]:>19.0f} {fast:>15.0f}")


if __name__ == "__main__":
    main()
