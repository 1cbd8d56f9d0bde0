"""Floor plans of marker maps (matplotlib, imported here only)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gtsam
import numpy as np

from markergraph.estimator.trajectory import Trajectory
from markergraph.markermap import MarkerMap

__all__ = ["plot_comparison", "plot_map"]


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _draw_map(ax: Any, marker_map: MarkerMap, truth: dict[int, gtsam.Pose2], title: str) -> None:
    """Markers with their normals, ids and 2-sigma ellipses; true markers as grey crosses."""
    circle = np.stack(
        [np.cos(np.linspace(0, 2 * math.pi, 60)), np.sin(np.linspace(0, 2 * math.pi, 60))]
    )
    for marker_id, marker in marker_map.markers.items():
        T = marker.T_map_marker
        ax.annotate(
            str(marker_id), (T.x(), T.y()), textcoords="offset points", xytext=(4, 4), fontsize=8
        )
        ax.arrow(
            T.x(),
            T.y(),
            0.3 * math.cos(T.theta()),
            0.3 * math.sin(T.theta()),
            width=0.02,
            color="tab:blue",
            length_includes_head=True,
        )
        ellipse = marker.position_ellipse(2.0)
        if ellipse is not None:
            (major, minor), heading = ellipse
            c, s = math.cos(heading), math.sin(heading)
            outline = np.array([[c, -s], [s, c]]) @ (np.array([[major / 2], [minor / 2]]) * circle)
            ax.plot(T.x() + outline[0], T.y() + outline[1], color="tab:blue", lw=0.8)
    if truth:
        xy = np.array([[T.x(), T.y()] for T in truth.values()])
        ax.plot(xy[:, 0], xy[:, 1], "x", color="grey", label="true markers")
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=9)


def plot_map(
    marker_map: MarkerMap,
    truth: dict[int, gtsam.Pose2],
    path: Path,
    *,
    trajectory: Trajectory | None = None,
    odometry: Trajectory | None = None,
    truth_path: Trajectory | None = None,
) -> None:
    """The map with its estimated trajectory, the raw odometry (anchored on the trajectory's
    first pose) and the dashed ground truth, as PNG and SVG."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 6), constrained_layout=True)
    _draw_map(
        ax,
        marker_map,
        truth,
        f"{marker_map.method}: markers in the frame of marker {marker_map.home_id}, "
        "2-sigma ellipses",
    )
    if trajectory is not None and len(trajectory) and odometry is not None and len(odometry):
        T_map_odom = trajectory.T_self_other(odometry, int(trajectory.t_ns[0]))
        if T_map_odom is not None:
            drawn = odometry.in_frame(T_map_odom, "map").poses
            ax.plot(drawn[:, 0], drawn[:, 1], color="tab:orange", lw=0.8, label="odometry")
    if trajectory is not None and len(trajectory):
        xy = trajectory.poses
        ax.plot(xy[:, 0], xy[:, 1], color="tab:green", lw=1.0, label="estimated trajectory")
    if truth_path is not None and len(truth_path):
        xy = truth_path.poses
        ax.plot(xy[:, 0], xy[:, 1], "k--", lw=0.8, label="ground truth")
    ax.legend(fontsize=8, loc="best")
    fig.savefig(path)
    fig.savefig(Path(path).with_suffix(".svg"))
    plt.close(fig)


def plot_comparison(
    maps: Sequence[tuple[str, MarkerMap]], truth: dict[int, gtsam.Pose2], path: Path
) -> None:
    """Every method's map side by side."""
    plt = _pyplot()
    fig, axes = plt.subplots(
        1, len(maps), figsize=(4.5 * len(maps), 4.5), constrained_layout=True, squeeze=False
    )
    for ax, (label, marker_map) in zip(axes[0], maps, strict=True):
        _draw_map(ax, marker_map, truth, label)
    fig.savefig(path)
    plt.close(fig)
