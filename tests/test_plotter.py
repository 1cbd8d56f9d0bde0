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
from markergraph.settings import MapConfig

BAD_FIGURE = "no such marker"
# The "figures" below are functions the plotter's process can import by name, as it does ours.
FIGURE = Path.write_text
TWO_CORES = pytest.mark.skipif(available_cores() < 2, reason="a plotter draws here on one core")


@pytest.fixture(scope="module")
def run(log: Path) -> MapRun:
    return map_logs([log])


@pytest.fixture(scope="module")
def every_method(log: Path) -> MapRun:
    return map_logs([log], MapConfig.from_values({"method": "all"}))


@TWO_CORES
@pytest.mark.slow
@pytest.mark.parametrize("processes", [1, 2])
def test_a_plotters_folder_is_the_one_drawn_here(
    run: MapRun, every_method: MapRun, processes: int, tmp_path: Path
) -> None:
    """One method's folder and every method's (its comparison and a map copied under methods/)
    drawn by one or two processes: the files drawn here, PNGs byte for byte."""
    one, several = tmp_path / "one", tmp_path / "several"
    write_results(run, one / "here")
    write_results(every_method, several / "here")
    with Plotter.start(processes) as plotter:
        assert len(plotter._processes) == processes
        write_results(run, one / "there", plotter=plotter)
        write_results(run, one / "again", plotter=plotter)  # a plotter serves many folders
        write_results(every_method, several / "there", plotter=plotter)
    for top, names in ((one, ("here", "there", "again")), (several, ("here", "there"))):
        listed = [sorted(p.relative_to(top / n) for p in (top / n).rglob("*")) for n in names]
        assert all(files == listed[0] for files in listed)
        pngs = [p for p in listed[0] if p.suffix == ".png"]
        for png in pngs:
            assert (top / "here" / png).read_bytes() == (top / "there" / png).read_bytes(), png
        manifests = [json.loads((top / n / "report.json").read_text())["files"] for n in names]
        assert all(m == manifests[0] for m in manifests)
    drawn = {str(p.relative_to(one / "there")) for p in (one / "there").rglob("*.png")}
    assert drawn == {"map.png", "diagnostics.png"}
    shown = {str(p.relative_to(several / "there")) for p in (several / "there").rglob("*.png")}
    assert {"comparison.png", "methods/slam/map.png", "methods/ekf/map.png"} <= shown
    copied = several / "there" / "methods" / "slam" / "map.png"
    assert copied.read_bytes() == (several / "there" / "map.png").read_bytes()


@TWO_CORES
def test_a_figures_error_is_raised_in_the_command(tmp_path: Path) -> None:
    with Plotter.start() as plotter:
        plotter.draw(FIGURE, tmp_path / "a.txt", "a")
        plotter.draw(operator.getitem, {}, BAD_FIGURE)
        with pytest.raises(KeyError, match=BAD_FIGURE):
            plotter.finish()
    assert (tmp_path / "a.txt").read_text() == "a"


@TWO_CORES
@pytest.mark.parametrize("processes", [1, 2])
def test_figures_a_dead_plotter_did_not_draw_are_drawn_here(processes: int, tmp_path: Path) -> None:
    """One of the plotter's processes dies (the other, if any, lives on): every figure asked for
    after it is still drawn, by the other or here."""
    with Plotter.start(processes) as plotter:
        plotter.draw(FIGURE, tmp_path / "a.txt", "a")
        plotter.finish()
        plotter._processes[0].kill()
        plotter._processes[0].join()
        for name in "bcdef":
            plotter.draw(FIGURE, tmp_path / f"{name}.txt", name)
        plotter.finish()
    assert [(tmp_path / f"{n}.txt").read_text() for n in "abcdef"] == list("abcdef")


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
        assert plotter._processes == []
    assert list(tmp_path.iterdir()) == []


@TWO_CORES
def test_a_figure_that_cannot_be_sent_is_drawn_here(tmp_path: Path) -> None:
    with Plotter.start() as plotter:
        plotter.draw(lambda: (tmp_path / "a.txt").write_text("a"))  # a lambda does not pickle
        plotter.finish()
        assert (tmp_path / "a.txt").read_text() == "a"
        assert plotter._processes  # the process still serves the next figure
