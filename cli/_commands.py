"""The subcommands: where each one's flags and run live, and its line in ``markergraph --help``.

A command's module is imported only when that command is named: ``markergraph --help`` imports
none of them, ``markergraph info LOG`` only the front end's (no GTSAM, no plots).
"""

from __future__ import annotations

import argparse
import importlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import cast

__all__ = ["COMMANDS", "Command", "command", "summary"]


@dataclass(frozen=True, slots=True)
class Command:
    """One subcommand.

    Attributes:
        name: what the user types (``markergraph NAME``).
        module: the ``markergraph.cli`` module holding its parser and its run.
        add: that module's function adding the subcommand's parser to the subparsers.
        run: that module's function running the parsed arguments, returning the exit code.
        summary: its line in ``markergraph --help`` and the start of its own help.
    """

    name: str
    module: str
    add: str
    run: str
    summary: str

    def adder(self) -> Callable[[argparse._SubParsersAction], None]:
        """The function adding this command's parser (its module imported)."""
        return cast(Callable[[argparse._SubParsersAction], None], self._attribute(self.add))

    def runner(self) -> Callable[[argparse.Namespace], int]:
        """The function running this command (its module imported)."""
        return cast(Callable[[argparse.Namespace], int], self._attribute(self.run))

    def _attribute(self, name: str) -> object:
        return getattr(importlib.import_module(f"markergraph.cli.{self.module}"), name)


# In the order ``markergraph --help`` lists them.
COMMANDS = (
    Command("map", "_map", "add_parser", "run",
            "estimate a corrected marker map from an MCAP log (default: the bundled sample)"),
    Command("localize", "_map", "add_localize_parser", "run_localize",
            "the robot's path in a saved map, and which of its markers moved"),
    Command("simulate", "_simulate", "add_parser", "run",
            "simulate a scenario and write a ROS 2 MCAP log with ground truth"),
    Command("detect", "_frontend", "add_detect_parser", "run_detect",
            "detect markers in an MCAP log and write observations as JSON lines"),
    Command("info", "_frontend", "add_info_parser", "run_info",
            "check that a log can be mapped: what it holds and what map would read from it"),
    Command("export", "_mapfile", "add_export_parser", "run_export",
            "write a map.json in another tool's format"),
    Command("heading", "_mapfile", "add_heading_parser", "run_heading",
            "the paper's target heading from a localisation on one marker to another, with its "
            "1-sigma from the map's covariances: a straight line that knows nothing of walls or "
            "obstacles"),
    Command("compare", "_compare", "add_parser", "run",
            "score a map.json against a reference map or survey"),
)  # fmt: skip


def command(name: str) -> Command:
    """The command called ``name``.

    Raises:
        KeyError: no command has that name.
    """
    return _BY_NAME[name]


def summary(name: str) -> str:
    """The named command's one-line summary."""
    return _BY_NAME[name].summary


_BY_NAME = {c.name: c for c in COMMANDS}
