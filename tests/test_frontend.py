"""The front end against OpenCV's published corners, exact geometry, simulated and real logs."""

from __future__ import annotations

import itertools
import math
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import cv2
import gtsam
import numpy as np
import pytest
import yaml
from mcap_ros2.writer import Writer

from markergraph.common.errors import MarkerGraphError
from markergraph.datasets import Marker, Wall, World, scenario
from markergraph.datasets.write import write_log
from markergraph.formats import read_observations
from markergraph.frontend import (
    FrontendConfig,
    LogError,
    decode_image,
    extract,
    open_log,
)
from markergraph.frontend.camera import Camera, CameraMount
from markergraph.frontend.detect import Detection, Detector
from markergraph.frontend.observe import ObservationModel, observe, observe_detections
from markergraph.frontend.ros2 import MESSAGE_DEFINITIONS, header
from markergraph.frontend.sizes import MarkerSizes
from markergraph.frontend.yaw import YawMethod, yaw_from_corners
from markergraph.settings import MapConfig

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
TUTORIAL = DATA / "opencv-aruco-tutorial" / "modules" / "aruco"
needs_data = pytest.mark.skipif(not DATA.is_dir(), reason="../shared/data is not beside the repo")


def gold_corners() -> dict[int, np.ndarray]:
    """OpenCV's expected corners for singlemarkersoriginal.jpg, read from its own test file."""
    text = (TUTORIAL / "test_aruco_tutorial.cpp.txt").read_text()
    block = text[text.index("can_find_singlemarkersoriginal") :]
    corners = re.search(r"goldCorners\[N\]\[8\] = \{(.*?)\};", block, re.S).group(1)
    ids = re.search(r"goldCornersIds\[N\] = \{(.*?)\};", block, re.S).group(1)
    rows = [
        np.array(list(map(float, row.split(",")))).reshape(4, 2)
        for row in re.findall(r"\{([^{}]*)\}", corners)
    ]
    return dict(zip(map(int, ids.split(",")), rows, strict=True))


@needs_data
@pytest.mark.parametrize("subpixel", [False, True])
def test_tutorial_photo_ids_and_corners_match_opencv(subpixel: bool) -> None:
    """On OpenCV's tutorial photo the ids and corners match OpenCV's expected values within its
    own test's 1 px. Those are whole pixels of the marker's contour, the centres of its corner
    pixels: half a pixel inside the square's edges, where sub-pixel corners sit."""
    image = cv2.imread(str(TUTORIAL / "tutorials/aruco_detection/images/singlemarkersoriginal.jpg"))
    found = Detector("DICT_6X6_250", subpixel=subpixel).detect(image[..., ::-1].copy())
    gold = gold_corners()
    assert sorted(d.marker_id for d in found) == sorted(gold)
    for detection in found:
        expected = gold[detection.marker_id]
        if subpixel:
            expected = expected + 0.5 * np.sign(expected - expected.mean(axis=0))
        np.testing.assert_allclose(detection.corners, expected, atol=1.0)


@needs_data
def test_custom_dictionary_file_and_allow_list() -> None:
    """The board photo's custom dictionary loads from its file; an allow list filters ids."""
    image = cv2.imread(str(TUTORIAL / "tutorials/aruco_board_detection/images/gboriginal.png"))
    dictionary = str(TUTORIAL / "samples/tutorial_dict.yml")
    assert len(Detector(dictionary).detect(image)) == 35
    assert {d.marker_id for d in Detector(dictionary, allowed_ids=[0, 1, 2]).detect(image)} == {
        0,
        1,
        2,
    }


@needs_data
def test_camera_from_opencv_calibration_file() -> None:
    """Intrinsics and distortion load from OpenCV's calibration YAML."""
    camera = Camera.from_opencv_yaml(TUTORIAL / "samples/tutorial_camera_params.yml")
    assert (camera.fx, camera.fy, camera.cx, camera.cy) == (628.158, 628.156, 324.099, 260.908)
    assert camera.distortion[:2] == (0.0995485, -0.206384)


# --- yaw on exact projected corners -----------------------------------------------------------

LEVEL = CameraMount(x_m=0.0, height_m=1.0, pitch_rad=0.0)  # at the marker's height, level


def exact_corners(
    d: float, theta: float, bearing: float, mount: CameraMount = LEVEL, dither_px: float = 0.0
) -> tuple[np.ndarray, Camera]:
    """Corners of a 0.2 m marker seen from polar (d, theta) in its frame, at a bearing."""
    world = World("one", (Wall((-5.0, 0.0), (5.0, 0.0)),), (Marker(0, 0, 5.0, side=1),), 0)
    T_marker = world.T_world_marker(0)
    p_camera = T_marker.transformFrom(np.array([d * math.cos(theta), d * math.sin(theta)]))
    facing = T_marker.theta() + theta + math.pi  # straight at the marker ...
    T_world_base = gtsam.Pose2(p_camera[0], p_camera[1], facing - bearing)  # ... then turned
    camera = Camera()
    corners = camera.project(mount.world_to_optical(T_world_base, world.marker_corners(0)))
    rng = np.random.default_rng(0)
    return corners + rng.uniform(-dither_px, dither_px, corners.shape), camera


@pytest.mark.parametrize("theta_deg", [-60, -30, -10, 10, 30, 60])
@pytest.mark.parametrize("d", [1.0, 3.0])
def test_mean_edge_is_exact_for_a_centred_marker(theta_deg: float, d: float) -> None:
    """Level camera, centred marker: s_a / mean vertical edge = cos(theta) exactly."""
    corners, _ = exact_corners(d, math.radians(theta_deg), 0.0)
    assert yaw_from_corners(corners, YawMethod.MEAN_EDGE) == pytest.approx(
        math.radians(theta_deg), abs=1e-9
    )


