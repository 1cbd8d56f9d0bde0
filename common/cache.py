"""markergraph's cache folder: generated sample logs and cached extractions."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["cache_dir"]


def cache_dir() -> Path:
    """``$MARKERGRAPH_CACHE``, else ``$XDG_CACHE_HOME/markergraph`` or ``~/.cache/markergraph``."""
    if "MARKERGRAPH_CACHE" in os.environ:
        return Path(os.environ["MARKERGRAPH_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "markergraph"
