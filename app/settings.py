"""Settings of the main job: one table, read from a TOML or YAML file, flags or keywords.

Every setting is declared once, in :data:`SETTINGS`: its key (dotted for a section:
``camera.height`` is ``height`` under ``[camera]``), default, check (type and bounds, from
:mod:`markergraph.setting_values`), line of help, and flag with the commands that take it (the
command line, :mod:`markergraph.cli._settings`, builds its flags from this alone). Outside this
module the settings are read by attribute (:class:`MapConfig`), never by key. Angles are
written in degrees in the file and on the command line (``*_deg`` keys) and are radians inside.
Later sources win: defaults, then the file, then flags.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any, cast

from markergraph.common.documents import yaml_document
from markergraph.common.errors import SettingsError
from markergraph.estimator import ODOMETRY_NOISE, Method, OdometryNoise, Robust
from markergraph.frontend.camera import CameraMount
from markergraph.frontend.config import FrontendConfig
from markergraph.frontend.detectors import DetectorChoice
from markergraph.frontend.observe import DepthModel
from markergraph.frontend.odometry_kind import OdometryEvidence, choose_odometry_source
from markergraph.frontend.rig import read_tagslam
from markergraph.frontend.sizes import MarkerSizes
from markergraph.frontend.yaw import YawMethod
from markergraph.sections import (
    CameraSettings,
    NoiseSettings,
    OdometrySettings,
    OverlaySettings,
    RigSettings,
    Shutter,
    TopicSettings,
)
from markergraph.setting_values import (
    SIDE_M,
    bounded,
    count_or_auto,
    frame_name,
    marker_ids,
    nonempty,
    optional,
    optional_id,
    optional_text,
    scale_or_auto,
    sizes_by_id,
)

__all__ = [
    "ALL_METHODS",
    "SETTINGS",
    "CameraSettings",
    "Flag",
    "MapConfig",
    "NoiseSettings",
    "OdometrySettings",
    "OverlaySettings",
    "RigSettings",
    "Setting",
    "Shutter",
    "TopicSettings",
    "config_toml",
    "map_config",
    "read_config_file",
    "with_map_defaults",
]

# With "all", SLAM comes first: the result folder's top-level files are its.
ALL_METHODS = (Method.SLAM, Method.CLOSED_FORM, Method.MARKER_GRAPH, Method.ISAM2, Method.EKF)


# Which commands take a setting: all four, those that read observations, those that map.
_ALL = ("map", "localize", "detect", "info")
TOPIC_ROLES = ("color", "depth", "camera_info", "odom")  # FrontendConfig's ROLE_topic
_READ = ("map", "localize", "detect")  # what changes the observations, not what info checks
_MAP = ("map", "localize")


@dataclass(frozen=True, slots=True)
class Flag:
    """A setting's command-line flag: how argparse reads it, and which commands take it.

    Attributes:
        flag: the option, such as ``--marker-size``.
        metavar: its value's name in ``--help``, if not argparse's own.
        nargs: argparse's ``nargs`` for a list (``"+"``), else None.
        type: converts the flag's text before the setting's own check.
        commands: the commands that take it.
    """

    flag: str
    metavar: str | None = None
    nargs: str | None = None
    type: Callable[[str], Any] = str
    commands: tuple[str, ...] = _ALL


@dataclass(frozen=True, slots=True)
class Setting:
    """One setting: its one declaration, read by files, keywords and the command line alike.

    Attributes:
        key: its name in a configuration file, dotted under a section.
        default: the value when nothing sets it (degrees for ``*_deg`` keys).
        parse: its type and bounds: converts a value from a file, a flag or a keyword, or
            raises SettingsError; parsing a parsed value gives it back unchanged.
        help: one line for ``--help``, ending in the unit in brackets where it has one.
        flag: its command-line flag.
        choices: the only values allowed, if limited.
    """

    key: str
    default: Any
    parse: Callable[[Any], Any]
    help: str
    flag: Flag
    choices: list[str] | None = None

    def check(self, value: Any) -> Any:
        """The value converted and checked, or SettingsError saying what is wrong with it."""
        value = self.parse(value)
        if self.choices is not None and value not in self.choices:
            raise SettingsError(f"must be one of {', '.join(self.choices)}, got {value!r}")
        return value


_NOISE_M = bounded(0.0, 10.0)
_ODOMETRY_NOISE = bounded(1e-6, 10.0)

SETTINGS: tuple[Setting, ...] = (
    Setting("dictionary", "DICT_4X4_50", nonempty,
            "OpenCV dictionary name (DICT_*, incl. AprilTag) or a dictionary file",
            flag=Flag("--dictionary", "NAME")),
    Setting("detector", DetectorChoice.AUTO.value, nonempty,
            "which library finds the markers: opencv, apriltag3 (AprilTag 16h5, 25h9, 36h11; "
            "pip install pupil-apriltags), or auto: the better one for the dictionary",
            choices=[c.value for c in DetectorChoice], flag=Flag("--detector", commands=_READ)),
    Setting("marker_size", 0.2, SIDE_M, "side of the markers' black square [m]",
            flag=Flag("--marker-size", "M", type=float, commands=_READ)),
    Setting("marker_sizes", {}, sizes_by_id, "sides of markers whose size differs, by id [m]",
            flag=Flag("--marker-sizes", "ID=M", "+", commands=_READ)),
    Setting("yaw_method", YawMethod.PNP.value, nonempty, "how theta comes from the corners",
            choices=[m.value for m in YawMethod],
            flag=Flag("--yaw-method", commands=_READ)),
    Setting("ids", None, marker_ids, "only these marker ids (default: all the dictionary's)",
            flag=Flag("--ids", "ID", "+", int)),
    *(
        Setting(f"topics.{role}", None, optional_text,
                f"{role.replace('_', ' ')} topic (default: chosen from the log)",
                flag=Flag(f"--{role.replace('_', '-')}-topic", "TOPIC"))
        for role in TOPIC_ROLES
    ),
    Setting("rig.cameras", None, optional_text,
            "a Kalibr cameras.yaml: intrinsics of the cameras whose detections the log holds",
            flag=Flag("--cameras", "FILE")),
    Setting("rig.camera_poses", None, optional_text,
            "a TagSLAM camera_poses.yaml: each camera's pose on the rig (without /tf_static)",
            flag=Flag("--camera-poses", "FILE")),
    Setting("rig.tagslam", None, optional_text,
            "a TagSLAM tagslam.yaml: tag sizes, surveyed tags, and the odometry's body on the rig",
            flag=Flag("--tagslam", "FILE")),
    Setting("rig.survey", None, optional_text,
            "surveyed tags held by their stated noise in a 3-D map: a CSV (id,x,y[,z][,yaw]), a "
            "map.json or a tagslam.yaml",
            flag=Flag("--survey", "FILE", commands=("map",))),
    Setting("rig.mounts", "fixed", nonempty,
            "cameras' mounts given by /tf_static or camera_poses.yaml in a 3-D map: fixed, or "
            "seed (estimated from the tags, starting there)",
            choices=["fixed", "seed"], flag=Flag("--mounts", commands=("map",))),
    Setting("camera.base_frame", "base_link", nonempty,
            "the robot's base frame, to read the camera mount from /tf_static",
            flag=Flag("--base-frame", "FRAME")),
    # The camera's mount without /tf_static; the flag is the key's first word.
    *(
        Setting(f"camera.{name}", default, bounded(lowest, limit), f"without /tf_static: {text}",
                flag=Flag(f"--camera-{name.split('_')[0]}", unit, type=float, commands=_READ))
        for name, default, lowest, limit, unit, text in (
            ("x", 0.1, -100.0, 100.0, "M", "camera ahead of the base origin [m]"),
            ("y", 0.0, -100.0, 100.0, "M", "camera left of the base origin [m]"),
            ("height", 0.6, 0.0, 100.0, "M", "optical centre above the floor [m]"),
            ("pitch_deg", 0.0, -90.0, 90.0, "DEG", "optical axis tilted up from level [deg]"),
            ("yaw_deg", 0.0, -360.0, 360.0, "DEG",
             "optical axis turned left of the base's x axis [deg]"),
        )
    ),
    Setting("camera.delay_ms", None, optional(bounded(-500.0, 500.0)),
            "how late the camera's stamps are against odometry [ms] (default: chosen by "
            "SLAM's residuals over -50..100 ms)",
            flag=Flag("--camera-delay", "MS", type=float, commands=_MAP)),
    Setting("camera.readout_ms", None, optional(bounded(0.0, 200.0)),
            "rolling shutter: time to read the rows out, top to bottom [ms]; 0: a global "
            "shutter (default: unknown: theta's sigma covers up to 33 ms in turns, and each "
            "marker's covariance its move between 0 and 33 ms)",
            flag=Flag("--readout", "MS", type=float, commands=_MAP)),
    Setting("camera.shutter", "model", nonempty,
            "a rolling shutter's row delay: model (each marker at its row's time) or widen "
            "(sigmas grow with the turn rate)", choices=["model", "widen"],
            flag=Flag("--shutter", commands=_MAP)),
    Setting("camera.exposure_ms", 0.0, bounded(0.0, 200.0),
            "exposure time: sigmas grow with what a turn smears during it [ms]",
            flag=Flag("--exposure", "MS", type=float, commands=_MAP)),
    Setting("noise.depth_scale", None, scale_or_auto,
            "what depth reads per true metre; auto (default): measured against the markers' "
            "size and applied when more than 1 percent from 1 (the measurement's own error)",
            flag=Flag("--depth-scale", "K|auto", commands=_READ)),
    Setting("noise.corner_px", 0.3, bounded(0.01, 100.0),
            "corner noise after sub-pixel refinement, propagated into theta [px]",
            flag=Flag("--corner-noise", "PX", type=float, commands=_READ)),
    Setting("noise.depth_base_m", DepthModel().base_m, _NOISE_M,
            "depth sigma = base + per_m2 * Z^2: its constant term [m]",
            flag=Flag("--depth-noise-base", "M", type=float, commands=_READ)),
    Setting("noise.depth_per_m2", DepthModel().per_m2, _NOISE_M,
            "depth sigma's quadratic term [1/m]",
            flag=Flag("--depth-noise-per-m2", "K", type=float, commands=_READ)),
    Setting("noise.depth_max_m", DepthModel().max_range_m, bounded(0.1, 1000.0),
            "depths beyond this are treated as no return [m]",
            flag=Flag("--depth-max", "M", type=float, commands=_READ)),
    Setting("odometry.source", "auto", nonempty,
            "the odometry's noise preset; auto: by its messages (3-D motion: vio, or t265 by rate "
            "or name; planar: wheel, unless the topic's name says vio or t265)",
            choices=["auto", *ODOMETRY_NOISE],
            flag=Flag("--odometry-source", commands=_MAP)),
    Setting("odometry.scale", None, scale_or_auto,
            "what the odometry's distances are multiplied by (the wheels' radius error); auto "
            "(default): chosen by SLAM's residuals over 0.95..1.05, 1 where they cannot tell",
            flag=Flag("--odometry-scale", "K|auto", commands=_MAP)),
    Setting("odometry.turn_scale", None, scale_or_auto,
            "what the odometry's turns are multiplied by (a wheel base's track width error); "
            "auto (default): chosen by SLAM's residuals over 0.95..1.05, 1 where they cannot tell",
            flag=Flag("--odometry-turn-scale", "K|auto", commands=_MAP)),
    Setting("noise.odometry_per_m", None, optional(_ODOMETRY_NOISE),
            "odometry position sigma after 1 m travelled [m/sqrt(m)] (default: the source's)",
            flag=Flag("--odometry-noise", "M", type=float, commands=_MAP)),
    Setting("noise.odometry_yaw_per_m", None, optional(_ODOMETRY_NOISE),
            "odometry heading sigma after 1 m travelled [rad/sqrt(m)] (default: the source's)",
            flag=Flag("--odometry-yaw-noise", "RAD", type=float, commands=_MAP)),
    Setting("noise.odometry_yaw_per_rad", None, optional(_ODOMETRY_NOISE),
            "odometry heading sigma after 1 rad turned [rad/sqrt(rad)] (default: the source's)",
            flag=Flag("--odometry-turn-noise", "RAD", type=float, commands=_MAP)),
    # Huber by default: real detections have outliers (near-frontal pose flips); on the
    # rendered paper-room log it cut SLAM's marker error 4x, and cost nothing elsewhere.
    Setting("noise.robust", Robust.HUBER.value, nonempty,
            "robust kernel on observation factors (SLAM, iSAM2, marker graph)",
            choices=[r.value for r in Robust],
            flag=Flag("--robust", commands=_MAP)),
    Setting("method", Method.SLAM.value, nonempty,
            "which estimator; all runs every one side by side",
            choices=[m.value for m in Method] + ["all"],
            flag=Flag("--method", commands=("map",))),
    Setting("dimensions", "auto", nonempty,
            "2: the wall map of a wheeled robot; 3: every tag's full pose (any rig, with or "
            "without odometry); auto: 3 for a log of tag detections, 2 for a log of images",
            choices=["2", "3", "auto"], flag=Flag("--dimensions", commands=("map",))),
    Setting("home", None, optional_id,
            "the marker whose frame is the map (default: the first seen)",
            flag=Flag("--home", "ID", type=int, commands=("map",))),
    Setting("workers", None, count_or_auto,
            "processes that decode and detect; auto (default): as many as help, one per 1,500 "
            "frames and idle core",
            flag=Flag("--workers", "N|auto", commands=("map", "localize", "detect"))),
    Setting("overlay.map_frame", "map", frame_name,
            "overlay.mcap's map frame (rename it where nav2 already publishes map -> odom)",
            flag=Flag("--map-frame", "FRAME", commands=_MAP)),
    Setting("overlay.odom_frame", "odom", frame_name, "overlay.mcap's odometry frame",
            flag=Flag("--odom-frame", "FRAME", commands=_MAP)),
)  # fmt: skip
_BY_KEY = {s.key: s for s in SETTINGS}


def _with_rig_defaults(values: Mapping[str, Any]) -> dict[str, Any]:
    """Every setting (:func:`_complete`), with what a rig file gives where the user gave none:
    a TagSLAM ``tagslam.yaml``'s ``default_tag_size`` is the marker size, and the tags it sizes
    one by one keep theirs (under ``marker_sizes``, which wins where it sizes them too)."""
    given = dict(values)
    if not given.get("rig.tagslam"):
        return _complete(given)
    rig = read_tagslam(Path(given["rig.tagslam"]))
    if (
        rig.default_tag_size_m is not None
        and given.setdefault("marker_size", rig.default_tag_size_m) != rig.default_tag_size_m
    ):
        # Its tags sized one by one would keep the file's sizes, the others the flag's: a map
        # of two scales (test 16 at 0.1 m against the file's 0.16 m: 37 cm off, verdict ok).
        raise SettingsError(
            f"--marker-size {given['marker_size']:g} disagrees with {given['rig.tagslam']}'s "
            f"default_tag_size {rig.default_tag_size_m:g}: leave one of them out (--marker-sizes "
            "sizes single tags)"
        )
    complete = _complete(given)
    complete["marker_sizes"] = {**rig.tag_sizes_m, **complete["marker_sizes"]}
    return complete


def with_map_defaults(
    values: Mapping[str, Any],
    dictionary: str,
    marker_size_m: float,
    sizes_by_id: Mapping[int, float],
    source: Path,
) -> dict[str, Any]:
    """``values`` with a saved map's dictionary, marker size and markers sized apart where they
    give none: the same markers in another dictionary are other ids, and at another size every
    range from their corners is off by the ratio.

    Raises:
        SettingsError: a dictionary or marker size given that the map (``source``) contradicts.
    """
    given = dict(values)
    if given.setdefault("dictionary", dictionary) != dictionary:
        raise SettingsError(
            f"--dictionary {given['dictionary']}, but {source} was made with {dictionary}: the "
            "same markers read in another dictionary are other ids (leave --dictionary out to "
            "take the map's)"
        )
    size = given.setdefault("marker_size", marker_size_m)
    if not math.isclose(size, marker_size_m, rel_tol=1e-9):
        raise SettingsError(
            f"--marker-size {size:g}, but {source} was made with {marker_size_m:g} m markers "
            "(leave --marker-size out to take the map's)"
        )
    given["marker_sizes"] = {**sizes_by_id, **given.get("marker_sizes", {})}
    return given


@dataclass(frozen=True)
class MapConfig:
    """Everything the main job needs besides the log and the output folder: every setting,
    checked once when the object is made, and read by attribute in typed sections
    (``config.camera.delay_ns``, ``config.noise.robust``, ``config.overlay.map_frame``).

    Build one with :meth:`from_values` (any subset of the settings by key; the rest take their
    defaults); ``values`` then holds every key, as a settings file writes it.
    """

    values: Mapping[str, Any]

    def __post_init__(self) -> None:
        object.__setattr__(self, "values", _with_rig_defaults(self.values))
        if self.values["overlay.map_frame"] == self.values["overlay.odom_frame"]:
            raise SettingsError(
                f"overlay.map_frame and overlay.odom_frame are both "
                f"{self.values['overlay.map_frame']!r}: the overlay needs two frames"
            )

    @classmethod
    def from_values(cls, values: Mapping[str, Any] | None = None) -> MapConfig:
        """The settings given by key (as in a settings file: ``{"method": "all",
        "camera.height": 0.45}``), checked; missing keys take their defaults.

        Raises:
            SettingsError: an unknown setting or a bad value, naming it.
        """
        return cls(dict(values or {}))

    @property
    def dictionary(self) -> str:
        """The markers' dictionary: an OpenCV name (``DICT_*``) or a dictionary file."""
        return cast(str, self.values["dictionary"])

    @cached_property
    def marker_sizes(self) -> MarkerSizes:
        """The side of each marker's black square, a rig file's among them [m]."""
        return MarkerSizes(self.values["marker_size"], dict(self.values["marker_sizes"]))

    @property
    def yaw_method(self) -> YawMethod:
        """How theta comes from the corners."""
        return YawMethod(self.values["yaw_method"])

    @property
    def ids(self) -> tuple[int, ...] | None:
        """The only marker ids kept (None: all the dictionary's)."""
        return cast("tuple[int, ...] | None", self.values["ids"])

    @cached_property
    def topics(self) -> TopicSettings:
        """The log's topics (None: chosen from the log)."""
        v = self.values
        return TopicSettings(
            v["topics.color"], v["topics.depth"], v["topics.camera_info"], v["topics.odom"]
        )

    @cached_property
    def rig(self) -> RigSettings:
        """A rig's files."""
        v = self.values
        return RigSettings(
            _path(v["rig.cameras"]),
            _path(v["rig.camera_poses"]),
            _path(v["rig.tagslam"]),
            _path(v["rig.survey"]),
            v["rig.mounts"] == "seed",
        )

    @cached_property
    def camera(self) -> CameraSettings:
        """The camera's mount without /tf_static, and its timing."""
        v = self.values
        mount = CameraMount(
            v["camera.x"],
            v["camera.y"],
            v["camera.height"],
            math.radians(v["camera.yaw_deg"]),
            math.radians(v["camera.pitch_deg"]),
        )
        delay_ms, readout_ms = v["camera.delay_ms"], v["camera.readout_ms"]
        return CameraSettings(
            base_frame=v["camera.base_frame"],
            default_mount=mount,
            delay_ns=None if delay_ms is None else round(delay_ms * 1e6),
            readout_ns=None if readout_ms is None else round(readout_ms * 1e6),
            shutter=Shutter(v["camera.shutter"]),
            exposure_s=v["camera.exposure_ms"] * 1e-3,
        )

    @cached_property
    def noise(self) -> NoiseSettings:
        """The noise model."""
        v = self.values
        return NoiseSettings(
            depth_scale=v["noise.depth_scale"],
            corner_px=v["noise.corner_px"],
            depth=DepthModel(
                v["noise.depth_base_m"], v["noise.depth_per_m2"], v["noise.depth_max_m"]
            ),
            odometry_per_m=v["noise.odometry_per_m"],
            odometry_yaw_per_m=v["noise.odometry_yaw_per_m"],
            odometry_yaw_per_rad=v["noise.odometry_yaw_per_rad"],
            robust=Robust(v["noise.robust"]),
        )

    @cached_property
    def odometry(self) -> OdometrySettings:
        """The odometry's noise preset, scale and turn scale (None: auto)."""
        source = self.values["odometry.source"]
        return OdometrySettings(
            None if source == "auto" else source,
            self.values["odometry.scale"],
            self.values["odometry.turn_scale"],
        )

    @cached_property
    def overlay(self) -> OverlaySettings:
        """overlay.mcap's frames."""
        return OverlaySettings(self.values["overlay.map_frame"], self.values["overlay.odom_frame"])

    @cached_property
    def frontend(self) -> FrontendConfig:
        """How the log is read: a view of the settings the front end takes."""
        topics, rig, noise = self.topics, self.rig, self.noise
        return FrontendConfig(
            dictionary=self.dictionary,
            detector=DetectorChoice(self.values["detector"]),
            marker_sizes=self.marker_sizes,
            method=self.yaw_method,
            allowed_ids=self.ids,
            **{f"{role}_topic": getattr(topics, role) for role in TOPIC_ROLES},
            base_frame=self.camera.base_frame,
            default_mount=self.camera.default_mount,
            depth_scale=noise.depth_scale,
            depth_model=noise.depth,
            corner_sigma_px=noise.corner_px,
            kalibr_cameras=rig.cameras,
            camera_poses=rig.camera_poses,
            tagslam=rig.tagslam,
        )

    @property
    def methods(self) -> tuple[Method, ...]:
        """The estimators to run; the first one's map is on top of the result folder."""
        method = self.values["method"]
        return ALL_METHODS if method == "all" else (Method(method),)

    @property
    def dimensions(self) -> str:
        """``"2"``, ``"3"`` or ``"auto"`` (3 for a log of tag detections, 2 for images)."""
        return cast(str, self.values["dimensions"])

    @property
    def home_id(self) -> int | None:
        """The map's home marker (None: the first seen)."""
        return cast("int | None", self.values["home"])

    @property
    def workers(self) -> int | None:
        """Processes that decode and detect (None: as many as help)."""
        return cast("int | None", self.values["workers"])

    def odometry_source(
        self, topic: str | None = None, evidence: OdometryEvidence | None = None
    ) -> tuple[str, str]:
        """The odometry source and what decided it: ``odometry.source`` as set, or (auto) the
        odometry's own messages (:func:`choose_odometry_source`: 3-D motion, rate, covariance;
        the ``topic``'s name only as a tie-breaker or where there is no evidence)."""
        if self.odometry.source is not None:
            return self.odometry.source, "set by odometry.source"
        return choose_odometry_source(evidence, topic)

    def odometry_noise(
        self, topic: str | None = None, evidence: OdometryEvidence | None = None
    ) -> tuple[str, OdometryNoise]:
        """The odometry source (:meth:`odometry_source`) and the noise model the estimators
        assume: its preset, with any ``noise.odometry_*`` given."""
        noise = self.noise
        source, _ = self.odometry_source(topic, evidence)
        preset = ODOMETRY_NOISE[source]
        return source, OdometryNoise(
            *(
                preset_value if value is None else value
                for value, preset_value in (
                    (noise.odometry_per_m, preset.per_m),
                    (noise.odometry_yaw_per_m, preset.yaw_per_m),
                    (noise.odometry_yaw_per_rad, preset.yaw_per_rad),
                )
            )
        )


