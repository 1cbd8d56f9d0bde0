"""The error family: one base every deliberate error derives from, so a caller can catch
markergraph's own failures (bad input, settings, outputs) apart from bugs."""

from __future__ import annotations

__all__ = [
    "EstimationError",
    "MarkerGraphError",
    "OutputError",
    "RejectedObservationError",
    "SettingsError",
]


class MarkerGraphError(Exception):
    """Base of every error markergraph raises on purpose."""


class RejectedObservationError(MarkerGraphError, ValueError):
    """An observation the estimator cannot use (NaN, negative range, unknown marker id)."""


class SettingsError(MarkerGraphError, ValueError):
    """A setting, flag or settings file with a bad value; the message names it."""


class EstimationError(MarkerGraphError):
    """A graph the optimiser cannot solve (an indeterminate system: a marker or pose that no
    factor pins down); the message says which method and what GTSAM reported."""


class OutputError(MarkerGraphError):
    """An output that may not be written (it would replace the input or a user's files), or
    that another run took meanwhile; the message names it."""
