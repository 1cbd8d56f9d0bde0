"""Settings on the command line: ``--config FILE`` and one flag per setting, flags winning."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from markergraph.estimator.types import SettingsError
from markergraph.frontend.config import SETTINGS, read_config_file

_GROUPS = {
    "": "settings (a flag overrides --config; (file: key) names it in the file)",
    "topics": "topics",
    "camera": "camera mount",
    "noise": "noise model",
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
        if command not in setting.commands:
            continue
        shown = setting.default
        default = "" if shown in (None, {}) else f", default {shown}"
        options: dict[str, Any] = {
            "dest": _dest(setting.key),
            "default": argparse.SUPPRESS,  # absent unless given, so the file's value stands
            "help": f"{setting.help} (file: {setting.key}{default})",
            "type": setting.flag_type,
        }
        if setting.choices:
            options["choices"] = setting.choices
        if setting.metavar:
            options["metavar"] = setting.metavar
        if setting.nargs:
            options["nargs"] = setting.nargs
        section = setting.key.rpartition(".")[0]
        groups[section].add_argument(setting.flag, **options)


def settings_from(args: argparse.Namespace, command: str) -> dict[str, Any]:
    """The settings the file and the flags give (defaults are filled in later).

    Raises:
        SettingsError: a bad file or value, naming the file and key or the flag.
    """
    values = read_config_file(args.config) if args.config is not None else {}
    for setting in SETTINGS:
        if command in setting.commands and hasattr(args, _dest(setting.key)):
            try:
                values[setting.key] = setting.check(getattr(args, _dest(setting.key)))
            except ValueError as error:
                raise SettingsError(f"{setting.flag} {error}") from None
    return values
