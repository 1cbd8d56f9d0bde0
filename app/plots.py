"""Floor plans of marker maps and the diagnostics figure (matplotlib, imported here only)."""

from __future__ import annotations

import math
import shutil
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.estimator import Observation
from markergraph.estimator.metrics import align_rigid_2d
from markergraph.estimator.trajectory import Trajectory
from markergraph.markermap import MarkerMap

__all__ = [
    "copy_map",
    "diagnostics_figure",
    "draw_marker_map",
    "map_figure",
    "plot_comparison",
    "plot_diagnostics",
    "plot_map",
    "truth_onto_map",
    "warm_up",
]

MARGIN = 0.1  # of the view's larger side, around what is drawn
PANEL_TEXT_IN = 1.1  # a comparison panel's two-line title and tick labels [in]
CIRCLE = np.stack([np.cos(np.linspace(0, math.tau, 60)), np.sin(np.linspace(0, math.tau, 60))])


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def warm_up() -> None:
    """matplotlib imported and its font loaded, as drawing the first figure would (0.3-0.5 s)."""
    plt = _pyplot()
    fig = plt.figure(figsize=(1, 1))
    fig.text(0.5, 0.5, "markergraph")
    fig.canvas.draw()
    plt.close(fig)


def _extent(points: Sequence[NDArray[np.float64]]) -> tuple[float, float, float, float]:
    """The view (x0, x1, y0, y1) around every point, with a margin: the room, not the ellipses."""
    xy = np.concatenate([p.reshape(-1, 2) for p in points if len(p)])
    (x0, y0), (x1, y1) = xy.min(axis=0), xy.max(axis=0)
    pad = MARGIN * max(x1 - x0, y1 - y0, 1.0)
    return x0 - pad, x1 + pad, y0 - pad, y1 + pad


def _map_points(
    marker_map: MarkerMap, truth: Mapping[int, gtsam.Pose2], paths: Sequence[Trajectory | None]
) -> list[NDArray[np.float64]]:
    points = [np.array([[T.x(), T.y()] for T in truth.values()]).reshape(-1, 2)]
    points.append(
        np.array([[m.T_map_marker.x(), m.T_map_marker.y()] for m in marker_map.markers.values()])
    )
    points += [p.poses[:, :2] for p in paths if p is not None and len(p)]
    return points


def truth_onto_map(marker_map: MarkerMap, truth: Mapping[int, gtsam.Pose2]) -> gtsam.Pose2 | None:
    """``T_map_truth``: the rigid SE(2) fit (Kabsch, positions) of the true markers onto the
    estimated ones, so that the truth is drawn where the map put the room; None with fewer
    than two markers in both."""
    ids = sorted(set(marker_map.markers) & set(truth))
    if len(ids) < 2:
        return None
    true_xy = np.array([[truth[i].x(), truth[i].y()] for i in ids])
    map_xy = np.array(
        [[marker_map.markers[i].T_map_marker.x(), marker_map.markers[i].T_map_marker.y()]
         for i in ids]
    )  # fmt: skip
    return align_rigid_2d(true_xy, map_xy)


def _aligned(
    marker_map: MarkerMap, truth: Mapping[int, gtsam.Pose2]
) -> tuple[dict[int, gtsam.Pose2], gtsam.Pose2 | None]:
    """The true markers moved onto the map (unmoved when they cannot be fitted), and the fit."""
    T_map_truth = truth_onto_map(marker_map, truth)
    if T_map_truth is None:
        return dict(truth), None
    return {i: T_map_truth.compose(T) for i, T in truth.items()}, T_map_truth


def _title(marker_map: MarkerMap, rmse_m: tuple[float, float] | None) -> str:
    """What the panel shows: ellipses or none, and the marker RMSE when the truth is known:
    after a rigid alignment first (what evo and other mappers report), then with the home
    marker held fixed (its own error carried to the far markers)."""
    has_covariance = any(m.covariance is not None for m in marker_map.markers.values())
    title = "2-sigma ellipses" if has_covariance else "no covariance"
    if rmse_m is not None:
        title += (
            f", marker RMSE {100 * rmse_m[1]:.1f} cm aligned ({100 * rmse_m[0]:.1f} cm home-fixed)"
        )
    return title


def _legend_outside(ax: Any, fontsize: int) -> None:
    """The legend right of the axes: inside, a narrow map leaves it nowhere free to go."""
    ax.legend(fontsize=fontsize, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)


