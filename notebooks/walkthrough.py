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
# # Walkthrough: from a robot's log to a marker map
#
# You have a wheeled robot with an RGB-D camera (a RealSense D435i, say), ArUco markers on the
# walls, and a ROS 2 bag recorded as MCAP. This notebook goes the way you would: look at the
# log, look at a few raw frames and what the front end makes of them, map the markers, read the
# result, and export it for other tools. Every step is one command (shown) or a few lines of
# Python.
#
# We have no robot in CI, so the log is simulated: the paper's own room (three markers, one of
# them a charging station), recorded as realsense-ros 4.x would publish it, with JPEG colour,
# aligned 16-bit depth, `/odom`, `/tf_static` and, because it is simulated, the ground truth.
# Everything is written to a temporary folder (the log alone is 150 MB) that the last cell
# deletes; run the same commands in a folder of your own to keep the results.

# %%
import json
import os
import shlex
import subprocess
import tempfile
from pathlib import Path

import cv2
import matplotlib.pyplot as plt
import numpy as np

from markergraph.notebook_figures import NotebookFigures

# each figure is also saved as PNG: in $MARKERGRAPH_FIGURES, or notebooks/figures/ from a script
figures = NotebookFigures.of("walkthrough")  # before the chdir below


def sh(command: str) -> None:
    """Run a shell command as you would in a terminal and print what it says."""
    print(f"$ {command}")
    done = subprocess.run(shlex.split(command), capture_output=True, text=True)
    print(done.stdout + done.stderr, end="")
    assert done.returncode == 0, f"exit code {done.returncode}"


workdir = tempfile.TemporaryDirectory(prefix="markergraph-walkthrough-")
os.chdir(workdir.name)
sh(
    "markergraph simulate --scenario paper-room --compressed --frame-rate 5 --out robot.mcap --force"
)

# %% [markdown]
# ## 1. What is in the log?
#
# `markergraph info` lists the topics and which ones the mapper would read. Topics are found
# by name (realsense-ros's, then older names) and by type; `--color-topic` and friends, or a
# settings file, override the choice.

# %%
sh("markergraph info robot.mcap")

# %% [markdown]
# ## 2. Raw frames, and what the front end sees in them
#
# The same calls the mapper makes, on three frames: decode colour and depth, detect the markers
# (sub-pixel corners), and turn each into an observation: the marker's yaw **theta** (from the
# corners), its horizontal **range** (from aligned depth, corrected for the camera's height and
# pitch), and its **bearing** in the image.

# %%
from markergraph.frontend import (
    decode_depth,
    decode_image,
    mount_from_transforms,
    open_log,
    transforms_of,
)
from markergraph.frontend.camera import Camera
from markergraph.frontend.detect import Detector
from markergraph.frontend.observe import ObservationModel, observe_detections
from markergraph.frontend.sizes import MarkerSizes

COLOR = "/camera/camera/color/image_raw/compressed"
DEPTH = "/camera/camera/aligned_depth_to_color/image_raw"
INFO = "/camera/camera/color/camera_info"
log = open_log(Path("robot.mcap"))
camera = Camera.from_camera_info(next(iter(log.messages([INFO]))).decoded)
static = [t for m in log.messages(["/tf_static"]) for t in transforms_of(m.decoded)]
mount = mount_from_transforms(static, "base_link", "camera_color_optical_frame")
print(camera)
print(mount)

colour, depth = {}, {}
for message in log.messages([COLOR, DEPTH]):
    stamp = message.decoded.header.stamp.sec * 10**9 + message.decoded.header.stamp.nanosec
    if message.topic == COLOR:
        colour[stamp] = message
    else:
        depth[stamp] = message
detector = Detector("DICT_4X4_50")
shown, seen_ids = [], set()  # the first frame where each marker appears
for stamp in sorted(set(colour) & set(depth)):
    image = decode_image(colour[stamp])
    detections = detector.detect(image)
    new = {d.marker_id for d in detections} - seen_ids
    if new and all(abs(d.corners[:, 0].mean() - camera.cx) < 120 for d in detections):
        shown.append((stamp, image, decode_depth(depth[stamp]), detections))
        seen_ids |= new
    if len(shown) == 3:
        break

fig, axes = plt.subplots(2, 3, figsize=(15, 7.5))
for (stamp, image, depth_image, detections), top, bottom in zip(shown, *axes, strict=True):
    drawn = cv2.cvtColor(image, cv2.COLOR_GRAY2RGB)  # the front end works on grey
    cv2.aruco.drawDetectedMarkers(
        drawn, [d.corners.reshape(1, 4, 2).astype(np.float32) for d in detections],
        np.array([d.marker_id for d in detections]),
    )  # fmt: skip
    top.imshow(drawn)
    for obs in observe_detections(
        detections, camera, ObservationModel(MarkerSizes(0.2)), depth=depth_image, mount=mount
    ):
        u, v = np.asarray(obs.corners).mean(axis=0)
        top.annotate(
            f"id {obs.marker_id}\nθ {np.degrees(obs.theta):.1f}°\nd {obs.range_m:.2f} m",
            (u, v + 60), color="yellow", fontsize=9, ha="center", va="top",
        )  # fmt: skip
    top.set_title(f"{(stamp - min(colour)) / 1e9:.1f} s into the log")
    depth_shown = bottom.imshow(
        np.where(depth_image > 0, depth_image / 1000.0, np.nan), cmap="viridis", vmin=0, vmax=6
    )
    bottom.set_title("aligned depth (white: no depth)")
