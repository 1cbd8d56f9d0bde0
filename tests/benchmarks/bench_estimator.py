"""Estimator speed: batch SLAM at 10,000 poses, iSAM2 per-update times, sparse vs dense EKF.

Usage: python tests/benchmarks/bench_estimator.py
Targets (issue 5): batch under 1 s; iSAM2 median update under 1 ms; the EKF update at 200
markers at least 20 times faster than filterpy's dense one.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small matrices: one BLAS thread is faster

import time
from dataclasses import replace

import gtsam
import numpy as np

from markergraph.datasets import scenario, simulate_fast
from markergraph.estimator import Frames, Observation, build_frames
from markergraph.estimator.ekf import MarkerEkf
from markergraph.estimator.slam import IncrementalSlam, solve_slam

N_POSES, N_MARKERS = 10_000, 100


def warehouse_problem() -> tuple[Frames, gtsam.Pose2]:
    """The first 10,000 frames of a 30 Hz warehouse run, observations of 100 markers kept."""
    world, route = scenario("warehouse")
    run = simulate_fast(world, route, seed=1, frame_hz=30.0)
    frames = build_frames(run.observations, run.odometry, 0, odometry_noise=run.odometry_noise)
    keep: list[int] = []
    for frame in frames.frames:
        for obs in frame.observations:
            if obs.marker_id not in keep and len(keep) < N_MARKERS:
                keep.append(obs.marker_id)
    trimmed = [
        replace(f, observations=tuple(o for o in f.observations if o.marker_id in keep))
        for f in frames.frames[:N_POSES]
    ]
    return Frames(trimmed, frames.home_id, frames.home_frame), run.mount.T_base_camera


def bench_batch(frames: Frames, T_base_camera: gtsam.Pose2) -> None:
    n_obs = sum(len(f.observations) for f in frames.frames)
    print(
        f"problem: {len(frames.frames)} poses, {len(frames.marker_ids())} markers, "
        f"{n_obs} observations"
    )
    for _ in range(2):  # the second run is warm
        result = solve_slam(frames, T_base_camera)
    t = result.timings_s
    print(
        f"batch SLAM: build {t['build']:.3f} s, optimise {t['optimize']:.3f} s, "
        f"marginals {t['marginals']:.3f} s; optimise+build {t['build'] + t['optimize']:.3f} s"
    )


def bench_isam2(frames: Frames, T_base_camera: gtsam.Pose2) -> None:
    slam = IncrementalSlam(frames, T_base_camera)
    times = []
    for k in range(len(frames.frames)):
        start = time.perf_counter()
        slam.add_frames_through(k)
        times.append(time.perf_counter() - start)
    times_ms = np.array(times[frames.home_frame :]) * 1e3
    print(
        f"iSAM2 update ({len(times_ms)} frames): median {np.median(times_ms):.3f} ms, "
        f"p95 {np.percentile(times_ms, 95):.3f} ms, p99 {np.percentile(times_ms, 99):.3f} ms, "
        f"max {times_ms.max():.1f} ms"
    )


def filled_ekf(n_markers: int, rng: np.random.Generator) -> MarkerEkf:
    """An EKF whose state holds n markers around the robot, each added from an observation."""
    ekf = MarkerEkf(gtsam.Pose2(), home_id=-1, robot=np.zeros(3))
    ekf.kf.P[:3, :3] = np.eye(3) * 0.01
    for marker_id in range(n_markers):
        ekf.update(
            Observation(
                0,
                marker_id,
                rng.uniform(-0.5, 0.5),
                rng.uniform(-1, 1),
                rng.uniform(1, 5),
                0.002,
                0.01,
                0.01,
            )
        )
    return ekf


def bench_ekf() -> None:
    rng = np.random.default_rng(0)
    for n_markers in (10, 50, 200):
        ekf = filled_ekf(n_markers, rng)
        rows = []
        for dense in (False, True):
            repeats = 400 if not dense else (200 if n_markers < 100 else 40)
            observations = [
                Observation(0, int(rng.integers(n_markers)), 0.1, 0.2, 2.0, 0.002, 0.01, 0.01)
                for _ in range(repeats)
            ]
            start = time.perf_counter()
            for obs in observations:
                ekf.update(obs, dense=dense)
            rows.append((time.perf_counter() - start) / repeats * 1e3)
        print(
            f"EKF update, {n_markers:>3} markers ({3 + 3 * n_markers} states): sparse "
            f"{rows[0]:.3f} ms, filterpy dense {rows[1]:.3f} ms, {rows[1] / rows[0]:.0f}x"
        )


def main() -> None:
    print(f"OPENBLAS_NUM_THREADS={os.environ['OPENBLAS_NUM_THREADS']}, cores: {os.cpu_count()}")
    frames, T_base_camera = warehouse_problem()
    bench_batch(frames, T_base_camera)
    bench_isam2(frames, T_base_camera)
    bench_ekf()


if __name__ == "__main__":
    main()
