"""Real sensors in the simulator: each effect moves the rendered pixels or the recorded stamps as
its definition says, against the simulator's own truth; and the remedies find what the effects
did (the camera's delay, the depth's scale)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import cv2
import gtsam
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

import markergraph as mg
from markergraph.datasets import Marker, Wall, World, scenario, write_log
from markergraph.datasets.capture import capture
from markergraph.datasets.render import Renderer
from markergraph.datasets.sensors import D435_DISTORTION, D435I_ON_DIFF_DRIVE, SensorEffects
from markergraph.estimator import Estimate, Trajectory
from markergraph.estimator.consider import marker_moves
from markergraph.frontend import FrontendConfig, extract
from markergraph.frontend.depth_scale import (
    DEPTH_SCALE_FLOOR,
    DEPTH_SCALE_RESOLUTION,
    depth_scale_from_markers,
)
from markergraph.frontend.detect import Detector
from markergraph.frontend.observe import (
    Flags,
    ObservationModel,
    marker_depth,
    observe_detections,
)
from markergraph.frontend.sizes import MarkerSizes

pytestmark = pytest.mark.slow  # its tests share a fixture that renders or maps a whole log

RATE = 1.0  # turn rate in the capture tests [rad/s]


@pytest.fixture(scope="module")
def wall_marker() -> tuple[Renderer, Trajectory]:
    """One marker 2 m ahead, and a robot turning in place at RATE, facing it at t = 0.1 s."""
    world = World("wall", (Wall((0.0, 0.0), (6.0, 0.0)),), (Marker(0, 0, 3.0, size_m=0.3),), 0)
    t_ns = np.arange(0, 400_000_000, 5_000_000)
    yaw = -math.pi / 2 + RATE * (t_ns - 100_000_000) * 1e-9
    poses = np.column_stack([np.full(len(t_ns), 3.0), np.full(len(t_ns), 2.1), yaw])
    return Renderer(world, texture_seed=1), Trajectory(t_ns, poses, "world")


def corners_of(rgb: np.ndarray) -> np.ndarray:
    found = Detector().detect(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY))
    assert len(found) == 1
    return found[0].corners


def test_rolling_shutter_skews_a_marker_by_the_turn_in_the_readout(wall_marker) -> None:
    """Each row is read readout * row / height later: while turning, a marker's bottom corners
    shift sideways against its top corners by rate * fx * readout * (rows between) / height."""
    renderer, truth = wall_marker
    rng = np.random.default_rng(0)
    readout = 0.025
    still = corners_of(capture(renderer, truth, 100_000_000, SensorEffects(), rng).rgb)
    rolled = corners_of(
        capture(renderer, truth, 100_000_000, SensorEffects(rolling_shutter_s=readout), rng).rgb
    )
    shift = rolled[:, 0] - still[:, 0]  # corners: top-left, top-right, bottom-right, bottom-left
    rows = (still[2, 1] + still[3, 1] - still[0, 1] - still[1, 1]) / 2.0
    skew = (shift[2] + shift[3] - shift[0] - shift[1]) / 2.0
    expected = RATE * renderer.camera.fx * readout * rows / renderer.camera.height
    assert skew == pytest.approx(expected, rel=0.2)
    assert abs(expected) > 2.0  # a skew worth measuring: corners are good to 0.05 px


def test_exposure_smears_edges_by_the_turn_during_it(wall_marker) -> None:
    """A 15 ms exposure at 1 rad/s sweeps fx * 0.015 = 9 px: the marker's left edge (the white
    sheet to its black border) spreads by that much (its 10-90 % rise by 80 % of the sweep)."""
    renderer, truth = wall_marker
    still = capture(renderer, truth, 100_000_000, SensorEffects(), np.random.default_rng(1))
    corners = corners_of(still.rgb)
    row = round(corners[:, 1].mean())
    edge = round((corners[0, 0] + corners[3, 0]) / 2.0)

    def rise(rgb: np.ndarray) -> int:
        profile = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)[row, edge - 20 : edge + 12].astype(float)
        level = (profile - profile.min()) / (profile.max() - profile.min())
        return int(np.count_nonzero((level > 0.1) & (level < 0.9)))

    smeared = capture(
        renderer, truth, 100_000_000, SensorEffects(exposure_s=0.015), np.random.default_rng(1)
    )
    sweep = RATE * 0.015 * renderer.camera.fx
    assert rise(smeared.rgb) - rise(still.rgb) == pytest.approx(0.8 * sweep, abs=2.0)


def test_depth_scale_and_black_cells(wall_marker) -> None:
    """Depth reads depth_scale times the truth; laminated black cells return nothing."""
    renderer, truth = wall_marker
    plain = capture(renderer, truth, 100_000_000, SensorEffects(), np.random.default_rng(2))
    scaled = capture(
        renderer, truth, 100_000_000,
        SensorEffects(depth_scale=1.012, black_cells_without_depth=True), np.random.default_rng(2),
    )  # fmt: skip
    both = (plain.depth_mm > 0) & (scaled.depth_mm > 0)
    ratio = scaled.depth_mm[both] / plain.depth_mm[both]
    assert np.median(ratio) == pytest.approx(1.012, abs=0.001)
    ink = cv2.cvtColor(plain.rgb, cv2.COLOR_RGB2GRAY) < 45
    assert ink.sum() > 500 and np.all(scaled.depth_mm[ink] == 0)
    assert np.all(scaled.depth_mm[~ink & both] > 0)


def test_distortion_is_what_camera_info_says(wall_marker) -> None:
    """With D435-like plumb_bob coefficients, detected corners sit several pixels from the
    pinhole's, and undistorting them with the same coefficients puts them back within 0.3 px."""
    renderer, _ = wall_marker
    camera = replace(renderer.camera, distortion=D435_DISTORTION)
    distorted = Renderer(renderer.world, camera, renderer.mount, texture_seed=1)
    pose = gtsam.Pose2(3.0, 2.1, -math.pi / 2 + 0.35)  # the marker near the image's edge
    ideal = corners_of(renderer.render(pose, np.random.default_rng(3)).rgb)
    bent = corners_of(distorted.render(pose, np.random.default_rng(3)).rgb)
    assert np.max(np.abs(bent - ideal)) > 1.0
    assert np.max(np.abs(camera.undistort(bent) - ideal)) < 0.3


