"""Trust: memory follows what the log holds, not what a message claims. An image whose header
declares a gigapixel is refused before it is decoded, and odometry is kept in columns."""

from __future__ import annotations

import functools
import json
import struct
import sys
import zlib
from array import array
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import cv2
import numpy as np
import pytest
from trust_helpers import run_with_peak, snapshot

from markergraph.datasets.rewrite import rewrite_log
from markergraph.frontend.logs import Message

COLOR = "/camera/camera/color/image_raw/compressed"
PEAK_RSS_BOUND_MB = 1024  # the bound on any run's peak memory
BOMB_SIDE_PX = 30_000  # the PNG: 875 KB declaring 30,000 x 30,000 grey pixels


# --- helpers ---------------------------------------------------------------------------------


def png_chunk(kind: bytes, body: bytes) -> bytes:
    """One PNG chunk: length, type, body, and the CRC over type and body."""
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


@functools.cache
def png_bomb(side_px: int = BOMB_SIDE_PX) -> bytes:
    """A valid 8-bit grey PNG of ``side_px`` x ``side_px`` black pixels: deflate packs each
    all-zero row about a thousandfold, so the file is small and decoding it is not. A block of
    rows is deflated once after a full flush (no history), so the same bytes stand for every
    block and the file takes a second, not the 13 s of deflating 900 MB."""
    rows_per_block = 100
    block = bytes(side_px + 1) * rows_per_block  # each row: filter byte 0, then its pixels
    packer = zlib.compressobj(9, zlib.DEFLATED, -15)  # raw deflate: the zlib frame by hand
    deflated = packer.compress(block) + packer.flush(zlib.Z_FULL_FLUSH)
    blocks, rest = divmod(side_px, rows_per_block)
    rest_rows = bytes(side_px + 1) * rest
    body = deflated * blocks + packer.compress(rest_rows) + packer.flush()
    adler = 1
    for _ in range(blocks):
        adler = zlib.adler32(block, adler)
    idat = b"\x78\xda" + body + struct.pack(">I", zlib.adler32(rest_rows, adler))
    header = struct.pack(">IIBBBBB", side_px, side_px, 8, 0, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + png_chunk(b"IHDR", header)
        + png_chunk(b"IDAT", idat)
        + png_chunk(b"IEND", b"")
    )


def test_png_bomb_is_a_valid_png() -> None:
    """The bomb is what it claims: OpenCV decodes a small one to the declared size."""
    pixels = cv2.imdecode(np.frombuffer(png_bomb(1234), np.uint8), cv2.IMREAD_GRAYSCALE)
    assert pixels is not None and pixels.shape == (1234, 1234) and not pixels.any()


def run_measured(*arguments: str | Path, timeout_s: float = 300.0) -> tuple[int, str, float]:
    """The ``markergraph`` command in a fresh process: (exit code, stderr, peak RSS [MB] of the
    largest process it ran, workers included)."""
    command = [sys.executable, "-m", "markergraph.cli", *map(str, arguments)]
    done, peak_kb = run_with_peak(command, timeout_s=timeout_s)
    return done.returncode, done.stderr, peak_kb / 1024


# --- images ----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def bomb_log(log: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The shared log with its 11th colour frame replaced by the PNG bomb."""
    bomb = png_bomb()
    target = tmp_path_factory.mktemp("bomb") / "bomb.mcap"

    def change(topic: str, index: int, decoded: Any) -> Any:
        if topic == COLOR and index == 10:
            decoded.format = "png"
            decoded.data = bomb
        return decoded

    rewrite_log(log, target, change)
    return target


def test_png_bomb_header_is_read_not_decoded() -> None:
    """The bomb is small, and its declared size is read from its header alone."""
    from markergraph.frontend.decode import declared_size

    bomb = png_bomb()
    assert len(bomb) < 1_000_000
    assert declared_size(bomb) == (BOMB_SIDE_PX, BOMB_SIDE_PX)


def compressed(data: bytes, schema: str = "sensor_msgs/msg/CompressedImage") -> Message:
    """A CompressedImage message on :data:`COLOR` holding ``data``."""
    return Message(COLOR, schema, 0, SimpleNamespace(format="png", data=data))


