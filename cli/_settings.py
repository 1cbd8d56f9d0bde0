"""Settings on the command line: ``--config FILE`` and one flag per setting, flags winning.

The settings themselves (keys, defaults, checks, help) are the library's
(:mod:`markergraph.settings`); which command takes which, and how argparse reads each flag,
is decided here.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from markergraph.common.errors import SettingsError
from markergraph.settings import SETTINGS, read_config_file

__all__ = ["FLAGS", "add_settings", "add_verbosity", "settings_from"]


@dataclass(frozen=True)
class Flag:
    """How argparse reads one setting's flag, and the commands that take it."""

    flag: str
    metavar: str | None = None
    nargs: str | None = None
    type: Callable[[str], Any] = str
    commands: tuple[str, ...] = ("map", "localize", "detect", "info")


_MAP = ("map", "localize")
_READ = ("map", "localize", "detect")  # what changes the observations, not what info checks
FLAGS: dict[str, Flag] = {
    "dictionary": Flag("--dictionary", "NAME"),
    "marker_size": Flag("--marker-size", "M", type=float, commands=_READ),
    "marker_sizes": Flag("--marker-sizes", "ID=M", "+", commands=_READ),
    "yaw_method": Flag("--yaw-method", commands=_READ),
    "ids": Flag("--ids", "ID", "+", int),
    "topics.color": Flag("--color-topic", "TOPIC"),
    "topics.depth": Flag("--depth-topic", "TOPIC"),
    "topics.camera_info": Flag("--camera-info-topic", "TOPIC"),
    "topics.odom": Flag("--odom-topic", "TOPIC"),
    "rig.cameras": Flag("--cameras", "FILE"),
    "rig.camera_poses": Flag("--camera-poses", "FILE"),
    "rig.tagslam": Flag("--tagslam", "FILE"),
    "camera.base_frame": Flag("--base-frame", "FRAME"),
    "camera.x": Flag("--camera-x", "M", type=float, commands=_READ),
    "camera.y": Flag("--camera-y", "M", type=float, commands=_READ),
    "camera.height": Flag("--camera-height", "M", type=float, commands=_READ),
    "camera.pitch_deg": Flag("--camera-pitch", "DEG", type=float, commands=_READ),
    "camera.yaw_deg": Flag("--camera-yaw", "DEG", type=float, commands=_READ),
    "camera.delay_ms": Flag("--camera-delay", "MS", type=float, commands=_MAP),
    "camera.readout_ms": Flag("--readout", "MS", type=float, commands=_MAP),
    "camera.shutter": Flag("--shutter", commands=_MAP),
    "camera.exposure_ms": Flag("--exposure", "MS", type=float, commands=_MAP),
    "noise.depth_scale": Flag("--depth-scale", "K|auto", commands=_READ),
    "noise.corner_px": Flag("--corner-noise", "PX", type=float, commands=_READ),
    "noise.depth_base_m": Flag("--depth-noise-base", "M", type=float, commands=_READ),
    "noise.depth_per_m2": Flag("--depth-noise-per-m2", "K", type=float, commands=_READ),
    "noise.depth_max_m": Flag("--depth-max", "M", type=float, commands=_READ),
    "odometry.source": Flag("--odometry-source", commands=_MAP),
    "odometry.scale": Flag("--odometry-scale", "K|auto", commands=_MAP),
    "noise.odometry_per_m": Flag("--odometry-noise", "M", type=float, commands=_MAP),
    "noise.odometry_yaw_per_m": Flag("--odometry-yaw-noise", "RAD", type=float, commands=_MAP),
    "noise.odometry_yaw_per_rad": Flag("--odometry-turn-noise", "RAD", type=float, commands=_MAP),
    "noise.robust": Flag("--robust", commands=_MAP),
    "method": Flag("--method", commands=("map",)),
    "home": Flag("--home", "ID", type=int, commands=("map",)),
    "workers": Flag("--workers", "N|auto", commands=("map", "localize", "detect")),
    "overlay.map_frame": Flag("--map-frame", "FRAME", commands=_MAP),
    "overlay.odom_frame": Flag("--odom-frame", "FRAME", commands=_MAP),
}

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
        flag = FLAGS[setting.key]
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
        if command in FLAGS[setting.key].commands and hasattr(args, _dest(setting.key)):
            try:
                values[setting.key] = setting.check(getattr(args, _dest(setting.key)))
            except SettingsError as error:
                raise SettingsError(f"{FLAGS[setting.key].flag} {error}") from None
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
