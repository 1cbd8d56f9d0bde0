"""What a user sees of `markergraph map`: the aligned marker RMSE leads the summary, the path is
written at the odometry's rate and follows the truth between detections, each trajectory file
names its frame, the last line points to the report, and the legend hides no marker."""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import gtsam
import numpy as np
import pytest

from markergraph.formats import MARKER_VERTEX_OFFSET, read_tum
from markergraph.frontend import extract
from markergraph.markermap import MapMarker, MarkerMap

pytestmark = pytest.mark.slow  # its tests share a fixture that renders or maps a whole log

RATE_TOLERANCE = 0.05  # the path's rate against the odometry's, relative
MAX_GAP_PERIODS = 2.0  # the longest step of the path, in odometry periods
PATH_TOLERANCE_M = 0.05  # the corrected path against the simulator's truth, everywhere
EXACT = 1e-9  # text round trips of the same pose (repr floats, quaternion to yaw)
PRINTED = 0.0005 + 1e-12  # a figure printed with three decimals


def _kabsch_2d(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rotation R and translation t minimising |R source + t - target| (no scale), by SVD;
    written here apart from the package's own alignment."""
    source_mean, target_mean = source.mean(axis=0), target.mean(axis=0)
    H = (source - source_mean).T @ (target - target_mean)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, d]) @ U.T
    return R, target_mean - R @ source_mean


def _aligned_rmse(source: np.ndarray, target: np.ndarray) -> tuple[float, np.ndarray]:
    """RMSE after the rigid fit of source onto target, and each point's error."""
    R, t = _kabsch_2d(source, target)
    errors = np.linalg.norm(source @ R.T + t - target, axis=1)
    return float(np.sqrt(np.mean(errors**2))), errors


