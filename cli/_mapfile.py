"""``markergraph export`` and ``markergraph heading``: working with a written map.json."""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path

from markergraph.common.errors import SettingsError
from markergraph.common.files import check_output_file
from markergraph.estimator.paper import Form
from markergraph.formats import ExportFormat, export_map
from markergraph.markermap import MarkerMap, MarkerMapError

EXPORT = "write a map.json in another tool's format"
HEADING = "the paper's target heading from a localisation on one marker to another"


def add_parsers(commands: argparse._SubParsersAction) -> None:
    export = commands.add_parser("export", help=EXPORT, description=EXPORT)
    export.add_argument("map", type=Path, help="a map.json written by markergraph map")
    export.add_argument(
        "--format",
        required=True,
        choices=[f.value for f in ExportFormat],
        help="aruco-yaml (ArUco MarkerMap), fiducial-slam (map.txt, degrees), "
        "tagslam (a static body, rotation vectors) or csv",
    )
    export.add_argument(
        "--out",
        required=True,  # kept a string: Path("./-") would read as "-"
        metavar="FILE",
        help="the file to write; - writes to standard output (a file named - is ./-)",
    )
    export.add_argument("--force", action="store_true", help="overwrite an existing --out file")
    head = commands.add_parser("heading", help=HEADING, description=HEADING)
    head.add_argument("map", type=Path, help="a map.json written by markergraph map")
    head.add_argument(
        "--from",
        dest="source",
        type=int,
        required=True,
        metavar="A",
        help="the marker the robot is localised on",
    )
    head.add_argument(
        "--at",
        required=True,
        metavar="D,THETA",
        help="the robot's centred observation of A: distance [m], theta [deg]",
    )
    head.add_argument("--to", type=int, required=True, metavar="C", help="the target marker")


def run_export(args: argparse.Namespace) -> int:
    if args.out == "-":
        return _export_to_stdout(args)
    out = Path(args.out)
    check_output_file(out, [args.map], force=args.force)
    marker_map = MarkerMap.load(args.map)
    export_map(marker_map, ExportFormat(args.format), out)
    print(f"wrote {len(marker_map.markers)} markers as {args.format} to {args.out}")
    return 0


def _export_to_stdout(args: argparse.Namespace) -> int:
    """The export on standard output, and nothing else there (a pipe takes it as it is)."""
    marker_map = MarkerMap.load(args.map)
    # The same bytes as a file: the one writer writes a file of its own, copied out whole once
    # written, so an export that fails half-way puts nothing on standard output.
    with tempfile.TemporaryDirectory(prefix="markergraph-export-") as folder:
        written = Path(folder) / "export"
        export_map(marker_map, ExportFormat(args.format), written)
        data = written.read_bytes()
    sys.stdout.flush()
    binary = getattr(sys.stdout, "buffer", None)  # text-only where a caller replaced stdout
    if binary is None:
        sys.stdout.write(data.decode("utf-8"))
    else:
        binary.write(data)
    sys.stdout.flush()
    return 0


def run_heading(args: argparse.Namespace) -> int:
    marker_map = MarkerMap.load(args.map)
    try:
        d_text, theta_text = args.at.split(",")
        d, theta = float(d_text), math.radians(float(theta_text))
    except ValueError:
        raise SettingsError(f"--at takes D,THETA (metres, degrees), got {args.at!r}") from None
    if not (math.isfinite(d) and d > 0 and math.isfinite(theta)):
        raise SettingsError(f"--at takes a positive distance and a finite angle, got {args.at!r}")
    try:
        distance, turn = marker_map.heading(args.source, d, theta, args.to)
        printed = marker_map.heading(args.source, d, theta, args.to, Form.PAPER)
    except MarkerMapError as error:
        raise MarkerMapError(f"{args.map}: {error}") from None
    side = "counter-clockwise" if turn >= 0 else "clockwise"
    print(
        f"turn {abs(math.degrees(turn)):.1f} deg {side} from facing marker {args.source}, "
        f"then drive {distance:.3f} m to marker {args.to}"
    )
    print(
        f"(the paper's printed formula says turn {math.degrees(printed[1]):.1f} deg, "
        f"drive {printed[0]:.3f} m)"
    )
    return 0
