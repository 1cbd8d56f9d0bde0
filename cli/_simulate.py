"""``markergraph simulate``: write a scenario's run as a ROS 2 MCAP log with ground truth."""

from __future__ import annotations

import argparse
from pathlib import Path

from markergraph.datasets.scenarios import SCENARIOS, scenario
from markergraph.datasets.write import write_log
from markergraph.frontend.progress import ProgressBar

SUMMARY = "simulate a scenario and write a ROS 2 MCAP log with ground truth"


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
    parser.add_argument("--force", action="store_true", help="overwrite an existing --out file")


def run(args: argparse.Namespace) -> int:
    out: Path = args.out
    if out.exists() and not args.force:
        raise FileExistsError(f"{out} exists; pass --force to overwrite it")
    if not out.parent.is_dir():
        raise FileNotFoundError(f"cannot write {out}: {out.parent} is not a folder")
    if args.duration is not None and args.duration <= 0:
        raise ValueError(f"--duration must be positive, got {args.duration}")
    if args.frame_rate <= 0:
        raise ValueError(f"--frame-rate must be positive, got {args.frame_rate}")
    world, route = scenario(args.scenario)
    with ProgressBar(f"simulating {args.scenario}") as bar:
        summary = write_log(
            world,
            route,
            out,
            args.seed,
            duration_s=args.duration,
            compressed=args.compressed,
            frame_hz=args.frame_rate,
            progress=bar,
        )
    print(
        f"wrote {summary.path}: {summary.frames} frames, "
        f"{sum(summary.messages.values())} messages on {len(summary.messages)} topics, "
        f"{summary.bytes / 1e6:.1f} MB"
    )
    return 0
