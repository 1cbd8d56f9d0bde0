"""Result files read back: map.json's schema, TUM through a reader, g2o through gtsam.readG2o."""

from __future__ import annotations

import csv
import json
import math
import re
import subprocess
import sys
from pathlib import Path

import cv2
import gtsam
import numpy as np
import pytest
import yaml

from markergraph.datasets import scenario, simulate_fast
from markergraph.estimator import Edge, MarkerHeight, Method, build_frames, estimate_frames
from markergraph.formats import (
    MARKER_VERTEX_OFFSET,
    ExportFormat,
    read_tum,
    write_g2o,
    write_tum,
)
from markergraph.frontend import MarkerSizes
from markergraph.markermap import MAP_SCHEMA, MarkerMap


@pytest.fixture(scope="module")
def solved():
    world, route = scenario("corridor-loop")
    run = simulate_fast(world, route, seed=2, duration_s=240.0)
    frames = build_frames(run.observations, run.odometry, 0, odometry_noise=run.odometry_noise)
    return run, frames, estimate_frames(frames, Method.SLAM, run.mount.T_base_camera)


@pytest.fixture(scope="module")
def map_json(solved, tmp_path_factory: pytest.TempPathFactory) -> Path:
    _, _, result = solved
    path = tmp_path_factory.mktemp("export") / "map.json"
    MarkerMap.from_estimate(
        result,
        log="sim.mcap",
        dictionary="DICT_4X4_50",
        marker_sizes=MarkerSizes(0.2, {3: 0.1}),  # one smaller marker
        heights={0: MarkerHeight(1.0, 0.01, 5)},
    ).save(path)
    return path


def test_map_json_holds_the_map_and_the_papers_edges(solved, map_json: Path) -> None:
    """map.json has the schema, every marker with a covariance, and links whose edge values
    rebuild the relative pose of the two markers."""
    _, _, result = solved
    document = json.loads(map_json.read_text())
    assert document["schema"] == MAP_SCHEMA and document["units"]["angle"] == "rad"
    assert {m["id"] for m in document["markers"]} == set(result.markers)
    home = next(m for m in document["markers"] if m["id"] == 0)
    assert home["z"] == 1.0 and abs(home["x"]) < 1e-9
    assert all(np.array(m["covariance"]).shape == (3, 3) for m in document["markers"])
    markers = {m["id"]: gtsam.Pose2(m["x"], m["y"], m["yaw"]) for m in document["markers"]}
    assert document["links"]
    for link in document["links"]:
        rebuilt = gtsam.Pose2(
            link["d"] * math.cos(link["theta_ab"]),
            link["d"] * math.sin(link["theta_ab"]),
            -link["phi"],
        )
        assert rebuilt.equals(markers[link["a"]].between(markers[link["b"]]), 1e-9)
        edge = Edge(link["phi"], link["theta_ab"], link["theta_ba"], link["d"])
        assert abs(edge.constraint_error()) < 1e-9


def test_tum_round_trip(solved, tmp_path: Path) -> None:
    """A TUM trajectory reads back to the same stamps (ns) and poses."""
    _, _, result = solved
    path = tmp_path / "estimate.tum"
    write_tum(path, result.trajectory)
    read = read_tum(path)
    np.testing.assert_array_equal(read.t_ns, result.trajectory.t_ns)
    np.testing.assert_allclose(read.poses, result.trajectory.poses, atol=1e-12)


def test_g2o_loads_in_gtsam_and_reoptimises_to_the_same_map(solved, tmp_path: Path) -> None:
    """gtsam.readG2o loads map.g2o (markers at offset ids, full precision) and, with the home
    vertex fixed, re-optimises to the same markers within 5 mm: g2o's relative-pose
    edges are our polar observations linearised at the measurement."""
    _, frames, result = solved
    graph, values = result.pose_graph()
    path = tmp_path / "map.g2o"
    write_g2o(path, graph, values)
    loaded, initial = gtsam.readG2o(str(path), False)
    observations = sum(len(f.observations) for f in frames.frames)
    assert loaded.size() == graph.size() == len(frames.frames) - 1 + observations
    assert initial.size() == len(result.trajectory) + len(result.markers)
    home = MARKER_VERTEX_OFFSET + result.home_id
    loaded.add(
        gtsam.PriorFactorPose2(
            home, gtsam.Pose2(), gtsam.noiseModel.Diagonal.Sigmas(np.full(3, 1e-4))
        )
    )
    optimised = gtsam.LevenbergMarquardtOptimizer(loaded, initial).optimize()
    for marker_id, marker in result.markers.items():
        loaded_pose = optimised.atPose2(MARKER_VERTEX_OFFSET + marker_id)
        assert np.hypot(*(loaded_pose.translation() - marker.T_map_marker.translation())) < 5e-3
        assert abs(loaded_pose.theta() - marker.T_map_marker.theta()) < 2e-3
    # The base poses, not the camera's: the vertices are the trajectory the estimate reports.
    first = initial.atPose2(0)
    np.testing.assert_allclose([first.x(), first.y(), first.theta()], result.trajectory.poses[0])


def run_cli(*arguments: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "markergraph.cli", *arguments], capture_output=True, text=True
    )


