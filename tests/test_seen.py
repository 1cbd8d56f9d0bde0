"""What a new user still found wanting (issue 29, second look): notes said once and in our words,
the odometry note's true count, the mount actually used, columns that mean something for each
method, one size unit, readable figures, clean labels and numbers, map.json without float noise,
README's API example showing the aligned error."""

from __future__ import annotations

import json
import re
from pathlib import Path

import gtsam
import numpy as np
import pytest

from markergraph.markermap import MapMarker, MarkerMap

NEGATIVE_ZERO = re.compile(r"(?<![\w.])-0(?:\.0+)?(?![\d.e])")
FLOAT_NOISE = re.compile(r"e-(1[3-9]|[2-9]\d|\d{3})\b")  # 1e-13 and smaller


def _noisy_map() -> MarkerMap:
    """A map whose home marker the solver left at float noise, with a covariance whose
    off-diagonal entries are noise against its 1e-8 prior."""
    prior = np.diag([1e-8, 1e-8, 1e-8])
    prior[0, 1] = prior[1, 0] = -1.6e-24
    prior[2, 1] = prior[1, 2] = -9.0e-23
    home = MapMarker(0, gtsam.Pose2(-9.44e-21, -1.8e-20, -2.07e-19), prior, 45, 0.2, z_m=1.0)
    other = MapMarker(1, gtsam.Pose2(4.05, -5.95, 1.59), np.diag([2.7e-3, 5.8e-3, 3.6e-4]), 22, 0.2)
    return MarkerMap({0: home, 1: other}, (), 0, "DICT_4X4_50", 0.2, "slam", "corridor.mcap")


def test_map_json_rounds_float_noise(tmp_path: Path) -> None:
    """map.json writes the home marker's -9.44e-21 m and its covariance's -1.6e-24 as 0.0, and
    keeps every figure above the noise (the prior's 1e-8, the other marker's pose) exactly."""
    path = tmp_path / "map.json"
    _noisy_map().save(path)
    text = path.read_text()
    assert not FLOAT_NOISE.search(text), text[:600]
    document = json.loads(text)
    home, other = document["markers"]
    assert (home["x"], home["y"], home["yaw"]) == (0.0, 0.0, 0.0)
    assert home["covariance"] == [[1e-8, 0.0, 0.0], [0.0, 1e-8, 0.0], [0.0, 0.0, 1e-8]]
    assert (other["x"], other["y"], other["yaw"]) == (4.05, -5.95, 1.59)
    loaded = MarkerMap.load(path)
    assert loaded.markers[0].T_map_marker.x() == 0.0


@pytest.mark.parametrize(
    ("value", "spec", "text"),
    [(-0.0004, ".1f", "0.0"), (-0.0, ">8.3f", "   0.000"), (-0.04, ".1f", "0.0"),
     (-0.4, ".1f", "-0.4"), (-0.00002, "+.1f", "+0.0"), (-0.0, ".4g", "0"), (2.5, ".2f", "2.50")],
)  # fmt: skip
def test_shown_has_no_negative_zero(value: float, spec: str, text: str) -> None:
    """A figure that rounds to zero is printed without its sign, in the field's width; a sign
    that carries a figure stays."""
    from markergraph.common.numbers import shown

    assert shown(value, spec) == text


def test_report_page_labels_and_zero() -> None:
    """report.html says "xy variance per metre travelled [m²/m]" and "marker size used [m]",
    never "per [m]" or "size m used", and a camera delay of -0.0001 ms as 0."""
    from markergraph.report_page import render_report_page

    report = {
        "schema": "markergraph.report/1",
        "camera_delay_ms": -0.0001,
        "inputs": {
            "marker_size_m_used": 0.2,
            "odometry_evidence": {"samples": 600, "rate_hz": 50.0, "xy_variance_per_m": 2.5e-5},
        },
    }
    page = render_report_page(report, {})
    text = re.sub(r"<[^>]+>", " ", page)
    assert "per [m]" not in text and "size m used" not in text
    assert "xy variance per metre travelled [m²/m]" in text and "2.5e-05" in text
    assert "marker size used [m]" in text and "rate [Hz]" in text
    assert not NEGATIVE_ZERO.search(text), re.findall(r".{30}-0.{10}", text)
