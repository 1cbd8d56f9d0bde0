"""Which library finds a dictionary's markers: OpenCV's ArUco detector or AprilTag 3."""

from __future__ import annotations

from collections.abc import Collection
from enum import Enum

from markergraph.frontend.apriltag3 import (
    APRILTAG3_FAMILIES,
    AprilTag3Detector,
    apriltag3_available,
)
from markergraph.frontend.detect import Detector, DetectorMode

__all__ = ["AUTO_CHOICE", "DetectorChoice", "MarkerDetector", "chosen_detector", "make_detector"]

MarkerDetector = Detector | AprilTag3Detector
"""Either library's detector: ``detect(image) -> list[Detection]``, ``left_out``."""


class DetectorChoice(Enum):
    """The library that finds markers."""

    AUTO = "auto"
    """The better one for the dictionary (:data:`AUTO_CHOICE`), OpenCV for the rest."""
    OPENCV = "opencv"
    """OpenCV's ArUco detector (every dictionary), searching as its ``DetectorMode`` says."""
    APRILTAG3 = "apriltag3"
    """The AprilTag 3 library (``pupil-apriltags``; AprilTag 16h5, 25h9 and 36h11 only)."""


AUTO_CHOICE: dict[str, DetectorChoice] = {
    name: DetectorChoice.OPENCV for name in APRILTAG3_FAMILIES
}
"""The better library per AprilTag family, by ``tests/benchmarks/bench_apriltag.py --map`` (see
docs/benchmarks.md), OpenCV for all three. On rendered frames AprilTag 3 on the whole image
found 1-16 points more of the tags observations use (sides of 20 px or more) and put their
corners closer at the 90th percentile (0.22-0.45 px against 0.27-1.05 px), but took 9-15x
OpenCV's fast path's time; on a half-size image (3-4x the time) it lost up to a quarter of the
far tags in the corridor. Mapped by SLAM, a minute of the office in 36h11 gave the same marker
error with either (aligned RMSE 0.024 m with OpenCV, 0.025 m with AprilTag 3) for 2.6x the CPU
time. Dictionaries not named here: OpenCV."""


def chosen_detector(dictionary: str, choice: DetectorChoice) -> DetectorChoice:
    """The library ``choice`` comes to for ``dictionary``: AUTO resolved by :data:`AUTO_CHOICE`,
    and OpenCV wherever AprilTag 3 would be chosen automatically but does not import."""
    if choice is not DetectorChoice.AUTO:
        return choice
    chosen = AUTO_CHOICE.get(dictionary, DetectorChoice.OPENCV)
    if chosen is DetectorChoice.APRILTAG3 and not apriltag3_available():
        return DetectorChoice.OPENCV
    return chosen


def make_detector(
    dictionary: str,
    choice: DetectorChoice = DetectorChoice.AUTO,
    *,
    mode: DetectorMode = DetectorMode.FAST,
    allowed_ids: Collection[int] | None = None,
) -> MarkerDetector:
    """A detector for ``dictionary`` from the library ``choice`` comes to (:func:`chosen_detector`).

    Raises:
        SettingsError: an unknown dictionary or ids outside it; AprilTag 3 asked for a dictionary
            it does not read, or not installed.
        TypeError: a choice that is not a :class:`DetectorChoice`.
    """
    if not isinstance(choice, DetectorChoice):
        raise TypeError(f"choice must be a DetectorChoice, not {choice!r}")
    if chosen_detector(dictionary, choice) is DetectorChoice.APRILTAG3:
        return AprilTag3Detector(dictionary, allowed_ids=allowed_ids)
    return Detector(dictionary, mode=mode, allowed_ids=allowed_ids)
