"""The bundled sample logs: generated deterministically on first use into a cache folder.

The logs are too large for the repository (hundreds of MB of images), so the first call renders
them once, with a progress bar, into ``$MARKERGRAPH_CACHE`` (default
``$XDG_CACHE_HOME/markergraph`` or ``~/.cache/markergraph``) and later calls reuse the file.
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

from markergraph.common.cache import cache_dir
from markergraph.common.progress import ProgressBar
from markergraph.datasets.scenarios import scenario
from markergraph.datasets.write import write_log

__all__ = ["SAMPLES", "sample_log", "sample_path"]

# name -> (scenario, seed, laps, frame rate [Hz]); bump the version when the output changes.
SAMPLES = {
    "paper-room": ("paper-room", 1, 3, 5.0),
    "corridor-loop": ("corridor-loop", 1, 1, 5.0),
}
SAMPLE_VERSION = 1


def sample_path(name: str) -> Path:
    """Where a sample log lives in the cache (whether or not it has been generated)."""
    if name not in SAMPLES:
        raise ValueError(f"unknown sample {name!r}; choose one of {', '.join(SAMPLES)}")
    return cache_dir() / f"{name}-v{SAMPLE_VERSION}.mcap"


def sample_log(name: str) -> Path:
    """The path of a sample log, generating it first if it is not in the cache yet."""
    path = sample_path(name)
    scenario_name, seed, laps, frame_hz = SAMPLES[name]
    if path.exists():
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    print(f"markergraph: generating the {name} sample log once, into {path}", file=sys.stderr)
    world, route = scenario(scenario_name)
    with ProgressBar(f"rendering {name}") as bar:
        write_log(
            world,
            replace(route, laps=laps),
            path,
            seed,
            compressed=True,
            frame_hz=frame_hz,
            progress=bar,
        )
    return path
