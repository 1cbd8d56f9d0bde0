"""``markergraph detect`` and ``markergraph info``: the front end from the command line.

``info`` is a preflight: it exits 0 when the log can be mapped, :data:`EXIT_CANNOT_MAP` (3)
when it cannot (the verdict line says why), and 1, as every command, when the log cannot be
read or a setting is bad.
"""

from __future__ import annotations

import argparse
import sys
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import TYPE_CHECKING

from markergraph.cli._commands import summary
from markergraph.cli._settings import add_settings, add_verbosity, say_notes, settings_from
from markergraph.settings import map_config

if TYPE_CHECKING:
    from markergraph.frontend.preflight_report import ImageStats, Intrinsics, Mount, Preflight

DETECT = summary("detect")
INFO = summary("info")
INFO_EPILOG = (
    "Prints the log's duration and time range, each topic's message count, rate and type, the "
    "colour image's size and encoding, whether depth is aligned to it, the camera model, the TF "
    "chain from the odometry's body to the camera, the odometry and its rate, then a verdict: "
    "'can map: yes' or 'cannot map: <why>'. Exit codes: 0 can map, 3 cannot map, 1 a log that "
    "cannot be read or a bad setting."
)
LOG_HELP = "an .mcap file, a rosbag2 folder (MCAP or SQLite) or a ROS 1 .bag"
EXIT_CANNOT_MAP = 3


def add_detect_parser(commands: argparse._SubParsersAction) -> None:
    detect = commands.add_parser("detect", help=DETECT, description=DETECT)
    detect.add_argument("log", type=Path, help=LOG_HELP)
    detect.add_argument("--out", type=Path, required=True, help="the .jsonl file to write")
    detect.add_argument("--force", action="store_true", help="overwrite an existing --out file")
    add_verbosity(detect)
    add_settings(detect, "detect")


def add_info_parser(commands: argparse._SubParsersAction) -> None:
    info = commands.add_parser("info", help=INFO, description=INFO, epilog=INFO_EPILOG)
    info.add_argument("log", type=Path, help=LOG_HELP)
    add_settings(info, "info")


def run_detect(args: argparse.Namespace) -> int:
    from markergraph.common.files import check_output_file
    from markergraph.common.numbers import counted
    from markergraph.common.progress import ProgressBar
    from markergraph.formats.observations import write_observations
    from markergraph.frontend.pipeline import extract

    out: Path = args.out
    config = map_config(settings_from(args, "detect"))  # the front end's part, and workers
    check_output_file(out, [args.log], force=args.force)
    with ProgressBar(f"reading {args.log.name}", quiet=args.quiet) as bar:
        result = extract(args.log, config.frontend, progress=bar, workers=config.workers)
    written = write_observations(
        out, result.observations, result.odometry, result.mount, result.topics.odom,
        result.odometry_evidence, result.frames,
    )  # fmt: skip
    markers = sorted({o.marker_id for o in result.observations})
    print(
        f"{result.frames} frames ({result.frames_with_depth} with depth), {written} "
        f"observations of {counted(len(markers), 'marker')}, "
        f"{len(result.odometry)} odometry samples -> {out}"
    )
    for reason, count in sorted(result.skipped.items()):
        print(f"  {counted(count, 'frame')}: {reason}")
    say_notes(result.notes, quiet=args.quiet)
    for warning in result.warnings:
        print(f"markergraph detect: warning: {warning}", file=sys.stderr)
    return 0


def run_info(args: argparse.Namespace) -> int:
    from markergraph.frontend.preflight import preflight

    config = map_config(settings_from(args, "info")).frontend
    report = preflight(args.log, config)
    _print_preflight(report, config.dictionary)
    return 0 if report.can_map else EXIT_CANNOT_MAP


