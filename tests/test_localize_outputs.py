"""What `localize` and `heading` show: localize's map.png (moved markers as arrows) and
report.html, listed in report.json; its printout says what the sigma and the ATE are; heading's
1-sigma matches a Monte Carlo of the map's covariances, and it says it is a straight line."""

from __future__ import annotations

import base64
import dataclasses
import json
import math
import re
import shutil
import struct
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

import gtsam
import numpy as np
import pytest

from markergraph.estimator.metrics import align_rigid_2d
from markergraph.estimator.paper import Form
from markergraph.heading_sigma import heading_sigma
from markergraph.markermap import MapMarker, MarkerMap

pytestmark = pytest.mark.slow  # its tests share a fixture that renders or maps a whole log

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
        float, re.findall(r"1 sigma: turn \+- ([\d.]+) deg, drive \+- ([\d.]+) m", run.stdout)[0]
    )
    sigma = heading_sigma(saved, 0, 1.2, math.radians(20.0), 5)
    assert turn_sigma == pytest.approx(math.degrees(sigma.turn_rad), abs=0.06)
    assert distance_sigma == pytest.approx(sigma.distance_m, abs=6e-4)
    assert "straight line" in run.stdout and "obstacles" in run.stdout


# --- localize's folder: a map of one office log, a second log with marker 3 moved 0.3 m -------

CHROMIUM = shutil.which("chromium")
MIN_FIGURE_PX, MAX_FIGURE_PX = 300, 4000  # an 8x6 in figure at matplotlib's 100 dpi, cropped
MIN_FIGURE_BYTES = 5_000  # a map with axes and labels is tens of kB
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
MOVED_TOLERANCE_M = 0.05  # as tests/test_sessions.py: the moved marker's place from one log


class Tags(HTMLParser):
    """Every start tag with its attributes, and the page's text."""

    def __init__(self) -> None:
        super().__init__()
        self.tags: list[tuple[str, dict[str, str]]] = []
        self.text: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags.append((tag, {k: v or "" for k, v in attrs}))

    def handle_data(self, data: str) -> None:
        self.text.append(data)


def _moved_world():
    from markergraph.datasets import scenario

    world, route = scenario("office")
    markers = list(world.markers)
    index = next(i for i, m in enumerate(markers) if m.id == MOVED_ID)
    markers[index] = dataclasses.replace(
        markers[index], position_m=markers[index].position_m + MOVED_BY_M
    )
    return world, dataclasses.replace(world, markers=tuple(markers)), route


