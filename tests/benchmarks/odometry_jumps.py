"""An odometry reset (a VIO jump): the map without it, with it released (what markergraph does)
and with it taken at its word.

- The fast simulator's corridor loop (seed 7, the whole route): every odometry pose after the
  middle moved rigidly by (0.3 m, -0.1 m, 0.05 rad); SLAM's marker RMSE against the truth.
- A rendered 20 s log of the paper room (seed 3): every /odom pose after the 500th moved 0.3 m;
  how far `markergraph map`'s markers move from the clean log's map.

Usage: python tests/benchmarks/odometry_jumps.py
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import gtsam
import numpy as np

import markergraph as mg
from markergraph.datasets import scenario, simulate_fast, write_log
from markergraph.datasets.rewrite import rewrite_log
from markergraph.estimator import (
    Method,
    OdometrySample,
    Trajectory,
    build_frames,
    estimate_frames,
    map_error,
)


def simulated() -> None:
    world, route = scenario("corridor-loop")
    run = simulate_fast(world, route, seed=7)
    half = len(run.odometry) // 2
    reset = gtsam.Pose2(0.3, -0.1, 0.05)
    jumped = run.odometry[:half] + [
        OdometrySample(s.t_ns, p.x(), p.y(), p.theta())
        for s in run.odometry[half:]
        for p in [reset.compose(s.pose())]
    ]
    breaks = [t for t, _ in Trajectory.from_samples(jumped).jumps()]

    def rmse(odometry: list[OdometrySample], released: list[int]) -> float:
        frames = build_frames(run.observations, odometry, 0, odometry_noise=run.odometry_noise,
                              odometry_breaks=released)  # fmt: skip
        result = estimate_frames(frames, Method.SLAM, run.mount.T_base_camera)
        return map_error(result, run.true_markers()).rmse_position_m

    print(
        f"corridor loop, SLAM marker RMSE: no jump {100 * rmse(run.odometry, []):.1f} cm, "
        f"jump released {100 * rmse(jumped, breaks):.1f} cm, "
        f"jump taken at its word {100 * rmse(jumped, []):.1f} cm"
    )


def logged() -> None:
    def reset(topic: str, index: int, decoded: Any) -> Any:
        if topic == "/odom" and index >= 500:
            decoded.pose.pose.position.x += 0.3
        return decoded

    def markers(run: mg.MapRun) -> dict[int, np.ndarray]:
        estimate = run.results[0].estimate
        return {i: m.T_map_marker.translation() for i, m in estimate.markers.items()}

    with tempfile.TemporaryDirectory() as folder:
        clean, jumped = Path(folder) / "room.mcap", Path(folder) / "reset.mcap"
        world, route = scenario("paper-room")
        write_log(world, route, clean, seed=3, duration_s=20.0, compressed=True, frame_hz=5.0)
        rewrite_log(clean, jumped, reset)
        before = markers(mg.map_log(clean))
        released = markers(mg.map_log(jumped))
        original = Trajectory.jumps
        Trajectory.jumps = lambda self, *_, **__: []  # type: ignore[method-assign]
        try:
            ignored = markers(mg.map_log(jumped))
        finally:
            Trajectory.jumps = original  # type: ignore[method-assign]
    for label, after in (("released", released), ("taken at its word", ignored)):
        moved = max(np.linalg.norm(before[i] - after[i]) for i in before)
        print(f"paper-room log, the reset {label}: markers move up to {100 * moved:.1f} cm")


if __name__ == "__main__":
    simulated()
    logged()
