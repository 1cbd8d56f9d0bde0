"""A RealSense D435i on a diff-drive base, simulated: each method's marker RMSE (after a rigid
2-D alignment) on two scenarios' ideal and realistic logs, with no remedy, each remedy alone
and all of them (README, "Real sensors").

    python tests/benchmarks/real_sensors.py [--seconds 60] [--scenarios paper-room office]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import markergraph as mg
from markergraph.datasets import scenario, write_log
from markergraph.datasets.sensors import D435I_ON_DIFF_DRIVE, SensorEffects
from markergraph.estimator import map_error

NONE = {"camera.delay_ms": 0.0, "noise.depth_scale": 1.0}
REMEDIES = {
    "no remedy": NONE,
    "delay by residuals": {**NONE, "camera.delay_ms": None},
    "depth scale from markers": {**NONE, "noise.depth_scale": None},
    "shutter modelled": {**NONE, "camera.readout_ms": 25.0},
    "shutter widened": {**NONE, "camera.readout_ms": 25.0, "camera.shutter": "widen"},
    "blur widened": {**NONE, "camera.exposure_ms": 15.0},
    "all, shutter modelled": {"camera.readout_ms": 25.0, "camera.exposure_ms": 15.0},
    "all, shutter widened": {"camera.readout_ms": 25.0, "camera.exposure_ms": 15.0,
                             "camera.shutter": "widen"},
}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--scenarios", nargs="+", default=["paper-room", "office"])
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        for name in args.scenarios:
            world, route = scenario(name)
            for sensors, remedies in (
                ("ideal", {"default settings": {}}),
                ("D435i preset", REMEDIES),
            ):
                log = Path(scratch) / f"{name}-{sensors}.mcap"
                effects = SensorEffects() if sensors == "ideal" else D435I_ON_DIFF_DRIVE
                write_log(world, route, log, seed=3, duration_s=args.seconds, compressed=True,
                          frame_hz=5.0, sensors=effects)  # fmt: skip
                print(f"{name}, {sensors} ({args.seconds:.0f} s): marker RMSE [cm]")
                for remedy, values in remedies.items():
                    run = mg.map_log(log, mg.MapConfig.from_values({"method": "all", **values}))
                    errors = {
                        r.label: map_error(r.estimate, run.true_markers, align=True)
                        for r in run.results
                    }
                    rmse = "  ".join(
                        f"{label} {100 * e.rmse_position_m:5.1f}" for label, e in errors.items()
                    )
                    print(f"  {remedy:<24} {rmse}", flush=True)


if __name__ == "__main__":
    main()
