"""The 3-D simulator (datasets/scene3d.py) against independent projections and through the front
end: worlds of tags at any pose, a tilted multi-camera rig, its MCAP log and rig files."""

from __future__ import annotations

import math
import subprocess
import sys
from collections import Counter
from dataclasses import replace
from pathlib import Path
from typing import Any

import cv2
import gtsam
import numpy as np
import pytest

from markergraph.datasets.scene3d import (
    OUTLIER_PX,
    TRUE_TAGS3D,
    Board,
    OdometryDrift,
    Scene3dError,
    Scene3dTruth,
    SceneKind,
    TagDetection3d,
    detections,
    make_scene3d,
    odometry3d,
    read_scene3d_truth,
    tag_scene,
    write_rig_files,
    write_scene3d_log,
)
from markergraph.estimator.tags3d import tag_corners
from markergraph.frontend import open_log
from markergraph.frontend.camera import EQUIDISTANT, PLUMB_BOB, Camera
from markergraph.frontend.detections import detections_of
from markergraph.frontend.rig import read_camera_poses, read_kalibr_cameras, read_tagslam

EXACT = 1e-12  # exact algebra and values copied through a file
PROJECTION_PX = 1e-6  # two float64 projections of the same point
UNDISTORTION_RAY = 1e-5  # OpenCV's iterative undistortion (about 1e-3 px here)
PNP_M = 1e-3  # IPPE on noise-free corners (FACTS: rare flips; the median is exact)
SEED = 7


@pytest.fixture(scope="module")
def room4() -> Scene3dTruth:
    return make_scene3d(SEED, cameras=4, frames=80)


def _tag_world_corners(truth: Scene3dTruth, tag_id: int) -> np.ndarray:
    T = truth.tags[tag_id]
    return (T.rotation().matrix() @ tag_corners(truth.tag_sizes[tag_id]).T).T + T.translation()


def _linked(found: list[TagDetection3d]) -> int:
    """The number of groups of tags joined by being seen in the same picture."""
    parent: dict[int, int] = {}

    def root(a: int) -> int:
        while parent.setdefault(a, a) != a:
            a = parent[a]
        return a

    pictures: dict[tuple[int, int], list[int]] = {}
    for d in found:
        pictures.setdefault((d.frame, d.camera), []).append(d.tag_id)
    for ids in pictures.values():
        for i in ids:
            parent[root(i)] = root(ids[0])
    return len({root(a) for a in parent})


def test_default_room_has_tags_everywhere_seen_linked_by_a_tilted_rig() -> None:
    """The default room has tags on walls, floor, ceiling and a board, all off the vertical
    where not on walls; a one-camera tilted rig sees nearly every tag, in one linked group, in
    nearly every frame, with each detection inside the image, big enough and facing it."""
    truth = make_scene3d(SEED)
    assert len(truth.frame_times) == 300 and len(truth.tags) == 30
    assert set(truth.surfaces.values()) == {"wall", "floor", "ceiling", "board"}
    normals_z = {i: T.rotation().matrix()[2, 2] for i, T in truth.tags.items()}
    for i, on in truth.surfaces.items():
        expected = {"wall": 0.0, "floor": 1.0, "ceiling": -1.0, "board": math.sin(0.61)}[on]
        assert abs(normals_z[i] - expected) < 0.1, (i, on, normals_z[i])
    rpy = np.array([T.rotation().rpy() for T in truth.T_world_rig])
    assert np.degrees(np.abs(rpy[:, 0]).max()) > 5.0 and np.degrees(np.abs(rpy[:, 1]).max()) > 12
    found = detections(truth, SEED, 0.0)
    seen = Counter(d.tag_id for d in found)
    assert len(seen) >= 27 and {truth.surfaces[i] for i in seen} == set(truth.surfaces.values())
    assert _linked(found) == 1
    assert len({d.frame for d in found}) >= 0.9 * len(truth.frame_times)
    for d in found:
        camera = truth.cameras[d.camera].camera
        px = d.true_corners_px
        assert np.all((px >= 1.0) & (px <= [camera.width - 2.0, camera.height - 2.0]))
        assert np.linalg.norm(px - np.roll(px, -1, axis=0), axis=1).min() > 15.0
        c = np.asarray(truth.T_world_camera(d.frame, d.camera).translation())
        to_camera = c - _tag_world_corners(truth, d.tag_id).mean(axis=0)
        normal = truth.tags[d.tag_id].rotation().matrix()[:, 2]
        assert normal @ to_camera / np.linalg.norm(to_camera) > math.cos(math.radians(75.0))


