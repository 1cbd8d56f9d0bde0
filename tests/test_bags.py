"""ROS 2 SQLite bags (Humble's default) read through rosbags: a simulated log written as a .db3
rosbag2 folder gives exactly the observations and odometry its MCAP twin gives."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from trust_helpers import as_sqlite_bag

from markergraph.datasets import scenario, write_log
from markergraph.frontend import FrontendConfig, extract, open_log


@pytest.fixture(scope="module")
def twins(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    folder = tmp_path_factory.mktemp("bags")
    mcap = folder / "room.mcap"
    world, route = scenario("paper-room")
    write_log(world, route, mcap, seed=2, duration_s=15.0, compressed=True, frame_hz=5.0)
    as_sqlite_bag(mcap, folder / "room_bag")
    return mcap, folder / "room_bag"


def test_sqlite_bag_reads_like_its_mcap_twin(twins: tuple[Path, Path]) -> None:
    """Same topics with the same counts; the same observations and odometry, to the bit."""
    mcap, bag = twins
    assert (bag / "metadata.yaml").is_file() and any(bag.glob("*.db3"))
    assert open_log(bag).topics == open_log(mcap).topics
    config = FrontendConfig(allowed_ids=tuple(range(30)))
    from_bag, from_mcap = extract(bag, config), extract(mcap, config)
    assert from_bag.observations == from_mcap.observations and from_mcap.observations
    assert from_bag.odometry == from_mcap.odometry
    assert from_bag.true_markers.keys() == from_mcap.true_markers.keys()


def test_humble_bag_without_definitions_reads_the_detection_types(tmp_path: Path) -> None:
    """A Humble SQLite bag stores no message definitions: apriltag_ros's and Isaac ROS's
    detection arrays decode from markergraph's own definitions, corners as written (in OpenCV's
    order: the AprilTag library's reversed)."""
    import sqlite3

    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    from markergraph.frontend.detections import DETECTION_DEFINITIONS, detections_of

    store = get_typestore(Stores.ROS2_HUMBLE)
    for name, text in DETECTION_DEFINITIONS.items():
        store.register(get_types_from_msg(text, name))
    corners = [(100.0 + 10 * k, 200.0 - 5 * k) for k in range(4)]
    Time, Header = store.types["builtin_interfaces/msg/Time"], store.types["std_msgs/msg/Header"]
    header = Header(stamp=Time(sec=5, nanosec=250), frame_id="camera_optical")
    A = {k.rsplit("/", 1)[1]: v for k, v in store.types.items() if k.startswith("apriltag_msgs/")}
    apriltag = A["AprilTagDetectionArray"](header=header, detections=[A["AprilTagDetection"](
        family="36h11", id=7, hamming=0, goodness=0.0, decision_margin=40.0,
        centre=A["Point"](x=115.0, y=192.5), corners=[A["Point"](x=x, y=y) for x, y in corners],
        homography=np.zeros(9))])  # fmt: skip
    G = {k.rsplit("/", 1)[1]: v for k, v in store.types.items()
         if k.startswith(("isaac_ros_apriltag_interfaces/", "geometry_msgs/"))}  # fmt: skip
    pose = G["PoseWithCovarianceStamped"](header=header, pose=G["PoseWithCovariance"](
        pose=G["Pose"](position=G["Point"](x=0.0, y=0.0, z=1.0),
                       orientation=G["Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)),
        covariance=np.zeros(36)))  # fmt: skip
    isaac = G["AprilTagDetectionArray"](header=header, detections=[G["AprilTagDetection"](
        family="tag36h11", id=9, center=G["Point"](x=115.0, y=192.5, z=0.0),
        corners=[G["Point"](x=x, y=y, z=0.0) for x, y in corners], pose=pose)])  # fmt: skip
    folder = tmp_path / "humble_bag"
    with Writer(folder, version=8) as writer:
        for topic, message in (("/apriltag/detections", apriltag), ("/isaac/detections", isaac)):
            connection = writer.add_connection(topic, message.__msgtype__, typestore=store)
            writer.write(
                connection, 5_000_000_250, store.serialize_cdr(message, message.__msgtype__)
            )
    # As Humble writes it: schema 3, no message definitions.
    database = sqlite3.connect(next(folder.glob("*.db3")))
    database.execute("DROP TABLE message_definitions")
    database.execute("UPDATE schema SET schema_version = 3")
    database.commit()
    database.close()

    read = {
        m.topic: detections_of(m.decoded)
        for m in open_log(folder).messages(["/apriltag/detections", "/isaac/detections"])
    }
    assert [d.marker_id for d in read["/apriltag/detections"]] == [7]
    assert [d.marker_id for d in read["/isaac/detections"]] == [9]
    for found in read.values():
        np.testing.assert_array_equal(found[0].corners, np.array(corners)[::-1])
