"""Range without depth: the marker's full pose (PnP, what markergraph uses) against its edge
length alone (the size-based range it replaced), on rendered frames and on real photos.

- Rendered paper room (2 Hz, the first 60 s): median |horizontal range error| against the
  simulator's truth.
- OpenCV's ChArUco calibration photos (../shared/data/opencv-aruco-tutorial, img_00..03, its own
  calibration): every pair of markers' centre-to-centre distance against the board's geometry
  (5x7 squares of 40 mm, 20 mm markers), the centres placed in 3-D from each range.

Usage: python tests/benchmarks/range_without_depth.py
"""

from __future__ import annotations

import itertools
from pathlib import Path

import cv2
import gtsam
import numpy as np

from markergraph.datasets import scenario
from markergraph.datasets.render import Renderer
from markergraph.datasets.route import drive
from markergraph.frontend.camera import Camera
from markergraph.frontend.detect import Detector
from markergraph.frontend.observe import ObservationModel, observe_detections
from markergraph.frontend.sizes import MarkerSizes
from markergraph.frontend.yaw import marker_centre, pnp_pose

TUTORIAL = Path(__file__).resolve().parents[3] / "shared/data/opencv-aruco-tutorial/modules/aruco"


def size_range_z(corners: np.ndarray, camera: Camera, side_m: float) -> float:
    """The replaced estimate: the mean vertical edge images f * L / Z."""
    left = np.linalg.norm(corners[0] - corners[3])
    right = np.linalg.norm(corners[1] - corners[2])
    return float(camera.fy * side_m / ((left + right) / 2.0))


def rendered() -> None:
    world, route = scenario("paper-room")
    renderer = Renderer(world)
    rng = np.random.default_rng(0)
    detector = Detector(allowed_ids=[m.id for m in world.markers])
    camera, mount = renderer.camera, renderer.mount
    pose_errors, size_errors = [], []
    for pose in drive(world, route, rng, frame_hz=2.0).frame_poses[:120]:
        T_world_base = gtsam.Pose2(*pose)
        at = T_world_base.compose(mount.T_base_camera).translation()
        for detection in detector.detect(renderer.render(T_world_base, rng).rgb):
            truth = np.linalg.norm(world.T_world_marker(detection.marker_id).translation() - at)
            (obs,) = observe_detections(
                [detection], camera, ObservationModel(MarkerSizes(0.2)), mount=mount
            )
            pose_errors.append(abs(obs.range_m - truth))
            corners = camera.undistort(detection.corners)
            centre = marker_centre(corners)
            ray = np.array([(centre[0] - camera.cx) / camera.fx,
                            (centre[1] - camera.cy) / camera.fy, 1.0])  # fmt: skip
            p_base = mount.R_base_optical @ (size_range_z(corners, camera, 0.2) * ray)
            size_errors.append(abs(np.hypot(p_base[0], p_base[1]) - truth))
    pose_cm, size_cm = 100 * np.median(pose_errors), 100 * np.median(size_errors)
    print(
        f"rendered paper room, {len(pose_errors)} observations: median range error "
        f"PnP {pose_cm:.1f} cm, edge length {size_cm:.1f} cm"
    )


def photos() -> None:
    if not TUTORIAL.is_dir():
        print("real photos: ../shared/data/opencv-aruco-tutorial is absent")
        return
    camera = Camera.from_opencv_yaml(TUTORIAL / "samples/tutorial_camera_charuco.yml")
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250)
    board = cv2.aruco.CharucoBoard((5, 7), 0.04, 0.02, dictionary)
    centres = {int(i): np.mean(c, axis=0) for i, c in zip(board.getIds().ravel(),
               board.getObjPoints(), strict=True)}  # fmt: skip
    detector = Detector("DICT_6X6_250")
    pose_errors, size_errors = [], []
    for image in sorted((TUTORIAL / "tutorials/aruco_calibration/images").glob("img_0*.jpg")):
        gray = cv2.imread(str(image), cv2.IMREAD_GRAYSCALE)
        placed: dict[str, dict[int, np.ndarray]] = {"pose": {}, "size": {}}
        for detection in detector.detect(gray):
            corners = camera.undistort(detection.corners)
            pose = pnp_pose(corners, camera, 0.02)
            if pose is None or detection.marker_id not in centres:
                continue
            placed["pose"][detection.marker_id] = pose[1]
            ray = pose[1] / pose[1][2]
            placed["size"][detection.marker_id] = size_range_z(corners, camera, 0.02) * ray
        for a, b in itertools.combinations(sorted(placed["pose"]), 2):
            truth = np.linalg.norm(centres[a] - centres[b])
            for kind, errors in (("pose", pose_errors), ("size", size_errors)):
                errors.append(abs(np.linalg.norm(placed[kind][a] - placed[kind][b]) - truth))
    print(
        f"ChArUco photos, {len(pose_errors)} marker pairs: median distance error "
        f"PnP {1000 * np.median(pose_errors):.1f} mm, edge length "
        f"{1000 * np.median(size_errors):.1f} mm"
    )


if __name__ == "__main__":
    rendered()
    photos()
