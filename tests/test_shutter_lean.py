"""A turning camera's image, against the simulator's truth: a rolling shutter leans a marker and
an exposure smears it; theta comes out right once the lean is taken off (``theta_per_turn``),
and edges are found across the smear."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from markergraph.datasets import Marker, Wall, World
from markergraph.datasets.capture import capture
from markergraph.datasets.render import Renderer
from markergraph.datasets.sensors import SensorEffects
from markergraph.estimator import Observation, Trajectory, unleaned
from markergraph.frontend.detect import Detector
from markergraph.frontend.observe import ObservationModel, observe_detections
from markergraph.frontend.sizes import MarkerSizes

RATE = 0.6  # the turn [rad/s]: the simulated warehouse robot's
READOUT = 0.025  # the D435i preset's rolling shutter [s]
SIZE = 0.2
WORLD = World("wall", (Wall((0.0, 0.0), (6.0, 0.0)),), (Marker(0, 0, 3.0, size_m=SIZE),), 0)
RENDERER = Renderer(WORLD, texture_seed=1)
T_WORLD_MARKER = WORLD.T_world_marker(0)


def turning_at(view_deg: float, distance_m: float = 1.4) -> Trajectory:
    """The robot 1.4 m from the marker at ``view_deg`` off its normal, turning left at RATE in
    place, facing the marker (turned 0.1 rad past it) at 0.1 s."""
    view = math.radians(view_deg)
    x, y = T_WORLD_MARKER.transformFrom(
        np.array([distance_m * math.cos(view), distance_m * math.sin(view)])
    )
    facing = math.atan2(T_WORLD_MARKER.y() - y, T_WORLD_MARKER.x() - x) + 0.1
    t_ns = np.arange(0, 300_000_000, 5_000_000)
    yaw = facing + RATE * (t_ns - 100_000_000) * 1e-9
    return Trajectory(t_ns, np.column_stack([np.full(len(t_ns), x), np.full(len(t_ns), y), yaw]))


def seen(truth: Trajectory, effects: SensorEffects, seed: int = 0) -> tuple[Observation, float]:
    """The marker's observation in the frame whose top row is read at 0.1 s, and its true theta
    at the moment its middle row was read."""
    frame = capture(RENDERER, truth, 100_000_000, effects, np.random.default_rng(seed))
    gray = cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY)
    detections = Detector().detect(gray)
    assert [d.marker_id for d in detections] == [0]
    model = ObservationModel(MarkerSizes(SIZE))
    (observation,) = observe_detections(
        detections, RENDERER.camera, model, mount=RENDERER.mount, t_ns=100_000_000
    )
    row = float(np.mean(detections[0].corners[:, 1]))
    t_ns = 100_000_000 + round(effects.rolling_shutter_s * 1e9 * row / RENDERER.camera.height)
    T_camera = truth.at(t_ns).compose(RENDERER.mount.T_base_camera)
    local = T_WORLD_MARKER.transformTo(T_camera.translation())
    return observation, math.atan2(local[1], local[0])


def theta_error(observation: Observation, true_theta: float, lean: float = 0.0) -> float:
    return abs(math.degrees(math.remainder(observation.theta - lean - true_theta, math.tau)))


@pytest.mark.parametrize("view_deg", [-20.0, -5.0, 0.0, 5.0, 20.0])
def test_a_leaned_marker_reads_true_once_the_lean_is_taken_off(view_deg: float) -> None:
    """In a 0.6 rad/s turn a 25 ms readout leans a marker 1.4 m ahead; read as perspective the
    lean moves theta by degrees near face-on. Its theta_per_turn times the turn during the
    readout takes that off, to within half the corners' own noise (sigma 1.1-1.4 deg)."""
    observation, true_theta = seen(turning_at(view_deg), SensorEffects(rolling_shutter_s=READOUT))
    lean = observation.theta_per_turn * RATE * READOUT
    assert theta_error(observation, true_theta, lean) < 0.6
    if abs(view_deg) <= 5.0:
        assert theta_error(observation, true_theta) > 2.0  # the lean matters here


def test_a_still_marker_has_the_same_theta_per_turn_as_a_leaned_one() -> None:
    """theta_per_turn is a property of the view, not of the lean: a global shutter's frame of the
    same view gives it within a tenth."""
    still, _ = seen(turning_at(0.0), SensorEffects())
    leaned, _ = seen(turning_at(0.0), SensorEffects(rolling_shutter_s=READOUT))
    assert abs(still.theta_per_turn) > 1.0
    assert leaned.theta_per_turn == pytest.approx(still.theta_per_turn, rel=0.1)


@pytest.mark.parametrize("view_deg", [-30.0, 0.0, 30.0])
@pytest.mark.parametrize(("distance_m", "smear_px"), [(1.4, 9.0), (2.5, 6.0)])
def test_edges_are_found_across_a_smear(
    view_deg: float, distance_m: float, smear_px: float
) -> None:
    """An exposure in a turn smears the image sideways: 9 px (15 ms at 1 rad/s) is over half a
    module of a marker 1.4 m away, 6 px three quarters of one at 2.5 m. The sides' edges, found
    across the whole smear, keep theta within a degree of the truth, where a fixed 2 px window
    left it 0.9-2.8 deg off at 20-40 deg."""
    truth = turning_at(view_deg, distance_m)
    exposure_s = smear_px / (RATE * RENDERER.camera.fx)
    sharp, true_theta = seen(truth, SensorEffects())
    smeared, _ = seen(truth, SensorEffects(exposure_s=exposure_s))
    assert theta_error(sharp, true_theta) < 1.0
    assert theta_error(smeared, true_theta) < 1.0


def test_unleaned_takes_the_lean_off_or_widens_theta_by_it() -> None:
    """Exact algebra: a known readout moves theta by theta_per_turn * omega * readout; an unknown
    one keeps theta and adds (theta_per_turn * omega * bound)^2 / 3 to its variance."""
    t_ns = np.arange(0, 2_000_000_000, 10_000_000)
    poses = np.column_stack([np.zeros(len(t_ns)), np.zeros(len(t_ns)), 0.5 * t_ns * 1e-9])
    odometry = Trajectory(t_ns, poses)
    o = Observation(1_000_000_000, 3, 0.1, 0.05, 2.0, 0.01, 0.02, 0.03, theta_per_turn=-4.0)
    (known,) = unleaned([o], odometry, 0.025)
    assert known.theta == pytest.approx(0.05 + 4.0 * 0.5 * 0.025, abs=1e-9)
    assert known.sigma_theta == o.sigma_theta and known.theta_per_turn == 0.0
    (unknown,) = unleaned([o], odometry, 0.033, known=False)
    assert unknown.theta == o.theta
    assert unknown.sigma_theta == pytest.approx(math.sqrt(0.02**2 + (4.0 * 0.5 * 0.033) ** 2 / 3))