@pytest.mark.parametrize("bearing_deg", [-20, -8, 8, 20])
@pytest.mark.parametrize("theta_deg", [-45, -20, -5, 5, 20, 45])
def test_calibrated_undoes_the_bearing(theta_deg: float, bearing_deg: float) -> None:
    """Off-centre the ratio is cos(theta)/cos(bearing) exactly; CALIBRATED is exact, also
    where the paper's sign rule (left edge shorter => theta > 0) picks the wrong side."""
    theta, bearing = math.radians(theta_deg), math.radians(bearing_deg)
    corners, camera = exact_corners(2.0, theta, bearing)
    s_a = (abs(corners[0, 0] - corners[1, 0]) + abs(corners[2, 0] - corners[3, 0])) / 2
    mean_edge = (abs(corners[0, 1] - corners[3, 1]) + abs(corners[1, 1] - corners[2, 1])) / 2
    assert s_a / mean_edge == pytest.approx(math.cos(theta) / math.cos(bearing), abs=1e-9)
    assert yaw_from_corners(corners, YawMethod.CALIBRATED, camera) == pytest.approx(theta, abs=1e-6)
    assert abs(yaw_from_corners(corners, YawMethod.MEAN_EDGE) - theta) > 1e-3


def test_paper_formula_uses_one_edge_and_fails_for_small_positive_theta() -> None:
    """PAPER is arccos(s_a / left edge) with the paper's sign: biased, and NaN for small
    theta > 0, where the left edge is the farther one and images shorter than s_a."""
    corners, _ = exact_corners(1.0, math.radians(30.0), 0.0)
    left = abs(corners[0, 1] - corners[3, 1])
    s_a = (abs(corners[0, 0] - corners[1, 0]) + abs(corners[2, 0] - corners[3, 0])) / 2
    assert yaw_from_corners(corners, YawMethod.PAPER) == pytest.approx(math.acos(s_a / left))
    # Biased by about -5.7 degrees / d[m] at 30 degrees and 1 m:
    bias = math.degrees(yaw_from_corners(corners, YawMethod.PAPER)) - 30.0
    assert -8.0 < bias < -4.0
    small, _ = exact_corners(1.0, math.radians(3.0), 0.0)
    assert math.isnan(yaw_from_corners(small, YawMethod.PAPER))
    mirrored, _ = exact_corners(1.0, math.radians(-3.0), 0.0)
    assert yaw_from_corners(mirrored, YawMethod.PAPER) < 0.0


@pytest.mark.parametrize("theta_deg", [-50, -20, 20, 50])
def test_pnp_recovers_theta_on_dithered_corners(theta_deg: float) -> None:
    """IPPE with the marker size recovers theta even with a pitched, raised camera (0.001 px
    dither: exactly noise-free corners of a purely yawed marker trip IPPE)."""
    mount = CameraMount(x_m=0.0, height_m=0.6, pitch_rad=math.radians(10.0))
    corners, camera = exact_corners(2.0, math.radians(theta_deg), 0.1, mount, dither_px=0.001)
    assert yaw_from_corners(corners, YawMethod.PNP, camera, 0.2) == pytest.approx(
        math.radians(theta_deg), abs=2e-3
    )


def test_a_small_markers_mirrored_pose_is_flagged_and_covered() -> None:
    """A 16 px marker 7.5 m away at 25 deg: its two planar poses (theta and about -theta) differ
    by 0.1-0.2 px at the corners, under their 0.3 px noise, so IPPE picks the mirrored one in
    some draws. Every such draw is flagged ambiguous, its sigma (with the view's shared part)
    covering the error within 2.5 sigma, never the few degrees a clear view gets: a ratio of
    reprojection errors near zero once let 1 in 4 through on the simulated warehouse."""
    corners, camera = exact_corners(7.5, math.radians(25.0), 0.0)
    rng = np.random.default_rng(7)
    model = ObservationModel(MarkerSizes(0.2))
    mirrored = 0
    for _ in range(300):
        noisy = corners + rng.normal(0.0, 0.3, corners.shape)
        (o,) = observe_detections([Detection(0, noisy)], camera, model, mount=LEVEL)
        error = abs(o.theta - math.radians(25.0))
        if error > math.radians(30.0):
            mirrored += 1
            assert "ambiguous" in o.flags
            assert error < 2.5 * math.hypot(o.sigma_theta, o.sigma_theta_shared)
    assert mirrored >= 10  # the case is exercised


def test_range_without_depth_comes_from_size_and_is_flagged() -> None:
    """With no depth image the range is estimated from the marker's size and flagged no-depth."""
    world, _ = scenario("paper-room")
    from markergraph.datasets.render import Renderer

    renderer = Renderer(world)
    T_world_base = gtsam.Pose2(1.8, 1.5, math.pi)  # 1.7 m in front of the home marker
    frame = renderer.render(T_world_base, np.random.default_rng(0))
    with_depth = observe(
        frame.rgb, renderer.camera, MarkerSizes(0.2), depth=frame.depth_mm, mount=renderer.mount
    )
    without = observe(frame.rgb, renderer.camera, MarkerSizes(0.2), mount=renderer.mount)
    assert len(with_depth) == len(without) == 1
    assert "no-depth" in without[0].flags and "no-depth" not in with_depth[0].flags
    assert without[0].range_m == pytest.approx(with_depth[0].range_m, abs=0.1)
    with pytest.raises(ValueError, match="not aligned"):
        observe(frame.rgb, renderer.camera, MarkerSizes(0.2), depth=frame.depth_mm[::2, ::2])


# --- simulated logs ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def simulated(tmp_path_factory: pytest.TempPathFactory) -> list[tuple[Path, object]]:
    folder = tmp_path_factory.mktemp("logs")
    runs = []
    for name in ("paper-room", "office"):
        world, route = scenario(name)
        path = folder / f"{name}.mcap"
        write_log(world, route, path, seed=4, compressed=True, frame_hz=3.0)
        runs.append((path, extract(path, FrontendConfig(allowed_ids=tuple(range(30))))))
    return runs


