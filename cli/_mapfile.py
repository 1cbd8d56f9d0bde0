"""``markergraph export`` and ``markergraph heading``: working with a written map.json."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import gtsam

from markergraph.estimator.export import MAP_SCHEMA, ExportFormat, export_map
from markergraph.estimator.paper import Form, edge_from_pose2, heading

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
    export.add_argument("--out", type=Path, required=True, help="the file to write")
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


def _load(path: Path) -> dict[str, Any]:
    try:
        document = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as error:
        raise ValueError(f"{path}: not a readable map.json ({error})") from error
    if not isinstance(document, dict) or document.get("schema") != MAP_SCHEMA:
        raise ValueError(f"{path}: not a {MAP_SCHEMA} document")
    return document


def run_export(args: argparse.Namespace) -> int:
    if args.out.exists() and not args.force:
        raise FileExistsError(f"{args.out} exists; pass --force to overwrite it")
    document = _load(args.map)
    export_map(document, ExportFormat(args.format), args.out)
    print(f"wrote {len(document['markers'])} markers as {args.format} to {args.out}")
    return 0


def run_heading(args: argparse.Namespace) -> int:
    document = _load(args.map)
    poses = {m["id"]: gtsam.Pose2(m["x"], m["y"], m["yaw"]) for m in document["markers"]}
    for marker_id in (args.source, args.to):
        if marker_id not in poses:
            raise ValueError(
                f"{args.map}: no marker {marker_id} in the map "
                f"(it has {', '.join(map(str, sorted(poses)))})"
            )
    try:
        d_text, theta_text = args.at.split(",")
        d, theta = float(d_text), math.radians(float(theta_text))
    except ValueError as error:
        raise ValueError(f"--at takes D,THETA (metres, degrees), got {args.at!r}") from error
    e_ac = edge_from_pose2(poses[args.source].between(poses[args.to]))
    distance, turn = heading(e_ac, d, theta, Form.EXACT)
    printed = heading(e_ac, d, theta, Form.PAPER)
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
