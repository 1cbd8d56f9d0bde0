"""``markergraph info`` as a preflight (what a log holds, and a verdict with its own exit code)
and ``markergraph export --out -`` (the export on standard output)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer
from trust_helpers import as_sqlite_bag

from markergraph.cli import main
from markergraph.cli._frontend import EXIT_CANNOT_MAP
from markergraph.datasets import scenario, simulate_fast, write_log
from markergraph.datasets.rewrite import rewrite_log
from markergraph.estimator import Method, build_frames, estimate_frames
from markergraph.formats import ExportFormat
from markergraph.frontend import Camera, MarkerSizes
from markergraph.markermap import MarkerMap

DURATION_S, FRAME_HZ, ODOMETRY_HZ = 6.0, 5.0, 50.0  # what the complete log is written with
RATE_TOLERANCE = 0.05  # relative: rates come from log times, which carry a transport latency
DURATION_TOLERANCE_S = 0.1  # log times of the first and last message against the route's span
TAGSLAM = Path(__file__).resolve().parents[2] / "shared" / "data" / "tagslam-test" / "tests"


def info(capsys: pytest.CaptureFixture[str], *arguments: Any) -> tuple[int, str]:
    """``markergraph info`` in this process: (exit code, stdout)."""
    code = main(["info", *(str(a) for a in arguments)])
    return code, capsys.readouterr().out


def field(out: str, name: str) -> str:
    """The text after a report line's label (``colour``, ``odometry``, ...)."""
    match = re.search(rf"^{re.escape(name)} +(.*)$", out, re.MULTILINE)
    assert match, (name, out)
    return match.group(1)


def verdict(out: str) -> str:
    lines = [line for line in out.splitlines() if re.match(r"(can|cannot) map: ", line)]
    assert len(lines) == 1, out
    return lines[0]


def table(out: str) -> tuple[str, list[str]]:
    """The topic table's header and rows."""
    lines = out.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("topic "))
    end = lines.index("", start)
    return lines[start], lines[start + 1 : end]


def rate_of(out: str, topic: str) -> float:
    _, rows = table(out)
    row = next(r.split(maxsplit=3) for r in rows if r.split()[0] == topic)
    return float(row[2])