@pytest.mark.slow
@pytest.mark.slow
def test_observations_match_ground_truth_on_simulated_logs(simulated) -> None:
    """Median |theta error| <= 1 deg within 2 m and <= 2 deg within 3 m (|theta| >= 15 deg);
    median range error <= 2 cm; bearings within 0.2 deg."""
    rows = []
    for _, result in simulated:
        T_base_camera = result.mount.T_base_camera
        for obs in result.observations:
            T_camera = result.true_path.at(obs.t_ns).compose(T_base_camera)
            T_marker = result.true_markers[obs.marker_id]
            local = T_marker.transformTo(T_camera.translation())
            seen = T_camera.transformTo(T_marker.translation())
            rows.append(
                (
                    math.hypot(*local),
                    math.atan2(local[1], local[0]),
                    abs(obs.theta - math.atan2(local[1], local[0])),
                    abs(obs.range_m - math.hypot(*local)),
                    abs(obs.bearing - math.atan2(seen[1], seen[0])),
                )
            )
    rows = np.array(rows)
    oblique = np.abs(rows[:, 1]) >= math.radians(15.0)
    near = oblique & (rows[:, 0] < 2.0)
    mid = oblique & (rows[:, 0] < 3.0)
    assert near.sum() >= 10 and mid.sum() >= 30
    assert np.degrees(np.median(rows[near, 2])) <= 1.0
    assert np.degrees(np.median(rows[mid, 2])) <= 2.0
    assert np.median(rows[:, 3]) <= 0.02
    assert np.degrees(np.median(rows[:, 4])) <= 0.2


def errors_against_truth(result) -> np.ndarray:
    """Rows (true range, true theta, |theta error|, |range error|, |bearing error|)."""
    T_base_camera = result.mount.T_base_camera
    rows = []
    for obs in result.observations:
        T_camera = result.true_path.at(obs.t_ns).compose(T_base_camera)
        T_marker = result.true_markers[obs.marker_id]
        local = T_marker.transformTo(T_camera.translation())
        seen = T_camera.transformTo(T_marker.translation())
        true_theta = math.atan2(local[1], local[0])
        rows.append((math.hypot(*local), true_theta, abs(obs.theta - true_theta),
                     abs(obs.range_m - math.hypot(*local)),
                     abs(obs.bearing - math.atan2(seen[1], seen[0]))))  # fmt: skip
    return np.array(rows)


@pytest.mark.slow
@pytest.mark.slow
def test_tilted_base_is_levelled_with_the_odometrys_attitude(simulated, tmp_path: Path) -> None:
    """The rendered log rewritten as if the base stood rolled 8 deg (a ramp) with the camera
    counter-rolled on it, so the images are the same: /odom carries the roll, /tf_static the
    rolled mount. Every frame is levelled with the odometry's attitude and the observations keep
    their accuracy against the truth (ranges from PnP, as depth is not used there)."""
    from markergraph.datasets.rewrite import rewrite_log
    from markergraph.frontend.ros2 import quaternion_from_matrix
    from markergraph.frontend.tf import rotation_of

    path, level = simulated[0]
    roll = math.radians(8.0)
    R_roll = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(roll), -math.sin(roll)],
                       [0.0, math.sin(roll), math.cos(roll)]])  # fmt: skip

    def tilt(topic: str, _: int, message):
        if topic == "/odom":
            q = message.pose.pose.orientation
            R = rotation_of(q) @ R_roll
            for key, value in quaternion_from_matrix(R).items():
                setattr(q, key, value)
        elif topic == "/tf_static":
            for transform in message.transforms:
                if transform.header.frame_id == "base_link":
                    moved = transform.transform
                    t = moved.translation
                    t.x, t.y, t.z = R_roll.T @ np.array([t.x, t.y, t.z])
                    R = R_roll.T @ rotation_of(moved.rotation)
                    for key, value in quaternion_from_matrix(R).items():
                        setattr(moved.rotation, key, value)
        return message

    tilted_log = tmp_path / "tilted.mcap"
    rewrite_log(path, tilted_log, tilt)
    tilted = extract(tilted_log, FrontendConfig(allowed_ids=tuple(range(30))))
    assert tilted.mount.roll_rad < -math.radians(7.0)  # the mount as /tf_static now says
    assert tilted.levelled_frames == tilted.frames
    assert any(
        n.kind == "frames.levelled" and n.topic == "/odom" and n.figure == tilted.levelled_frames
        for n in tilted.notes
    )
    assert {o.marker_id for o in tilted.observations} == {o.marker_id for o in level.observations}
    rows = errors_against_truth(tilted)
    oblique = np.abs(rows[:, 1]) >= math.radians(15.0)
    assert np.degrees(np.median(rows[oblique & (rows[:, 0] < 3.0), 2])) <= 1.0
    assert np.median(rows[:, 3]) <= 0.03
    assert np.degrees(np.median(rows[:, 4])) <= 0.2


@pytest.mark.slow
def test_log_frames_are_all_accounted_for(simulated) -> None:
    """Every colour frame is read and paired with its depth; the mount comes from /tf_static."""
    for path, result in simulated:
        counts = {t.topic: t.count for t in open_log(path).topics}
        assert result.frames == counts["/camera/camera/color/image_raw/compressed"]
        assert result.frames_with_depth == result.frames and not result.skipped
        assert result.mount.height_m == pytest.approx(0.6)
        assert result.mount.pitch_rad == pytest.approx(math.radians(10.0))
        assert len(result.odometry) == counts["/odom"]


@pytest.mark.slow
@pytest.mark.slow
def test_detect_command_writes_json_lines(simulated, tmp_path: Path) -> None:
    """`markergraph detect` writes one line per observation, each with its odometry pose."""
    path, result = simulated[0]
    out = tmp_path / "obs.jsonl"
    run = subprocess.run(
        [sys.executable, "-m", "markergraph.cli", "detect", str(path), "--out", str(out)],
        capture_output=True,
        text=True,
    )
    assert run.returncode == 0, run.stderr
    observations, odometry = read_observations(out)
    assert len(observations) == len(result.observations) > 50
    assert observations[0].marker_id == result.observations[0].marker_id
    assert len(odometry) == len({o.t_ns for o in observations})


# --- real bags and bad input ------------------------------------------------------------------


