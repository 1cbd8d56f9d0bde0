"""The smaller things users trip on: ``simulate --sensors d435i`` puts the preset's effects in the
log, and the Foxglove layout beside overlay.mcap names the overlay's own topics."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from markergraph.cli import main
from markergraph.datasets.sensors import D435I_ON_DIFF_DRIVE

pytestmark = pytest.mark.slow  # its tests share a fixture that renders or maps a whole log

PRESET = D435I_ON_DIFF_DRIVE
COLOR = "/camera/camera/color/image_raw/compressed"
COLOR_INFO = "/camera/camera/color/camera_info"
DEPTH = "/camera/camera/aligned_depth_to_color/image_raw"
FRAMES = 50  # 10 s at 5 Hz: the preset's 17 renders a frame make longer logs slow here
CENTRE_PX = 10  # half the side of the image-centre patch, where the lens distortion is ~0
# The depth ratio's median over frames: mm quantisation (3e-4 at 3 m), and the rolling shutter's
# few millimetres of motion between the ideal frame's and the preset's centre row (~1e-3).
DEPTH_SCALE_TOLERANCE = 2e-3


def _simulate(out: Path, *extra: str) -> Path:
    arguments = ["simulate", "--scenario", "paper-room", "--seed", "3", "--duration", "10"]
    arguments += ["--frame-rate", "5", "--compressed", "--out", str(out), *extra]
    assert main(arguments) == 0
    return out


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The paper room for 10 s from the command line, ideal and with ``--sensors d435i``."""
    folder = tmp_path_factory.mktemp("smalls")
    return _simulate(folder / "ideal.mcap"), _simulate(folder / "d435i.mcap", "--sensors", "d435i")


