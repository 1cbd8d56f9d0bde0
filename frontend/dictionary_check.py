"""Markers of a larger dictionary than the one given.

OpenCV's DICT_4X4_50, _100 and _250 are the first markers of DICT_4X4_1000 (and so for 5X5, 6X6
and 7X7), so a log of DICT_4X4_250 markers read as DICT_4X4_50 finds the ids under 50 alone: a
right but partial map, and nothing to say it is partial (on the simulated warehouse, 92 cm off
where the whole map is 33 cm). So every :data:`CHECK_EVERY`-th frame is searched with the
family's largest dictionary too, and the ids beyond the given one's are counted. On seven clean
simulated logs none was (none beyond DICT_4X4_50 or _250 in 60-88 frames each); on the warehouse
read as DICT_4X4_50, five were.
"""

from __future__ import annotations

import re
from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

from markergraph.common.notes import Note, some_of
from markergraph.frontend.detect import Detector, load_dictionary

__all__ = [
    "CHECK_EVERY",
    "MIN_FRAMES",
    "BeyondDictionary",
    "beyond_note",
    "larger_dictionary",
    "markers_beyond",
]

CHECK_EVERY = 15  # colour frames: about one a second at 15 Hz, 2-3 ms each at 640x480
# An id beyond the dictionary counts once it is seen in this many checked frames: a larger
# dictionary's codes lie closer together, and a speck of texture may read as one of them once.
MIN_FRAMES = 3


def larger_dictionary(dictionary: str) -> str | None:
    """The largest predefined dictionary whose first markers are ``dictionary``'s
    (``DICT_4X4_50`` -> ``DICT_4X4_1000``), or None where there is none (the largest itself,
    AprilTag and ArUco's original families, a dictionary file)."""
    found = re.fullmatch(r"DICT_(\dX\d)_(50|100|250)", dictionary)
    return None if found is None else f"DICT_{found.group(1)}_1000"


class BeyondDictionary:
    """Finds markers of ``dictionary``'s larger family with ids beyond it, in grey images (the
    fast detector, corners as found: the ids alone are wanted); one per thread, as a detector
    is."""

    def __init__(self, dictionary: str) -> None:
        larger = larger_dictionary(dictionary)
        self.size = len(load_dictionary(dictionary).bytesList)
        self._detector = None if larger is None else Detector(larger, subpixel=False)

    def ids(self, gray: NDArray[np.uint8]) -> tuple[int, ...] | None:
        """The ids beyond the dictionary's that ``gray`` shows, sorted; None where the
        dictionary has no larger family."""
        if self._detector is None:
            return None
        found = self._detector.detect(gray)
        return tuple(sorted({d.marker_id for d in found if d.marker_id >= self.size}))


def markers_beyond(seen: Mapping[int, int]) -> list[int]:
    """The ids beyond the dictionary seen in :data:`MIN_FRAMES` checked frames or more
    (``seen``: id -> frames), sorted."""
    return sorted(i for i, frames in seen.items() if frames >= MIN_FRAMES)


def beyond_note(dictionary: str, seen: Mapping[int, int], checks: int) -> Note | None:
    """What the checked frames say of ``dictionary`` (``seen``: ids beyond it -> frames), or
    None where no id beyond it was seen often enough to count."""
    ids = markers_beyond(seen)
    larger = larger_dictionary(dictionary)
    if not ids or larger is None:
        return None
    family = larger.rsplit("_", 1)[0]
    holding = next(f"{family}_{n}" for n in (50, 100, 250, 1000) if max(ids) < n)
    shown_ids = some_of(ids, 8)
    return Note(
        "dictionary.too_small",
        f"the images show {len(ids)} marker(s) of {larger} beyond {dictionary}'s ids (ids "
        f"{shown_ids}; in up to {max(seen[i] for i in ids)} of the {checks} frames checked): "
        f"the map leaves them out; --dictionary {holding} or a larger one holds them",
        figure=len(ids),
    )
