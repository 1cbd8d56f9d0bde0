"""markergraph.datasets: simulated worlds, routes, and the measurements and logs made in them.

The random convex rooms of the closed-form property tests live in
:mod:`markergraph.datasets.rooms`; the 3-D worlds of tags at any pose, seen by a rig of
cameras, in :mod:`markergraph.datasets.scene3d`."""

from typing import TYPE_CHECKING

from markergraph.common.lazy import lazy_package

if TYPE_CHECKING:
    from markergraph.datasets.route import GoTo, Look, Route, RoutePlan, WheelErrors, plan
    from markergraph.datasets.scenarios import SCENARIOS, scenario
    from markergraph.datasets.scene3d import (
        Scene3dTruth,
        SceneKind,
        make_scene3d,
        read_scene3d_truth,
        write_scene3d_log,
    )
    from markergraph.datasets.simulate import (
        SIMULATED_MOUNT,
        ObservationNoise,
        SimulatedRun,
        Visibility,
        simulate_fast,
        visible_markers,
    )
    from markergraph.datasets.world import Marker, Wall, World, WorldFileError
    from markergraph.datasets.write import write_log

__all__ = [
    "SCENARIOS",
    "SIMULATED_MOUNT",
    "GoTo",
    "Look",
    "Marker",
    "ObservationNoise",
    "Route",
    "RoutePlan",
    "Scene3dTruth",
    "SceneKind",
    "SimulatedRun",
    "Visibility",
    "Wall",
    "WheelErrors",
    "World",
    "WorldFileError",
    "make_scene3d",
    "plan",
    "read_scene3d_truth",
    "scenario",
    "simulate_fast",
    "visible_markers",
    "write_log",
    "write_scene3d_log",
]

lazy_package(
    __name__,
    {
        "markergraph.datasets.route": (
            "GoTo",
            "Look",
            "Route",
            "RoutePlan",
            "WheelErrors",
            "plan",
        ),
        "markergraph.datasets.scenarios": (
            "SCENARIOS",
            "scenario",
        ),
        "markergraph.datasets.scene3d": (
            "Scene3dTruth",
            "SceneKind",
            "make_scene3d",
            "read_scene3d_truth",
            "write_scene3d_log",
        ),
        "markergraph.datasets.simulate": (
            "SIMULATED_MOUNT",
            "ObservationNoise",
            "SimulatedRun",
            "Visibility",
            "simulate_fast",
            "visible_markers",
        ),
        "markergraph.datasets.world": (
            "Marker",
            "Wall",
            "World",
            "WorldFileError",
        ),
        "markergraph.datasets.write": ("write_log",),
    },
)
