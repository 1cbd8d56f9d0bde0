"""overlay.mcap plays along the log: the path grows, each pose has its stamp, each marker has a
frame at its height, and the frame names are the caller's; read back with mcap, rosbags and evo."""

from __future__ import annotations

import itertools
import math
from collections import defaultdict
from pathlib import Path
from typing import Any

import gtsam
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from markergraph.estimator.trajectory import MAX_EXTRAPOLATION_NS, Trajectory
from markergraph.frontend.ros2 import yaw_from_quaternion
from markergraph.markermap import MapMarker, MarkerMap
from markergraph.overlay import (
    MARKER_TOPIC,
    PATH_PERIOD_NS,
    PATH_TOPIC,
    POSE_TOPIC,
    TF_STATIC_TOPIC,
    TF_TOPIC,
    write_overlay,
)

EXACT = 1e-12  # poses copied through float64 CDR fields and a yaw <-> quaternion round trip
EVO_SECONDS = 1e-6  # evo keeps stamps as float64 seconds: about 2e-7 s resolution near 1.7e9 s
T0_NS = 1_700_000_000_123_456_789  # a real epoch stamp, so seconds and nanoseconds both matter
N_POSES = 60
GAP_NS = 2_300_000_000  # longer than a few path periods: periods without a new pose
T_MAP_ODOM = gtsam.Pose2(1.5, -0.7, 0.4)  # where the log's odom frame lies on the map
ODOMETRY_EARLY_NS = 1_000_000_000  # the odometry starts this long before the first estimate
ODOMETRY_POSES = 40  # ... and ends at this estimated pose


