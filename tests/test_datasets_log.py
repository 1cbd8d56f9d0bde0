"""Rendered frames and ROS 2 MCAP logs against the simulator's ground truth."""

from __future__ import annotations

import hashlib
import math
import subprocess
import sys
from pathlib import Path

import cv2
import gtsam
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from markergraph.datasets import Marker, Wall, World, scenario
from markergraph.datasets.render import DepthNoise, Renderer
from markergraph.datasets.route import drive
from markergraph.datasets.write import Topics, write_log
from markergraph.frontend.camera import Camera, CameraMount

CORNER_MEDIAN_PX = 0.5


def detector(dictionary: str) -> cv2.aruco.ArucoDetector:
    parameters = cv2.aruco.DetectorParameters()
    parameters.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    return cv2.aruco.ArucoDetector(
        cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary)), parameters
    )


def rendered_run(name: str, seconds: float, seed: int = 0):
    world, route = scenario(name)
    renderer = Renderer(world, texture_seed=seed)
    rng = np.random.default_rng(seed)
    motion = drive(world, route, rng, frame_hz=5.0, duration_s=seconds)
    for pose in motion.frame_poses:
        T_world_base = gtsam.Pose2(*pose)
        yield world, renderer, T_world_base, renderer.render(T_world_base, rng)


@pytest.mark.slow
def test_detected_corners_match_projected_ground_truth() -> None:
    """Over the paper-room log OpenCV finds the drawn markers at their true corners (median
    under 0.5 px), and below 60 degrees of view angle in the corridor as well."""
    errors_by_name: dict[str, list[tuple[float, float]]] = {}
    for name, seconds in (("paper-room", 149.0), ("corridor-loop", 120.0)):
        errors = errors_by_name.setdefault(name, [])
        for world, renderer, T_world_base, frame in rendered_run(name, seconds):
            gray = cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY)
            corners, ids, _ = detector("DICT_4X4_50").detectMarkers(gray)
            for found, marker_id in zip(corners, [] if ids is None else ids.ravel(), strict=True):
                assert int(marker_id) in frame.drawn_ids  # no marker that is not there
                true = renderer.camera.project(
                    renderer.mount.world_to_optical(
                        T_world_base, world.marker_corners(int(marker_id))
                    )
                )
                T_camera = T_world_base.compose(renderer.mount.T_base_camera)
                local = world.T_world_marker(int(marker_id)).transformTo(T_camera.translation())
                view_angle = abs(math.atan2(local[1], local[0]))
                errors.append((view_angle, float(np.linalg.norm(found[0] - true, axis=1).max())))
    paper = np.array(errors_by_name["paper-room"])
    corridor = np.array(errors_by_name["corridor-loop"])
    assert len(paper) > 100 and np.median(paper[:, 1]) < CORNER_MEDIAN_PX
    below_60 = corridor[corridor[:, 0] < math.radians(60.0)]
    assert len(below_60) > 30 and np.median(below_60[:, 1]) < CORNER_MEDIAN_PX


@pytest.mark.slow
def test_depth_at_marker_centres_matches_true_range() -> None:
    """The aligned depth under each marker centre in clear view is its true optical Z within
    3 sigma of the depth noise model (in at least 97% of samples: dropouts aside)."""
    noise = DepthNoise()
    inside, total = 0, 0
    for world, renderer, T_world_base, frame in rendered_run("office", 60.0, seed=3):
        T_camera = T_world_base.compose(renderer.mount.T_base_camera)
        for marker_id in frame.drawn_ids:
            T_marker = world.T_world_marker(marker_id)
            if world.blocked(T_camera.translation(), T_marker.translation()):
                continue  # seen in part past a doorway: its centre is hidden
            centre = world.marker_corners(marker_id).mean(axis=0, keepdims=True)
            optical = renderer.mount.world_to_optical(T_world_base, centre)
            u, v = np.rint(renderer.camera.project(optical)[0]).astype(int)
            if not (0 <= u < renderer.camera.width and 0 <= v < renderer.camera.height):
                continue
            z = float(optical[0, 2])
            if z > noise.max_range_m:  # beyond the camera's range: no return, by design
                assert frame.depth_mm[v, u] == 0
                continue
            measured = frame.depth_mm[v, u] / 1000.0
            total += 1
            sigma = noise.base_m + noise.per_m2 * z * z
            inside += measured > 0 and abs(measured - z) < 3 * sigma + 0.0005  # 0.5 mm: rounding
    assert total > 50
    assert inside / total > 0.97


