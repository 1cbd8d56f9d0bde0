"""Numbers as a person reads them: a solver's float noise written as 0, and no negative zero
("-0.0 ms") in any printed figure."""

from __future__ import annotations

from collections.abc import Iterable

__all__ = ["NOISE_FLOOR", "counted", "denoised", "denoised_matrix", "shown"]

NOISE_FLOOR = 1e-12
"""[m] or [rad]: below it a value is rounding left by the solver (the home marker's
``-9.4e-21``), not a place."""


def denoised(value: float) -> float:
    """``value``, or 0.0 where it is float noise (:data:`NOISE_FLOOR`); never -0.0."""
    value = float(value)
    return 0.0 if abs(value) < NOISE_FLOOR else value


def denoised_matrix(rows: Iterable[Iterable[float]]) -> list[list[float]]:
    """A matrix (a covariance) with entries that are noise against its largest set to 0.0.

    Relative, not absolute: a covariance's own scale may be 1e-8 (the home marker's prior), and
    its off-diagonal 1e-24 is noise against that, not a correlation.
    """
    matrix = [[float(v) for v in row] for row in rows]
    largest = max((abs(v) for row in matrix for v in row), default=0.0)
    floor = NOISE_FLOOR * largest
    return [[0.0 if abs(v) <= floor else v for v in row] for row in matrix]


def shown(value: float, spec: str) -> str:
    """``format(value, spec)`` without a negative zero: -0.0004 with ``.1f`` is "0.0" (as wide
    as the field asks), and so is -0.0; a sign that carries a figure is kept ("-0.4")."""
    text = format(value, spec)
    mantissa = text.lower().split("e")[0]
    if "-" in mantissa and "inf" not in mantissa and not any(c in "123456789" for c in mantissa):
        return format(0.0, spec)
    return text


def counted(count: int, noun: str) -> str:
    """``count`` and ``noun``, plural unless one: "1 marker", "6 markers"."""
    return f"{count} {noun}" if count == 1 else f"{count} {noun}s"