@pytest.mark.parametrize("kind", [SceneKind.BOARD, SceneKind.CORRIDOR])
def test_board_and_corridor_scenes_see_every_tag_with_four_cameras(kind: SceneKind) -> None:
    """A board and a corridor, each seen by the four-camera rig: every tag detected, in one
    linked group."""
    truth = make_scene3d(SEED, cameras=4, kind=kind, frames=150)
    found = detections(truth, SEED, 0.0)
    assert {d.tag_id for d in found} == set(truth.tags)
    assert _linked(found) == 1


def test_projections_equal_opencvs_from_the_world_points(room4: Scene3dTruth) -> None:
    """Every detection's noise-free corners equal cv2.projectPoints (pinhole, plumb_bob,
    rational polynomial) or cv2.fisheye.projectPoints (equidistant) of the tag's corners in
    the world, with the camera's pose as rvec/tvec; the noisy ones differ by the noise."""
    found = detections(room4, SEED, 0.5)
    models: Counter[tuple[str, int]] = Counter()
    for d in found:
        camera = room4.cameras[d.camera].camera
        T_camera_world = room4.T_world_camera(d.frame, d.camera).inverse()
        rvec, _ = cv2.Rodrigues(T_camera_world.rotation().matrix())
        tvec = np.asarray(T_camera_world.translation())
        points = _tag_world_corners(room4, d.tag_id).reshape(-1, 1, 3)
        D = np.array(camera.distortion)
        if camera.model == EQUIDISTANT:
            pixels, _ = cv2.fisheye.projectPoints(points, rvec, tvec, camera.K, D)
        else:
            pixels, _ = cv2.projectPoints(points, rvec, tvec, camera.K, D if D.size else None)
        np.testing.assert_allclose(d.true_corners_px, pixels.reshape(4, 2), atol=PROJECTION_PX)
        models[(camera.model, len(camera.distortion))] += 1
    assert set(models) == {(PLUMB_BOB, 5), (EQUIDISTANT, 4), (PLUMB_BOB, 8), (PLUMB_BOB, 0)}
    noise = np.concatenate([(d.corners_px - d.true_corners_px).ravel() for d in found])
    assert abs(noise.std() - 0.5) < 0.02 and abs(noise.mean()) < 0.02


def test_outliers_move_one_corner_of_the_fraction_asked(room4: Scene3dTruth) -> None:
    """outliers=0.1 moves one corner of about a tenth of the detections by 5-20 px (binomial
    bound at 4 sigma) and leaves every other detection as it is without outliers."""
    clean = detections(room4, SEED, 0.5)
    dirty = detections(room4, SEED, 0.5, outliers=0.1)
    n = len(clean)
    flagged = [d for d in dirty if d.outlier]
    assert abs(len(flagged) - 0.1 * n) < 4.0 * math.sqrt(0.09 * n)
    for a, b in zip(clean, dirty, strict=True):
        moved = np.linalg.norm(b.corners_px - a.corners_px, axis=1)
        if b.outlier:
            assert np.count_nonzero(moved) == 1 and OUTLIER_PX[0] <= moved.max() <= OUTLIER_PX[1]
        else:
            np.testing.assert_array_equal(b.corners_px, a.corners_px)


def test_a_board_between_camera_and_tag_hides_it(room4: Scene3dTruth) -> None:
    """A wall tag seen in one frame is not seen once a board stands between it and the
    camera, and is seen again when the board stands beside the line of sight."""
    d = next(d for d in detections(room4, SEED, 0.0) if room4.surfaces[d.tag_id] == "wall")
    one = replace(room4, frame_times=room4.frame_times[d.frame : d.frame + 1],
                  T_world_rig=room4.T_world_rig[d.frame : d.frame + 1], boards=())  # fmt: skip
    c = np.asarray(one.T_world_camera(0, d.camera).translation())
    middle = (c + _tag_world_corners(one, d.tag_id).mean(axis=0)) / 2.0
    facing = gtsam.Rot3(one.T_world_camera(0, d.camera).rotation().matrix() @ np.diag([1, -1, -1]))

    def seen(centre: np.ndarray) -> bool:
        board = Board(gtsam.Pose3(facing, centre), 0.5, 0.5)
        found = detections(replace(one, boards=(board,)), SEED, 0.0)
        return any(f.tag_id == d.tag_id and f.camera == d.camera for f in found)

    aside = middle + 2.0 * one.T_world_camera(0, d.camera).rotation().matrix()[:, 0]
    assert not seen(middle)
    assert seen(aside)


