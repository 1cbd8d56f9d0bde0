"""markergraph.datasets: simulated worlds and the measurements made in them."""

from markergraph.datasets.rooms import (
    ConvexRoom,
    MarkerObservation,
    observe_marker,
    random_convex_room,
    turn_toward,
)

__all__ = [
    "ConvexRoom",
    "MarkerObservation",
    "observe_marker",
    "random_convex_room",
    "turn_toward",
]
