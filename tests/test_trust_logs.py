"""Damaged MCAP files: a length field holding a huge value costs a clear line or its own
chunk, never a gigabyte or a crash; a file whose index is damaged or missing (a recording cut
by a power loss) is read record by record and maps as far as it goes, with a note."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import breakup_chunk, make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader

from markergraph.cli import main
from markergraph.frontend.logs import DecodeFailures, open_log

COLOR = "/camera/camera/color/image_raw/compressed"
FOOTER_AT = -(8 + 20 + 1 + 8)  # the footer record: opcode, length, then its 20 bytes; magic


def run(capsys: pytest.CaptureFixture[str], *arguments: object) -> tuple[int, str]:
    """A command in this process: its exit code, and what it printed (stdout then stderr)."""
    code = main([str(a) for a in arguments])
    captured = capsys.readouterr()
    return code, captured.out + captured.err


def markers(folder: Path) -> dict[int, np.ndarray]:
    document = json.loads((folder / "map.json").read_text())
    return {m["id"]: np.array([m["x"], m["y"], m["yaw"]]) for m in document["markers"]}


@pytest.fixture(scope="module")
def clean_map(log: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[int, np.ndarray]:
    out = tmp_path_factory.mktemp("clean") / "map"
    assert main(["map", str(log), "--out", str(out), "--no-plots", "-q"]) == 0
    return markers(out)


def chunk_offsets(log: Path) -> list[int]:
    with open(log, "rb") as stream:
        summary = make_reader(stream).get_summary()
    return sorted(c.chunk_start_offset for c in summary.chunk_indexes)


def with_bytes(log: Path, target: Path, at: int, value: bytes) -> Path:
    data = bytearray(log.read_bytes())
    data[at : at + len(value)] = value
    target.write_bytes(bytes(data))
    return target


def chunk_field(log: Path, name: str) -> int:
    """Where a field of the log's fourth chunk lies (its records are zstd)."""
    content = chunk_offsets(log)[3] + 1 + 8  # past the opcode and the record's length
    # start and end times, then the uncompressed size and CRC, the compression, the records
    fields = {"uncompressed size": 16, "uncompressed crc": 24, "records length": 32 + len("zstd")}
    return content + fields[name]


@pytest.mark.parametrize("value", [2**64 - 1, 2**40, 2**31])
def test_a_huge_uncompressed_size_costs_its_chunk(log, tmp_path, capsys, value) -> None:
    """Before: OverflowError or MemoryError from zstd's output size, exit 2. Now the chunk's
    messages are counted as lost, in a note naming the file."""
    at = chunk_field(log, "uncompressed size")
    damaged = with_bytes(log, tmp_path / "huge.mcap", at, struct.pack("<Q", value))
    code, err = run(capsys, "map", damaged, "--out", tmp_path / "r", "--no-plots")
    assert code == 0, err
    assert f"{damaged}: skipped" in err and "a damaged chunk" in err


def test_a_chunk_failing_its_crc_costs_its_messages(log, tmp_path, capsys) -> None:
    """A chunk whose records disagree with its CRC (damage that still decompresses: a flipped
    byte in a JPEG read as data, libjpeg's "Corrupt JPEG data" on stderr its only sign) costs
    its messages, as many as mcap's own reader finds in the intact chunk."""
    at = chunk_field(log, "uncompressed crc")
    (crc,) = struct.unpack_from("<I", log.read_bytes(), at)
    damaged = with_bytes(log, tmp_path / "crc.mcap", at, struct.pack("<I", crc ^ 1))
    with open(log, "rb") as stream:
        channels = make_reader(stream).get_summary().channels
        stream.seek(0)
        chunks = [r for r in StreamReader(stream, emit_chunks=True).records if isinstance(r, Chunk)]
    colour = next(i for i, c in channels.items() if c.topic == COLOR)
    records = breakup_chunk(chunks[3], validate_crc=True)
    in_chunk = sum(isinstance(r, Message) and r.channel_id == colour for r in records)
    assert in_chunk > 0
    code, err = run(capsys, "detect", damaged, "--out", tmp_path / "o.jsonl")
    assert code == 0, err
    line = (
        f"{damaged}: skipped {in_chunk} unreadable message(s) on {COLOR} (a damaged chunk at "
        f"byte {chunk_offsets(log)[3]}: a chunk whose records fail its CRC)"
    )
    assert line in err, err


@pytest.mark.parametrize("value", [2**63 - 1, 2**63, 2**40])
def test_a_huge_records_length_reads_what_the_chunk_holds(
    log, tmp_path, capsys, clean_map, value
) -> None:
    """Before: MemoryError (the reader allocated what the field claimed) or OverflowError (2^63
    is past an index), exit 2. The chunk is read within its record's own length, so nothing is
    lost."""
    at = chunk_field(log, "records length")
    damaged = with_bytes(log, tmp_path / "huge.mcap", at, struct.pack("<Q", value))
    code, err = run(capsys, "map", damaged, "--out", tmp_path / "r", "--no-plots")
    assert code == 0, err
    found = markers(tmp_path / "r")
    assert found.keys() == clean_map.keys()
    for marker_id, pose in found.items():
        np.testing.assert_allclose(pose, clean_map[marker_id], atol=1e-9)


