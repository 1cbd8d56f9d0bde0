"""What every layer uses and none owns: the error family, whole-or-nothing files, progress on
stderr and notes. Depends on no other part of markergraph."""

from markergraph.common.errors import (
    EstimationError,
    MarkerGraphError,
    OutputError,
    RejectedObservationError,
    SettingsError,
)
from markergraph.common.notes import Note

__all__ = [
    "EstimationError",
    "MarkerGraphError",
    "Note",
    "OutputError",
    "RejectedObservationError",
    "SettingsError",
]
