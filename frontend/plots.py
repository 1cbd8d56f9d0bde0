"""Floor plans of estimated marker maps (matplotlib, imported here only)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.estimator.types import Estimate, OdometrySample

__all__ = ["plot_comparison", "plot_map"]


def _axes_for(ax: Any, estimate: Estimate, truth: dict[int, gtsam.Pose2], title: str) -> None:
    """Markers with their normals, ids and 2-sigma ellipses; true markers as grey crosses."""
    for marker_id, marker in estimate.markers.items():
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
        if marker.covariance is not None:
            c, s = math.cos(T.theta()), math.sin(T.theta())
            R = np.array([[c, -s], [s, c]])
            covariance = R @ marker.covariance[:2, :2] @ R.T  # into the map frame
            values, vectors = np.linalg.eigh(covariance)
            angles = np.linspace(0, 2 * math.pi, 60)
            circle = np.stack([np.cos(angles), np.sin(angles)])
            ellipse = vectors @ (2.0 * np.sqrt(np.maximum(values, 0.0))[:, None] * circle)
            ax.plot(T.x() + ellipse[0], T.y() + ellipse[1], color="tab:blue", lw=0.8)
    if truth:
        xy = np.array([[T.x(), T.y()] for T in truth.values()])
        ax.plot(xy[:, 0], xy[:, 1], "x", color="grey", label="true markers")
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=9)


def _odometry_in_map(
    estimate: Estimate, odometry: Sequence[OdometrySample]
) -> NDArray[np.float64] | None:
    """Raw odometry drawn in the map frame, anchored at the first estimated pose."""
    if not len(estimate.trajectory) or not odometry:
        return None
    stamps = np.array([s.t_ns for s in odometry])
    i = int(np.argmin(np.abs(stamps - estimate.trajectory_t_ns[0])))
    T_map_odom = gtsam.Pose2(*estimate.trajectory[0]).compose(odometry[i].pose().inverse())
    points = [T_map_odom.transformFrom(np.array([s.x, s.y])) for s in odometry]
    return np.array(points)


def plot_map(
    estimate: Estimate,
    truth: dict[int, gtsam.Pose2],
    path: Path,
    *,
    odometry: Sequence[OdometrySample] = (),
    truth_path: NDArray[np.float64] | None = None,
) -> None:
    """The map with its trajectory, odometry and (dashed) ground truth, as PNG and SVG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 6), constrained_layout=True)
    _axes_for(
        ax,
        estimate,
        truth,
        f"{estimate.method.value}: markers in the frame of marker "
        f"{estimate.home_id}, 2-sigma ellipses",
    )
    odometry_xy = _odometry_in_map(estimate, odometry)
    if odometry_xy is not None:
        ax.plot(odometry_xy[:, 0], odometry_xy[:, 1], color="tab:orange", lw=0.8, label="odometry")
    if len(estimate.trajectory):
        ax.plot(
            estimate.trajectory[:, 0],
            estimate.trajectory[:, 1],
            color="tab:green",
            lw=1.0,
            label="estimated trajectory",
        )
    if truth_path is not None:
        ax.plot(truth_path[:, 0], truth_path[:, 1], "k--", lw=0.8, label="ground truth")
    ax.legend(fontsize=8, loc="best")
    fig.savefig(path)
    fig.savefig(Path(path).with_suffix(".svg"))
    plt.close(fig)


def plot_comparison(
    estimates: Sequence[tuple[str, Estimate]], truth: dict[int, gtsam.Pose2], path: Path
) -> None:
    """Every method's map side by side."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(
        1,
        len(estimates),
        figsize=(4.5 * len(estimates), 4.5),
        constrained_layout=True,
        squeeze=False,
    )
    for ax, (label, estimate) in zip(axes[0], estimates, strict=True):
        _axes_for(ax, estimate, truth, label)
    fig.savefig(path)
    plt.close(fig)
