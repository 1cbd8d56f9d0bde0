# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # How well the front end measures theta, range and position
#
# The paper measures a marker's yaw **theta** from its four corner pixels, without calibration,
# and its distance with a depth camera (an Intel RealSense D435i), and reports:
#
# > an error of less than 2 degrees [in theta] from a distance of 3 m or less with the marker
# > size being 20 cm x 20 cm. [...] the measurement is less accurate when the marker is not
# > aligned at the center of the frame.
#
# > the error was observed to be approximately less than or equal to 15 cm for both x and y from
# > a distance d of up to 4 m.
#
# Here one 20 cm marker hangs 1 m high on a long wall, and the simulator renders it (colour with
# blur and noise, aligned depth with a D435i-like error) from a grid of viewpoints: distance 1 to
# 5 m, view angle theta from -70 to +70 degrees, and the marker at the image centre or 15
# degrees to either side. The camera is 0.6 m high and pitched up 10 degrees, as on our robot.
# Each frame is detected once and measured with each of the four yaw methods
# (`markergraph.frontend.yaw.YawMethod`):
#
# | method | theta from |
# |---|---|
# | `paper` | the paper's arccos(s_a / left edge), literally |
# | `mean-edge` | arccos(s_a / mean of both vertical edges) |
# | `calibrated` | the mean-edge ratio with the bearing undone (needs the intrinsics) |
# | `pnp` | OpenCV's `solvePnP` with `SOLVEPNP_IPPE_SQUARE` (intrinsics and marker size) |
#
# Truth is the geometry the frames were drawn from. Position is the camera's (x, y) in the
# marker's frame (x along its normal) from (range, theta), the paper's "taxi-cab" coordinates.

# %%
import math

import gtsam
import matplotlib.pyplot as plt
import numpy as np

from markergraph.datasets import Marker, Wall, World
from markergraph.datasets.render import Renderer
from markergraph.frontend.detect import Detector
from markergraph.frontend.observe import ObservationModel, observe_detections
from markergraph.frontend.sizes import MarkerSizes
from markergraph.frontend.yaw import YawMethod
from markergraph.notebook_figures import NotebookFigures

# each figure is also saved as PNG: in $MARKERGRAPH_FIGURES, or notebooks/figures/ from a script
figures = NotebookFigures.of("frontend_accuracy")

DISTANCES = np.arange(1.0, 5.01, 0.5)
ANGLES_DEG = np.arange(-70, 71, 10)
OFF_CENTRE_DEG = (-15.0, 0.0, 15.0)  # the marker's bearing in the image, left positive
METHODS = list(YawMethod)
COLOURS = {
    "paper": "tab:red",
    "mean-edge": "tab:orange",
    "calibrated": "tab:purple",
    "pnp": "tab:blue",
}

world = World(
    "wall", (Wall((-8.0, 0.0), (8.0, 0.0)),), (Marker(0, 0, 8.0, side=1, height_m=1.0),), 0
)
renderer = Renderer(world)
detector = Detector("DICT_4X4_50")
T_world_marker = world.T_world_marker(0)
rng = np.random.default_rng(7)

rows = []  # distance, angle, off-centre, method index, theta err, range err, x err, y err
for d in DISTANCES:
    for angle in np.radians(ANGLES_DEG):
        for off in np.radians(OFF_CENTRE_DEG):
            p_camera = T_world_marker.transformFrom(
                np.array([d * math.cos(angle), d * math.sin(angle)])
            )
            to_marker = T_world_marker.translation() - p_camera
            heading = math.atan2(to_marker[1], to_marker[0]) - off
            T_world_camera = gtsam.Pose2(p_camera[0], p_camera[1], heading)
            frame = renderer.render(
                T_world_camera.compose(renderer.mount.T_base_camera.inverse()), rng
            )
            detections = detector.detect(frame.rgb)
            for k, method in enumerate(METHODS):
                found = observe_detections(
                    detections,
                    renderer.camera,
                    ObservationModel(MarkerSizes(0.2), method=method),
                    depth=frame.depth_mm,
                    mount=renderer.mount,
                )
                if not found:  # not detected, or no solution (the paper's formula)
                    rows.append((d, angle, off, k, np.nan, np.nan, np.nan, np.nan))
                    continue
                obs = found[0]
                x, y = obs.range_m * math.cos(obs.theta), obs.range_m * math.sin(obs.theta)
                rows.append((
                    d, angle, off, k,
                    abs(math.remainder(obs.theta - angle, math.tau)),
                    abs(obs.range_m - d),
                    abs(x - d * math.cos(angle)),
                    abs(y - d * math.sin(angle)),
                ))  # fmt: skip
