"""ArUco and AprilTag detection over OpenCV's ``cv2.aruco.ArucoDetector``."""

from __future__ import annotations

import functools
import math
from collections import Counter
from collections.abc import Collection, Iterable
from dataclasses import dataclass
from enum import Enum
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from markergraph.common.errors import SettingsError

__all__ = [
    "Detection",
    "Detector",
    "DetectorMode",
    "allowed_in",
    "detection_agreement",
    "edge_refined",
    "load_dictionary",
    "marker_modules",
]


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


class DetectorMode(Enum):
    """How a :class:`Detector` searches an image."""

    FULL = "full"
    """OpenCV's ``detectMarkers`` over the whole image: the reference the others are held to."""
    FAST = "fast"
    """Square candidates from two cheap passes (the whole image through the smallest
    thresholding window, the image at half size through a 5-pixel one), then the FULL detector
    on a window of the image around each candidate, merged where they overlap: the same pixels
    give the same markers and corners. On the simulator's logs (far, small, grazing and
    motion-smeared markers) it kept 99.2-100 % of FULL's detections, corners equal to 1e-5 px
    (median), for 0.4-0.5 of FULL's detection time; on OpenCV's real tutorial photos all of
    them. Where the windows would cover more than half the image (a board filling the view), it
    runs FULL on the whole image instead: there it costs the candidate passes more than FULL."""
    ARUCO3 = "aruco3"
    """OpenCV's ArUco3 mode: candidates on an image shrunk by ``min_marker_ratio``, corners
    refined up an image pyramid with a 3-pixel window. Fast, but on the simulator's office log
    it kept at most 80 % of FULL's detections (``minSideLengthCanonicalImg`` 8-32, ratio 0-0.03)
    and moved corners by 0.07-0.8 px (median)."""


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


@functools.cache
def marker_modules(dictionary: str) -> int:
    """Modules across a marker of ``dictionary``, its one-module black border included."""
    return int(load_dictionary(dictionary).markerSize) + 2


def allowed_in(dictionary: str, allowed_ids: Collection[int] | None) -> frozenset[int] | None:
    """``allowed_ids`` as a set, checked to lie in ``dictionary`` (``None``: every id)."""
    allowed = None if allowed_ids is None else frozenset(allowed_ids)
    size = len(load_dictionary(dictionary).bytesList)
    outside = sorted(i for i in allowed or () if i >= size)
    if outside:
        raise SettingsError(
            f"--ids {', '.join(map(str, outside))}: not in {dictionary}, whose ids are 0-{size - 1}"
        )
    return allowed


# FAST mode: above this share of the image covered by candidate windows, one whole-image pass
# costs less than the windows and the candidate pass together.
FAST_MAX_WINDOW_SHARE = 0.5

# FAST mode's candidate passes: the whole image through OpenCV's smallest thresholding window
# (3 px), and the image at half size through a 5-pixel window. On the simulator's logs the first
# alone found 99.6-99.8 % of FULL's markers, but 68 % under a D435's motion blur (soft edges);
# the second brings that to 99.2 % for about 40 % more time.
CANDIDATE_WINDOW_PX = 3
CANDIDATE_WINDOW_HALF_PX = 5

_Window = tuple[int, int, int, int]  # x0, y0, x1, y1: pixel columns [x0, x1), rows [y0, y1)


