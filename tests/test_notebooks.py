"""Every notebook in notebooks/ (jupytext percent files) executes top to bottom, shows plots
and saves each as a PNG file, in Jupyter and as a script."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import jupytext
import pytest
from nbclient import NotebookClient

from markergraph.notebook_figures import FIGURES_ENV, NotebookFigures

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.py"))
MIN_FIGURE_BYTES = 5_000  # a matplotlib figure with axes and labels is tens of kB
FAST_NOTEBOOK = "paper_closed_forms"  # a few seconds as a script


def saved_figures(folder: Path, notebook: str) -> list[Path]:
    """The notebook's PNG files in ``folder``, each checked to be an image worth looking at."""
    paths = sorted(folder.glob(f"{notebook}-*.png"))
    for path in paths:
        assert path.stat().st_size > MIN_FIGURE_BYTES, path
        image = cv2.imread(str(path))
        assert image is not None and min(image.shape[:2]) > 100, path
    return paths


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
@pytest.mark.slow
def test_notebook_executes(path: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The notebook runs in a fresh kernel without an error, renders its figures and saves
    every figure it shows to $MARKERGRAPH_FIGURES as a PNG file."""
    # A headless MPLBACKEND (Agg) would reach the kernel and silently drop every figure.
    monkeypatch.delenv("MPLBACKEND", raising=False)
    figures = tmp_path / "figures"
    monkeypatch.setenv(FIGURES_ENV, str(figures))  # the kernel inherits the environment
    notebook = jupytext.read(path)
    client = NotebookClient(
        notebook,
        timeout=600,
        kernel_name="python3",
        resources={"metadata": {"path": str(tmp_path)}},
    )
    client.execute()
    outputs = [output for cell in notebook.cells for output in cell.get("outputs", [])]
    assert not [o for o in outputs if o.get("output_type") == "error"]
    shown = [o for o in outputs if "image/png" in o.get("data", {})]
    assert shown, "no figure was rendered"
    assert len(saved_figures(figures, path.stem)) == len(shown)


@pytest.mark.slow
def test_notebook_as_a_script_saves_its_figures_beside_it(tmp_path: Path) -> None:
    """`python notebook.py` with no $MARKERGRAPH_FIGURES writes its figures to figures/ beside
    the notebook's file."""
    script = tmp_path / f"{FAST_NOTEBOOK}.py"
    shutil.copy(next(p for p in NOTEBOOKS if p.stem == FAST_NOTEBOOK), script)
    environment = {k: v for k, v in os.environ.items() if k not in (FIGURES_ENV, "MPLBACKEND")}
    run = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, env=environment,
        cwd=tmp_path, timeout=600,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    saved = saved_figures(tmp_path / "figures", FAST_NOTEBOOK)
    assert len(saved) == script.read_text().count("figures.show(")
    assert all(f"figure saved: {path}" in run.stdout for path in saved)


def test_figures_are_only_shown_in_jupyter_without_the_variable(monkeypatch) -> None:
    """In a kernel (argv[0] is its launcher) and with no variable, nothing is written; a figure
    name with a folder in it is refused."""
    monkeypatch.delenv(FIGURES_ENV, raising=False)
    monkeypatch.setattr(sys, "argv", ["/venv/lib/ipykernel_launcher.py", "-f", "kernel.json"])
    figures = NotebookFigures.of("walkthrough")
    assert figures.folder is None and figures.path("map") is None
    with pytest.raises(ValueError, match="plain file name"):
        NotebookFigures("walkthrough", Path("out")).path("../map")
