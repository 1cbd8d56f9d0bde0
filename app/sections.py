"""The main job's settings by section, typed: what :class:`~markergraph.settings.MapConfig`
gives by attribute (``config.camera.delay_ns``, ``config.overlay.map_frame``)."""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from pathlib import Path

from markergraph.estimator import Robust
from markergraph.frontend.camera import CameraMount
from markergraph.frontend.observe import DepthModel

__all__ = [
    "CameraSettings",
    "NoiseSettings",
    "OdometrySettings",
    "OverlaySettings",
    "RigSettings",
    "Shutter",
    "TopicSettings",
]


class Shutter(Enum):
    """What a rolling shutter's row delay does to the observations."""

    MODEL = "model"  # each marker at its row's time
    WIDEN = "widen"  # sigmas grow with the turn rate instead


@dataclass(frozen=True, slots=True)
class TopicSettings:
    """The log's topics; None is chosen from the log (``[topics]``)."""

    color: str | None
    """The colour (or detections) topic."""
    depth: str | None
    """The aligned depth topic."""
    camera_info: str | None
    """The camera info topic."""
    odom: str | None
    """The odometry topic."""


@dataclass(frozen=True, slots=True)
class RigSettings:
    """A rig's files, for logs of marker detections (``[rig]``)."""

    cameras: Path | None
    """A Kalibr ``cameras.yaml``: intrinsics of the cameras whose detections the log holds."""
    camera_poses: Path | None
    """A TagSLAM ``camera_poses.yaml``: each camera's pose on the rig."""
    tagslam: Path | None
    """A TagSLAM ``tagslam.yaml``: tag sizes, surveyed tags, and the odometry's body on the rig."""
    survey: Path | None
    """Surveyed tags for a 3-D map (a CSV, a map.json or a tagslam.yaml)."""
    seed_mounts: bool
    """Given mounts seed the 3-D estimate instead of holding fixed."""


@dataclass(frozen=True, slots=True)
class CameraSettings:
    """The camera's mount and timing (``[camera]``)."""

    base_frame: str
    """The robot's base frame, to read the camera mount from /tf_static."""
    default_mount: CameraMount
    """The mount assumed without /tf_static (angles in radians)."""
    delay_ns: int | None
    """How late the camera's stamps are against odometry [ns]; None: chosen by SLAM."""
    readout_ns: int | None
    """A rolling shutter's time to read the rows out, top to bottom [ns] (0: global; None:
    unknown)."""
    shutter: Shutter
    """What the rolling shutter's row delay does."""
    exposure_s: float
    """Exposure time: sigmas grow with what a turn smears during it [s]."""


@dataclass(frozen=True, slots=True)
class NoiseSettings:
    """The noise model (``[noise]``)."""

    depth_scale: float | None
    """What depth reads per true metre; None (auto): measured against the markers' size."""
    corner_px: float
    """Corner noise after sub-pixel refinement [px]."""
    depth: DepthModel
    """The depth camera's error model."""
    odometry_per_m: float | None
    """Odometry position sigma after 1 m [m/sqrt(m)]; None: the source's preset."""
    odometry_yaw_per_m: float | None
    """Odometry heading sigma after 1 m [rad/sqrt(m)]; None: the source's preset."""
    odometry_yaw_per_rad: float | None
    """Odometry heading sigma after 1 rad turned [rad/sqrt(rad)]; None: the source's preset."""
    robust: Robust
    """The robust kernel on observation factors."""


@dataclass(frozen=True, slots=True)
class OdometrySettings:
    """The odometry (``[odometry]``)."""

    source: str | None
    """Its noise preset (a key of ``ODOMETRY_NOISE``); None (auto): chosen by its messages."""
    scale: float | None
    """What its distances are multiplied by; None (auto): chosen by SLAM's residuals."""
    turn_scale: float | None = None
    """What its turns are multiplied by; None (auto): chosen by SLAM's residuals."""


@dataclass(frozen=True, slots=True)
class OverlaySettings:
    """overlay.mcap's frames (``[overlay]``)."""

    map_frame: str
    """The map frame (renamed where nav2 already publishes map -> odom)."""
    odom_frame: str
    """The odometry frame."""
