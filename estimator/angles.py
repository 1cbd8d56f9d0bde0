"""Angle helpers: wrapping to (-pi, pi] and wrapped differences."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["angle_diff", "wrap", "wrap_array"]

TWO_PI = 2.0 * math.pi


def wrap(angle_rad: float) -> float:
    """Wrap an angle to the half-open interval (-pi, pi].

    Written as ``pi - ((pi - a) mod 2pi)`` so that +pi stays +pi and -pi maps to +pi, which
    ``atan2`` and ``math.remainder`` do not guarantee.
    """
    wrapped = math.pi - (math.pi - angle_rad) % TWO_PI
    # A tiny negative (pi - a) rounds up to exactly 2pi under %, which would give -pi.
    return math.pi if wrapped <= -math.pi else wrapped


def wrap_array(angles_rad: ArrayLike) -> NDArray[np.float64]:
    """Vectorised :func:`wrap` over an array of any shape."""
    a = np.asarray(angles_rad, dtype=np.float64)
    wrapped = np.pi - np.mod(np.pi - a, TWO_PI)
    return np.where(wrapped <= -np.pi, np.pi, wrapped)


def angle_diff(a_rad: float, b_rad: float) -> float:
    """The wrapped difference ``a - b`` in (-pi, pi]: the residual of two headings."""
    return wrap(a_rad - b_rad)
