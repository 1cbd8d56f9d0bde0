"""Trust: markergraph never harms the user's files, one bad message costs one frame, and a
user's mistake is one line naming the file, topic or value, with exit code 1."""

from __future__ import annotations

import json
import math
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from trust_helpers import cli, one_line_error, snapshot, strict_json

from markergraph.common.errors import OutputError
from markergraph.common.files import clean_stale, result_folder
from markergraph.datasets.rewrite import rewrite_log
from markergraph.results import REPORT_SCHEMA

COLOR = "/camera/camera/color/image_raw/compressed"
DEPTH = "/camera/camera/aligned_depth_to_color/image_raw"
INFO = "/camera/camera/color/camera_info"
SAME_MAP_M = 1e-3  # the bound: two lost frames move no marker by more than 1 mm


# --- helpers ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def frames_with_markers(log: Path) -> list[int]:
    """Indices of colour frames in which the simulator saw markers (from the front end)."""
    from markergraph.frontend.pipeline import extract

    stamps = sorted({o.t_ns for o in extract(log).observations})
    indices = []
    with open(log, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for i, (_, _, _, decoded) in enumerate(reader.iter_decoded_messages(topics=[COLOR])):
            stamp = decoded.header.stamp
            if stamp.sec * 1_000_000_000 + stamp.nanosec in stamps:
                indices.append(i)
    return indices


def markers_of(folder: Path) -> dict[int, np.ndarray]:
    document = strict_json(folder / "map.json")
    return {m["id"]: np.array([m["x"], m["y"]]) for m in document["markers"]}


# --- never harm the user's files --------------------------------------------------------------


def test_out_may_not_be_or_hold_the_input(log: Path, tmp_path: Path, capsys) -> None:
    """--out onto the input log, a rosbag2 folder, or a folder holding them is refused before
    any work, with --force too, and every file is left byte-identical."""
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "room_0.mcap").write_bytes(log.read_bytes())
    single = tmp_path / "room.mcap"
    single.write_bytes(log.read_bytes())
    before = snapshot(tmp_path)
    os.chdir(bag)
    for source, out in (
        (bag, bag),
        (bag, tmp_path),
        (bag, Path("..")),
        (single, single),
        (single, tmp_path),
        (bag, bag / "result"),
    ):
        code, out_text, err = cli(capsys, "map", source, "--out", out, "--force")
        assert code == 1 and not out_text
        one_line_error(err, f"--out {out}")
    assert snapshot(tmp_path) == before


@pytest.mark.slow
def test_force_replaces_only_our_own_or_an_empty_folder(log: Path, tmp_path: Path, capsys):
    """--force onto a user's folder or onto a file is refused before any work; onto an empty
    folder or a result markergraph wrote, it replaces it with a whole new result."""
    user = tmp_path / "photos"
    user.mkdir()
    (user / "holiday.jpg").write_bytes(b"not yours")
    a_file = tmp_path / "notes.txt"
    a_file.write_text("mine")
    before = snapshot(tmp_path)
    for out, name in ((user, "not a markergraph result folder"), (a_file, "is a file")):
        code, _, err = cli(capsys, "map", log, "--out", out, "--force")
        assert code == 1
        one_line_error(err, str(out), name)
    assert snapshot(tmp_path) == before

    empty = tmp_path / "empty"
    empty.mkdir()
    code, _, err = cli(capsys, "map", log, "--out", empty, "--force", "--no-plots")
    assert code == 0, err
    first = strict_json(empty / "report.json")
    code, _, err = cli(capsys, "map", log, "--out", empty, "--force", "--no-plots")
    assert code == 0, err
    assert strict_json(empty / "report.json")["schema"] == first["schema"]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_a_failure_half_way_keeps_the_old_result_whole(log: Path, tmp_path: Path, monkeypatch):
    """A --force run that fails while writing leaves the old result byte-identical and no
    temporary folder behind."""
    from markergraph import results
    from markergraph.run import map_log

    out = tmp_path / "result"
    run = map_log(log)
    results.write_results(run, out, plots=False)
    before = snapshot(out)

    def disk_full(*_: Any, **__: Any) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(results, "write_overlay", disk_full)
    with pytest.raises(OSError, match="No space"):
        results.write_results(run, out, force=True, plots=False)
    assert snapshot(out) == before
    assert [p.name for p in tmp_path.iterdir()] == ["result"]


