"""AprilTag families through the AprilTag 3 library (``pupil-apriltags``), as a
:class:`~markergraph.frontend.detect.Detector` would find them: same ids, corners in OpenCV's
order and pixel convention, refined the same way."""

from __future__ import annotations

import weakref
from collections import Counter
from collections.abc import Collection
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from markergraph.common.errors import SettingsError
from markergraph.frontend.detect import Detection, allowed_in, edge_refined, marker_modules

__all__ = ["APRILTAG3_FAMILIES", "AprilTag3Detector", "apriltag3_available"]

APRILTAG3_FAMILIES = {
    "DICT_APRILTAG_16h5": "tag16h5",
    "DICT_APRILTAG_25h9": "tag25h9",
    "DICT_APRILTAG_36h11": "tag36h11",
}
"""OpenCV's AprilTag dictionaries that AprilTag 3 also reads (its ids are OpenCV's: checked on
rendered tags). OpenCV's ``DICT_APRILTAG_36h10`` is not among AprilTag 3's families."""

# Bits the library may correct per family (it corrects up to 2). 16h5 has a minimum Hamming
# distance of 5 and so few bits that corrected codes are mostly noise: on a minute of the
# rendered office, AprilTag 3 with 2 corrected bits found 204 tags that were not there (OpenCV:
# none).
MAX_HAMMING = {"tag16h5": 0, "tag25h9": 2, "tag36h11": 2}

# AprilTag 3 puts pixel centres at +0.5 (pixel i spans [i, i + 1]); OpenCV at integers. On
# rendered tags its corners sat (+0.49, +0.48) px from the truth, (-0.01, -0.01) once shifted.
PIXEL_CENTRE_SHIFT_PX = 0.5

# Its corners wrap the tag counter-clockwise from the top right as a viewer facing the tag sees
# it (top-right, top-left, bottom-left, bottom-right); these indices put them in OpenCV's order
# (top-left, top-right, bottom-right, bottom-left). Checked on rendered tags.
TO_OPENCV_ORDER = [1, 0, 3, 2]


# AprilTag 3's own default: sharpening before the bits are read, which helps small and blurred
# tags. pupil-apriltags 1.0.4 documents it but passes int(0.25), that is none: set here. On the
# rendered office under the softer blur it found 3.3 points more of the tags of 20 px or more.
DECODE_SHARPENING = 0.25


def apriltag3_available() -> bool:
    """Whether the AprilTag 3 binding (``pupil-apriltags``) imports."""
    try:
        import pupil_apriltags  # noqa: F401
    except ImportError:
        return False
    return True


class AprilTag3Detector:
    """Finds AprilTags in grey images with the AprilTag 3 library; the same surface as
    :class:`~markergraph.frontend.detect.Detector` (``detect``, ``left_out``).

    Args:
        dictionary: an OpenCV AprilTag dictionary name (:data:`APRILTAG3_FAMILIES`).
        subpixel: refine corners with :func:`~markergraph.frontend.detect.edge_refined`, as the
            OpenCV detector does (AprilTag 3's own edge refinement is always on).
        quad_decimate: AprilTag 3 looks for quads on the image shrunk by this factor. 2 takes
            a quarter to a third of the time of 1, but on the rendered corridor found 69 % of
            the 36h11 tags of 20 px or more against 98 %; 1 (the default) found the most tags
            of any detector measured (docs/benchmarks.md).
        allowed_ids: if given, detections of other ids are dropped and counted in ``left_out``.

    Raises:
        SettingsError: a dictionary AprilTag 3 does not read, allowed ids outside it, or
            ``pupil-apriltags`` not installed.
    """

    def __init__(
        self,
        dictionary: str = "DICT_APRILTAG_36h11",
        *,
        subpixel: bool = True,
        quad_decimate: float = 1.0,
        allowed_ids: Collection[int] | None = None,
    ) -> None:
        family = APRILTAG3_FAMILIES.get(dictionary)
        if family is None:
            raise SettingsError(
                f"--detector apriltag3 reads {', '.join(APRILTAG3_FAMILIES)}, not {dictionary}"
            )
        try:
            import pupil_apriltags
        except ImportError:
            raise SettingsError(
                "--detector apriltag3 needs the AprilTag 3 library: pip install pupil-apriltags"
            ) from None
        self.dictionary_name = dictionary
        self.subpixel = subpixel
        self.allowed_ids = allowed_in(dictionary, allowed_ids)
        self.modules = marker_modules(dictionary)
        self.left_out: Counter[int] = Counter()  # detections of ids outside ``allowed_ids``
        self._max_hamming = MAX_HAMMING[family]
        self._detector = pupil_apriltags.Detector(
            families=family, nthreads=1, quad_decimate=quad_decimate
        )
        weakref.finalize(self, _release, self._detector)
        self._detector.tag_detector_ptr.contents.decode_sharpening = DECODE_SHARPENING

    def detect(self, image: NDArray[np.uint8]) -> list[Detection]:
        """Tags in a grey (or colour, converted) image, sorted by id."""
        gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
        gray = np.ascontiguousarray(gray, dtype=np.uint8)
        found = [
            Detection(int(tag.tag_id), _opencv_corners(tag.corners))
            for tag in self._detector.detect(gray)
            if tag.hamming <= self._max_hamming
        ]
        if self.allowed_ids is not None:
            self.left_out.update(d.marker_id for d in found if d.marker_id not in self.allowed_ids)
            found = [d for d in found if d.marker_id in self.allowed_ids]
        if self.subpixel and found:
            refined = edge_refined(gray, np.array([d.corners for d in found]), self.modules)
            found = [Detection(d.marker_id, c) for d, c in zip(found, refined, strict=True)]
        return sorted(found, key=lambda d: d.marker_id)


def _opencv_corners(corners: Any) -> NDArray[np.float64]:
    """AprilTag 3's (4, 2) corners in OpenCV's order and pixel convention."""
    return np.asarray(corners, dtype=np.float64)[TO_OPENCV_ORDER] - PIXEL_CENTRE_SHIFT_PX


def _release(detector: Any) -> None:
    """Frees a ``pupil_apriltags.Detector`` in the order the C library needs.

    pupil-apriltags 1.0.4's own ``__del__`` frees the tag families before the detector, whose
    destructor then reads them (use after free: a segfault or ``malloc(): mismatching
    next->prev_size`` when a second detector is dropped or at exit; pupil-labs/apriltags #34,
    #46; fixed the same way in dt-apriltags #26). Here the detector goes first, and the
    binding's own ``__del__`` then finds nothing left to free."""
    pointer = getattr(detector, "tag_detector_ptr", None)
    libc = getattr(detector, "libc", None)
    if pointer is None or libc is None:
        return
    libc.apriltag_detector_destroy.restype = None
    libc.apriltag_detector_destroy(pointer)
    detector.tag_detector_ptr = None
    for family, family_pointer in getattr(detector, "tag_families", {}).items():
        destroy = getattr(libc, f"{family}_destroy")
        destroy.restype = None
        destroy(family_pointer)
