"""What a real camera and base do to a simulated log: late and jittered camera stamps, a rolling
shutter, motion blur, a depth scale error and holes, lens distortion, dropped frames, jittered
odometry stamps and the TF tree realsense-ros and a diff-drive base publish.

Each is an option of :class:`SensorEffects` (all off by default: the ideal sensors), and
:data:`D435I_ON_DIFF_DRIVE` sets them all at the values of a RealSense D435i on a diff-drive base.
:data:`SENSOR_PRESETS` names both for ``markergraph simulate --sensors``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = [
    "D435I_ON_DIFF_DRIVE",
    "D435_DISTORTION",
    "SENSOR_PRESETS",
    "SensorEffects",
    "black_cells_without_depth",
    "motion_smear",
    "shutter_offsets",
]

# plumb_bob (k1, k2, p1, p2, k3) like a D435's colour camera.
D435_DISTORTION = (0.11, -0.24, 0.0005, -0.0003, 0.09)
_SHUTTER_RENDERS = 17  # a rolling shutter's frame is blended from renders this many times
_BLACK_INK = 45  # grey level below which a marker's cell is black ink (walls are 70 and up)


@dataclass(frozen=True)
class SensorEffects:
    """A camera's and a base's departures from ideal sensors.

    Attributes:
        camera_latency_s: the colour and depth header stamps trail the capture by this [s]
            (realsense-ros over USB: 20-50 ms).
        stamp_jitter_s: and by a further Gaussian jitter of this sigma [s].
        rolling_shutter_s: the colour rows are read out top to bottom over this time, the
            stamp's capture time being the top row's [s] (D435 colour: about 25 ms).
        exposure_s: the shutter stays open this long; turning smears the image [s].
        depth_scale: depth reads this times the true distance (a 1-2 % bias at 2-4 m).
        black_cells_without_depth: no depth on the markers' black cells (laminated markers
            the stereo matcher cannot see into).
        distortion: the lens' plumb_bob coefficients, applied to colour and aligned depth and
            published in camera_info; empty for none.
        dropped_frames: the fraction of frames never recorded.
        odometry_jitter_s: odometry header stamps off the sampling time by a Gaussian of this
            sigma [s].
        realsense_tf_tree: odom -> base_footprint -> base_link -> camera_link ->
            camera_color_frame -> camera_color_optical_frame, instead of three frames.
    """

    camera_latency_s: float = 0.0
    stamp_jitter_s: float = 0.0
    rolling_shutter_s: float = 0.0
    exposure_s: float = 0.0
    depth_scale: float = 1.0
    black_cells_without_depth: bool = False
    distortion: tuple[float, ...] = ()
    dropped_frames: float = 0.0
    odometry_jitter_s: float = 0.0
    realsense_tf_tree: bool = False


D435I_ON_DIFF_DRIVE = SensorEffects(
    camera_latency_s=0.035,
    stamp_jitter_s=0.002,
    rolling_shutter_s=0.025,
    exposure_s=0.015,
    depth_scale=1.012,
    black_cells_without_depth=True,
    distortion=D435_DISTORTION,
    dropped_frames=0.02,
    odometry_jitter_s=0.002,
    realsense_tf_tree=True,
)

SENSOR_PRESETS: dict[str, SensorEffects] = {
    "ideal": SensorEffects(),
    "d435i": D435I_ON_DIFF_DRIVE,
}
"""The sensors ``markergraph simulate --sensors NAME`` puts in its log: ``ideal`` (no effect, the
default) or ``d435i`` (:data:`D435I_ON_DIFF_DRIVE`)."""


def shutter_offsets(readout_s: float) -> NDArray[np.float64]:
    """The times after the top row's capture [s] at which a frame is rendered: the readout's
    start and end and evenly between under a rolling shutter (each row is blended from the two
    renders about its own time), once at 0 for a global shutter."""
    if readout_s <= 0:
        return np.zeros(1)
    return np.linspace(0.0, readout_s, _SHUTTER_RENDERS)


def motion_smear(image: NDArray[np.uint8], length_px: float) -> NDArray[np.uint8]:
    """A horizontal smear of ``length_px`` (a turn about the vertical axis during the exposure),
    as a box kernel with fractional ends."""
    if length_px < 0.05:
        return image
    whole = math.floor(length_px)
    kernel = np.ones(whole + 2, dtype=np.float32)
    kernel[0] = kernel[-1] = (length_px - whole) / 2.0
    kernel /= kernel.sum()
    smeared = cv2.filter2D(image, -1, kernel[None, :], borderType=cv2.BORDER_REPLICATE)
    return np.asarray(smeared, dtype=np.uint8)


def black_cells_without_depth(
    rgb: NDArray[np.uint8], depth_mm: NDArray[np.uint16]
) -> NDArray[np.uint16]:
    """Depth with no return (0) wherever the colour image shows black ink."""
    dark = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY) < _BLACK_INK
    return np.where(dark, 0, depth_mm).astype(np.uint16)
