"""The markers' size measured by depth: depth over PnP's distance, times the given size.

Depth's scale and the markers' size are one ratio seen from two sides: PnP's distance is
proportional to the size it is given, depth's is not, so depth / PnP reads both the depth
camera's scale error and the size's. Which to believe is decided by how large it is: a depth
camera's scale is off by a percent or two at most (a D435i by +1.2 % on the independent
generator's logs), while a wrong marker size is off by a step between the sizes markers are
printed in (0.15 against 0.20 m: 25 %). Beyond :data:`SIZE_NOT_DEPTH` the size is taken as
wrong and measured; within it, the ratio is the depth's scale (the pipeline's depth-scale rule,
which leaves depth alone within its own 0.4 % error).
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

__all__ = ["MIN_SIZE_RATIOS", "SIZE_NOT_DEPTH", "SizeByDepth", "marker_sizes_by_depth"]

# Beyond this, depth / PnP is a wrong marker size, not a depth camera's scale (see above).
SIZE_NOT_DEPTH = 0.05
MIN_SIZE_RATIOS = 20  # sightings with depth before the overall size is measured
MIN_MARKER_RATIOS = 5  # sightings of one marker before its own size is measured
ROBUST_SIGMAS = 3.0  # a size differs from the given one beyond this many of its own errors


@dataclass(frozen=True)
class SizeByDepth:
    """The markers' size as depth measures it.

    Attributes:
        ratio: the robust mean of depth over PnP's distance over every sighting (depth's own
            scale divided out).
        ratio_sigma: its standard error.
        sightings: how many sightings it rests on.
        size_m: the markers' size by depth: the given size times ``ratio`` where that is
            wrong, else the given size [m].
        sizes_m: markers whose own ratio differs from the rest, by id: their size [m].
        use: whether the given size is wrong (beyond :data:`SIZE_NOT_DEPTH` and its error).
    """

    ratio: float
    ratio_sigma: float
    sightings: int
    size_m: float
    sizes_m: Mapping[int, float] = field(default_factory=dict)
    use: bool = False


def _robust_mean(ratios: list[float]) -> tuple[float, float, int]:
    """Mean, its standard error and the values kept: started from the median (not the mean,
    which a marker of another size seen in a third of the sightings drags halfway to itself),
    the values beyond three robust sigmas (1.4826 MAD) of the last estimate dropped, thrice."""
    values = np.array(ratios, dtype=np.float64)
    centre = float(np.median(values))
    kept = np.ones(values.size, dtype=bool)
    for _ in range(3):
        sigma = 1.4826 * float(np.median(np.abs(values[kept] - centre)))
        kept = np.abs(values - centre) <= ROBUST_SIGMAS * max(sigma, 1e-9)
        centre = float(np.mean(values[kept]))
    n = int(np.count_nonzero(kept))
    spread = float(np.std(values[kept], ddof=1)) if n > 1 else 0.0
    return centre, spread / math.sqrt(n), n


def marker_sizes_by_depth(
    ratios: list[tuple[int, float]],
    given_m: float,
    given_by_id: Mapping[int, float],
    depth_scale: float,
) -> SizeByDepth | None:
    """The markers' size measured by depth, or None with fewer than :data:`MIN_SIZE_RATIOS`
    sightings.

    Args:
        ratios: (marker id, depth over PnP's distance) of each well-placed sighting.
        given_m: the size given for the markers; given_by_id: markers given their own.
        depth_scale: what depth reads per true metre, when set (1 when trusted).
    """
    finite = [(i, r / depth_scale) for i, r in ratios if math.isfinite(r) and r > 0]
    if len(finite) < MIN_SIZE_RATIOS:
        return None
    # The size given to all is measured on the markers that take it: one given its own size
    # and seen most would otherwise pass its own error off as everyone's.
    taking = [r for i, r in finite if i not in given_by_id]
    ratio, sigma, n = _robust_mean(
        taking if len(taking) >= MIN_SIZE_RATIOS else [r for _, r in finite]
    )
    overall_wrong = abs(ratio - 1.0) > max(SIZE_NOT_DEPTH, ROBUST_SIGMAS * sigma)
    by_marker: dict[int, list[float]] = defaultdict(list)
    for marker_id, r in finite:
        by_marker[marker_id].append(r)
    # With the overall size wrong, depth is the trusted side; otherwise the overall ratio is the
    # depth's own scale, which a marker's ratio carries too.
    depth_reads = 1.0 if overall_wrong else ratio
    sizes: dict[int, float] = {}
    for marker_id, own in sorted(by_marker.items()):
        if len(own) < MIN_MARKER_RATIOS:
            continue
        own_ratio, own_sigma, _ = _robust_mean(own)
        # A marker apart from the rest is a marker of another size (a depth scale is one for
        # all); one given a size of its own is measured against that.
        given = given_by_id.get(marker_id, given_m)
        apart = abs(own_ratio / ratio - 1.0) > max(SIZE_NOT_DEPTH, ROBUST_SIGMAS * own_sigma)
        if apart or (marker_id in given_by_id and abs(own_ratio - 1.0) > SIZE_NOT_DEPTH):
            sizes[marker_id] = given * own_ratio / depth_reads
    size_m = given_m * ratio if overall_wrong else given_m
    return SizeByDepth(ratio, sigma, n, size_m, sizes, overall_wrong or bool(sizes))
