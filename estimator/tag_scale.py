"""Whether a 3-D tag map's scale agrees with its odometry's.

A tag's corners cannot tell its size: a map of tags all given twice their size is the same map
twice as large. Metric odometry can: over a stretch of a second or more, the rig moves as far by
the odometry as by the map, whatever the odometry's drift over the whole log. The median ratio
of the two over such stretches is the factor the tags' sizes are off by (simulated rooms and
corridors with tags given 0.7-1.1 times their size: within 2 % of it; at their size, within
0.7 %), or the odometry's own scale error.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

import gtsam
import numpy as np

from markergraph.common.notes import Note
from markergraph.estimator.tags3d import TagScene

__all__ = [
    "MIN_STRETCHES",
    "ODOMETRY_SCALE_KIND",
    "ODOMETRY_SCALE_OFF",
    "odometry_scale_note",
    "resized",
    "size_factor_by_odometry",
]

ODOMETRY_SCALE_KIND = "map.odometry_scale"
MIN_STRETCHES = 8  # stretches compared before a ratio is said
STRETCH_S = 1.0  # a stretch's least length in time: its odometry drift stays small
MIN_MOVE_M = 0.05  # and in distance: a tag view's own noise stays small beside it
ODOMETRY_SCALE_OFF = 0.05
"""The share the odometry's distances may differ from the map's before its scale is in doubt:
tags given a size a step off (0.2 m for 0.42 m: the map 47 cm off on TagSLAM's test 22, the
odometry 47 % further) or odometry that is not metric. A camera's or a VIO's own scale error is a
percent or two (test 22: -1.6 %)."""
MAX_SIZE_SOLVES = 6  # maps solved again to find the size the odometry agrees with
SIZE_TOLERANCE = 0.005  # where the secant stops: the odometry within 0.5 % of the map


def odometry_scale_note(
    scene: TagScene, frames: list[int], T_map_rig: list[gtsam.Pose3]
) -> list[Note]:
    """A note (kind :data:`ODOMETRY_SCALE_KIND`, its figure the odometry's distance over the
    map's) where the log has odometry at enough of the map's frames; none otherwise.

    Args:
        frames: the map's rig frames (indices into ``scene.frame_times``), ascending.
        T_map_rig: their poses in the map.
    """
    if not scene.odometry:
        return []
    ratios = _stretch_ratios(scene, frames, T_map_rig)
    if len(ratios) < MIN_STRETCHES:
        return []
    ratio = float(np.median(ratios))
    text = (
        f"the odometry moved the rig {ratio:.3f} times as far as the map does over "
        f"{len(ratios)} stretches of {STRETCH_S:g} s or more (median)"
    )
    return [Note(ODOMETRY_SCALE_KIND, text, figure=ratio)]


def _stretch_ratios(
    scene: TagScene, frames: list[int], T_map_rig: list[gtsam.Pose3]
) -> list[float]:
    """The odometry's distance over the map's between consecutive frames at least
    :data:`STRETCH_S` apart, where the odometry moved at least :data:`MIN_MOVE_M`."""
    placed = []
    for i, T in zip(frames, T_map_rig, strict=True):
        pose = scene.odometry[i] if i < len(scene.odometry) else None
        if pose is not None:
            placed.append((int(scene.frame_times[i]), pose.translation(), T.translation()))
    ratios = []
    start = 0
    for end in range(1, len(placed)):
        (t0, odo0, map0), (t1, odo1, map1) = placed[start], placed[end]
        if (t1 - t0) * 1e-9 < STRETCH_S:
            continue
        by_odometry, by_map = np.linalg.norm(odo1 - odo0), np.linalg.norm(map1 - map0)
        if by_odometry >= MIN_MOVE_M and by_map > 0.0:
            ratios.append(float(by_odometry / by_map))
        start = end
    return ratios


def size_factor_by_odometry(
    scene: TagScene, ratio: float, solve: Callable[[TagScene], list[Note]]
) -> float | None:
    """The factor the tags' sizes would take for the map to move as far as the odometry, from
    the ``ratio`` the given sizes gave: the map leans toward the odometry, so the ratio falls
    short of a large error (test 22's tags given 0.2 m for 0.42 m: 1.47, not 2.1). A secant on
    log(ratio) over log(factor), each point a map solved again (``solve``: its notes), to
    within :data:`SIZE_TOLERANCE`; None where a solve says no ratio or it does not settle in
    :data:`MAX_SIZE_SOLVES`."""
    points = [(0.0, math.log(ratio))]
    log_factor = math.log(ratio)  # the first guess: the ratio taken at its word
    for _ in range(MAX_SIZE_SOLVES):
        found = [
            n.figure for n in solve(resized(scene, math.exp(log_factor)))
            if n.kind == ODOMETRY_SCALE_KIND
        ]  # fmt: skip
        if not found or found[0] is None:
            return None
        points.append((log_factor, math.log(found[0])))
        if abs(points[-1][1]) < SIZE_TOLERANCE:
            return math.exp(log_factor)
        (x0, y0), (x1, y1) = points[-2], points[-1]
        # The secant, kept within twice the ratio's own step: a map in another minimum can
        # make two ratios nearly equal and send the secant to a size no camera sees.
        step = -y1 * (x1 - x0) / (y1 - y0) if y1 != y0 else -y1
        log_factor = x1 + float(np.clip(step, -2 * abs(y1), 2 * abs(y1)))
    return None


def resized(scene: TagScene, factor: float) -> TagScene:
    """``scene`` with every tag ``factor`` times its size, and each view's seeds as far again
    from its camera: the same corners, seen as those tags."""

    def farther(T: gtsam.Pose3) -> gtsam.Pose3:
        return gtsam.Pose3(T.rotation(), factor * np.asarray(T.translation()))

    views = [
        replace(v, T_camera_tag=farther(v.T_camera_tag), T_camera_tag_alt=(
            None if v.T_camera_tag_alt is None else farther(v.T_camera_tag_alt)))
        for v in scene.views
    ]  # fmt: skip
    return replace(
        scene, views=views, tag_sizes={i: size * factor for i, size in scene.tag_sizes.items()}
    )