def rosbag2_folders() -> list[Path]:
    return (
        sorted({p.parent for p in (DATA / "rosbag2-mcap").rglob("*.mcap")}) if DATA.is_dir() else []
    )


@needs_data
@pytest.mark.parametrize("folder", rosbag2_folders(), ids=lambda p: p.name)
def test_shared_rosbag2_bags_read_with_their_counts_or_fail_clearly(folder: Path) -> None:
    """Every shared rosbag2 bag decodes with the per-topic counts its metadata.yaml states, or
    fails with one LogError line naming the file."""
    metadata = folder / "metadata.yaml"
    expected = None
    if metadata.is_file():
        info = yaml.safe_load(metadata.read_text())["rosbag2_bagfile_information"]
        expected = {
            t["topic_metadata"]["name"]: t["message_count"]
            for t in info["topics_with_message_count"]
        }
    names = [t.topic for t in open_log(folder).topics]
    try:
        decoded: dict[str, int] = {}
        for message in open_log(folder).messages(names):
            decoded[message.topic] = decoded.get(message.topic, 0) + 1
    except LogError as error:
        assert "\n" not in str(error) and ".mcap" in str(error)
        return
    if expected is not None:
        assert {t: n for t, n in expected.items() if n} == decoded


@needs_data
def test_real_ros2_images_decode() -> None:
    """A real rosbag2 recording's rgb8 Image and JPEG CompressedImage decode to 640x480 grey."""
    path = DATA / "mcap-rerun-fixtures" / "rosbag2_2025_09_10-13_03_56_0.mcap"
    log = open_log(path)
    shapes = [decode_image(m).shape for m in log.messages(["/image", "/compressed_image"])]
    assert shapes == [(480, 640), (480, 640)]


def write_mismatched_log(path: Path) -> None:
    """A log whose depth image is half the colour image's size."""
    with open(path, "wb") as stream:
        writer = Writer(stream)
        schemas = {
            name: writer.register_msgdef(name, MESSAGE_DEFINITIONS[name])
            for name in ("sensor_msgs/msg/Image", "sensor_msgs/msg/CameraInfo")
        }
        for topic, width, height, encoding, channels in (
            ("/camera/camera/color/image_raw", 64, 48, "mono8", 1),
            ("/camera/camera/aligned_depth_to_color/image_raw", 32, 24, "16UC1", 2),
        ):
            writer.write_message(
                topic,
                schemas["sensor_msgs/msg/Image"],
                {
                    "header": header(1000, "camera_color_optical_frame"),
                    "height": height,
                    "width": width,
                    "encoding": encoding,
                    "is_bigendian": 0,
                    "step": width * channels,
                    "data": bytes(width * height * channels),
                },
                log_time=1000,
            )
        writer.write_message(
            "/camera/camera/color/camera_info",
            schemas["sensor_msgs/msg/CameraInfo"],
            {
                "header": header(1000, "x"),
                "height": 48,
                "width": 64,
                "k": [50.0, 0, 32, 0, 50.0, 24, 0, 0, 1],
            },
            log_time=1000,
        )
        writer.finish()


@pytest.mark.slow
def test_bad_logs_fail_with_one_line_naming_file_and_topic(tmp_path: Path) -> None:
    """Not MCAP, truncated, no camera, misaligned depth: exit 1 and one line naming the file."""
    not_mcap = tmp_path / "notes.mcap"
    not_mcap.write_text("hello")
    truncated = tmp_path / "cut.mcap"
    world, route = scenario("paper-room")
    write_log(world, route, tmp_path / "whole.mcap", seed=1, duration_s=2.0, compressed=True)
    truncated.write_bytes((tmp_path / "whole.mcap").read_bytes()[:100_000])
    no_camera = tmp_path / "odom-only.mcap"
    with open(no_camera, "wb") as stream:
        writer = Writer(stream)
        schema = writer.register_msgdef(
            "std_msgs/msg/String", MESSAGE_DEFINITIONS["std_msgs/msg/String"]
        )
        writer.write_message("/chatter", schema, {"data": "hi"}, log_time=1)
        writer.finish()
    misaligned = tmp_path / "misaligned.mcap"
    write_mismatched_log(misaligned)
    cases = [
        (not_mcap, "not an MCAP file"),
        (truncated, "not a complete MCAP file"),
        (no_camera, "no camera image topic"),
        (misaligned, "/camera/camera/aligned_depth_to_color/image_raw"),
    ]
    for path, message in cases:
        run = subprocess.run(
            [
                sys.executable,
                "-m",
                "markergraph.cli",
                "detect",
                str(path),
                "--out",
                str(tmp_path / "out.jsonl"),
            ],
            capture_output=True,
            text=True,
        )
        assert run.returncode == 1, (path, run.stderr)
        lines = run.stderr.strip().splitlines()
        assert len(lines) == 1 and message in lines[0] and str(path) in lines[0]
        assert not (tmp_path / "out.jsonl").exists()
    with pytest.raises(MarkerGraphError):
        extract(not_mcap)


@pytest.mark.slow
def test_worker_processes_give_the_same_observations(simulated) -> None:
    """Two spawned workers return exactly the single-process observations, in order."""
    path, result = simulated[0]
    parallel = extract(path, FrontendConfig(allowed_ids=tuple(range(30))), workers=2)
    assert parallel.observations == result.observations
    assert parallel.frames_with_depth == result.frames_with_depth


