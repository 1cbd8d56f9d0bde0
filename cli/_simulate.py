"""``markergraph simulate``: write a scenario's run as a ROS 2 MCAP log with ground truth."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from markergraph.cli._commands import summary
from markergraph.common.errors import SettingsError
from markergraph.common.files import check_output_file
from markergraph.common.progress import ProgressBar
from markergraph.datasets.scenarios import SCENARIOS, scenario
from markergraph.datasets.sensors import D435I_ON_DIFF_DRIVE, SENSOR_PRESETS
from markergraph.datasets.write import write_log

MAX_FRAME_RATE_HZ = 240.0  # faster than any camera the simulator models
SUMMARY = summary("simulate")


def add_parser(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser("simulate", help=SUMMARY, description=SUMMARY)
    parser.add_argument(
        "--scenario",
        required=True,
        choices=sorted(SCENARIOS),
        help="the world and route to simulate",
    )
    parser.add_argument(
        "--seed",
        type=int,
        default=0,
        help="seeds every random draw; one seed gives the same bytes (default 0)",
    )
    parser.add_argument("--out", type=Path, required=True, help="the .mcap file to write")
    parser.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="S",
        help="stop after S seconds (default: the whole route)",
    )
    parser.add_argument(
        "--compressed",
        action="store_true",
        help="JPEG colour on .../image_raw/compressed instead of raw rgb8",
    )
    parser.add_argument(
        "--frame-rate",
        type=float,
        default=15.0,
        metavar="HZ",
        help="camera frame rate (default 15)",
    )
    parser.add_argument(
        "--sensors",
        choices=sorted(SENSOR_PRESETS),
        default="ideal",
        help=_sensors_help(),
    )
    parser.add_argument("--force", action="store_true", help="overwrite an existing --out file")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar on stderr")


def _sensors_help() -> str:
    """The --sensors help, with the preset's figures taken from the preset itself."""
    d = D435I_ON_DIFF_DRIVE
    return (
        "the camera and base: 'ideal' (default; exact stamps, global shutter, true depth) or "
        f"'d435i', a RealSense D435i on a diff-drive base: colour and depth stamps "
        f"{d.camera_latency_s * 1e3:g} ms late with {d.stamp_jitter_s * 1e3:g} ms jitter, "
        f"a {d.rolling_shutter_s * 1e3:g} ms rolling shutter, {d.exposure_s * 1e3:g} ms "
        f"exposure blur, depth reading {(d.depth_scale - 1) * 100:g} %% long and none on black "
        f"ink, lens distortion, {d.dropped_frames * 100:g} %% of frames dropped, odometry "
        f"stamps jittered by {d.odometry_jitter_s * 1e3:g} ms, and realsense-ros's TF tree"
    )


def run(args: argparse.Namespace) -> int:
    out: Path = args.out
    check_output_file(out, [], force=args.force)
    if args.duration is not None and not (0 < args.duration < math.inf):
        raise SettingsError(f"--duration must be a positive number of seconds, got {args.duration}")
    if not 0 < args.frame_rate <= MAX_FRAME_RATE_HZ:
        raise SettingsError(
            f"--frame-rate must be above 0 and at most {MAX_FRAME_RATE_HZ:g} Hz, "
            f"got {args.frame_rate:g}"
        )
    world, route = scenario(args.scenario)
    with ProgressBar(f"simulating {args.scenario}", quiet=args.quiet) as bar:
        summary = write_log(
            world,
            route,
            out,
            args.seed,
            duration_s=args.duration,
            compressed=args.compressed,
            frame_hz=args.frame_rate,
            sensors=SENSOR_PRESETS[args.sensors],
            progress=bar,
        )
    print(
        f"wrote {summary.path}: {summary.frames} frames, "
        f"{sum(summary.messages.values())} messages on {len(summary.messages)} topics, "
        f"{summary.bytes / 1e6:.1f} MB"
    )
    return 0