def test_occluded_and_back_facing_markers_are_not_drawn() -> None:
    """A wall between the camera and a marker hides it; so does standing behind its wall."""
    walls = (
        Wall((0.0, 0.0), (4.0, 0.0)),
        Wall((1.5, 1.0), (2.5, 1.0)),
        Wall((0.0, 0.0), (0.0, 4.0)),
        Wall((4.0, 0.0), (4.0, 4.0)),
    )
    world = World("screen", walls, (Marker(0, 0, 2.0, side=1),), 0)
    mount = CameraMount(x_m=0.0, height_m=1.0, pitch_rad=0.0)
    renderer = Renderer(world, Camera(), mount)
    rng = np.random.default_rng(0)
    seen = renderer.render(gtsam.Pose2(2.0, 0.9, -math.pi / 2), rng)
    hidden = renderer.render(gtsam.Pose2(2.0, 2.5, -math.pi / 2), rng)
    behind = renderer.render(gtsam.Pose2(2.0, -1.5, math.pi / 2), rng)
    assert seen.drawn_ids == (0,)
    assert hidden.drawn_ids == () and behind.drawn_ids == ()
    for frame, expected in ((seen, 1), (hidden, 0), (behind, 0)):
        _, ids, _ = detector("DICT_4X4_50").detectMarkers(
            cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY)
        )
        assert (0 if ids is None else len(ids)) == expected


@pytest.fixture(scope="module")
def short_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    world, route = scenario("paper-room")
    path = tmp_path_factory.mktemp("log") / "paper-room.mcap"
    write_log(world, route, path, seed=5, duration_s=4.0, compressed=True)
    return path


@pytest.mark.slow
def test_one_seed_gives_the_same_bytes(short_log: Path, tmp_path: Path) -> None:
    """Writing the same run twice gives byte-identical files; another seed does not."""
    world, route = scenario("paper-room")
    again, other = tmp_path / "again.mcap", tmp_path / "other.mcap"
    write_log(world, route, again, seed=5, duration_s=4.0, compressed=True)
    write_log(world, route, other, seed=6, duration_s=4.0, compressed=True)
    digest = [hashlib.sha256(p.read_bytes()).hexdigest() for p in (short_log, again, other)]
    assert digest[0] == digest[1] != digest[2]