def _messages(log: Path, topic: str) -> list[Any]:
    with open(log, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        return [message for *_, message in reader.iter_decoded_messages(topics=[topic])]


def _stamp_ns(message: Any) -> int:
    return int(message.header.stamp.sec) * 10**9 + int(message.header.stamp.nanosec)


def _late_ns(ideal: list[Any], real: list[Any]) -> tuple[np.ndarray, np.ndarray]:
    """Each preset frame's stamp minus its capture time (the ideal log's stamp of the same
    frame, the nearest one to the preset's latency), and that frame's index in ``ideal``."""
    captured = np.array([_stamp_ns(m) for m in ideal], dtype=np.float64)
    stamped = np.array([_stamp_ns(m) for m in real], dtype=np.float64)
    late = stamped[:, None] - captured[None, :]
    nearest = np.argmin(np.abs(late - PRESET.camera_latency_s * 1e9), axis=1)
    return late[np.arange(len(stamped)), nearest], nearest


def test_sensors_d435i_stamps_late_jittered_and_drops_frames(logs) -> None:
    """With ``--sensors d435i`` colour stamps trail the capture by the preset's latency with its
    jitter, some frames are missing (binomial bound), and without the switch none of that."""
    ideal, real = (_messages(log, COLOR) for log in logs)
    assert len(ideal) == FRAMES
    late_ns, _ = _late_ns(ideal, real)
    assert np.median(late_ns) == pytest.approx(PRESET.camera_latency_s * 1e9, abs=1e6)
    assert np.std(late_ns) == pytest.approx(PRESET.stamp_jitter_s * 1e9, rel=0.4)
    dropped = FRAMES - len(real)
    sigma = np.sqrt(FRAMES * PRESET.dropped_frames * (1 - PRESET.dropped_frames))
    assert 0 <= dropped <= FRAMES * PRESET.dropped_frames + 4 * sigma
    ideal_stamps = np.array([_stamp_ns(m) for m in ideal])
    assert np.all(ideal_stamps % 200_000_000 == ideal_stamps[0] % 200_000_000)  # on the 5 Hz grid


def test_sensors_d435i_depth_scale_distortion_and_tf_tree(logs) -> None:
    """The preset's depth reads its scale times the ideal depth at the image centre; camera_info
    carries its distortion; /tf_static its TF tree; odometry stamps its jitter."""
    ideal_log, real_log = logs
    ideal, real = _messages(ideal_log, DEPTH), _messages(real_log, DEPTH)
    _, nearest = _late_ns(ideal, real)
    ratios = []
    for message, j in zip(real, nearest, strict=True):
        a, b = (
            np.frombuffer(m.data, np.uint16).reshape(m.height, m.width).astype(np.float64)
            for m in (ideal[j], message)
        )
        h, w = a.shape
        centre = (slice(h // 2 - CENTRE_PX, h // 2 + CENTRE_PX),
                  slice(w // 2 - CENTRE_PX, w // 2 + CENTRE_PX))  # fmt: skip
        x, y = a[centre], b[centre]
        seen = (x > 0) & (y > 0)  # black ink has no depth in the preset
        if seen.sum() > CENTRE_PX**2:
            ratios.append(np.median(y[seen] / x[seen]))
    assert len(ratios) > FRAMES // 2
    assert np.median(ratios) == pytest.approx(PRESET.depth_scale, abs=DEPTH_SCALE_TOLERANCE)
    assert tuple(_messages(real_log, COLOR_INFO)[0].d) == pytest.approx(PRESET.distortion)
    assert tuple(_messages(ideal_log, COLOR_INFO)[0].d) == (0.0,) * 5

    def frames(log: Path) -> set[str]:
        (message,) = _messages(log, "/tf_static")
        return {t.child_frame_id for t in message.transforms}

    assert {"camera_color_frame", "base_link"} <= frames(real_log)
    assert "camera_color_frame" not in frames(ideal_log)
    off_grid = np.array([_stamp_ns(m) for m in _messages(real_log, "/odom")]) - np.array(
        [_stamp_ns(m) for m in _messages(ideal_log, "/odom")]
    )
    assert np.std(off_grid) == pytest.approx(PRESET.odometry_jitter_s * 1e9, rel=0.3)


def _refuse(constant: str) -> None:
    raise ValueError(f"non-standard JSON constant {constant}")


def _topics(log: Path) -> set[str]:
    with open(log, "rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    return {channel.topic for channel in summary.channels.values()}


def _named_topics(config: dict[str, Any]) -> set[str]:
    """Every topic a panel's config names: its ``topics`` keys and its image mode's topics."""
    mode = config.get("imageMode", {})
    return set(config.get("topics", {})) | {mode[k] for k in mode if k.endswith("Topic")}


@pytest.fixture(scope="module")
def mapped(logs, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``markergraph map`` of the ideal log, with a renamed map frame."""
    folder = tmp_path_factory.mktemp("mapped")
    out = folder / "result"
    arguments = ["map", str(logs[0]), "--out", str(out), "--marker-size", "0.2", "--no-plots"]
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("MARKERGRAPH_CACHE", str(folder / "cache"))
        assert main([*arguments, "--map-frame", "markergraph_map"]) == 0
    return out


def test_foxglove_layout_beside_the_overlay(mapped, logs) -> None:
    """overlay.layout.json is strict JSON listed in report.json; its 3D panel follows the
    overlay's map frame and shows the overlay's markers and path; its Image panel is on the log's
    colour topic and camera_info with the overlay's markers over it; no other topic is named."""
    layout = json.loads((mapped / "overlay.layout.json").read_text(), parse_constant=_refuse)
    report = json.loads((mapped / "report.json").read_text(), parse_constant=_refuse)
    assert "overlay.layout.json" in report["files"]
    panels = layout["configById"]
    (three_d,) = [name for name in panels if name.startswith("3D!")]
    (image,) = [name for name in panels if name.startswith("Image!")]
    assert {layout["layout"]["first"], layout["layout"]["second"]} == {three_d, image}
    overlay_topics = _topics(mapped / "overlay.mcap")
    assert {"/markergraph/markers", "/markergraph/path"} <= _named_topics(panels[three_d])
    assert _named_topics(panels[three_d]) <= overlay_topics
    assert set(panels[image]["topics"]) == {"/markergraph/markers"}
    mode = panels[image]["imageMode"]
    assert (mode["imageTopic"], mode["calibrationTopic"]) == (COLOR, COLOR_INFO)
    assert {COLOR, COLOR_INFO} <= _topics(logs[0]) and not {COLOR, COLOR_INFO} & overlay_topics
    with open(mapped / "overlay.mcap", "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        parents = {
            transform.header.frame_id
            for *_, message in reader.iter_decoded_messages(topics=["/tf_static"])
            for transform in message.transforms
        }
    assert parents == {"markergraph_map"} and panels[three_d]["followTf"] == "markergraph_map"
