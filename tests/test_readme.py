"""README's and the docs pages' Python examples run as written, on a simulated log where they
name one."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from markergraph.datasets import scenario, write_log

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
PAGES = [README, *sorted((ROOT / "docs").glob("*.md"))]
"""README and the docs pages, whose Python examples all run here."""


def python_blocks() -> list[tuple[Path, str]]:
    """Every python block of README and docs/*.md, with the page it is on."""
    return [
        (page, block)
        for page in PAGES
        for block in re.findall(r"```python\n(.*?)```", page.read_text(), flags=re.DOTALL)
    ]


@pytest.mark.slow
def test_readme_python_examples_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every python block of README and docs/*.md runs; the main-job example maps robot.mcap
    (20 s of the paper room) and the map.json it writes loads back with the markers the run
    placed."""
    world, route = scenario("paper-room")
    write_log(world, route, tmp_path / "robot.mcap", seed=5, duration_s=20.0, compressed=True,
              frame_hz=5.0)  # fmt: skip
    monkeypatch.chdir(tmp_path)
    blocks = python_blocks()
    assert len(blocks) >= 2 and any(page != README for page, _ in blocks)
    namespaces = []
    for page, block in blocks:
        namespace: dict[str, object] = {}
        exec(compile(block, str(page), "exec"), namespace)
        namespaces.append(namespace)
    main_job = next(n for n in namespaces if "marker_map" in n)
    result: object = main_job["result"]
    first = result.results[0]  # type: ignore[attr-defined]
    loaded = main_job["marker_map"]
    assert set(loaded.markers) == set(first.marker_map.markers) == {0, 1, 2}  # type: ignore[attr-defined]
    assert (tmp_path / "robot-map" / "report.json").is_file()
