"""Marker detections a robot recorded instead of images: AprilTag detection messages to
:class:`~markergraph.frontend.detect.Detection` records with corners in OpenCV's order.

Types read, by name: ROS 2 ``apriltag_msgs/msg/AprilTagDetectionArray`` (apriltag_ros for ROS 2,
both shapes of its corners field: ``Point[4]`` and ``float64[8]``),
``isaac_ros_apriltag_interfaces/msg/AprilTagDetectionArray`` and TagSLAM's ROS 1
``apriltag_msgs/ApriltagArrayStamped``.

The AprilTag library lists a tag's corners counter-clockwise in the image from the tag's
bottom-left; OpenCV's ArUco lists them clockwise from the top-left. Reversing the order turns
one into the other up to where the list starts, which only rotates the marker in its own plane:
the estimators use the marker's normal, which the winding alone decides (checked on TagSLAM's
recordings: reversed, every tag faces the camera; as listed, none does).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from markergraph.common.errors import SettingsError
from markergraph.common.notes import Note
from markergraph.frontend.detect import Detection, load_dictionary
from markergraph.frontend.dictionary_check import larger_dictionary
from markergraph.frontend.ros2 import MESSAGE_DEFINITIONS

__all__ = ["DETECTION_DEFINITIONS", "DETECTION_SCHEMAS", "TagFamilies", "detections_of"]

DETECTION_SCHEMAS = (
    "apriltag_msgs/msg/AprilTagDetectionArray",
    "isaac_ros_apriltag_interfaces/msg/AprilTagDetectionArray",
    "apriltag_msgs/msg/ApriltagArrayStamped",
)

# Their definitions, for logs that carry none (a Humble SQLite bag stores no definitions).
DETECTION_DEFINITIONS = {
    name: MESSAGE_DEFINITIONS[name] for name in DETECTION_SCHEMAS if name in MESSAGE_DEFINITIONS
}


def _corners(tag: Any) -> np.ndarray:
    """(4, 2) pixel corners of one detection, whichever shape its message has."""
    corners = tag.corners
    if len(corners) == 8 and not hasattr(corners[0], "x"):  # float64[8]: x0, y0, x1, y1, ...
        return np.asarray(corners, dtype=np.float64).reshape(4, 2)
    return np.array([[float(p.x), float(p.y)] for p in corners], dtype=np.float64)


def detections_of(decoded: Any) -> list[Detection]:
    """The detections one message carries, corners in OpenCV's order, sorted by id.

    Raises:
        ValueError: a detection without four corners.
    """
    tags = decoded.apriltags if hasattr(decoded, "apriltags") else decoded.detections
    found = []
    for tag in tags:
        corners = _corners(tag)
        if corners.shape != (4, 2):
            raise ValueError(f"a detection of tag {tag.id} has {len(tag.corners)} corners, not 4")
        found.append(Detection(int(tag.id), corners[::-1].copy()))
    return sorted(found, key=lambda d: d.marker_id)


_FAMILIES = {f: f"DICT_APRILTAG_{f}" for f in ("16h5", "25h9", "36h10", "36h11")}
# A family known by its bits alone (TagSLAM's ROS 1 detector names itself "mit" or "umich"):
# the AprilTag family most robots carry with that many.
_BY_BITS = {
    4: "DICT_APRILTAG_16h5",
    5: "DICT_APRILTAG_25h9",
    6: "DICT_APRILTAG_36h11 (or DICT_APRILTAG_36h10)",
}


class TagFamilies:
    """What detection messages say of their tags' family (a ``family`` field, or ``bits``
    across the code) and the highest id they carry, held to the dictionary the map is labelled
    with: a map of 36h11 tags called DICT_4X4_50 exports files no ArUco user can read."""

    def __init__(self) -> None:
        self.first: dict[str, tuple[str, int | None]] = {}  # topic -> (family, bits)
        self.ids: dict[str, set[int]] = {}  # topic -> the ids seen

    def take(self, topic: str, decoded: Any, found: list[Detection]) -> None:
        """One detection message's tags (``found``: as :func:`detections_of` read them)."""
        if not found:
            return
        self.ids.setdefault(topic, set()).update(d.marker_id for d in found)
        if topic not in self.first:
            tags = decoded.apriltags if hasattr(decoded, "apriltags") else decoded.detections
            bits = getattr(tags[0], "bits", None)
            self.first[topic] = (str(getattr(tags[0], "family", "") or ""), bits and int(bits))

    def check(self, path: Path, dictionary: str) -> list[Note]:
        """Raises SettingsError, in one line naming the log, the topic and the dictionary to
        pass, where the tags are another family's, or ids lie beyond the dictionary and a
        larger one of its family holds them. Ids beyond every OpenCV dictionary of the family
        (TagSLAM's test 24: ids to 2,109 with 36h11's 6x6 bits, another family OpenCV lacks)
        are a note: their corners map them all the same, under their ids."""
        known = load_dictionary(dictionary)
        size, bits = len(known.bytesList), int(known.markerSize)
        for topic, (family, tag_bits) in self.first.items():
            named = re.search(r"(16h5|25h9|36h10|36h11)", family)
            if named and _FAMILIES[named.group(1)] != dictionary:
                raise SettingsError(
                    f"{path}: the tags on {topic} are AprilTag {named.group(1)} (their family "
                    f"field), not {dictionary}: pass --dictionary {_FAMILIES[named.group(1)]}"
                )
            if not named and tag_bits and tag_bits != bits:
                guess = _BY_BITS.get(tag_bits)
                raise SettingsError(
                    f"{path}: the tags on {topic} have {tag_bits}x{tag_bits} bits (family "
                    f"{family!r}), not {dictionary}'s {bits}x{bits}: pass --dictionary "
                    + (guess or "with the tags' family")
                )
        notes = []
        larger = larger_dictionary(dictionary)
        holds = len(load_dictionary(larger).bytesList) if larger else size
        for topic, ids in self.ids.items():
            beyond = sorted(i for i in ids if i >= size)
            if beyond and beyond[-1] < holds:
                raise SettingsError(
                    f"{path}: tag {beyond[-1]} on {topic} lies beyond {dictionary} ({size} "
                    f"markers): pass --dictionary {larger}"
                )
            if beyond:
                shown = ", ".join(map(str, beyond[:8])) + (" ..." if len(beyond) > 8 else "")
                text = (
                    f"{len(beyond)} tag id(s) on {topic} lie beyond {dictionary} ({size} "
                    f"markers), and no OpenCV dictionary of its family holds them ({shown}): "
                    "mapped from their corners under their ids, which an exported ArUco file "
                    "cannot name"
                )
                notes.append(Note("detections.beyond_dictionary", text, topic, len(beyond)))
        return notes