class Detector:
    """Finds markers in grey images.

    Args:
        dictionary: predefined dictionary name or a dictionary file (see :func:`load_dictionary`).
            Larger dictionaries cost more per frame (4x4_50: ~7 ms at 640x480; AprilTag 36h11:
            ~29 ms) and confuse fewer random patterns for markers.
        subpixel: refine corners to sub-pixel accuracy (OpenCV's ``cornerSubPix``, then
            :func:`edge_refined`); on by default, the yaw and PnP need it.
        mode: how the image is searched (:class:`DetectorMode`). ``FAST`` (the default) finds
            the same markers with the same corners as ``FULL`` at 0.4-0.5 of the cost on a
            robot's frames; ``FULL`` is OpenCV's detector as it is; ``ARUCO3`` trades
            small and far markers and corner accuracy for speed.
        min_marker_ratio: ARUCO3's smallest marker side as a fraction of the image's larger
            side (higher is faster and loses more small markers).
        allowed_ids: if given, detections of other ids are dropped (false positives on clutter)
            and counted in ``left_out``.

    Raises:
        SettingsError: an unknown dictionary, or allowed ids outside it.
        TypeError: a mode that is not a :class:`DetectorMode`.
    """

    def __init__(
        self,
        dictionary: str = "DICT_4X4_50",
        *,
        subpixel: bool = True,
        mode: DetectorMode = DetectorMode.FAST,
        min_marker_ratio: float = 0.03,
        allowed_ids: Collection[int] | None = None,
    ) -> None:
        if not isinstance(mode, DetectorMode):
            raise TypeError(f"mode must be a DetectorMode, not {mode!r}")
        self.dictionary_name = dictionary
        self.mode = mode
        self.subpixel = subpixel
        self.allowed_ids = allowed_in(dictionary, allowed_ids)
        loaded = load_dictionary(dictionary)
        self.modules = marker_modules(dictionary)
        self.left_out: Counter[int] = Counter()  # detections of ids outside ``allowed_ids``
        parameters = _parameters(subpixel)
        if mode is DetectorMode.ARUCO3:
            parameters.useAruco3Detection = True
            parameters.minMarkerLengthRatioOriginalImg = min_marker_ratio
        self._detector = cv2.aruco.ArucoDetector(loaded, parameters)
        # FAST. A window holds the largest thresholding window's reach around the marker (there
        # each pixel thresholds as in the whole image), and any edge it cuts stays further from
        # the marker than OpenCV's grouping distance (minMarkerDistanceRate of the perimeter:
        # half a side), or a square the cut makes could stand in for the marker.
        self._reach = parameters.adaptiveThreshWinSizeMax // 2 + 1
        self._grouping = parameters.minMarkerDistanceRate * 4.0
        self._perimeter_rates = (
            parameters.minMarkerPerimeterRate,
            parameters.maxMarkerPerimeterRate,
        )
        # The window's detector keeps the whole image's smallest and largest perimeters in
        # pixels (OpenCV scales them by the image's size; a window's would let through every
        # speck of a few pixels, and cost more than the whole image).
        self._window_parameters = _parameters(subpixel)
        self._window_detector = cv2.aruco.ArucoDetector(loaded, self._window_parameters)
        # Candidates alone are wanted (accepted or rejected alike), so a one-marker dictionary of
        # the same size spares identifying each square against the whole dictionary (5x cheaper
        # on a ChArUco board's squares with DICT_6X6_250).
        one = cv2.aruco.Dictionary(loaded.bytesList[:1], loaded.markerSize)
        self._candidates = [
            cv2.aruco.ArucoDetector(one, _candidate_parameters(window))
            for window in (CANDIDATE_WINDOW_PX, CANDIDATE_WINDOW_HALF_PX)
        ]

    def detect(self, image: NDArray[np.uint8]) -> list[Detection]:
        """Markers in a grey (or colour, converted) image, sorted by id."""
        gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
        gray = np.asarray(gray, dtype=np.uint8)
        if self.mode is DetectorMode.FAST:
            found = self._detect_in_windows(gray)
        else:
            found = self._detect_whole(gray)
        if self.allowed_ids is not None:
            self.left_out.update(d.marker_id for d in found if d.marker_id not in self.allowed_ids)
            found = [d for d in found if d.marker_id in self.allowed_ids]
        if self.subpixel:
            found_corners = np.array([d.corners for d in found]).reshape(-1, 4, 2)
            refined = edge_refined(gray, found_corners, self.modules)
            found = [Detection(d.marker_id, c) for d, c in zip(found, refined, strict=True)]
        return sorted(found, key=lambda d: d.marker_id)

    def _detect_whole(self, gray: NDArray[np.uint8]) -> list[Detection]:
        corners, ids, _ = self._detector.detectMarkers(gray)
        if ids is None:
            return []
        return [
            Detection(int(i), np.asarray(c, dtype=np.float64).reshape(4, 2))
            for c, i in zip(corners, ids.ravel(), strict=True)
        ]

    def _detect_in_windows(self, gray: NDArray[np.uint8]) -> list[Detection]:
        """FAST mode: FULL's detector on a window around each candidate square."""
        height, width = gray.shape
        windows = _merged(self._window(q, width, height) for q in self._candidate_squares(gray))
        if not windows:
            return []
        if sum((x1 - x0) * (y1 - y0) for x0, y0, x1, y1 in windows) > (
            FAST_MAX_WINDOW_SHARE * width * height
        ):
            return self._detect_whole(gray)
        found: list[Detection] = []
        # In contour pixels, truncated as OpenCV does (``unsigned int(rate * size)``).
        min_px, max_px = (int(rate * max(width, height)) for rate in self._perimeter_rates)
        for x0, y0, x1, y1 in windows:
            size = max(x1 - x0, y1 - y0)
            self._window_parameters.minMarkerPerimeterRate = (min_px + 0.5) / size
            self._window_parameters.maxMarkerPerimeterRate = (max_px + 0.5) / size
            self._window_detector.setDetectorParameters(self._window_parameters)
            corners, ids, _ = self._window_detector.detectMarkers(gray[y0:y1, x0:x1])
            if ids is None:
                continue
            # Trusted where the thresholds are the whole image's: not within reach of a cut edge.
            lo_x = x0 + (self._reach if x0 > 0 else 0)
            lo_y = y0 + (self._reach if y0 > 0 else 0)
            hi_x = x1 - (self._reach if x1 < width else 0)
            hi_y = y1 - (self._reach if y1 < height else 0)
            for c, i in zip(corners, ids.ravel(), strict=True):
                quad = np.asarray(c, dtype=np.float64).reshape(4, 2) + np.array([x0, y0])
                xs, ys = quad[:, 0], quad[:, 1]
                if xs.min() >= lo_x and ys.min() >= lo_y and xs.max() <= hi_x and ys.max() <= hi_y:
                    found.append(Detection(int(i), quad))
        return found

    def _candidate_squares(self, gray: NDArray[np.uint8]) -> list[NDArray[np.float64]]:
        """Every square the candidate passes find, (4, 2) pixel corners each: the whole image
        through the smallest thresholding window (sharp and small markers), and the image at
        half size through a 5-pixel window (blurred markers, whose soft edges the smallest
        window does not see)."""
        whole, half = self._candidates
        accepted, _, rejected = whole.detectMarkers(gray)
        squares = [np.asarray(q, dtype=np.float64).reshape(4, 2) for q in (*accepted, *rejected)]
        height, width = gray.shape
        if min(width, height) >= 2 * CANDIDATE_WINDOW_HALF_PX:
            small = cv2.resize(gray, (width // 2, height // 2), interpolation=cv2.INTER_AREA)
            accepted, _, rejected = half.detectMarkers(small)
            # A half-size pixel's centre i is the full-size image's 2 i + 0.5.
            squares += [
                np.asarray(q, dtype=np.float64).reshape(4, 2) * 2.0 + 0.5
                for q in (*accepted, *rejected)
            ]
        return squares

    def _window(self, quad: NDArray[np.float64], width: int, height: int) -> _Window:
        """The image window FULL's detector sees one candidate square through."""
        (x0, y0), (x1, y1) = quad.min(axis=0), quad.max(axis=0)
        margin = self._reach + math.ceil(self._grouping * max(x1 - x0, y1 - y0)) + 2
        return (
            max(int(x0) - margin, 0),
            max(int(y0) - margin, 0),
            min(math.ceil(x1) + margin + 1, width),
            min(math.ceil(y1) + margin + 1, height),
        )


def _parameters(subpixel: bool) -> cv2.aruco.DetectorParameters:
    """OpenCV's default detector parameters, with sub-pixel corners if asked."""
    parameters = cv2.aruco.DetectorParameters()
    if subpixel:
        parameters.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    return parameters


def _candidate_parameters(window_px: int) -> cv2.aruco.DetectorParameters:
    """A candidate pass's parameters: one thresholding window, squares up to the image's
    border (a marker there still gets its window), corners left as found."""
    parameters = cv2.aruco.DetectorParameters()
    parameters.adaptiveThreshWinSizeMin = parameters.adaptiveThreshWinSizeMax = window_px
    parameters.minDistanceToBorder = 0
    # Each square is still read against the one-marker dictionary; make that cheap: one pixel
    # a cell, and no Otsu threshold (a spread under 256 grey levels counts as flat).
    parameters.perspectiveRemovePixelPerCell = 1
    parameters.minOtsuStdDev = 256.0
    return parameters


def _merged(windows: Iterable[_Window]) -> list[_Window]:
    """Windows joined into their bounding box wherever two overlap, until none do: a marker in
    two windows is then searched once, in one window that holds all of it."""
    merged: list[list[int]] = []
    for window in windows:
        box = list(window)
        overlapping = True
        while overlapping:
            overlapping = False
            for other in merged:
                if (
                    box[0] < other[2]
                    and other[0] < box[2]
                    and box[1] < other[3]
                    and other[1] < box[3]
                ):
                    merged.remove(other)
                    box = [min(box[0], other[0]), min(box[1], other[1]),
                           max(box[2], other[2]), max(box[3], other[3])]  # fmt: skip
                    overlapping = True
                    break
        merged.append(box)
    return [(x0, y0, x1, y1) for x0, y0, x1, y1 in merged]


# Edge refinement (:func:`edge_refined`): each side's edge found across it, in its middle.
EDGE_SPAN = (0.2, 0.8)  # the part of a side used: clear of the rounded corners
EDGE_POINTS = 12  # edge points per side
EDGE_HALF_WIDTH_PX = 2.0  # wider windows reach the marker's inner cells on small markers
EDGE_STEP_PX = 0.25
EDGE_PASSES = 2  # each recentred on the last: noise then pulls toward the edge, not the start
EDGE_MAX_SHIFT_PX = 1.5  # a corner moved further means a side was occluded or cut: keep OpenCV's
SHARP_WIDTH_PX = 5.0  # a rise wider than this is smeared (a sharp edge's is 3-4.5 px wide)
BLUR_REACH_MODULES = 0.9  # how far across an edge its smear is looked for: short of inner cells
BLUR_SAMPLES = 16  # samples each way across an edge when measuring its rise's width
_NEXT = [1, 2, 3, 0]  # side k runs from corner k to corner k + 1
_PREVIOUS = [3, 0, 1, 2]
_FRACTIONS = np.linspace(*EDGE_SPAN, EDGE_POINTS)[:, None]  # where along a side
_OFFSETS = np.arange(-EDGE_HALF_WIDTH_PX, EDGE_HALF_WIDTH_PX + 1e-9, EDGE_STEP_PX)  # across it
_MIDDLES = (_OFFSETS[1:] + _OFFSETS[:-1]) / 2.0  # where each difference of the profile sits
_MEDIAN = slice((EDGE_POINTS - 1) // 2, EDGE_POINTS // 2 + 1)  # the middle one or two, sorted


def edge_refined(
    gray: NDArray[np.uint8], corners: NDArray[np.float64], modules: int
) -> NDArray[np.float64]:
    """Markers' corners ((M, 4, 2) pixels) as the intersections of lines fitted to their sides'
    edges, all of a frame's markers at once.

    OpenCV's ``cornerSubPix`` places a convex corner of a blurred square a few tenths of a pixel
    inside the true one (the blur rounds the corner and its gradients lean inward), so PnP reads
    far markers long and the yaw leans with the viewing angle. A straight edge, by contrast, is
    where a symmetric blur (lens, exposure smear, JPEG) leaves it: each side's edge is found
    across it as the centroid of the rising gradient (dark marker to bright margin), along the
    side's middle, and a line fitted through those points; the corners are where the lines
    meet. On the independent generator's corridor renders (by the marker's size in the image)
    the corners' mean inset went from +0.17-0.37 px to -0.01..+0.06 px, and their median error
    from 0.21-0.50 px to 0.04-0.28 px.
    Under a turn's smear each side's window reaches across its rise (:func:`_half_windows`).
    A marker whose corners would move more than :data:`EDGE_MAX_SHIFT_PX` (and as much again as
    its widest window grew), or whose edges are not found, keeps its corners as given."""
    corners = np.asarray(corners, dtype=np.float64)
    markers = len(corners)
    if markers == 0:
        return corners.copy()
    start, end = corners, corners[:, _NEXT]
    length = np.linalg.norm(end - start, axis=2, keepdims=True)
    along = (end - start) / np.maximum(length, 1e-9)
    outward = np.stack([along[..., 1], -along[..., 0]], axis=-1)
    centre = corners.mean(axis=1, keepdims=True)
    outward *= np.sign(np.sum(outward * (start - centre), axis=2, keepdims=True))
    # (marker, side, point, xy)
    on_side = start[:, :, None] + _FRACTIONS * (end - start)[:, :, None]
    half = _half_windows(gray, on_side, outward, length[..., 0].mean(axis=1) / modules)
    scale = (half / EDGE_HALF_WIDTH_PX)[..., None, None]  # (marker, side, 1, 1)
    offsets, middles = _OFFSETS * scale, _MIDDLES * scale
    shift = np.zeros((markers, 4, EDGE_POINTS))
    for _ in range(EDGE_PASSES):
        rise = _rises(gray, on_side, outward, shift[..., None] + offsets)
        weight = rise.sum(axis=3)
        shift += np.sum(rise * middles, axis=3) / np.maximum(weight, 1e-9)
    edge = on_side + shift[..., None] * outward[:, :, None]
    # np.median's own machinery costs more than the rest of this step: the sorted middle.
    median = np.sort(weight, axis=2)[..., _MEDIAN].mean(axis=2, keepdims=True)
    kept = (weight > 0.25 * median)[..., None]
    count = kept.sum(axis=2)
    mean = (edge * kept).sum(axis=2) / np.maximum(count, 1)
    spread = (edge - mean[:, :, None]) * kept
    # Each side's line runs along its points' axis of most spread (a 2x2 eigenproblem, solved
    # in closed form); its normal is across it.
    sxx, syy = np.sum(spread[..., 0] ** 2, axis=2), np.sum(spread[..., 1] ** 2, axis=2)
    sxy = np.sum(spread[..., 0] * spread[..., 1], axis=2)
    angle = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    normal = np.stack([-np.sin(angle), np.cos(angle)], axis=-1)
    offset = np.sum(normal * mean, axis=2)
    # Corner k is where side k - 1 (into it) meets side k (out of it): Cramer's rule.
    n_in, o_in = normal[:, _PREVIOUS], offset[:, _PREVIOUS]
    det = n_in[..., 0] * normal[..., 1] - n_in[..., 1] * normal[..., 0]
    solvable = np.abs(det) > 1e-6
    det = np.where(solvable, det, 1.0)
    refined = np.stack(
        [
            (o_in * normal[..., 1] - n_in[..., 1] * offset) / det,
            (n_in[..., 0] * offset - o_in * normal[..., 0]) / det,
        ],
        axis=-1,
    )
    moved = np.linalg.norm(refined - corners, axis=2).max(axis=1)
    # A smeared side's edge lies further from OpenCV's corner: the bound grows with its window.
    bound = EDGE_MAX_SHIFT_PX + half.max(axis=1) - EDGE_HALF_WIDTH_PX
    good = (moved <= bound) & solvable.all(axis=1) & (count >= 3).all(axis=(1, 2))
    return np.where(good[:, None, None], refined, corners)


def _half_windows(
    gray: NDArray[np.uint8],
    on_side: NDArray[np.float64],
    outward: NDArray[np.float64],
    module_px: NDArray[np.float64],
) -> NDArray[np.float64]:
    """How far across each side ((marker, side)) its edge is looked for [px]. A turn during the
    exposure smears the image sideways, and a smeared edge's rise is as wide as the smear: a
    window of :data:`EDGE_HALF_WIDTH_PX` each way sat inside it and kept OpenCV's corners,
    biased inward (theta 1.6-2.8 deg off at 20-40 deg under a 9 px smear from 1.4 m). So each
    side's rise is measured first, over most of a module (``module_px`` (marker,)) each way,
    short of the inner cells, as ``(sum g)^2 / sum g^2`` of the rise g at each point (a box's
    length, a smear's; about 3.5 sigma of a Gaussian blur's), and the window reaches across it."""
    reach = np.maximum(BLUR_REACH_MODULES * module_px, EDGE_HALF_WIDTH_PX)[:, None]
    step = reach / BLUR_SAMPLES  # between samples [px], (marker, 1)
    offsets = np.arange(-BLUR_SAMPLES, BLUR_SAMPLES + 1) * step[..., None, None]
    rise = _rises(gray, on_side, outward, offsets)
    widths = rise.sum(axis=3) ** 2 / np.maximum(np.sum(rise * rise, axis=3), 1e-9) * step[..., None]
    width = np.sort(widths, axis=2)[..., _MEDIAN].mean(axis=2)
    return np.minimum(EDGE_HALF_WIDTH_PX + np.clip(width - SHARP_WIDTH_PX, 0.0, None), reach)


def _rises(
    gray: NDArray[np.uint8],
    on_side: NDArray[np.float64],
    outward: NDArray[np.float64],
    offsets: NDArray[np.float64],
) -> NDArray[np.float32]:
    """The rise (dark to bright outward; falls count 0) between each pair of neighbouring
    samples across each side, the samples ``offsets`` px outward of its points ``on_side``:
    (marker, side, point, samples - 1)."""
    across = offsets[..., None] * outward[:, :, None, None]
    samples = (on_side[..., None, :] + across).astype(np.float32)  # (marker, side, point, n, xy)
    flat = samples.reshape(-1, samples.shape[3], 2)
    profile = cv2.remap(gray, flat[..., 0], flat[..., 1], cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE)  # fmt: skip
    rise = np.clip(np.diff(profile.astype(np.float32), axis=1), 0.0, None)
    return rise.reshape(*samples.shape[:3], -1)


SAME_MARKER_PX = 5.0  # a detection of the same id this close to another is the same marker


def detection_agreement(
    reference: list[list[Detection]], found: list[list[Detection]]
) -> tuple[int, float, NDArray[np.float64]]:
    """How well ``found`` (frame by frame) reproduces ``reference``: (the reference's
    detections, the share of them found, the corner distances [px] of those matched)."""
    matched, distances = 0, []
    for mine, theirs in zip(reference, found, strict=True):
        for detection in mine:
            gaps = [
                np.linalg.norm(other.corners - detection.corners, axis=1)
                for other in theirs
                if other.marker_id == detection.marker_id
            ]
            best = min(gaps, key=lambda gap: float(gap.max()), default=None)
            if best is not None and best.max() < SAME_MARKER_PX:
                matched += 1
                distances.extend(best)
    total = sum(map(len, reference))
    return total, matched / max(total, 1), np.asarray(distances, dtype=np.float64)
