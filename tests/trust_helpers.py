"""What the trust tests share: a folder's bytes fingerprinted, the command run in this process,
a refusal checked to be one line that names what it should and gives a reason, strict JSON."""

from __future__ import annotations

import hashlib
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from markergraph.cli import main


def snapshot(folder: Path) -> dict[str, str]:
    """Every file under ``folder`` (hidden ones included) -> the hash of its bytes."""
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def cli(capsys: pytest.CaptureFixture[str], *arguments: object) -> tuple[int, str, str]:
    """The ``markergraph`` command in this process: (exit code, stdout, stderr); a usage
    mistake's ``SystemExit`` gives its code."""
    try:
        code = main([str(a) for a in arguments])
    except SystemExit as stop:
        code = int(stop.code or 0)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def one_line_error(err: str, *names: str) -> str:
    """The single stderr line of a refused command, checked to name each of ``names``, to give
    a reason (never the empty one of a bare ``AssertionError``) and not to be a bug of ours."""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    for name in names:
        assert name in lines[0], (name, lines[0])
    assert not re.search(r"\w+Error: ?\)|\(\)", lines[0]), lines[0]
    assert "internal error" not in lines[0] and "Traceback" not in err
    return lines[0]


def strict_json(path: Path) -> Any:
    """A JSON file parsed with NaN and infinities refused, as any strict reader does."""

    def refuse(name: str) -> None:
        raise AssertionError(f"{path} holds {name}")

    return json.loads(path.read_text(), parse_constant=refuse)


# Linux keeps a process's peak memory across exec, and a child spawned by vfork (as subprocess
# does) starts from its parent's peak: a command run straight from pytest reports pytest's own
# high-water mark (1.08 GB late in the suite). A small Python process in between starts the
# command instead and hands back the command's own peak.
_PEAK_SHIM = """
import os, subprocess, sys
process = subprocess.Popen(sys.argv[2:])
_, status, usage = os.wait4(process.pid, 0)
with open(sys.argv[1], "w") as peak:
    peak.write(str(usage.ru_maxrss))
sys.exit(os.waitstatus_to_exitcode(status) % 256)
"""


def run_with_peak(
    command: list[str], timeout_s: float | None = None
) -> tuple[subprocess.CompletedProcess[str], int]:
    """A command in a process of its own, and that command's own peak memory [kB], its reaped
    children included."""
    with tempfile.TemporaryDirectory() as folder:
        peak = Path(folder) / "peak"
        shim = [sys.executable, "-c", _PEAK_SHIM, str(peak)]
        run = subprocess.run(
            shim + command, capture_output=True, text=True, check=False, timeout=timeout_s
        )
        done = subprocess.CompletedProcess(command, run.returncode, run.stdout, run.stderr)
        return done, int(peak.read_text())


def as_sqlite_bag(mcap: Path, folder: Path) -> None:
    """The same messages (their CDR bytes as recorded) in a rosbag2 folder stored in SQLite."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    with open(mcap, "rb") as stream, Writer(folder, version=8) as writer:
        connections: dict[str, Any] = {}
        for schema, channel, message in make_reader(stream).iter_messages():
            if channel.topic not in connections:
                connections[channel.topic] = writer.add_connection(
                    channel.topic, schema.name, typestore=store
                )
            writer.write(connections[channel.topic], message.log_time, message.data)
