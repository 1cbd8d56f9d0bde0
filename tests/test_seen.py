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


# --- notes said once, in our words -----------------------------------------------------------

LIBRARY_WORDS = ("RecordLengthLimitExceeded", "McapError", "EndOfFile", "InvalidMagic", "opcode",
                 "exceeds limit", "ZstdError")  # fmt: skip


@pytest.fixture(scope="module")
def cut_log(log: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The short log cut at 80 %, as a recording stopped by a power loss: no summary, a
    half-written chunk."""
    cut = tmp_path_factory.mktemp("cut") / "cut.mcap"
    cut.write_bytes(log.read_bytes()[: int(log.stat().st_size * 0.8)])
    return cut


def test_a_recovered_index_is_said_once_in_our_words(cut_log: Path) -> None:
    """A cut log's rebuilt index is one note (both of a stretch's readers meet it), naming the
    file and the byte where the read stopped, without the mcap package's own text."""
    from markergraph.frontend import extract

    extraction = extract(cut_log)
    size = cut_log.stat().st_size
    recovered = [w for w in extraction.warnings if "without its index" in w]
    assert len(recovered) == 1, extraction.warnings
    assert recovered[0].startswith(f"{cut_log}: ")
    assert f"of {size:,}" in recovered[0]
    assert not any(word in w for w in extraction.warnings for word in LIBRARY_WORDS), (
        extraction.warnings
    )


def test_stretches_join_their_failures_once() -> None:
    """Stretches read by several workers each meet the same damaged index: the joined
    extraction says it once, and sums their skipped messages per topic rather than repeating
    or collapsing them."""
    from markergraph.estimator.trajectory import Trajectory
    from markergraph.frontend.camera import CameraMount
    from markergraph.frontend.extraction import Extraction, Part, merge_parts
    from markergraph.frontend.logs import DecodeFailures
    from markergraph.frontend.topics import TopicChoice

    parts = []
    for _ in range(3):
        failures = DecodeFailures()
        failures.note(Path("log.mcap"), "read up to byte 10 of 20 without its index")
        failures.add(Path("log.mcap"), "/odom", "a damaged chunk at byte 8")
        extraction = Extraction([], Trajectory.from_samples([]), None,
                                CameraMount(0.0, 0.0, 0.0, 0.0, 0.0),
                                TopicChoice(None, None, None, None, None))  # fmt: skip
        extraction.read_failures = failures
        extraction.warnings = failures.warnings()
        parts.append(Part(extraction))
    joined = merge_parts(parts).extraction
    assert joined.warnings == [
        "log.mcap: read up to byte 10 of 20 without its index",
        "log.mcap: skipped 3 unreadable message(s) on /odom (a damaged chunk at byte 8)",
    ]


def test_mcap_errors_in_our_words() -> None:
    """Each error the mcap package raises reads as what it means for the file, never as the
    library's class and text; our own damage texts pass through as they are."""
    from mcap.exceptions import EndOfFile, InvalidMagic, RecordLengthLimitExceeded

    from markergraph.frontend.logs.records import McapDamageError, why

    assert why(RecordLengthLimitExceeded(1, 2**62, 100)) == (
        "a record claims more bytes than the file holds"
    )
    assert "cut short" in why(InvalidMagic(b"\x00"))
    assert why(EndOfFile()) == "the file ends inside a record"
    assert why(McapDamageError("no chunk at byte 12")) == "no chunk at byte 12"


# --- one run of `markergraph map --method all`, with a mount in the settings the log overrides -

UNUSED_HEIGHT_M, UNUSED_PITCH_DEG = 0.45, 5.0


