"""``markergraph map``: a log (or the bundled sample) to a corrected marker map on disk."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from markergraph.cli._settings import add_settings, add_verbosity, settings_from
from markergraph.frontend.files import check_output_folder
from markergraph.frontend.progress import ProgressBar, Stages
from markergraph.results import write_results
from markergraph.run import MapRun, map_log
from markergraph.settings import config_toml, map_config

SUMMARY = "estimate a corrected marker map from an MCAP log (default: the bundled sample)"
DEFAULT_SAMPLE = "corridor-loop"


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
        "--out", type=Path, default=None, help="result folder (default: map-<log name> here)"
    )
    parser.add_argument("--force", action="store_true", help="replace an existing result folder")
    parser.add_argument("--no-plots", action="store_true", help="skip map.png and comparison.png")
    parser.add_argument(
        "--print-config",
        action="store_true",
        help="print the settings in effect as a TOML file for --config, and stop",
    )
    add_verbosity(parser)
    add_settings(parser, "map")


def run(args: argparse.Namespace) -> int:
    from markergraph.datasets.samples import sample_log, sample_path

    config = map_config(settings_from(args, "map"))
    if args.print_config:
        print(config_toml(config.values), end="")
        return 0
    log = args.log if args.log is not None else sample_path(DEFAULT_SAMPLE)
    out = args.out or Path(f"map-{Path(log).stem}")
    # Before any work (a sample's rendering included): never over the input or a user's folder.
    check_output_folder(out, [log], force=args.force)
    if args.log is None:
        log = sample_log(DEFAULT_SAMPLE)
        print(f"no log given: mapping the bundled {DEFAULT_SAMPLE} sample ({log})")
    stages = Stages(quiet=args.quiet, verbose=args.verbose)
    with ProgressBar(f"reading {Path(log).name}", quiet=args.quiet) as bar:
        result = map_log(log, config, progress=bar, stage=stages)
    stages(f"writing {out}/")
    written = write_results(result, out, force=args.force, plots=not args.no_plots)
    stages.close()
    _print_summary(result, quiet=args.quiet)
    print(f"wrote {len(written)} files to {out}/")
    return 0


def _print_summary(result: MapRun, *, quiet: bool = False) -> None:
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
                + (f" {aligned.rmse_position_m:>8.3f}" if aligned else f" {'-':>8}")
                + (f" {trajectory.ate_rmse_m:>7.3f}" if trajectory else f" {'-':>7}")
            )
        print(line)
        for note in estimate.notes:
            print(f"  {method_result.label}: {note}")
    for reason, count in sorted(extraction.skipped.items()):
        print(f"  {count} frame(s): {reason}")
    if not quiet:
        for note in extraction.notes + extraction.warnings:
            print(f"note: {note}", file=sys.stderr)
