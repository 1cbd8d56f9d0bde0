"""The ``markergraph`` argument parser: every subcommand's flags, and a usage mistake as one line.

Parsing a command line builds the flags of the subcommand it names alone, and so imports only
that subcommand's module (``map``'s brings GTSAM and the plots; ``info``'s neither); the others
are listed by their summaries. :func:`markergraph.cli.main` imports this module once its signal
handlers are in place.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import Any, NoReturn

from markergraph.cli._commands import COMMANDS

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
    # importlib.metadata costs more than the rest of `markergraph --help`: read when asked.
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("markergraph")
    except PackageNotFoundError:  # running from a source tree that is not installed
        return "unknown"


class _VersionAction(argparse.Action):
    """``--version``: argparse's own, but the installed version is looked up only when asked."""

    def __init__(self, option_strings: Sequence[str], dest: str, **kwargs: Any) -> None:
        super().__init__(
            option_strings, dest, nargs=0, help="show program's version number and exit", **kwargs
        )

    def __call__(self, parser: argparse.ArgumentParser, *_: object) -> None:
        print(f"markergraph {_version()}")
        parser.exit()


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The argument parser.

    Args:
        only: the one subcommand whose flags are built (the others are listed, flagless); None
            builds every subcommand's.
    """
    parser = _Parser(
        prog="markergraph",
        description="Turn a robot's recorded log into a corrected map of the fiducial markers on "
        "its walls.",
    )
    parser.add_argument("--version", action=_VersionAction, default=argparse.SUPPRESS)
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for command in COMMANDS:
        if only is None or command.name == only:
            command.adder()(commands)
        else:
            commands.add_parser(command.name, help=command.summary)
    return parser


def _named_command(argv: Sequence[str]) -> str:
    """The subcommand ``argv`` names: its first word that is not a flag (the top level has no
    flag that takes a value), or "" when there is none."""
    return next((word for word in argv if not word.startswith("-")), "")


def parse_command_line(
    argv: Sequence[str] | None,
) -> tuple[argparse.ArgumentParser, argparse.Namespace]:
    """The parser and the arguments parsed; a usage mistake exits 1 with one line.

    argparse reports a flag no subcommand knows as the top-level parser's mistake (``markergraph:
    error: unrecognized arguments``); it is reported here as the subcommand's, whose help lists
    the flags.
    """
    words = sys.argv[1:] if argv is None else argv
    parser = build_parser(only=_named_command(words))
    args, extras = parser.parse_known_args(argv)
    if extras:
        commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        named = commands.choices.get(getattr(args, "command", None) or "", parser)
        named.error(f"unrecognized arguments: {' '.join(extras)}")
    return parser, args