@pytest.fixture(scope="module")
def realistic_log(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The paper room for 20 s, ideal and with the D435i preset."""
    folder = tmp_path_factory.mktemp("sensors")
    world, route = scenario("paper-room")
    logs = folder / "ideal.mcap", folder / "d435i.mcap"
    for log, sensors in zip(logs, (SensorEffects(), D435I_ON_DIFF_DRIVE), strict=True):
        write_log(world, route, log, seed=3, duration_s=20.0, compressed=True, frame_hz=5.0,
                  sensors=sensors)  # fmt: skip
    return logs


def stamps(log: Path, topic: str) -> np.ndarray:
    with open(log, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        return np.array(
            [
                m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
                for _, _, _, m in reader.iter_decoded_messages(topics=[topic])
            ]
        )


def test_stamps_drops_jitter_and_tf_tree(realistic_log) -> None:
    """Colour stamps 35 ms late (2 ms jitter) against the ideal log's capture times, 2 % of
    frames missing, odometry stamps off their 50 Hz grid by 2 ms, and the realsense TF tree,
    through which the front end still finds the camera 0.6 m above the floor."""
    ideal, real = realistic_log
    topic = "/camera/camera/color/image_raw/compressed"
    captured, stamped = stamps(ideal, topic), stamps(real, topic)
    assert 0 < len(captured) - len(stamped) <= 8  # 2 % of 100
    late = stamped[:, None] - captured[None, :]
    nearest = late[np.arange(len(stamped)), np.argmin(np.abs(late - 35e6), axis=1)]
    assert np.median(nearest) == pytest.approx(35e6, abs=1e6)
    assert np.std(nearest) == pytest.approx(2e6, rel=0.4)
    odometry = stamps(real, "/odom")
    off_grid = odometry - stamps(ideal, "/odom")
    assert np.std(off_grid) == pytest.approx(2e6, rel=0.3)
    extraction = extract(real, FrontendConfig())
    assert extraction.mount.height_m == pytest.approx(0.6, abs=1e-6)
    assert extraction.mount.x_m == pytest.approx(0.1, abs=1e-6)
    assert extraction.camera is not None and extraction.camera.distortion == D435_DISTORTION


def test_remedies_find_the_delay_and_the_depth_scale(realistic_log) -> None:
    """Chosen by SLAM's residuals, the camera's delay comes out near 35 ms once the shutter's
    row delay is modelled (and near 0 on the ideal log); the depth's scale, measured against
    the markers' size, within 0.2 % of 1.012 (and 1), and applied by default only beyond its
    own error."""
    for log, delay_ms, scale in zip(realistic_log, (0.0, 35.0), (1.0, 1.012), strict=True):
        run = mg.map_log(
            log, mg.MapConfig.from_values({"camera.readout_ms": 25.0 * bool(delay_ms)})
        )
        assert run.camera_delay_ns / 1e6 == pytest.approx(delay_ms, abs=6.0)
        measured = run.extraction.measured_depth_scale
        assert measured == pytest.approx(scale, abs=0.002)
        assert run.extraction.depth_scale == (
            measured if abs(measured - 1) > DEPTH_SCALE_RESOLUTION else 1.0
        )
        assert (run.extraction.depth_scale != 1.0) == (scale != 1.0)


def test_depth_at_an_oblique_marker_with_black_cells_is_its_centres(wall_marker) -> None:
    """Seen 40 degrees off its normal with no depth on its black cells, a marker's depth still
    comes out at its centre's (a plane through the white cells' depths), within 5 mm; a depth
    image that disagrees with the marker's size by more than 20 % is not used."""
    renderer, _ = wall_marker
    pose = gtsam.Pose2(1.2, 2.1, -math.pi / 2 + math.radians(40.0))
    true_z = renderer.mount.world_to_optical(pose, np.array([[3.0, 0.0, 1.0]]))[0, 2]
    effects = SensorEffects(black_cells_without_depth=True)
    truth = Trajectory(np.array([0, 10**9]), np.array([[pose.x(), pose.y(), pose.theta()]] * 2))
    frame = capture(renderer, truth, 0, effects, np.random.default_rng(4))
    (detection,) = Detector().detect(cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY))
    model = ObservationModel(MarkerSizes(0.3))
    (seen,) = observe_detections([detection], renderer.camera, model, depth=frame.depth_mm,
                                 mount=renderer.mount)  # fmt: skip
    assert Flags.NO_DEPTH not in seen.flags
    u, v = np.rint(detection.corners.mean(axis=0)).astype(int)
    z = marker_depth(frame.depth_mm, detection.corners, model.depth_model)
    assert z == pytest.approx(true_z, abs=0.005)  # the white cells' median: 24 mm off
    assert np.count_nonzero(frame.depth_mm[v - 20 : v + 20, u - 20 : u + 20] == 0) > 100
    wrong = np.full_like(frame.depth_mm, round(700 * true_z))  # 30 % short
    (unused,) = observe_detections([detection], renderer.camera, model, depth=wrong,
                                   mount=renderer.mount)  # fmt: skip
    assert Flags.NO_DEPTH in unused.flags


