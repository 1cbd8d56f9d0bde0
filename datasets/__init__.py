"""markergraph.datasets: simulated worlds, routes, and the measurements made in them."""

from markergraph.datasets.rooms import (
    ConvexRoom,
    MarkerObservation,
    observe_marker,
    random_convex_room,
    turn_toward,
)
from markergraph.datasets.route import GoTo, Look, Route, Trajectory, WheelErrors, plan
from markergraph.datasets.scenarios import SCENARIOS, scenario
from markergraph.datasets.simulate import (
    ObservationNoise,
    SimulatedRun,
    Visibility,
    simulate_fast,
    visible_markers,
)
from markergraph.datasets.world import Marker, Wall, World, WorldFileError

__all__ = [
    "SCENARIOS",
    "ConvexRoom",
    "GoTo",
    "Look",
    "Marker",
    "MarkerObservation",
    "ObservationNoise",
    "Route",
    "SimulatedRun",
    "Trajectory",
    "Visibility",
    "Wall",
    "WheelErrors",
    "World",
    "WorldFileError",
    "observe_marker",
    "plan",
    "random_convex_room",
    "scenario",
    "simulate_fast",
    "turn_toward",
    "visible_markers",
]
