"""The notebooks' figures kept as PNG files, not only shown: in ``$MARKERGRAPH_FIGURES`` when it
is set, else beside the notebook when it runs as a script (``python notebooks/walkthrough.py``
writes ``notebooks/figures/walkthrough-*.png``). In Jupyter without the variable they are only
shown, as any notebook's are.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from markergraph.common.files import written_whole

__all__ = ["FIGURES_ENV", "NotebookFigures"]

FIGURES_ENV = "MARKERGRAPH_FIGURES"
FIGURE_DPI = 150  # sharper than the screen's 100 dpi, small enough to mail


@dataclass(frozen=True, slots=True)
class NotebookFigures:
    """Where one notebook's figures go.

    Attributes:
        notebook: the notebook's name (its file's stem); each figure's file starts with it.
        folder: where the PNG files are written; None to only show the figures.
    """

    notebook: str
    folder: Path | None

    @classmethod
    def of(cls, notebook: str) -> NotebookFigures:
        """The folder for ``notebook``: ``$MARKERGRAPH_FIGURES`` if set; else ``figures/``
        beside the notebook when it runs as a script (``sys.argv[0]`` is its file); else none
        (a Jupyter kernel, whose ``sys.argv[0]`` is the kernel's launcher).

        Args:
            notebook: the notebook's file stem, such as ``"drift_comparison"``.
        """
        configured = os.environ.get(FIGURES_ENV, "").strip()
        if configured:
            # absolute now: the walkthrough changes its working folder later
            return cls(notebook, Path(configured).expanduser().resolve())
        script = Path(sys.argv[0]) if sys.argv and sys.argv[0] else None
        if script is not None and script.suffix == ".py" and script.stem == notebook:
            return cls(notebook, script.resolve().parent / "figures")
        return cls(notebook, None)

    def path(self, name: str) -> Path | None:
        """The file figure ``name`` is saved to (``<folder>/<notebook>-<name>.png``)."""
        if not name or any(c in name for c in "/\\") or name.startswith("."):
            raise ValueError(f"figure name {name!r} must be a plain file name without a folder")
        return None if self.folder is None else self.folder / f"{self.notebook}-{name}.png"

    def show(self, fig: Any, name: str) -> Path | None:
        """Save ``fig`` (a matplotlib figure) when there is a folder, then show it as
        ``plt.show()`` does and close it, so a script does not pile up open figures.

        Args:
            fig: the figure.
            name: a short file-name-safe name for it, unique within the notebook.

        Returns:
            The PNG file written, or None when the figure was only shown.
        """
        import matplotlib.pyplot as plt

        path = self.path(name)
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            with written_whole(path) as partial:
                fig.savefig(partial, format="png", dpi=FIGURE_DPI, bbox_inches="tight")
            print(f"figure saved: {path}")
        plt.show()
        plt.close(fig)
        return path
