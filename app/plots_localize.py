"""localize's map.png: the saved map, the localised path and the markers that moved (matplotlib,
imported here only)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from markergraph.estimator.localization import Localization
from markergraph.estimator.trajectory import Trajectory
from markergraph.markermap import MarkerMap
from markergraph.plots import draw_marker_map

__all__ = ["MOVED_ARROW_GID", "draw_localization", "plot_localization"]

MOVED_ARROW_GID = "moved-marker"  # each moved marker's arrow carries "moved-marker-<id>"


def _points(localization: Localization, truth_path: Trajectory | None) -> list[Any]:
    """Everything the view must hold besides the map's markers: paths, moved and new markers."""
    points = [localization.trajectory.poses[:, :2]]
    if truth_path is not None and len(truth_path):
        points.append(truth_path.poses[:, :2])
    points += [np.array([[m.T_map_now.x(), m.T_map_now.y()]]) for m in localization.moved]
    points += [np.array([[m.T_map_marker.x(), m.T_map_marker.y()]])
               for m in localization.new.values()]  # fmt: skip
    return points


def draw_localization(
    ax: Any,
    saved: MarkerMap,
    localization: Localization,
    *,
    truth_path: Trajectory | None = None,
    title: str = "",
) -> list[Any]:
    """The saved map with its ellipses, the localised path (green), the logged truth (dashed),
    each moved marker as a red arrow from where the map has it to where this log saw it, and
    new markers (orange), with a legend.

    Returns:
        The moved markers' arrows, one per moved marker, in the order of ``localization.moved``.
    """
    from matplotlib.lines import Line2D
    from matplotlib.patches import FancyArrowPatch

    draw_marker_map(ax, saved, title, _points(localization, truth_path))
    xy = localization.trajectory.poses
    ax.plot(xy[:, 0], xy[:, 1], color="tab:green", lw=1.0, label="localised path")
    if truth_path is not None and len(truth_path):
        ax.plot(truth_path.poses[:, 0], truth_path.poses[:, 1], "k--", lw=0.8,
                label="ground truth")  # fmt: skip
    arrows = []
    for m in localization.moved:
        arrow = FancyArrowPatch(
            (m.T_map_before.x(), m.T_map_before.y()), (m.T_map_now.x(), m.T_map_now.y()),
            arrowstyle="-|>", mutation_scale=14, color="tab:red", lw=1.6, zorder=4,
            gid=f"{MOVED_ARROW_GID}-{m.marker_id}",
        )  # fmt: skip
        ax.add_patch(arrow)
        ax.annotate(f"{m.marker_id} moved {100 * m.displacement_m:.0f} cm",
                    (m.T_map_now.x(), m.T_map_now.y()), textcoords="offset points",
                    xytext=(4, -10), fontsize=8, color="tab:red")  # fmt: skip
        arrows.append(arrow)
    if localization.new:
        new_xy = np.array([[m.T_map_marker.x(), m.T_map_marker.y()]
                           for m in localization.new.values()])  # fmt: skip
        ax.plot(new_xy[:, 0], new_xy[:, 1], "P", color="tab:orange", ms=7,
                label="new markers (not in the map)")  # fmt: skip
    handles, labels = ax.get_legend_handles_labels()
    if arrows:  # a patch added by hand has no legend entry of its own
        handles.append(Line2D([], [], color="tab:red", lw=1.6, marker=">"))
        labels.append("moved marker: map -> now")
    ax.legend(handles, labels, fontsize=8, loc="best")
    return arrows


def plot_localization(
    saved: MarkerMap,
    localization: Localization,
    path: Path,
    *,
    truth_path: Trajectory | None = None,
    title: str = "",
) -> None:
    """:func:`draw_localization` as a PNG at ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 6), constrained_layout=True)
    draw_localization(ax, saved, localization, truth_path=truth_path, title=title)
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)