rows = np.array(rows)
dist, view, off_centre, method_ix, theta_err, range_err, x_err, y_err = rows.T
print(f"{len(rows) // len(METHODS)} frames rendered and measured four ways")
print(
    "detected or solved:",
    {
        m.value: f"{np.mean(np.isfinite(theta_err[method_ix == k])):.0%}"
        for k, m in enumerate(METHODS)
    },
)

# %% [markdown]
# ## Theta error against distance, view angle and off-centre offset
#
# Medians (lines) with the 90th percentile (shaded), over every viewpoint the marker was
# detected from. The dashed lines are the paper's 2 degrees and 3 m.


# %%
def band(ax, x_values, select, errors, colour, label, scale=1.0):
    medians, highs = [], []
    for value in x_values:
        chosen = errors[select(value)]
        chosen = chosen[np.isfinite(chosen)] * scale
        medians.append(np.median(chosen) if len(chosen) else np.nan)
        highs.append(np.percentile(chosen, 90) if len(chosen) else np.nan)
    ax.plot(x_values, medians, "o-", color=colour, label=label, ms=4)
    ax.fill_between(x_values, medians, highs, color=colour, alpha=0.15)


fig, axes = plt.subplots(1, 3, figsize=(15, 4), sharey=True)
for k, method in enumerate(METHODS):
    colour = COLOURS[method.value]
    band(
        axes[0],
        DISTANCES,
        lambda v, k=k: (method_ix == k) & np.isclose(dist, v),
        theta_err,
        colour,
        method.value,
        180 / math.pi,
    )
    band(
        axes[1],
        ANGLES_DEG,
        lambda v, k=k: (method_ix == k) & np.isclose(view, math.radians(v)) & (dist <= 3.0),
        theta_err,
        colour,
        method.value,
        180 / math.pi,
    )
    band(
        axes[2],
        OFF_CENTRE_DEG,
        lambda v, k=k: (method_ix == k) & np.isclose(off_centre, math.radians(v)) & (dist <= 3.0),
        theta_err,
        colour,
        method.value,
        180 / math.pi,
    )
axes[0].set(
    xlabel="distance [m]",
    ylabel="|theta error| [deg]",
    yscale="log",
    title="all angles and offsets",
)
axes[0].axvline(3.0, color="k", ls=":", lw=1)
axes[1].set(xlabel="view angle theta [deg]", title="within 3 m")
axes[2].set(xlabel="marker's bearing in the image [deg]", title="within 3 m", xticks=OFF_CENTRE_DEG)
for ax in axes:
    ax.axhline(2.0, color="k", ls="--", lw=1)
    ax.grid(True, which="both", alpha=0.3)
axes[0].legend()
figures.show(fig, "theta-error")

# %% [markdown]
# ## Range and position error against distance
#
# Range comes from the median aligned depth inside the marker, turned through the camera's
# height and pitch into the horizontal distance (the paper's "corrected distance"); it does not
# depend on the yaw method. Position (x, y) in the marker's frame combines range and theta, so
# a theta error of e radians moves the position sideways by about d * e.

# %%
fig, axes = plt.subplots(1, 2, figsize=(12, 4))
band(
    axes[0],
    DISTANCES,
    lambda v: (method_ix == 0) & np.isclose(dist, v),
    range_err,
    "k",
    "range (every method)",
    100.0,
)
axes[0].set(xlabel="distance [m]", ylabel="|range error| [cm]", yscale="log")
xy_err = np.maximum(x_err, y_err)
for k, method in enumerate(METHODS):
    band(
        axes[1],
        DISTANCES,
        lambda v, k=k: (method_ix == k) & np.isclose(dist, v),
        xy_err,
        COLOURS[method.value],
        method.value,
        100.0,
    )
axes[1].axhline(15.0, color="k", ls="--", lw=1)
axes[1].axvline(4.0, color="k", ls=":", lw=1)
axes[1].set(xlabel="distance [m]", ylabel="max(|x error|, |y error|) [cm]", yscale="log")
for ax in axes:
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
figures.show(fig, "range-and-position-error")
range_cm = {
    d: 100 * np.nanmedian(range_err[(method_ix == 0) & np.isclose(dist, d)]) for d in DISTANCES
}
print(
    "median |range error| [cm]:",
    {f"{d:g} m": round(float(value), 2) for d, value in range_cm.items()},
)

