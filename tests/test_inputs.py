"""The front end judges its inputs against each other: an odd odometry or frame stamp, an absurd
camera_info, a wrong marker size and the odometry's kind are found by the majority of the
log's own evidence, checked against the simulator's ground truth."""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from markergraph.datasets.rewrite import rewrite_log
from markergraph.datasets.scenarios import scenario
from markergraph.datasets.write import write_log
from markergraph.frontend.camera import Camera, majority_camera
from markergraph.frontend.inputs import odd_stamps
from markergraph.frontend.marker_size import marker_sizes_by_depth
from markergraph.records import MapRun
from markergraph.run import map_log
from markergraph.settings import MapConfig

COLOR = "/camera/camera/color/image_raw/compressed"
INFO = "/camera/camera/color/camera_info"
SAME_MAP_M = 1e-3  # one bad message set aside moves no marker by more than 1 mm
EXACT = 1e-9


@pytest.fixture(scope="module")
def clean(log: Path) -> MapRun:
    return map_log(log)


def rewritten(
    log: Path, tmp_path: Path, change: Callable[[str, int, Any], Any], name: str = "rewritten"
) -> Path:
    path = tmp_path / f"{name}.mcap"
    rewrite_log(log, path, change)
    return path


def marker_error_m(run: MapRun) -> float:
    """SLAM's marker RMSE against the simulator's ground truth [m]."""
    error = run.results[0].map_error
    assert error is not None
    return error.rmse_position_m


def moved_m(run: MapRun, clean: MapRun) -> float:
    """How far the run's markers lie from the clean log's [m]."""
    a, b = run.results[0].estimate.markers, clean.results[0].estimate.markers
    assert a.keys() == b.keys()
    return max(
        float(np.linalg.norm(a[i].T_map_marker.translation() - b[i].T_map_marker.translation()))
        for i in a
    )


# --- stamps ---------------------------------------------------------------------------------


def test_odd_stamps_keep_the_majority() -> None:
    """One stamp 1000 s late, one 5 s early at the start, and a repeat are the ones dropped,
    with the worst offset from where the others put them."""
    t = np.arange(100, dtype=np.int64) * 20_000_000
    stamps = t.copy()
    stamps[40] += 1000 * 10**9
    stamps[0] -= 5 * 10**9
    stamps[70] = stamps[68]  # a repeat of an earlier stamp
    judged = odd_stamps(stamps, t + 3_000_000)
    assert sorted(np.flatnonzero(~judged.kept).tolist()) == [0, 40, 70]
    assert judged.worst_offset_s == pytest.approx(1000.0, abs=EXACT)


