"""Trust, for bags: a damaged ROS 1 bag (plain or lz4) costs only its damaged chunks' messages,
counted per topic like an MCAP file's; what cannot be read is one line with a reason and the
byte where it lies; no length a record claims is allocated before it is checked against the
file; a damaged SQLite bag is one line; ``info`` and ``map`` agree on what can be read."""

from __future__ import annotations

import hashlib
import json
import os
import random
import shutil
import struct
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from trust_helpers import as_sqlite_bag, cli, one_line_error, run_with_peak

from markergraph.datasets import scenario, write_log
from markergraph.frontend.logs.ros1 import Ros1Bag, open_ros1

COLOR = "/camera/camera/color/image_raw/compressed"
DEPTH = "/camera/camera/aligned_depth_to_color/image_raw"
MEMORY_LIMIT_KB = 1 << 20  # the bound on a run's peak memory: 1 GB (ru_maxrss is in kB)
# Seeded damaged bags run through info and map (each about 2 s); more with the variable.
FUZZ_CASES = int(os.environ.get("MARKERGRAPH_BAG_FUZZ_CASES", "6"))


# --- bags made from a simulated log -------------------------------------------------------


def as_ros1_bag(mcap: Path, path: Path, compression: str | None) -> None:
    """The MCAP's messages re-serialised for ROS 1 in a bag of 256 kB chunks (a few messages
    each), lz4-compressed or plain."""
    from rosbags.convert.converter import migrate_bytes
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ros2, ros1 = get_typestore(Stores.ROS2_HUMBLE), get_typestore(Stores.ROS1_NOETIC)
    # Noetic's store lacks tf2_msgs; the bag carries the definition, as rosbag record writes it.
    ros1.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms",
                                     "tf2_msgs/msg/TFMessage"))  # fmt: skip
    writer = Writer(path)
    if compression == "lz4":
        writer.set_compression(Writer.CompressionFormat.LZ4)
    writer.chunk_threshold = 256 * 1024
    writer.open()
    connections: dict[str, Any] = {}
    cache: dict[str, object] = {}
    with open(mcap, "rb") as stream:
        for schema, channel, message in make_reader(stream).iter_messages(log_time_order=True):
            if channel.topic not in connections:
                connections[channel.topic] = writer.add_connection(
                    channel.topic, schema.name, typestore=ros1
                )
            data = migrate_bytes(ros2, ros1, schema.name, schema.name, cache, message.data,
                                 src_is2=True, dst_is2=False)  # fmt: skip
            writer.write(connections[channel.topic], message.log_time, bytes(data))
    writer.close()


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """6 s of the paper room at 5 Hz as a plain ROS 1 bag, an lz4 one and a SQLite folder.
    Read them, never write to them: damage a copy."""
    folder = tmp_path_factory.mktemp("bags")
    mcap = folder / "room.mcap"
    world, route = scenario("paper-room")
    write_log(world, route, mcap, seed=2, duration_s=6.0, compressed=True, frame_hz=5.0)
    made = {"plain": folder / "room-plain.bag", "lz4": folder / "room-lz4.bag"}
    for compression, path in made.items():
        as_ros1_bag(mcap, path, None if compression == "plain" else compression)
    as_sqlite_bag(mcap, folder / "room_db")
    return {**made, "sqlite": folder / "room_db"}


# --- helpers -------------------------------------------------------------------------------