def test_depth_scale_is_the_steady_markers_robust_mean_ratio() -> None:
    """Exact algebra: pairs built as depth / PnP = k with 0.3 % noise, a tenth of them 20 %
    off (depth from the wall behind), are read back as k within 0.05 %; pairs taken while the
    robot turned at 1 rad/s, 5 % off, are left out."""
    from markergraph.estimator import Trajectory

    rng = np.random.default_rng(5)
    k = 1.012
    z = rng.uniform(1.0, 6.0, 400)
    ratio = k * (1 + rng.normal(0.0, 3e-3, z.size))
    ratio[::10] *= 1.2
    t_ns = np.arange(z.size) * 10**8  # 10 Hz; the robot turns through the last quarter
    turning = t_ns >= 3 * 10**10
    ratio[turning] *= 1.05
    yaw = np.where(turning, (t_ns - 3 * 10**10) * 1e-9, 0.0)
    odometry = Trajectory(t_ns, np.column_stack([np.zeros(z.size), np.zeros(z.size), yaw]))
    pairs = [(int(t), float(zi), float(zi / r)) for t, zi, r in zip(t_ns, z, ratio, strict=True)]
    scale, used, sigma = depth_scale_from_markers(pairs, odometry)
    assert used == np.count_nonzero(~turning)
    assert scale == pytest.approx(k, rel=5e-4)
    # Its sigma: the clean nine tenths' scatter over their root count, with the floor.
    clean = used - used // 10
    assert sigma == pytest.approx(np.hypot(3e-3 * k / np.sqrt(clean), DEPTH_SCALE_FLOOR), rel=0.05)


