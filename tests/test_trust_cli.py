"""Trust at the command line's edges: where --out may go, usage mistakes, signals at any moment,
--force over a protected result, absurd --at values and compressed logs: one line each, the
right exit code, the user's files byte-identical and no hidden folder left behind."""

from __future__ import annotations

import bz2
import gzip
import lzma
import os
import shutil
import signal
import subprocess
import sys
import tarfile
import time
import zipfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from trust_helpers import cli, one_line_error, snapshot

from markergraph.cli import main

START_TIMEOUT_S = 120.0  # a loaded 2-core CI machine takes seconds to start a run
END_TIMEOUT_S = 120.0
POLL_S = 0.005
CLI = [sys.executable, "-m", "markergraph.cli"]


# --- helpers ---------------------------------------------------------------------------------


def hidden(folder: Path) -> list[str]:
    """Temporary entries (``.NAME.partial-...``, ``.NAME.old-...``) in ``folder``."""
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def wait_for(condition: Callable[[], bool], run: subprocess.Popen[str], what: str) -> None:
    """Poll until ``condition`` holds, failing if the run ended first or it took too long."""
    deadline = time.monotonic() + START_TIMEOUT_S
    while not condition():
        assert run.poll() is None, f"the run ended before {what}: {run.communicate()}"
        assert time.monotonic() < deadline, f"no {what} within {START_TIMEOUT_S} s"
        time.sleep(POLL_S)


def catches(pid: int, signum: int) -> bool:
    """Whether process ``pid`` has a handler for ``signum`` (Linux's /proc status mask)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    for line in status.splitlines():
        if line.startswith("SigCgt:"):
            return bool(int(line.split()[1], 16) >> (signum - 1) & 1)
    return False


@pytest.fixture(scope="module")
def result(log: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A result folder of ``log`` (no plots), mapped once; copy it, never change it."""
    out = tmp_path_factory.mktemp("result") / "result"
    code = main(["map", str(log), "--out", str(out), "--no-plots", "-q"])
    assert code == 0
    return out


# --- where --out may go -----------------------------------------------------------------------


def test_no_writer_puts_its_output_inside_a_rosbag2_folder(log, result, tmp_path, capsys):
    """map and localize --out inside a rosbag2 folder that is not an input (or a subfolder of
    one), like detect and simulate, are refused in one line naming the bag; nothing changes."""
    bag = tmp_path / "bag"
    bag.mkdir()
    shutil.copyfile(log, bag / "a_0.mcap")
    (bag / "metadata.yaml").write_text(
        "rosbag2_bagfile_information:\n  relative_file_paths:\n    - a_0.mcap\n"
    )
    before = snapshot(tmp_path)
    for arguments in (
        ("map", log, "--out", bag / "result", "--no-plots"),
        ("map", log, "--out", bag / "deeper" / "result", "--no-plots"),
        ("localize", log, "--map", result / "map.json", "--out", bag / "where"),
        ("detect", log, "--out", bag / "obs.jsonl"),
        ("simulate", "--scenario", "paper-room", "--out", bag / "deeper" / "x.mcap"),
    ):
        code, stdout, err = cli(capsys, *arguments)
        assert code == 1, (arguments, stdout, err)
        one_line_error(err, str(bag), "rosbag2")
    assert snapshot(tmp_path) == before
    assert sorted(p.name for p in bag.iterdir()) == ["a_0.mcap", "metadata.yaml"]


# --- usage mistakes ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("arguments", "prog", "words"),
    [
        (["map", "--executor", "bad"], "markergraph map", "'bad'"),
        (["map", "--no-such-flag"], "markergraph map", "--no-such-flag"),
        (["map", "--out"], "markergraph map", "--out"),
        (["heading", "m.json", "--from", "x", "--at", "1,0", "--to", "1"], "markergraph heading",
         "'x'"),
        (["heading"], "markergraph heading", "--at"),
        (["no-such-command"], "markergraph", "no-such-command"),
    ],
)  # fmt: skip
def test_usage_mistakes_are_one_line_and_exit_1(capsys, arguments, prog, words) -> None:
    """argparse's mistakes: one line `PROG: error: ...` naming the flag or value and where help
    is, no usage block, exit 1 (README: 1 for the user's mistakes, 2 only for a bug of ours)."""
    code, stdout, err = cli(capsys, *arguments)
    assert code == 1 and not stdout
    line = one_line_error(err, words, f"{prog} --help")
    assert line.startswith(f"{prog}: error: ")


# --- signals ----------------------------------------------------------------------------------