@pytest.fixture(scope="module")
def localized(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """`map` on 60 s of the office at 5 Hz (seed 1), then `localize` on 60 s of the same office
    with marker 3 moved 0.3 m along its wall (seed 2): about 100 s. The folder and stdout."""
    from markergraph.datasets import write_log

    folder = tmp_path_factory.mktemp("localize")
    world, moved, route = _moved_world()
    for name, each, seed in (("a", world, 1), ("b", moved, 2)):
        write_log(each, route, folder / f"{name}.mcap", seed=seed, duration_s=60.0,
                  compressed=True, frame_hz=5.0)  # fmt: skip
    mapped = run_cli("map", str(folder / "a.mcap"), "--out", str(folder / "map"), "--no-plots")
    assert mapped.returncode == 0, mapped.stderr
    located = run_cli("localize", str(folder / "b.mcap"), "--map", str(folder / "map" / "map.json"),
                      "--out", str(folder / "loc"))  # fmt: skip
    assert located.returncode == 0, located.stderr
    return folder, located.stdout


def test_localize_writes_a_real_map_png_and_lists_it(localized: tuple[Path, str]) -> None:
    """map.png and report.html are written, listed in report.json's files, and map.png is a
    PNG of a sensible size."""
    folder, _ = localized
    loc = folder / "loc"
    report = json.loads((loc / "report.json").read_text())
    on_disk = sorted(str(p.relative_to(loc)) for p in loc.rglob("*") if p.is_file())
    assert report["files"] == on_disk
    assert {"map.png", "report.html", "report.json", "localization.json"} <= set(on_disk)
    data = (loc / "map.png").read_bytes()
    assert data.startswith(PNG_SIGNATURE) and len(data) > MIN_FIGURE_BYTES
    width, height = struct.unpack(">II", data[16:24])  # IHDR, right after the signature
    assert MIN_FIGURE_PX <= width <= MAX_FIGURE_PX and MIN_FIGURE_PX <= height <= MAX_FIGURE_PX


def test_localize_report_page_parses_shows_the_figure_and_lists_the_files(
    localized: tuple[Path, str],
) -> None:
    """report.html parses, inlines map.png byte for byte, names every file, fetches nothing."""
    folder, _ = localized
    loc = folder / "loc"
    page = Tags()
    page.feed((loc / "report.html").read_text(encoding="utf-8"))
    images = [attrs for tag, attrs in page.tags if tag == "img"]
    assert [attrs["alt"] for attrs in images] == ["map.png"]
    prefix = "data:image/png;base64,"
    assert images[0]["src"].startswith(prefix)
    assert base64.b64decode(images[0]["src"][len(prefix) :]) == (loc / "map.png").read_bytes()
    text = " ".join(page.text)
    assert "markergraph localize" in text
    for name in json.loads((loc / "report.json").read_text())["files"]:
        assert name in text, name
    for _, attrs in page.tags:
        for key in ("src", "href"):
            assert not attrs.get(key, "").startswith(("http:", "https:", "//", "file:"))
    assert not [tag for tag, _ in page.tags if tag in ("script", "link", "iframe")]


@pytest.mark.skipif(CHROMIUM is None, reason="needs a headless browser: apt-get install chromium")
def test_localize_report_page_opens_offline_in_a_browser(
    localized: tuple[Path, str], tmp_path: Path
) -> None:
    """A headless chromium builds the page with the figure and logs no console message."""
    assert CHROMIUM is not None
    page = (localized[0] / "loc" / "report.html").as_uri()
    run = subprocess.run(
        [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
         "--disable-background-networking", "--enable-logging=stderr", "--v=0",
         f"--user-data-dir={tmp_path}", "--dump-dom", page],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert 'alt="map.png"' in run.stdout
    assert not [line for line in run.stderr.splitlines() if ":CONSOLE" in line]


def test_the_moved_marker_is_in_the_report_from_its_old_to_its_new_place(
    localized: tuple[Path, str],
) -> None:
    """report.json's moved_markers holds marker 3 alone, from the map's place (map.json) to
    within 5 cm of its true new place, about 0.3 m on."""
    folder, _ = localized
    report = json.loads((folder / "loc" / "report.json").read_text())
    (entry,) = report["moved_markers"]
    assert entry["id"] == MOVED_ID
    assert entry["displacement_m"] == pytest.approx(MOVED_BY_M, abs=MOVED_TOLERANCE_M)
    saved = {m["id"]: m for m in json.loads((folder / "map" / "map.json").read_text())["markers"]}
    assert entry["before_x_m"] == pytest.approx(saved[MOVED_ID]["x"], abs=1e-9)
    assert entry["before_y_m"] == pytest.approx(saved[MOVED_ID]["y"], abs=1e-9)
    world, moved, _ = _moved_world()
    home = world.T_map_markers()[0].inverse()  # the map's frame is marker 0's
    true_now = home.compose(moved.T_map_markers()[MOVED_ID])
    assert math.hypot(entry["now_x_m"] - true_now.x(), entry["now_y_m"] - true_now.y()) < (
        MOVED_TOLERANCE_M
    )
    # localization.json gives its new place's covariance, given the map: against the truth
    # carried onto the map's other markers (the map's own error taken out), within its 99.9 %.
    (moved_entry,) = json.loads((folder / "loc" / "localization.json").read_text())["moved"]
    now = moved_entry["now"]
    others = sorted(set(saved) - {MOVED_ID})
    truth = {i: home.compose(world.T_map_markers()[i]) for i in others}
    fit = align_rigid_2d(np.array([[truth[i].x(), truth[i].y()] for i in others]),
                         np.array([[saved[i]["x"], saved[i]["y"]] for i in others]))  # fmt: skip
    error = gtsam.Pose2(now["x"], now["y"], now["yaw"]).localCoordinates(fit.compose(true_now))
    covariance = np.array(moved_entry["now_covariance"])
    assert float(error @ np.linalg.solve(covariance, error)) < 16.27


def test_localize_says_what_its_sigma_and_its_ate_are(localized: tuple[Path, str]) -> None:
    """stdout names the sigma as the localisation's own uncertainty given the map and each ATE
    (home-fixed, then aligned) a line of its own with its alignment, then what both are; the
    figures are report.json's."""
    folder, stdout = localized
    accuracy = json.loads((folder / "loc" / "report.json").read_text())["accuracy"]
    sigma_line = next(line for line in stdout.splitlines() if "position sigma" in line)
    ate_line, aligned_line = (line for line in stdout.splitlines() if line.startswith("ATE"))
    means_line = next(line for line in stdout.splitlines() if line.startswith("each ATE is"))
    assert "uncertainty given the map" in sigma_line
    assert f"{100 * accuracy['median_position_sigma_m']:.1f} cm" in sigma_line
    assert "no alignment" in ate_line and "home marker's true pose" in ate_line
    assert f"ATE {100 * accuracy['ate_m']:.1f} cm" in ate_line
    assert f"ATE {100 * accuracy['ate_aligned_m']:.1f} cm after a rigid 2-D" in aligned_line
    assert "ground truth" in means_line and "map's own error" in means_line
    assert accuracy["ate_m"] < 3 * accuracy["rms_position_sigma_m"] or "note" in stdout


def test_moved_markers_are_drawn_as_one_arrow_each_from_old_to_new() -> None:
    """draw_localization adds one arrow per moved marker (and none otherwise), from the map's
    place to the new one, and a legend entry for them."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from markergraph.datasets import simulate_fast
    from markergraph.estimator import build_frames
    from markergraph.estimator.localization import localize
    from markergraph.estimator.sessions import MapPrior, solve_sessions
    from markergraph.plots_localize import MOVED_ARROW_GID, draw_localization

    world, moved, route = _moved_world()
    runs = [simulate_fast(w, route, seed=s, duration_s=120.0) for w, s in ((world, 1), (moved, 4))]
    frames = [build_frames(r.observations, r.odometry, h, odometry_noise=r.odometry_noise)
              for r, h in zip(runs, (0, None), strict=True)]  # fmt: skip
    merged = solve_sessions([frames[0]], [runs[0].mount.T_base_camera])
    priors = {i: MapPrior(m.T_map_marker, m.relative_covariance) for i, m in merged.markers.items()}
    localization = localize(frames[1], runs[1].mount.T_base_camera, priors)
    marker_map = _map_of(merged)
    fig, ax = plt.subplots()
    arrows = draw_localization(ax, marker_map, localization)
    drawn = [p for p in ax.patches if (p.get_gid() or "").startswith(MOVED_ARROW_GID)]
    assert [m.marker_id for m in localization.moved] == [MOVED_ID]
    assert drawn == arrows and len(drawn) == 1
    (m,) = localization.moved
    start, end = drawn[0]._posA_posB  # the arrow's two ends as given
    np.testing.assert_allclose(start, [m.T_map_before.x(), m.T_map_before.y()], atol=1e-12)
    np.testing.assert_allclose(end, [m.T_map_now.x(), m.T_map_now.y()], atol=1e-12)
    assert "moved marker: map -> now" in [t.get_text() for t in ax.get_legend().get_texts()]
    plt.close(fig)


def _map_of(merged) -> MarkerMap:
    """A 2-D MarkerMap of a sessions estimate's markers (no links: the figure needs none)."""
    markers = {
        i: MapMarker(
            i, m.T_map_marker, m.covariance, 1, 0.2, relative_covariance=m.relative_covariance
        )
        for i, m in sorted(merged.markers.items())
    }
    return MarkerMap(markers, (), 0, "DICT_4X4_50", 0.2, "slam", "a.mcap")


def test_an_ate_far_beyond_the_sigmas_gets_a_note_and_one_within_does_not() -> None:
    """ate_note fires above 3x the RMS sigma (naming the ratio and the map's own error), not at
    or below it, and not without truth."""
    from markergraph.localize_accuracy import TOO_FAR_RATIO, LocalizeAccuracy, ate_note

    rms = 0.025
    far = ate_note(LocalizeAccuracy(0.02, rms, 0.199, 0.03))
    assert far is not None and far.kind == "localization.ate_beyond_sigma"
    assert far.figure == pytest.approx(0.199 / rms)
    assert "8.0x the RMS position sigma 2.5 cm" in far.text
    assert "map's own error" in far.text and "wrong map" in far.text
    assert ate_note(LocalizeAccuracy(0.02, rms, TOO_FAR_RATIO * rms, None)) is None
    assert ate_note(LocalizeAccuracy(0.02, rms, 0.05, 0.01)) is None
    assert ate_note(LocalizeAccuracy(0.02, rms, None, None)) is None
