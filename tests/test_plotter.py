"""Figures drawn in a process of their own (markergraph.plotter): the same folder as drawn in the
command's process, byte for byte where matplotlib is deterministic (PNG), a figure's error
raised in the command, and a plotter whose process dies still delivers every figure."""

from __future__ import annotations

import json
import operator
from pathlib import Path

import pytest

import markergraph.results
from markergraph.common.pool import available_cores
from markergraph.plotter import Plotter
from markergraph.records import MapRun
from markergraph.results import write_results
from markergraph.run import map_logs

BAD_FIGURE = "no such marker"
# The "figures" below are functions the plotter's process can import by name, as it does ours.
FIGURE = Path.write_text
TWO_CORES = pytest.mark.skipif(available_cores() < 2, reason="a plotter draws here on one core")


@pytest.fixture(scope="module")
def run(log: Path) -> MapRun:
    return map_logs([log])


@TWO_CORES
@pytest.mark.slow
def test_a_plotters_folder_is_the_one_drawn_here(run: MapRun, tmp_path: Path) -> None:
    write_results(run, tmp_path / "here")
    with Plotter.start() as plotter:
        assert plotter._process is not None
        write_results(run, tmp_path / "there", plotter=plotter)
        write_results(run, tmp_path / "again", plotter=plotter)  # a plotter serves many folders
    here, there, again = (
        sorted(p.relative_to(tmp_path / name) for p in (tmp_path / name).rglob("*"))
        for name in ("here", "there", "again")
    )
    assert here == there == again
    assert {"map.png", "map.svg", "diagnostics.png"} <= {str(p) for p in there}
    for name in ("map.png", "diagnostics.png"):
        assert (tmp_path / "here" / name).read_bytes() == (tmp_path / "there" / name).read_bytes()
    manifests = [
        json.loads((tmp_path / name / "report.json").read_text())["files"]
        for name in ("here", "there", "again")
    ]
    assert manifests[0] == manifests[1] == manifests[2]


@TWO_CORES
def test_a_figures_error_is_raised_in_the_command(tmp_path: Path) -> None:
    with Plotter.start() as plotter:
        plotter.draw(FIGURE, tmp_path / "a.txt", "a")
        plotter.draw(operator.getitem, {}, BAD_FIGURE)
        with pytest.raises(KeyError, match=BAD_FIGURE):
            plotter.finish()
    assert (tmp_path / "a.txt").read_text() == "a"


@TWO_CORES
def test_figures_a_dead_plotter_did_not_draw_are_drawn_here(tmp_path: Path) -> None:
    with Plotter.start() as plotter:
        assert plotter._process is not None
        plotter.draw(FIGURE, tmp_path / "a.txt", "a")
        plotter.finish()
        plotter._process.kill()
        plotter._process.join()
        plotter.draw(FIGURE, tmp_path / "b.txt", "b")
        plotter.draw(FIGURE, tmp_path / "c.txt", "c")
        plotter.finish()
    assert [(tmp_path / n).read_text() for n in ("a.txt", "b.txt", "c.txt")] == ["a", "b", "c"]


@TWO_CORES
@pytest.mark.slow
def test_an_error_while_writing_stops_the_plotter_before_the_folder_goes(
    run: MapRun, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The figures are being drawn into the folder being written when writing fails: the
    plotter's process is ended first, so the folder goes whole and nothing is left behind."""

    def fail(*args: object, **kwargs: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(markergraph.results, "write_overlay", fail)
    with Plotter.start() as plotter:
        with pytest.raises(OSError, match="disk full"):
            write_results(run, tmp_path / "out", plotter=plotter)
        assert plotter._process is None
    assert list(tmp_path.iterdir()) == []


@TWO_CORES
def test_a_figure_that_cannot_be_sent_is_drawn_here(tmp_path: Path) -> None:
    with Plotter.start() as plotter:
        plotter.draw(lambda: (tmp_path / "a.txt").write_text("a"))  # a lambda does not pickle
        plotter.finish()
        assert (tmp_path / "a.txt").read_text() == "a"
        assert plotter._process is not None  # the process still serves the next figure