# %% [markdown]
# ## Do the paper's figures hold?
#
# The paper's robot turns to centre the marker before it measures, and our front end down-weights
# views beyond 60 degrees (the mirrored-pose ambiguity of a foreshortened square). So the
# figures are judged twice: over the views the paper's procedure uses (marker centred,
# |theta| <= 60 degrees) and over every view of the grid. "Holds" means for 95% of the
# measurements in range (a median would hide the bad views); views where a method gave no
# answer are counted apart.


# %%
def verdict(select):
    """{method: (theta 95th percentile within 3 m [deg], x,y 95th percentile within 4 m [cm])}"""
    figures = {}
    for k, method in enumerate(METHODS):
        chosen = select & (method_ix == k)
        theta = np.degrees(theta_err[chosen & (dist <= 3.0)])
        xy = 100.0 * xy_err[chosen & (dist <= 4.0)]
        answered = np.isfinite(theta).mean()
        theta, xy = theta[np.isfinite(theta)], xy[np.isfinite(xy)]
        figures[method.value] = (np.percentile(theta, 95), np.percentile(xy, 95))
        print(
            f"  {method.value:<11} answered {answered:>4.0%}   theta median {np.median(theta):5.2f},"
            f" 95% {figures[method.value][0]:5.2f} deg ({'holds' if figures[method.value][0] < 2 else 'fails'})"
            f"   x,y median {np.median(xy):5.1f}, 95% {figures[method.value][1]:5.1f} cm"
            f" ({'holds' if figures[method.value][1] <= 15 else 'fails'})"
        )
    return figures


print("the paper's views (marker centred, |theta| <= 60 deg):")
papers_views = verdict(np.isclose(off_centre, 0.0) & (np.abs(view) <= math.radians(60.0)))
print("every view (offsets of 15 deg, |theta| up to 70 deg):")
every_view = verdict(np.ones_like(dist, dtype=bool))
for k, method in enumerate(METHODS):
    near = (method_ix == k) & (dist <= 3.0)
    ratio = np.nanmedian(theta_err[near & ~np.isclose(off_centre, 0.0)]) / np.nanmedian(
        theta_err[near & np.isclose(off_centre, 0.0)]
    )
    print(f"{method.value}: off-centre median theta error is {ratio:.1f}x the centred one")

# %% [markdown]
# What this says:
#
# * With the intrinsics, `pnp` meets both of the paper's figures over the paper's views, and
#   its median theta error is a tenth of a degree; it is the front end's default.
# * Without calibration, as the paper measures, theta misses 2 degrees at the 95th percentile
#   for every ratio method, even over the paper's views. Their ratio is cos(theta), which is
#   flat near theta = 0, and the camera looking up at the marker (0.4 m below it, pitched 10
#   degrees) foreshortens the edges so that the ratio reaches 1 early: every ratio method reads
#   theta = 0 at a true 10 degrees (the spikes at +-10 in the middle panel), and the paper's
#   one-edge formula has no answer at all there.
# * The paper's remark that off-centre markers measure worse holds for the ratio methods (about
#   2.5x); `calibrated` undoes the bearing and `pnp` never had the problem.
# * Range comes from aligned depth averaged over the marker (its median error per distance is
#   printed above). The simulated depth noise (1 + 2 Z^2 mm per 8x8 block) has no bias, so
#   these range figures are optimistic next to a real D435i, whose error has a bias that grows
#   with distance; x, y errors are dominated by theta all the same: a theta error e moves the
#   position by about d * e.
#
# The checks below are this notebook's claims.

# %%
assert papers_views["pnp"][0] < 2.0 and papers_views["pnp"][1] <= 15.0, papers_views
assert min(papers_views[m][0] for m in ("paper", "mean-edge", "calibrated")) > 2.0, papers_views
assert every_view["pnp"][1] > papers_views["pnp"][1]  # off-centre, grazing views cost accuracy
# PnP, with the intrinsics, beats every calibration-free ratio up to 4 m. At 5 m the marker
# is about 25 px wide (615 px x 0.2 m / 5 m) and PnP loses its edge: the medians printed last.
for d in DISTANCES[DISTANCES <= 4.0]:
    by_method = {
        m.value: np.nanmedian(theta_err[(method_ix == k) & np.isclose(dist, d)])
        for k, m in enumerate(METHODS)
    }
    assert by_method["pnp"] < min(by_method["mean-edge"], by_method["paper"]), (d, by_method)
at_5_m = {
    m.value: np.degrees(np.nanmedian(theta_err[(method_ix == k) & np.isclose(dist, 5.0)]))
    for k, m in enumerate(METHODS)
}
print(
    "median |theta error| at 5 m [deg]:",
    {name: round(float(value), 2) for name, value in at_5_m.items()},
)