def _draw_map(
    ax: Any,
    marker_map: MarkerMap,
    truth: Mapping[int, gtsam.Pose2],
    title: str,
    view: tuple[float, float, float, float],
) -> None:
    """The marker graph's links, markers with their normals and ids, 2-sigma ellipses (those
    larger than half the view drawn dashed, clipped by it and their size written beside the
    id), and the true markers as grey crosses."""
    x0, x1, y0, y1 = view
    too_big = 0.5 * max(x1 - x0, y1 - y0)
    for i, link in enumerate(marker_map.links):
        a, b = marker_map.markers[link.marker_a], marker_map.markers[link.marker_b]
        ax.plot(
            [a.T_map_marker.x(), b.T_map_marker.x()],
            [a.T_map_marker.y(), b.T_map_marker.y()],
            color="tab:purple", lw=0.5, alpha=0.5, zorder=1,
            label="links (the paper's edges)" if i == 0 else None,
        )  # fmt: skip
    xy = np.array([[m.T_map_marker.x(), m.T_map_marker.y()] for m in marker_map.markers.values()])
    ax.plot(xy[:, 0], xy[:, 1], "o", color="tab:blue", ms=4, label="estimated markers", zorder=3)
    for marker_id, marker in marker_map.markers.items():
        T = marker.T_map_marker
        label = str(marker_id)
        ax.arrow(T.x(), T.y(), 0.3 * math.cos(T.theta()), 0.3 * math.sin(T.theta()),
                 width=0.02, color="tab:blue", length_includes_head=True, zorder=3)  # fmt: skip
        ellipse = marker.position_ellipse(2.0)
        if ellipse is not None:
            (major, minor), heading = ellipse
            c, s = math.cos(heading), math.sin(heading)
            outline = np.array([[c, -s], [s, c]]) @ (np.array([[major / 2], [minor / 2]]) * CIRCLE)
            oversized = major > too_big
            ax.plot(T.x() + outline[0], T.y() + outline[1], color="tab:blue", lw=0.8,
                    ls="--" if oversized else "-", alpha=0.35 if oversized else 1.0,
                    zorder=2)  # fmt: skip
            if oversized:
                label += f" (2σ {major:.1f} m)"
        ax.annotate(label, (T.x(), T.y()), textcoords="offset points", xytext=(4, 4), fontsize=8)
    if truth:
        true_xy = np.array([[T.x(), T.y()] for T in truth.values()])
        ax.plot(true_xy[:, 0], true_xy[:, 1], "x", color="grey", label="true markers")
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title, fontsize=9)


def map_figure(
    marker_map: MarkerMap,
    truth: Mapping[int, gtsam.Pose2],
    *,
    trajectory: Trajectory | None = None,
    odometry: Trajectory | None = None,
    truth_path: Trajectory | None = None,
    rmse_m: tuple[float, float] | None = None,
) -> Any:
    """The map with its estimated trajectory, the raw odometry (anchored on the trajectory's
    first pose) and the dashed ground truth; ``rmse_m`` (against the truth,
    home-fixed and aligned) goes into the title.

    The truth (markers and path) is drawn fitted onto the map by a rigid SE(2) motion
    (:func:`truth_onto_map`), as the title says: in the home marker's frame the home marker's
    own yaw error turns the whole room, and hides how well its shape was found.

    Returns:
        The matplotlib figure (the caller saves and closes it).
    """
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 6), constrained_layout=True)
    truth, T_map_truth = _aligned(marker_map, truth)
    if T_map_truth is not None and truth_path is not None:
        truth_path = truth_path.in_frame(T_map_truth, "map")
    drawn_odometry = None
    if trajectory is not None and len(trajectory) and odometry is not None and len(odometry):
        T_map_odom = trajectory.T_self_other(odometry, int(trajectory.t_ns[0]))
        if T_map_odom is not None:
            drawn_odometry = odometry.in_frame(T_map_odom, "map")
    view = _extent(_map_points(marker_map, truth, [trajectory, truth_path, drawn_odometry]))
    fitted = (
        "truth fitted onto the map (rigid SE(2) on the markers)"
        if T_map_truth is not None
        else "truth as logged"
    )
    title = (
        f"{marker_map.method}: {_title(marker_map, rmse_m)}\n"
        f"map in the frame of marker {marker_map.home_id}; {fitted}"
    )
    _draw_map(ax, marker_map, truth, title, view)
    if drawn_odometry is not None:
        xy = drawn_odometry.poses
        ax.plot(xy[:, 0], xy[:, 1], color="tab:orange", lw=0.8, label="odometry")
    if trajectory is not None and len(trajectory):
        xy = trajectory.poses
        ax.plot(xy[:, 0], xy[:, 1], color="tab:green", lw=1.0, label="estimated trajectory")
    if truth_path is not None and len(truth_path):
        xy = truth_path.poses
        ax.plot(xy[:, 0], xy[:, 1], "k--", lw=0.8, label="ground truth")
    _legend_outside(ax, 8)
    return fig


