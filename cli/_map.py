"""``markergraph map``: a log (or the bundled sample) to a corrected marker map on disk."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from markergraph.cli._frontend import add_frontend_options, frontend_config
from markergraph.estimator import Method
from markergraph.frontend.mapping import map_log, write_results
from markergraph.frontend.progress import ProgressBar

SUMMARY = "estimate a corrected marker map from an MCAP log (default: the bundled sample)"
DEFAULT_SAMPLE = "corridor-loop"
ALL_METHODS = [Method.SLAM, Method.CLOSED_FORM, Method.MARKER_GRAPH, Method.ISAM2, Method.EKF]


def add_parser(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser("map", help=SUMMARY, description=SUMMARY)
    parser.add_argument(
        "log",
        type=Path,
        nargs="?",
        default=None,
        help=f"an .mcap file or rosbag2 folder (default: the bundled "
        f"{DEFAULT_SAMPLE} sample, rendered once into the cache)",
    )
    parser.add_argument(
        "--method",
        default="slam",
        choices=[m.value for m in Method] + ["all"],
        help="which estimator; all runs every one side by side (default slam)",
    )
    parser.add_argument(
        "--out", type=Path, default=None, help="result folder (default: map-<log name> here)"
    )
    parser.add_argument("--force", action="store_true", help="replace an existing result folder")
    parser.add_argument(
        "--home",
        type=int,
        default=None,
        metavar="ID",
        help="the marker whose frame is the map (default: the first seen)",
    )
    parser.add_argument(
        "--workers", type=int, default=1, metavar="N", help="processes for detection (default 1)"
    )
    parser.add_argument("--no-plots", action="store_true", help="skip map.png and comparison.png")
    add_frontend_options(parser)


def run(args: argparse.Namespace) -> int:
    from markergraph.datasets.samples import sample_log, sample_path

    log = args.log if args.log is not None else sample_path(DEFAULT_SAMPLE)
    out = args.out or Path(f"map-{Path(log).stem}")
    if out.exists() and not args.force:  # before any work, a sample's rendering included
        raise FileExistsError(f"{out} exists; pass --force to replace it")
    if args.log is None:
        log = sample_log(DEFAULT_SAMPLE)
        print(f"no log given: mapping the bundled {DEFAULT_SAMPLE} sample ({log})")
    # With all, SLAM comes first: the top-level map.json, map.g2o and overlay are its.
    methods = ALL_METHODS if args.method == "all" else [Method(args.method)]
    config = frontend_config(args)
    with ProgressBar(f"reading {Path(log).name}") as bar:
        result = map_log(
            log, config, methods, home_id=args.home, workers=args.workers, progress=bar
        )
    written = write_results(result, out, config, force=args.force, plots=not args.no_plots)
    extraction = result.extraction
    markers = {o.marker_id for o in extraction.observations}
    print(
        f"{extraction.frames} frames, {len(extraction.observations)} observations of "
        f"{len(markers)} markers, home marker {result.frames.home_id}"
    )
    header = f"{'method':<14} {'markers':>7} {'links':>5}"
    if result.true_markers:
        header += f" {'marker RMSE':>11} {'aligned':>8} {'ATE':>7}"
    print(header)
    for method_result in result.results:
        estimate = method_result.estimate
        line = f"{method_result.label:<14} {len(estimate.markers):>7} {len(estimate.links):>5}"
        if method_result.map_error is not None:
            aligned = method_result.map_error_aligned
            trajectory = method_result.trajectory_error
            line += (
                f" {method_result.map_error.rmse_position_m:>9.3f} m"
                f" {aligned.rmse_position_m if aligned else float('nan'):>8.3f}"
                f" {trajectory.ate_rmse_m if trajectory else float('nan'):>7.3f}"
            )
        print(line)
        for note in estimate.notes:
            print(f"  {method_result.label}: {note}")
    for note in extraction.notes + extraction.warnings:
        print(f"note: {note}", file=sys.stderr)
    print(f"wrote {len(written)} files to {out}/")
    return 0
