"""The figure of ``markergraph compare --plot``: both maps in the reference's frame, top view
(matplotlib, imported here only)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from markergraph.common.files import written_whole
from markergraph.compare import CHI2_95, Comparison

__all__ = ["SHOWN_ERROR", "exaggeration", "plot_comparison"]

SHOWN_ERROR = 0.02
"""The largest error is drawn at least this share of the view's size (errors and ellipses
exaggerated by a round factor, said in the legend): centimetres in a room vanish otherwise."""

MIN_SHOWN_ERROR_M = 1e-6
"""Errors below a micrometre are drawn as they are, not exaggerated."""
PANEL_WIDTH_IN = 7.0  # the figure's width; its height follows the maps' aspect [in]

_CIRCLE = np.stack([np.cos(np.linspace(0, math.tau, 60)), np.sin(np.linspace(0, math.tau, 60))])


def _ellipse_xy(centre: np.ndarray, covariance: np.ndarray) -> np.ndarray | None:
    """The 95 % ellipse of a 2x2 covariance, as (2, 60) points; None for a singular one."""
    values, vectors = np.linalg.eigh(covariance)
    if not np.all(np.isfinite(values)) or values[0] <= 0.0:
        return None
    radii = np.sqrt(values * CHI2_95[2])
    return centre[:, None] + vectors @ (radii[:, None] * _CIRCLE)


def exaggeration(errors_m: np.ndarray, size_m: float) -> float:
    """The round factor (1, 2, 5, 10, 20, ...) by which errors are drawn so that the largest
    is at least :data:`SHOWN_ERROR` of ``size_m``; 1 where they show as they are."""
    largest = float(np.nanmax(np.abs(errors_m))) if errors_m.size else 0.0
    # Float noise (a map against itself) is no error to magnify by 10^14.
    if largest <= MIN_SHOWN_ERROR_M or largest >= SHOWN_ERROR * size_m:
        return 1.0
    needed = SHOWN_ERROR * size_m / largest
    decade = 10.0 ** math.floor(math.log10(needed))
    return next(decade * step for step in (1.0, 2.0, 5.0, 10.0) if decade * step >= needed)


def _figure_size(xy: np.ndarray) -> tuple[float, float]:
    """(width, height) [in] for points ``xy`` (N, 2) drawn with equal axes: as tall as they are
    at the figure's width, within 0.3 to 1.5 of it, plus room for the title and legend."""
    span = np.ptp(xy, axis=0) if len(xy) > 1 else np.ones(2)
    aspect = float(span[1] / span[0]) if span[0] > 0 else 1.0
    return PANEL_WIDTH_IN, PANEL_WIDTH_IN * min(max(aspect, 0.3), 1.5) + 1.6


def plot_comparison(result: Comparison, path: Path, title: str) -> None:
    """Draw the reference's markers hollow, the aligned map's filled, a line from each to its
    counterpart, and the map's 95 % position ellipses; a PNG written whole.

    The map is the rigidly aligned one (``result.aligned``); a 3-D comparison is drawn from
    above.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scored = result.aligned
    theirs = result.p_ref[:, :2]
    size = float(np.max(np.ptp(theirs, axis=0))) if len(theirs) > 1 else 1.0
    factor = exaggeration(scored.p_map_aligned[:, :2] - theirs, max(size, 1e-9))
    # The map's markers drawn at the reference's plus the error times the factor.
    ours = theirs + factor * (scored.p_map_aligned[:, :2] - theirs)
    figure, axes = plt.subplots(figsize=_figure_size(np.vstack([ours, theirs])), dpi=110)
    for k in range(len(result.ids)):
        axes.plot(*np.stack([ours[k], theirs[k]]).T, color="tab:red", linewidth=1.2, zorder=2)
        ellipse = _ellipse_xy(ours[k], factor**2 * scored.cov_aligned[k][:2, :2])
        if ellipse is not None:
            axes.plot(*ellipse, color="tab:blue", linewidth=0.8, alpha=0.7, zorder=1)
        axes.annotate(str(int(result.ids[k])), theirs[k], textcoords="offset points",
                      xytext=(5, 5), fontsize=8)  # fmt: skip
    times = "" if factor == 1.0 else f" x{factor:g}"
    axes.scatter(
        theirs[:, 0], theirs[:, 1], s=60, facecolors="none", edgecolors="black",
        label="reference", zorder=3,
    )  # fmt: skip
    axes.scatter(ours[:, 0], ours[:, 1], s=22, color="tab:blue", label="map (aligned)", zorder=4)
    axes.plot([], [], color="tab:red", label=f"error{times}")
    axes.plot([], [], color="tab:blue", linewidth=0.8, label=f"map's 95 % ellipse{times}")
    # The axes fit to the maps (adjustable="box"), the figure cut to them: "datalim" with a
    # fixed figure left an empty band above and below a wide map.
    axes.set_aspect("equal", adjustable="box")
    axes.set_xlabel("x [m]")
    axes.set_ylabel("y [m]")
    position = scored.position
    figures = f"aligned position RMSE {position.rmse:.4f} m, max {position.max:.4f} m"
    axes.set_title(f"{title}\n{figures}", fontsize=9)
    # Below the axes, in two rows: inside, "best" still covered markers in a crowded map.
    axes.legend(loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2, fontsize=8,
                frameon=False)  # fmt: skip
    axes.grid(True, alpha=0.3)
    with written_whole(path) as partial:
        figure.savefig(partial, format="png", bbox_inches="tight")
    plt.close(figure)