@pytest.fixture(scope="module", params=[True, False], ids=["jpeg", "rgb8"])
def complete(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("preflight") / "room.mcap"
    world, route = scenario("paper-room")
    write_log(world, route, path, seed=7, duration_s=DURATION_S, compressed=request.param,
              frame_hz=FRAME_HZ, odometry_hz=ODOMETRY_HZ)  # fmt: skip
    return path


def written_encoding(path: Path) -> tuple[str, str]:
    """(colour topic, its first message's encoding or compressed format), read with mcap."""
    with open(path, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, _, decoded in reader.iter_decoded_messages():
            if "/color/image_raw" in channel.topic:
                return channel.topic, getattr(decoded, "format", None) or decoded.encoding
    raise AssertionError(f"{path}: no colour image")


def without(source: Path, target: Path, *topics: str) -> Path:
    rewrite_log(source, target, lambda topic, _, message: None if topic in topics else message)
    return target


def test_complete_log_can_be_mapped(complete: Path, capsys) -> None:
    """A complete log: exit 0, 'can map: yes', and the size, encoding, rates and duration it
    was written with."""
    code, out = info(capsys, complete)
    assert code == 0, out
    assert verdict(out) == "can map: yes"
    topic, encoding = written_encoding(complete)
    colour = field(out, "colour")
    camera = Camera()  # the simulator's
    assert colour.startswith(f"{topic}, size {camera.width}x{camera.height}, ")
    assert f", encoding {encoding}, " in colour
    assert rate_of(out, topic) == pytest.approx(FRAME_HZ, rel=RATE_TOLERANCE)
    assert rate_of(out, "/odom") == pytest.approx(ODOMETRY_HZ, rel=RATE_TOLERANCE)
    odometry = re.match(r"/odom, ([\d.]+) Hz, child frame base_link$", field(out, "odometry"))
    assert odometry and float(odometry.group(1)) == pytest.approx(ODOMETRY_HZ, rel=RATE_TOLERANCE)
    duration = re.match(
        r"([\d.]+) s, (\S+)Z to (\S+)Z \(([\d.]+) to ([\d.]+) s\)", field(out, "duration")
    )
    assert duration, out
    assert float(duration.group(1)) == pytest.approx(DURATION_S, abs=DURATION_TOLERANCE_S)
    assert float(duration.group(5)) - float(duration.group(4)) == pytest.approx(
        float(duration.group(1)), abs=0.002
    )
    assert "aligned to colour (same size and frame)" in field(out, "depth")
    assert field(out, "camera").startswith(f"plumb_bob, K [{camera.fx:g} 0 {camera.cx:g}; ")
    assert field(out, "TF chain") == (  # the simulator's mount: 0.6 m up, pitched 10 deg
        "base_link -> camera_link -> camera_color_optical_frame (/tf_static): the camera "
        "0.10 m ahead, 0.00 m left, 0.60 m up, pitched +10.0 deg"
    )
    assert "warning:" not in out


def test_log_without_odometry_is_mapped_in_3d(complete: Path, tmp_path: Path, capsys) -> None:
    """Without /odom and /tf: info can map, warning that the map is the tags' alone in 3-D,
    and map does just that (info once said it could not)."""
    log = without(complete, tmp_path / "no-odom.mcap", "/odom", "/tf")
    code, out = info(capsys, log)
    assert code == 0 and verdict(out) == "can map: yes", out
    assert field(out, "odometry") == "none"
    assert "warning: no odometry (no nav_msgs/Odometry topic" in out, out
    assert "mapped in 3-D from the tags alone" in out, out
    assert main(["map", str(log), "--out", str(tmp_path / "map"), "--no-plots", "-q"]) == 0
    assert json.loads((tmp_path / "map" / "map.json").read_text())["dimensions"] == 3


def test_odometry_from_tf_needs_the_base_frame(complete: Path, tmp_path: Path, capsys) -> None:
    """Without /odom, the odom -> base_link transforms on /tf are the odometry; with a base
    frame /tf does not carry, there is none, and the verdict says which transform is missing."""
    log = without(complete, tmp_path / "tf-only.mcap", "/odom")
    code, out = info(capsys, log)
    assert code == 0 and verdict(out) == "can map: yes", out
    assert field(out, "odometry").startswith("/tf, ")
    code, out = info(capsys, log, "--base-frame", "base_footprint")
    assert code == EXIT_CANNOT_MAP, out
    assert "no odom -> base_footprint transform" in verdict(out)


def test_log_without_depth_is_a_warning(complete: Path, tmp_path: Path, capsys) -> None:
    """No depth topic: still 'can map: yes' (ranges from the marker size), with a warning."""
    log = without(complete, tmp_path / "no-depth.mcap",
                  "/camera/camera/aligned_depth_to_color/image_raw")  # fmt: skip
    code, out = info(capsys, log)
    assert code == 0 and verdict(out) == "can map: yes", out
    assert "warning: no depth (ranges from marker size)" in out.splitlines()


LONG_TYPE = "a_package_with_a_long_name/msg/AMessageTypeWhoseNameIsLongerThanAnyColumnWasMadeFor"


def test_long_type_names_do_not_break_the_columns(tmp_path: Path, capsys) -> None:
    """Every row's count, rate and type start where the header's do, however long the type
    (and the topic) names; the counts and rates are those written."""
    path = tmp_path / "long.mcap"
    written = {"/a": (LONG_TYPE, 7, 10.0), "/a/topic/name/longer/than/the/header/row": (
        "std_msgs/msg/String", 1234, 100.0)}  # fmt: skip
    with open(path, "wb") as stream:
        writer = Writer(stream)
        for topic, (name, count, rate_hz) in written.items():
            field_text = "int32 data" if name == LONG_TYPE else "string data"
            schema = writer.register_msgdef(name, field_text)
            for i in range(count):
                t_ns = 1_000_000_000 + round(i * 1e9 / rate_hz)
                value = i if name == LONG_TYPE else str(i)
                writer.write_message(topic, schema, {"data": value}, t_ns, t_ns)
        writer.finish()
    code, out = info(capsys, path)
    assert code == EXIT_CANNOT_MAP and verdict(out).startswith("cannot map: no camera"), out
    header, rows = table(out)
    assert len(rows) == len(written)
    ends = [header.index("messages") + len("messages"), header.index("rate [Hz]") + 9]
    type_at = header.index("type")
    for row in rows:
        topic, count, rate, name = row.split(maxsplit=3)
        assert (name, int(count)) == written[topic][:2]
        assert float(rate) == pytest.approx(written[topic][2], rel=1e-3)
        assert row.index(count, len(topic)) + len(count) == ends[0], row  # right-aligned
        assert row.index(rate, ends[0]) + len(rate) == ends[1], row
        assert row.index(name, ends[1]) == type_at, row


def test_sqlite_bag_reports_as_its_mcap_twin(complete: Path, tmp_path: Path, capsys) -> None:
    """A rosbag2 SQLite folder of the same messages: the same report, line for line."""
    bag = tmp_path / "room_bag"
    as_sqlite_bag(complete, bag)
    code_mcap, from_mcap = info(capsys, complete)
    code_bag, from_bag = info(capsys, bag)
    assert any(bag.glob("*.db3")) and code_bag == code_mcap == 0
    assert from_bag.splitlines()[1:] == from_mcap.splitlines()[1:]


@pytest.mark.skipif(not TAGSLAM.is_dir(), reason="../shared/data/tagslam-test is absent")
def test_ros1_detection_bags(tmp_path: Path, capsys) -> None:
    """TagSLAM's ROS 1 bags: without a camera file no intrinsics (cannot map); with its rig
    files it can be mapped; a recording without odometry is mapped in 3-D from its tags, and
    its 36h11 tags under the default dictionary are one line."""
    from markergraph.datasets import tagslam

    folder = TAGSLAM / "test_22"
    bag = tagslam.unpacked(folder, "tag_detections", tmp_path)
    code, out = info(capsys, bag, "--dictionary", "DICT_APRILTAG_36h11")
    assert code == EXIT_CANNOT_MAP and verdict(out).startswith("cannot map: no camera intrinsics")
    rig = ["--cameras", folder / "cameras.yaml", "--camera-poses", folder / "camera_poses.yaml",
           "--tagslam", folder / "tagslam.yaml", "--dictionary", "DICT_APRILTAG_36h11"]  # fmt: skip
    code, out = info(capsys, bag, *rig)
    assert code == 0 and verdict(out) == "can map: yes", out
    assert field(out, "odometry").startswith("/camera/odom/sample, ")
    assert re.search(r"^  camera +equidistant, K \[", out, re.MULTILINE), out
    folder = TAGSLAM / "test_23"  # no odometry: mapped in 3-D from the tags alone, as map does
    no_odometry = tagslam.unpacked(folder, "tag_detections", tmp_path)
    rig = ["--cameras", folder / "cameras.yaml", "--camera-poses", folder / "camera_poses.yaml",
           "--tagslam", folder / "tagslam.yaml", "--dictionary", "DICT_APRILTAG_36h11"]  # fmt: skip
    code, out = info(capsys, no_odometry, *rig)
    assert code == 0 and verdict(out) == "can map: yes", out
    assert "warning: no odometry" in out and "mapped in 3-D from the tags alone" in out, out
    code = main(["info", *(str(a) for a in (no_odometry, *rig[:-2]))])  # 36h11 as DICT_4X4_50
    err = capsys.readouterr().err
    assert code == 1 and "have 6x6 bits" in err and "--dictionary DICT_APRILTAG_36h11" in err


def test_unreadable_log_is_exit_1_not_cannot_map(tmp_path: Path, capsys) -> None:
    """A file that is not a log is bad input (1), one line on stderr; not a verdict (3)."""
    path = tmp_path / "not.mcap"
    path.write_bytes(b"not a log at all, just some bytes")
    code = main(["info", str(path)])
    captured = capsys.readouterr()
    assert code == 1 and not captured.out
    assert len(captured.err.strip().splitlines()) == 1 and str(path) in captured.err


@pytest.fixture(scope="module")
def map_json(tmp_path_factory: pytest.TempPathFactory) -> Path:
    world, route = scenario("paper-room")
    run = simulate_fast(world, route, seed=2, duration_s=60.0)
    frames = build_frames(run.observations, run.odometry, 0, odometry_noise=run.odometry_noise)
    result = estimate_frames(frames, Method.SLAM, run.mount.T_base_camera)
    path = tmp_path_factory.mktemp("export") / "map.json"
    MarkerMap.from_estimate(result, log="sim.mcap", dictionary="DICT_4X4_50",
                            marker_sizes=MarkerSizes(0.2)).save(path)  # fmt: skip
    return path


@pytest.mark.parametrize("fmt", list(ExportFormat), ids=lambda f: f.value)
def test_export_to_stdout_writes_the_files_bytes(
    fmt: ExportFormat, map_json: Path, tmp_path: Path, capsys
) -> None:
    """``--out -`` puts exactly the bytes of ``--out FILE`` on standard output, nothing else,
    and no file named ``-``."""
    out = tmp_path / f"map.{fmt.value}"
    assert main(["export", str(map_json), "--format", fmt.value, "--out", str(out)]) == 0
    capsys.readouterr()
    run = subprocess.run(
        [sys.executable, "-m", "markergraph.cli", "export", str(map_json), "--format",
         fmt.value, "--out", "-"],
        capture_output=True, cwd=tmp_path,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert run.stdout == out.read_bytes() and run.stdout
    assert not run.stderr and not (tmp_path / "-").exists()


def test_export_to_a_file_named_dash(map_json: Path, tmp_path: Path, monkeypatch, capsys) -> None:
    """``--out ./-`` is a file named ``-``, written as any file (refused when it exists)."""
    monkeypatch.chdir(tmp_path)
    assert main(["export", str(map_json), "--format", "csv", "--out", "./-"]) == 0
    assert (tmp_path / "-").read_text().startswith("id,")
    assert main(["export", str(map_json), "--format", "csv", "--out", "./-"]) == 1
    assert "exists" in capsys.readouterr().err
