"""The ``markergraph`` command: a thin shell that parses arguments and calls library functions.

Exit codes: 0 done, 1 user error (one line on stderr, no traceback), 2 internal error.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from importlib.metadata import PackageNotFoundError, version

__all__ = ["main"]

EXIT_OK, EXIT_USER_ERROR, EXIT_INTERNAL_ERROR = 0, 1, 2

# Subcommands that later issues fill in; each still answers --help and says what it will do.
PLANNED_COMMANDS = {
    "map": "estimate a corrected marker map from an MCAP log (default: the bundled sample)",
    "detect": "detect markers in an MCAP log and write observations as JSON lines",
    "simulate": "simulate a world and write a ROS 2 MCAP log with ground truth",
    "info": "list what an MCAP log holds and which topics would be used",
    "export": "write a map.json in another tool's format",
    "heading": "the paper's target heading from a localisation on one marker to another",
}


def _version() -> str:
    try:
        return version("markergraph")
    except PackageNotFoundError:  # running from a source tree that is not installed
        return "unknown"


def build_parser() -> argparse.ArgumentParser:
    """The argument parser for every subcommand."""
    parser = argparse.ArgumentParser(
        prog="markergraph",
        description="Turn a robot's recorded log into a corrected map of the fiducial markers on "
        "its walls.",
    )
    parser.add_argument("--version", action="version", version=f"markergraph {_version()}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, summary in PLANNED_COMMANDS.items():
        commands.add_parser(name, help=summary, description=summary)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return EXIT_OK
    print(f"markergraph {args.command}: not built yet in {_version()}", file=sys.stderr)
    return EXIT_USER_ERROR
