"""Re-runs: a log's extraction taken from the cache (no image decoded) under the same front-end
settings and the same log, read again otherwise; detect's obs.jsonl as input; the progress bar
on a pseudo-terminal."""

from __future__ import annotations

import fcntl
import json
import os
import pty
import re
import select
import shutil
import struct
import subprocess
import sys
import termios
from pathlib import Path

import numpy as np
import pytest

import markergraph.frontend.seeing as seeing
from markergraph.cli import main
from markergraph.frontend import FrontendConfig
from markergraph.obs_cache import (
    CACHE_VERSION,
    CacheEntry,
    cache_folder,
    entry_key,
    load_entry,
    store_entry,
)

SAME_MAP_M = 1e-9  # the same inputs through the same optimiser: the same numbers
PTY_TIMEOUT_S = 300.0


@pytest.fixture
def decoded(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> list[int]:
    """A fresh cache folder, and a list that grows by one per colour image decoded."""
    monkeypatch.setenv("MARKERGRAPH_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv("MARKERGRAPH_NO_CACHE", raising=False)
    calls: list[int] = []
    real = seeing.decode_image

    def counting(*args: object, **kwargs: object) -> object:
        calls.append(1)
        return real(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(seeing, "decode_image", counting)
    return calls


def _map(log: Path, out: Path, *flags: str) -> dict:
    """``markergraph map`` in this process; its map.json."""
    assert main(["map", str(log), "--out", str(out), "--no-plots", "--quiet", *flags]) == 0
    return json.loads((out / "map.json").read_text())


def _positions(document: dict) -> dict[int, tuple[float, float]]:
    return {int(m["id"]): (m["x"], m["y"]) for m in document["markers"]}


def _map_document_text(out: Path) -> str:
    return (out / "map.json").read_text()


@pytest.mark.slow
def test_second_run_reads_no_image_and_gives_the_same_map(
    log: Path, tmp_path: Path, decoded: list[int]
) -> None:
    """The second run of a log decodes no image and writes the same map.json; an estimator
    setting changed still decodes none and moves the markers."""
    first = _map(log, tmp_path / "one")
    read_first = len(decoded)
    assert read_first >= 100  # the 100 frames, once or twice (a size measured by depth)
    _map(log, tmp_path / "two")
    assert len(decoded) == read_first
    assert _map_document_text(tmp_path / "one") == _map_document_text(tmp_path / "two")
    first_notes = json.loads((tmp_path / "one" / "report.json").read_text())["notes"]
    notes = json.loads((tmp_path / "two" / "report.json").read_text())["notes"]
    assert not any(note.startswith("observations from the cache") for note in first_notes)
    assert notes[0].startswith("observations from the cache")  # said first
    changed = _map(log, tmp_path / "three", "--odometry-noise", "0.2")
    assert len(decoded) == read_first
    a, b = _positions(first), _positions(changed)
    assert a.keys() == b.keys()
    moved = max(np.hypot(a[i][0] - b[i][0], a[i][1] - b[i][1]) for i in a)
    assert moved > 1e-4


@pytest.mark.slow
def test_front_end_setting_or_log_change_reads_again(
    log: Path, tmp_path: Path, decoded: list[int], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A changed front-end setting, a log touched, --no-cache and MARKERGRAPH_NO_CACHE each
    decode the images again."""
    copy = tmp_path / "room.mcap"
    shutil.copyfile(log, copy)
    _map(copy, tmp_path / "one")
    n = len(decoded)
    _map(copy, tmp_path / "two", "--corner-noise", "0.5")
    assert len(decoded) >= n + 100
    n = len(decoded)
    stat = copy.stat()
    os.utime(copy, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1_000_000_000))
    _map(copy, tmp_path / "three")
    assert len(decoded) >= n + 100
    n = len(decoded)
    _map(copy, tmp_path / "four", "--no-cache")
    assert len(decoded) >= n + 100
    n = len(decoded)
    _map(copy, tmp_path / "five")  # the touched log's entry, kept by the third run
    assert len(decoded) == n
    monkeypatch.setenv("MARKERGRAPH_NO_CACHE", "1")
    _map(copy, tmp_path / "six")
    assert len(decoded) >= n + 100


@pytest.mark.slow
def test_corrupt_entry_is_ignored_and_rewritten(
    log: Path, tmp_path: Path, decoded: list[int]
) -> None:
    """A truncated entry is a miss: the log is read again and the entry rewritten whole."""
    _map(log, tmp_path / "one")
    (entry,) = cache_folder().iterdir()
    good = entry.read_bytes()
    entry.write_bytes(good[: len(good) // 2])
    n = len(decoded)
    _map(log, tmp_path / "two")
    assert len(decoded) >= n + 100
    assert load_entry(entry_key(log, FrontendConfig())) is not None
    assert _map_document_text(tmp_path / "one") == _map_document_text(tmp_path / "two")


def test_entries_of_another_version_or_key_are_not_trusted(
    log: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An entry written by another cache version, or holding another key, is not read."""
    monkeypatch.setenv("MARKERGRAPH_CACHE", str(tmp_path))
    key = entry_key(log, FrontendConfig())
    placeholder = CacheEntry(CACHE_VERSION + 1, key, None)  # type: ignore[arg-type]
    store_entry(placeholder)
    assert load_entry(key) is None


def test_least_recently_used_entries_go_first(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, log: Path
) -> None:
    """Over the bound, the entries used longest ago are removed; the one just written stays."""
    from markergraph.frontend import extract

    monkeypatch.setenv("MARKERGRAPH_CACHE", str(tmp_path))
    extraction = extract(log)
    keys = [str(i) * 64 for i in range(3)]
    paths = [store_entry(CacheEntry(CACHE_VERSION, k, extraction)) for k in keys]
    assert all(p is not None for p in paths)
    size = paths[0].stat().st_size  # type: ignore[union-attr]
    for age, path in enumerate(paths):  # written in order, a second apart
        os.utime(path, ns=(10**18 + age * 10**9,) * 2)  # type: ignore[arg-type]
    assert load_entry(keys[0]) is not None  # used now: the newest
    store_entry(CacheEntry(CACHE_VERSION, "9" * 64, extraction), limit_bytes=int(2.5 * size))
    left = sorted(p.name[:4] for p in cache_folder().iterdir())
    assert left == ["0000", "9999"]
    assert load_entry(keys[0]) is not None and load_entry(keys[1]) is None
    assert load_entry(keys[2]) is None


def _under_pty(args: list[str], env: dict[str, str]) -> str:
    """A command's output on a pseudo-terminal (stdout and stderr), as the terminal got it."""
    leader, follower = pty.openpty()
    # A fresh pty is 0 columns wide, where tqdm draws nothing: 24 rows of 120, as a terminal.
    fcntl.ioctl(follower, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 120, 0, 0))
    process = subprocess.Popen(args, stdout=follower, stderr=follower, stdin=subprocess.DEVNULL,
                               env=env, close_fds=True)  # fmt: skip
    os.close(follower)
    chunks = []
    while True:
        ready, _, _ = select.select([leader], [], [], PTY_TIMEOUT_S)
        if not ready:
            process.kill()
            raise AssertionError("no output for too long")
        try:
            chunk = os.read(leader, 65536)
        except OSError:  # the terminal closed: the command ended
            break
        if not chunk:
            break
        chunks.append(chunk)
    os.close(leader)
    assert process.wait(timeout=60) == 0
    return b"".join(chunks).decode("utf-8", "replace")


@pytest.mark.slow
def test_progress_on_a_terminal_ends_at_100_and_each_stage_has_its_line(
    log: Path, tmp_path: Path
) -> None:
    """On a pseudo-terminal the bar ends at 100 % with the frames counted, each stage's line
    begins a line, and no bar is drawn after the reading."""
    env = {**os.environ, "MARKERGRAPH_CACHE": str(tmp_path / "cache")}
    markergraph = str(Path(sys.executable).with_name("markergraph"))
    text = _under_pty([markergraph, "map", str(log), "--out", str(tmp_path / "out"),
                       "--no-plots"], env)  # fmt: skip
    frames = int(re.search(r"^(\d+) frames, ", text, re.M).group(1))  # type: ignore[union-attr]
    stage = "choosing the camera's delay"
    reading, after = text.split(stage, 1)
    assert reading.endswith("\n"), repr(reading[-200:])
    last_bar = re.split(r"[\r\n]+", reading.rstrip())[-1]
    assert "100%" in last_bar and f"{frames}/{frames}" in last_bar, last_bar
    assert "frame/s" not in after and "%|" not in after
    for line in ("choosing the odometry's scale", "estimating: slam", "writing "):
        assert re.search(rf"(^|\n){re.escape(line)}", after), line


@pytest.mark.slow
def test_detect_output_maps_to_the_same_markers_as_the_log(
    log: Path, tmp_path: Path, decoded: list[int]
) -> None:
    """``map obs.jsonl`` (detect's output: observations, mount, odometry) reads no image and
    places the same markers where ``map`` of the log does."""
    obs = tmp_path / "obs.jsonl"
    assert main(["detect", str(log), "--out", str(obs), "--quiet"]) == 0
    from_log = _map(log, tmp_path / "log", "--no-cache")
    n = len(decoded)
    from_file = _map(obs, tmp_path / "file")
    assert len(decoded) == n
    a, b = _positions(from_log), _positions(from_file)
    assert a.keys() == b.keys() and len(a) == 3
    for i in a:
        np.testing.assert_allclose(b[i], a[i], atol=SAME_MAP_M)
    mounts = [json.loads((tmp_path / d / "report.json").read_text())["camera_mount"]
              for d in ("log", "file")]  # fmt: skip
    assert mounts[1]["source"] == f"{obs} (detect's output)"  # not "the settings"
    assert mounts[1]["height_m"] == pytest.approx(mounts[0]["height_m"], abs=1e-9)


def test_detect_output_without_odometry_fails_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Observations without any odometry: exit 1, one line naming the file and what is
    missing."""
    monkeypatch.setenv("MARKERGRAPH_CACHE", str(tmp_path / "cache"))
    row = {"t_ns": 1, "marker_id": 0, "bearing": 0.0, "theta": 0.0, "range_m": 1.0,
           "sigma_bearing": 0.01, "sigma_theta": 0.01, "sigma_range": 0.01,
           "odom": None}  # fmt: skip
    obs = tmp_path / "obs.jsonl"
    obs.write_text(json.dumps(row) + "\n")
    assert main(["map", str(obs), "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(obs) in err[0] and "no odometry" in err[0], err


def test_simulate_quiet_draws_no_bar_on_a_terminal(tmp_path: Path) -> None:
    """On a pseudo-terminal ``simulate`` draws its bar; with ``-q`` only its one result line."""
    markergraph = str(Path(sys.executable).with_name("markergraph"))
    texts = []
    for flags in ([], ["-q"]):
        out = tmp_path / f"room{len(flags)}.mcap"
        texts.append(_under_pty([markergraph, "simulate", "--scenario", "paper-room",
                                 "--duration", "3", "--frame-rate", "3", "--out", str(out),
                                 *flags], dict(os.environ)))  # fmt: skip
    loud, quiet = texts
    assert "simulating paper-room" in loud and "100%" in loud
    assert quiet.strip().startswith("wrote ") and quiet.strip().count("\n") == 0, quiet