def test_jpeg_size_is_read_from_its_start_of_frame() -> None:
    """A real JPEG's declared size is its start-of-frame's, read past the segments before it."""
    from markergraph.frontend.decode import declared_size

    image = np.random.default_rng(0).integers(0, 255, (37, 53), dtype=np.uint8)
    for flags in ([], [cv2.IMWRITE_JPEG_PROGRESSIVE, 1]):
        ok, jpeg = cv2.imencode(".jpg", image, flags)
        assert ok
        assert declared_size(jpeg.tobytes()) == (53, 37)
    assert declared_size(b"\xff\xd8\xff\xda") is None  # a scan before any frame header
    assert declared_size(b"GIF89a") is None


def test_image_far_larger_than_its_camera_is_refused_before_decoding() -> None:
    """A PNG declaring more than twice its camera_info's size is a LogError naming the topic;
    one within it decodes."""
    from markergraph.frontend.decode import decode_image
    from markergraph.frontend.logs import LogError

    ok, png = cv2.imencode(".png", np.zeros((480, 640), np.uint8))
    assert ok
    assert decode_image(compressed(png.tobytes()), (640, 480)).shape == (480, 640)
    with pytest.raises(LogError, match=f"{COLOR}.*640x480.*camera_info 319x239"):
        decode_image(compressed(png.tobytes()), (319, 239))
    with pytest.raises(LogError, match=f"{COLOR}.*30000x30000"):
        decode_image(compressed(png_bomb()))


def test_compressed_depth_bomb_is_refused_before_decoding() -> None:
    """A compressedDepth PNG (12-byte header first) declaring a gigapixel is a LogError."""
    from markergraph.frontend.decode import decode_depth
    from markergraph.frontend.logs import LogError

    header = struct.pack(">IIBBBBB", BOMB_SIDE_PX, BOMB_SIDE_PX, 16, 0, 0, 0, 0)
    forged = b"\x89PNG\r\n\x1a\n" + png_chunk(b"IHDR", header) + png_chunk(b"IEND", b"")
    with pytest.raises(LogError, match=f"{COLOR}.*compressedDepth.*30000x30000"):
        decode_depth(compressed(bytes(12) + forged))


@pytest.mark.slow
def test_png_bomb_in_a_log_costs_one_frame_not_the_machine(bomb_log: Path, tmp_path: Path) -> None:
    """A 30,000 x 30,000 PNG in a log: the run maps the rest, names the topic, and no process
    it runs goes past 1 GB."""
    before = snapshot(bomb_log.parent)
    out = tmp_path / "result"
    code, err, peak_mb = run_measured("map", bomb_log, "--out", out, "--no-plots")
    assert code in (0, 1), err
    assert "Traceback" not in err
    assert peak_mb < PEAK_RSS_BOUND_MB, peak_mb
    assert snapshot(bomb_log.parent) == before
    named = [line for line in err.splitlines() if COLOR in line or "30000x30000" in line]
    if code == 0:
        report = json.loads((out / "report.json").read_text())
        assert "30000x30000" in json.dumps(report) or named, err
    else:
        assert len(err.strip().splitlines()) == 1 and named, err
        assert not out.exists()


# --- odometry --------------------------------------------------------------------------------

TRACK_BYTES_PER_SAMPLE = 40  # four 8-byte columns, plus array.array's growth margin


def test_odometry_track_takes_about_32_bytes_a_sample() -> None:
    """200,000 samples appended one by one take under 40 bytes each (a list of
    OdometrySample objects takes about 200)."""
    import tracemalloc

    from markergraph.estimator.types import OdometrySample, OdometryTrack

    n = 200_000
    rng = np.random.default_rng(7)
    values = rng.normal(size=(3, 1000)).tolist()
    tracemalloc.start()
    try:
        track = OdometryTrack()
        for i in range(n):
            k = i % 1000
            track.append(OdometrySample(i, values[0][k], values[1][k], values[2][k]))
        held, _ = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert len(track) == n and track[-1].t_ns == n - 1
    assert held / n < TRACK_BYTES_PER_SAMPLE, held / n