def test_an_unknown_readout_widens_the_map_by_how_far_it_moves(realistic_log) -> None:
    """The D435i's readout not given: SLAM's markers carry the readout's share of their
    covariance, and its note says how far they move between a readout of 0 and of 33 ms, which
    a map made with 33 ms given (a separate run) confirms."""
    log = realistic_log[1]
    unknown = mg.map_log(log, mg.MapConfig.from_values({"method": "slam"}))
    longest = mg.map_log(
        log, mg.MapConfig.from_values({"method": "slam", "camera.readout_ms": 1e3 / 30})
    )
    (result,), (other,) = unknown.results, longest.results
    (note,) = [n for n in result.estimate.notes if n.kind == "camera.readout_share"]
    moves = [
        math.dist(
            m.T_map_marker.translation(), other.estimate.markers[i].T_map_marker.translation()
        )
        for i, m in result.estimate.markers.items()
        if i in other.estimate.markers
    ]
    assert note.figure == pytest.approx(max(moves), abs=1e-5)  # the searches warm-start apart
    assert not [n for n in other.estimate.notes if n.kind == "camera.readout_share"]


@pytest.mark.parametrize(
    ("searched_key", "fixed", "note_kind"),
    [
        ("odometry.scale", {"camera.delay_ms": 35.0, "odometry.turn_scale": 1.0},
         "odometry.scale_share"),
        ("odometry.turn_scale", {"camera.delay_ms": 35.0, "odometry.scale": 1.0},
         "odometry.turn_scale_share"),
        ("camera.delay_ms", {"odometry.scale": 1.0, "odometry.turn_scale": 1.0},
         "camera.delay_share"),
    ],
)  # fmt: skip
def test_a_searched_setting_widens_the_map_by_how_far_one_sigma_moves_it(
    realistic_log, searched_key: str, fixed: dict, note_kind: str
) -> None:
    """The odometry's scale, its turn scale or the camera's delay, chosen by SLAM's residuals
    (the others given), known to the sigma their curvature gives: SLAM's markers carry its
    share, exactly d d^T for each marker's move d between maps made with the setting given at
    the chosen value and at one sigma further (separate runs), and its note gives the largest
    move."""
    log = realistic_log[1]
    # Neither the readout's share nor the depth's (the preset's scale given).
    settings = {"method": "slam", "camera.readout_ms": 25.0, "noise.depth_scale": 1.012, **fixed}
    searched = mg.map_log(log, mg.MapConfig.from_values(settings))
    if searched_key == "odometry.scale":
        chosen, sigma = searched.odometry_scale, searched.odometry_scale_sigma
        assert sigma is not None and 0.0 < sigma < 0.05
    elif searched_key == "odometry.turn_scale":
        chosen, sigma = searched.odometry_turn_scale, searched.odometry_turn_scale_sigma
        assert sigma is not None and 0.0 < sigma < 0.05
    else:
        chosen, sigma_ns = searched.camera_delay_ns / 1e6, searched.camera_delay_sigma_ns
        assert sigma_ns is not None and 0.0 < sigma_ns < 20e6
        sigma = round(chosen * 1e6 + sigma_ns) / 1e6 - chosen  # the stamps move by whole ns

    def given(value: float) -> Estimate:
        values = {**settings, searched_key: value}
        (result,) = mg.map_log(log, mg.MapConfig.from_values(values)).results
        assert not [n for n in result.estimate.notes if n.kind.endswith("_share")]
        return result.estimate

    (result,), at_chosen, further = searched.results, given(chosen), given(chosen + sigma)
    moves = marker_moves(at_chosen, further)
    assert set(moves) == set(result.estimate.markers) - {result.estimate.home_id}
    for i, marker in result.estimate.markers.items():
        assert marker.T_map_marker.equals(at_chosen.markers[i].T_map_marker, 1e-9)
        grown = marker.covariance - at_chosen.markers[i].covariance
        d = moves.get(i, np.zeros(3))  # the home marker: the map's origin, never moved
        np.testing.assert_allclose(grown, np.outer(d, d), atol=1e-12)
    (note,) = [n for n in result.estimate.notes if n.kind == note_kind]
    far = max(
        math.dist(m.T_map_marker.translation(), further.markers[i].T_map_marker.translation())
        for i, m in at_chosen.markers.items()
    )
    assert note.figure == pytest.approx(far, abs=1e-12)


