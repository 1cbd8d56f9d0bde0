"""markergraph.datasets: simulated worlds, routes, and the measurements and logs made in them.

The random convex rooms of the closed-form property tests live in
:mod:`markergraph.datasets.rooms`."""

from markergraph.datasets.route import GoTo, Look, Route, RoutePlan, WheelErrors, plan
from markergraph.datasets.scenarios import SCENARIOS, scenario
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
    "SimulatedRun",
    "Visibility",
    "Wall",
    "WheelErrors",
    "World",
    "WorldFileError",
    "plan",
    "scenario",
    "simulate_fast",
    "visible_markers",
    "write_log",
]