def _path(value: str | None) -> Path | None:
    return None if value is None else Path(value)


# Settings that name files: relative to the settings file they are written in.
PATH_KEYS = ("rig.cameras", "rig.camera_poses", "rig.tagslam", "rig.survey")
MAX_SETTINGS_BYTES = 1_000_000
"""A settings file is small: anything larger is refused before it is parsed."""
MAX_SETTINGS_DEPTH = 6
"""... and flat: sections nest this deep at most (``[camera]``, a table of sizes)."""


def _flatten(table: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for name, value in table.items():
        key = f"{prefix}{name}"
        if isinstance(value, Mapping) and key not in _BY_KEY:
            flat.update(_flatten(value, f"{key}."))
        else:
            flat[key] = value
    return flat


def _depth(value: Any, limit: int = MAX_SETTINGS_DEPTH + 1) -> int:
    """How deep tables and lists nest in ``value`` (counted no further than ``limit``)."""
    if limit <= 0 or not isinstance(value, (Mapping, list)):
        return 0
    items = value.values() if isinstance(value, Mapping) else value
    return 1 + max((_depth(v, limit - 1) for v in items), default=0)


def read_config_file(path: str | Path) -> dict[str, Any]:
    """The settings a TOML (``.toml``) or YAML (``.yaml``, ``.yml``) file gives, checked.

    Raises:
        SettingsError: unreadable file, unknown key or bad value, in one line naming file and key.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as error:
        raise SettingsError(f"{path}: cannot read the configuration ({error.strerror})") from None
    except UnicodeDecodeError:
        raise SettingsError(f"{path}: not UTF-8 text, so not a settings file") from None
    if len(text) > MAX_SETTINGS_BYTES:
        raise SettingsError(f"{path}: {len(text):,} characters is not a settings file")
    text = text.removeprefix("\ufeff")  # a byte-order mark some editors write
    suffix = path.suffix.lower()
    try:
        if suffix == ".toml":
            if sys.version_info >= (3, 11):
                import tomllib
            else:  # pragma: no cover - Python 3.10
                import tomli as tomllib
            table: Any = tomllib.loads(text)
        elif suffix in (".yaml", ".yml"):
            table = yaml_document(text, MAX_SETTINGS_DEPTH, unique_keys=True) or {}
        else:
            raise SettingsError("a configuration file ends in .toml, .yaml or .yml")
    except ValueError as error:  # tomllib's and yaml's errors are ValueErrors too
        raise SettingsError(f"{path}: {str(error).splitlines()[0]}") from None
    except RecursionError:
        raise SettingsError(f"{path}: nested too deep for a settings file") from None
    except Exception as error:  # yaml.YAMLError
        raise SettingsError(f"{path}: not valid YAML ({str(error).splitlines()[0]})") from None
    if not isinstance(table, Mapping):
        raise SettingsError(f"{path}: expected a table of settings at the top")
    if _depth(table) > MAX_SETTINGS_DEPTH:
        raise SettingsError(f"{path}: nested deeper than {MAX_SETTINGS_DEPTH} levels")
    values = {}
    for key, value in _flatten(table).items():
        setting = _BY_KEY.get(key)
        if setting is None:
            raise SettingsError(f"{path}: unknown setting {key!r} (markergraph map --help)")
        try:
            values[key] = setting.check(value)
        except ValueError as error:
            raise SettingsError(f"{path}: {key} {error}") from None
        if key in PATH_KEYS and values[key] is not None:
            values[key] = str(path.parent / Path(values[key]).expanduser())
    return values


def _complete(values: Mapping[str, Any]) -> dict[str, Any]:
    """Every setting: the given ones checked (parsing is idempotent), the rest defaults."""
    complete = {}
    for setting in SETTINGS:
        if setting.key not in values:
            complete[setting.key] = setting.default
            continue
        try:
            complete[setting.key] = setting.check(values[setting.key])
        except ValueError as error:
            raise SettingsError(f"setting {setting.key} {error}") from None
    unknown = set(values) - set(complete)
    if unknown:
        raise SettingsError(f"unknown setting(s) {', '.join(sorted(unknown))}")
    if complete["noise.depth_base_m"] == 0 and complete["noise.depth_per_m2"] == 0:
        raise SettingsError(
            "noise.depth_base_m (--depth-noise-base) and noise.depth_per_m2 "
            "(--depth-noise-per-m2) are both 0: depth would count as exact"
        )
    return complete


def map_config(values: Mapping[str, Any] | None = None) -> MapConfig:
    """:meth:`MapConfig.from_values`."""
    return MapConfig.from_values(values)


def _toml_value(value: Any) -> str:
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return repr(value)


def config_toml(values: Mapping[str, Any]) -> str:
    """Settings as a TOML file that :func:`read_config_file` reads back to the same values;
    unset optional settings are left as comments. What a rig file gives is written as given
    (written as a default, the marker size would then beat the rig's own)."""
    v = _with_rig_defaults(values)
    sections: dict[str, list[str]] = {"": []}
    for setting in SETTINGS:
        section, _, name = setting.key.rpartition(".")
        lines = sections.setdefault(section, [])
        if setting.key == "marker_sizes":
            continue  # a table of its own, last
        value = v[setting.key]
        if value is None and setting.parse in (scale_or_auto, count_or_auto):
            value = "auto"
        lines.append(f"# {setting.help}")
        lines.append(f"# {name} = ..." if value is None else f"{name} = {_toml_value(value)}")
    parts = ["\n".join(sections.pop(""))]
    parts += [f"[{name}]\n" + "\n".join(lines) for name, lines in sections.items()]
    sizes = v["marker_sizes"]
    parts.append(
        f"# {_BY_KEY['marker_sizes'].help}\n[marker_sizes]\n"
        + (
            "".join(f"{marker_id} = {side!r}\n" for marker_id, side in sizes.items())
            or "# 7 = 0.1\n"
        )
    )
    return "\n\n".join(part.rstrip("\n") for part in parts) + "\n"