@pytest.mark.slow
def test_a_damaged_footer_is_read_past_and_maps_as_the_clean_log(
    log: Path, tmp_path: Path, capsys, clean_map
) -> None:
    """The footer's summary offset set to 2^63: before, "[Errno 22] Invalid argument" naming no
    file; now the file is read record by record, says so, and gives the clean log's map."""
    damaged = with_bytes(log, tmp_path / "footer.mcap", log.stat().st_size + FOOTER_AT + 9,
                         struct.pack("<Q", 2**63))  # fmt: skip
    code, err = run(capsys, "info", damaged)
    assert code == 0, err
    assert "read to its end without its index" in err
    code, err = run(capsys, "map", damaged, "--out", tmp_path / "r", "--no-plots")
    assert code == 0, err
    assert f"{damaged}: its summary cannot be read" in err
    found = markers(tmp_path / "r")
    assert found.keys() == clean_map.keys()
    for marker_id, pose in found.items():
        np.testing.assert_allclose(pose, clean_map[marker_id], atol=1e-9)


def test_a_recording_cut_short_maps_as_far_as_it_goes(log: Path, tmp_path: Path, capsys) -> None:
    """A file cut at 70 % (no summary, a half-written chunk): before, "not a complete MCAP
    file"; now its whole chunks are read, the rest is named in a note."""
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(log.read_bytes()[: int(log.stat().st_size * 0.7)])
    opened = open_log(cut)
    assert opened.notes and "without its index" in opened.notes[0]
    start, end = opened.time_range
    clean_start, clean_end = open_log(log).time_range
    assert start == clean_start and clean_start < end < clean_end
    failures = DecodeFailures()
    read = sum(1 for _ in opened.messages(["/odom"], failures))
    assert 0 < read < sum(t.count for t in open_log(log).topics if t.topic == "/odom")
    assert failures.notes == opened.notes
    code, err = run(capsys, "map", cut, "--out", tmp_path / "r", "--no-plots")
    assert code == 0, err
    assert "without its index" in err and len(markers(tmp_path / "r")) >= 2


@pytest.mark.slow
def test_a_summary_missing_a_channel_is_rebuilt(log: Path, tmp_path: Path, capsys, clean_map):
    """Before: KeyError from the message index naming a channel the summary lost, exit 2 in
    info. Now the summary is found unusable and rebuilt from the chunks."""
    with open(log, "rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
    data = log.read_bytes()
    # The summary's channel records (opcode 0x04) come after its schemas; zero the odometry's.
    odom = next(c for c in summary.channels.values() if c.topic == "/odom")
    name = struct.pack("<HHI", odom.id, odom.schema_id, len("/odom")) + b"/odom"
    at = data.rindex(name)
    damaged = with_bytes(log, tmp_path / "channel.mcap", at, struct.pack("<H", 999))
    code, err = run(capsys, "info", damaged)
    assert code == 0, err
    code, err = run(capsys, "map", damaged, "--out", tmp_path / "r", "--no-plots")
    assert code == 0, err
    assert "its chunk index names channels its summary does not hold" in err
    assert markers(tmp_path / "r").keys() == clean_map.keys()


@pytest.mark.parametrize(
    ("head", "said"),
    [(b"\xff\xd8\xff\xe0", "a JPEG image, not a recording"),
     (b"\x89PNG\r\n\x1a\n", "a PNG image, not a recording"),
     (b"SQLite format 3\x00", "give the rosbag2 folder that holds it")],
)  # fmt: skip
def test_a_file_that_is_no_log_says_what_it_is(head, said, tmp_path, capsys) -> None:
    """A photo or a rosbag2's .db3 given as the log: one line saying what it is instead,
    where "not an MCAP file" alone left the user guessing."""
    path = tmp_path / "given.mcap"
    path.write_bytes(head + bytes(64))
    code, err = run(capsys, "info", path)
    assert code == 1 and f"{path}: not an MCAP file (" in err and said in err, err


def test_every_unreadable_file_says_why(log: Path, tmp_path: Path, capsys) -> None:
    """A record header cut inside the footer: before, "not a complete MCAP file ...: " with
    nothing after the colon."""
    cut = tmp_path / "footer-cut.mcap"
    cut.write_bytes(log.read_bytes()[:40])
    for command in (["info", cut], ["map", cut, "--out", tmp_path / "r"]):
        code, err = run(capsys, *command)
        lines = err.strip().splitlines()
        assert code == 1 and len(lines) == 1, err  # nothing on stdout either
        assert str(cut) in lines[0] and not lines[0].rstrip().endswith((":", "()"))
