"""What `localize` and `heading` show: localize's map.png (moved markers as arrows) and
report.html, listed in report.json; its printout says what the sigma and the ATE are; heading's
1-sigma matches a Monte Carlo of the map's covariances, and it says it is a straight line."""

from __future__ import annotations

import dataclasses
import math
import re
import subprocess
import sys
from pathlib import Path

import gtsam
import numpy as np
import pytest

from markergraph.estimator.paper import Form
from markergraph.heading_sigma import heading_sigma
from markergraph.markermap import MapMarker, MarkerMap

MC_SAMPLES = 2000
MC_TOLERANCE = 0.15  # a 2000-sample std is within ~3 % (1 sigma); 15 % leaves room for linearity
MOVED_ID, MOVED_BY_M = 3, 0.3


def run_cli(*arguments: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "markergraph.cli", *arguments],
        capture_output=True, text=True, check=False,
    )  # fmt: skip


def _covariance(rng: np.random.Generator, sigma_m: float, sigma_rad: float) -> np.ndarray:
    """A random full 3x3 covariance with about the given position and yaw sigmas."""
    A = rng.normal(size=(3, 3)) * np.array([sigma_m, sigma_m, sigma_rad])[:, None]
    return A @ A.T / 3 + np.diag([sigma_m, sigma_m, sigma_rad]) ** 2 * 0.1


def _two_marker_map(rng: np.random.Generator) -> MarkerMap:
    T_a = gtsam.Pose2(0.3, -0.2, 0.1)
    T_c = gtsam.Pose2(3.0, 2.5, -2.0)
    markers = {
        i: MapMarker(i, T, _covariance(rng, s, r), 10, 0.2)
        for i, T, s, r in ((0, T_a, 0.02, 0.01), (5, T_c, 0.05, 0.03))
    }
    return MarkerMap(markers, (), 0, "DICT_4X4_50", 0.2, "slam", "sim.mcap")


def test_heading_sigma_matches_a_monte_carlo_of_the_maps_covariances() -> None:
    """The propagated 1-sigma of distance and turn is within 15 % of the spread of the closed
    form over 2000 seeded draws of both markers from their covariances."""
    rng = np.random.default_rng(29)
    marker_map = _two_marker_map(rng)
    d, theta = 1.2, math.radians(20.0)
    sigma = heading_sigma(marker_map, 0, d, theta, 5)
    a, c = marker_map.markers[0], marker_map.markers[5]
    draws_a = rng.multivariate_normal(np.zeros(3), a.covariance, MC_SAMPLES)
    draws_c = rng.multivariate_normal(np.zeros(3), c.covariance, MC_SAMPLES)
    samples = []
    for xa, xc in zip(draws_a, draws_c, strict=True):
        moved = dataclasses.replace(
            marker_map,
            markers={
                0: dataclasses.replace(a, T_map_marker=a.T_map_marker.retract(xa)),
                5: dataclasses.replace(c, T_map_marker=c.T_map_marker.retract(xc)),
            },
        )
        samples.append(moved.heading(0, d, theta, 5, Form.EXACT))
    distances, turns = np.array(samples).T
    turn0 = marker_map.heading(0, d, theta, 5)[1]
    turn_spread = np.std([math.remainder(t - turn0, math.tau) for t in turns])
    assert sigma.distance_m == pytest.approx(np.std(distances), rel=MC_TOLERANCE)
    assert sigma.turn_rad == pytest.approx(turn_spread, rel=MC_TOLERANCE)
    assert sigma.distance_m > 0.01 and sigma.turn_rad > 0.005  # not a trivially small match


def test_heading_prints_its_sigma_and_says_it_is_a_straight_line(tmp_path: Path) -> None:
    """`markergraph heading` prints the sigmas heading_sigma gives and the straight-line note."""
    marker_map = _two_marker_map(np.random.default_rng(3))
    marker_map.save(tmp_path / "map.json")
    saved = MarkerMap.load(tmp_path / "map.json")
    run = run_cli("heading", str(tmp_path / "map.json"), "--from", "0", "--at", "1.2,20",
                  "--to", "5")  # fmt: skip
    assert run.returncode == 0, run.stderr
    turn_sigma, distance_sigma = map(
        float, re.findall(r"deg \+- ([\d.]+) .* m \+- ([\d.]+) to", run.stdout)[0]
    )
    sigma = heading_sigma(saved, 0, 1.2, math.radians(20.0), 5)
    assert turn_sigma == pytest.approx(math.degrees(sigma.turn_rad), abs=0.06)
    assert distance_sigma == pytest.approx(sigma.distance_m, abs=6e-4)
    assert "straight line" in run.stdout and "obstacles" in run.stdout
