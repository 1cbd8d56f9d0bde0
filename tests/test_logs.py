"""A log opened once (:func:`open_log`): its kind and files decided, each MCAP summary read once
and kept, its topics, time range and messages read through the one handle, which pickles as
its path."""

from __future__ import annotations

import pickle
from pathlib import Path
from unittest import mock

import pytest
from mcap_ros2.writer import Writer

from markergraph.frontend import Log, LogError, open_log
from markergraph.frontend.logs import DecodeFailures, LogKind, chunks, mcap
from markergraph.frontend.ros2 import MESSAGE_DEFINITIONS

STRING = "std_msgs/msg/String"
T0_NS = 1_750_000_000_000_000_000
STEP_NS = 100_000_000
METADATA = """rosbag2_bagfile_information:
  relative_file_paths: [bag_0.mcap, bag_1.mcap]
"""


def write_strings(path: Path, n: int, first: int = 0) -> None:
    """``n`` std_msgs/String messages on /chatter, one every 0.1 s from message ``first``."""
    with open(path, "wb") as stream:
        writer = Writer(stream, chunk_size=256)  # small chunks: several per file
        schema = writer.register_msgdef(STRING, MESSAGE_DEFINITIONS[STRING])
        for i in range(first, first + n):
            t_ns = T0_NS + i * STEP_NS
            writer.write_message("/chatter", schema, {"data": str(i)}, t_ns, t_ns)
        writer.finish()


def test_one_file_is_read_through_its_summary_read_once(tmp_path: Path) -> None:
    """Topics, time range, topic times and two readings of the messages parse no summary
    beyond the one read when the log was opened."""
    path = tmp_path / "chatter.mcap"
    write_strings(path, 20)
    with (
        mock.patch.object(mcap, "read_summary", wraps=mcap.read_summary) as opened,
        mock.patch.object(chunks, "read_summary", wraps=chunks.read_summary) as read,
    ):
        log = open_log(path)
        assert opened.call_count == 1
        assert log.kind is LogKind.MCAP and log.files == (path,)
        assert [(t.topic, t.schema, t.count) for t in log.topics] == [("/chatter", STRING, 20)]
        assert log.time_range == (T0_NS, T0_NS + 19 * STEP_NS)
        assert log.topic_times == {"/chatter": log.time_range}
        assert [m.decoded.data for m in log.messages(["/chatter"])] == [str(i) for i in range(20)]
        late = list(log.messages(["/chatter"], start_ns=T0_NS + 15 * STEP_NS))
        assert [m.decoded.data for m in late] == [str(i) for i in range(15, 20)]
        assert opened.call_count == 1 and read.call_count == 0


def test_a_folder_of_files_is_one_log(tmp_path: Path) -> None:
    """A rosbag2 folder without metadata.yaml: its .mcap files in name order, counts summed,
    the time range over both, messages file after file."""
    folder = tmp_path / "bag"
    folder.mkdir()
    write_strings(folder / "bag_0.mcap", 5)
    write_strings(folder / "bag_1.mcap", 7, first=5)
    log = open_log(folder)
    assert log.files == (folder / "bag_0.mcap", folder / "bag_1.mcap")
    assert [t.count for t in log.topics] == [12]
    assert log.time_range == (T0_NS, T0_NS + 11 * STEP_NS)
    assert [m.decoded.data for m in log.messages(["/chatter"])] == [str(i) for i in range(12)]
    # Nothing says the files belong together: joining them is said, where a reading counts.
    failures = DecodeFailures()
    assert len(list(log.messages(["/chatter"], failures))) == 12
    joined = f"{folder}: no metadata.yaml: its 2 .mcap files (bag_0.mcap, bag_1.mcap) read as one"
    assert failures.warnings()[0].startswith(joined) and log.notes[0].startswith(joined)
    (folder / "old-map.mcap").mkdir()  # a folder so named (a result folder) is no file of it
    assert open_log(folder).files == log.files
    (folder / "metadata.yaml").write_text(METADATA)
    assert open_log(folder).notes == []


def test_a_log_pickles_as_its_path(tmp_path: Path) -> None:
    """A worker given a Log opens the log itself: the pickle holds the path, not the file."""
    path = tmp_path / "chatter.mcap"
    write_strings(path, 3)
    log = open_log(path)
    data = pickle.dumps(log)
    assert len(data) < 500
    again = pickle.loads(data)
    assert isinstance(again, Log) and again is not log
    assert again.path == path and again.topics == log.topics


def test_what_is_not_a_log_fails_when_opened(tmp_path: Path) -> None:
    """No such path, or a file that is not MCAP: one LogError naming it, from open_log."""
    with pytest.raises(LogError, match="no such file or folder"):
        open_log(tmp_path / "missing.mcap")
    text = tmp_path / "notes.txt"
    text.write_text("not a log")
    with pytest.raises(LogError, match=f"{text}: not an MCAP file"):
        open_log(text)