@pytest.fixture(scope="module")
def mapped_all(log: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str, str]:
    """`markergraph map --method all` on the short log with a camera mount in the settings that
    the log's /tf_static overrides: the folder, stdout and stderr."""
    import os
    import subprocess
    import sys

    folder = tmp_path_factory.mktemp("seen-all")
    settings = folder / "robot.toml"
    settings.write_text(
        f'method = "all"\n[camera]\nheight = {UNUSED_HEIGHT_M}\npitch_deg = {UNUSED_PITCH_DEG}\n'
    )
    out = folder / "result"
    run = subprocess.run(
        [sys.executable, "-m", "markergraph.cli", "map", str(log), "--config", str(settings),
         "--out", str(out)],
        capture_output=True, text=True, env={**os.environ, "MARKERGRAPH_NO_CACHE": "1"},
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    return out, run.stdout, run.stderr


def _odometry_messages(log: Path) -> int:
    """The /odom messages in the log, counted from its records (not from our reader)."""
    from mcap.reader import make_reader

    with open(log, "rb") as stream:
        reader = make_reader(stream)
        return sum(1 for _ in reader.iter_messages(topics=["/odom"]))


def test_odometry_note_states_the_true_count(mapped_all, log: Path) -> None:
    """The odometry note counts every sample used (the log's /odom messages: 1,001 over 20 s
    at 50 Hz), not the 600 its kind was judged on, says the model is applied to all of them,
    and has one colon, not two."""
    folder, _, err = mapped_all
    notes = [line for line in err.splitlines() if line.startswith("note: odometry noise")]
    assert len(notes) == 1, err
    note = notes[0].removeprefix("note: ")
    report = json.loads((folder / "report.json").read_text())
    total = _odometry_messages(log)
    assert report["odometry_samples"] == total > 600
    assert f"for all {total:,} odometry samples on /odom" in note
    assert "first 600 samples" in note
    assert note.count(":") == 1, note
    assert note in report["notes"]


def test_report_lists_the_mount_used_and_its_source(mapped_all, log: Path) -> None:
    """A mount from /tf_static is what report.json's and report.html's settings list (not the
    0.45 m and 5 degrees of the settings file, unused), with where it came from."""
    from markergraph.frontend.logs import open_log
    from markergraph.frontend.tf import mount_from_transforms, transforms_of

    folder, _, _ = mapped_all
    report = json.loads((folder / "report.json").read_text())
    opened = open_log(log)
    static = [t for m in opened.messages(["/tf_static"]) for t in transforms_of(m.decoded)]
    frames = {t.child_frame_id for t in static}
    optical = next(f for f in frames if "color_optical" in f)
    truth = mount_from_transforms(static, ("base_link",), optical)
    settings, mount = report["settings"], report["camera_mount"]
    assert mount["source"].startswith("/tf_static") and optical in mount["source"]
    assert settings["camera.height"] == pytest.approx(truth.height_m, abs=1e-6)
    assert settings["camera.pitch_deg"] == pytest.approx(np.degrees(truth.pitch_rad), abs=1e-5)
    assert abs(truth.height_m - UNUSED_HEIGHT_M) > 0.05
    assert mount["height_m"] == pytest.approx(truth.height_m, abs=1e-9)
    page = (folder / "report.html").read_text()
    assert f"from {mount['source']}" in page.replace("&gt;", ">")


def test_columns_that_mean_nothing_are_dashes(mapped_all) -> None:
    """The EKF measures no links and neither the closed form nor the EKF iterates: their links
    and converged are "-" (null in report.json) and the summary says what links are; the
    graph methods keep their counts."""
    folder, out, _ = mapped_all
    report = json.loads((folder / "report.json").read_text())
    methods = report["methods"]
    assert methods["ekf"]["links"] is None and methods["ekf"]["converged"] is None
    assert methods["closed-form"]["converged"] is None and methods["closed-form"]["links"] >= 1
    assert methods["slam"]["links"] >= 1 and methods["slam"]["converged"] is True
    ekf_row = next(line for line in out.splitlines() if line.startswith("ekf "))
    assert ekf_row.split()[1:3] == ["3", "-"], ekf_row
    assert "links: marker pairs measured together" in out
    page = (folder / "report.html").read_text()
    assert "Links: marker pairs measured together" in page


# --- figures ---------------------------------------------------------------------------------

WHITE_BAND_PX = 40  # the tallest run of blank rows allowed between or around panels


def _longest_blank_run(png: Path) -> int:
    """The tallest run of pixel rows that are blank (white) from edge to edge, inside the
    image (the first and last drawn rows bound it)."""
    import matplotlib.image

    image = matplotlib.image.imread(png)[..., :3]
    blank = np.all(image > 0.98, axis=(1, 2))
    drawn = np.flatnonzero(~blank)
    longest = run = 0
    for row_blank in blank[drawn[0] : drawn[-1] + 1]:
        run = run + 1 if row_blank else 0
        longest = max(longest, run)
    return longest


def _wide_map(offset_m: float = 0.0) -> MarkerMap:
    """Twelve markers along a 20 m by 3 m hall, each with a covariance."""
    rng = np.random.default_rng(8)
    markers = {
        i: MapMarker(
            i, gtsam.Pose2(2.0 * i + offset_m * rng.normal(), 3.0 * (i % 2), 0.5 * i),
            1e-4 * np.eye(3), 10, 0.2,
        )
        for i in range(12)
    }  # fmt: skip
    return MarkerMap(markers, (), 0, "DICT_4X4_50", 0.2, "slam", "hall.mcap")


def test_diagnostics_legends_cover_no_data_and_ids_are_integers() -> None:
    """diagnostics.png: no legend box holds a plotted point, and the detections' marker-id axis
    has whole-number ticks only (3 markers: 0, 1, 2, not 0.25 steps)."""
    from markergraph.estimator.types import Observation
    from markergraph.plots import diagnostics_figure

    rng = np.random.default_rng(3)
    report = {
        "markers": {
            str(i): {"whitened_median": 0.2 + 0.1 * i, "whitened_p95": 0.5 + 0.2 * i,
                     "whitened_max": 0.6 + 0.3 * i, "downweighted": 0}
            for i in range(3)
        }
    }  # fmt: skip
    observations = [
        Observation(int(t * 1e9), int(rng.integers(0, 3)), 0.0, 0.0, 2.0, 0.01, 0.01, 0.01)
        for t in np.linspace(0.0, 60.0, 200)
    ]
    fig = diagnostics_figure("slam", report, observations)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    for ax in fig.axes:
        box = ax.get_legend().get_window_extent(renderer)
        for line in ax.get_lines():
            xy = ax.transData.transform(np.column_stack(line.get_data()).astype(float))
            inside = (
                (xy[:, 0] >= box.x0)
                & (xy[:, 0] <= box.x1)
                & (xy[:, 1] >= box.y0)
                & (xy[:, 1] <= box.y1)
            )
            assert not inside.any(), (ax.get_title(), line.get_label())
    right = fig.axes[1]
    low, high = right.get_ylim()
    ticks = [t for t in right.get_yticks() if low <= t <= high]
    assert ticks and all(float(t).is_integer() for t in ticks), ticks


def test_method_comparison_has_no_empty_band(tmp_path: Path) -> None:
    """comparison.png of five methods on a wide hall: no blank band between or around its rows
    taller than 40 px (a fixed panel height left about 170 px)."""
    from markergraph.plots import plot_comparison

    maps = [(label, _wide_map(0.01 * k), None) for k, label in enumerate("abcde")]
    path = tmp_path / "comparison.png"
    plot_comparison(maps, {}, path)
    assert _longest_blank_run(path) < WHITE_BAND_PX


def test_compare_plot_has_no_empty_band_nor_noise_magnified(tmp_path: Path) -> None:
    """`markergraph compare --plot` of a wide hall: no blank band above or below the maps; a map
    against itself (errors of float noise) is drawn unmagnified, not at x5e14."""
    from markergraph.cli import main
    from markergraph.compare_plot import exaggeration

    ours, theirs = tmp_path / "ours.json", tmp_path / "theirs.json"
    _wide_map(0.02).save(ours)
    _wide_map().save(theirs)
    plot = tmp_path / "compare.png"
    assert main(["compare", str(ours), str(theirs), "--plot", str(plot)]) == 0
    assert _longest_blank_run(plot) < WHITE_BAND_PX
    assert exaggeration(np.array([3e-15, 1e-15]), 20.0) == 1.0


# --- README ----------------------------------------------------------------------------------


def test_readme_api_example_prints_the_aligned_error(monkeypatch, capsys) -> None:
    """README's Python API example prints each method's aligned marker RMSE and names it, with
    the home-fixed one beside it named too (as the CLI summary does), not the bare home-fixed
    MapError; it is run here on a stand-in result with known errors (tests/test_readme.py runs
    it on a real log)."""
    from types import SimpleNamespace

    import markergraph as mg

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    block = next(b for b in re.findall(r"```python\n(.*?)```", readme, re.DOTALL) if "map_log" in b)
    method = SimpleNamespace(
        label="slam",
        map_error_aligned=SimpleNamespace(rmse_position_m=0.034),
        map_error=SimpleNamespace(rmse_position_m=0.190),
        marker_map=SimpleNamespace(markers={0: None, 1: None}),
    )
    from markergraph.common import Note
    from markergraph.verdicts import Judgement, Verdict

    result = SimpleNamespace(
        results=[method],
        notes=[Note("camera.delay_chosen", "camera stamps +0.0 ms against /odom")],
        judgement=Judgement(Verdict.OK),
    )
    monkeypatch.setattr(mg, "map_log", lambda *a, **k: result)
    monkeypatch.setattr(mg, "write_results", lambda *a, **k: [])
    monkeypatch.setattr(mg, "MarkerMap", SimpleNamespace(load=lambda path: None))
    exec(compile(block, "README.md", "exec"), {})
    printed = capsys.readouterr().out
    assert "0.034 m aligned" in printed and "0.190 m home-fixed" in printed, printed
    assert "MapError" not in printed
    assert "note: camera stamps +0.0 ms against /odom" in printed and "verdict: ok" in printed


def test_sizes_are_said_in_mb() -> None:
    """A chunk claiming more than the 268 MB a chunk may hold is said in MB (10^6 bytes), the
    unit `simulate` prints, with thousands separators; never MiB."""
    from mcap.records import Chunk

    from markergraph.frontend.logs.records import McapDamageError
    from markergraph.frontend.logs.scan import MAX_CHUNK_BYTES, decompress

    chunk = Chunk(message_start_time=0, message_end_time=0, uncompressed_size=2**40,
                  uncompressed_crc=0, compression="zstd", data=b"")  # fmt: skip
    with pytest.raises(McapDamageError) as raised:
        decompress(chunk)
    text = str(raised.value)
    assert MAX_CHUNK_BYTES == 268_435_456 and "(more than 268 MB)" in text
    assert "MiB" not in text and f"{2**40:,} bytes" in text


def test_compare_prints_no_negative_zero(tmp_path: Path, capsys) -> None:
    """`markergraph compare` of a map against a copy nudged by float noise prints its zero
    rotation, translation and errors without a minus sign."""
    from markergraph.cli import main

    ours, theirs = tmp_path / "ours.json", tmp_path / "theirs.json"
    _wide_map().save(theirs)
    nudged = _wide_map()
    markers = {
        i: MapMarker(i, gtsam.Pose2(m.T_map_marker.x() + 1e-9, m.T_map_marker.y() + 1e-9,
                                    m.T_map_marker.theta() + 1e-9), m.covariance, 10, 0.2)
        for i, m in nudged.markers.items()
    }  # fmt: skip
    MarkerMap(markers, (), 0, "DICT_4X4_50", 0.2, "slam", "hall.mcap").save(ours)
    assert main(["compare", str(ours), str(theirs)]) == 0
    printed = capsys.readouterr().out
    assert "translation (0.0000, 0.0000) m" in printed, printed
    assert not NEGATIVE_ZERO.search(printed), printed
