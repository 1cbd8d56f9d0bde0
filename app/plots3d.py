"""The 3-D tag map as one figure: a top view (x-y) and a side view (the longer horizontal axis
against z), each tag drawn as its square seen edge-on or flat with its normal (matplotlib,
imported here only)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.estimator.metrics import align_rigid_3d
from markergraph.estimator.tags3d import R_TAG_MARKER, TagMap3d, tag_corners
from markergraph.markermap import MarkerMap
from markergraph.plots import MARGIN

__all__ = ["plot_map_3d"]


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


NORMAL_SHARE = 0.04  # a normal's drawn length, of the view's larger side (at least 2 tag sides)
_MARKER_TO_TAG = gtsam.Pose3(gtsam.Rot3(R_TAG_MARKER.T), np.zeros(3))


@dataclass(frozen=True, slots=True)
class _Drawn:
    """One tag as drawn: its id, ``T_map_tag`` (z out of the print), side [m], surveyed."""

    tag_id: int
    T_map_tag: gtsam.Pose3
    size_m: float
    known: bool


def _tags_of(source: MarkerMap | TagMap3d) -> tuple[list[_Drawn], str]:
    """The tags to draw and the words for the map frame."""
    if isinstance(source, TagMap3d):
        tags = [_Drawn(i, t.T_map_tag, t.size_m, t.known) for i, t in sorted(source.tags.items())]
        anchor = "surveyed tags" if source.home_id is None else f"home tag {source.home_id}"
        level = "z up" if source.up else "z not known to be up"
        return tags, f"map frame fixed by the {anchor}, {level}"
    drawn = []
    for i, m in source.every_marker.items():
        if m.T_map_marker3 is None:  # a 2-D map: upright on its wall at its height
            T = m.T_map_marker
            z = m.z_m or 0.0
            T3 = gtsam.Pose3(gtsam.Rot3.Yaw(T.theta()), np.array([T.x(), T.y(), z]))
        else:
            T3 = m.T_map_marker3
        drawn.append(_Drawn(i, T3.compose(_MARKER_TO_TAG), m.size_m, m.known))
    frame = source.frame or f"map frame of home marker {source.home_id}"
    return drawn, frame.removeprefix("map: ")


def _aligned_truth(
    tags: list[_Drawn], truth: Mapping[int, gtsam.Pose3] | None
) -> tuple[dict[int, gtsam.Pose3], str]:
    """The true tags moved onto the map by the rigid alignment of the common tags' positions,
    and a word on it for the title."""
    if not truth:
        return {}, ""
    ours = {t.tag_id: t.T_map_tag for t in tags}
    common = sorted(set(ours) & set(truth))
    try:
        T_map_truth = align_rigid_3d(
            np.array([truth[i].translation() for i in common]).reshape(-1, 3),
            np.array([ours[i].translation() for i in common]).reshape(-1, 3),
        )
    except ValueError:
        return {}, f"; truth not drawn ({len(common)} tags in common, not 3 off one line)"
    return {i: T_map_truth.compose(T) for i, T in truth.items()}, "; truth rigidly aligned"


def _limits(points: NDArray[np.float64]) -> tuple[float, float, float, float]:
    (x0, y0), (x1, y1) = points.min(axis=0), points.max(axis=0)
    pad = MARGIN * max(x1 - x0, y1 - y0, 0.5)
    return x0 - pad, x1 + pad, y0 - pad, y1 + pad


def _draw_view(
    ax: Any,
    axes: tuple[int, int],
    tags: list[_Drawn],
    truth: Mapping[int, gtsam.Pose3],
    path_xyz: NDArray[np.float64] | None,
    normal_m: float,
) -> None:
    """One view: the path, each tag's square projected (an edge-on tag is a segment) with its
    normal, surveyed tags in red, true tags as grey outlines (at the mapped tag's side)."""
    a, b = axes
    if path_xyz is not None and len(path_xyz):
        ax.plot(path_xyz[:, a], path_xyz[:, b], color="tab:green", lw=0.8)
    sizes = {t.tag_id: t.size_m for t in tags}
    default = float(np.median(list(sizes.values()))) if sizes else 0.1
    for tag_id, T in truth.items():
        outline = np.array([T.transformFrom(c) for c in tag_corners(sizes.get(tag_id, default))])
        closed = np.vstack([outline, outline[:1]])
        ax.plot(closed[:, a], closed[:, b], color="grey", lw=0.8)
    for tag in tags:
        colour = "tab:red" if tag.known else "tab:blue"
        corners = np.array([tag.T_map_tag.transformFrom(c) for c in tag_corners(tag.size_m)])
        closed = np.vstack([corners, corners[:1]])
        ax.plot(closed[:, a], closed[:, b], color=colour, lw=1.6)
        centre = tag.T_map_tag.translation()
        tip = centre + normal_m * tag.T_map_tag.rotation().matrix()[:, 2]
        ax.plot([centre[a], tip[a]], [centre[b], tip[b]], color=colour, lw=0.8)
        ax.annotate(str(tag.tag_id), (centre[a], centre[b]), textcoords="offset points",
                    xytext=(3, 3), fontsize=7)  # fmt: skip


def plot_map_3d(
    marker_map_or_tag_map: MarkerMap | TagMap3d,
    path: Path,
    truth: Mapping[int, gtsam.Pose3] | None = None,
    path_xyz: NDArray[np.float64] | None = None,
) -> None:
    """The 3-D map as one PNG: a top view (x-y) and a side view (the longer horizontal axis
    against z).

    Args:
        marker_map_or_tag_map: a 3-D :class:`MarkerMap` (a 2-D one is drawn with its markers
            upright at their heights) or the estimator's :class:`TagMap3d`.
        path: the PNG to write.
        truth: tag id -> true ``T_ref_tag`` (the tag frame, z out of the print, as TagSLAM
            gives it) in any frame: drawn grey after the rigid alignment of the positions of
            the tags in common onto the map's.
        path_xyz: (n, 3) the rig's positions in the map frame; None takes a TagMap3d's own.
    """
    tags, frame = _tags_of(marker_map_or_tag_map)
    if path_xyz is None and isinstance(marker_map_or_tag_map, TagMap3d):
        path_xyz = np.array([T.translation() for T in marker_map_or_tag_map.rig_poses])
    path_xyz = None if path_xyz is None else np.asarray(path_xyz, dtype=float).reshape(-1, 3)
    true_tags, truth_words = _aligned_truth(tags, truth)
    points = [np.array([t.T_map_tag.translation() for t in tags]).reshape(-1, 3)]
    points += [np.array([T.translation() for T in true_tags.values()]).reshape(-1, 3)]
    points += [path_xyz] if path_xyz is not None else []
    xyz = np.concatenate(points) if sum(len(p) for p in points) else np.zeros((1, 3))
    extent = xyz.max(axis=0) - xyz.min(axis=0)
    horizontal = 0 if extent[0] >= extent[1] else 1
    sizes = [t.size_m for t in tags] or [0.0]
    normal_m = max(NORMAL_SHARE * float(max(extent.max(), 0.5)), 2.0 * max(sizes))
    plt = _pyplot()
    fig, (top, side) = plt.subplots(1, 2, figsize=(13, 6), constrained_layout=True)
    for ax, axes in ((top, (0, 1)), (side, (horizontal, 2))):
        _draw_view(ax, axes, tags, true_tags, path_xyz, normal_m)
        x0, x1, y0, y1 = _limits(xyz[:, list(axes)])
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
        ax.set_aspect("equal", adjustable="box")
        ax.set_xlabel(f"{'xyz'[axes[0]]} [m]")
        ax.set_ylabel(f"{'xyz'[axes[1]]} [m]")
    top.set_title("top view", fontsize=9)
    side.set_title(f"side view ({'xyz'[horizontal]}-z)", fontsize=9)
    handles = [
        plt.Line2D([], [], color="tab:blue", lw=1.6, label="tags (square, normal)"),
        plt.Line2D([], [], color="tab:red", lw=1.6, label="surveyed tags"),
        plt.Line2D([], [], color="grey", lw=0.8, label="truth (aligned)"),
        plt.Line2D([], [], color="tab:green", lw=0.8, label="rig path"),
    ]
    shown = [h for h, keep in zip(handles, (True, any(t.known for t in tags), bool(true_tags),
                                            path_xyz is not None and len(path_xyz) > 0),
                                  strict=True) if keep]  # fmt: skip
    top.legend(handles=shown, fontsize=8, loc="best")
    fig.suptitle(f"3-D map: {len(tags)} tags; {frame}{truth_words}", fontsize=10)
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)