for ax in axes.flat:
    ax.axis("off")
# One bar for the depth row (the panels share the 0-6 m scale), taken from all six axes so the
# two rows keep the same width; anchored low and half high, it stands beside the depth row.
fig.colorbar(depth_shown, ax=list(axes.flat), label="aligned depth [m]", shrink=0.45,
             anchor=(0.0, 0.0), pad=0.01)  # fmt: skip
figures.show(fig, "frames-and-detections")

# %% [markdown]
# ## 3. Map it
#
# One command reads the whole log (colour paired with depth by stamp, odometry interpolated at
# each frame), estimates the map, and writes a result folder. `--method all` runs every
# estimator on the same observations: the paper's closed form, its node graph optimised, batch
# SLAM, iSAM2 and an EKF. Settings can also come from a file (`--config robot.toml`;
# `markergraph map --print-config` writes one to start from).

# %%
sh("markergraph map robot.mcap --method all --out robot-map --force")

# %% [markdown]
# The table compares each method against the log's ground truth: marker RMSE in the home
# marker's frame, the same after a rigid alignment (the map's shape alone), and the
# trajectory's ATE. On a log without ground truth the table has the counts only.
#
# In the home marker's frame, every marker inherits the error of the home marker's own
# estimated yaw: a tenth of a degree over four metres is a few millimetres, a degree five
# centimetres. The aligned column shows the map's shape.
#
# ## 4. The result folder
#
# Open `report.html` in a browser for all of it on one page: the table above, the figures
# below, the notes and every setting used (it works offline: nothing in it is fetched).

# %%
folder = Path("robot-map")
for path in sorted(folder.rglob("*")):
    if path.is_file() and path.parent == folder:
        print(f"{path.name:<18} {path.stat().st_size:>9,} bytes")

for name, size in (("map.png", (10, 5)), ("comparison.png", (16, 4))):
    fig, ax = plt.subplots(figsize=size)
    ax.imshow(plt.imread(folder / name))
    ax.axis("off")
    figures.show(fig, f"result-{name.removesuffix('.png')}")

# %% [markdown]
# `map.json` is the corrected marker graph (schema `markergraph.map/1`, documented in the
# README): each marker's pose in the home marker's frame with its 3x3 covariance, and each link
# with the paper's edge values E_ab = (phi, theta_ab, theta_ba, d).

# %%
document = json.loads((folder / "map.json").read_text())
print(f"method {document['method']}, frame: {document['frame']}")
for marker in document["markers"]:
    sigma = np.sqrt(np.diag(marker["covariance"]))
    print(
        f"marker {marker['id']}: x {marker['x']:6.3f}  y {marker['y']:6.3f} m  yaw {np.degrees(marker['yaw']):7.2f}°"
        f"   1-sigma {100 * sigma[0]:.1f} / {100 * sigma[1]:.1f} cm, {np.degrees(sigma[2]):.2f}°"
        f"   ({marker['n_observations']} observations)"
    )
for link in document["links"]:
    print(
        f"edge {link['a']} -> {link['b']}: phi {np.degrees(link['phi']):7.2f}°  theta_ab {np.degrees(link['theta_ab']):7.2f}°"
        f"  theta_ba {np.degrees(link['theta_ba']):7.2f}°  d {link['d']:.3f} m"
    )

# %% [markdown]
# ## 5. Use the map elsewhere
#
# `markergraph export` writes it for the tools people already use: ArUco's MarkerMap YAML,
# UbiquityRobotics fiducial_slam's `map.txt`, a TagSLAM body, or CSV. `overlay.mcap` holds the
# map as `visualization_msgs/MarkerArray`, the path and `/tf` map to odom: open it in Foxglove
# or Lichtblick next to `robot.mcap`. The trajectories are TUM files for evo.

# %%
sh("markergraph export robot-map/map.json --format fiducial-slam --out map.txt --force")
print(Path("map.txt").read_text())
sh("markergraph export robot-map/map.json --format csv --out markers.csv --force")
print(Path("markers.csv").read_text())

# %% [markdown]
# And the paper's navigation: localised 1.5 m from marker 0 at theta = 20 degrees, which way
# to turn and how far to drive to reach marker 2, through the optimised map. The paper's printed
# formula is shown beside it.

# %%
sh("markergraph heading robot-map/map.json --from 0 --at 1.5,20 --to 2")

# %% [markdown]
# ## The checks this walkthrough rests on

# %%
report = json.loads((folder / "report.json").read_text())
methods = report["methods"]
assert report["ground_truth"] and len(document["markers"]) == 3
assert "report.html" in report["files"] and (folder / "report.html").is_file()
assert methods["slam"]["marker_rmse_aligned_m"] < 0.02
assert methods["slam"]["ate_m"] < methods["closed-form"]["ate_m"]
print({name: round(figures["marker_rmse_m"], 3) for name, figures in methods.items()})
os.chdir(Path.home())  # leave the folder before deleting it
workdir.cleanup()
