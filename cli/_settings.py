"""Settings on the command line: ``--config FILE`` and one flag per setting, flags winning.

Each setting is declared once, flag and commands included, by the library
(:data:`markergraph.settings.SETTINGS`); the flags are built from that declaration here.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from markergraph.common.errors import SettingsError
from markergraph.settings import SETTINGS, read_config_file

__all__ = ["add_settings", "add_verbosity", "say_notes", "settings_from"]


_GROUPS = {
    "": "settings (a flag overrides --config; (file: key) names it in the file)",
    "topics": "topics",
    "rig": "a rig's cameras (logs of marker detections)",
    "camera": "camera: its mount (without /tf_static) and timing",
    "odometry": "odometry",
    "noise": "noise model",
    "overlay": "overlay.mcap",
}


def _dest(key: str) -> str:
    return "setting_" + key.replace(".", "_")


def add_settings(parser: argparse.ArgumentParser, command: str) -> None:
    """``--config`` and a flag for each setting that applies to ``command``, with its default."""
    groups = {section: parser.add_argument_group(title) for section, title in _GROUPS.items()}
    groups[""].add_argument(
        "--config",
        type=Path,
        metavar="FILE",
        help="a TOML (.toml) or YAML (.yaml, .yml) file of the settings below",
    )
    for setting in SETTINGS:
        flag = setting.flag
        if command not in flag.commands:
            continue
        shown = setting.default
        default = "" if shown in (None, {}) else f", default {shown}"
        options: dict[str, Any] = {
            "dest": _dest(setting.key),
            "default": argparse.SUPPRESS,  # absent unless given, so the file's value stands
            "help": f"{setting.help} (file: {setting.key}{default})",
            "type": flag.type,
        }
        if setting.choices:
            options["choices"] = setting.choices
        if flag.metavar:
            options["metavar"] = flag.metavar
        if flag.nargs:
            options["nargs"] = flag.nargs
        groups[setting.key.rpartition(".")[0]].add_argument(flag.flag, **options)


def settings_from(args: argparse.Namespace, command: str) -> dict[str, Any]:
    """The settings the file and the flags give, each checked where it comes from so that an
    error names the file and key or the flag (defaults are filled in by ``MapConfig``).

    Raises:
        SettingsError: a bad file or value, naming the file and key or the flag.
    """
    values = read_config_file(args.config) if args.config is not None else {}
    for setting in SETTINGS:
        if command in setting.flag.commands and hasattr(args, _dest(setting.key)):
            try:
                values[setting.key] = setting.check(getattr(args, _dest(setting.key)))
            except SettingsError as error:
                raise SettingsError(f"{setting.flag.flag} {error}") from None
    return values


def add_verbosity(parser: argparse.ArgumentParser) -> None:
    """``-q`` and ``-v``: how much goes to stderr."""
    loudness = parser.add_mutually_exclusive_group()
    loudness.add_argument(
        "-q", "--quiet", action="store_true", help="no progress, stages or notes on stderr"
    )
    loudness.add_argument(
        "-v", "--verbose", action="store_true",
        help="each stage and its time on stderr, even off a terminal",
    )  # fmt: skip


def say_notes(notes: Iterable[object], *, quiet: bool) -> None:
    """What was assumed or measured, a ``note:`` line each on stderr; none with ``-q``."""
    if not quiet:
        for note in notes:
            print(f"note: {note}", file=sys.stderr)
