"""The ``markergraph`` argument parser: every subcommand's flags, and a usage mistake as one line.

Importing this module imports every subcommand's module, and so most of markergraph (GTSAM,
OpenCV): :func:`markergraph.cli.main` imports it only once its signal handlers are in place.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from importlib.metadata import PackageNotFoundError, version
from typing import NoReturn

from markergraph.cli import _compare, _frontend, _map, _mapfile, _simulate

__all__ = ["EXIT_USAGE", "build_parser", "parse_command_line"]

# A usage mistake is the user's, as bad input is: exit 1, as README's exit codes say. argparse's
# own 2 means a bug of ours here.
EXIT_USAGE = 1


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage mistake is one line naming it and where help is, exit 1.

    argparse prints the whole usage first (up to 26 lines for ``map``), which buries the line
    that says what was wrong, and exits 2, which here means a bug of ours.
    """

    def error(self, message: str) -> NoReturn:
        said = " ".join(message.split())  # one line, whatever argparse or a type= put in it
        self.exit(EXIT_USAGE, f"{self.prog}: error: {said} (see `{self.prog} --help`)\n")


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


def parse_command_line(
    argv: Sequence[str] | None,
) -> tuple[argparse.ArgumentParser, argparse.Namespace]:
    """The parser and the arguments parsed; a usage mistake exits 1 with one line.

    argparse reports a flag no subcommand knows as the top-level parser's mistake (``markergraph:
    error: unrecognized arguments``); it is reported here as the subcommand's, whose help lists
    the flags.
    """
    parser = build_parser()
    args, extras = parser.parse_known_args(argv)
    if extras:
        commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        named = commands.choices.get(getattr(args, "command", None) or "", parser)
        named.error(f"unrecognized arguments: {' '.join(extras)}")
    return parser, args
