"""markergraph: a robot's recorded log in, a corrected map of the fiducial markers on its walls out.

The public API (``import markergraph as mg``)::

    result = mg.map_log("robot.mcap", mg.MapConfig.from_values({"method": "all"}))
    mg.write_results(result, "robot-map")
    marker_map = mg.MarkerMap.load("robot-map/map.json")

Layers, each importing only those below it: ``markergraph.estimator`` (numpy, GTSAM, filterpy:
observations and odometry to an :class:`Estimate`), ``markergraph.frontend`` (OpenCV and log
reading: logs to observations), ``markergraph.datasets`` (simulated worlds and logs), this
application layer (the main job, settings, file formats, plots, overlay, report) and
``markergraph.cli``. The names below load on first use, so ``import markergraph.estimator``
stays free of OpenCV.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from markergraph.common.errors import (
        MarkerGraphError,
        OutputError,
        RejectedObservationError,
        SettingsError,
    )
    from markergraph.estimator import Estimate, Method, OdometrySample, Trajectory, estimate
    from markergraph.frontend import LogError, extract
    from markergraph.markermap import MarkerMap, MarkerMapError
    from markergraph.records import MapRun
    from markergraph.results import write_results
    from markergraph.run import map_log, map_logs
    from markergraph.settings import MapConfig

__all__ = [
    "Estimate",
    "LogError",
    "MapConfig",
    "MapRun",
    "MarkerGraphError",
    "MarkerMap",
    "MarkerMapError",
    "Method",
    "OdometrySample",
    "OutputError",
    "RejectedObservationError",
    "SettingsError",
    "Trajectory",
    "estimate",
    "extract",
    "map_log",
    "map_logs",
    "write_results",
]

_HOME = {
    "Estimate": "markergraph.estimator",
    "MarkerGraphError": "markergraph.common.errors",
    "Method": "markergraph.estimator",
    "OdometrySample": "markergraph.estimator",
    "OutputError": "markergraph.common.errors",
    "RejectedObservationError": "markergraph.common.errors",
    "SettingsError": "markergraph.common.errors",
    "Trajectory": "markergraph.estimator",
    "estimate": "markergraph.estimator",
    "LogError": "markergraph.frontend",
    "extract": "markergraph.frontend",
    "MarkerMap": "markergraph.markermap",
    "MarkerMapError": "markergraph.markermap",
    "write_results": "markergraph.results",
    "MapRun": "markergraph.records",
    "map_logs": "markergraph.run",
    "map_log": "markergraph.run",
    "MapConfig": "markergraph.settings",
}


def __getattr__(name: str) -> Any:
    if name not in _HOME:
        raise AttributeError(f"module 'markergraph' has no attribute {name!r}")
    value = getattr(importlib.import_module(_HOME[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(__all__)
