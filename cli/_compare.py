"""``markergraph compare``: a map scored against a reference, as ``evo_ape`` scores a path."""

from __future__ import annotations

import argparse
from pathlib import Path

from markergraph.cli._commands import summary
from markergraph.common.files import check_output_file
from markergraph.compare import compare, map_points, read_reference
from markergraph.compare_text import comparison_document, comparison_lines, plot_title
from markergraph.markermap import MarkerMap, write_json

COMPARE = summary("compare")


def add_parser(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser("compare", help=COMPARE, description=COMPARE)
    parser.add_argument("map", type=Path, help="a map.json written by markergraph map")
    parser.add_argument(
        "reference",
        type=Path,
        help="another map.json, a CSV survey (id,x,y[,z][,yaw]; m, rad), TagSLAM's "
        "tagslam.yaml or an ArUco map (.yml, as export --format aruco-yaml writes)",
    )
    parser.add_argument(
        "--home",
        type=int,
        metavar="ID",
        help="the marker the home-fixed figures align on (default: the map's home marker if "
        "in common, else the smallest common id)",
    )
    parser.add_argument(
        "--scale", action="store_true", help="fit a scale too (a similarity) and print it"
    )
    parser.add_argument("--plot", type=Path, metavar="FILE.png", help="draw both maps aligned")
    parser.add_argument("--json", type=Path, metavar="FILE", help="write the figures as JSON")
    parser.add_argument("--force", action="store_true", help="overwrite --plot / --json files")


def run(args: argparse.Namespace) -> int:
    inputs = [args.map, args.reference]
    for out in (args.plot, args.json):
        if out is not None:
            check_output_file(out, inputs, force=args.force)
    marker_map = MarkerMap.load(args.map)
    refs, kind = read_reference(args.reference)
    result = compare(
        map_points(marker_map),
        refs,
        map_dimensions=marker_map.dimensions,
        home_id=args.home,
        default_home=marker_map.home_id,
        with_scale=args.scale,
    )
    print(
        f"map {args.map} ({marker_map.dimensions}-D, {len(marker_map.every_marker)} markers) "
        f"against {args.reference} ({kind}, {len(refs)} markers)"
    )
    for line in comparison_lines(result):
        print(line)
    if args.json is not None:
        write_json(args.json, comparison_document(result, str(args.map), str(args.reference), kind))
        print(f"wrote {args.json}")
    if args.plot is not None:
        from markergraph.compare_plot import plot_comparison

        plot_comparison(result, args.plot, plot_title(args.map, args.reference))
        print(f"wrote {args.plot}")
    return 0
