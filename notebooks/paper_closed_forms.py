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
# # Where the paper's closed forms hold, and where they break
#
# The paper gives four closed forms: the odometry composition **alpha**, the marker edge
# **E_ab** built from odometry and an observation, the edge composition **M**, and the target
# **heading**. `markergraph.estimator.paper` evaluates each three ways:
#
# * `Form.PAPER`: the equations exactly as printed (unsigned `arccos` terms),
# * `Form.SIGNED`: the same closed forms with the signs resolved,
# * `Form.EXACT`: SE(2) composition with `gtsam.Pose2`, the reference.
#
# Each map below puts a robot at every point of a room and colours it by how far the printed
# formula lands from the exact one. White means the printed formula holds there.
# Conventions: top view, angles counter-clockwise, a marker's +x is its normal into the room.

# %%
import itertools
import math

import gtsam
import matplotlib.pyplot as plt
import numpy as np

from markergraph.datasets.rooms import observe_marker, turn_toward
from markergraph.estimator import (
    Form,
    Goal,
    PolarPose,
    angle_diff,
    compose,
    edge_from_observation,
    edge_from_pose2,
    heading,
    odometry,
)
from markergraph.notebook_figures import NotebookFigures

# each figure is also saved as PNG: in $MARKERGRAPH_FIGURES, or notebooks/figures/ from a script
figures = NotebookFigures.of("paper_closed_forms")

WIDTH_M, HEIGHT_M = 6.0, 4.0
# Three markers on three consecutive walls, clockwise: the layout of the paper's figures.
T_room_a = gtsam.Pose2(0.0, 1.5, 0.0)  # left wall, facing +x
T_room_b = gtsam.Pose2(2.5, HEIGHT_M, -math.pi / 2)  # top wall, facing -y
T_room_c = gtsam.Pose2(WIDTH_M, 2.6, math.pi)  # right wall, facing -x
xs = np.linspace(0.15, WIDTH_M - 0.15, 120)
ys = np.linspace(0.15, HEIGHT_M - 0.15, 80)


def draw_room(ax, title):
    ax.plot([0, WIDTH_M, WIDTH_M, 0, 0], [0, 0, HEIGHT_M, HEIGHT_M, 0], "k-", lw=1)
    for name, T in (("a", T_room_a), ("b", T_room_b), ("c", T_room_c)):
        ax.arrow(
            T.x(),
            T.y(),
            0.4 * math.cos(T.theta()),
            0.4 * math.sin(T.theta()),
            width=0.03,
            color="k",
        )
        ax.annotate(name, (T.x(), T.y()), textcoords="offset points", xytext=(6, 6))
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=9)


def error_map(error_deg_at, title, ax):
    grid = np.array([[error_deg_at(np.array([x, y])) for x in xs] for y in ys])
    image = ax.pcolormesh(xs, ys, grid, cmap="Reds", vmin=0, vmax=180, shading="auto")
    draw_room(ax, title)
    return image, grid


# %% [markdown]
# ## E_ab: linking marker a to marker b
#
# The robot stands somewhere, knows its odometry `(d_a, theta_a)` about a, turns `theta_delta`
# from facing away from a until b is centred, and measures `(d_delta, theta_b)`.
# The printed `theta_ab` uses an unsigned `arccos`, so it is right only on one side of the line
# through a and b. The printed `theta_ba = theta_b + arccos(...)` needs `theta_b` measured
# clockwise while the paper's own sign rule gives it counter-clockwise, so `theta_ba` and `phi_ab`
# are right only where `theta_b = 0`: on b's normal.


# %%
def observation_inputs(p_robot):
    obs_a, obs_b = observe_marker(T_room_a, p_robot), observe_marker(T_room_b, p_robot)
    theta_delta = turn_toward(T_room_a.theta() + obs_a.theta, p_robot, T_room_b.translation())
    return obs_a.d, obs_a.theta, theta_delta, obs_b.d, obs_b.theta


true_ab = edge_from_pose2(T_room_a.between(T_room_b))