def _utc(t_ns: int) -> str:
    """A log time as ISO 8601 UTC, to the millisecond."""
    whole = datetime.fromtimestamp(t_ns // 1_000_000_000, timezone.utc)
    moment = whole + timedelta(microseconds=(t_ns % 1_000_000_000) // 1000)
    return moment.isoformat(timespec="milliseconds").replace("+00:00", "Z")


def _rate(rate_hz: float | None) -> str:
    return "-" if rate_hz is None else f"{rate_hz:.2f}"


def _camera_text(intrinsics: Intrinsics | None) -> str:
    """Distortion model and K, or none."""
    if intrinsics is None:
        return "none"
    c = intrinsics.camera
    distortion = ", ".join(f"{d:.6g}" for d in c.distortion)
    return (
        f"{intrinsics.model_name}, K [{c.fx:g} 0 {c.cx:g}; 0 {c.fy:g} {c.cy:g}; 0 0 1], "
        f"{f'D ({distortion})' if distortion else 'no distortion'} ({intrinsics.source})"
    )


def _mount_text(mount: Mount | None, missing: str) -> str:
    """The chain of frames to the camera, or where else its mount comes from."""
    if mount is None:
        return f"none: {missing}"
    if mount.frames:
        pose = f": the camera {mount.pose}" if mount.pose else ""
        return f"{' -> '.join(mount.frames)} ({mount.source}){pose}"
    return f"none: the camera's pose from {mount.source}"


def _image_text(image: ImageStats | None, topic: str | None, rate_hz: float | None) -> str:
    if image is None:
        return topic or "none"
    return (
        f"{image.topic}, size {image.width}x{image.height}, encoding {image.encoding}, "
        f"frame {image.frame_id}, {_rate(rate_hz)} Hz"
    )


def _alignment(color: ImageStats | None, depth: ImageStats | None) -> str:
    if color is None or depth is None:
        return ""
    if (depth.width, depth.height) != (color.width, color.height):
        return "not aligned to colour (another size)"
    if depth.frame_id != color.frame_id:
        return "the colour's size, but another frame"
    return "aligned to colour (same size and frame)"


def _print_preflight(report: Preflight, dictionary: str) -> None:
    """The report; columns sized to their contents, the type (the longest) last."""
    print(f"log          {report.path}")
    if report.start_ns is None or report.end_ns is None:
        print("duration     no messages")
    else:
        print(
            f"duration     {report.duration_s:.3f} s, {_utc(report.start_ns)} to "
            f"{_utc(report.end_ns)} ({report.start_ns * 1e-9:.3f} to {report.end_ns * 1e-9:.3f} s)"
        )
    rows = [(t.topic, str(t.count), _rate(t.rate_hz), t.schema or "?") for t in report.topics]
    header = ("topic", "messages", "rate [Hz]", "type")
    widths = [max(len(row[i]) for row in [header, *rows]) for i in range(3)]
    print()
    for topic, count, rate, schema in [header, *rows]:
        print(f"{topic:<{widths[0]}}  {count:>{widths[1]}}  {rate:>{widths[2]}}  {schema}")
    print()
    choice = report.choice
    for d in report.detections:
        print(f"detections   {d.topic}, frame {d.frame_id}, {_rate(report.rate_hz(d.topic))} Hz")
        print(f"  camera     {_camera_text(d.intrinsics)}")
        print(f"  TF chain   {_mount_text(d.mount, 'the topic is left out')}")
    if not report.detections:
        color, depth = report.color, report.depth
        print(f"colour       {_image_text(color, choice.color, report.rate_hz(choice.color))}")
        depth_text = _image_text(depth, choice.depth, report.rate_hz(choice.depth))
        aligned = _alignment(color, depth)
        print(f"depth        {depth_text}{', ' + aligned if aligned else ''}")
        print(f"camera       {_camera_text(report.intrinsics)}")
        assumed = "the configured camera mount is assumed" if color else "no camera"
        print(f"TF chain     {_mount_text(report.mount, assumed)}")
        print(f"dictionary   {dictionary}")
    odometry = "none"
    if choice.odom:
        odometry = f"{choice.odom}, {_rate(report.rate_hz(choice.odom))} Hz"
        if report.odometry_frame:
            odometry += f", child frame {report.odometry_frame}"
    print(f"odometry     {odometry}")
    print()
    print("can map: yes" if report.can_map else f"cannot map: {'; '.join(report.blockers)}")
    for warning in report.warnings:
        print(f"warning: {warning}")
