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
# # Drift: the paper's closed form against the optimised maps
#
# The paper places each new marker by composing measured edges from the home marker (its
# function **M**), so every error along the chain stays in the map: nothing closes a loop. Here
# the simulator drives seeded runs through the built-in scenarios and every estimator maps the
# same observations:
#
# | method | what it is |
# |---|---|
# | `closed-form/signed` | the paper's procedure with its signs fixed (the printed signs are wrong; see `paper_closed_forms`) |
# | `marker-graph` | the paper's node graph, every measured edge E_ab a factor, optimised |
# | `slam` | robot poses and markers, odometry and observation factors, batch Levenberg-Marquardt |
# | `isam2` | the same graph solved incrementally, frame by frame |
# | `ekf` | EKF-SLAM on filterpy |
#
# The wheels drift as a real base's do: a scale error, a turn-scale error and a heading bias
# drawn once per run, plus a random walk (`WheelErrors`). We sweep that drift from half to four
# times the default and look at the marker map error (RMSE of marker positions in the home
# marker's frame, against the simulator's truth) and the trajectory error (ATE).
#
# `MARKERGRAPH_SEEDS` sets the seeds per point (3 by default, so the notebook runs in CI in
# about two minutes; `python tests/benchmarks/drift_study.py --seeds 10` is the larger study).

# %%
import math
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small matrices: one BLAS thread is faster

import dataclasses

import gtsam
import matplotlib.pyplot as plt
import numpy as np

from markergraph.datasets import scenario, simulate_fast
from markergraph.datasets.route import WheelErrors
from markergraph.datasets.study import DEFAULT_METHODS, drift_study, summarise
from markergraph.estimator import Form, Method, OdometryNoise, build_frames, estimate_frames
from markergraph.notebook_figures import NotebookFigures

# each figure is also saved as PNG: in $MARKERGRAPH_FIGURES, or notebooks/figures/ from a script
figures = NotebookFigures.of("drift_comparison")

SEEDS = range(int(os.environ.get("MARKERGRAPH_SEEDS", "3")))
LEVELS = (0.5, 1.0, 2.0, 4.0)  # wheel error, as a multiple of WheelErrors()'s
COLOURS = {
    "closed-form/signed": "tab:red",
    "marker-graph": "tab:orange",
    "slam": "tab:blue",
    "isam2": "tab:cyan",
    "ekf": "tab:green",
}


def scaled(level: float) -> WheelErrors:
    """The simulated wheels' errors, all ``level`` times the default."""
    default = WheelErrors()
    return WheelErrors(*(level * getattr(default, f.name) for f in dataclasses.fields(default)))


def assumed(level: float) -> OdometryNoise:
    """The odometry noise the estimators are told, scaled with the wheels' (a fair fight)."""
    default = OdometryNoise()
    return OdometryNoise(
        level * default.per_m, level * default.yaw_per_m, level * default.yaw_per_rad
    )


# %% [markdown]
# ## Marker error and drift against wheel error (corridor loop)
#
# The corridor loop is a 50 m rectangle with 12 markers: the case drift hurts most, since the
# closed form reaches the last marker through eleven edges. At each level the estimators are
# told an odometry noise model scaled the same way. iSAM2 is left out of the sweep: it solves
# the same graph as batch SLAM and matches it to 1e-6 (`tests/test_estimator.py`); it is in
# the scenario comparison below.

# %%
SWEEP_METHODS = [(m, f) for m, f in DEFAULT_METHODS if m is not Method.ISAM2]
sweep = {
    level: summarise(
        drift_study(
            ["corridor-loop"],
            SEEDS,
            SWEEP_METHODS,
            wheel=scaled(level),
            odometry_noise=assumed(level),
        )
    )
    for level in LEVELS
}
labels = [label for (_, label) in sweep[1.0]]

fig, axes = plt.subplots(1, 2, figsize=(11, 4))
for label in labels:
    for ax, figure in zip(axes, ("marker_rmse_m", "ate_m"), strict=True):
        values = [sweep[level][("corridor-loop", label)][figure] for level in LEVELS]
        ax.plot(LEVELS, values, "o-", color=COLOURS[label], label=label)