def clean_path_as_lists(samples: list[Any], log_ns: list[int]) -> tuple[Any, int]:
    """The list form cleaning had before odometry went into columns (kept here as the
    reference): (the path, samples dropped)."""
    import math

    from markergraph.estimator.trajectory import Trajectory
    from markergraph.frontend.cleaning import MAX_COORDINATE_M, MAX_SPEED_MPS
    from markergraph.frontend.inputs import odd_stamps

    finite, finite_log_ns = [], []
    for sample, logged in zip(samples, log_ns, strict=True):
        values = (sample.x, sample.y, sample.yaw)
        if all(math.isfinite(v) for v in values) and max(abs(sample.x), abs(sample.y)) <= (
            MAX_COORDINATE_M
        ):
            finite.append(sample)
            finite_log_ns.append(logged)
    judged = odd_stamps(
        np.array([s.t_ns for s in finite], dtype=np.int64),
        np.array(finite_log_ns, dtype=np.int64),
    )
    in_order = [s for s, kept in zip(finite, judged.kept, strict=True) if kept]

    def speed(a: Any, b: Any) -> float:
        return math.hypot(b.x - a.x, b.y - a.y) / ((b.t_ns - a.t_ns) * 1e-9)

    kept = [
        s
        for i, s in enumerate(in_order)
        if not (
            0 < i < len(in_order) - 1
            and speed(in_order[i - 1], s) > MAX_SPEED_MPS
            and speed(s, in_order[i + 1]) > MAX_SPEED_MPS
            and speed(in_order[i - 1], in_order[i + 1]) <= MAX_SPEED_MPS
        )
    ]
    return Trajectory.from_samples(kept, "odom"), len(samples) - len(kept)


def test_odometry_in_columns_cleans_as_the_lists_did(log: Path) -> None:
    """The simulated log's odometry with bad samples put in (NaN, absurd, a spike, a late
    stamp, a repeat): cleaning its columns gives the very path and counts the lists gave,
    and the front end's whole result on the log is unchanged."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from markergraph.estimator.types import OdometrySample, OdometryTrack
    from markergraph.frontend.cleaning import clean_path
    from markergraph.frontend.decode import odometry_sample

    samples, log_ns = [], []
    with open(log, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages(topics=["/odom"]):
            record = Message(
                channel.topic, schema.name if schema else "", message.log_time, decoded
            )
            samples.append(odometry_sample(record))
            log_ns.append(message.log_time)
    assert len(samples) > 500
    rng = np.random.default_rng(11)
    bad = rng.choice(np.arange(2, len(samples) - 2), size=5, replace=False)
    s = samples
    s[bad[0]] = OdometrySample(s[bad[0]].t_ns, float("nan"), s[bad[0]].y, s[bad[0]].yaw)
    s[bad[1]] = OdometrySample(s[bad[1]].t_ns, 2e7, s[bad[1]].y, s[bad[1]].yaw)
    s[bad[2]] = OdometrySample(s[bad[2]].t_ns, s[bad[2]].x + 40.0, s[bad[2]].y, s[bad[2]].yaw)
    s[bad[3]] = OdometrySample(s[bad[3]].t_ns + 10**12, s[bad[3]].x, s[bad[3]].y, s[bad[3]].yaw)
    s[bad[4]] = s[bad[4] - 1]
    expected_path, expected_dropped = clean_path_as_lists(samples, log_ns)
    track = OdometryTrack(samples)
    assert len(track) == len(samples)
    assert [repr(a) for a in track] == [repr(b) for b in samples]  # NaN != NaN: compare text
    cleaned = clean_path(track, array("q", log_ns), "/odom", "odometry", "odom")
    assert cleaned.path == expected_path
    assert cleaned.dropped == expected_dropped == 5
    assert {n.kind for n in cleaned.notes} == {
        "odometry.dropped_absurd",
        "odometry.dropped_by_stamp",
        "odometry.dropped_spikes",
    }