def to_foxglove(source: Path, target: Path) -> None:
    """Rewrite a simulated ROS 2 log with Foxglove's protobuf schemas, on topics of other names."""
    from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
    from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
    from google.protobuf.timestamp_pb2 import Timestamp
    from mcap_protobuf.writer import Writer as ProtobufWriter

    from markergraph.frontend import stamp_ns

    def timestamp(decoded) -> Timestamp:
        t_ns = stamp_ns(decoded)
        return Timestamp(seconds=t_ns // 10**9, nanos=t_ns % 10**9)

    topics = [
        "/camera/camera/color/image_raw/compressed",
        "/camera/camera/color/camera_info",
        "/camera/camera/aligned_depth_to_color/image_raw",
        "/odom",
        "/tf_static",
    ]
    with open(target, "wb") as stream:
        writer = ProtobufWriter(stream)
        for message in open_log(source).messages(topics):
            m = message.decoded
            if message.topic.endswith("compressed"):
                out = CompressedImage(
                    timestamp=timestamp(m),
                    frame_id=m.header.frame_id,
                    data=bytes(m.data),
                    format="jpeg",
                )
                topic = "/front/image"
            elif message.topic.endswith("camera_info"):
                out = CameraCalibration(
                    **_image_header(m, timestamp(m)),
                    distortion_model=m.distortion_model,
                    D=list(m.d),
                    K=list(m.k),
                    R=list(m.r),
                    P=list(m.p),
                )
                topic = "/front/calibration"
            elif message.topic == "/odom":
                out = _foxglove_pose(m.pose.pose, timestamp(m))
                topic = "/base/pose"
            elif message.topic == "/tf_static":
                out = _foxglove_transforms(m.transforms)
                topic = "/transforms"
            else:
                out = RawImage(
                    **_image_header(m, timestamp(m)),
                    encoding=m.encoding,
                    step=m.step,
                    data=bytes(m.data),
                )
                topic = "/front/depth"
            writer.write_message(topic, out, log_time=message.log_time_ns)
        writer.finish()


def _image_header(message: Any, stamp: Any) -> dict[str, Any]:
    """What Foxglove's image and calibration messages share, from a ROS 2 image or info."""
    return {
        "timestamp": stamp, "frame_id": message.header.frame_id,
        "width": message.width, "height": message.height,
    }  # fmt: skip


def _foxglove_pose(pose: Any, timestamp: Any) -> Any:
    """A ROS ``geometry_msgs/msg/Pose`` as Foxglove's ``PoseInFrame`` in ``odom``."""
    from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame

    out = PoseInFrame(timestamp=timestamp, frame_id="odom")
    out.pose.position.x, out.pose.position.y = pose.position.x, pose.position.y
    q = pose.orientation
    out.pose.orientation.x, out.pose.orientation.y = q.x, q.y
    out.pose.orientation.z, out.pose.orientation.w = q.z, q.w
    return out


def _foxglove_transforms(transforms: Any) -> Any:
    """ROS ``TransformStamped``s as Foxglove's ``FrameTransforms``."""
    from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
    from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms

    out = FrameTransforms()
    for transform in transforms:
        moved = transform.transform
        item = FrameTransform(
            parent_frame_id=transform.header.frame_id,
            child_frame_id=transform.child_frame_id,
        )
        t, q = moved.translation, moved.rotation
        item.translation.x, item.translation.y, item.translation.z = t.x, t.y, t.z
        item.rotation.x, item.rotation.y = q.x, q.y
        item.rotation.z, item.rotation.w = q.z, q.w
        out.transforms.append(item)
    return out


@pytest.mark.slow
@pytest.mark.slow
def test_foxglove_log_gives_the_same_observations(simulated, tmp_path: Path) -> None:
    """The same run written with Foxglove's protobuf schemas reads to the same observations."""
    path, result = simulated[0]
    foxglove = tmp_path / "foxglove.mcap"
    to_foxglove(path, foxglove)
    other = extract(foxglove, FrontendConfig(allowed_ids=tuple(range(30))))
    assert other.topics.color == "/front/image" and other.topics.depth == "/front/depth"
    assert other.mount == result.mount
    assert other.observations == result.observations
    assert other.odometry == result.odometry


@needs_data
def test_foxglove_pose_decodes_as_odometry() -> None:
    """A real Foxglove PoseInFrame (protobuf) decodes to an odometry sample."""
    from markergraph.frontend import odometry_sample

    path = DATA / "mcap-rerun-fixtures" / "simple-protobuf.mcap"
    (pose,) = [odometry_sample(m) for m in open_log(path).messages(["pose"])]
    assert math.isfinite(pose.x) and math.isfinite(pose.yaw)


def copy_without(path: Path, target: Path, topic: str | None, compression: str = "zstd") -> None:
    """A copy of an MCAP log without one topic's channel and messages, its chunks compressed
    with ``compression`` (zstd, lz4 or none)."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType
    from mcap.writer import Writer as McapWriter

    with open(path, "rb") as source, open(target, "wb") as stream:
        reader = make_reader(source)
        summary = reader.get_summary()
        writer = McapWriter(stream, compression=CompressionType[compression.upper()])
        writer.start(profile="ros2")
        schema_ids = {
            sid: writer.register_schema(s.name, s.encoding, s.data)
            for sid, s in summary.schemas.items()
        }
        channel_ids = {
            cid: writer.register_channel(
                channel.topic, channel.message_encoding, schema_ids[channel.schema_id]
            )
            for cid, channel in summary.channels.items()
            if channel.topic != topic
        }
        for _, channel, message in reader.iter_messages():
            if channel.id in channel_ids:
                writer.add_message(
                    channel_ids[channel.id], message.log_time, message.data, message.publish_time
                )
        writer.finish()


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
@pytest.mark.slow
def test_chunks_read_as_mcaps_own_reader_reads_them(
    simulated, tmp_path: Path, compression: str
) -> None:
    """Our chunk reader gives every message of every compression as mcap's own reader does:
    the same topics, log times and bytes, in log-time order."""
    from mcap.reader import make_reader

    from markergraph.frontend.logs import chunks

    path = tmp_path / f"{compression}.mcap"
    copy_without(simulated[0][0], path, None, compression)
    with open(path, "rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert {c.compression for c in summary.chunk_indexes} == {compression.replace("none", "")}
        theirs = [(c.topic, m.log_time, m.data) for _, c, m in reader.iter_messages()]
        topics = sorted({c.topic for c in summary.channels.values()})
        stream.seek(0)
        ours = [
            (c.topic, m.log_time, m.data)
            for _, c, m in chunks.raw_messages(path, stream, topics, None, None, None)
        ]
    assert len(ours) == len(theirs) > 1000
    assert sorted(ours) == sorted(theirs)
    assert all(a[1] <= b[1] for a, b in itertools.pairwise(ours))


@needs_data
def test_shared_real_mcap_files_read_as_mcaps_own_reader_reads_them() -> None:
    """Every MCAP file in ../shared/data (rosbag2's test bags, the rerun and Foxglove fixtures:
    zstd and uncompressed chunks, services, several files) gives our chunk reader the messages
    mcap's own reader gives: the same topics, log times and bytes."""
    from mcap.reader import make_reader

    from markergraph.frontend.logs import chunks

    files = sorted(DATA.rglob("*.mcap"))
    assert len(files) >= 20
    for path in files:
        with open(path, "rb") as stream:
            reader = make_reader(stream)
            summary = reader.get_summary()
            theirs = sorted((c.topic, m.log_time, m.data) for _, c, m in reader.iter_messages())
            topics = sorted({c.topic for c in summary.channels.values()})
            stream.seek(0)
            ours = sorted(  # our messages are views into their chunk's bytes
                (c.topic, m.log_time, bytes(m.data))
                for _, c, m in chunks.raw_messages(path, stream, topics, None, None, None)
            )
        assert ours == theirs, path


def test_a_record_past_its_chunk_is_damage() -> None:
    """A chunk whose last record claims more bytes than the chunk holds raises McapError (the
    reader then counts the chunk's messages as lost), never reads on into the next."""
    import struct

    from mcap.exceptions import McapError
    from mcap.records import Chunk

    from markergraph.frontend.logs import chunks

    whole = struct.pack("<BQHIQQ", 0x05, 22 + 3, 1, 0, 5, 5) + b"abc"
    chunk = Chunk(
        compression="", data=whole, message_end_time=5, message_start_time=5,
        uncompressed_crc=0, uncompressed_size=len(whole),
    )  # fmt: skip
    [message] = chunks.chunk_messages(chunk, {1})
    assert (message.channel_id, message.log_time, message.data) == (1, 5, b"abc")
    assert chunks.chunk_messages(chunk, {2}) == []
    cut = Chunk(**{**chunk.__dict__, "data": whole[:-1]})
    with pytest.raises(McapError, match="runs past its chunk"):
        chunks.chunk_messages(cut, {1})


@pytest.mark.slow
@pytest.mark.slow
def test_tf_stands_in_for_missing_odometry(simulated, tmp_path: Path) -> None:
    """Without /odom, the odom -> base_link transforms on /tf give the same odometry."""
    path, result = simulated[0]
    without_odom = tmp_path / "tf-only.mcap"
    copy_without(path, without_odom, "/odom")
    other = extract(without_odom, FrontendConfig(allowed_ids=tuple(range(30))))
    assert other.topics.odom == "/tf"
    assert other.odometry == result.odometry


@pytest.mark.slow
@pytest.mark.slow
def test_configured_mount_stands_in_for_missing_tf_static(simulated, tmp_path: Path) -> None:
    """Without /tf_static the configured mount is used and said so: the true one (0.6 m,
    pitched 10 deg) gives the same observations as /tf_static; a level camera does not."""
    path, result = simulated[0]
    stripped = tmp_path / "no-tf-static.mcap"
    copy_without(path, stripped, "/tf_static")
    ids = {"ids": list(range(30))}
    true = extract(
        stripped,
        MapConfig.from_values({**ids, "camera.height": 0.6, "camera.pitch_deg": 10}).frontend,
    )
    level = extract(stripped, MapConfig.from_values({**ids, "camera.pitch_deg": 0.0}).frontend)
    assert true.topics.tf_static is None and any(n.kind == "mount.no_tf_static" for n in true.notes)
    assert [o.range_m for o in true.observations] == pytest.approx(
        [o.range_m for o in result.observations], abs=1e-9
    )
    errors = [
        abs(a.range_m - b.range_m)
        for a, b in zip(level.observations, result.observations, strict=True)
    ]
    assert np.median(errors) > 0.01


def test_marker_sizes_per_id_set_the_range_without_depth() -> None:
    """A 0.1 m marker beside a 0.2 m one: with its size given per id, its size-based range is
    right (within the 6% a pitched camera's edge-length range allows); with the default size
    alone it reads exactly twice as far."""
    markers = (Marker(0, 0, 2.6, size_m=0.2), Marker(1, 0, 3.4, size_m=0.1))
    world = World("wall", (Wall((0.0, 0.0), (6.0, 0.0)),), markers, 0)
    from markergraph.datasets.render import Renderer

    renderer = Renderer(world)
    T_world_base = gtsam.Pose2(3.0, 1.5, -math.pi / 2)
    frame = renderer.render(T_world_base, np.random.default_rng(2))
    camera = T_world_base.compose(renderer.mount.T_base_camera).translation()
    ranges = {}
    for sizes in ({1: 0.1}, {}):
        observations = observe(
            frame.rgb, renderer.camera, MarkerSizes(0.2, sizes), mount=renderer.mount
        )
        assert sorted(o.marker_id for o in observations) == [0, 1]
        ranges[len(sizes)] = {o.marker_id: o.range_m for o in observations}
    for marker_id, range_m in ranges[1].items():
        truth = float(np.linalg.norm(world.T_world_marker(marker_id).translation() - camera))
        assert range_m == pytest.approx(truth, rel=0.06)
    assert ranges[0][0] == ranges[1][0]
    assert ranges[0][1] == pytest.approx(2.0 * ranges[1][1], rel=1e-12)


def test_compressed_depth_decodes_like_raw_depth() -> None:
    """A compressedDepth message (12-byte header, then a 16-bit PNG) decodes to the same depth."""
    from types import SimpleNamespace

    from markergraph.frontend import Message, decode_depth

    depth = np.random.default_rng(0).integers(0, 8000, (48, 64)).astype(np.uint16)
    ok, png = cv2.imencode(".png", depth)
    assert ok
    message = Message(
        "/depth/compressedDepth",
        "sensor_msgs/msg/CompressedImage",
        0,
        SimpleNamespace(format="16UC1; compressedDepth", data=bytes(12) + png.tobytes()),
    )
    np.testing.assert_array_equal(decode_depth(message), depth)


def test_range_is_the_papers_corrected_distance() -> None:
    """A marker 0.684 m above the camera at 1.44 m slant range reads 1.267 m horizontally."""
    height_difference, slant = 0.684, 1.44
    horizontal = math.sqrt(slant**2 - height_difference**2)
    assert horizontal == pytest.approx(1.267, abs=5e-4)  # the paper's figure
    world = World("wall", (Wall((-3.0, 0.0), (3.0, 0.0)),), (Marker(0, 0, 3.0, side=1),), 0)
    mount = CameraMount(
        x_m=0.0,
        height_m=1.0 - height_difference,
        pitch_rad=math.atan2(height_difference, horizontal),
    )
    from markergraph.datasets.render import Renderer

    renderer = Renderer(world, Camera(), mount)
    frame = renderer.render(gtsam.Pose2(0.0, horizontal, -math.pi / 2), np.random.default_rng(1))
    (obs,) = observe(
        frame.rgb, renderer.camera, MarkerSizes(0.2), depth=frame.depth_mm, mount=mount
    )
    assert obs.range_m == pytest.approx(horizontal, abs=0.01)


def test_range_without_depth_comes_from_the_full_pose() -> None:
    """Without depth, the range is PnP's: on rendered frames of the paper room (camera pitched
    10 deg) its median error is under 3 cm (1.5 cm by tests/benchmarks/range_without_depth.py
    on the first 60 s), where the marker's edge length alone gives 5.3 cm."""
    from markergraph.datasets.render import Renderer
    from markergraph.datasets.route import drive
    from markergraph.frontend.observe import ObservationModel, observe_detections

    world, route = scenario("paper-room")
    renderer = Renderer(world)
    rng = np.random.default_rng(0)
    detector = Detector(allowed_ids=[m.id for m in world.markers])
    errors = []
    for pose in drive(world, route, rng, frame_hz=2.0).frame_poses[:120]:
        T_world_base = gtsam.Pose2(*pose)
        camera = T_world_base.compose(renderer.mount.T_base_camera).translation()
        for obs in observe_detections(
            detector.detect(renderer.render(T_world_base, rng).rgb),
            renderer.camera,
            ObservationModel(MarkerSizes(0.2)),
            mount=renderer.mount,
        ):
            truth = np.linalg.norm(world.T_world_marker(obs.marker_id).translation() - camera)
            errors.append(abs(obs.range_m - truth))
    assert len(errors) > 50
    assert np.median(errors) < 0.03


def test_theta_sigma_from_one_pnp_solve_matches_re_solving() -> None:
    """Away from frontal views, theta's sigma propagated through the one PnP solve equals
    the one found by moving each corner and solving again (within 12 %, median within 2 %)."""
    import cv2

    from markergraph.frontend.yaw import (
        YawMethod,
        marker_object_points,
        pnp_pose,
        pnp_theta,
        pnp_theta_sigma,
        yaw_sigma,
    )  # fmt: skip

    camera = Camera()
    rng = np.random.default_rng(11)
    ratios = []
    while len(ratios) < 100:
        z = rng.uniform(0.8, 5.0)
        # About y by pi plus up to 70 deg: the marker faces the camera, seen obliquely.
        rvec = np.array([0.05 * rng.standard_normal(), math.pi + rng.uniform(-1.2, 1.2), 0.0])
        tvec = np.array([rng.uniform(-0.25, 0.25) * z, 0.1 * rng.standard_normal(), z])
        corners = cv2.projectPoints(marker_object_points(0.2), rvec, tvec, camera.K, None)[0]
        corners = corners.reshape(4, 2)
        pose = pnp_pose(corners, camera, 0.2)
        if pose is None or abs(pnp_theta(pose)) < math.radians(12.0):
            continue
        resolved = yaw_sigma(corners, YawMethod.PNP, 0.3, camera, 0.2)
        ratios.append(pnp_theta_sigma(pose, camera, 0.2, 0.3) / resolved)
    assert np.all(np.abs(np.array(ratios) - 1.0) < 0.12)
    assert abs(float(np.median(ratios)) - 1.0) < 0.02


def test_theta_sigma_gradient_is_theta_differentiated() -> None:
    """theta's sigma uses theta's analytic gradient in the pose; it equals the sigma from
    central differences of theta itself (through Rodrigues) to 1e-6."""
    from markergraph.frontend.yaw import marker_object_points, pnp_pose, pnp_theta, pnp_theta_sigma

    camera = Camera()
    rng = np.random.default_rng(5)
    for _ in range(50):
        z = rng.uniform(0.8, 5.0)
        rvec = np.array([0.1 * rng.standard_normal(), math.pi + rng.uniform(-1.2, 1.2), 0.05])
        tvec = np.array([rng.uniform(-0.25, 0.25) * z, 0.1 * rng.standard_normal(), z])
        corners = cv2.projectPoints(marker_object_points(0.2), rvec, tvec, camera.K, None)[0]
        pose = pnp_pose(corners.reshape(4, 2), camera, 0.2)
        assert pose is not None
        r, _ = cv2.Rodrigues(pose[0])
        params = np.concatenate([r.ravel(), pose[1]])
        gradient = np.zeros(6)
        for k in range(6):
            step = np.zeros(6)
            step[k] = 1e-6
            ahead, behind = params + step, params - step
            gradient[k] = (
                pnp_theta((cv2.Rodrigues(ahead[:3])[0], ahead[3:]))
                - pnp_theta((cv2.Rodrigues(behind[:3])[0], behind[3:]))
            ) / 2e-6
        _, jacobian = cv2.projectPoints(marker_object_points(0.2), r, pose[1], camera.K, None)
        J = jacobian[:, :6]
        expected = 0.3 * math.sqrt(gradient @ np.linalg.solve(J.T @ J, gradient))
        assert pnp_theta_sigma(pose, camera, 0.2, 0.3) == pytest.approx(expected, rel=1e-6)


def test_workers_auto_uses_a_second_process_only_where_it_helps(monkeypatch) -> None:
    """Auto: a process per 2 idle cores (its reading and detecting threads keep two busy) and per
    1,500 frames: one on a 2-core machine, a short log or a busy machine (by the load average
    where busy cores cannot be measured); a number asked for is kept, capped at the cores."""
    from markergraph.common import pool

    monkeypatch.setattr(pool, "busy_cores", lambda: 0.2)
    monkeypatch.setattr(pool, "available_cores", lambda: 2)
    assert pool.choose_workers(9000, None) == (1, None)  # one process: nothing to say
    monkeypatch.setattr(pool, "available_cores", lambda: 4)
    assert pool.choose_workers(9000, None)[0] == 1  # 3.8 idle cores: one process's worth
    monkeypatch.setattr(pool, "busy_cores", lambda: 0.0)
    assert pool.choose_workers(9000, None)[0] == 2  # 4 idle cores
    assert pool.choose_workers(2000, None)[0] == 1  # 2,000 frames: one worker's worth
    monkeypatch.setattr(pool, "busy_cores", lambda: 0.2)
    monkeypatch.setattr(pool, "available_cores", lambda: 8)
    assert pool.choose_workers(9000, None)[0] == 3  # 7.8 idle cores
    assert pool.choose_workers(3000, None)[0] == 2  # 1,500 frames each
    workers, note = pool.choose_workers(9000, None)
    assert note is not None and note.kind == "workers.auto" and note.figure == 3
    assert "read in 3 processes at once" in note.text and "7.8 of 8 cores were idle" in note.text
    monkeypatch.setattr(pool, "busy_cores", lambda: 6.2)
    assert pool.choose_workers(9000, None) == (1, None)  # 1.8 idle cores
    monkeypatch.setattr(pool, "busy_cores", lambda: None)
    monkeypatch.setattr(pool.os, "getloadavg", lambda: (3.5, 3.5, 3.5))
    workers, note = pool.choose_workers(9000, None)
    assert workers == 2 and note is not None and note.figure == 2  # 4.5 idle by the load
    assert pool.choose_workers(100, 2) == (2, None)
    assert pool.choose_workers(100, 9)[0] == 8


def test_core_ticks_read_proc_stat() -> None:
    """Each core's idle ticks are idle plus iowait, its total the first eight fields (user to
    steal: guest is inside user); the all-cores line and other lines are passed over."""
    from markergraph.common.pool import core_ticks

    text = (
        "cpu  100 2 30 400 5 6 7 8 9 10\n"
        "cpu0 10 1 3 40 2 1 1 5 50 0\n"
        "cpu1 20 0 4 70 0 0 0 0\n"
        "intr 12345 1 2\n"
        "ctxt 999\n"
    )
    assert core_ticks(text) == {0: (42, 63), 1: (70, 94)}


@pytest.mark.alone
def test_busy_cores_sees_a_process_spinning_on_our_cores() -> None:
    """A process spinning beside us shows as about one more busy core than before it ran."""
    from markergraph.common.pool import available_cores, busy_cores

    # A second's window: /proc/stat counts 100 ticks a second per core, so 0.3 s left a
    # tick's 3 % a core of rounding, and CI's own background work rides on top of it.
    quiet = busy_cores(1.0)
    if quiet is None:
        pytest.skip("no per-core counters in /proc/stat here")
    if available_cores() - quiet < 1.5:
        pytest.skip(f"other work holds {quiet:.1f} of {available_cores()} cores: no idle one")
    spinner = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        time.sleep(0.3)  # started and spinning
        loaded = busy_cores(1.0)
    finally:
        spinner.kill()
        spinner.wait()
    assert loaded is not None
    assert 0.6 < loaded - quiet <= 1.3  # one core, never two
    assert loaded <= available_cores() + 0.05


@pytest.mark.alone
def test_busy_cores_leaves_out_our_own_children() -> None:
    """A child of ours (the plotter warming up, say) is not other work: busy as it is, the
    cores read as before it ran (a spinner that is not ours reads as one more, above)."""
    import math
    import multiprocessing

    from markergraph.common.pool import available_cores, busy_cores

    quiet = busy_cores(1.0)
    if quiet is None:
        pytest.skip("no per-core counters in /proc/stat here")
    if available_cores() - quiet < 1.5:
        pytest.skip(f"other work holds {quiet:.1f} of {available_cores()} cores: no idle one")
    context = multiprocessing.get_context("spawn")
    child = context.Process(target=math.factorial, args=(3_000_000,), daemon=True)  # a minute
    child.start()
    try:
        time.sleep(0.5)  # started and computing
        loaded = busy_cores(1.0)
        assert child.is_alive()
    finally:
        child.kill()
        child.join()
    assert loaded is not None and loaded - quiet < 0.3


def test_read_ahead_yields_everything_raises_in_place_and_stops_early() -> None:
    """The reading thread hands over every item in order, raises a producer's error at the item
    where it happened, and when the consumer stops early the generator is closed and the
    thread ends."""
    import threading

    from markergraph.frontend.logs import read_ahead

    for n, size in ((1000, 8), (1001, 8), (3, 32), (0, 32), (77, 1)):  # whole and part batches
        assert list(read_ahead(iter(range(n)), size=size)) == list(range(n))

    def failing():
        yield from range(5)
        raise LogError("log.mcap: a damaged chunk")

    seen = []
    with pytest.raises(LogError, match="damaged chunk"):
        for item in read_ahead(failing(), size=2):
            seen.append(item)
    assert seen == [0, 1, 2, 3, 4]

    closed = threading.Event()

    def endless():
        try:
            n = 0
            while True:
                yield n
                n += 1
        finally:
            closed.set()

    stream = read_ahead(endless(), size=4)
    assert [next(stream) for _ in range(10)] == list(range(10))
    stream.close()  # what a consumer's break does
    assert closed.wait(5.0)
    assert not any(t.name == "markergraph-read-ahead" for t in threading.enumerate())
