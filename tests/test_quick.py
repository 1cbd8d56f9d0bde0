"""Quick re-runs and quick writing: an estimator setting changed reuses the cached camera-delay
and odometry-scale searches (they weigh residuals by the sensors' presets, not the user's noise)
and gives the map a fresh run would; overlay.mcap's own CDR bytes are what mcap_ros2 encodes."""

from __future__ import annotations

import io
import json
import math
from pathlib import Path

import gtsam
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer

import markergraph.prepare as prepare_module
import markergraph.run as run_module
from markergraph.cli import main
from markergraph.common import MarkerGraphError
from markergraph.estimator.trajectory import Trajectory
from markergraph.formats.cdr import CdrWriter, layout, string_fields
from markergraph.markermap import MapMarker, MarkerMap
from markergraph.overlay import PATH_TOPIC, POSE_TOPIC, TF_TOPIC, write_overlay
from markergraph.settings import MapConfig

SAME_MAP_M = 1e-9  # the same inputs through the same optimiser: the same numbers
MOVED_M = 1e-4  # a tenfold odometry noise moves some marker by more than this
EXACT = 1e-12  # float64 fields copied through CDR and a yaw <-> quaternion round trip


@pytest.fixture
def cached(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Path:
    """The cache turned on, in a folder of this test's own."""
    monkeypatch.setenv("MARKERGRAPH_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv("MARKERGRAPH_NO_CACHE", raising=False)
    return tmp_path / "cache"


def _map(log: Path, out: Path, *flags: str) -> tuple[dict, dict]:
    """``markergraph map`` in this process; its map.json and report.json."""
    assert main(["map", str(log), "--out", str(out), "--no-plots", "--quiet", *flags]) == 0
    return (
        json.loads((out / "map.json").read_text()),
        json.loads((out / "report.json").read_text()),
    )


def _no_search(*args: object, **kwargs: object) -> object:
    raise AssertionError("a search ran that the cache holds")


def _positions(document: dict) -> dict[int, np.ndarray]:
    return {int(m["id"]): np.array([m["x"], m["y"]]) for m in document["markers"]}


def _position_variances(document: dict) -> dict[int, float]:
    """Each marker's x and y variances summed [m^2], the home marker (held by a prior) left
    out."""
    variances = {}
    for m in document["markers"]:
        if m["id"] != document["home_id"]:
            covariance = np.asarray(m["covariance"], dtype=float).reshape(3, 3)
            variances[int(m["id"])] = float(covariance[0, 0] + covariance[1, 1])
    return variances


def test_estimator_setting_changed_reuses_the_searches(
    log: Path, tmp_path: Path, cached: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A tenfold odometry noise and another robust kernel take the delay and scale from the
    cache (no search runs; the notes say so), and the map is the one a fresh run with those
    settings makes: markers moved, wider ellipses where odometry weighs less (a global shutter:
    the odometry alone widens them, not an unknown readout's share)."""
    first, first_report = _map(log, tmp_path / "one", "--readout", "0")
    monkeypatch.setattr(prepare_module, "camera_delay_by_residuals", _no_search)
    monkeypatch.setattr(prepare_module, "odometry_scale_by_residuals", _no_search)
    monkeypatch.setattr(prepare_module, "odometry_turn_scale_by_residuals", _no_search)
    flags = ("--odometry-noise", "0.12", "--robust", "cauchy", "--readout", "0")
    again, report = _map(log, tmp_path / "two", *flags)
    for setting in ("camera_delay_ms", "odometry_scale", "odometry_turn_scale"):
        assert report[setting] == first_report[setting], setting
    cache_said = [n for n in report["notes"] if "on an earlier run: from the cache" in n]
    assert len(cache_said) == 3, report["notes"]  # the delay's, the scale's, the turn scale's
    a, b = _positions(first), _positions(again)
    assert a.keys() == b.keys()
    assert max(float(np.linalg.norm(a[i] - b[i])) for i in a) > MOVED_M
    wide, narrow = _position_variances(again), _position_variances(first)
    assert wide.keys() == narrow.keys() and wide
    assert all(wide[i] > narrow[i] for i in wide)
    monkeypatch.undo()  # a fresh run searches again, under the same presets
    fresh, fresh_report = _map(log, tmp_path / "three", "--no-cache", *flags)
    assert fresh_report["camera_delay_ms"] == report["camera_delay_ms"]
    assert fresh_report["odometry_scale"] == report["odometry_scale"]
    assert fresh_report["odometry_turn_scale"] == report["odometry_turn_scale"]
    c = _positions(fresh)
    assert max(float(np.linalg.norm(b[i] - c[i])) for i in b) < SAME_MAP_M


def test_an_unknown_readouts_searches_are_cached_too(
    log: Path, tmp_path: Path, cached: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The readout not given, the map is also made ready as if it were 33 ms (for the
    readout's share of the covariances): those searches too come from the cache when only an
    estimator setting changed, and the covariances are those a fresh run makes."""
    _map(log, tmp_path / "one")
    monkeypatch.setattr(prepare_module, "camera_delay_by_residuals", _no_search)
    monkeypatch.setattr(prepare_module, "odometry_scale_by_residuals", _no_search)
    again, _ = _map(log, tmp_path / "two", "--odometry-noise", "0.12")
    monkeypatch.undo()
    fresh, _ = _map(log, tmp_path / "three", "--no-cache", "--odometry-noise", "0.12")
    a, b = _position_variances(again), _position_variances(fresh)
    assert a.keys() == b.keys() and a
    assert max(abs(a[i] - b[i]) for i in a) < SAME_MAP_M


def test_a_readout_map_that_cannot_be_made_costs_only_its_share(
    log: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Where the map cannot be made ready as if the readout were 33 ms, the map is still made,
    its covariances those of the map with the readout taken as 0, and a note says what they
    lack."""
    real = run_module.prepare

    def failing(
        log: Path, extraction: object, config: MapConfig, *args: object, **kwargs: object
    ) -> object:
        if config.camera.readout_ns is not None:
            raise MarkerGraphError("no odometry at the moved stamps")
        return real(log, extraction, config, *args, **kwargs)

    monkeypatch.setattr(run_module, "prepare", failing)
    _, report = _map(log, tmp_path / "lacking", "--no-cache")
    notes = report["methods"]["slam"]["notes"] + report["notes"]
    assert [n for n in notes if "could not be made as if it were 33 ms" in n], notes
    assert not [n for n in notes if "readout not given: the markers move" in n]


def _trajectory(seed: int, n: int) -> Trajectory:
    rng = np.random.default_rng(seed)
    t_ns = 1_700_000_000_123_456_789 + np.cumsum(rng.integers(20_000_000, 300_000_000, n))
    poses = np.cumsum(rng.normal(0.0, [0.1, 0.1, 0.2], (n, 3)), axis=0)
    poses[:, 2] = np.arctan2(np.sin(poses[:, 2]), np.cos(poses[:, 2]))
    return Trajectory(t_ns, poses, "map")


def _map_of(seed: int) -> MarkerMap:
    rng = np.random.default_rng(seed)
    markers = {}
    for marker_id in (0, 4, 9, 31):
        x, y, yaw = rng.uniform(-4.0, 4.0), rng.uniform(-4.0, 4.0), rng.uniform(-3.0, 3.0)
        covariance = np.diag(rng.uniform(0.01, 0.1, 3) ** 2) if marker_id else None
        z_m = float(rng.uniform(0.2, 1.5)) if marker_id % 2 else None
        markers[marker_id] = MapMarker(marker_id, gtsam.Pose2(x, y, yaw), covariance, 3, 0.2, z_m)
    return MarkerMap(markers, (), 0, "DICT_4X4_50", 0.2, "slam", "test.mcap")


def _reencoded(path: Path) -> list[tuple[str, int, bytes, bytes]]:
    """Each message of the file as (topic, log time, its bytes, the bytes mcap_ros2's own
    encoder makes of its decoded form)."""
    with open(path, "rb") as stream:
        decoded = list(
            make_reader(stream, decoder_factories=[DecoderFactory()]).iter_decoded_messages()
        )
    buffer = io.BytesIO()
    writer = Writer(buffer)
    schemas = {}
    for schema, channel, message, value in decoded:
        if schema.name not in schemas:
            schemas[schema.name] = writer.register_msgdef(schema.name, schema.data.decode())
        writer.write_message(channel.topic, schemas[schema.name], value, message.log_time)
    writer.finish()
    buffer.seek(0)
    reference = [m.data for _, _, m in make_reader(buffer).iter_messages()]
    assert len(reference) == len(decoded)
    return [
        (channel.topic, message.log_time, message.data, data)
        for (_, channel, message, _), data in zip(decoded, reference, strict=True)
    ]


@pytest.mark.parametrize("map_frame", ["m", "map", "world", "map_abc", "markergraph_map"])
def test_overlay_bytes_are_mcap_ros2s(tmp_path: Path, map_frame: str) -> None:
    """Every message of overlay.mcap (markers, static and moving frames, poses, paths whose
    first pose falls on either alignment) is byte for byte what mcap_ros2's encoder makes of
    its decoded form, and the poses and stamps decoded are the trajectory's."""
    trajectory = _trajectory(7, 300)
    odometry = Trajectory(trajectory.t_ns[10:250], trajectory.poses[10:250] * 0.9, "odom")
    path = tmp_path / "overlay.mcap"
    write_overlay(path, _map_of(7), trajectory, odometry, map_frame=map_frame,
                  max_path_poses=40)  # fmt: skip
    messages = _reencoded(path)
    assert {topic for topic, *_ in messages} >= {POSE_TOPIC, PATH_TOPIC, TF_TOPIC}
    for topic, t_ns, data, reference in messages:
        assert data == reference, (topic, t_ns)
    with open(path, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        poses = [m for _, _, _, m in reader.iter_decoded_messages(topics=[POSE_TOPIC])]
    assert len(poses) == len(trajectory)
    for pose, t_ns, (x, y, yaw) in zip(poses, trajectory.t_ns, trajectory.poses, strict=True):
        stamp = pose.header.stamp
        assert stamp.sec * 1_000_000_000 + stamp.nanosec == t_ns
        assert pose.header.frame_id == map_frame
        q = pose.pose.orientation
        assert math.isclose(pose.pose.position.x, x, abs_tol=EXACT)
        assert math.isclose(pose.pose.position.y, y, abs_tol=EXACT)
        assert math.isclose(2 * math.atan2(q.z, q.w), yaw, abs_tol=EXACT)


def test_bytes_laid_out_for_another_offset_are_refused() -> None:
    """Records laid out from one offset (mod 8) go only where the message is at that offset,
    and keep their alignment one after another."""
    record = layout([("sec", "<i4"), *string_fields("frame_id", "map"), ("x", "<f8")])
    assert record.itemsize % 8 == 0
    data = np.zeros(2, record).tobytes()
    with pytest.raises(ValueError, match="mod 8"):
        CdrWriter().uint32(1).encoded(data)
    assert CdrWriter().uint32(1, 2).encoded(data).data()[-len(data) :] == data
    assert CdrWriter().uint32(1).encoded(data[:16], start=4).offset == 20


def test_at_stamps_takes_own_poses_and_interpolates_the_rest() -> None:
    """At its own stamps a trajectory gives its poses exactly; between them, what ``at``
    gives; beyond its reach, nothing."""
    trajectory = _trajectory(3, 50)
    t = trajectory.t_ns
    between = (t[:-1] + t[1:]) // 2
    far = np.array([t[0] - 10**10, t[-1] + 10**10])
    stamps = np.concatenate([t, between, far])
    found = trajectory.at_stamps(stamps)
    assert np.array_equal(found.t_ns, np.concatenate([t, between]))
    np.testing.assert_array_equal(found.poses[: len(t)], trajectory.poses)
    for k, s in enumerate(between):
        expected = trajectory.at(int(s))
        assert expected is not None
        np.testing.assert_allclose(
            found.poses[len(t) + k], [expected.x(), expected.y(), expected.theta()], atol=EXACT
        )


def test_a_map_of_the_home_marker_alone_has_no_move_to_report() -> None:
    """The readout's note says how far the markers move; the home marker is the map's frame and
    cannot move, so a map of it alone gets no note (it said "up to 0.000 m"), while a second
    marker moved by 3 cm is reported at 0.030 m."""
    from dataclasses import replace

    import markergraph as mg
    from markergraph.estimator import Estimate, Trajectory
    from markergraph.estimator.types import MarkerEstimate
    from markergraph.shares import with_readout_share

    covariance = np.diag([1e-4, 1e-4, 1e-5])
    home = MarkerEstimate(0, gtsam.Pose2(), covariance, 10)
    far = MarkerEstimate(4, gtsam.Pose2(5.0, 2.0, 1.0), covariance, 10)
    alone = Estimate(mg.Method.SLAM, 0, {0: home}, Trajectory.from_samples([]))
    assert not with_readout_share(alone, alone).notes
    moved_far = replace(far, T_map_marker=gtsam.Pose2(5.03, 2.0, 1.0))
    two = replace(alone, markers={0: home, 4: far})
    (note,) = with_readout_share(two, replace(alone, markers={0: home, 4: moved_far})).notes
    assert note.kind == "camera.readout_share" and note.figure == pytest.approx(0.03)
    assert "up to 0.030 m" in note.text


def test_counts_are_said_in_the_singular_for_one() -> None:
    """The summaries' counts: "1 marker", never "1 markers"."""
    from markergraph.common.numbers import counted

    assert [counted(n, "marker") for n in (0, 1, 6)] == ["0 markers", "1 marker", "6 markers"]
