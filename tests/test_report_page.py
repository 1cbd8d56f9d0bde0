"""report.html: a real `markergraph map` opened in a real headless browser (Debian's chromium)
shows report.json's figures, inlines every image, fetches nothing and renders; the page itself
escapes what it shows and picks up report keys and figures it does not know."""

from __future__ import annotations

import base64
import json
import shutil
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from markergraph.datasets.scenarios import scenario
from markergraph.datasets.write import write_log
from markergraph.report_page import REPORT_PAGE, render_report_page

pytestmark = pytest.mark.slow  # its tests share a fixture that renders or maps a whole log

CHROMIUM = shutil.which("chromium")
needs_chromium = pytest.mark.skipif(
    CHROMIUM is None, reason="needs a headless browser: apt-get install chromium"
)
BROWSER_FLAGS = (
    "--headless",
    "--no-sandbox",  # CI runs as root, where chromium's sandbox refuses to start
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--enable-logging=stderr",  # console messages (script errors, CSP refusals) to stderr
    "--v=0",
)
MIN_FIGURE_BYTES = 5_000  # a matplotlib map with axes and labels is tens of kB
MIN_SCREEN_STD = 20.0  # grey levels: a blank or single-colour page is near 0
METHODS = ("slam", "closed-form", "marker-graph", "isam2", "ekf")


class Elements(HTMLParser):
    """Every start tag with its attributes, and the text inside each ``<td>``."""

    def __init__(self) -> None:
        super().__init__()
        self.tags: list[tuple[str, dict[str, str]]] = []
        self.cells: list[tuple[dict[str, str], str]] = []  # (attributes, text) per <td>
        self.rows: list[list[str]] = []  # the text of each cell of each table row
        self._cell: dict[str, str] | None = None
        self._text: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        attributes = {k: v or "" for k, v in attrs}
        self.tags.append((tag, attributes))
        if tag == "tr":
            self.rows.append([])
        if tag in ("td", "th"):
            self._cell, self._text = attributes, []

    def handle_endtag(self, tag: str) -> None:
        if tag in ("td", "th") and self._cell is not None:
            text = "".join(self._text).strip()
            if tag == "td":
                self.cells.append((self._cell, text))
            if self.rows:
                self.rows[-1].append(text)
            self._cell = None

    def handle_data(self, data: str) -> None:
        if self._cell is not None:
            self._text.append(data)


def parse(text: str) -> Elements:
    elements = Elements()
    elements.feed(text)
    return elements


def browse(page: Path, profile: Path, *flags: str) -> subprocess.CompletedProcess[str]:
    """Chromium headless on ``page`` with a profile of its own."""
    assert CHROMIUM is not None
    return subprocess.run(
        [CHROMIUM, *BROWSER_FLAGS, f"--user-data-dir={profile}", *flags, page.as_uri()],
        capture_output=True,
        text=True,
        timeout=120,
    )


def console_lines(stderr: str) -> list[str]:
    """What the page said on the console: script errors and refused loads alike."""
    return [line for line in stderr.splitlines() if ":CONSOLE" in line or "Uncaught" in line]