def test_log_reads_back_through_the_front_end(room4: Scene3dTruth, tmp_path: Path) -> None:
    """The MCAP log through open_log and detections_of: every camera's corners as simulated
    (OpenCV's order), its camera_info giving the same Camera, /tf_static each mount, the
    odometry the drifted path, the truth topics the truth; the same seed writes the same bytes."""
    path = tmp_path / "room.mcap"
    found = write_scene3d_log(room4, path, SEED, odometry=True)
    assert found and {d.camera for d in found} == {0, 1, 2, 3}
    expected = {(int(room4.frame_times[d.frame]), d.camera, d.tag_id): d for d in found}
    names = [c.name for c in room4.cameras]
    log = open_log(path)
    topics = [f"/{n}/tags" for n in names] + [f"/{n}/camera_info" for n in names]
    read: dict[tuple[int, int, int], np.ndarray] = {}
    odometry = []
    for message in log.messages([*topics, "/tf_static", "/odom", TRUE_TAGS3D]):
        m, topic = message.decoded, message.topic
        if topic == TRUE_TAGS3D:
            assert len(m.transforms) == len(room4.tags)
            for tf in m.transforms:
                assert tf.header.frame_id == "world"
                _assert_transform(tf.transform, room4.tags[int(tf.child_frame_id[4:])])
        elif topic.endswith("/tags"):
            k = names.index(topic.split("/")[1])
            assert m.header.frame_id == room4.cameras[k].frame_id
            t_ns = m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
            for detection in detections_of(m):
                read[(t_ns, k, detection.marker_id)] = detection.corners
        elif topic.endswith("/camera_info"):
            k = names.index(topic.split("/")[1])
            assert Camera.from_camera_info(m) == room4.cameras[k].camera
        elif topic == "/tf_static":
            for tf in m.transforms:
                sim = next(c for c in room4.cameras if c.frame_id == tf.child_frame_id)
                assert tf.header.frame_id == "base_link"
                _assert_transform(tf.transform, sim.T_rig_camera)
        else:
            assert m.child_frame_id == "base_link"
            odometry.append(m.pose.pose)
    for pose, T in zip(odometry, odometry3d(room4, SEED), strict=True):
        _assert_transform(pose, T)
    assert read.keys() == expected.keys()
    for key, corners in read.items():
        np.testing.assert_array_equal(corners, expected[key].corners_px)
    truth = read_scene3d_truth(path)
    assert truth.kind == room4.kind and truth.surfaces == room4.surfaces
    for a, b in zip(truth.cameras, room4.cameras, strict=True):
        assert (a.name, a.camera) == (b.name, b.camera) and a.T_rig_camera.equals(b.T_rig_camera, 0)
    assert truth.tag_sizes == room4.tag_sizes and truth.tags.keys() == room4.tags.keys()
    assert all(truth.tags[i].equals(T, 0) for i, T in room4.tags.items())
    np.testing.assert_array_equal(truth.frame_times, room4.frame_times)
    for a, b in zip(truth.T_world_rig, room4.T_world_rig, strict=True):
        assert a.equals(b, 0)
    again = tmp_path / "again.mcap"
    write_scene3d_log(room4, again, SEED, odometry=True)
    assert again.read_bytes() == path.read_bytes()


def _assert_transform(transform: Any, T: gtsam.Pose3) -> None:
    """A geometry_msgs Transform (or Pose) is T."""
    t = getattr(transform, "translation", None) or transform.position
    q = getattr(transform, "rotation", None) or transform.orientation
    R = gtsam.Rot3.Quaternion(q.w, q.x, q.y, q.z).matrix()
    np.testing.assert_allclose([t.x, t.y, t.z], T.translation(), atol=EXACT)
    np.testing.assert_allclose(R, T.rotation().matrix(), atol=EXACT)


def test_without_mounts_the_log_has_no_tf_static(room4: Scene3dTruth, tmp_path: Path) -> None:
    """mounts="none" leaves /tf_static out, and a log with no truth topic is refused."""
    path = tmp_path / "none.mcap"
    write_scene3d_log(replace(room4, cameras=room4.cameras[:2]), path, SEED, mounts="none")
    topics = {t.topic for t in open_log(path).topics}
    assert "/tf_static" not in topics and "/odom" not in topics
    assert {"/cam0/tags", "/cam1/tags", "/cam1/camera_info"} <= topics
    with pytest.raises(Scene3dError, match="not a 3-D scene"):
        Scene3dTruth.from_json('{"version": 1}', "x")