for ax, title in zip(axes, ("marker position RMSE [m]", "trajectory ATE [m]"), strict=True):
    ax.set(xscale="log", yscale="log", xlabel="wheel error (x default)", title=title)
    ax.set_xticks(LEVELS, [f"{level:g}" for level in LEVELS])
    ax.set_xticks([], minor=True)
    ax.grid(True, which="both", alpha=0.3)
axes[0].legend()
fig.suptitle(f"corridor loop, mean of {len(SEEDS)} seeds per point")
figures.show(fig, "wheel-error-sweep")
for level in LEVELS:
    print(
        f"wheel error x{level:g}: EKF mean NEES {sweep[level][('corridor-loop', 'ekf')]['mean_nees']:.1f}"
    )

# %% [markdown]
# SLAM's error grows about as fast as the wheels' and stays an order of magnitude below the
# closed form's. The EKF falls away as the drift grows, even told the right noise level: the
# simulated wheels carry systematic errors (a heading bias drawn with a spread of 0.23 deg per metre at
# the default, 0.9 at x4) that a random-walk noise model does not describe, and the filter,
# unlike the batch solver, never relinearises the poses it has passed. Its mean NEES (3 for a
# consistent 3-dof filter) says how overconfident it becomes.

# %% [markdown]
# ## Every method on every scenario, default wheel error
#
# The paper room (3 markers, the paper's own layout), the corridor loop and an office of six
# rooms with 30 markers.

# %%
SCENARIOS = ("paper-room", "corridor-loop", "office")
rows = drift_study(SCENARIOS, SEEDS)
summary = summarise(rows)

fig, ax = plt.subplots(figsize=(11, 4))
width = 0.8 / len(COLOURS)
for k, label in enumerate(COLOURS):
    values = [
        [r.marker_rmse_m for r in rows if r.scenario == s and r.method == label] for s in SCENARIOS
    ]
    x = np.arange(len(SCENARIOS)) + (k - len(COLOURS) / 2 + 0.5) * width
    ax.bar(x, [np.mean(v) for v in values], width, yerr=[np.std(v) for v in values],
           color=COLOURS[label], label=label, capsize=3)  # fmt: skip
ax.set(yscale="log", ylabel="marker position RMSE [m]", xticks=range(len(SCENARIOS)))
ax.set_xticklabels(SCENARIOS)
ax.grid(True, axis="y", which="both", alpha=0.3)
ax.legend(ncols=5, fontsize=8)
figures.show(fig, "scenarios")

print(
    f"{'scenario':<14} {'method':<20} {'marker RMSE':>11} {'aligned':>8} {'yaw':>7} {'ATE':>7}"
    f" {'NEES':>6} {'in 95%':>6}"
)
for (name, label), f in summary.items():
    nees = "" if math.isnan(f["mean_nees"]) else f"{f['mean_nees']:.2f}"
    inside = "" if math.isnan(f["ellipse_coverage"]) else f"{100 * f['ellipse_coverage']:.0f}%"
    print(
        f"{name:<14} {label:<20} {f['marker_rmse_m']:>9.3f} m {f['marker_rmse_aligned_m']:>8.3f}"
        f" {math.degrees(f['marker_yaw_rmse_rad']):>6.2f}° {f['ate_m']:>7.3f} {nees:>6} {inside:>6}"
    )

# %% [markdown]
# "in 95%" is the share of true markers (home aside, which defines the map frame) inside each
# method's 95 % position ellipse (`estimator.metrics.ellipse_coverage`): 95 % for honest
# covariances. Over more seeds the EKF's falls short on the corridor loop (65 % over 10 seeds in
# `tests/benchmarks/drift_study.py`): the wheels' systematic errors bring the robot back to home
# up to 10 deg off, and the filter corrects the markers it placed on the way to first order only.

# %% [markdown]
# ## One run, drawn
#
# Seed 0 of the corridor loop at twice the default wheel error: the true path, wheel odometry
# started at the true pose, and each method's markers and trajectory. The right panel is the
# position error along the way: odometry drifts without bound; the closed form's markers (and
# the robot localised on them) inherit the drift of the chain that placed them; SLAM and the
# EKF pull it back every time a marker is seen again.

