"""ROS 2 SQLite bags (Humble's default) read through rosbags: a simulated log written as a .db3
rosbag2 folder gives exactly the observations and odometry its MCAP twin gives."""

from __future__ import annotations

from pathlib import Path

import pytest
from mcap.reader import make_reader

from markergraph.datasets import scenario, write_log
from markergraph.frontend import FrontendConfig, extract, log_topics


def as_sqlite_bag(mcap: Path, folder: Path) -> None:
    """The same messages (their CDR bytes as recorded) in a rosbag2 folder stored in SQLite."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    with open(mcap, "rb") as stream, Writer(folder, version=8) as writer:
        connections = {}
        for schema, channel, message in make_reader(stream).iter_messages():
            if channel.topic not in connections:
                connections[channel.topic] = writer.add_connection(
                    channel.topic, schema.name, typestore=store
                )
            writer.write(connections[channel.topic], message.log_time, message.data)


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
    assert log_topics(bag) == log_topics(mcap)
    config = FrontendConfig(allowed_ids=tuple(range(30)))
    from_bag, from_mcap = extract(bag, config), extract(mcap, config)
    assert from_bag.observations == from_mcap.observations and from_mcap.observations
    assert from_bag.odometry == from_mcap.odometry
    assert from_bag.true_markers.keys() == from_mcap.true_markers.keys()