def printed_edge_error(field):
    def error_deg(p_robot):
        printed = edge_from_observation(*observation_inputs(p_robot), form=Form.PAPER)
        return abs(math.degrees(angle_diff(getattr(printed, field), getattr(true_ab, field))))

    return error_deg


fig, axes = plt.subplots(1, 3, figsize=(13, 3.4), constrained_layout=True)
for ax, field in zip(axes, ("theta_ab", "theta_ba", "phi"), strict=True):
    image, grid = error_map(
        printed_edge_error(field), f"printed E_ab: |error of {field}| [deg]", ax
    )
    print(f"{field:>8}: printed value right at {np.mean(grid < 1e-4):.0%} of robot positions")
fig.colorbar(image, ax=axes, shrink=0.8)
figures.show(fig, "edge-error-maps")

# %% [markdown]
# The signed form is exact at every position (largest error over the grid):

# %%
worst = {form: 0.0 for form in (Form.SIGNED, Form.EXACT)}
for y in ys[::4]:
    for x in xs[::4]:
        for form in worst:
            edge = edge_from_observation(*observation_inputs(np.array([x, y])), form=form)
            errors = [
                abs(angle_diff(getattr(edge, f), getattr(true_ab, f)))
                for f in ("phi", "theta_ab", "theta_ba")
            ]
            worst[form] = max(worst[form], *errors, abs(edge.d - true_ab.d))
for form, error in worst.items():
    print(f"{form.name:>6}: worst error {error:.1e} (rad or m)")

# %% [markdown]
# ## M: composing E_ab and E_bc into E_ac
#
# `phi_ac` and `d_ac` are exact. The printed `theta_ac = theta_ab - arccos(...)` is right when
# c lies clockwise of b seen from a; the printed `theta_ca = pi - phi_ac + theta_ac` breaks the
# edge constraint by `2 theta_ac`, so it is right only when a and c squarely face each other.
# Here a and b stay put and c goes once around the room, counter-clockwise from the bottom-left
# corner.

# %%
positions = np.linspace(0.005, 0.995, 400)


PERIMETER_M = 2 * (WIDTH_M + HEIGHT_M)
CORNERS = [(0.0, 0.0), (WIDTH_M, 0.0), (WIDTH_M, HEIGHT_M), (0.0, HEIGHT_M), (0.0, 0.0)]


def marker_on_perimeter(s):
    """c at fraction s of the way around the walls, facing into the room."""
    along = s * PERIMETER_M
    for start, end in itertools.pairwise(CORNERS):
        length = math.dist(start, end)
        if along <= length:
            t = along / length
            wall_yaw = math.atan2(end[1] - start[1], end[0] - start[0])
            return gtsam.Pose2(
                start[0] + t * (end[0] - start[0]),
                start[1] + t * (end[1] - start[1]),
                wall_yaw + math.pi / 2,
            )
        along -= length
    raise ValueError(s)


rows = []
for s in positions:
    T_room_c_s = marker_on_perimeter(s)
    e_bc = edge_from_pose2(T_room_b.between(T_room_c_s))
    truth = edge_from_pose2(T_room_a.between(T_room_c_s))
    printed = compose(true_ab, e_bc, Form.PAPER)
    signed = compose(true_ab, e_bc, Form.SIGNED)
    rows.append(
        [
            abs(math.degrees(angle_diff(printed.theta_ab, truth.theta_ab))),
            abs(math.degrees(angle_diff(printed.theta_ba, truth.theta_ba))),
            abs(math.degrees(angle_diff(signed.theta_ab, truth.theta_ab))),
        ]
    )
rows = np.array(rows)
fig, ax = plt.subplots(figsize=(8, 3.2), constrained_layout=True)
ax.plot(positions, rows[:, 0], label="printed theta_ac")
ax.plot(positions, rows[:, 1], label="printed theta_ca")
ax.plot(positions, rows[:, 2], "k--", label="signed theta_ac")
for corner in np.cumsum([WIDTH_M, HEIGHT_M, WIDTH_M]) / PERIMETER_M:
    ax.axvline(corner, color="grey", lw=0.8)
ax.set_xlabel("c's position around the walls: bottom, right, top, left (fraction of perimeter)")
ax.set_ylabel("|error| [deg]")
ax.set_title("M(E_ab, E_bc) against the true E_ac")
ax.legend()
figures.show(fig, "composition-error")