@pytest.fixture(scope="module")
def mapped(log: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """`markergraph map` on the short simulated log: its folder and what it printed."""
    folder = tmp_path_factory.mktemp("seen")
    out = folder / "result"
    run = subprocess.run(
        [sys.executable, "-m", "markergraph.cli", "map", str(log), "--out", str(out)],
        capture_output=True, text=True,
        env={**os.environ, "MARKERGRAPH_CACHE": str(folder / "cache")},
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    return out, run.stdout


@pytest.fixture(scope="module")
def logged(log: Path):
    """The log as the front end reads it: the simulator's true markers and path (world
    frame), the detections' stamps."""
    return extract(log)


def test_path_is_at_the_odometry_rate_without_gaps(mapped) -> None:
    """trajectory.tum's rate equals the odometry's within 5 %, and no step of it is longer
    than two odometry periods."""
    folder, _ = mapped
    path, odometry = read_tum(folder / "trajectory.tum"), read_tum(folder / "odometry.tum")
    period_ns = float(np.median(np.diff(odometry.t_ns)))
    rate = (len(path) - 1) / ((path.t_ns[-1] - path.t_ns[0]) * 1e-9)
    assert abs(rate * period_ns * 1e-9 - 1.0) < RATE_TOLERANCE, rate
    assert np.diff(path.t_ns).max() <= MAX_GAP_PERIODS * period_ns
    report = json.loads((folder / "report.json").read_text())
    slam = report["methods"]["slam"]
    assert slam["trajectory_poses"] == len(path) > 4 * slam["optimised_poses"]


def test_path_follows_the_truth_between_detections(mapped, logged) -> None:
    """Every pose of trajectory.tum, those between detections included, lies within 5 cm of
    the simulator's true path (after the rigid fit evo makes); the report's aligned ATE is that
    fit's RMSE, over all of them."""
    folder, _ = mapped
    path = read_tum(folder / "trajectory.tum")
    truth = logged.true_path.at_stamps(path.t_ns)
    assert np.array_equal(truth.t_ns, path.t_ns)
    rmse_m, errors = _aligned_rmse(path.poses[:, :2], truth.poses[:, :2])
    assert errors.max() < PATH_TOLERANCE_M, errors.max()
    detected = np.unique([o.t_ns for o in logged.observations])
    nearest = np.abs(path.t_ns[:, None] - detected[None, :]).min(axis=1)
    between = nearest > 50_000_000  # over 50 ms from any detection
    assert between.sum() > len(path) // 2  # most of the path lies between detections
    report = json.loads((folder / "report.json").read_text())
    assert report["methods"]["slam"]["ate_poses"] == len(path)
    assert abs(report["methods"]["slam"]["ate_aligned_m"] - rmse_m) < 1e-9


def test_odometry_in_the_map_starts_at_the_first_optimised_pose(mapped) -> None:
    """odometry_map.tum's first pose is the graph's first robot pose (map.g2o), and then it
    keeps the odometry's stamps; odometry.tum stays in the odom frame as logged."""
    folder, _ = mapped
    _, initial = gtsam.readG2o(str(folder / "map.g2o"))
    keys = list(initial.keys())  # gtsam.Values does not iterate
    first_key = min(k for k in keys if k < MARKER_VERTEX_OFFSET)
    first = initial.atPose2(first_key)
    placed, odometry = read_tum(folder / "odometry_map.tum"), read_tum(folder / "odometry.tum")
    np.testing.assert_allclose(placed.poses[0], [first.x(), first.y(), first.theta()], atol=EXACT)
    assert np.array_equal(placed.t_ns[1:], odometry.t_ns[odometry.t_ns > placed.t_ns[0]])
    path = read_tum(folder / "trajectory.tum")
    np.testing.assert_allclose(path.poses[0], placed.poses[0], atol=EXACT)


def test_each_trajectory_names_its_frame(mapped) -> None:
    """Each TUM file opens with one comment line naming its frame, as report.json's
    file_frames does; evo's reader skips it."""
    folder, _ = mapped
    report = json.loads((folder / "report.json").read_text())
    expected = {"trajectory.tum": "map", "odometry_map.tum": "map", "odometry.tum": "odom",
                "ground_truth.tum": "map"}  # fmt: skip
    assert {k: v["frame"] for k, v in report["file_frames"].items()} == expected
    assert isinstance(report["frames"], int)  # the old key keeps its meaning
    for name, frame in expected.items():
        lines = (folder / name).read_text().splitlines()
        assert lines[0].startswith(f"# {name}: frame {frame};"), lines[0]
        assert not any(line.startswith("#") for line in lines[1:])
    file_interface = pytest.importorskip("evo.tools.file_interface")
    evo_path = file_interface.read_tum_trajectory_file(str(folder / "trajectory.tum"))
    assert evo_path.num_poses == len(read_tum(folder / "trajectory.tum"))


def test_summary_leads_with_the_aligned_rmse(mapped, logged) -> None:
    """The summary's first error column is the aligned marker RMSE, equal to a Kabsch fit of
    map.json onto the simulator's markers; the home-fixed one follows, both in metres."""
    folder, stdout = mapped
    lines = stdout.splitlines()
    header = next(line for line in lines if line.startswith("method"))
    assert header.index("aligned RMSE [m]") < header.index("home-fixed RMSE [m]")
    row = next(line for line in lines if line.startswith("slam "))
    figures = row.split()[3:]
    document = json.loads((folder / "map.json").read_text())
    markers = {m["id"]: m for m in document["markers"]}
    ids = sorted(set(markers) & set(logged.true_markers))
    estimated = np.array([[markers[i]["x"], markers[i]["y"]] for i in ids])
    true = np.array([[logged.true_markers[i].x(), logged.true_markers[i].y()] for i in ids])
    aligned_m, _ = _aligned_rmse(estimated, true)
    assert abs(float(figures[0]) - aligned_m) < PRINTED, (figures, aligned_m)
    report = json.loads((folder / "report.json").read_text())
    assert abs(report["methods"]["slam"]["marker_rmse_aligned_m"] - aligned_m) < 1e-6
    assert abs(float(figures[1]) - report["methods"]["slam"]["marker_rmse_m"]) < PRINTED


def test_last_line_points_to_the_report_page(mapped) -> None:
    """The last line of `map` says which page to open, and that page exists."""
    folder, stdout = mapped
    last = stdout.splitlines()[-1]
    assert last == f"open {folder / 'report.html'}"
    assert (folder / "report.html").is_file()


def _narrow_map() -> tuple[MarkerMap, dict[int, gtsam.Pose2]]:
    """A corridor 24 m long and 0.6 m wide: markers on both walls, and their truth 2 cm off."""
    rng = np.random.default_rng(29)
    markers, truth = {}, {}
    for i in range(12):
        x, y = 2.0 * i, 0.3 if i % 2 else -0.3
        yaw = -math.pi / 2 if i % 2 else math.pi / 2
        markers[i] = MapMarker(i, gtsam.Pose2(x, y, yaw), 1e-4 * np.eye(3), 10, 0.2)
        dx, dy = rng.normal(0.0, 0.02, 2)
        truth[i] = gtsam.Pose2(x + dx, y + dy, yaw)
    marker_map = MarkerMap(markers, (), 0, "DICT_4X4_50", 0.2, "slam", "corridor.mcap")
    return marker_map, truth


def test_legend_hides_no_marker() -> None:
    """In a narrow map the legend's box contains none of the markers drawn (estimated or
    true), in display coordinates."""
    from markergraph.plots import map_figure

    marker_map, truth = _narrow_map()
    t_ns = np.arange(0, 10_000_000_000, 20_000_000, dtype=np.int64)
    poses = np.column_stack([2.2 * t_ns * 1e-9, np.zeros(len(t_ns)), np.zeros(len(t_ns))])
    from markergraph.estimator import Trajectory

    path = Trajectory(t_ns, poses, "map")
    fig = map_figure(marker_map, truth, trajectory=path, truth_path=path, rmse_m=(0.05, 0.02))
    fig.canvas.draw()
    ax = fig.axes[0]
    box = ax.get_legend().get_window_extent(fig.canvas.get_renderer())
    xy = np.array([[T.x(), T.y()] for T in [*truth.values()]]
                  + [[m.T_map_marker.x(), m.T_map_marker.y()]
                     for m in marker_map.markers.values()])  # fmt: skip
    shown = ax.transData.transform(xy)
    inside = (
        (shown[:, 0] >= box.x0) & (shown[:, 0] <= box.x1)
        & (shown[:, 1] >= box.y0) & (shown[:, 1] <= box.y1)
    )  # fmt: skip
    assert not inside.any(), xy[inside]
    title = ax.get_title()
    assert "aligned" in title and "fitted onto the map" in title
    assert title.index("aligned") < title.index("home-fixed")


@pytest.mark.parametrize("fmt", ["csv", "aruco-yaml", "fiducial-slam", "tagslam"])
def test_exports_write_no_float_noise(fmt: str, tmp_path: Path) -> None:
    """A home marker left at -4.2e-21 m by the solver is exported as 0.0, in every format; a
    value above the noise floor keeps all its digits."""
    from markergraph.formats import ExportFormat, export_map

    marker_map, _ = _narrow_map()
    markers = dict(marker_map.markers)
    markers[0] = MapMarker(0, gtsam.Pose2(-4.2e-21, 3.1e-19, -2.1e-19), None, 10, 0.2)
    markers[1] = MapMarker(1, gtsam.Pose2(1.5e-3, 2.0, 0.5), None, 10, 0.2)
    noisy = MarkerMap(markers, (), 0, "DICT_4X4_50", 0.2, "slam", "corridor.mcap")
    out = tmp_path / "map.txt"
    export_map(noisy, ExportFormat(fmt), out)
    text = out.read_text()
    assert not re.search(r"e-(1[3-9]|[2-9]\d|\d{3})\b", text), text[:400]
    assert "0.0015" in text or fmt == "aruco-yaml"  # the corners move the centre away


def test_no_plots_skips_what_its_help_says(mapped, log: Path, tmp_path: Path) -> None:
    """--no-plots leaves out exactly the pictures its help names, and nothing else."""
    from markergraph.cli._map import NO_PLOTS_HELP

    folder, _ = mapped
    out = tmp_path / "bare"
    run = subprocess.run(
        [sys.executable, "-m", "markergraph.cli", "map", str(log), "--out", str(out),
         "--no-plots"],
        capture_output=True, text=True,
        env={**os.environ, "MARKERGRAPH_CACHE": str(tmp_path / "cache")},
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    with_plots = {p.name for p in folder.rglob("*") if p.is_file()}
    without = {p.name for p in out.rglob("*") if p.is_file()}
    skipped = with_plots - without
    assert without <= with_plots
    assert skipped == {"map.png", "map.svg", "diagnostics.png"}  # one method: no comparison
    named = set(re.findall(r"[\w-]+\.(?:png|svg)", NO_PLOTS_HELP))
    assert named == skipped | {"comparison.png"}


def test_corrected_odometry_is_exact_when_the_correction_is_constant() -> None:
    """Odometry that is the true path seen from a frame 3 m and 0.5 rad away, and optimised
    poses that are the truth at a few stamps: the corrected path is the truth at every
    odometry stamp between them (exact algebra), and odometry_in_map starts at the first."""
    from markergraph.estimator import Trajectory, corrected_odometry, odometry_in_map

    rng = np.random.default_rng(7)
    t_ns = np.arange(0, 5_000_000_000, 20_000_000, dtype=np.int64)
    steps = rng.normal([0.02, 0.0, 0.0], [0.005, 0.002, 0.02], (len(t_ns), 3))
    poses = [gtsam.Pose2()]
    for dx, dy, dyaw in steps[1:]:
        poses.append(poses[-1].compose(gtsam.Pose2(dx, dy, dyaw)))
    T_odom_map = gtsam.Pose2(3.0, -1.0, 0.5)
    truth = np.array([[p.x(), p.y(), p.theta()] for p in poses])
    odom = [T_odom_map.compose(p) for p in poses]
    odometry = Trajectory(t_ns, np.array([[p.x(), p.y(), p.theta()] for p in odom]), "odom")
    keys = np.sort(rng.choice(np.arange(10, len(t_ns) - 10), 6, replace=False))
    optimised = Trajectory(t_ns[keys], truth[keys], "map")
    path = corrected_odometry(optimised, odometry)
    span = (t_ns >= t_ns[keys[0]]) & (t_ns <= t_ns[keys[-1]])
    np.testing.assert_array_equal(path.t_ns, t_ns[span])
    np.testing.assert_allclose(path.poses, truth[span], atol=1e-12)
    placed = odometry_in_map(optimised, odometry)
    np.testing.assert_array_equal(placed.poses[0], truth[keys[0]])
    np.testing.assert_allclose(placed.poses, truth[t_ns >= t_ns[keys[0]]], atol=1e-12)