def plot_map(
    marker_map: MarkerMap,
    truth: Mapping[int, gtsam.Pose2],
    path: Path,
    *,
    trajectory: Trajectory | None = None,
    odometry: Trajectory | None = None,
    truth_path: Trajectory | None = None,
    rmse_m: tuple[float, float] | None = None,
) -> None:
    """:func:`map_figure` as PNG and SVG."""
    plt = _pyplot()
    fig = map_figure(
        marker_map, truth, trajectory=trajectory, odometry=odometry, truth_path=truth_path,
        rmse_m=rmse_m,
    )  # fmt: skip
    fig.savefig(path, bbox_inches="tight")
    fig.savefig(Path(path).with_suffix(".svg"), bbox_inches="tight")
    plt.close(fig)


def copy_map(drawn: Path, path: Path) -> None:
    """:func:`plot_map`'s PNG and SVG at ``drawn`` copied to ``path``: one method's map in two
    folders is drawn once."""
    for suffix in (".png", ".svg"):
        shutil.copyfile(Path(drawn).with_suffix(suffix), Path(path).with_suffix(suffix))


def plot_comparison(
    maps: Sequence[tuple[str, MarkerMap, tuple[float, float] | None]],
    truth: Mapping[int, gtsam.Pose2],
    path: Path,
) -> None:
    """Every method's map, three to a row, on shared axes; (label, map, RMSE in the home
    frame and aligned, or None) each."""
    plt = _pyplot()
    columns = min(3, len(maps))
    rows = math.ceil(len(maps) / columns)
    points = [p for _, m, _ in maps for p in _map_points(m, _aligned(m, truth)[0], [])]
    view = _extent(points)
    # Each panel as tall as the map is at its width (equal axes), plus its two-line title and
    # tick labels: a fixed height left an empty band between the rows of a wide map.
    aspect = (view[3] - view[2]) / (view[1] - view[0])
    panel_in = 5.5
    height_in = min(max(panel_in * aspect, 1.5), 2.0 * panel_in) + PANEL_TEXT_IN
    fig, axes = plt.subplots(
        rows, columns, figsize=(panel_in * columns, height_in * rows), constrained_layout=True,
        squeeze=False, sharex=True, sharey=True,
    )  # fmt: skip
    for ax, (label, marker_map, rmse_m) in zip(axes.flat, maps, strict=False):
        fitted, T_map_truth = _aligned(marker_map, truth)
        how = "truth fitted onto the map" if T_map_truth is not None else "truth as logged"
        _draw_map(ax, marker_map, fitted, f"{label} ({how})\n{_title(marker_map, rmse_m)}", view)
    for ax in axes.flat[len(maps) :]:
        ax.axis("off")
    _legend_outside(axes[0][-1], 7)
    _trim_rows(fig, axes[0][0], rows)
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)


def _trim_rows(fig: Any, ax: Any, rows: int) -> None:
    """The figure made as short as its equal-aspect panels allow, so that no empty band is
    left between rows: the shortest height at which a panel still fills its slot's width
    (a bisection: the titles and labels keep their size, the layout does not scale). Each step
    lays the figure out without drawing it: with five methods' panels, drawing it at each step
    made the figure take 4.2 s, against 2.0-2.9 s laid out (the same PNG)."""
    width_in, high = fig.get_size_inches()
    engine = fig.get_layout_engine()
    low = rows * 1.0
    for _ in range(8):
        middle = 0.5 * (low + high)
        fig.set_size_inches(width_in, middle)
        engine.execute(fig)
        slot, used = ax.get_position(original=True), ax.get_position()
        if used.width >= slot.width * 0.995:  # still as wide as its slot: shorter may do
            high = middle
        else:
            low = middle
    fig.set_size_inches(width_in, high)


