"""The depth camera's scale, measured against the markers' known size and applied to the
ranges from depth."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from markergraph.common.notes import Note
from markergraph.common.numbers import shown
from markergraph.estimator import turn_rate
from markergraph.estimator.trajectory import Trajectory
from markergraph.estimator.types import Observation
from markergraph.frontend.extraction import Extraction
from markergraph.frontend.marker_size import SIZE_NOT_DEPTH
from markergraph.frontend.observe import Flags, robust_least_squares

__all__ = [
    "DEPTH_SCALE_FLOOR",
    "DEPTH_SCALE_RESOLUTION",
    "MAX_DEPTH_SCALE_ERROR",
    "MIN_DEPTH_RATIOS",
    "correct_depth_scale",
    "depth_scale_from_markers",
    "scale_depth_ranges",
]


MIN_DEPTH_RATIOS = 20  # markers seen with depth before a depth scale is estimated
# Depth over PnP's range is one ratio with two readings: the depth camera's scale, or the
# markers' size. Beyond SIZE_NOT_DEPTH (5 %) it is taken as the size, which extract measures
# and reads the log again with (marker_size.py says why); within it, as the depth's scale,
# applied by auto beyond the measurement's own error (DEPTH_SCALE_RESOLUTION). A depth scale is
# never set beyond it: a 25 % disagreement is a size, a 1 % one a depth camera.
MAX_DEPTH_SCALE_ERROR = SIZE_NOT_DEPTH
# A depth scale within this of 1 is left alone by auto: the measurement's own error. On the
# independent generator's eight logs it read within 0.07 % of the truth, on our paper room's
# within 0.1 %; on our office's ideal log of seed 4 -0.32 % (its markers seen from 2.4-6 m
# only, the far ones small and drawn without the lens blur that smooths a real camera's edges),
# and applied, SLAM was 1.7 cm off instead of 1.0.
DEPTH_SCALE_RESOLUTION = 0.004
# The measured scale's standard deviation is never taken below this: half that resolution. Its
# errors above are mostly not the sightings' scatter (0.02-0.05 % over a hundred of them) but
# how the markers were seen (up to 0.35 % on a D435i's office log of ours after correction).
DEPTH_SCALE_FLOOR = DEPTH_SCALE_RESOLUTION / 2


def depth_scale_from_markers(
    pairs: list[tuple[int, float, float]], odometry: Trajectory
) -> tuple[float, int, float]:
    """What depth reads per true metre, how many markers said so, and that mean's standard
    deviation from their scatter (:data:`DEPTH_SCALE_FLOOR` bounds it below): the mean of depth over
    PnP's distance (which rests on the marker's known size; points beyond three robust sigmas
    dropped, twice), over markers seen while the robot turned slower than 0.2 rad/s (blur and
    a rolling shutter bend PnP).

    PnP is unbiased at every distance because the corners are (:func:`edge_refined`): with
    OpenCV's corners alone, a few tenths of a pixel inside the true ones, PnP read long by 0.3-0.6
    % a metre, and a line's intercept through depth / PnP had to stand in for the scale, 0.0 to
    +0.85 % off on ideal logs. Now depth / PnP shows no trend with distance (a line's slope
    within 0.09 % a metre), and its mean reads within 0.07 % of the truth on the independent
    generator's eight logs (exact depth, and a D435i's +1.2 %), 0.04-0.13 % low on ours.
    """
    steady = [(z, z_pnp) for t_ns, z, z_pnp in pairs if abs(turn_rate(odometry, t_ns)) < 0.2]
    if len(steady) < MIN_DEPTH_RATIOS:
        steady = [(z, z_pnp) for _, z, z_pnp in pairs]
    z, z_pnp = np.array(steady, dtype=np.float64).T
    ratio = z / z_pnp
    mean, kept, sigma = robust_least_squares(np.ones((ratio.size, 1)), ratio, passes=3)
    spread = sigma / np.sqrt(max(int(kept.sum()), 1))
    return float(mean[0]), len(steady), float(np.hypot(spread, DEPTH_SCALE_FLOOR))


def correct_depth_scale(result: Extraction, configured: float | None, topic: str | None) -> None:
    """Measure the depth's scale against the markers' known size
    (:func:`depth_scale_from_markers`) and say it; divide the ranges from depth by the
    configured scale, or (``configured`` None: auto) by the measured one when it is further
    from 1 than the measurement's own error (:data:`DEPTH_SCALE_RESOLUTION`)."""
    measured = None
    if len(result.depth_ratios) >= MIN_DEPTH_RATIOS:
        scale, used, sigma = depth_scale_from_markers(result.depth_ratios, result.odometry)
        result.measured_depth_scale = scale
        note, applies = _scale_note(scale, used, configured, topic)
        result.notes.append(note)
        measured = scale if applies else None
        if configured is None and abs(scale - 1.0) <= MAX_DEPTH_SCALE_ERROR:
            result.depth_scale_sigma = sigma
    applied = configured if configured is not None else measured
    if applied is None or applied == 1.0:
        return
    result.depth_scale = applied
    result.observations = scale_depth_ranges(result.observations, 1.0 / applied)


def scale_depth_ranges(observations: list[Observation], factor: float) -> list[Observation]:
    """The observations with each range from depth (and its sigma) multiplied by ``factor``;
    ranges from the marker's size alone (no depth) as they are."""
    return [
        o if Flags.NO_DEPTH in o.flags
        else replace(o, range_m=o.range_m * factor, sigma_range=o.sigma_range * factor)
        for o in observations
    ]  # fmt: skip


def _scale_note(
    scale: float, used: int, configured: float | None, topic: str | None
) -> tuple[Note, bool]:
    """What the measured ``scale`` says (its kind ``depth_scale.*``, the scale its figure), and
    whether auto would apply it."""
    reads = f"depth on {topic} reads {shown(100 * (scale - 1), '+.2f')} % against the markers' size"
    if abs(scale - 1.0) > MAX_DEPTH_SCALE_ERROR:
        text = (
            f"{reads}: too far off for a depth camera, so the marker size is more likely "
            "wrong; depth left as it is"
        )
        return Note("depth_scale.too_far_off", text, topic, scale), False
    if configured is not None:
        text = (
            f"{reads} ({used} sightings of markers); --depth-scale {configured:g} applied"
            if configured != 1.0
            else f"{reads} ({used} sightings of markers); depth taken as it is (--depth-scale 1)"
        )
        return Note("depth_scale.configured", text, topic, scale), True
    if abs(scale - 1.0) <= DEPTH_SCALE_RESOLUTION:
        text = (
            f"{reads} ({used} sightings of markers): within the measurement's own "
            f"{100 * DEPTH_SCALE_RESOLUTION:g} % error, so depth is left as it is "
            "(--depth-scale K sets it)"
        )
        return Note("depth_scale.within_error", text, topic, scale), False
    text = f"{reads} ({used} sightings of markers): ranges from depth corrected"
    return Note("depth_scale.corrected", text, topic, scale), True
