"""Detections observed from their full pose: the corners' winding decided by the camera seeing
the print, and each marker's drops counted, against exact geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from markergraph.frontend.camera import Camera
from markergraph.frontend.detect import Detection
from markergraph.frontend.observe import ObservationModel
from markergraph.frontend.posed import (
    DropReason,
    LevelledCamera,
    drop_notes,
    observe_levelled_frame,
    tally_detections,
)
from markergraph.frontend.sizes import MarkerSizes

EXACT = 1e-6  # noise-free corners through PnP: the pose comes back to solver precision
SIDE_M = 0.2

# Optical axes (x right, y down, z forward) in a level frame looking along +x, pitched 10 deg
# down and rolled 5 deg, 30 cm above the body origin.
_C, _S = math.cos(math.radians(10.0)), math.sin(math.radians(10.0))
_PITCH = np.array([[_C, 0.0, _S], [0.0, 1.0, 0.0], [-_S, 0.0, _C]])
_c, _s = math.cos(math.radians(5.0)), math.sin(math.radians(5.0))
_ROLL = np.array([[1.0, 0.0, 0.0], [0.0, _c, -_s], [0.0, _s, _c]])
R_LEVEL_OPTICAL = _PITCH @ _ROLL @ np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
VIEW = LevelledCamera(Camera(600.0, 600.0, 640.0, 400.0, 1280, 800), R_LEVEL_OPTICAL,
                      np.array([0.0, 0.0, 0.3]))  # fmt: skip


def corners_of(centre: np.ndarray, normal_yaw: float, tilt: float = 0.0) -> np.ndarray:
    """Pixel corners, OpenCV's order (clockwise in the image from the top-left), of a marker at
    ``centre`` (level frame) whose normal has heading ``normal_yaw``, tilted ``tilt`` up."""
    n = np.array([math.cos(tilt) * math.cos(normal_yaw), math.cos(tilt) * math.sin(normal_yaw),
                  math.sin(tilt)])  # fmt: skip
    hint = np.array([0.0, 0.0, 1.0]) if abs(tilt) < 1.0 else np.array([1.0, 0.0, 0.0])
    right = -np.cross(n, hint) / np.linalg.norm(np.cross(n, hint))  # the viewer's right
    up = np.cross(n, right)
    h = SIDE_M / 2.0
    corners = [centre - right * h + up * h, centre + right * h + up * h,
               centre + right * h - up * h, centre - right * h - up * h]  # fmt: skip
    optical = (np.array(corners) - VIEW.t_level_optical) @ VIEW.R_level_optical
    return VIEW.camera.project(optical)


@pytest.mark.parametrize("normal_deg", [160.0, 180.0, 215.0])
def test_corners_wound_either_way_give_the_same_observation(normal_deg: float) -> None:
    """A wall marker's corners as OpenCV lists them and reversed (as a detector that winds them
    the other way gives them): the same bearing, theta and range, the exact ones; only the
    reversed list is counted as read in reverse."""
    centre = np.array([2.5, 0.6, 0.9])
    normal = math.radians(normal_deg)
    corners = corners_of(centre, normal)
    bearing = math.atan2(centre[1], centre[0])
    theta = math.remainder(bearing + math.pi - normal, math.tau)
    model = ObservationModel(MarkerSizes(SIDE_M))
    as_listed = observe_levelled_frame([Detection(3, corners)], VIEW, model, 7)
    reversed_ = observe_levelled_frame([Detection(3, corners[::-1].copy())], VIEW, model, 7)
    assert as_listed.rewound == [] and reversed_.rewound == [3]
    for frame in (as_listed, reversed_):
        (obs,) = frame.observations
        assert obs.theta == pytest.approx(theta, abs=EXACT)
        assert obs.range_m == pytest.approx(math.hypot(*centre[:2]), abs=EXACT)
        assert obs.bearing == pytest.approx(bearing, abs=EXACT)
    np.testing.assert_allclose(reversed_.observations[0].corners, corners, atol=0)


def test_each_markers_drops_are_counted_and_said_as_they_are() -> None:
    """A wall marker seen four times, once slanted 60 deg down toward the camera (dropped), and
    a floor marker seen three times (all dropped): the counts, the drop's elevation, and the
    notes say that one of four detections of the wall marker was dropped (it is mapped) and
    that the floor marker is left out."""
    model = ObservationModel(MarkerSizes(SIDE_M))
    wall, floor = 4, 9
    frames = []
    for k in range(4):
        tilt = math.radians(-60.0) if k == 0 else 0.0
        detections = [Detection(wall, corners_of(np.array([2.0, 0.2 * k, 0.9]), math.pi, tilt))]
        if k < 3:
            floor_corners = corners_of(np.array([1.6, -0.3, 0.0]), math.pi, math.radians(88.0))
            detections.append(Detection(floor, floor_corners))
        frames.append(observe_levelled_frame(detections, VIEW, model, k))
    counts = tally_detections(frames)
    assert (counts[wall].detections, counts[wall].off_wall, counts[wall].no_pose) == (4, 1, 0)
    assert not counts[wall].left_out
    assert counts[wall].off_wall_elevation_rad == pytest.approx(math.radians(-60.0), abs=1e-4)
    assert (counts[floor].detections, counts[floor].dropped) == (3, 3) and counts[floor].left_out
    assert counts[floor].off_wall_elevation_rad == pytest.approx(math.radians(88.0), abs=1e-4)
    assert all(d.reason is DropReason.OFF_WALL for f in frames for d in f.dropped)
    assert counts[wall].rewound == counts[floor].rewound == 0
    assert sum(len(f.observations) for f in frames) == 3
    wall_note, floor_note = drop_notes(counts)
    assert wall_note.kind == "detections.dropped" and wall_note.figure == 1
    assert wall_note.text.startswith(f"1 of 4 detections of marker {wall} dropped")
    assert "60 deg from horizontal" in wall_note.text and "left out" not in wall_note.text
    assert floor_note.kind == "detections.marker_left_out" and floor_note.figure == 3
    assert floor_note.text.startswith(f"marker {floor} left out of the 2-D map: every one of its 3")
