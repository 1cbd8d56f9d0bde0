"""The ``markergraph`` command: a thin shell that parses arguments and calls library functions.

Exit codes: 0 done, 1 a problem with the input, the settings or the output (one line on stderr
naming the file, topic or value: every :class:`MarkerGraphError`, and ``OSError``), 2 a bug of
ours, 130 interrupted (Ctrl-C).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from importlib.metadata import PackageNotFoundError, version
from typing import NoReturn

from markergraph.cli import _compare, _frontend, _map, _mapfile, _simulate
from markergraph.common.errors import MarkerGraphError

__all__ = ["main"]

EXIT_OK, EXIT_USER_ERROR, EXIT_INTERNAL_ERROR, EXIT_INTERRUPTED = 0, 1, 2, 130


class _Parser(argparse.ArgumentParser):
    """argparse exits with 2 on a usage error; here 2 means an internal error, so use 1."""

    def error(self, message: str) -> NoReturn:
        self.print_usage(sys.stderr)
        self.exit(EXIT_USER_ERROR, f"{self.prog}: error: {message}\n")


def _version() -> str:
    try:
        return version("markergraph")
    except PackageNotFoundError:  # running from a source tree that is not installed
        return "unknown"


def build_parser() -> argparse.ArgumentParser:
    """The argument parser for every subcommand."""
    parser = _Parser(
        prog="markergraph",
        description="Turn a robot's recorded log into a corrected map of the fiducial markers on "
        "its walls.",
    )
    parser.add_argument("--version", action="version", version=f"markergraph {_version()}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    _map.add_parser(commands)
    _map.add_localize_parser(commands)
    _simulate.add_parser(commands)
    _frontend.add_parsers(commands)
    _mapfile.add_parsers(commands)
    _compare.add_parser(commands)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return EXIT_OK
    try:
        if args.command == "map":
            return _map.run(args)
        if args.command == "localize":
            return _map.run_localize(args)
        if args.command == "simulate":
            return _simulate.run(args)
        if args.command == "detect":
            return _frontend.run_detect(args)
        if args.command == "info":
            return _frontend.run_info(args)
        if args.command == "compare":
            return _compare.run(args)
        if args.command == "export":
            return _mapfile.run_export(args)
        return _mapfile.run_heading(args)
    except (MarkerGraphError, OSError) as error:
        print(f"markergraph {args.command}: {error}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print(f"markergraph {args.command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as error:  # a bug of ours: say so plainly
        if os.environ.get("MARKERGRAPH_DEBUG"):
            raise
        print(
            f"markergraph {args.command}: internal error: {error!r} "
            "(set MARKERGRAPH_DEBUG=1 for the traceback)",
            file=sys.stderr,
        )
        return EXIT_INTERNAL_ERROR