def plot_diagnostics(
    label: str, report: Mapping[str, Any], observations: Sequence[Observation], path: Path
) -> None:
    """diagnostics.png (:func:`diagnostics_figure`)."""
    fig = diagnostics_figure(label, report, observations)
    fig.savefig(path, bbox_inches="tight")
    _pyplot().close(fig)


def _legend_below(ax: Any) -> None:
    """The legend under the axes, in one row: inside, it covers the markers' points."""
    handles, _ = ax.get_legend_handles_labels()
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=len(handles),
              frameon=False)  # fmt: skip


def diagnostics_figure(
    label: str, report: Mapping[str, Any], observations: Sequence[Observation]
) -> Any:
    """Two panels for one method: each marker's whitened residuals (median, 95th percentile
    and largest, down-weighted factors counted), and a timeline of each marker's detections
    with the down-weighted ones marked; legends below the panels, marker ids as integers.

    Returns:
        The matplotlib figure (the caller saves and closes it).
    """
    from matplotlib.ticker import FuncFormatter, LogLocator, MaxNLocator, NullFormatter

    plt = _pyplot()
    fig, (left, right) = plt.subplots(
        1, 2, figsize=(12, 4.5), constrained_layout=True, width_ratios=[1, 1.6]
    )
    markers = report.get("markers", {})
    if markers:
        ids = list(markers)
        x = np.arange(len(ids))
        for key, style, name in (("whitened_median", "o", "median"),
                                 ("whitened_p95", "^", "95th percentile"),
                                 ("whitened_max", "v", "largest")):  # fmt: skip
            left.plot(x, [markers[i][key] for i in ids], style, ms=4, label=name)
        for xi, i in zip(x, ids, strict=True):
            if down := markers[i]["downweighted"]:
                left.annotate(f"{down} down", (xi, markers[i]["whitened_max"]),
                              textcoords="offset points", xytext=(0, 4), fontsize=7,
                              ha="center", color="tab:red")  # fmt: skip
        left.axhline(3.0, color="grey", lw=0.8, ls="--", label="3 sigma")
        left.set_xticks(x, ids, fontsize=7)
        left.set_yscale("log")
        # 0.2, 0.5, 1, 2, 5: not 3 x 10^-1, and no crowd of minor labels.
        left.yaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
        left.yaxis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
        left.yaxis.set_minor_formatter(NullFormatter())
        _legend_below(left)
    else:
        left.text(0.5, 0.5, f"{label}: no residuals (no factors)", ha="center",
                  transform=left.transAxes)  # fmt: skip
    left.set_xlabel("marker id")
    left.set_ylabel("whitened residual [sigma]")
    left.set_title(f"{label}: residuals per marker", fontsize=9)
    if observations:
        t0 = min(o.t_ns for o in observations)
        t = np.array([(o.t_ns - t0) * 1e-9 for o in observations])
        ids_seen = np.array([o.marker_id for o in observations])
        right.plot(t, ids_seen, "|", color="tab:blue", ms=6, label="detections")
        rejected = [(d["t_ns"], m) for d in report.get("downweighted", [])
                    if d["kind"] == "observation" and d["t_ns"] is not None
                    for m in d["marker_ids"]]  # fmt: skip
        if rejected:
            rt = np.array([(s - t0) * 1e-9 for s, _ in rejected])
            right.plot(rt, [m for _, m in rejected], "x", color="tab:red", ms=6,
                       label="down-weighted by the robust kernel")  # fmt: skip
        _legend_below(right)
    right.yaxis.set_major_locator(MaxNLocator(integer=True))  # marker ids: no 0.25
    right.set_xlabel("time since the first detection [s]")
    right.set_ylabel("marker id")
    right.set_title("detections per marker", fontsize=9)
    return fig


def draw_marker_map(
    ax: Any, marker_map: MarkerMap, title: str, points: Sequence[NDArray[np.float64]]
) -> None:
    """The map as map.png draws it (links, markers with normals, 2-sigma ellipses), without
    truth, on ``ax`` in a view around its markers and ``points`` ((N, 2) arrays [m]): for
    figures of other commands (localize's map.png) drawn over the same map."""
    view = _extent(_map_points(marker_map, {}, []) + [p for p in points if len(p)])
    _draw_map(ax, marker_map, {}, title, view)
