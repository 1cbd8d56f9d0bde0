"""Each marker's height, from a rendered log of markers hung at different heights, reaches
map.json and every export within 5 cm of the simulator's truth."""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from markergraph.datasets import scenario, write_log
from markergraph.estimator import MarkerHeight, Observation, marker_heights

pytestmark = pytest.mark.slow  # its tests share a fixture that renders or maps a whole log

HEIGHTS_M = (0.85, 1.2, 1.0, 0.9, 1.15, 1.05)


def test_heights_are_a_robust_median_with_its_standard_error() -> None:
    """Exact algebra: the median ignores one wild height; its sigma is the median's standard
    error from the MAD, and a marker seen with no height is left out."""

    def seen(marker_id: int, height: float) -> Observation:
        return Observation(0, marker_id, 0.0, 0.0, 2.0, 1e-3, 1e-2, 1e-2, height_m=height)

    rng = np.random.default_rng(7)
    heights = 1.1 + 0.02 * rng.standard_normal(401)
    heights[0] = 5.0  # a depth that hit something else
    observations = [seen(4, float(h)) for h in heights] + [seen(9, math.nan)]
    result = marker_heights(observations)
    assert set(result) == {4}
    z, sigma, n = result[4]
    assert n == 401 and z == pytest.approx(float(np.median(heights)))
    assert abs(z - 1.1) < 3 * sigma
    assert sigma == pytest.approx(math.sqrt(math.pi / 2) * 0.02 / math.sqrt(401), rel=0.15)
    # One observation: a centimetre, not zero.
    assert marker_heights([seen(1, 0.7)])[1] == MarkerHeight(0.7, math.sqrt(math.pi / 2) * 0.01, 1)


@pytest.fixture(scope="module")
def mapped(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[int, float]]:
    """The paper room with its markers hung at different heights, mapped by the CLI."""
    world, route = scenario("paper-room")
    markers = tuple(
        dataclasses.replace(m, height_m=HEIGHTS_M[i % len(HEIGHTS_M)])
        for i, m in enumerate(world.markers)
    )
    world = dataclasses.replace(world, markers=markers)
    folder = tmp_path_factory.mktemp("heights")
    log = folder / "room.mcap"
    write_log(world, route, log, seed=3, duration_s=30.0, compressed=True, frame_hz=5.0)
    out = folder / "result"
    run = subprocess.run(
        [sys.executable, "-m", "markergraph.cli", "map", str(log), "--out", str(out)],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    return out, {m.id: m.height_m for m in markers}


def test_map_json_carries_each_markers_height_and_its_sigma(mapped) -> None:
    out, truth = mapped
    markers = json.loads((out / "map.json").read_text())["markers"]
    assert len(markers) >= 2
    for m in markers:
        assert abs(m["z"] - truth[m["id"]]) < 0.05, m
        assert 0 < m["sigma_z"] < 0.05


def test_every_export_carries_the_heights(mapped, tmp_path: Path) -> None:
    out, truth = mapped

    def export(fmt: str) -> str:
        run = subprocess.run(
            [sys.executable, "-m", "markergraph.cli", "export", str(out / "map.json"),
             "--format", fmt, "--out", str(tmp_path / f"map.{fmt}")],
            capture_output=True, text=True, check=False,
        )  # fmt: skip
        assert run.returncode == 0, run.stderr
        return (tmp_path / f"map.{fmt}").read_text()

    heights: dict[str, dict[int, float]] = {}
    heights["csv"] = {
        int(r["id"]): float(r["z_m"]) for r in csv.DictReader(export("csv").splitlines())
    }
    heights["fiducial-slam"] = {
        int(f[0]): float(f[3])
        for f in (line.split() for line in export("fiducial-slam").splitlines())
    }
    tags = yaml.safe_load(export("tagslam"))["bodies"][0]["map"]["tags"]
    heights["tagslam"] = {t["id"]: t["pose"]["position"]["z"] for t in tags}
    aruco = export("aruco-yaml")
    assert 'aruco_bc_dict: "4X4_50"' in aruco  # the ArUco library's own name, a string
    storage = cv2.FileStorage(str(tmp_path / "map.aruco-yaml"), cv2.FILE_STORAGE_READ)
    assert storage.getNode("aruco_bc_dict").string() == "4X4_50"
    node = storage.getNode("aruco_bc_markers")
    heights["aruco-yaml"] = {}
    for i in range(node.size()):
        corners = node.at(i).getNode("corners")
        z = np.mean([corners.at(j).at(2).real() for j in range(corners.size())])
        heights["aruco-yaml"][int(node.at(i).getNode("id").real())] = float(z)
    storage.release()
    for fmt, found in heights.items():
        assert found, fmt
        for marker_id, z in found.items():
            assert abs(z - truth[marker_id]) < 0.05, (fmt, marker_id, z)