def make_trajectory(seed: int) -> Trajectory:
    """A random walk of ``N_POSES`` poses at irregular stamps 50-400 ms apart, with one gap of
    ``GAP_NS`` (frames without markers) half-way."""
    rng = np.random.default_rng(seed)
    steps_ns = rng.integers(50_000_000, 400_000_000, N_POSES - 1)
    steps_ns[N_POSES // 2] = GAP_NS
    t_ns = T0_NS + np.concatenate([[0], np.cumsum(steps_ns)])
    poses = np.cumsum(rng.normal(0.0, [0.2, 0.2, 0.3], (N_POSES, 3)), axis=0)
    poses[:, 2] = np.arctan2(np.sin(poses[:, 2]), np.cos(poses[:, 2]))
    return Trajectory(t_ns, poses, "map")


def make_odometry(trajectory: Trajectory) -> Trajectory:
    """The estimated poses seen from ``odom`` (``T_MAP_ODOM`` away) up to pose
    ``ODOMETRY_POSES``, plus one pose a second before the first estimate."""
    T_odom_map = T_MAP_ODOM.inverse()
    first = T_odom_map.compose(trajectory.pose(0))
    moved = [T_odom_map.compose(trajectory.pose(i)) for i in range(ODOMETRY_POSES)]
    t_ns = [int(trajectory.t_ns[0]) - ODOMETRY_EARLY_NS, *trajectory.t_ns[:ODOMETRY_POSES]]
    poses = [[first.x(), first.y(), first.theta()]] + [[p.x(), p.y(), p.theta()] for p in moved]
    return Trajectory(np.array(t_ns), np.array(poses), "odom")


def make_map(seed: int) -> MarkerMap:
    """Six markers at random poses; heights known for some, covariances for some."""
    rng = np.random.default_rng(seed)
    markers = {}
    for marker_id in (0, 3, 7, 12, 25, 49):
        x, y = rng.uniform(-5.0, 5.0, 2)
        yaw = rng.uniform(-math.pi, math.pi)
        z_m = float(rng.uniform(0.2, 1.8)) if marker_id % 2 else None
        sigmas = rng.uniform(0.01, 0.1, 3)
        covariance = np.diag(sigmas**2) if marker_id != 12 else None
        markers[marker_id] = MapMarker(marker_id, gtsam.Pose2(x, y, yaw), covariance, 5, 0.2, z_m)
    return MarkerMap(markers, (), 0, "DICT_4X4_50", 0.2, "slam", "test.mcap")


def read_overlay(path: Path) -> dict[str, list[tuple[int, Any]]]:
    """Topic -> [(log time [ns], decoded message)] in log-time order."""
    topics: dict[str, list[tuple[int, Any]]] = defaultdict(list)
    with open(path, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, message, decoded in reader.iter_decoded_messages(log_time_order=True):
            topics[channel.topic].append((message.log_time, decoded))
    return dict(topics)


def stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def yaw_error(a: float, b: float) -> float:
    return abs(math.remainder(a - b, 2.0 * math.pi))


def quaternion_yaw(q: Any) -> float:
    return yaw_from_quaternion(q.x, q.y, q.z, q.w)


@pytest.fixture
def overlay(tmp_path: Path) -> tuple[Path, Trajectory, Trajectory, MarkerMap]:
    trajectory = make_trajectory(seed=1)
    odometry = make_odometry(trajectory)
    marker_map = make_map(seed=2)
    path = tmp_path / "overlay.mcap"
    write_overlay(path, marker_map, trajectory, odometry)
    return path, trajectory, odometry, marker_map


def test_topics_and_types(overlay) -> None:
    """The overlay has exactly the five documented topics with their ROS 2 types."""
    path, *_ = overlay
    with open(path, "rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    types = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
    assert types == {
        MARKER_TOPIC: "visualization_msgs/msg/MarkerArray",
        TF_STATIC_TOPIC: "tf2_msgs/msg/TFMessage",
        PATH_TOPIC: "nav_msgs/msg/Path",
        POSE_TOPIC: "geometry_msgs/msg/PoseStamped",
        TF_TOPIC: "tf2_msgs/msg/TFMessage",
    }


def test_path_grows_along_the_log(overlay) -> None:
    """A Path every period from the first pose to the last: each holds exactly the poses stamped
    up to its own stamp, counts strictly grow, and the last holds the whole trajectory."""
    path, trajectory, *_ = overlay
    messages = read_overlay(path)[PATH_TOPIC]
    first, last = int(trajectory.t_ns[0]), int(trajectory.t_ns[-1])
    stamps = [stamp_ns(m.header) for _, m in messages]
    counts = [len(m.poses) for _, m in messages]
    assert len(messages) > 1
    assert [t for t, _ in messages] == stamps  # log time is the header stamp
    assert first <= stamps[0] < first + PATH_PERIOD_NS and stamps[-1] == last
    assert all(b > a for a, b in itertools.pairwise(counts))
    assert counts[-1] == len(trajectory)
    for t_ns, (_, message) in zip(stamps, messages, strict=True):
        assert t_ns == last or (t_ns - first) % PATH_PERIOD_NS == 0
        expected = int(np.searchsorted(trajectory.t_ns, t_ns, side="right"))
        assert len(message.poses) == expected
        assert [stamp_ns(p.header) for p in message.poses] == list(trajectory.t_ns[:expected])
        xy = [(p.pose.position.x, p.pose.position.y) for p in message.poses]
        np.testing.assert_allclose(xy, trajectory.poses[:expected, :2], rtol=0, atol=EXACT)
    # No period that gained a pose is skipped: the path is never more than one period behind.
    for t_ns in range(first, last, PATH_PERIOD_NS):
        behind = [s for s in stamps if s <= t_ns][-1]
        gained = np.searchsorted(trajectory.t_ns, t_ns, side="right") - np.searchsorted(
            trajectory.t_ns, behind, side="right"
        )
        assert gained == 0


def test_long_path_is_thinned_but_only_grows(tmp_path: Path) -> None:
    """With a pose limit, each Path before the last keeps every k-th pose and the newest, the
    kept poses never change from one message to the next, and the last holds every pose."""
    trajectory = make_trajectory(seed=3)
    limit = 10
    path = tmp_path / "overlay.mcap"
    write_overlay(path, make_map(seed=4), trajectory, make_odometry(trajectory),
                  max_path_poses=limit)  # fmt: skip
    messages = read_overlay(path)[PATH_TOPIC]
    stride = math.ceil(N_POSES / limit)
    previous: list[int] = []
    for _, message in messages[:-1]:
        stamps = [stamp_ns(p.header) for p in message.poses]
        count = int(np.searchsorted(trajectory.t_ns, stamp_ns(message.header), side="right"))
        kept = list(trajectory.t_ns[0:count:stride])
        assert stamps[: len(kept)] == kept and stamps[-1] == trajectory.t_ns[count - 1]
        assert len(stamps) <= limit + 1
        assert stamps[: len(previous) - 1] == previous[:-1]  # the old line stays as it was
        previous = stamps
    assert [stamp_ns(p.header) for p in messages[-1][1].poses] == list(trajectory.t_ns)


def test_pose_topic_is_the_trajectory(overlay) -> None:
    """One PoseStamped per estimated pose, stamped and logged at its stamp, at its x, y, yaw."""
    path, trajectory, *_ = overlay
    messages = read_overlay(path)[POSE_TOPIC]
    assert [t for t, _ in messages] == list(trajectory.t_ns)
    assert [stamp_ns(m.header) for _, m in messages] == list(trajectory.t_ns)
    assert {m.header.frame_id for _, m in messages} == {"map"}
    for (_, message), (x, y, yaw) in zip(messages, trajectory.poses, strict=True):
        position = message.pose.position
        assert (position.x, position.y, position.z) == pytest.approx((x, y, 0.0), abs=EXACT)
        assert yaw_error(quaternion_yaw(message.pose.orientation), yaw) < EXACT


def test_map_to_odom_where_the_odometry_reaches(overlay) -> None:
    """``/tf`` carries map -> odom at each estimated stamp the odometry reaches, equal to the
    offset the odometry was made with."""
    path, trajectory, odometry, _ = overlay
    messages = read_overlay(path)[TF_TOPIC]
    reached = [int(t) for t in trajectory.t_ns if t <= odometry.t_ns[-1] + MAX_EXTRAPOLATION_NS]
    assert ODOMETRY_POSES <= len(reached) < N_POSES
    assert [t for t, _ in messages] == reached
    for t_ns, message in messages:
        (transform,) = message.transforms
        assert stamp_ns(transform.header) == t_ns
        assert (transform.header.frame_id, transform.child_frame_id) == ("map", "odom")
        translation = transform.transform.translation
        assert (translation.x, translation.y, translation.z) == pytest.approx(
            (T_MAP_ODOM.x(), T_MAP_ODOM.y(), 0.0), abs=1e-9
        )
        assert yaw_error(quaternion_yaw(transform.transform.rotation), T_MAP_ODOM.theta()) < 1e-9


def test_one_static_frame_per_marker(overlay) -> None:
    """``/tf_static`` holds map -> marker_<id> for every marker at its x, y, height and yaw,
    once, at the start of the odometry (the earliest stamp given)."""
    path, _, odometry, marker_map = overlay
    messages = read_overlay(path)[TF_STATIC_TOPIC]
    start = int(odometry.t_ns[0])
    assert len(messages) == 1 and messages[0][0] == start
    transforms = {t.child_frame_id: t for t in messages[0][1].transforms}
    assert sorted(transforms) == sorted(f"marker_{i}" for i in marker_map.markers)
    for marker_id, marker in marker_map.markers.items():
        transform = transforms[f"marker_{marker_id}"]
        T, z = marker.T_map_marker, marker.z_m if marker.z_m is not None else 0.0
        assert transform.header.frame_id == "map" and stamp_ns(transform.header) == start
        translation = transform.transform.translation
        assert (translation.x, translation.y, translation.z) == pytest.approx(
            (T.x(), T.y(), z), abs=EXACT
        )
        assert yaw_error(quaternion_yaw(transform.transform.rotation), T.theta()) < EXACT
    assert any(m.z_m for m in marker_map.markers.values())  # heights are really exercised


def test_markers_drawn_once_from_the_start_at_their_height(overlay) -> None:
    """One MarkerArray at the earliest stamp: an arrow per marker at its pose and height, its
    id above it, and an ellipse for each marker with a covariance."""
    path, _, odometry, marker_map = overlay
    messages = read_overlay(path)[MARKER_TOPIC]
    assert len(messages) == 1 and messages[0][0] == int(odometry.t_ns[0])
    drawn = defaultdict(dict)
    for item in messages[0][1].markers:
        drawn[item.ns][item.id] = item
    assert set(drawn["normals"]) == set(drawn["ids"]) == set(marker_map.markers)
    assert set(drawn["ellipses"]) == {
        i for i, m in marker_map.markers.items() if m.covariance is not None
    }
    for marker_id, marker in marker_map.markers.items():
        T, z = marker.T_map_marker, marker.z_m if marker.z_m is not None else 0.0
        arrow = drawn["normals"][marker_id]
        position = arrow.pose.position
        assert (position.x, position.y, position.z) == pytest.approx((T.x(), T.y(), z), abs=EXACT)
        assert yaw_error(quaternion_yaw(arrow.pose.orientation), T.theta()) < EXACT
        assert drawn["ids"][marker_id].text == str(marker_id)
        assert drawn["ids"][marker_id].pose.position.z == pytest.approx(z + 0.25, abs=EXACT)
        if marker_id in drawn["ellipses"]:
            assert drawn["ellipses"][marker_id].pose.position.z == pytest.approx(z, abs=EXACT)


def test_frame_names_follow_the_arguments(tmp_path: Path) -> None:
    """Renamed map, odom and marker frames are used in every header and transform, and the
    default names appear nowhere."""
    trajectory = make_trajectory(seed=5)
    marker_map = make_map(seed=6)
    path = tmp_path / "overlay.mcap"
    write_overlay(path, marker_map, trajectory, make_odometry(trajectory),
                  map_frame="markergraph_map", odom_frame="wheel_odom",
                  marker_frame_prefix="tag_")  # fmt: skip
    topics = read_overlay(path)
    frames: set[str] = set()
    for _, message in topics[MARKER_TOPIC]:
        frames |= {m.header.frame_id for m in message.markers}
    for topic in (PATH_TOPIC, POSE_TOPIC):
        frames |= {m.header.frame_id for _, m in topics[topic]}
    for _, message in topics[PATH_TOPIC]:
        frames |= {p.header.frame_id for p in message.poses}
    assert frames == {"markergraph_map"}
    pairs = {
        (t.header.frame_id, t.child_frame_id)
        for topic in (TF_TOPIC, TF_STATIC_TOPIC)
        for _, message in topics[topic]
        for t in message.transforms
    }
    assert pairs == {("markergraph_map", "wheel_odom")} | {
        ("markergraph_map", f"tag_{i}") for i in marker_map.markers
    }


@pytest.mark.parametrize(
    "arguments",
    [
        {"map_frame": ""},
        {"map_frame": "/map"},
        {"odom_frame": "odom "},
        {"map_frame": "odom"},
        {"marker_frame_prefix": ""},
        {"path_period_ns": 0},
        {"max_path_poses": 0},
    ],
)
def test_bad_arguments_are_refused(tmp_path: Path, arguments: dict[str, Any]) -> None:
    """A frame name ROS would reject, the same map and odom frame, or a period or limit below
    1 is a ValueError naming the argument, and no file is written."""
    trajectory = make_trajectory(seed=7)
    path = tmp_path / "overlay.mcap"
    with pytest.raises(ValueError, match="|".join(arguments)):
        write_overlay(path, make_map(seed=8), trajectory, make_odometry(trajectory), **arguments)
    assert not path.exists()


def test_no_trajectory_still_writes_the_map(tmp_path: Path) -> None:
    """Without a trajectory or odometry the overlay holds the map alone, at stamp 0."""
    empty = Trajectory(np.zeros(0, dtype=np.int64), np.zeros((0, 3)))
    marker_map = make_map(seed=9)
    path = tmp_path / "overlay.mcap"
    write_overlay(path, marker_map, empty, Trajectory(empty.t_ns, empty.poses, "odom"))
    topics = read_overlay(path)
    assert sorted(topics) == sorted([MARKER_TOPIC, TF_STATIC_TOPIC])
    assert len(topics[TF_STATIC_TOPIC][0][1].transforms) == len(marker_map.markers)


def test_rosbags_reads_the_pose_topic_as_evo_does(overlay) -> None:
    """rosbags' MCAP reader (what evo opens a ROS 2 bag with) lists the pose topic as
    geometry_msgs/msg/PoseStamped and decodes the trajectory from it with its own type store."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    path, trajectory, *_ = overlay
    typestore = get_typestore(Stores.LATEST)
    with Reader(path) as reader:
        assert reader.topics[POSE_TOPIC].msgtype == "geometry_msgs/msg/PoseStamped"
        connections = [c for c in reader.connections if c.topic == POSE_TOPIC]
        decoded = [
            typestore.deserialize_cdr(raw, c.msgtype)
            for c, _, raw in reader.messages(connections=connections)
        ]
    assert [stamp_ns(m.header) for m in decoded] == list(trajectory.t_ns)
    xy_yaw = [(m.pose.position.x, m.pose.position.y, quaternion_yaw(m.pose.orientation))
              for m in decoded]  # fmt: skip
    np.testing.assert_allclose(xy_yaw, trajectory.poses, rtol=0, atol=EXACT)


def test_evo_reads_the_pose_topic(overlay) -> None:
    """evo's bag reader turns the pose topic into the trajectory: stamps, positions, rotations."""
    file_interface = pytest.importorskip("evo.tools.file_interface")
    from rosbags.rosbag2 import Reader

    path, trajectory, *_ = overlay
    with Reader(path) as reader:
        read = file_interface.read_bag_trajectory(reader, POSE_TOPIC)
    np.testing.assert_allclose(read.timestamps, trajectory.t_ns * 1e-9, rtol=0, atol=EVO_SECONDS)
    expected_xyz = np.c_[trajectory.poses[:, :2], np.zeros(len(trajectory))]
    np.testing.assert_allclose(read.positions_xyz, expected_xyz, rtol=0, atol=EXACT)
    yaw = trajectory.poses[:, 2]
    wxyz = np.c_[np.cos(yaw / 2), np.zeros((len(yaw), 2)), np.sin(yaw / 2)]
    np.testing.assert_allclose(read.orientations_quat_wxyz, wxyz, rtol=0, atol=EXACT)
    assert read.meta["frame_id"] == "map"
