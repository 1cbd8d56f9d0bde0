"""Logs of detections: message shapes to OpenCV's corner order, fisheye and Kalibr cameras, and
observations from a marker's full pose through a tilted camera, against exact geometry."""

from __future__ import annotations

import math
import re
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from markergraph.common.errors import SettingsError
from markergraph.frontend.camera import EQUIDISTANT, Camera
from markergraph.frontend.detect import Detection, load_dictionary
from markergraph.frontend.detections import TagFamilies, detections_of
from markergraph.frontend.observe import ObservationModel
from markergraph.frontend.posed import DropReason, LevelledCamera, observe_levelled_frame
from markergraph.frontend.sizes import MarkerSizes

EXACT = 1e-6  # noise-free corners through PnP: the pose comes back to solver precision

# Corners of one tag in OpenCV's order (top-left, top-right, bottom-right, bottom-left).
OPENCV = np.array([[100.0, 50.0], [160.0, 52.0], [158.0, 110.0], [98.0, 108.0]])


def point(x: float, y: float) -> SimpleNamespace:
    return SimpleNamespace(x=x, y=y, z=0.0)


@pytest.mark.parametrize("shape", ["tagslam", "points", "flat"])
def test_apriltag_corners_become_opencv_order(shape: str) -> None:
    """The AprilTag order (counter-clockwise from bottom-left) reversed is OpenCV's, for TagSLAM's
    ROS 1 array, apriltag_ros's Point[4] and float64[8] shapes."""
    apriltag = OPENCV[::-1]  # bottom-left, bottom-right, top-right, top-left
    if shape == "flat":
        tag = SimpleNamespace(id=7, corners=list(apriltag.ravel()))
    else:
        tag = SimpleNamespace(id=7, corners=[point(*c) for c in apriltag])
    message = (
        SimpleNamespace(apriltags=[tag])
        if shape == "tagslam"
        else SimpleNamespace(detections=[tag])
    )
    (found,) = detections_of(message)
    assert found.marker_id == 7
    np.testing.assert_array_equal(found.corners, OPENCV)


def families_of(**tag_fields: object) -> TagFamilies:
    """The families seen in one message holding one tag (id 7 unless given) with these fields."""
    tag = SimpleNamespace(**{"id": 7, **tag_fields}, corners=[point(*c) for c in OPENCV[::-1]])
    message = SimpleNamespace(detections=[tag])
    families = TagFamilies()
    families.take("/tags", message, detections_of(message))
    return families


@pytest.mark.parametrize(
    ("fields", "dictionary", "refused"),
    [
        ({"family": "36h11"}, "DICT_APRILTAG_36h11", None),
        ({"family": "tag36h11"}, "DICT_4X4_50", "pass --dictionary DICT_APRILTAG_36h11"),
        ({"family": "16h5"}, "DICT_APRILTAG_36h11", "pass --dictionary DICT_APRILTAG_16h5"),
        ({"family": "mit", "bits": 6}, "DICT_APRILTAG_36h11", None),
        ({"family": "mit", "bits": 6}, "DICT_APRILTAG_36h10", None),
        ({"family": "mit", "bits": 6}, "DICT_APRILTAG_16h5", "have 6x6 bits (family 'mit')"),
        ({"family": "umich", "bits": 4}, "DICT_4X4_50", None),
        ({"family": "mit", "bits": 6, "id": 586}, "DICT_APRILTAG_36h11", None),
        ({"family": "", "id": 586}, "DICT_4X4_1000", None),
        (
            {"family": "", "id": 586},
            "DICT_4X4_250",
            "tag 586 on /tags lies beyond DICT_4X4_250 "
            "(250 markers): pass --dictionary DICT_4X4_1000",
        ),
        ({"family": "mit", "bits": 6, "id": 2109}, "DICT_APRILTAG_36h11", None),
    ],
)
def test_tags_of_another_family_than_the_dictionary_are_refused(fields, dictionary, refused):
    """A map labels its markers with the dictionary: 36h11 tags (TagSLAM's 'mit' detector says
    so by their 6x6 bits) mapped as DICT_4X4_50 exported an ArUco file of id 586 in 4X4_50.
    The family field, the bits, and the highest id are each held to the dictionary's (its
    ``markerSize`` and size, as OpenCV defines them)."""
    families = families_of(**fields)
    if refused is None:
        notes = families.check(Path("log.bag"), dictionary)
        # An id no dictionary of the family holds (TagSLAM's test 24) is mapped, with a note.
        beyond = fields.get("id", 7) >= len(load_dictionary(dictionary).bytesList)
        assert [n.kind for n in notes] == ["detections.beyond_dictionary"] * beyond
        return
    with pytest.raises(SettingsError, match=re.escape(refused)) as raised:
        families.check(Path("log.bag"), dictionary)
    assert str(raised.value).startswith("log.bag: ") and "/tags" in str(raised.value)


