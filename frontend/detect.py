"""ArUco and AprilTag detection over OpenCV's ``cv2.aruco.ArucoDetector``."""

from __future__ import annotations

from collections import Counter
from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from markergraph.estimator.types import SettingsError

__all__ = ["Detection", "Detector", "load_dictionary"]


@dataclass(frozen=True)
class Detection:
    """One marker found in an image.

    Attributes:
        marker_id: the id in the dictionary.
        corners: (4, 2) pixel corners in OpenCV's order: the printed marker's top-left,
            top-right, bottom-right, bottom-left (as a viewer facing it sees it).
    """

    marker_id: int
    corners: NDArray[np.float64]


def load_dictionary(name_or_path: str) -> cv2.aruco.Dictionary:
    """An OpenCV predefined dictionary by name (``DICT_4X4_50``, ``DICT_APRILTAG_36h11``, ...)
    or a custom one from an OpenCV YAML file (``marker_size``, ``max_correction_bits``, ...)."""
    if hasattr(cv2.aruco, name_or_path) and name_or_path.startswith("DICT_"):
        return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name_or_path))
    path = Path(name_or_path)
    if not path.is_file():
        raise SettingsError(
            f"unknown dictionary {name_or_path!r}: neither an OpenCV DICT_* name "
            "nor a dictionary file"
        )
    dictionary = cv2.aruco.Dictionary()
    try:
        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
        readable = storage.isOpened() and dictionary.readDictionary(storage.root())
    except (cv2.error, SystemError):  # OpenCV's parser raises on what is not YAML/XML/JSON
        readable = False
    if not readable or dictionary.bytesList is None or len(dictionary.bytesList) == 0:
        raise SettingsError(f"--dictionary {path}: not an OpenCV dictionary file")
    return dictionary


class Detector:
    """Finds markers in grey images.

    Args:
        dictionary: predefined dictionary name or a dictionary file (see :func:`load_dictionary`).
            Larger dictionaries cost more per frame (4x4_50: ~7 ms at 640x480; AprilTag 36h11:
            ~29 ms) and confuse fewer random patterns for markers.
        subpixel: refine corners to sub-pixel accuracy (0.03 px on real photos against 1.3 px
            without); on by default, the yaw and PnP need it.
        aruco3: OpenCV's faster ArUco3 mode (3-4x faster); it may miss markers smaller than
            ``min_marker_ratio`` of the image width.
        min_marker_ratio: ArUco3's smallest marker side as a fraction of the image (0.02-0.04
            keeps recall; higher loses markers).
        allowed_ids: if given, detections of other ids are dropped (false positives on clutter)
            and counted in ``left_out``.

    Raises:
        SettingsError: an unknown dictionary, or allowed ids outside it.
    """

    def __init__(
        self,
        dictionary: str = "DICT_4X4_50",
        *,
        subpixel: bool = True,
        aruco3: bool = False,
        min_marker_ratio: float = 0.03,
        allowed_ids: Collection[int] | None = None,
    ) -> None:
        parameters = cv2.aruco.DetectorParameters()
        if subpixel:
            parameters.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        if aruco3:
            parameters.useAruco3Detection = True
            parameters.minMarkerLengthRatioOriginalImg = min_marker_ratio
        self.dictionary_name = dictionary
        self.allowed_ids = None if allowed_ids is None else frozenset(allowed_ids)
        loaded = load_dictionary(dictionary)
        size = len(loaded.bytesList)
        outside = sorted(i for i in self.allowed_ids or () if i >= size)
        if outside:
            raise SettingsError(
                f"--ids {', '.join(map(str, outside))}: not in {dictionary}, whose ids are "
                f"0-{size - 1}"
            )
        self.left_out: Counter[int] = Counter()  # detections of ids outside ``allowed_ids``
        self._detector = cv2.aruco.ArucoDetector(loaded, parameters)

    def detect(self, image: NDArray[np.uint8]) -> list[Detection]:
        """Markers in a grey (or colour, converted) image, sorted by id."""
        gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
        corners, ids, _ = self._detector.detectMarkers(gray)
        if ids is None:
            return []
        found = [
            Detection(int(i), np.asarray(c, dtype=np.float64).reshape(4, 2))
            for c, i in zip(corners, ids.ravel(), strict=True)
        ]
        if self.allowed_ids is not None:
            self.left_out.update(d.marker_id for d in found if d.marker_id not in self.allowed_ids)
            found = [d for d in found if d.marker_id in self.allowed_ids]
        return sorted(found, key=lambda d: d.marker_id)