@pytest.fixture(scope="module")
def result(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """`markergraph map --method all` on 20 s of the paper room at 5 Hz (three markers, ground
    truth): a few seconds."""
    folder = tmp_path_factory.mktemp("report")
    world, route = scenario("paper-room")
    write_log(world, route, folder / "room.mcap", seed=3, duration_s=20.0, compressed=True,
              frame_hz=5.0)  # fmt: skip
    run = subprocess.run(
        [sys.executable, "-m", "markergraph.cli", "map", str(folder / "room.mcap"),
         "--method", "all", "--out", str(folder / "result")],
        capture_output=True, text=True,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    return folder / "result"


@pytest.fixture(scope="module")
def dom(result: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[str, str]:
    """The page's DOM as the browser built it, and what the browser said on stderr."""
    run = browse(result / REPORT_PAGE, tmp_path_factory.mktemp("profile"), "--dump-dom")
    assert run.returncode == 0, run.stderr
    assert "<html" in run.stdout
    return run.stdout, run.stderr


@pytest.fixture(scope="module")
def screenshot(result: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("screenshot")
    png = folder / "page.png"
    run = browse(
        result / REPORT_PAGE, folder / "profile", f"--screenshot={png}", "--window-size=1200,2000"
    )
    assert run.returncode == 0 and png.is_file(), run.stderr
    return png


@needs_chromium
def test_summary_table_shows_report_json_figures(result: Path, dom: tuple[str, str]) -> None:
    """Each method's row carries report.json's exact marker RMSE, ATE and RPE and shows them
    rounded to the millimetre."""
    report = json.loads((result / "report.json").read_text())
    elements = parse(dom[0])
    rows = {row[0]: row for row in elements.rows if row and row[0] in METHODS}
    assert set(rows) == set(METHODS)
    shown = {
        (attrs["data-key"], float(attrs["data-value"])): text
        for attrs, text in elements.cells
        if "data-key" in attrs and attrs["data-value"] not in ("null", "true", "false")
    }
    for method in METHODS:
        figures = report["methods"][method]
        for key in ("marker_rmse_m", "marker_rmse_aligned_m", "ate_m"):
            value = figures[key]
            assert shown[(key, value)] == f"{value:.3f}", (method, key)
            assert f"{value:.3f}" in rows[method]
        assert str(figures["markers_placed"]) in rows[method]
    for note in report["notes"]:
        assert note in dom[0].replace("&amp;", "&").replace("&gt;", ">").replace("&lt;", "<")


@needs_chromium
def test_every_image_is_inline_png(result: Path, dom: tuple[str, str]) -> None:
    """Every <img> is a data: URI decoding to a PNG of its stated size; the map and the
    comparison are both there."""
    images = [attrs for tag, attrs in parse(dom[0]).tags if tag == "img"]
    assert {attrs["alt"] for attrs in images} >= {"map.png", "comparison.png"}
    for attrs in images:
        prefix = "data:image/png;base64,"
        assert attrs["src"].startswith(prefix), attrs["src"][:40]
        data = base64.b64decode(attrs["src"][len(prefix) :], validate=True)
        assert len(data) > MIN_FIGURE_BYTES
        assert data == (result / attrs["alt"]).read_bytes()
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        assert image is not None
        assert (image.shape[1], image.shape[0]) == (int(attrs["width"]), int(attrs["height"]))


@needs_chromium
def test_nothing_is_fetched_and_no_script_runs(result: Path, dom: tuple[str, str]) -> None:
    """No src or href leaves the page, no script, stylesheet link or font; a CSP forbids any
    load; the browser logged no console message (no script error, no refused load)."""
    for text in ((result / REPORT_PAGE).read_text(), dom[0]):
        elements = parse(text)
        for _, attrs in elements.tags:
            for name in ("src", "href", "srcset", "action", "poster", "data"):
                value = attrs.get(name, "").strip().lower()
                assert not value.startswith(("http:", "https:", "//", "file:", "ftp:")), value
        assert not [tag for tag, _ in elements.tags if tag in ("script", "link", "iframe")]
        assert "@import" not in text and "url(" not in text and "@font-face" not in text
        csp = [a for t, a in elements.tags if t == "meta" and a.get("http-equiv")]
        assert csp and "default-src 'none'" in csp[0]["content"]
    assert console_lines(dom[1]) == []


@needs_chromium
def test_page_renders_something_a_person_reads(screenshot: Path) -> None:
    """The screenshot is neither blank nor one colour."""
    image = cv2.imread(str(screenshot), cv2.IMREAD_GRAYSCALE)
    assert image is not None and image.shape == (2000, 1200)
    assert float(image.std()) > MIN_SCREEN_STD
    assert 0.01 < float((image < 128).mean()) < 0.5  # text and figures on a light page


def test_page_is_listed_so_force_may_replace_the_folder(result: Path, tmp_path: Path) -> None:
    """report.json lists report.html with every other file, so --force replaces the folder; a
    run without plots writes a page with no figure."""
    report = json.loads((result / "report.json").read_text())
    on_disk = sorted(str(p.relative_to(result)) for p in result.rglob("*") if p.is_file())
    assert REPORT_PAGE in report["files"] and sorted(report["files"]) == on_disk
    copy = tmp_path / "copy"
    shutil.copytree(result, copy)
    run = subprocess.run(
        [sys.executable, "-m", "markergraph.cli", "map", str(result.parent / "room.mcap"),
         "--out", str(copy), "--force", "--no-plots"],
        capture_output=True, text=True,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    page = (copy / REPORT_PAGE).read_text()
    assert "<img" not in page and 'data-key="marker_rmse_m"' in page


def test_every_string_is_escaped() -> None:
    """Notes, keys, settings and method names with markup come out as text, never as tags."""
    evil = '<script>alert("x")</script>'
    report: dict[str, Any] = {
        "log": f"{evil}.mcap",
        "notes": [evil],
        "settings": {evil: evil},
        "methods": {evil: {"marker_rmse_m": 0.1, "notes": [evil], "unplaced": {"7": evil}}},
        evil: {evil: evil},
    }
    page = render_report_page(report, {})
    assert "<script" not in page.lower()
    assert page.count("&lt;script&gt;") >= 7


def test_keys_and_figures_it_does_not_know_are_shown() -> None:
    """A report key added later (a diagnostics section, a per-method figure) and any PNG in
    the folder appear without a change to the page."""
    report = {
        "ground_truth": True,
        "methods": {
            "slam": {"marker_rmse_m": 0.05, "nees_mean": 3.1, "diagnostics": {"worst_id": 4}},
            "ekf": {"marker_rmse_m": 0.07, "nees_mean": 2.2},
        },
        "diagnostics": {
            "per_marker": [
                {"id": 0, "residual_rms": 0.4, "theta_bias_rad": 0.01},
                {"id": 1, "residual_rms": 2.5, "theta_bias_rad": -0.02},
            ]
        },
    }
    page = render_report_page(report, {"diagnostics.png": _tiny_png()})
    elements = parse(page)
    assert ("h2", {"id": "diagnostics"}) in elements.tags
    assert [a["alt"] for t, a in elements.tags if t == "img"] == ["diagnostics.png"]
    assert ["1", "2.5", "-1.15"] in elements.rows  # radians shown in degrees
    assert "NEES mean" in page and ("h2", {"id": "method-diagnostics"}) in elements.tags
    assert 'class="num best" data-key="marker_rmse_m" data-value="0.05"' in page


def _tiny_png() -> bytes:
    ok, encoded = cv2.imencode(".png", np.full((8, 8, 3), 200, np.uint8))
    assert ok
    return encoded.tobytes()