# %%
world, route = scenario("corridor-loop")
run = simulate_fast(world, route, 0, wheel=scaled(2.0))
frames = build_frames(
    run.observations, run.odometry, world.home_id, odometry_noise=run.odometry_noise
)
truth_by_stamp = dict(zip(run.frame_t_ns.tolist(), run.true_trajectory(), strict=True))
true_path = np.array([truth_by_stamp[f.t_ns] for f in frames.frames])
travelled = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(true_path[:, :2], axis=0).T))])
# Wheel odometry, started at the true pose of the first frame.
T_map_odom = gtsam.Pose2(*true_path[0]).compose(frames.frames[0].T_odom_base.inverse())
odometry_path = np.array(
    [[p.x(), p.y()] for p in (T_map_odom.compose(f.T_odom_base) for f in frames.frames)]
)
estimates = {
    label: estimate_frames(frames, method, run.mount.T_base_camera, form=Form.SIGNED)
    for method, label in (
        (Method.CLOSED_FORM, "closed-form/signed"),
        (Method.SLAM, "slam"),
        (Method.EKF, "ekf"),
    )
}

fig, (ax_map, ax_error) = plt.subplots(1, 2, figsize=(13, 5), width_ratios=(1.3, 1))
ax_map.plot(true_path[:, 0], true_path[:, 1], "k--", lw=1, label="truth")
ax_map.plot(odometry_path[:, 0], odometry_path[:, 1], color="grey", lw=1, label="wheel odometry")
truth = run.true_markers()
ax_map.plot(
    [T.x() for T in truth.values()], [T.y() for T in truth.values()], "ks", mfc="none", ms=9
)
for label, estimate in estimates.items():
    markers = np.array(
        [[m.T_map_marker.x(), m.T_map_marker.y()] for m in estimate.markers.values()]
    )
    ax_map.plot(*markers.T, "o", color=COLOURS[label], ms=5, label=f"{label} markers")
ax_map.set(aspect="equal", title="map frame = home marker's frame [m]")
ax_map.legend(fontsize=8)

stamps = np.array([f.t_ns for f in frames.frames])
ax_error.plot(
    travelled, np.hypot(*(odometry_path - true_path[:, :2]).T), color="grey", label="wheel odometry"
)
for label, estimate in estimates.items():
    index = np.searchsorted(stamps, estimate.trajectory.t_ns)
    error = np.hypot(*(estimate.trajectory.poses[:, :2] - true_path[index, :2]).T)
    ax_error.plot(travelled[index], error, color=COLOURS[label], lw=1, label=label)
ax_error.set(xlabel="distance travelled [m]", ylabel="position error [m]", yscale="log")
ax_error.grid(True, which="both", alpha=0.3)
ax_error.legend(fontsize=8)
figures.show(fig, "one-run")

# %% [markdown]
# ## What the figures say
#
# The checks below are the claims of this notebook; they hold for every seed count we ran.

# %%
for level in LEVELS:
    by_method = {label: sweep[level][("corridor-loop", label)]["marker_rmse_m"] for label in labels}
    assert by_method["slam"] < by_method["marker-graph"] < by_method["closed-form/signed"], (
        by_method
    )
for name in SCENARIOS:
    slam, isam2 = summary[(name, "slam")], summary[(name, "isam2")]
    assert abs(slam["marker_rmse_m"] - isam2["marker_rmse_m"]) < 1e-3
    ratio = summary[(name, "closed-form/signed")]["marker_rmse_m"] / slam["marker_rmse_m"]
    print(f"{name}: the closed form's marker error is {ratio:.0f}x SLAM's")
closed = [
    sweep[level][("corridor-loop", "closed-form/signed")]["marker_rmse_m"] for level in LEVELS
]
slam = [sweep[level][("corridor-loop", "slam")]["marker_rmse_m"] for level in LEVELS]
print(
    "corridor loop, wheel error x0.5 -> x4: closed form "
    f"{closed[0]:.2f} -> {closed[-1]:.2f} m, SLAM {slam[0]:.3f} -> {slam[-1]:.3f} m"
)
