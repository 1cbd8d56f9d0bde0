"""Result files read back: map.json's schema, TUM through a reader, g2o through gtsam.readG2o."""

from __future__ import annotations

import json
import math
from pathlib import Path

import gtsam
import numpy as np
import pytest

from markergraph.datasets import scenario, simulate_fast
from markergraph.estimator import Edge, Method, build_frames, estimate_frames
from markergraph.estimator.export import (
    MAP_SCHEMA,
    MARKER_VERTEX_OFFSET,
    estimate_values,
    map_document,
    read_tum,
    write_g2o,
    write_json,
    write_tum,
)
from markergraph.estimator.slam import build_slam_graph


@pytest.fixture(scope="module")
def solved():
    world, route = scenario("corridor-loop")
    run = simulate_fast(world, route, seed=2, duration_s=240.0)
    frames = build_frames(run.observations, run.odometry, 0, odometry_noise=run.odometry_noise)
    return run, frames, estimate_frames(frames, Method.SLAM, run.mount.T_base_camera)


def test_map_json_holds_the_map_and_the_papers_edges(solved, tmp_path: Path) -> None:
    """map.json has the schema, every marker with a covariance, and links whose edge values
    rebuild the relative pose of the two markers."""
    _, _, result = solved
    path = tmp_path / "map.json"
    write_json(
        path,
        map_document(
            result,
            log="sim.mcap",
            dictionary="DICT_4X4_50",
            marker_length_m=0.2,
            marker_heights_m={0: 1.0},
        ),
    )
    document = json.loads(path.read_text())
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
    write_tum(path, result.trajectory_t_ns, result.trajectory)
    stamps, poses = read_tum(path)
    np.testing.assert_array_equal(stamps, result.trajectory_t_ns)
    np.testing.assert_allclose(poses, result.trajectory, atol=1e-12)


def test_g2o_loads_in_gtsam_and_reoptimises_to_the_same_map(solved, tmp_path: Path) -> None:
    """gtsam.readG2o loads map.g2o (markers at offset ids, full precision) and, with the home
    vertex fixed, re-optimises to the same markers."""
    run, frames, result = solved
    graph, _, _ = build_slam_graph(frames, run.mount.T_base_camera)
    path = tmp_path / "map.g2o"
    write_g2o(path, graph, estimate_values(result))
    loaded, initial = gtsam.readG2o(str(path), False)
    assert loaded.size() == graph.size() - 1  # all but the home prior
    assert initial.size() == len(result.trajectory) + len(result.markers)
    home = MARKER_VERTEX_OFFSET + result.home_id
    loaded.add(
        gtsam.PriorFactorPose2(
            home, gtsam.Pose2(), gtsam.noiseModel.Diagonal.Sigmas(np.full(3, 1e-4))
        )
    )
    optimised = gtsam.LevenbergMarquardtOptimizer(loaded, initial).optimize()
    for marker_id, marker in result.markers.items():
        assert optimised.atPose2(MARKER_VERTEX_OFFSET + marker_id).equals(marker.T_map_marker, 1e-6)
