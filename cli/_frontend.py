"""``markergraph detect`` and ``markergraph info``: the front end from the command line."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from markergraph.cli._settings import add_settings, settings_from
from markergraph.formats import write_observations
from markergraph.frontend import choose_topics, extract, log_topics
from markergraph.frontend.files import check_output_file
from markergraph.frontend.progress import ProgressBar
from markergraph.settings import map_config

DETECT = "detect markers in an MCAP log and write observations as JSON lines"
INFO = "list what an MCAP log holds and which topics would be used"


def add_parsers(commands: argparse._SubParsersAction) -> None:
    detect = commands.add_parser("detect", help=DETECT, description=DETECT)
    detect.add_argument("log", type=Path, help="an .mcap file or a rosbag2 folder")
    detect.add_argument("--out", type=Path, required=True, help="the .jsonl file to write")
    detect.add_argument("--force", action="store_true", help="overwrite an existing --out file")
    add_settings(detect, "detect")
    info = commands.add_parser("info", help=INFO, description=INFO)
    info.add_argument("log", type=Path, help="an .mcap file or a rosbag2 folder")
    add_settings(info, "info")


def run_detect(args: argparse.Namespace) -> int:
    out: Path = args.out
    config = map_config(settings_from(args, "detect"))  # the front end's part, and workers
    check_output_file(out, [args.log], force=args.force)
    with ProgressBar(f"reading {args.log.name}") as bar:
        result = extract(args.log, config.frontend, progress=bar, workers=config.workers)
    written = write_observations(out, result.observations, result.odometry)
    markers = sorted({o.marker_id for o in result.observations})
    print(
        f"{result.frames} frames ({result.frames_with_depth} with depth), {written} "
        f"observations of {len(markers)} markers, {len(result.odometry)} odometry samples "
        f"-> {out}"
    )
    for reason, count in sorted(result.skipped.items()):
        print(f"  {count} frame(s): {reason}")
    for note in result.notes:
        print(f"  note: {note}")
    for warning in result.warnings:
        print(f"markergraph detect: warning: {warning}", file=sys.stderr)
    return 0


def run_info(args: argparse.Namespace) -> int:
    config = map_config(settings_from(args, "info")).frontend
    topics = log_topics(args.log)
    width = max(len(t.topic) for t in topics) if topics else 5
    print(f"{'topic':<{width}}  {'type':<36} messages")
    for topic in topics:
        print(f"{topic.topic:<{width}}  {topic.schema:<36} {topic.count}")
    choice = choose_topics(args.log, topics, config)
    print("\nwould use:")
    for role, name in (
        ("colour", choice.color),
        ("depth", choice.depth),
        ("camera info", choice.camera_info),
        ("odometry", choice.odom),
        ("camera mount", choice.tf_static),
        ("detections", ", ".join(choice.detections) or None),
    ):
        print(f"  {role:<12} {name or '(none)'}")
    return 0