# %% [markdown]
# ## The target heading
#
# Localised on a, the robot turns toward c by `theta_heading`. The printed `arccos` gives the
# size of the turn but never its direction: wherever the robot must turn clockwise, it turns the
# wrong way.

# %%
true_ac = edge_from_pose2(T_room_a.between(T_room_c))


def printed_heading_error_deg(p_robot):
    obs_a = observe_marker(T_room_a, p_robot)
    printed = heading(true_ac, obs_a.d, obs_a.theta, Form.PAPER)
    exact = heading(true_ac, obs_a.d, obs_a.theta, Form.EXACT)
    return abs(math.degrees(angle_diff(printed[1], exact[1])))


fig, ax = plt.subplots(figsize=(6, 3.6), constrained_layout=True)
image, grid = error_map(printed_heading_error_deg, "printed heading: |turn error| [deg]", ax)
fig.colorbar(image, ax=ax)
figures.show(fig, "heading-error-map")
print(f"printed heading right at {np.mean(grid < 1e-4):.0%} of robot positions")

# %% [markdown]
# ## alpha: chaining odometry
#
# The printed alpha returns the angle at the origin between two positions, not the new polar
# angle, and assumes the robot faced straight away from the origin before the goal. Chained over
# a route it drifts from the true position; the signed form with the heading offset as a third
# state stays exact.

# %%
rng = np.random.default_rng(7)
goals = [Goal(float(rng.uniform(0.5, 2.0)), float(rng.uniform(-1.5, 1.5))) for _ in range(12)]
states = {form: [PolarPose(0.0, 0.0)] for form in Form}
for goal in goals:
    for form, chain in states.items():
        chain.append(odometry(chain[-1], goal, form))

fig, ax = plt.subplots(figsize=(6, 5), constrained_layout=True)
for form, style in ((Form.EXACT, "k-o"), (Form.SIGNED, "g--x"), (Form.PAPER, "r-s")):
    xy = np.array([[s.d * math.cos(s.theta), s.d * math.sin(s.theta)] for s in states[form]])
    ax.plot(xy[:, 0], xy[:, 1], style, label=form.name, ms=4)
ax.set_aspect("equal")
ax.set_title("odometry chained with alpha over 12 goals")
ax.legend()
figures.show(fig, "alpha-chain")
end = {form: chain[-1] for form, chain in states.items()}
for form in (Form.PAPER, Form.SIGNED):
    gap = math.dist(
        (end[form].d * math.cos(end[form].theta), end[form].d * math.sin(end[form].theta)),
        (
            end[Form.EXACT].d * math.cos(end[Form.EXACT].theta),
            end[Form.EXACT].d * math.sin(end[Form.EXACT].theta),
        ),
    )
    print(f"{form.name:>6}: final position {gap:.3g} m from the exact one")

# %% [markdown]
# ## In short
#
# | formula | printed form holds when | fix (`Form.SIGNED`) |
# |---|---|---|
# | alpha | `theta_{i-1} = 0`, robot facing away from the origin, CCW turn | add `theta_{i-1}`, sign by `sin(turn)`, carry the heading offset |
# | E_ab `theta_ab` | b counter-clockwise of the robot's heading | `theta_a + sgn(sin theta_delta) arccos(..)` |
# | E_ab `theta_ba`, `phi_ab` | robot on b's normal (`theta_b = 0`) | `sgn(sin theta_delta) arccos(..) - theta_b` |
# | M `theta_ac` | `sin(theta_ba + theta_bc) >= 0` (three consecutive walls, clockwise) | `theta_ab - sgn(sin(theta_ba + theta_bc)) arccos(..)` |
# | M `theta_ca` | a and c squarely facing (`theta_ac = 0`) | `pi - phi_ac - theta_ac` |
# | heading | the turn from a to c is counter-clockwise | `-sgn(sin(theta_ac - theta_ra)) arccos(..)` |
#
# `tests/test_paper.py` pins each row down, including the rates at which the printed forms fail
# in random convex rooms.