def test_standard_reader_reads_the_expected_topics(short_log: Path) -> None:
    """mcap + mcap-ros2-support alone read the ros2 profile, topics, types and counts."""
    topics = Topics()
    frames, odometry = 60, 201  # 4 s at the default 15 Hz and at 50 Hz
    expected = {
        topics.color_compressed: ("sensor_msgs/msg/CompressedImage", frames),
        topics.depth: ("sensor_msgs/msg/Image", frames),
        topics.color_info: ("sensor_msgs/msg/CameraInfo", frames),
        topics.depth_info: ("sensor_msgs/msg/CameraInfo", frames),
        topics.odom: ("nav_msgs/msg/Odometry", odometry),
        topics.tf: ("tf2_msgs/msg/TFMessage", odometry),
        topics.tf_static: ("tf2_msgs/msg/TFMessage", 1),
        topics.true_pose: ("geometry_msgs/msg/PoseStamped", odometry),
        topics.true_markers: ("tf2_msgs/msg/TFMessage", 1),
        topics.world: ("std_msgs/msg/String", 1),
    }
    with open(short_log, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        found = {
            channel.topic: (
                summary.schemas[channel.schema_id].name,
                summary.statistics.channel_message_counts[channel.id],
            )
            for channel in summary.channels.values()
        }
        assert found == expected
        for _, channel, message, decoded in reader.iter_decoded_messages(
            topics=[topics.depth, topics.color_compressed]
        ):
            image_stamp = decoded.header.stamp.sec * 10**9 + decoded.header.stamp.nanosec
            assert message.log_time > image_stamp  # received after capture
            if channel.topic == topics.depth:
                depth = np.frombuffer(decoded.data, np.uint16).reshape(
                    decoded.height, decoded.width
                )
                assert decoded.encoding == "16UC1" and depth.max() > 500
            else:
                jpeg = cv2.imdecode(np.frombuffer(decoded.data, np.uint8), cv2.IMREAD_COLOR)
                assert jpeg.shape == (480, 640, 3)


@pytest.mark.slow
def test_simulate_command_refuses_to_overwrite(tmp_path: Path) -> None:
    """`markergraph simulate` writes a log, then will not overwrite it without --force."""
    out = tmp_path / "run.mcap"
    command = [
        sys.executable,
        "-m",
        "markergraph.cli",
        "simulate",
        "--scenario",
        "paper-room",
        "--seed",
        "1",
        "--duration",
        "1",
        "--out",
        str(out),
    ]
    first = subprocess.run(command, capture_output=True, text=True)
    assert first.returncode == 0 and "wrote" in first.stdout
    size = out.stat().st_size
    second = subprocess.run(command, capture_output=True, text=True)
    assert second.returncode == 1 and "--force" in second.stderr
    assert len(second.stderr.strip().splitlines()) == 1 and out.stat().st_size == size


@pytest.mark.slow
def test_sample_log_is_generated_once_and_reused(tmp_path: Path, monkeypatch) -> None:
    """The first call renders the sample into the cache (saying so); the second reuses it."""
    from markergraph.datasets import samples

    monkeypatch.setenv("MARKERGRAPH_CACHE", str(tmp_path))
    monkeypatch.setitem(samples.SAMPLES, "paper-room", ("paper-room", 1, 1, 2.0))  # a short one
    path = samples.sample_log("paper-room")
    assert path.parent == tmp_path and path.stat().st_size > 1_000_000
    written = path.stat().st_mtime_ns
    assert samples.sample_log("paper-room") == path and path.stat().st_mtime_ns == written
    with pytest.raises(ValueError, match="unknown sample"):
        samples.sample_log("moon-base")


def test_bag_thread_writes_the_bytes_one_thread_writes(tmp_path: Path) -> None:
    """The simulators' writer (a thread of its own, JPEG made there) against mcap_ros2's writer
    called in order from one thread: the same bytes; an error in either thread leaves the file
    unfinished and is raised."""
    from mcap_ros2.writer import Writer

    from markergraph.datasets.bag import Bag
    from markergraph.frontend.ros2 import MESSAGE_DEFINITIONS, header

    rng = np.random.default_rng(3)
    depth = rng.integers(0, 4000, (480, 640), dtype=np.uint16).tobytes()  # 12 fill 6 chunks
    messages = []
    for i in range(12):
        t = 1_000_000_000 + i * 10_000_000
        image = {"header": header(t, "cam"), "height": 480, "width": 640, "encoding": "16UC1",
                 "is_bigendian": 0, "step": 1280, "data": depth}  # fmt: skip
        text = {"data": f"message {i}"}
        messages += [("/depth", "sensor_msgs/msg/Image", image, t), ("/text", "std_msgs/msg/String",
                     text, t)]  # fmt: skip
    one = tmp_path / "one.mcap"
    with open(one, "wb") as stream:
        writer, schemas = Writer(stream), {}
        for topic, schema, message, t in messages:
            if schema not in schemas:
                schemas[schema] = writer.register_msgdef(schema, MESSAGE_DEFINITIONS[schema])
            writer.write_message(topic, schemas[schema], message, t + 5, t)
        writer.finish()
    threaded = tmp_path / "threaded.mcap"
    with open(threaded, "wb") as stream, Bag(stream) as bag:
        for k, (topic, schema, message, t) in enumerate(messages):
            made = message if k % 3 else (lambda m=message: m)  # some made in the thread
            bag.write(topic, schema, made, t, t + 5)
    assert threaded.read_bytes() == one.read_bytes()
    assert bag.counts == {"/depth": 12, "/text": 12}
    with pytest.raises(RuntimeError, match="inside its with statement"):
        bag.write("/text", "std_msgs/msg/String", {"data": "after"}, 1, 1)

    def fails() -> dict:
        raise RuntimeError("JPEG encoding failed")

    broken = tmp_path / "broken.mcap"
    with (
        pytest.raises(RuntimeError, match="JPEG encoding failed"),
        open(broken, "wb") as stream,
        Bag(stream) as bag,
    ):
        bag.write("/text", "std_msgs/msg/String", fails, 1, 1)
        for i in range(200):
            bag.write("/text", "std_msgs/msg/String", {"data": str(i)}, i, i)
    assert not broken.read_bytes().endswith(b"\x89MCAP0\r\n")  # never finished
    # The caller's own error: what waited is dropped.
    with pytest.raises(KeyError), open(broken, "wb") as stream, Bag(stream) as bag:
        bag.write("/text", "std_msgs/msg/String", {"data": "kept?"}, 1, 1)
        raise KeyError("the caller's")
    assert not broken.read_bytes().endswith(b"\x89MCAP0\r\n")


def test_frames_rendered_in_threads_give_the_bytes_of_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A D435i's log (rolling shutter: 17 renders a frame; dropped frames; late stamps)
    written with frames rendered two at a time and several ahead equals the log written with
    each frame rendered and written before the next is started."""
    import markergraph.datasets.write as write
    from markergraph.datasets.sensors import D435I_ON_DIFF_DRIVE

    world, route = scenario("corridor-loop")
    paths = []
    for threads, ahead in ((2, 4), (1, 0)):
        monkeypatch.setattr(write, "RENDER_THREADS", threads)
        monkeypatch.setattr(write, "RENDERING_AHEAD", ahead)
        paths.append(tmp_path / f"threads-{threads}.mcap")
        summary = write_log(world, route, paths[-1], seed=9, duration_s=1.0, compressed=True,
                            sensors=D435I_ON_DIFF_DRIVE, frame_hz=15.0)  # fmt: skip
    assert summary.frames > 10
    assert paths[0].read_bytes() == paths[1].read_bytes()


def test_progress_reaches_the_end_when_the_last_frames_are_dropped(tmp_path: Path) -> None:
    """Progress counts the route's frames, dropped ones too: it ends at (all, all) even where the
    last frames were dropped, not rendered (seed 2: the last frame rendered is the 8th of 10)."""
    from markergraph.datasets.sensors import SensorEffects

    world, route = scenario("paper-room")
    calls: list[tuple[int, int]] = []
    write_log(world, route, tmp_path / "dropped.mcap", seed=2, duration_s=2.0, compressed=True,
              sensors=SensorEffects(dropped_frames=0.5), frame_hz=5.0,
              progress=lambda done, total: calls.append((done, total)))  # fmt: skip
    assert calls[-2] == (8, 10)  # the last frame rendered
    assert calls[-1] == (10, 10)
    assert [done for done, _ in calls] == sorted(done for done, _ in calls)