@pytest.mark.slow
def test_every_export_format_parses_back_to_the_map(map_json: Path, tmp_path: Path) -> None:
    """CSV, ArUco's MarkerMap YAML (OpenCV FileStorage), fiducial_slam map.txt and TagSLAM YAML
    carry each marker's position and the direction of its normal."""
    document = json.loads(map_json.read_text())
    markers = {m["id"]: m for m in document["markers"]}
    paths = {}
    for fmt in ExportFormat:
        paths[fmt] = tmp_path / f"map.{fmt.value}"
        run = run_cli("export", str(map_json), "--format", fmt.value, "--out", str(paths[fmt]))
        assert run.returncode == 0, run.stderr

    def normal_of(marker_id: int) -> np.ndarray:
        yaw = markers[marker_id]["yaw"]
        return np.array([math.cos(yaw), math.sin(yaw), 0.0])

    def map_sigmas(marker_id: int) -> np.ndarray:
        """x and y sigmas along the map's axes: map.json's covariance is in the marker's
        frame, turned by its yaw."""
        yaw, covariance = markers[marker_id]["yaw"], np.array(markers[marker_id]["covariance"])
        R = np.array([[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]])
        return np.sqrt(np.diag(R @ covariance[:2, :2] @ R.T))

    # The corridor's markers face along both axes: the sigmas are tested both ways round.
    assert {round(abs(math.sin(m["yaw"]))) for m in markers.values()} == {0, 1}
    rows = list(csv.DictReader(paths[ExportFormat.CSV].read_text().splitlines()))
    assert {int(r["id"]) for r in rows} == set(markers)
    for row in rows:
        # Exact but for float noise under 1e-12 m (the home marker's), written as 0.0.
        assert float(row["x_m"]) == pytest.approx(markers[int(row["id"])]["x"], rel=0, abs=1e-12)
        sigmas = [float(row["sigma_x_m"]), float(row["sigma_y_m"])]
        np.testing.assert_allclose(sigmas, map_sigmas(int(row["id"])), rtol=1e-9, atol=1e-12)

    storage = cv2.FileStorage(str(paths[ExportFormat.ARUCO_YAML]), cv2.FILE_STORAGE_READ)
    node = storage.getNode("aruco_bc_markers")
    assert int(storage.getNode("aruco_bc_nmarkers").real()) == node.size() == len(markers)
    for i in range(node.size()):
        marker_id = int(node.at(i).getNode("id").real())
        listed = node.at(i).getNode("corners")  # a list of [x, y, z] lists, as ArUco writes
        corners = np.array(
            [[listed.at(j).at(k).real() for k in range(3)] for j in range(listed.size())]
        )
        centre = corners.mean(axis=0)
        assert centre[:2] == pytest.approx([markers[marker_id]["x"], markers[marker_id]["y"]])
        # TL -> TR runs to the viewer's right, TL -> BL down; their cross product is the normal.
        across, down = corners[1] - corners[0], corners[3] - corners[0]
        assert np.linalg.norm(across) == pytest.approx(0.1 if marker_id == 3 else 0.2)
        normal = np.cross(down, across)
        np.testing.assert_allclose(normal / np.linalg.norm(normal), normal_of(marker_id), atol=1e-9)
    storage.release()

    for line in paths[ExportFormat.FIDUCIAL_SLAM].read_text().splitlines():
        fields = line.split()
        assert len(fields) == 9
        marker_id = int(fields[0])
        roll, pitch, yaw = (math.radians(float(v)) for v in fields[4:7])
        R = gtsam.Rot3.RzRyRx(roll, pitch, yaw).matrix()  # fiducial z = out of the marker
        np.testing.assert_allclose(R[:, 2], normal_of(marker_id), atol=1e-9)
        assert int(fields[8]) == markers[marker_id]["n_observations"]

    body = yaml.safe_load(paths[ExportFormat.TAGSLAM].read_text())["bodies"][0]["map"]
    assert len(body["tags"]) == len(markers)
    for tag in body["tags"]:
        rotation = tag["pose"]["rotation"]
        R = gtsam.Rot3.Expmap(np.array([rotation["x"], rotation["y"], rotation["z"]])).matrix()
        np.testing.assert_allclose(R[:, 2], normal_of(tag["id"]), atol=1e-9)
        assert tag["size"] == markers[tag["id"]]["size_m"] == (0.1 if tag["id"] == 3 else 0.2)
        noise = tag["pose"]["position_noise"]
        np.testing.assert_allclose([noise["x"], noise["y"]], map_sigmas(tag["id"]), rtol=1e-9)


def test_heading_command_matches_geometry(map_json: Path) -> None:
    """`markergraph heading` gives the turn and distance plain geometry gives from the map."""
    document = json.loads(map_json.read_text())
    markers = {m["id"]: m for m in document["markers"]}
    d, theta_deg, target = 1.5, 25.0, 6
    run = run_cli(
        "heading", str(map_json), "--from", "0", "--at", f"{d},{theta_deg}", "--to", str(target)
    )
    assert run.returncode == 0, run.stderr
    turn_deg, distance = map(
        float, re.findall(r"turn ([\d.]+) deg .* drive ([\d.]+) m", run.stdout.splitlines()[0])[0]
    )
    robot = d * np.array([math.cos(math.radians(theta_deg)), math.sin(math.radians(theta_deg))])
    goal = np.array([markers[target]["x"], markers[target]["y"]])
    to_home, to_goal = -robot, goal - robot
    expected_turn = math.degrees(
        abs(math.atan2(to_home[0] * to_goal[1] - to_home[1] * to_goal[0], to_home @ to_goal))
    )
    assert distance == pytest.approx(np.linalg.norm(to_goal), abs=1e-3)
    assert turn_deg == pytest.approx(expected_turn, abs=0.1)
    unknown = run_cli("heading", str(map_json), "--from", "0", "--at", "1,0", "--to", "99")
    assert unknown.returncode == 1 and "no marker 99" in unknown.stderr