def test_fisheye_undistortion_inverts_the_equidistant_projection() -> None:
    """Points projected through Kalibr's equidistant model of a T265 come back to where a
    distortion-free camera with the same K sees them."""
    camera = Camera(283.943, 284.986, 421.079, 400.527, 800, 848,
                    (0.00132, 0.03049, -0.02875, 0.0034), EQUIDISTANT)  # fmt: skip
    rng = np.random.default_rng(3)
    points = np.column_stack([rng.uniform(-1.5, 1.5, (50, 2)), np.ones(50)])  # up to 56 deg off
    distorted, _ = cv2.fisheye.projectPoints(
        points.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), camera.K, np.array(camera.distortion)
    )
    pinhole = camera.project(points)
    np.testing.assert_allclose(camera.undistort(distorted.reshape(-1, 2)), pinhole, atol=1e-4)


def test_kalibr_camera_reads_its_model() -> None:
    """A Kalibr entry gives the intrinsics, the size and the model (radtan is plumb_bob)."""
    entry = {
        "intrinsics": [610.0, 611.0, 320.5, 240.5],
        "distortion_model": "radtan",
        "distortion_coeffs": [0.1, -0.2, 0.001, 0.002],
        "resolution": [640, 480],
    }
    camera = Camera.from_kalibr(entry)
    assert (camera.fx, camera.cy, camera.width, camera.model) == (610.0, 240.5, 640, "plumb_bob")
    with pytest.raises(ValueError, match="distortion model 'kannala'"):
        Camera.from_kalibr({**entry, "distortion_model": "kannala"})


def rotation(axis: str, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return {
        "x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
        "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
        "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]),
    }[axis]


# Optical axes (x right, y down, z forward) in a level frame looking along +x.
R_LEVEL_FORWARD = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def seen(view: LevelledCamera, centre: np.ndarray, normal_yaw: float, tilt: float = 0.0):
    """The corners (OpenCV order) of a 0.2 m marker at ``centre`` in the level frame whose
    normal has heading ``normal_yaw`` and is tilted ``tilt`` up from horizontal."""
    n = np.array([math.cos(tilt) * math.cos(normal_yaw), math.cos(tilt) * math.sin(normal_yaw),
                  math.sin(tilt)])  # fmt: skip
    up_hint = np.array([0.0, 0.0, 1.0]) if abs(tilt) < 1.0 else np.array([1.0, 0.0, 0.0])
    right = np.cross(n, up_hint)  # the viewer's right, facing the marker
    right = -right / np.linalg.norm(right)
    up = np.cross(n, right)
    h = 0.1
    corners = [centre - right * h + up * h, centre + right * h + up * h,
               centre + right * h - up * h, centre - right * h - up * h]  # fmt: skip
    optical = (np.array(corners) - view.t_level_optical) @ view.R_level_optical
    return view.camera.project(optical)


def test_levelled_observation_is_exact_through_a_tilted_camera() -> None:
    """A camera rolled 8 deg and pitched 15 deg, 5 cm off the body origin, sees a wall marker:
    bearing, theta and range from the body origin come out as the geometry says; a ceiling
    marker is left out with its reason."""
    camera = Camera(600.0, 600.0, 640.0, 400.0, 1280, 800)
    R = rotation("z", 0.3) @ rotation("y", -math.radians(15)) @ rotation("x", math.radians(8))
    view = LevelledCamera(camera, R @ R_LEVEL_FORWARD, np.array([0.05, -0.02, 0.3]))
    centre, normal_yaw = np.array([2.5, 1.3, 0.9]), math.radians(200.0)
    corners = seen(view, centre, normal_yaw)
    frame = observe_levelled_frame(
        [Detection(4, corners)], view, ObservationModel(MarkerSizes(0.2)), 5
    )
    (obs,) = frame.observations
    bearing = math.atan2(centre[1], centre[0])
    assert not frame.dropped and obs.t_ns == 5
    assert obs.bearing == pytest.approx(bearing, abs=EXACT)
    assert obs.range_m == pytest.approx(math.hypot(*centre[:2]), abs=EXACT)
    assert obs.theta == pytest.approx(math.remainder(bearing + math.pi - normal_yaw, math.tau),
                                      abs=EXACT)  # fmt: skip
    assert 0 < obs.sigma_range < 0.05 and 0 < obs.sigma_theta < 0.2 and obs.sigma_bearing > 0
    ceiling = seen(view, np.array([2.0, 0.5, 2.4]), 0.0, tilt=-math.radians(85))
    frame = observe_levelled_frame(
        [Detection(9, ceiling)], view, ObservationModel(MarkerSizes(0.2)), 5
    )
    (dropped,) = frame.dropped
    assert frame.observations == [] and dropped.marker_id == 9
    assert dropped.reason is DropReason.OFF_WALL
    assert dropped.elevation_rad == pytest.approx(-math.radians(85), abs=1e-6)
