"""What the trust tests share: a folder's bytes fingerprinted, the command run in this process,
a refusal checked to be one line that names what it should and gives a reason, strict JSON."""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path
from typing import Any

import pytest

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