def test_odd_stamps_follow_a_drifting_clock() -> None:
    """Stamps every 10 s on a camera clock that drifts 3 s over an hour against the log's are
    all kept (a constant lead would set a third of them aside); one 2 s off that line, still
    in order, is dropped."""
    log_ns = np.arange(360, dtype=np.int64) * 10**10
    stamps = log_ns + (log_ns * 3 // 3600)
    stamps[180] += 2 * 10**9
    judged = odd_stamps(stamps, log_ns)
    assert np.flatnonzero(~judged.kept).tolist() == [180]
    assert judged.worst_offset_s == pytest.approx(2.0, abs=0.01)


def test_odd_stamps_without_log_times_judge_order_alone() -> None:
    """Log times all equal (none recorded): a stamp 5 s early at the start rises with the
    rest and is kept; one out of order is dropped."""
    stamps = np.arange(50, dtype=np.int64) * 10**8
    stamps[0] -= 5 * 10**9
    stamps[30] += 10**10
    judged = odd_stamps(stamps, np.zeros(50, dtype=np.int64))
    assert np.flatnonzero(~judged.kept).tolist() == [30]


@pytest.mark.parametrize(
    ("index", "seconds", "worst_s"), [(300, 1000, 1000.0), (0, 5, 5.0)], ids=["late", "first"]
)
@pytest.mark.slow
def test_one_odd_odometry_stamp_costs_that_sample(
    log: Path, clean: MapRun, tmp_path: Path, index: int, seconds: int, worst_s: float
) -> None:
    """One /odom stamp 1000 s late (formerly the 700 good samples after it were dropped: SLAM
    2.44 m off the truth against 0.118 m), or the first one 5 s late: that sample alone is
    dropped, with a note naming the topic and the offset, and the map is the clean log's."""

    def late(topic: str, i: int, decoded: Any) -> Any:
        if topic == "/odom" and i == index:
            decoded.header.stamp.sec += seconds
        return decoded

    run = map_log(rewritten(log, tmp_path, late))
    extraction = run.extraction
    assert extraction.dropped_odometry_samples == 1
    assert extraction.worst_odometry_stamp_offset_s == pytest.approx(worst_s, abs=0.05)
    assert any(
        n.kind == "odometry.dropped_by_stamp" and n.topic == "/odom" and n.figure == 1
        for n in extraction.notes
    )
    assert len(extraction.odometry) == len(clean.extraction.odometry) - 1
    assert moved_m(run, clean) < SAME_MAP_M
    assert marker_error_m(run) < marker_error_m(clean) + SAME_MAP_M


def test_a_log_time_of_zero_in_a_sqlite_bag_costs_that_sample(
    log: Path, clean: MapRun, tmp_path: Path
) -> None:
    """A .db3 bag whose 300th /odom message was logged at time 0 (so read first, 6 s before
    its stamp's place): formerly the 300 samples before its stamp were dropped and SLAM placed
    2 of 3 markers; now that sample alone is dropped and the map is the clean log's."""
    from mcap.reader import make_reader
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    folder, seen = tmp_path / "bag", 0
    with open(log, "rb") as stream, Writer(folder, version=8) as writer:
        connections: dict[str, Any] = {}
        for schema, channel, message in make_reader(stream).iter_messages():
            if channel.topic not in connections:
                connections[channel.topic] = writer.add_connection(
                    channel.topic, schema.name, typestore=store
                )
            t_ns = message.log_time
            if channel.topic == "/odom":
                t_ns, seen = (0 if seen == 300 else t_ns), seen + 1
            writer.write(connections[channel.topic], t_ns, message.data)
    run = map_log(folder)
    assert run.extraction.dropped_odometry_samples == 1
    assert run.extraction.worst_odometry_stamp_offset_s == pytest.approx(6.0, abs=0.05)
    assert moved_m(run, clean) < SAME_MAP_M


@pytest.mark.slow
def test_a_frame_stamped_seconds_off_costs_its_observations(
    log: Path, clean: MapRun, tmp_path: Path
) -> None:
    """A colour frame stamped 3 s late (inside the odometry's span, so it would put its markers
    where the robot was not) costs that frame: its observations are dropped with a note, and
    the map is the one of the log without that frame, within 1 mm."""
    stamps = sorted({o.t_ns for o in clean.extraction.observations})
    wrong_ns = stamps[10]

    def is_wrong(topic: str, decoded: Any) -> bool:
        stamp = decoded.header.stamp if topic == COLOR else None
        return stamp is not None and stamp.sec * 10**9 + stamp.nanosec == wrong_ns

    def late(topic: str, i: int, decoded: Any) -> Any:
        if is_wrong(topic, decoded):
            decoded.header.stamp.sec += 3
        return decoded

    run = map_log(rewritten(log, tmp_path, late, "late"))
    without = map_log(
        rewritten(log, tmp_path, lambda t, i, d: None if is_wrong(t, d) else d, "without")
    )
    assert run.extraction.frames_dropped_by_stamp == 1
    assert any(n.kind == "frames.dropped_by_stamp" and n.figure == 1 for n in run.extraction.notes)
    assert len(run.extraction.observations) == len(without.extraction.observations)
    assert moved_m(run, without) < SAME_MAP_M


# --- camera_info ----------------------------------------------------------------------------


def test_camera_models_that_cannot_be_are_named() -> None:
    """A distortion of 1e30 folds the image's border, a focal length of 1e300 sees no field of
    view, a k1 of -2 throws the border back 300 px away; real lenses pass."""
    assert Camera().implausible() is None
    assert Camera(distortion=(0.1, -0.2, 0.001, 0.001, 0.05)).implausible() is None
    fisheye = Camera(
        285.0, 285.0, 424.0, 400.0, 848, 800, (-0.01, 0.05, -0.05, 0.01), "equidistant"
    )
    assert fisheye.implausible() is None
    assert "folds" in str(Camera(distortion=(1e30,) * 5).implausible())
    assert "field of view" in str(Camera(fx=1e300, fy=1e300).implausible())
    assert "px from where it came from" in str(Camera(distortion=(-2.0, 0, 0, 0, 0)).implausible())


def test_the_majority_of_camera_infos_is_believed() -> None:
    """Two plausible models: the one more messages give wins; the others are counted by why."""
    chosen, set_aside = majority_camera(
        [Camera(fx=700.0), Camera(), Camera(), Camera(distortion=(1e30,) * 5), "no K"]
    )
    assert chosen == Camera()
    assert set_aside == {
        "it disagrees with the majority's model": 1,
        "its undistortion folds the image's border over (not monotone along an edge)": 1,
        "no K": 1,
    }


@pytest.mark.parametrize(
    ("field", "value", "why"),
    [("d", [1e30] * 5, "folds"), ("k", "f1e300", "field of view"), ("k", "f700", "majority")],
    ids=["distortion-1e30", "focal-1e300", "focal-700"],
)
def test_an_absurd_first_camera_info_is_set_aside(
    log: Path, clean: MapRun, tmp_path: Path, field: str, value: Any, why: str
) -> None:
    """The first camera_info with distortion 1e30 (formerly believed: SLAM 3.32 m off), focal
    length 1e300 (formerly: no markers found, exit 1) or a plausible 700 px the others
    contradict: set aside with a note, the majority's model used, the clean log's map."""

    def absurd(topic: str, i: int, decoded: Any) -> Any:
        if topic == INFO and i == 0:
            if field == "d":
                decoded.d = value
            else:
                f = float(value[1:])
                decoded.k = [f, 0.0, decoded.k[2], 0.0, f, decoded.k[5], 0.0, 0.0, 1.0]
        return decoded

    run = map_log(rewritten(log, tmp_path, absurd))
    extraction = run.extraction
    assert extraction.camera == clean.extraction.camera
    assert extraction.camera_infos_set_aside == 1
    assert any(why in reason for reason in extraction.camera_info_reasons)
    assert any(
        n.kind == "camera_info.set_aside" and n.topic == INFO and n.figure == 1
        and n.text.startswith("camera_info: 1 of 25 messages")
        for n in extraction.notes
    )  # fmt: skip
    assert moved_m(run, clean) < SAME_MAP_M


# --- the markers' size ------------------------------------------------------------------------


def test_depth_over_pnp_tells_a_size_from_a_depth_scale() -> None:
    """Exact algebra: ratios of 1.012 are a depth camera's scale (the size is kept); 4/3 is a
    size (0.15 given for 0.20); one marker at 4/3 among others at 1 is that marker's size."""
    rng = np.random.default_rng(7)

    def ratios(by_id: dict[int, float]) -> list[tuple[int, float]]:
        return [(i, k * (1 + rng.normal(0.0, 2e-3))) for i, k in by_id.items() for _ in range(30)]

    depth = marker_sizes_by_depth(ratios({0: 1.012, 1: 1.012}), 0.2, {}, 1.0)
    assert depth is not None and not depth.use and depth.size_m == 0.2
    assert depth.ratio == pytest.approx(1.012, rel=1e-3)
    size = marker_sizes_by_depth(ratios({0: 4 / 3, 1: 4 / 3}), 0.15, {}, 1.0)
    assert size is not None and size.use and not size.sizes_m
    assert size.size_m == pytest.approx(0.2, rel=1e-3)
    one = marker_sizes_by_depth(ratios({0: 1.0, 1: 4 / 3, 2: 1.0}), 0.15, {}, 1.0)
    assert one is not None and one.use and one.size_m == 0.15
    assert one.sizes_m.keys() == {1} and one.sizes_m[1] == pytest.approx(0.2, rel=1e-3)
    said = marker_sizes_by_depth(ratios({0: 4 / 3, 1: 4 / 3}), 0.15, {}, 4 / 3)
    assert said is not None and not said.use  # --depth-scale says depth is the side that is off
    # Marker 2 given 0.25 m for its 0.20 and seen most: its own error, not the others' size.
    own = marker_sizes_by_depth(ratios({0: 1.0, 1: 1.0, 2: 0.8, 3: 0.8, 4: 0.8}), 0.2,
                                {i: 0.25 for i in (2, 3, 4)}, 1.0)  # fmt: skip
    assert own is not None and own.use and own.size_m == 0.2
    assert own.sizes_m.keys() == {2, 3, 4}
    assert all(v == pytest.approx(0.2, rel=1e-3) for v in own.sizes_m.values())


def test_a_wrong_marker_size_is_measured_by_depth(log: Path, clean: MapRun) -> None:
    """--marker-size 0.15 on markers of 0.20 m: depth measures them 0.200 m (within 0.5 %),
    that size is used and said, map.json carries it, and the map is the clean log's."""
    run = map_log(log, MapConfig.from_values({"marker_size": 0.15}))
    extraction = run.extraction
    assert extraction.marker_sizes_used.default_m == pytest.approx(0.2, rel=5e-3)
    assert extraction.marker_size_m_by_depth == extraction.marker_sizes_used.default_m
    assert any(n.kind == "marker_size.measured" and n.figure == pytest.approx(0.2, abs=5e-4)
               and "(the given 0.15 m would put every range 25 % short" in n.text
               for n in extraction.notes)  # fmt: skip
    assert run.results[0].marker_map.marker_size_m == extraction.marker_sizes_used.default_m
    assert moved_m(run, clean) < SAME_MAP_M
    assert clean.extraction.marker_size_m_by_depth == pytest.approx(0.2, rel=5e-3)
    assert clean.extraction.marker_sizes_used.default_m == 0.2


def test_the_size_note_says_how_to_keep_the_given_size(log: Path) -> None:
    """The note's --depth-scale, given, keeps the given size: depth is then the side that is
    off, and the front end reads the log at 0.15 m without measuring the markers again."""
    from markergraph.frontend import extract

    wrong = extract(log, MapConfig.from_values({"marker_size": 0.15}).frontend)
    note = next(n for n in wrong.notes if n.kind == "marker_size.measured")
    found = re.search(r"if 0.15 m is right, --depth-scale ([0-9.]+) \(depth reads", note.text)
    assert found is not None
    scale = float(found.group(1))
    assert scale == pytest.approx(4 / 3, rel=1e-2)  # 0.20 m markers read with 0.15 m
    kept = extract(log, MapConfig.from_values({"marker_size": 0.15,
                                               "noise.depth_scale": scale}).frontend)  # fmt: skip
    assert kept.marker_sizes_used.default_m == 0.15
    assert not any(
        n.kind.startswith("marker_size.") for n in kept.notes if n.kind != "marker_size.given"
    )


def test_one_marker_of_another_size_is_measured(clean: MapRun, tmp_path: Path) -> None:
    """Marker 1 printed at 0.15 m among markers of 0.20: depth measures it within 1 %, it alone
    gets that size, and SLAM's map is as far from the truth as the clean log's, within 1 cm."""
    world, route = scenario("paper-room")
    markers = tuple(replace(m, size_m=0.15) if m.id == 1 else m for m in world.markers)
    path = tmp_path / "mixed.mcap"
    write_log(replace(world, markers=markers), route, path, seed=3, duration_s=20.0,
              compressed=True, frame_hz=5.0)  # fmt: skip
    run = map_log(path)
    extraction = run.extraction
    assert extraction.marker_sizes_used.default_m == 0.2
    assert extraction.marker_sizes_used.by_id.keys() == {1}
    assert extraction.marker_sizes_used.by_id[1] == pytest.approx(0.15, rel=0.01)
    assert any(
        n.kind == "marker_size.apart" and n.text.startswith("marker 1 measures 0.15")
        for n in extraction.notes
    )
    assert marker_error_m(run) < marker_error_m(clean) + 0.01


def test_without_depth_the_scale_rests_on_the_given_size(log: Path, tmp_path: Path) -> None:
    """A log without its depth topic says that the map's scale rests on the given size."""
    depthless = rewritten(log, tmp_path, lambda t, i, d: None if "depth" in t else d)
    extraction = map_log(depthless).extraction
    assert extraction.marker_size_m_by_depth is None
    assert any(n.kind == "marker_size.given" and n.figure is None and
               n.text.startswith("the map's scale rests on the given marker size (0.2 m")
               for n in extraction.notes)  # fmt: skip


# --- the odometry's kind --------------------------------------------------------------------

TAGSLAM = Path(__file__).resolve().parents[2] / "shared" / "data" / "tagslam-test" / "tests"


def test_planar_odometry_on_odom_is_wheel_odometry(clean: MapRun) -> None:
    """The simulator's wheel odometry (z, roll, pitch exactly zero, covariance unset, 50 Hz) is
    judged planar and gets the wheel model, with what decided it in the note."""
    evidence = clean.extraction.odometry_evidence
    assert evidence is not None and evidence.planar
    assert evidence.max_tilt_rad == 0.0 and evidence.z_span_m == 0.0
    assert evidence.covariance == "unset"
    assert evidence.rate_hz == pytest.approx(50.0, rel=0.05)
    assert clean.odometry_source == "wheel"
    assert str(clean.odometry_model_reason).startswith("planar")
    assert [n.kind for n in clean.notes].count("odometry.noise_model") == 1


def test_three_d_odometry_on_odom_is_visual_inertial(log: Path, tmp_path: Path) -> None:
    """/odom rewritten to roll by up to 2 deg and rise by 5 cm with a set, constant covariance
    (a VIO published under /odom): judged 3-D from its messages, not by its name, and gets
    the VIO model; the evidence carries the injected figures."""
    roll_rad, rise_m = np.radians(2.0), 0.05

    def three_d(topic: str, i: int, decoded: Any) -> Any:
        if topic == "/odom":
            pose = decoded.pose.pose
            half = roll_rad * np.sin(i / 25.0) / 2.0
            q = pose.orientation  # yaw only: (0, 0, sz, cz); roll about the body's x after it
            qz, qw = q.z, q.w
            q.x, q.y, q.z, q.w = (
                qw * np.sin(half),
                qz * np.sin(half),
                qz * np.cos(half),
                (qw * np.cos(half)),
            )
            pose.position.z = rise_m * (i % 100) / 99.0
            decoded.pose.covariance = [0.01 if k % 7 == 0 else 0.0 for k in range(36)]
        return decoded

    run = map_log(rewritten(log, tmp_path, three_d))
    evidence = run.extraction.odometry_evidence
    assert evidence is not None and not evidence.planar
    assert evidence.max_tilt_rad == pytest.approx(roll_rad, rel=1e-3)
    assert evidence.z_span_m == pytest.approx(rise_m, abs=1e-9)
    assert evidence.covariance == "constant"
    assert run.odometry_source == "vio"
    assert "3-D motion" in str(run.odometry_model_reason)
    assert [n.kind for n in run.notes].count("odometry.noise_model") == 1


@pytest.mark.skipif(not TAGSLAM.is_dir(), reason="../shared/data/tagslam-test is absent")
def test_tagslam_vio_republished_under_odom_is_visual_inertial(tmp_path: Path) -> None:
    """TagSLAM test 21's basalt VIO, named /odom: its messages say 3-D (roll and pitch up to
    98 deg, height over 0.44 m in its first 600 samples at 25 Hz, a constant placeholder
    covariance), so the VIO model, whatever the name."""
    from markergraph.datasets.tagslam import unpacked
    from markergraph.frontend import open_log
    from markergraph.frontend.odometry_kind import choose_odometry_source, odometry_evidence

    bag = unpacked(TAGSLAM / "test_21", "tag_detections", tmp_path)
    evidence = odometry_evidence(open_log(bag), "/vio_node/odom")
    assert evidence is not None and evidence.samples == 600
    assert evidence.rate_hz == pytest.approx(24.8, abs=0.1)
    assert evidence.covariance == "constant"
    source, why = choose_odometry_source(evidence, "/odom")
    assert source == "vio" and why.startswith("3-D motion")


def test_the_evidence_is_json_ready(clean: MapRun) -> None:
    """Extraction.input_evidence() holds the judged figures and survives strict JSON."""
    import json

    evidence = clean.extraction.input_evidence()
    text = json.dumps(evidence, allow_nan=False)
    assert json.loads(text)["odometry_evidence"]["covariance"] == "unset"
    assert evidence["dropped_odometry_samples"] == 0 and evidence["camera_infos_set_aside"] == 0
    assert evidence["marker_size_m_used"] == 0.2
    assert str(clean.odometry_model_reason).startswith("planar")  # the run's, beside these
