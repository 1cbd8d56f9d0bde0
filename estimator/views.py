"""Theta's shared error counted once a view: the observations of one marker from nearly one
place (one direction and distance, whenever they were made) show it alike, so the corners'
common bias (``sigma_theta_shared``) is the same in all of them and averaging them does not
reduce it; views apart show it differently, and averaging over them does."""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import replace

from markergraph.estimator.types import Observation

__all__ = ["VIEW_RANGE_STEP", "VIEW_THETA_STEP_RAD", "shared_over_views", "view_of"]

# One view's extent: theta within about 6 degrees, range within about 20 % (the marker's image
# then differs by under a pixel in size and width over its 20-100 px).
VIEW_THETA_STEP_RAD = 0.35
VIEW_RANGE_STEP = 0.2  # of the range's logarithm


def view_of(observation: Observation) -> tuple[int, int, int]:
    """(marker, theta's step, range's step): observations with one key are one view."""
    return (
        observation.marker_id,
        math.floor(observation.theta / VIEW_THETA_STEP_RAD),
        math.floor(math.log(observation.range_m) / VIEW_RANGE_STEP),
    )


def shared_over_views(observations: Sequence[Observation]) -> list[Observation]:
    """The observations, in their order, with theta's shared error folded into its sigma.

    Each of a view's n observations gets ``sigma_theta^2 + n sigma_theta_shared^2``: their n
    thetas together then weigh as their independent errors averaged plus the shared one once
    (n measurements of alike variance v sharing a bias of variance b: their mean's variance is
    ``v / n + b``, and n of ``v + n b`` give the same). ``sigma_theta_shared`` is 0 afterwards,
    so folding twice changes nothing.
    """
    counts = Counter(view_of(o) for o in observations if o.sigma_theta_shared > 0.0)
    folded = []
    for o in observations:
        if o.sigma_theta_shared > 0.0:
            n = counts[view_of(o)]
            sigma = math.sqrt(o.sigma_theta**2 + n * o.sigma_theta_shared**2)
            o = replace(o, sigma_theta=sigma, sigma_theta_shared=0.0)
        folded.append(o)
    return folded