def test_ctrl_c_while_the_command_starts_is_one_line(log: Path, tmp_path: Path) -> None:
    """SIGINT as soon as the command's handlers are in place, during its second of imports:
    exit 130, the one line `markergraph: interrupted`, no traceback, nothing written."""
    out = tmp_path / "result"
    run = subprocess.Popen([*CLI, "map", str(log), "--out", str(out)], text=True,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE)  # fmt: skip
    # Python catches SIGINT from its start, SIGTERM only once markergraph's handlers are set.
    wait_for(lambda: catches(run.pid, signal.SIGTERM), run, "the signal handlers")
    run.send_signal(signal.SIGINT)
    stdout, err = run.communicate(timeout=END_TIMEOUT_S)
    assert run.returncode == 130, err
    assert err == "markergraph: interrupted\n" and not stdout
    assert list(tmp_path.iterdir()) == []


def test_sigterm_while_simulate_writes_leaves_nothing(tmp_path: Path) -> None:
    """SIGTERM while simulate writes: exit 143, one line, no `.NAME.partial-...` file left."""
    out = tmp_path / "long.mcap"
    run = subprocess.Popen(
        [*CLI, "simulate", "--scenario", "corridor-loop", "--out", str(out), "--compressed",
         "--duration", "300"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    wait_for(lambda: bool(list(tmp_path.glob(".long.mcap.partial-*"))), run, "its partial file")
    run.send_signal(signal.SIGTERM)
    _, err = run.communicate(timeout=END_TIMEOUT_S)
    assert run.returncode == 143, err
    one_line_error(err, "markergraph simulate", "terminated", "SIGTERM")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("signum", "code", "word"),
    [(signal.SIGTERM, 143, "terminated"), (signal.SIGINT, 130, "interrupted")],
)
@pytest.mark.slow
def test_a_signal_while_the_result_folder_is_written_keeps_the_old_one(
    log: Path, result: Path, tmp_path: Path, signum: int, code: int, word: str
) -> None:
    """SIGTERM or SIGINT while map --force writes its folder (plots take a while): exit 143 or
    130, one line, the old result byte-identical and no hidden folder beside it."""
    out = tmp_path / "result"
    shutil.copytree(result, out)
    before = snapshot(tmp_path)
    run = subprocess.Popen([*CLI, "map", str(log), "--out", str(out), "--force"], text=True,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE)  # fmt: skip
    wait_for(lambda: bool(list(tmp_path.glob(".result.partial-*"))), run, "its partial folder")
    run.send_signal(signum)
    _, err = run.communicate(timeout=END_TIMEOUT_S)
    assert run.returncode == code, err
    line = err.strip().splitlines()[-1]  # after the run's own notes
    assert line == f"markergraph map: {word}" + (" (SIGTERM)" if code == 143 else ""), err
    assert "Traceback" not in err
    assert snapshot(tmp_path) == before and hidden(tmp_path) == []


# --- --force over a protected result ----------------------------------------------------------


@contextmanager
def write_protected(path: Path) -> Iterator[None]:
    """``path`` protected from deletion while the block runs: ``chmod a-w`` for a user, and
    for root, whom modes do not stop, ``chattr +i`` (skipped where the file system lacks it)."""
    if os.geteuid() != 0:
        mode = path.stat().st_mode
        path.chmod(mode & ~0o222)
        try:
            yield
        finally:
            path.chmod(mode)
        return
    chattr = shutil.which("chattr")
    if chattr is None or subprocess.run([chattr, "+i", str(path)], capture_output=True).returncode:
        pytest.skip("root, and no chattr +i here to protect a file from root")
    try:
        yield
    finally:
        subprocess.run([chattr, "-i", str(path)], check=True)


@pytest.mark.parametrize("protected", ["map.json", "."])
def test_force_over_a_protected_result_is_refused_whole(log, result, tmp_path, capsys, protected):
    """map --force over a result with a write-protected file, or itself write-protected: one
    line naming it, exit 1, before any work; the old result byte-identical, nothing hidden."""
    out = tmp_path / "result"
    shutil.copytree(result, out)
    before = snapshot(tmp_path)
    with write_protected(out / protected):
        code, stdout, err = cli(capsys, "map", log, "--out", out, "--force", "--no-plots")
        assert code == 1 and not stdout
        one_line_error(err, str(out), "write-protected")
        assert hidden(tmp_path) == []
    assert snapshot(tmp_path) == before


def test_an_old_result_that_will_not_go_is_named(log, result, tmp_path, capsys, monkeypatch):
    """If the old result cannot be deleted after all (protected between the check and the
    replacement), the line names where it was moved: nothing is left hidden without a word."""
    from markergraph.common import files

    out = tmp_path / "result"
    shutil.copytree(result, out)
    monkeypatch.setattr(files, "_write_protected", lambda _folder: None)  # the check passed
    with write_protected(out / "map.json"):
        code, _, err = cli(capsys, "map", log, "--out", out, "--force", "--no-plots", "-q")
        left = hidden(tmp_path)
        assert code == 1 and len(left) == 1 and left[0].startswith(".result.old-")
        one_line_error(err, str(tmp_path / left[0]), "delete it yourself")
    assert (out / "report.json").is_file()  # the new result is in place


# --- heading --at -----------------------------------------------------------------------------


@pytest.mark.parametrize("at", ["1e300,1e300", "nan,0", "inf,0", "1e7,0", "0,10", "-0.5,10",
                                "2,inf", "2,nan", "2,95", "2,-90"])  # fmt: skip
def test_heading_refuses_absurd_at(result: Path, capsys, at: str) -> None:
    """heading --at with a non-finite, absurd (beyond 1 km, a marker seen from behind) or
    non-positive value: one line naming --at and the value, exit 1, nothing on stdout."""
    code, stdout, err = cli(capsys, "heading", result / "map.json", "--from", "0", f"--at={at}",
                            "--to", "1")  # fmt: skip
    assert code == 1 and not stdout
    one_line_error(err, "--at", at)


def test_heading_takes_a_sensible_at(result: Path, capsys) -> None:
    """A sensible --at still gives a finite turn and distance."""
    code, stdout, err = cli(capsys, "heading", result / "map.json", "--from", "0", "--at",
                            "1.5,20", "--to", "1")  # fmt: skip
    assert code == 0, err
    assert "inf" not in stdout and "nan" not in stdout and " m to marker 1" in stdout


# --- compressed logs --------------------------------------------------------------------------


def _tar(data: bytes, path: Path) -> None:
    source = path.with_name("room.mcap")
    source.write_bytes(data)
    with tarfile.open(path, "w") as archive:
        archive.add(source, arcname="room.mcap")
    source.unlink()


def _zip(data: bytes, path: Path) -> None:
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("room.mcap", data)


def _zstd(data: bytes) -> bytes:
    zstandard = pytest.importorskip("zstandard")
    return bytes(zstandard.ZstdCompressor().compress(data))


PACKERS: dict[str, tuple[str, Callable[[bytes, Path], None]]] = {
    "room.mcap.gz": ("gunzip -k", lambda d, p: p.write_bytes(gzip.compress(d))),
    "room.bag.bz2": ("bunzip2 -k", lambda d, p: p.write_bytes(bz2.compress(d))),
    "room.mcap.xz": ("unxz -k", lambda d, p: p.write_bytes(lzma.compress(d))),
    "room.mcap.zst": ("unzstd", lambda d, p: p.write_bytes(_zstd(d))),
    "room.zip": ("unzip", _zip),
    "room.tar": ("tar -xf", _tar),
}


@pytest.mark.parametrize("name", sorted(PACKERS))
def test_a_compressed_log_says_how_to_unpack_it(log: Path, tmp_path: Path, capsys, name) -> None:
    """A log compressed or archived whole: map and info say so in one line naming the file
    and the command that unpacks it (not "not an MCAP file"), exit 1, the file untouched."""
    undo, pack = PACKERS[name]
    packed = tmp_path / name
    pack(log.read_bytes()[:65536], packed)  # the container is the point, not the whole log
    before = snapshot(tmp_path)
    for command in (["map", packed, "--out", tmp_path / "out"], ["info", packed]):
        code, _, err = cli(capsys, *command)
        assert code == 1, err
        one_line_error(err, str(packed), f"{undo} {packed}")
    assert snapshot(tmp_path) == before


def test_a_rosbag2_folder_of_compressed_files_says_so(log: Path, tmp_path: Path, capsys) -> None:
    """A rosbag2 folder recorded with file compression (its .mcap.zstd files): one line naming
    the file and how to decompress it."""
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "a_0.mcap.zstd").write_bytes(_zstd(log.read_bytes()[:65536]))
    (bag / "metadata.yaml").write_text(
        "rosbag2_bagfile_information:\n  relative_file_paths:\n    - a_0.mcap.zstd\n"
    )
    code, _, err = cli(capsys, "info", bag)
    assert code == 1, err
    one_line_error(err, str(bag / "a_0.mcap.zstd"), "zstd", "unzstd")


def test_a_reader_that_leaves_early_ends_the_command_quietly(result: Path) -> None:
    """`markergraph export ... --out - | head` with the reader gone before the first line: no
    "[Errno 32] Broken pipe" on stderr, exit 141 (128 + SIGPIPE), as a shell tool ends."""
    run = subprocess.Popen(
        [sys.executable, "-m", "markergraph.cli", "export", str(result / "map.json"),
         "--format", "csv", "--out", "-"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert run.stdout is not None and run.stderr is not None
    run.stdout.close()  # long before the command's imports are done and it writes
    error = run.stderr.read()
    assert run.wait(timeout=60) == 128 + signal.SIGPIPE and error == "", error
