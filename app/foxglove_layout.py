"""``overlay.layout.json``: a Foxglove layout for overlay.mcap, so that opening the overlay with
its log shows the map at once (Foxglove: Layouts, Import from file).

Two panels side by side, in the JSON Foxglove writes when it exports a layout (``configById``
keyed by ``<panel type>!<id>``, and ``layout``, a tree of splits over those ids):

- a 3D panel following the map frame, showing the markers (``/markergraph/markers``), the path
  (``/markergraph/path``) and the estimated pose (``/markergraph/pose``);
- an Image panel on the log's colour topic (played beside the overlay: overlay.mcap holds no
  image) with its camera_info as calibration, the map's markers drawn over the picture.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from markergraph.markermap import write_json

__all__ = [
    "IMAGE_PANEL",
    "LAYOUT_SUFFIX",
    "THREE_D_PANEL",
    "layout_path",
    "overlay_layout",
    "write_layout",
]

LAYOUT_SUFFIX = ".layout.json"
THREE_D_PANEL = "3D!markergraph"
IMAGE_PANEL = "Image!markergraph"
_MAP_SPLIT_PERCENT = 55  # the map gets the larger half: it is what the overlay adds to the log


def layout_path(overlay: Path) -> Path:
    """The layout's file beside an overlay: ``overlay.mcap`` -> ``overlay.layout.json``."""
    return overlay.with_name(overlay.stem + LAYOUT_SUFFIX)


def _visible(topics: list[str]) -> dict[str, dict[str, bool]]:
    return {topic: {"visible": True} for topic in topics}


def overlay_layout(
    map_frame: str,
    scene_topics: list[str],
    image_topic: str | None = None,
    calibration_topic: str | None = None,
) -> dict[str, Any]:
    """The layout document.

    Args:
        map_frame: the overlay's map frame, which the 3D panel follows and displays in.
        scene_topics: the overlay's topics the 3D panel shows; the first (the markers) is also
            drawn over the image.
        image_topic: the log's colour topic for the Image panel; None leaves the panel for the
            user to point at a topic (a log of detections only).
        calibration_topic: that image's camera_info topic, which projects the markers onto it.

    Returns:
        A JSON-ready dict.
    """
    image_mode: dict[str, Any] = {}
    if image_topic is not None:
        image_mode["imageTopic"] = image_topic
    if calibration_topic is not None:
        image_mode["calibrationTopic"] = calibration_topic
    three_d = {
        "followMode": "follow-none",  # the map stays put; the path moves over it
        "followTf": map_frame,
        "scene": {"transforms": {"showLabel": False}},
        "topics": _visible(scene_topics),
        "layers": {
            "grid": {"layerId": "foxglove.Grid", "visible": True, "frameId": map_frame,
                     "size": 20, "divisions": 20},
        },
    }  # fmt: skip
    image = {"imageMode": image_mode, "topics": _visible(scene_topics[:1])}
    return {
        "configById": {THREE_D_PANEL: three_d, IMAGE_PANEL: image},
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": {"speed": 1.0},
        "layout": {
            "first": THREE_D_PANEL,
            "second": IMAGE_PANEL,
            "direction": "row",
            "splitPercentage": _MAP_SPLIT_PERCENT,
        },
    }


def write_layout(path: Path, layout: dict[str, Any]) -> None:
    """The layout as indented JSON, written whole or not at all."""
    write_json(path, layout)
