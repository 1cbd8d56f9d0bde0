"""``markergraph export`` and ``markergraph heading``: working with a written map.json."""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path

from markergraph.cli._commands import summary
from markergraph.common.errors import SettingsError
from markergraph.common.files import check_output_file
from markergraph.estimator.paper import Form
from markergraph.formats import ExportFormat, export_map
from markergraph.heading_sigma import HeadingSigma, heading_sigma
from markergraph.markermap import MarkerMap, MarkerMapError

EXPORT = summary("export")
HEADING = summary("heading")


def add_export_parser(commands: argparse._SubParsersAction) -> None:
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


def add_heading_parser(commands: argparse._SubParsersAction) -> None:
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


# --at's bounds. The largest marker a setting allows (10 m) spans the 20 px a detector needs out
# to about 500 m with a 1000 px focal length: beyond 1 km no camera saw it. A marker is seen from
# its front only, |theta| < 90 deg.
MAX_AT_DISTANCE_M = 1000.0
MAX_AT_THETA_DEG = 90.0


def parse_at(text: str) -> tuple[float, float]:
    """``--at D,THETA``: the distance [m] and theta [rad] of a centred observation.

    Raises:
        SettingsError: not two numbers, a distance not above 0 and at most
            :data:`MAX_AT_DISTANCE_M`, or theta not within +-:data:`MAX_AT_THETA_DEG` deg
            (NaN and infinities included), naming the value.
    """
    try:
        d_text, theta_text = text.split(",")
        d, theta_deg = float(d_text), float(theta_text)
    except ValueError:
        raise SettingsError(f"--at takes D,THETA (metres, degrees), got {text!r}") from None
    if not 0 < d <= MAX_AT_DISTANCE_M:  # False for NaN too
        raise SettingsError(
            f"--at {text}: the distance must be above 0 and at most {MAX_AT_DISTANCE_M:g} m "
            f"(no camera sees a marker further), got {d:g}"
        )
    if not abs(theta_deg) < MAX_AT_THETA_DEG:
        raise SettingsError(
            f"--at {text}: theta must be within +-{MAX_AT_THETA_DEG:g} deg (a marker is seen "
            f"from its front), got {theta_deg:g}"
        )
    return d, math.radians(theta_deg)


def run_heading(args: argparse.Namespace) -> int:
    d, theta = parse_at(args.at)  # before the map: a mistake on the command line first
    marker_map = MarkerMap.load(args.map)
    try:
        distance, turn = marker_map.heading(args.source, d, theta, args.to)
        printed = marker_map.heading(args.source, d, theta, args.to, Form.PAPER)
        sigma = _sigma_or_none(marker_map, args.source, d, theta, args.to)
    except MarkerMapError as error:
        raise MarkerMapError(f"{args.map}: {error}") from None
    side = "counter-clockwise" if turn >= 0 else "clockwise"
    print(
        f"turn {abs(math.degrees(turn)):.1f} deg {side} from facing marker {args.source}, "
        f"then drive {distance:.3f} m to marker {args.to}"
    )
    if sigma is None:
        print("1 sigma: none (the map has no covariances)")
    else:
        print(
            f"1 sigma: turn +- {math.degrees(sigma.turn_rad):.1f} deg, drive +- "
            f"{sigma.distance_m:.3f} m (first order from the two markers' covariances in the map; "
            "the robot's own distance and angle taken as exact)"
        )
    print(
        "a straight line from the robot to the marker: it ignores walls and obstacles, so plan "
        "the path itself with a map of the free space"
    )
    print(
        f"(the paper's printed formula says turn {math.degrees(printed[1]):.1f} deg, "
        f"drive {printed[0]:.3f} m)"
    )
    return 0


def _sigma_or_none(
    marker_map: MarkerMap, source: int, d: float, theta: float, target: int
) -> HeadingSigma | None:
    """The heading's 1-sigma, or None for a map written without covariances."""
    markers = marker_map.markers
    if markers[source].covariance is None or markers[target].covariance is None:
        return None
    return heading_sigma(marker_map, source, d, theta, target)
