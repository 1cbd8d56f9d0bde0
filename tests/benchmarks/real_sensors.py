"""A RealSense D435i on a diff-drive base, simulated: each method's marker RMSE (after a rigid
2-D alignment) on two scenarios' ideal and realistic logs, with no remedy, each remedy alone
and all of them, and the camera delay, depth scale and odometry scale each run used (README,
"Real sensors").

    python tests/benchmarks/real_sensors.py [--seconds 60] [--scenarios paper-room office]
        [--seed 3] [--each-effect]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import tempfile
from pathlib import Path

import markergraph as mg
from markergraph.datasets import scenario, write_log
from markergraph.datasets.sensors import D435I_ON_DIFF_DRIVE, SensorEffects
from markergraph.estimator import map_error

NONE = {"camera.delay_ms": 0.0, "noise.depth_scale": 1.0, "odometry.scale": 1.0,
        "camera.readout_ms": 0.0}  # fmt: skip
REMEDIES = {
    "no remedy": NONE,
    "delay by residuals": {**NONE, "camera.delay_ms": None},
    "depth scale from markers": {**NONE, "noise.depth_scale": "auto"},
    "odometry scale by residuals": {**NONE, "odometry.scale": None},
    "defaults (the three above)": {},
    "shutter modelled": {**NONE, "camera.readout_ms": 25.0},
    "shutter widened": {**NONE, "camera.readout_ms": 25.0, "camera.shutter": "widen"},
    "blur widened": {**NONE, "camera.exposure_ms": 15.0},
    "all, shutter modelled": {"camera.readout_ms": 25.0, "camera.exposure_ms": 15.0},
    "all, shutter widened": {"camera.readout_ms": 25.0, "camera.exposure_ms": 15.0,
                             "camera.shutter": "widen"},
}  # fmt: skip


def print_runs(log: Path, remedies: dict[str, dict[str, object]]) -> None:
    for remedy, values in remedies.items():
        run = mg.map_log(log, mg.MapConfig.from_values({"method": "all", **values}))
        errors = {r.label: map_error(r.estimate, run.true_markers, align=True) for r in run.results}
        rmse = "  ".join(f"{label} {100 * e.rmse_position_m:5.1f}" for label, e in errors.items())
        measured = run.extraction.measured_depth_scale
        chosen = (
            f"delay {run.camera_delay_ns / 1e6:+5.1f} ms, depth scale "
            f"{run.extraction.depth_scale:.4f} applied, {measured or math.nan:.4f} measured, "
            f"odometry scale {run.odometry_scale:.4f}"
        )
        print(f"  {remedy:<26} {rmse}  ({chosen})", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--scenarios", nargs="+", default=["paper-room", "office"])
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument(
        "--each-effect", action="store_true",
        help="instead: one log per effect alone, mapped with the default remedies",
    )  # fmt: skip
    args = parser.parse_args()
    logs: dict[str, tuple[SensorEffects, dict[str, dict[str, object]]]] = {
        "ideal": (
            SensorEffects(),
            {"default settings": {}, "depth taken as it is": {"noise.depth_scale": 1.0}},
        ),
        "D435i preset": (D435I_ON_DIFF_DRIVE, REMEDIES),
    }
    if args.each_effect:
        logs = {"ideal": (SensorEffects(), {"default settings": {}})} | {
            f"{f.name} alone": (
                SensorEffects(**{f.name: getattr(D435I_ON_DIFF_DRIVE, f.name)}),
                {"default settings": {}},
            )
            for f in dataclasses.fields(SensorEffects)
        }
    with tempfile.TemporaryDirectory() as scratch:
        for name in args.scenarios:
            world, route = scenario(name)
            for sensors, (effects, remedies) in logs.items():
                log = Path(scratch) / f"{name}.mcap"
                log.unlink(missing_ok=True)
                write_log(world, route, log, seed=args.seed, duration_s=args.seconds,
                          compressed=True, frame_hz=5.0, sensors=effects)  # fmt: skip
                print(
                    f"{name}, {sensors} (seed {args.seed}, {args.seconds:.0f} s): marker RMSE [cm]"
                )
                print_runs(log, remedies)


if __name__ == "__main__":
    main()
