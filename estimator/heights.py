"""Each marker's height: the map is 2-D, but exports for 3-D consumers need the third axis.

A marker's centre is seen from a known camera mount, so every observation fixes its height above
the base frame's origin; the heights of one marker differ only by noise and by the odd outlier
(a mismatched depth, a tilted frame), so a median and its spread suffice.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterable
from typing import NamedTuple

import numpy as np

from markergraph.estimator.types import Observation

__all__ = ["MarkerHeight", "marker_heights"]

# A single observation's height is no better than the mount's height and pitch are known:
# a centimetre.
MIN_HEIGHT_SPREAD_M = 0.01
MEDIAN_EFFICIENCY = math.sqrt(math.pi / 2.0)  # the median's sigma over the mean's, Gaussian
MAD_TO_SIGMA = 1.4826


class MarkerHeight(NamedTuple):
    """A marker's estimated height above the base frame's origin and its standard deviation
    [m], from ``n_observations`` observations."""

    z_m: float
    sigma_m: float
    n_observations: int


def marker_heights(observations: Iterable[Observation]) -> dict[int, MarkerHeight]:
    """Each marker's height: the median of its observations' heights, with the median's
    standard error from their median absolute deviation (at least 1 cm per observation).
    Markers with no observation of known height are left out."""
    heights: defaultdict[int, list[float]] = defaultdict(list)
    for o in observations:
        if math.isfinite(o.height_m):
            heights[o.marker_id].append(o.height_m)
    result = {}
    for marker_id, values in sorted(heights.items()):
        z = np.asarray(values)
        median = float(np.median(z))
        spread = max(MAD_TO_SIGMA * float(np.median(np.abs(z - median))), MIN_HEIGHT_SPREAD_M)
        result[marker_id] = MarkerHeight(
            median, MEDIAN_EFFICIENCY * spread / math.sqrt(len(z)), len(z)
        )
    return result
