"""``markergraph detect`` and ``markergraph info``: the front end from the command line."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from markergraph.frontend.jsonl import write_observations
from markergraph.frontend.log import log_topics
from markergraph.frontend.pipeline import FrontendConfig, choose_topics, extract
from markergraph.frontend.progress import ProgressBar
from markergraph.frontend.yaw import YawMethod

DETECT = "detect markers in an MCAP log and write observations as JSON lines"
INFO = "list what an MCAP log holds and which topics would be used"


def add_frontend_options(parser: argparse.ArgumentParser) -> None:
    """Options every command that reads a log shares."""
    group = parser.add_argument_group("markers and topics")
    group.add_argument(
        "--dictionary",
        default="DICT_4X4_50",
        help="OpenCV dictionary name or dictionary file (default DICT_4X4_50)",
    )
    group.add_argument(
        "--marker-size",
        type=float,
        default=0.2,
        metavar="M",
        help="side of the markers' black square in metres (default 0.2)",
    )
    group.add_argument(
        "--yaw-method",
        choices=[m.value for m in YawMethod],
        default="pnp",
        help="how theta comes from the corners (default pnp)",
    )
    group.add_argument(
        "--ids",
        type=int,
        nargs="+",
        default=None,
        metavar="ID",
        help="only these marker ids (default: all the dictionary's)",
    )
    for name in ("color", "depth", "camera-info", "odom"):
        group.add_argument(
            f"--{name}-topic", default=None, help=f"{name} topic (default: chosen automatically)"
        )


def frontend_config(args: argparse.Namespace) -> FrontendConfig:
    if args.marker_size <= 0:
        raise ValueError(f"--marker-size must be positive, got {args.marker_size}")
    return FrontendConfig(
        dictionary=args.dictionary,
        marker_length_m=args.marker_size,
        method=YawMethod(args.yaw_method),
        allowed_ids=None if args.ids is None else tuple(args.ids),
        color_topic=args.color_topic,
        depth_topic=args.depth_topic,
        camera_info_topic=args.camera_info_topic,
        odom_topic=args.odom_topic,
    )


def add_parsers(commands: argparse._SubParsersAction) -> None:
    detect = commands.add_parser("detect", help=DETECT, description=DETECT)
    detect.add_argument("log", type=Path, help="an .mcap file or a rosbag2 folder")
    detect.add_argument("--out", type=Path, required=True, help="the .jsonl file to write")
    detect.add_argument("--force", action="store_true", help="overwrite an existing --out file")
    detect.add_argument(
        "--workers",
        type=int,
        default=1,
        metavar="N",
        help="processes that decode and detect (default 1)",
    )
    add_frontend_options(detect)
    info = commands.add_parser("info", help=INFO, description=INFO)
    info.add_argument("log", type=Path, help="an .mcap file or a rosbag2 folder")
    add_frontend_options(info)


def run_detect(args: argparse.Namespace) -> int:
    out: Path = args.out
    if out.exists() and not args.force:
        raise FileExistsError(f"{out} exists; pass --force to overwrite it")
    if not out.parent.is_dir():
        raise FileNotFoundError(f"cannot write {out}: {out.parent} is not a folder")
    with ProgressBar(f"reading {args.log.name}") as bar:
        result = extract(args.log, frontend_config(args), progress=bar, workers=args.workers)
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
    topics = log_topics(args.log)
    width = max(len(t.topic) for t in topics) if topics else 5
    print(f"{'topic':<{width}}  {'type':<36} messages")
    for topic in topics:
        print(f"{topic.topic:<{width}}  {topic.schema:<36} {topic.count}")
    choice = choose_topics(args.log, topics, frontend_config(args))
    print("\nwould use:")
    for role, name in (
        ("colour", choice.color),
        ("depth", choice.depth),
        ("camera info", choice.camera_info),
        ("odometry", choice.odom),
        ("camera mount", choice.tf_static),
    ):
        print(f"  {role:<12} {name or '(none)'}")
    return 0