def test_markergraph_info_lists_the_detection_topics(tmp_path: Path) -> None:
    """`markergraph info` reads the log: each detection topic with its lens model, its mount
    from /tf_static, the odometry, and says it can be mapped."""
    path = tmp_path / "info.mcap"
    write_scene3d_log(make_scene3d(SEED, cameras=2, frames=20), path, SEED, odometry=True)
    done = subprocess.run(
        [sys.executable, "-m", "markergraph.cli", "info", str(path), "--dictionary",
         "DICT_APRILTAG_36h11"],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    expected = (
        "detections   /cam0/tags", "detections   /cam1/tags", "equidistant",
        "base_link -> cam1_optical_frame", "odometry     /odom", "can map: yes",
    )  # fmt: skip
    for text in expected:
        assert text in done.stdout, (text, done.stdout)


def test_odometry_is_the_true_motion_plus_drift(room4: Scene3dTruth) -> None:
    """Without drift the odometry is the true path seen from the first frame; with it, the
    final pose is off by centimetres, not metres, and the same seed drifts the same way."""
    exact = odometry3d(room4, SEED, OdometryDrift(0.0, 0.0, 0.0, 0.0))
    start = room4.T_world_rig[0]
    for T_odom_rig, T_world_rig in zip(exact, room4.T_world_rig, strict=True):
        assert T_odom_rig.equals(start.between(T_world_rig), 1e-9)
    drifted = odometry3d(room4, SEED)
    error_m = np.linalg.norm(drifted[-1].translation() - exact[-1].translation())
    assert 0.002 < error_m < 0.5
    assert odometry3d(room4, SEED)[-1].equals(drifted[-1], EXACT)


def test_rig_files_read_back_through_the_front_end(room4: Scene3dTruth, tmp_path: Path) -> None:
    """cameras.yaml gives every camera's intrinsics and lens back, camera_poses.yaml the mounts
    asked for (rotation vectors), tagslam.yaml every tag's size."""
    files = write_rig_files(room4, tmp_path, mounts_for=["cam0", "cam2"], surveyed=[0, 3])
    cameras = {c.name: c for c in read_kalibr_cameras(files["cameras.yaml"])}
    for sim in room4.cameras:
        assert cameras[sim.name].camera == sim.camera
        assert cameras[sim.name].tag_topic == f"/{sim.name}/tags"
    poses = read_camera_poses(files["camera_poses.yaml"])
    assert set(poses) == {"cam0", "cam2"}
    for name, pose in poses.items():
        T = next(c for c in room4.cameras if c.name == name).T_rig_camera
        np.testing.assert_allclose(pose.R, T.rotation().matrix(), atol=EXACT)
        np.testing.assert_allclose(pose.t, T.translation(), atol=EXACT)
    assert read_tagslam(files["tagslam.yaml"]).tag_sizes_m == room4.tag_sizes
    with pytest.raises(ValueError, match="cam9"):
        write_rig_files(room4, tmp_path, mounts_for=["cam9"])


def test_tag_scene_gives_the_estimator_true_rays_and_pnp_seeds(room4: Scene3dTruth) -> None:
    """tag_scene's views hold the corners' true normalised rays (noise-free detections) and a
    PnP pose of each tag in the camera near the truth."""
    found = detections(room4, SEED, 0.0)
    scene = tag_scene(room4, found, pixel_noise_px=0.5, mounts_for=["cam1"], surveyed=[4])
    assert len(scene.views) == len(found)
    assert [c.T_rig_camera is None for c in scene.cameras] == [True, False, True, True]
    assert scene.cameras[1].T_rig_camera.equals(room4.cameras[1].T_rig_camera, 0)
    assert [k.tag_id for k in scene.known_tags] == [4] and scene.known_tags[0].T_map_tag.equals(
        room4.tags[4], 0
    )
    pnp_errors = []
    for d, view in zip(found, scene.views, strict=True):
        T_camera_tag = room4.T_world_camera(d.frame, d.camera).between(room4.tags[d.tag_id])
        p = (T_camera_tag.rotation().matrix() @ tag_corners(room4.tag_sizes[d.tag_id]).T).T
        p += T_camera_tag.translation()
        np.testing.assert_allclose(view.rays, p[:, :2] / p[:, 2:], atol=UNDISTORTION_RAY)
        camera = room4.cameras[d.camera].camera
        np.testing.assert_allclose(view.sigma, 0.5 * view.ray_per_px)
        if not camera.distortion:  # a plain pinhole: a pixel is 1/f of a ray everywhere
            np.testing.assert_allclose(view.ray_per_px, 1.0 / camera.fx, rtol=1e-6)
        pnp_errors.append(np.linalg.norm(view.T_camera_tag.translation() - p.mean(axis=0)))
    assert np.median(pnp_errors) < EXACT * 1e3 and max(pnp_errors) < PNP_M