def test_two_runs_at_once_never_mix_their_files(tmp_path: Path) -> None:
    """Two overlapping runs onto the same folder each write into a folder of their own; the
    first to finish takes the name, the other fails with OutputError and is not mixed in."""
    out = tmp_path / "result"
    with pytest.raises(OutputError, match="another run meanwhile"), result_folder(out) as slow:
        (slow / "report.json").write_text(json.dumps({"schema": REPORT_SCHEMA, "run": 1}))
        with result_folder(out) as fast:
            assert fast != slow
            (fast / "report.json").write_text('{"run": 2}')
            (fast / "map.json").write_text("{}")
    assert sorted(p.name for p in out.iterdir()) == ["map.json", "report.json"]
    assert strict_json(out / "report.json")["run"] == 2
    assert [p.name for p in tmp_path.iterdir()] == ["result"]


def test_a_signal_the_moment_the_partial_folder_exists_leaves_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Ctrl-C (a KeyboardInterrupt) just as the run's partial folder is made, the moment a
    watcher sees it (a test that signalled then found it left behind, under load): nothing is
    left beside the output."""
    made = Path.mkdir

    def interrupted(self: Path, *args: Any, **kwargs: Any) -> None:
        made(self, *args, **kwargs)
        if ".partial-" in self.name:
            raise KeyboardInterrupt

    monkeypatch.setattr(Path, "mkdir", interrupted)
    with pytest.raises(KeyboardInterrupt), result_folder(tmp_path / "out"):
        pass
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def dead_pid() -> int:
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


def test_stale_temporary_folders_of_killed_runs_are_cleaned(log: Path, tmp_path: Path, capsys):
    """What a killed run left (its half-written folder; an old result it had moved aside) is
    recognised by its dead process id: the half-written one removed, the old one put back."""
    out = tmp_path / "result"
    pid = dead_pid()
    half = tmp_path / f".result.partial-{pid}-0badc0de"
    half.mkdir()
    (half / "map.json").write_text("{")
    old = tmp_path / f".result.old-{pid}-0badc0de"
    old.mkdir()
    (old / "report.json").write_text(json.dumps({"schema": REPORT_SCHEMA}))
    live = tmp_path / f".result.partial-{os.getpid()}-00000000"  # a running run's: kept
    live.mkdir()
    clean_stale(out)
    assert not half.exists() and not old.exists() and live.exists()
    assert strict_json(out / "report.json")["schema"] == REPORT_SCHEMA


@pytest.mark.slow
def test_killed_run_leaves_no_workers_and_the_next_run_succeeds(log: Path, tmp_path: Path):
    """SIGKILL to a run with two workers (the run's own process and a spawned one): the spawned
    worker exits on its own within seconds, and the next run to the same --out succeeds and
    leaves no temporary folder."""
    psutil = pytest.importorskip("psutil")
    out = tmp_path / "result"
    command = [sys.executable, "-m", "markergraph.cli", "map", str(log), "--out", str(out)]
    run = subprocess.Popen([*command, "--workers", "2"], stderr=subprocess.DEVNULL)
    parent = psutil.Process(run.pid)
    deadline = time.monotonic() + 60
    workers: list[Any] = []
    while not workers and time.monotonic() < deadline and run.poll() is None:
        workers = [c for c in parent.children(recursive=True) if "spawn_main" in " ".join(
            c.cmdline())]  # fmt: skip
        time.sleep(0.05)
    assert len(workers) == 1, "the worker did not start"
    run.send_signal(signal.SIGKILL)
    run.wait()
    _, alive = psutil.wait_procs(workers, timeout=10)
    # A zombie has exited: only its reaping is left, to a container's PID 1 that may not reap.
    alive = [p for p in alive if _status(p, psutil) != psutil.STATUS_ZOMBIE]
    assert not alive, "workers outlived their parent"
    again = subprocess.run(command, capture_output=True, text=True)
    assert again.returncode == 0, again.stderr
    assert [p.name for p in tmp_path.iterdir()] == ["result"]


def _status(process: Any, psutil: Any) -> str:
    try:
        return str(process.status())
    except psutil.NoSuchProcess:
        return psutil.STATUS_ZOMBIE  # gone: as ended as a zombie


def test_every_writer_uses_the_one_helper() -> None:
    """No module but files.py renames or replaces files: every writer goes through it."""
    root = Path(__file__).resolve().parents[1]
    offenders = [
        str(path.relative_to(root))
        for folder in ("common", "estimator", "frontend", "datasets", "app", "cli")
        for path in (root / folder).rglob("*.py")
        if path.name != "files.py"
        and re.search(r"os\.replace|os\.rename|\.rename\(|\.partial(?!\()", path.read_text())
    ]  # (".partial(": functools's, not a temporary file's name)
    assert offenders == []


# --- one bad message costs one frame ----------------------------------------------------------


@pytest.mark.slow
def test_undecodable_frames_cost_those_frames_only(log, frames_with_markers, tmp_path, capsys):
    """Three bad JPEGs (garbage, truncated, empty) in frames with markers: the run goes on, says
    so, and its map equals the map of the log with those frames removed, within 1 mm."""
    bad = set(frames_with_markers[3:6])
    assert len(bad) == 3

    def corrupt(topic: str, index: int, decoded: Any) -> Any:
        if topic == COLOR and index in bad:
            kind = sorted(bad).index(index)
            data = bytes(decoded.data)
            decoded.data = [b"\x55" * len(data), data[:100], b""][kind]
        return decoded

    def drop(topic: str, index: int, decoded: Any) -> Any:
        return None if topic == COLOR and index in bad else decoded

    damaged, removed = tmp_path / "damaged.mcap", tmp_path / "removed.mcap"
    rewrite_log(log, damaged, corrupt)
    rewrite_log(log, removed, drop)
    code, out, err = cli(capsys, "map", damaged, "--out", tmp_path / "a", "--no-plots")
    assert code == 0, err
    assert "colour image does not decode" in out and COLOR in out
    report = strict_json(tmp_path / "a" / "report.json")
    assert report["undecodable_frames"] == 3 and report["frames"] == 100
    assert sum(report["skipped_frames"].values()) == 3
    code, _, err = cli(capsys, "map", removed, "--out", tmp_path / "b", "--no-plots")
    assert code == 0, err
    a, b = markers_of(tmp_path / "a"), markers_of(tmp_path / "b")
    assert a.keys() == b.keys() and len(a) == 3
    for marker_id in a:
        assert np.linalg.norm(a[marker_id] - b[marker_id]) < SAME_MAP_M


def test_empty_depth_frame_costs_its_depth(log: Path, tmp_path: Path, capsys) -> None:
    """An empty depth image is skipped with a warning naming it; its frame goes on without
    depth (not 'not aligned')."""

    def empty_depth(topic: str, index: int, decoded: Any) -> Any:
        if topic == DEPTH and index == 10:
            decoded.height = decoded.width = decoded.step = 0
            decoded.data = b""
        return decoded

    damaged = tmp_path / "empty-depth.mcap"
    rewrite_log(log, damaged, empty_depth)
    code, _, err = cli(capsys, "map", damaged, "--out", tmp_path / "r", "--no-plots")
    assert code == 0, err
    assert "an empty depth image" in err and DEPTH in err and "not aligned" not in err
    report = strict_json(tmp_path / "r" / "report.json")
    assert report["unusable_depth_images"] == 1 and report["frames_with_depth"] == 99


def test_damaged_chunk_costs_its_messages(log: Path, tmp_path: Path, capsys) -> None:
    """A chunk whose zstd data is damaged is skipped, its messages counted per topic; the map is
    still made from the rest."""
    with open(log, "rb") as stream:
        summary = make_reader(stream).get_summary()
    chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    chunk = chunks[len(chunks) // 2]
    assert chunk.compression == "zstd"
    # opcode, length, start and end times, uncompressed size and CRC, compression, records length
    records_at = chunk.chunk_start_offset + 1 + 8 + 8 + 8 + 8 + 4 + 4 + len("zstd") + 8
    data = bytearray(log.read_bytes())
    data[records_at : records_at + 16] = b"\xff" * 16  # the zstd frame header
    damaged = tmp_path / "damaged-chunk.mcap"
    damaged.write_bytes(bytes(data))
    code, _, err = cli(capsys, "map", damaged, "--out", tmp_path / "r", "--no-plots")
    assert code == 0, err
    assert "a damaged chunk" in err and str(damaged) in err
    report = strict_json(tmp_path / "r" / "report.json")
    assert any("damaged chunk" in note for note in report["notes"])
    assert report["frames"] < 100 and len(markers_of(tmp_path / "r")) == 3


@pytest.mark.slow
def test_non_finite_and_backward_odometry_is_dropped_with_notes(log, tmp_path, capsys) -> None:
    """NaN and inf odometry samples and a stamp that jumps back are dropped with notes; every
    output is strict JSON, map.g2o holds no nan, and the map stays within 1 cm of the clean one."""

    def poison(topic: str, index: int, decoded: Any) -> Any:
        if topic == "/odom" and index in (100, 400, 700):
            decoded.pose.pose.position.x = math.nan
        if topic == "/odom" and index == 500:
            decoded.pose.pose.orientation.z = math.inf
        if topic == "/odom" and index == 600:
            decoded.header.stamp.sec -= 5
        return decoded

    poisoned = tmp_path / "poisoned.mcap"
    rewrite_log(log, poisoned, poison)
    code, _, err = cli(capsys, "map", poisoned, "--out", tmp_path / "r", "--method", "all")
    assert code == 0, err
    assert "dropped 4 odometry sample(s) on /odom with NaN, infinite or absurd values" in err
    assert "dropped 1 odometry sample(s) on /odom whose stamps their neighbours contradict" in err
    assert "the worst by 5 s" in err
    for path in (tmp_path / "r").rglob("*.json"):
        strict_json(path)
    for path in (tmp_path / "r").rglob("*.g2o"):
        assert "nan" not in path.read_text().lower()
    code, _, err = cli(capsys, "map", log, "--out", tmp_path / "clean", "--no-plots")
    clean, got = markers_of(tmp_path / "clean"), markers_of(tmp_path / "r")
    assert max(np.linalg.norm(clean[i] - got[i]) for i in clean) < 0.01


# --- a user's mistake is one line and exit 1 --------------------------------------------------


def test_wrong_topics_name_the_flag_topic_and_type(log: Path, tmp_path: Path, capsys) -> None:
    """A topic of the wrong type for its role, or the colour topic given as depth, is refused
    before any work, naming the topic."""
    for flag, topic, words in (
        ("--color-topic", "/tf", "tf2_msgs/msg/TFMessage"),
        ("--odom-topic", INFO, "sensor_msgs/msg/CameraInfo"),
        ("--depth-topic", COLOR, "is the colour topic"),
    ):
        code, _, err = cli(capsys, "map", log, flag, topic, "--out", tmp_path / "r")
        assert code == 1
        one_line_error(err, str(log), topic, words)
    assert not (tmp_path / "r").exists()


def test_bad_settings_name_the_value(log: Path, tmp_path: Path, capsys) -> None:
    """A dictionary file that is not one, ids outside the dictionary, a settings file that is
    not UTF-8, a frame rate no camera has: exit 1 naming the file or value."""
    not_a_dictionary = tmp_path / "dict.yml"
    not_a_dictionary.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00")
    latin = tmp_path / "robot.toml"
    latin.write_bytes("marker_size = 0.2 # côté\n".encode("latin-1"))
    cases = [
        (("map", log, "--dictionary", not_a_dictionary), (str(not_a_dictionary), "dictionary")),
        (("map", log, "--ids", "3", "60"), ("--ids 60", "DICT_4X4_50")),
        (("map", log, "--config", latin), (str(latin), "UTF-8")),
        (("simulate", "--scenario", "paper-room", "--out", tmp_path / "s.mcap",
          "--frame-rate", "1e9"), ("--frame-rate", "1e+09")),
        (("simulate", "--scenario", "paper-room", "--out", tmp_path / "s.mcap",
          "--duration", "inf"), ("--duration", "inf")),
    ]  # fmt: skip
    for arguments, names in cases:
        code, _, err = (
            cli(capsys, *arguments, "--out", tmp_path / "r")
            if arguments[0] == "map"
            else cli(capsys, *arguments)
        )
        assert code == 1, (arguments, err)
        one_line_error(err, *names)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dict.yml", "robot.toml"]


def test_ids_that_leave_nothing_say_which_markers_were_seen(log, tmp_path, capsys) -> None:
    """--ids that filter out every marker: the error names the markers the log does show."""
    code, _, err = cli(capsys, "map", log, "--ids", "7", "--out", tmp_path / "r")
    assert code == 1
    one_line_error(err, str(log), "markers 0, 1, 2 were seen but are not in --ids")


def test_bad_log_files_are_named(log: Path, tmp_path: Path, capsys) -> None:
    """An MCAP under 37 bytes, a broken metadata.yaml (no silent fallback to the folder's
    .mcap files), camera info with a zero K: exit 1, naming the file or topic."""
    tiny = tmp_path / "tiny.mcap"
    tiny.write_bytes(b"\x89MCAP0\r\n" + bytes(20))
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "room_0.mcap").write_bytes(log.read_bytes())
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed\n")

    def zero_k(topic: str, index: int, decoded: Any) -> Any:
        if topic == INFO:
            decoded.k = [0.0] * 9
        return decoded

    no_k = tmp_path / "no-k.mcap"
    rewrite_log(log, no_k, zero_k)
    for source, names in (
        (tiny, (str(tiny), "not a complete MCAP file")),
        (bag, (str(bag / "metadata.yaml"), "not a rosbag2 metadata file")),
        (no_k, (str(no_k), "no camera intrinsics", "intrinsic matrix K")),
    ):
        code, _, err = cli(capsys, "map", source, "--out", tmp_path / "r")
        assert code == 1, err
        one_line_error(err, *names)
    assert not (tmp_path / "r").exists()


def test_bad_map_files_are_refused_by_export_and_heading(tmp_path: Path, capsys) -> None:
    """export and heading refuse a map.json with null markers, a missing field, a NaN or bytes
    that are not UTF-8, naming the file and the field; they never write a file."""
    good = {
        "schema": "markergraph.map/1",
        "marker_size_m": 0.2,
        "dictionary": "DICT_4X4_50",
        "markers": [{"id": 0, "x": 0.0, "y": 0.0, "yaw": 0.0, "n_observations": 3}],
    }
    variants = {
        "null.json": ({**good, "markers": None}, "markers must be a list"),
        "missing.json": ({**good, "markers": [{"id": 0, "x": 1.0}]}, "markers[0].y"),
        "nan.json": (
            {**good, "markers": [{**good["markers"][0], "x": math.nan}]},
            "not a number JSON allows",
        ),
    }
    for name, (document, words) in variants.items():
        path = tmp_path / name
        path.write_text(json.dumps(document))
        for command in (
            ("export", path, "--format", "csv", "--out", tmp_path / "out.csv"),
            ("heading", path, "--from", "0", "--at", "1,0", "--to", "1"),
        ):
            code, _, err = cli(capsys, *command)
            assert code == 1, err
            one_line_error(err, str(path), words)
    binary = tmp_path / "binary.json"
    binary.write_bytes(b"\xff\xfe\x00")
    code, _, err = cli(capsys, "export", binary, "--format", "csv", "--out", tmp_path / "o.csv")
    assert code == 1
    one_line_error(err, str(binary), "UTF-8")
    assert not (tmp_path / "out.csv").exists() and not (tmp_path / "o.csv").exists()


def test_export_onto_its_own_map_is_refused(tmp_path: Path, capsys) -> None:
    """export --out the map it reads is refused even with --force: the map stays."""
    path = tmp_path / "map.json"
    path.write_text('{"schema": "markergraph.map/1"}')
    code, _, err = cli(capsys, "export", path, "--format", "csv", "--out", path, "--force")
    assert code == 1
    one_line_error(err, str(path), "is the input")
    assert path.read_text() == '{"schema": "markergraph.map/1"}'


@pytest.mark.slow
def test_too_many_workers_are_capped_with_a_note(log: Path, tmp_path: Path, capsys) -> None:
    """--workers 1000 runs on the cores there are and says so."""
    out = tmp_path / "obs.jsonl"
    code, stdout, err = cli(capsys, "detect", log, "--out", out, "--workers", "1000")
    assert code == 0, err
    assert "--workers 1000 capped at the" in stdout + err
    assert out.read_text().count("\n") > 10


def test_ctrl_c_exits_130_and_writes_nothing(tmp_path: Path) -> None:
    """SIGINT during a run: exit code 130, one line, and no file or temporary file left."""
    out = tmp_path / "long.mcap"
    run = subprocess.Popen(
        [sys.executable, "-m", "markergraph.cli", "simulate", "--scenario", "corridor-loop",
         "--out", str(out), "--compressed", "--duration", "300"],
        stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    deadline = time.monotonic() + 60
    while not list(tmp_path.glob(".long.mcap.partial-*")) and time.monotonic() < deadline:
        time.sleep(0.05)  # until the run is writing
    assert run.poll() is None, "the run ended before it could be interrupted"
    run.send_signal(signal.SIGINT)
    _, err = run.communicate(timeout=60)
    assert run.returncode == 130, err
    assert "interrupted" in err
    assert list(tmp_path.iterdir()) == []


# --- found by a hostile review: each a case that once harmed files or stopped a run ---------


@pytest.mark.slow
def test_force_never_deletes_what_the_user_added_to_a_result(log, tmp_path, capsys) -> None:
    """A result folder the user added a file or a folder to is not replaced by --force; the
    line names what markergraph did not write; nothing changes."""
    out = tmp_path / "result"
    code, _, err = cli(capsys, "map", log, "--out", out, "--no-plots")
    assert code == 0, err
    assert "report.json" in strict_json(out / "report.json")["files"]
    (out / "notes.txt").write_text("mine")
    (out / "photos").mkdir()
    before = snapshot(tmp_path)
    code, _, err = cli(capsys, "map", log, "--out", out, "--force", "--no-plots")
    assert code == 1
    one_line_error(err, str(out), "notes.txt", "photos")
    assert snapshot(tmp_path) == before and (out / "photos").is_dir()


def test_outputs_never_land_inside_a_rosbag2_folder(log: Path, tmp_path: Path, capsys) -> None:
    """detect --out onto a file of the input bag, or simulate into a bag folder, is refused even
    with --force; the bag stays byte-identical."""
    bag = tmp_path / "bag"
    bag.mkdir()
    for name in ("a_0.mcap", "a_1.mcap"):
        (bag / name).write_bytes(log.read_bytes())
    (bag / "metadata.yaml").write_text(
        "rosbag2_bagfile_information:\n  relative_file_paths:\n    - a_0.mcap\n    - a_1.mcap\n"
    )
    before = snapshot(tmp_path)
    for arguments in (
        ("detect", bag, "--out", bag / "a_1.mcap", "--force"),
        ("detect", bag, "--out", bag / "metadata.yaml", "--force"),
        ("simulate", "--scenario", "paper-room", "--out", bag / "a_0.mcap", "--force"),
    ):
        code, _, err = cli(capsys, *arguments)
        assert code == 1, (arguments, err)
        one_line_error(err, str(bag))
    assert snapshot(tmp_path) == before


def test_output_places_that_cannot_be_are_refused_before_work(log, tmp_path, capsys) -> None:
    """--out . (the folder one is in) or under a file: one line, before any work."""
    empty = tmp_path / "empty"
    empty.mkdir()
    os.chdir(empty)
    for out, words in ((".", "the folder you are in"), (log / "x", "is a file")):
        code, stdout, err = cli(capsys, "map", log, "--out", out, "--force")
        assert code == 1 and not stdout
        one_line_error(err, words)
    assert list(empty.iterdir()) == []


def rewritten(log: Path, tmp_path: Path, name: str, change: Callable[[str, int, Any], Any]):
    path = tmp_path / f"{name}.mcap"
    rewrite_log(log, path, change)
    return path


def mapped(log: Path, tmp_path: Path, capsys, name: str, change: Callable[..., Any]) -> str:
    """Map the log with ``change`` applied into ``tmp_path / "r"``; checks exit 0 and returns
    what the run said on stderr."""
    code, _, err = cli(capsys, "map", rewritten(log, tmp_path, name, change), "--out",
                       tmp_path / "r", "--no-plots")  # fmt: skip
    assert code == 0, err
    return err


def moved_from_clean(log: Path, tmp_path: Path, capsys, result: Path) -> float:
    """How far [m] the markers of a result lie from those of the clean log's map."""
    code, _, err = cli(capsys, "map", log, "--out", tmp_path / "clean", "--no-plots")
    assert code == 0, err
    clean, got = markers_of(tmp_path / "clean"), markers_of(result)
    assert clean.keys() == got.keys()
    return max(float(np.linalg.norm(clean[i] - got[i])) for i in clean)


@pytest.mark.slow
def test_bad_ground_truth_and_camera_info_cost_only_themselves(log, tmp_path, capsys) -> None:
    """One NaN true pose, one NaN true marker and one camera info with a NaN distortion: the run
    goes on (the next camera info is used), each dropped with a note naming its topic, and the
    map is the clean log's."""

    def damage(topic: str, index: int, decoded: Any) -> Any:
        if topic == "/ground_truth/pose" and index == 50:
            decoded.pose.position.x = math.nan
        if topic == "/ground_truth/markers":
            decoded.transforms[1].transform.translation.y = math.nan
        if topic == INFO and index == 0:
            decoded.d = [math.nan, 0.0, 0.0, 0.0, 0.0]
        return decoded

    err = mapped(log, tmp_path, capsys, "truth", damage)
    assert "dropped 1 ground-truth sample(s) on /ground_truth/pose" in err
    assert "non-finite true pose of aruco_1 on /ground_truth/markers" in err
    assert INFO in err and "non-finite distortion" in err
    report = strict_json(tmp_path / "r" / "report.json")
    assert report["frames"] == 100 and sum(report["skipped_frames"].values()) == 0
    assert moved_from_clean(log, tmp_path, capsys, tmp_path / "r") < SAME_MAP_M


@pytest.mark.slow
def test_absurd_odometry_and_a_spike_are_dropped(log: Path, tmp_path: Path, capsys) -> None:
    """x = 1e300, x = 1e20, a zero quaternion and a 100 m spike in /odom are each dropped with
    a note; the map stays within 1 cm of the clean log's."""

    def damage(topic: str, index: int, decoded: Any) -> Any:
        if topic == "/odom":
            position, q = decoded.pose.pose.position, decoded.pose.pose.orientation
            if index in (100, 200):
                position.x = {100: 1e300, 200: 1e20}[index]
            elif index == 300:
                q.x = q.y = q.z = q.w = 0.0
            elif index == 400:
                position.x += 100.0
        return decoded

    err = mapped(log, tmp_path, capsys, "odometry", damage)
    assert "dropped 3 odometry sample(s) on /odom with NaN, infinite or absurd values" in err
    assert "dropped 1 odometry sample(s) on /odom that jump away and back faster" in err
    assert moved_from_clean(log, tmp_path, capsys, tmp_path / "r") < 0.01


@pytest.mark.slow
def test_one_frame_with_a_wrong_stamp_costs_that_frame(log, frames_with_markers, tmp_path, capsys):
    """A colour frame stamped seven years ahead does not hold up the frames behind it: every
    other frame keeps its depth and the map equals the one without that frame, within 1 mm."""
    wrong = frames_with_markers[4]

    def future(topic: str, index: int, decoded: Any) -> Any:
        if topic == COLOR and index == wrong:
            decoded.header.stamp.sec += 7 * 365 * 86400
        return decoded

    def drop(topic: str, index: int, decoded: Any) -> Any:
        return None if topic == COLOR and index == wrong else decoded

    for name, change in (("future", future), ("dropped", drop)):
        code, _, err = cli(capsys, "map", rewritten(log, tmp_path, name, change), "--out",
                           tmp_path / name, "--no-plots")  # fmt: skip
        assert code == 0, err
    report = strict_json(tmp_path / "future" / "report.json")
    assert report["frames_with_depth"] >= 99
    a, b = markers_of(tmp_path / "future"), markers_of(tmp_path / "dropped")
    assert max(np.linalg.norm(a[i] - b[i]) for i in a) < SAME_MAP_M


@pytest.mark.slow
def test_tf_static_damage_is_a_note_not_a_hang_or_nan(log, tmp_path, capsys) -> None:
    """A loop in /tf_static, or a NaN in it, is named in a note and the configured mount used;
    every output stays strict JSON."""

    def loop(topic: str, index: int, decoded: Any) -> Any:
        if topic == "/tf_static":
            for transform in decoded.transforms:
                if transform.child_frame_id == "camera_link":
                    transform.header.frame_id = "camera_color_optical_frame"
        return decoded

    def nan(topic: str, index: int, decoded: Any) -> Any:
        if topic == "/tf_static":
            decoded.transforms[0].transform.translation.z = math.nan
        return decoded

    for name, change, words in (("loop", loop, "form a loop"), ("nan", nan, "non-finite")):
        code, _, err = cli(capsys, "map", rewritten(log, tmp_path, name, change), "--out",
                           tmp_path / name, "--no-plots")  # fmt: skip
        assert code == 0, err
        assert "/tf_static" in err and words in err and "assuming the configured" in err
        for path in (tmp_path / name).rglob("*.json"):
            strict_json(path)


def test_depth_with_no_valid_pixel_is_said(log: Path, tmp_path: Path, capsys) -> None:
    """Depth images of zeros pair with every frame but give no range: a note says so and the
    ranges come from the markers' size."""

    def zeros(topic: str, index: int, decoded: Any) -> Any:
        if topic == DEPTH:
            decoded.data = bytes(len(decoded.data))
        return decoded

    err = mapped(log, tmp_path, capsys, "zeros", zeros)
    assert "found no valid depth on their marker in " + DEPTH in err


@pytest.mark.parametrize(
    ("flags", "words"),
    [
        (("--corner-noise", "1e300"), "--corner-noise must be between"),
        (("--odometry-noise", "1e300"), "--odometry-noise must be between"),
        (("--camera-x", "1e300"), "--camera-x must be between"),
        (("--marker-sizes", "0=1e-300"), "--marker-sizes must be between"),
        (("--depth-noise-base", "0", "--depth-noise-per-m2", "0"), "are both 0"),
    ],
)
def test_settings_out_of_any_robots_range_are_refused(log, tmp_path, capsys, flags, words):
    """Values that would overflow or make the graph singular after all the work are refused
    first, naming the flag."""
    code, stdout, err = cli(capsys, "map", log, *flags, "--out", tmp_path / "r")
    assert code == 1 and not stdout
    one_line_error(err, words)


def test_huge_numbers_in_files_are_named(tmp_path: Path, capsys) -> None:
    """A 400-digit integer in a settings file or a map.json, a variance of 1e308, a duplicate id
    or a dictionary name with a newline: one line naming the file and the field."""
    settings = tmp_path / "robot.yaml"
    settings.write_text(f"marker_size: {10**400}\n")
    code, _, err = cli(capsys, "map", "--config", settings, "--print-config")
    assert code == 1
    one_line_error(err, str(settings), "marker_size")
    good = {"id": 0, "x": 0.0, "y": 0.0, "yaw": 0.0, "n_observations": 3}
    base = {"schema": "markergraph.map/1", "marker_size_m": 0.2, "dictionary": "DICT_4X4_50"}
    cases = {
        "big.json": ({**base, "markers": [{**good, "x": 10**400}]}, "markers[0].x"),
        "variance.json": (
            {**base, "markers": [{**good, "covariance": [[1.5e308, 0, 0], [0, 1, 0], [0, 0, 1]]}]},
            "markers[0].covariance",
        ),
        "twice.json": ({**base, "markers": [good, good]}, "appears twice"),
        "newline.json": ({**base, "dictionary": "X\ninjected: 1", "markers": [good]}, "dictionary"),
    }
    for name, (document, words) in cases.items():
        path = tmp_path / name
        path.write_text(json.dumps(document))
        code, _, err = cli(capsys, "export", path, "--format", "fiducial-slam", "--out",
                           tmp_path / "out.txt")  # fmt: skip
        assert code == 1, name
        one_line_error(err, str(path), words)
    assert not (tmp_path / "out.txt").exists()


@pytest.mark.slow
def test_logs_that_cannot_be_mapped_say_why(log: Path, tmp_path: Path, capsys) -> None:
    """Colour stamps on another clock than odometry, every /odom sample NaN, a metadata.yaml
    listing a file outside its folder: one line that says which."""

    def other_clock(topic: str, index: int, decoded: Any) -> Any:
        if topic == COLOR:
            decoded.header.stamp.sec += 3600
        return decoded

    def all_nan(topic: str, index: int, decoded: Any) -> Any:
        if topic == "/odom":
            decoded.pose.pose.position.x = math.nan
        return decoded

    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_text(
        f"rosbag2_bagfile_information:\n  relative_file_paths:\n    - ../{log.name}\n"
    )
    (tmp_path / log.name).write_bytes(log.read_bytes())
    for source, words in (
        (rewritten(log, tmp_path, "clock", other_clock), "different clocks"),
        (rewritten(log, tmp_path, "nan", all_nan), "no usable odometry on /odom (dropped"),
        (bag, "outside the bag's folder"),
    ):
        code, _, err = cli(capsys, "map", source, "--out", tmp_path / "r")
        assert code == 1, err
        one_line_error(err, words)


@pytest.mark.slow
def test_an_odometry_reset_is_named_and_released(log: Path, tmp_path: Path, capsys) -> None:
    """Every /odom pose after the 500th moved 0.3 m (a VIO reset): the run names the jump with
    its size and time, and the markers stay within 3 cm of the clean log's map (1.3 cm, and
    17.1 cm taken at its word, by tests/benchmarks/odometry_jumps.py)."""

    def reset(topic: str, index: int, decoded: Any) -> Any:
        if topic == "/odom" and index >= 500:
            decoded.pose.pose.position.x += 0.3
        return decoded

    err = mapped(log, tmp_path, capsys, "reset", reset)
    assert "odometry on /odom jumped 0.30 m at 10.00 s into the log" in err
    assert moved_from_clean(log, tmp_path, capsys, tmp_path / "r") < 0.03