def run(*arguments: Any) -> subprocess.CompletedProcess[str]:
    """The ``markergraph`` command in a process of its own, within a minute."""
    return subprocess.run(
        [sys.executable, "-m", "markergraph.cli", *(str(a) for a in arguments)],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip


def digest(path: Path) -> str:
    """The hash of a file's bytes, or of every file's under a folder."""
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    return hashlib.sha256(b"".join(p.read_bytes() for p in files)).hexdigest()


def report_notes(folder: Path) -> list[str]:
    def refuse(name: str) -> None:
        raise AssertionError(f"{folder} holds {name}")

    document = json.loads((folder / "report.json").read_text(), parse_constant=refuse)
    return list(document["notes"])


def chunk_record(data: bytes, pos: int) -> tuple[int, int, int]:
    """A chunk record at ``pos``: (where its header starts, its length, where its data starts)."""
    (header_len,) = struct.unpack_from("<I", data, pos)
    return pos + 4, header_len, pos + 8 + header_len


def damaged_copy(bag: Path, folder: Path, name: str, change: Any) -> Path:
    """A copy of ``bag`` with ``change(bytearray)`` applied (it may return a shorter one)."""
    data = bytearray(bag.read_bytes())
    data = change(data) or data
    path = folder / name
    path.write_bytes(bytes(data))
    return path


def lost_per_topic(bag: Ros1Bag, pos: int) -> dict[str, int]:
    """Topic -> its messages in the chunk at ``pos``, by the intact bag's index."""
    chunk = next(c for c in bag.chunks if c.pos == pos)
    lost: dict[str, int] = {}
    for connection, n in chunk.counts.items():
        topic = bag.connections[connection].topic
        lost[topic] = lost.get(topic, 0) + n
    return lost


# --- a damaged chunk costs its messages ------------------------------------------------------


@pytest.mark.parametrize("kind", ["lz4", "plain"])
def test_a_damaged_chunk_costs_only_its_messages(bags, kind, tmp_path, capsys) -> None:
    """One chunk with damaged data (lz4 that does not decompress; a plain chunk whose first
    record's header length runs past it): map exits 0 from the other chunks, and says per topic
    how many messages it skipped, counted as the index counts them; the bag is untouched."""
    intact = open_ros1(bags[kind])
    with_colour = [c for c in intact.chunks
                   if any(intact.connections[i].topic == COLOR for i in c.counts)]  # fmt: skip
    pos = with_colour[len(with_colour) // 2].pos

    def damage(data: bytearray) -> None:
        _, _, data_at = chunk_record(bytes(data), pos)
        if kind == "lz4":
            data[data_at + 20 : data_at + 60] = bytes(range(40))  # past the frame's header
        else:
            data[data_at : data_at + 4] = struct.pack("<I", 0xFFFFFFF0)

    bag = damaged_copy(bags[kind], tmp_path, f"damaged-{kind}.bag", damage)
    before = digest(bag)
    code, _, err = cli(capsys, "map", bag, "--out", tmp_path / "r", "--no-plots")
    assert code == 0, err
    notes = [n for n in report_notes(tmp_path / "r") if "damaged chunk" in n]
    for topic, n in lost_per_topic(intact, pos).items():
        if topic in (COLOR, DEPTH, "/odom"):  # the topics map streams
            line = f"{bag}: skipped {n} unreadable message(s) on {topic} (a damaged chunk at byte "
            line += str(pos)
            assert line in err and any(note.startswith(line) for note in notes), (line, err)
    assert digest(bag) == before


def test_a_bag_whose_every_frame_is_unreadable_is_one_line(bags, tmp_path, capsys) -> None:
    """Every chunk holding a colour frame damaged: detect and map refuse the bag in one line
    naming it, the topic and the damage, never an empty observations file with exit 0."""
    intact = open_ros1(bags["lz4"])
    with_colour = [c.pos for c in intact.chunks
                   if any(intact.connections[i].topic == COLOR for i in c.counts)]  # fmt: skip

    def damage(data: bytearray) -> None:
        for pos in with_colour:
            _, _, data_at = chunk_record(bytes(data), pos)
            data[data_at + 20 : data_at + 60] = bytes(range(40))  # lz4 that does not decompress

    bag = damaged_copy(bags["lz4"], tmp_path, "every-frame.bag", damage)
    for command in ("detect", "map"):
        out = tmp_path / f"{command}-out"
        plots = ["--no-plots"] if command == "map" else []
        code, _, err = cli(capsys, command, bag, "--out", out, *plots)
        line = one_line_error(err, str(bag), COLOR, "damaged chunk")
        assert code == 1 and "could be read" in line and not out.exists(), (command, err)
        assert f"and {len(with_colour) - 1} other places" in line, line  # every chunk counted


def test_a_bag_cut_short_is_read_to_the_cut_with_a_note(bags, tmp_path, capsys) -> None:
    """A bag cut inside its last chunks (no index left): info and map read it by a scan of its
    records, and map says where the scan stopped and that the rest is lost."""
    size = bags["lz4"].stat().st_size
    bag = damaged_copy(bags["lz4"], tmp_path, "cut.bag", lambda data: data[: size * 3 // 4])
    code, out, err = cli(capsys, "info", bag)
    assert code == 0 and "can map: yes" in out, out + err
    code, _, err = cli(capsys, "map", bag, "--out", tmp_path / "r", "--no-plots")
    assert code == 0, err
    cut = [line for line in err.splitlines() if "the scan of its records stopped at" in line]
    assert len(cut) == 1 and str(bag) in cut[0] and "the messages after that are lost" in cut[0]
    assert any("the scan of its records stopped at" in n for n in report_notes(tmp_path / "r"))


def rosbag_padded(data: bytes) -> bytes:
    """A bag written by the rosbags library with its header record padded as ``rosbag record``
    pads it (4096 bytes of header and data, not 4096 in all): every record after it 8 bytes on."""
    (header_len,) = struct.unpack_from("<I", data, 13)
    at = 17 + header_len  # the bag header's data length
    (data_len,) = struct.unpack_from("<I", data, at)
    end = at + 4 + data_len
    return data[:at] + struct.pack("<I", data_len + 8) + data[at + 4 : end] + b" " * 8 + data[end:]


def test_a_cut_bag_is_scanned_from_where_its_header_record_ends(bags, tmp_path) -> None:
    """Real bags (``rosbag record``) have their first chunk at byte 4117, the rosbags library's
    at 4109: a bag of either, cut short, is scanned from its header record's end and gives the
    same chunks (the scan once began at 4109 and found nothing in a real bag)."""
    data = bags["lz4"].read_bytes()
    cut = len(data) * 3 // 4
    ours = damaged_copy(bags["lz4"], tmp_path, "ours.bag", lambda d: d[:cut])
    real = tmp_path / "real.bag"
    real.write_bytes(rosbag_padded(data)[: cut + 8])
    read_ours, read_real = open_ros1(ours), open_ros1(real)
    assert read_ours.scanned and read_real.scanned
    assert len(read_ours.chunks) >= 2
    assert [c.counts for c in read_real.chunks] == [c.counts for c in read_ours.chunks]
    assert [c.pos + 8 for c in read_ours.chunks] == [c.pos for c in read_real.chunks]


# --- lengths are checked before anything is allocated -----------------------------------------


def test_huge_lengths_are_refused_before_they_are_allocated(bags, tmp_path) -> None:
    """Three chunks claiming 4 GB (a header length, a data length, an uncompressed size): map
    exits 0 from the other chunks, counting the three's messages lost (the first reason named
    with its byte), and the run's peak memory stays under 1 GB."""
    intact = open_ros1(bags["lz4"])
    first, second, third = (c.pos for c in intact.chunks[2:5])

    def damage(data: bytearray) -> None:
        data[first : first + 4] = b"\xff\xff\xff\xff"  # the header's length
        _, _, data_at = chunk_record(bytes(data), second)
        data[data_at - 4 : data_at] = b"\xff\xff\xff\xff"  # the data's length
        header_at, header_len, _ = chunk_record(bytes(data), third)
        size_at = bytes(data).index(b"size=", header_at, header_at + header_len) + len("size=")
        data[size_at : size_at + 4] = b"\xff\xff\xff\xff"  # the uncompressed size

    bag = damaged_copy(bags["lz4"], tmp_path, "huge.bag", damage)
    done, peak_kb = run_with_peak(
        [sys.executable, "-m", "markergraph.cli", "map", str(bag), "--out", str(tmp_path / "r"),
         "--no-plots"]
    )  # fmt: skip
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
    lost: dict[str, int] = {}
    for pos in (first, second, third):
        for topic, n in lost_per_topic(intact, pos).items():
            lost[topic] = lost.get(topic, 0) + n
    line = f"{bag}: skipped {lost['/odom']} unreadable message(s) on /odom (a record header "
    line += f"claiming 4294967295 bytes at byte {first}; and 2 other places)"  # three chunks
    assert line in done.stderr, done.stderr
    assert peak_kb < MEMORY_LIMIT_KB


# --- what cannot be read is one line with a reason ------------------------------------------


@pytest.mark.slow
def test_unreadable_bags_are_one_line_with_a_reason(bags, tmp_path) -> None:
    """Bags rosbags gave "not a readable bag (AssertionError: )" for, and worse: a damaged index
    data record is read past (its chunk's span stands for its times); a bag whose records are
    all gone is exit 1 from info and map alike, one line naming the file and the byte."""

    def index_data(data: bytearray) -> None:
        pos = open_ros1(bags["lz4"]).chunks[0].pos
        _, _, data_at = chunk_record(bytes(data), pos)
        (data_len,) = struct.unpack_from("<I", data, data_at - 4)
        after = data_at + data_len  # the first index data record, whose layout rosbags asserted
        data[after : after + 4] = struct.pack("<I", 46)  # its header's length (47)

    readable = damaged_copy(bags["lz4"], tmp_path, "index-data.bag", index_data)
    done = run("info", readable)
    assert done.returncode == 0 and "can map: yes" in done.stdout, done.stderr
    assert run("map", readable, "--out", tmp_path / "m", "-q").returncode == 0
    gone = damaged_copy(bags["lz4"], tmp_path, "gone.bag", lambda data: data[:5000])
    for command in ("info", "map"):
        arguments = ["--out", tmp_path / "r"] if command == "map" else []
        done = run(command, gone, *arguments)
        assert done.returncode == 1 and not done.stdout.strip(), (command, done.stderr)
        line = one_line_error(done.stderr, str(gone), "not a readable bag", "at byte 4109")
        assert "Traceback" not in line
    assert not (tmp_path / "r").exists()


def test_a_damaged_sqlite_bag_is_one_line(bags, tmp_path, capsys) -> None:
    """A .db3 with zeroed pages or cut short ("database disk image is malformed"): info and map
    each exit 1 with one line naming the bag, and the folder is left byte-identical."""
    db3 = next(bags["sqlite"].glob("*.db3"))
    data = db3.read_bytes()
    for name, damaged in (("zeroed", data[:40960] + bytes(8192) + data[49152:]),
                          ("cut", data[: len(data) // 2])):  # fmt: skip
        folder = tmp_path / name
        shutil.copytree(bags["sqlite"], folder)
        (folder / db3.name).write_bytes(damaged)
        before = digest(folder)
        codes = []
        for command in ("info", "map"):
            out = tmp_path / f"r-{name}"
            arguments = ["--out", out, "--no-plots"] if command == "map" else []
            code, _, err = cli(capsys, command, folder, *arguments)
            codes.append(code)
            if code == 1:
                one_line_error(err, str(folder), "malformed")
            assert not out.exists() or code == 0
        assert codes in ([1, 1], [0, 0]) and digest(folder) == before, (name, codes)


# --- info and map agree ---------------------------------------------------------------------


def mutate(data: bytes, bag: Ros1Bag, rng: random.Random) -> tuple[str, bytes]:
    """One seeded damage: bytes flipped in a chunk, a cut, a huge length, a zeroed record."""
    changed = bytearray(data)
    kind = rng.choice(["flip", "cut", "huge", "zero"])
    pos = rng.choice(bag.chunks).pos
    if kind == "flip":
        at = pos + rng.randrange(0, 4000)
        for _ in range(rng.randint(1, 8)):
            changed[at + rng.randrange(64)] ^= 1 << rng.randrange(8)
    elif kind == "cut":
        return kind, data[: rng.randrange(len(data))]
    elif kind == "huge":
        _, _, data_at = chunk_record(data, pos)
        at = rng.choice([pos, data_at - 4, 13, 17])
        changed[at : at + 4] = b"\xff\xff\xff\x7f"
    else:
        _, _, data_at = chunk_record(data, pos)
        changed[pos : data_at + 64] = bytes(data_at + 64 - pos)
    return kind, bytes(changed)


@pytest.mark.parametrize("kind", ["lz4", "plain"])
@pytest.mark.slow
def test_info_and_map_agree_on_damaged_bags(bags, kind, tmp_path, capsys) -> None:
    """Seeded damage (flips, cuts, huge lengths, zeroed records): never a traceback; info exits
    1 exactly when map does, with the same single line; "can map: yes" means map succeeds."""
    rng = random.Random(28)
    intact = open_ros1(bags[kind])
    data = bags[kind].read_bytes()
    for case in range(FUZZ_CASES // 2):
        damage, changed = mutate(data, intact, rng)
        bag = tmp_path / f"{case}-{damage}.bag"
        bag.write_bytes(changed)
        info_code, info_out, info_err = cli(capsys, "info", bag)
        map_code, _, map_err = cli(capsys, "map", bag, "--out", tmp_path / f"r{case}", "-q")
        assert "Traceback" not in info_err + map_err
        assert (info_code == 1) == (map_code == 1), (bag.name, info_err, map_err)
        if info_code == 1:
            assert (
                one_line_error(info_err, str(bag)).split(": ", 1)[1]
                == one_line_error(map_err, str(bag)).split(": ", 1)[1]
            )
        if "can map: yes" in info_out:
            assert map_code == 0, (bag.name, map_err)