def test_the_measured_depth_scale_widens_the_map_by_how_far_one_sigma_moves_it(
    realistic_log,
) -> None:
    """The D435i's depth, its scale measured against the markers' size (the searched settings
    given): SLAM's markers carry its share, exactly d d^T for each marker's move d between maps
    made with the depth's scale given as measured and one sigma longer, the odometry's scale
    following it as its search would (separate runs); its sigma is at least the floor."""
    log = realistic_log[1]
    settings = {"method": "slam", "camera.readout_ms": 25.0, "camera.delay_ms": 35.0,
                "odometry.turn_scale": 1.0, "odometry.scale": 1.0}  # fmt: skip
    measured = mg.map_log(log, mg.MapConfig.from_values(settings))
    scale, sigma = measured.extraction.depth_scale, measured.extraction.depth_scale_sigma
    assert sigma is not None and DEPTH_SCALE_FLOOR <= sigma < 2 * DEPTH_SCALE_FLOOR
    assert scale == measured.extraction.measured_depth_scale != 1.0

    def given(depth_scale: float, odometry_scale: float) -> Estimate:
        values = {**settings, "noise.depth_scale": depth_scale, "odometry.scale": odometry_scale}
        run = mg.map_log(log, mg.MapConfig.from_values(values))
        assert run.extraction.depth_scale_sigma is None
        (result,) = run.results
        assert not [n for n in result.estimate.notes if n.kind.endswith("_share")]
        return result.estimate

    # Ranges from depth one sigma longer: divided by a scale (1 + sigma) times smaller.
    at_measured, further = given(scale, 1.0), given(scale / (1 + sigma), 1.0 + sigma)
    (result,) = measured.results
    moves = marker_moves(at_measured, further)
    assert max(np.linalg.norm(d[:2]) for d in moves.values()) > 1e-3
    for i, marker in result.estimate.markers.items():
        assert marker.T_map_marker.equals(at_measured.markers[i].T_map_marker, 1e-9)
        grown = marker.covariance - at_measured.markers[i].covariance
        np.testing.assert_allclose(grown, np.outer(*[moves.get(i, np.zeros(3))] * 2), atol=1e-10)
    (note,) = [n for n in result.estimate.notes if n.kind == "depth.scale_share"]
    assert "from the markers' size" in note.text
    assert note.figure == pytest.approx(max(math.hypot(*d[:2]) for d in moves.values()), abs=1e-9)
