"""Marker corners (:func:`~markergraph.frontend.detect.edge_refined`) against independent truth:
the simulator's projected corners, and on real photos of a ChArUco board the corners its
chessboard's saddle points (which blur does not move) put each marker at."""

from __future__ import annotations

from pathlib import Path

import cv2
import gtsam
import numpy as np
import pytest
from numpy.typing import NDArray

from markergraph.datasets import scenario
from markergraph.datasets.render import Renderer
from markergraph.datasets.route import drive
from markergraph.frontend.detect import Detector

TUTORIAL = Path(__file__).resolve().parents[2] / "shared/data/opencv-aruco-tutorial/modules/aruco"
CHARUCO_PHOTOS = [
    "tutorials/charuco_detection/images/choriginal.jpg",
    "tutorials/charuco_detection/images/chocclusion_original.jpg",
    *(f"tutorials/aruco_calibration/images/img_0{i}.jpg" for i in range(4)),
]


def inset(corners: NDArray[np.float64], true: NDArray[np.float64]) -> NDArray[np.float64]:
    """Each corner's offset from the true one toward the marker's centre [px]."""
    inward = true.mean(axis=0) - true
    inward /= np.linalg.norm(inward, axis=1, keepdims=True)
    return np.sum((corners - true) * inward, axis=1)


def opencv_corners(gray: NDArray[np.uint8], dictionary: str) -> dict[int, NDArray[np.float64]]:
    """OpenCV's detector with its sub-pixel corners, as it is."""
    parameters = cv2.aruco.DetectorParameters()
    parameters.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    predefined = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    corners, ids, _ = cv2.aruco.ArucoDetector(predefined, parameters).detectMarkers(gray)
    found = zip(corners, [] if ids is None else ids.ravel(), strict=True)
    return {int(i): np.asarray(c, dtype=np.float64).reshape(4, 2) for c, i in found}


def compare(pairs: list[tuple[NDArray, NDArray, NDArray]]) -> dict[str, float]:
    """(OpenCV's, ours, true) corners of each marker -> mean inset and median error of each."""
    theirs, ours, true = (np.concatenate(side) for side in zip(*pairs, strict=True))
    return {
        "inset opencv": float(np.mean([inset(c, t) for c, _, t in pairs])),
        "inset ours": float(np.mean([inset(c, t) for _, c, t in pairs])),
        "error opencv": float(np.median(np.linalg.norm(theirs - true, axis=1))),
        "error ours": float(np.median(np.linalg.norm(ours - true, axis=1))),
    }


@pytest.mark.parametrize("name", ["paper-room", "office"])
@pytest.mark.slow
def test_corners_sit_on_the_rendered_truth(name: str) -> None:
    """On a minute of each rendered log OpenCV's corners sit 0.28-0.39 px inside the true ones
    (median error 0.28-0.37 px); ours 0.01-0.05 px (0.04-0.07 px)."""
    world, route = scenario(name)
    renderer = Renderer(world)
    rng = np.random.default_rng(0)
    pairs = []
    ours = Detector()
    for pose in drive(world, route, rng, frame_hz=5.0, duration_s=60.0).frame_poses:
        T_world_base = gtsam.Pose2(*pose)
        frame = renderer.render(T_world_base, rng)
        gray = cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY)
        theirs = opencv_corners(gray, "DICT_4X4_50")
        for detection in ours.detect(gray):
            if detection.marker_id in theirs:
                corners = world.marker_corners(detection.marker_id)
                true = renderer.camera.project(
                    renderer.mount.world_to_optical(T_world_base, corners)
                )
                pairs.append((theirs[detection.marker_id], detection.corners, true))
    figures = compare(pairs)
    assert len(pairs) > 150
    assert figures["inset opencv"] > 0.2
    assert abs(figures["inset ours"]) < 0.1
    assert figures["error ours"] < 0.3 * figures["error opencv"]


@pytest.mark.skipif(not TUTORIAL.is_dir(), reason="../shared/data is not beside the repo")
def test_corners_on_real_charuco_photos() -> None:
    """OpenCV's tutorial photos of its 5x7 ChArUco board (4 cm squares, 2 cm DICT_6X6_250
    markers centred in them): a marker's true corners are where its square's four chessboard
    saddle points (found by OpenCV to a few hundredths of a pixel, and not moved by blur) put
    them through that square's homography. OpenCV's corners sit 0.46-0.57 px inside those;
    ours half as far, with half the median error."""
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250)
    board = cv2.aruco.CharucoBoard((5, 7), 0.04, 0.02, dictionary)
    chess_xy = board.getChessboardCorners()[:, :2]
    marker_xy = {
        int(i): np.asarray(p)[:, :2]
        for i, p in zip(board.getIds(), board.getObjPoints(), strict=True)
    }
    ours = Detector("DICT_6X6_250")
    pairs = []
    for photo in CHARUCO_PHOTOS:
        gray = cv2.imread(str(TUTORIAL / photo), cv2.IMREAD_GRAYSCALE)
        saddles, saddle_ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(gray)
        found = dict(zip(saddle_ids.ravel().tolist(), saddles.reshape(-1, 2), strict=True))
        theirs = opencv_corners(gray, "DICT_6X6_250")
        for detection in ours.detect(gray):
            square = marker_xy[detection.marker_id]
            distance = np.linalg.norm(chess_xy - square.mean(axis=0), axis=1)
            nearest = np.argsort(distance)[:4]  # its square's corners, if inside the board
            if not np.allclose(distance[nearest], distance[nearest[0]]) or not all(
                int(n) in found for n in nearest
            ):
                continue
            H, _ = cv2.findHomography(chess_xy[nearest], np.array([found[int(n)] for n in nearest]))
            true = cv2.perspectiveTransform(square[None].astype(np.float64), H)[0]
            pairs.append((theirs[detection.marker_id], detection.corners, true))
    figures = compare(pairs)
    assert len(pairs) >= 30
    assert figures["inset opencv"] > 0.4
    assert figures["inset ours"] < 0.6 * figures["inset opencv"]
    assert figures["error ours"] < 0.7 * figures["error opencv"]
