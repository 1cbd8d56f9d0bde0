"""The paper's closed forms against exact SE(2) algebra in random convex rooms."""

from __future__ import annotations

import math

import gtsam
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from markergraph.datasets.rooms import observe_marker, random_convex_room, turn_toward
from markergraph.estimator import (
    Edge,
    Form,
    Goal,
    PolarPose,
    angle_diff,
    compose,
    edge_from_observation,
    edge_from_pose2,
    edge_to_pose2,
    heading,
    odometry,
    wrap,
)

EXACT_ALGEBRA_RAD = 1e-12  # one Pose2 composition in float64
ANGLE_TOL_RAD = 1e-6  # arccos near +-1 loses ~1e-7 rad; the bar for SIGNED vs EXACT
DISTANCE_TOL_M = 1e-9
# arccos's ~1e-8 rad loss near +-1 in one alpha step becomes ~1e-8 m after a few more goals.
CHAINED_DISTANCE_TOL_M = {Form.SIGNED: 1e-6, Form.EXACT: 1e-9}
MIN_SEPARATION_M = 0.2  # closer markers make the triangles degenerate

seeds = st.integers(min_value=0, max_value=2**32 - 1)
exact_forms = pytest.mark.parametrize("form", [Form.SIGNED, Form.EXACT])


def edge_error(e1: Edge, e2: Edge) -> tuple[float, float]:
    """Largest wrapped angle difference [rad] and distance difference [m] between two edges."""
    angles = [
        abs(angle_diff(e1.phi, e2.phi)),
        abs(angle_diff(e1.theta_ab, e2.theta_ab)),
        abs(angle_diff(e1.theta_ba, e2.theta_ba)),
    ]
    return max(angles), abs(e1.d - e2.d)


def assert_edges_close(actual: Edge, expected: Edge, angle_tol: float = ANGLE_TOL_RAD) -> None:
    angle_err, dist_err = edge_error(actual, expected)
    assert angle_err < angle_tol and dist_err < DISTANCE_TOL_M, (actual, expected)


def true_edge(T_room_a: gtsam.Pose2, T_room_b: gtsam.Pose2) -> Edge:
    return edge_from_pose2(T_room_a.between(T_room_b))


def separated(*poses: gtsam.Pose2) -> bool:
    points = [p.translation() for p in poses]
    return all(
        np.linalg.norm(p - q) > MIN_SEPARATION_M for i, p in enumerate(points) for q in points[:i]
    )


def room_scene(seed: int) -> tuple[gtsam.Pose2, gtsam.Pose2, gtsam.Pose2, np.ndarray] | None:
    """Three markers a, b, c on the walls of a random convex room and a robot position inside."""
    rng = np.random.default_rng(seed)
    room = random_convex_room(rng, n_walls=int(rng.integers(3, 9)), n_markers=3)
    a, b, c = room.T_room_markers
    if not separated(a, b, c):
        return None
    return a, b, c, room.random_point(rng)


def observation_inputs(
    a: gtsam.Pose2, b: gtsam.Pose2, p_robot: np.ndarray
) -> tuple[float, float, float, float, float]:
    """The robot's (d_a, theta_a, theta_delta, d_delta, theta_b) as it would measure them."""
    obs_a, obs_b = observe_marker(a, p_robot), observe_marker(b, p_robot)
    facing_away_from_a = a.theta() + obs_a.theta
    theta_delta = turn_toward(facing_away_from_a, p_robot, b.translation())
    return obs_a.d, obs_a.theta, theta_delta, obs_b.d, obs_b.theta


# --- angles and the edge record -------------------------------------------------------------


@given(st.floats(min_value=-1e4, max_value=1e4, allow_nan=False))
def test_wrap_lands_in_half_open_interval(angle: float) -> None:
    """wrap() returns a value in (-pi, pi] that differs from its input by a multiple of 2 pi."""
    wrapped = wrap(angle)
    assert -math.pi < wrapped <= math.pi
    turns = (angle - wrapped) / (2 * math.pi)
    assert abs(turns - round(turns)) < 1e-9


def test_wrap_maps_both_ends_to_plus_pi() -> None:
    """Both +pi and -pi wrap to +pi, and a hair below -pi does not become -pi."""
    assert wrap(math.pi) == math.pi
    assert wrap(-math.pi) == math.pi
    assert wrap(-math.pi - 1e-17) == math.pi
    assert wrap(3 * math.pi) == math.pi


@given(st.floats(-10, 10), st.floats(-10, 10), st.floats(-math.pi, math.pi, exclude_min=True))
def test_edge_pose_round_trip_satisfies_constraint(x: float, y: float, yaw: float) -> None:
    """edge_from_pose2 gives an edge obeying phi = pi - (theta_ab + theta_ba) that maps back."""
    T_a_b = gtsam.Pose2(x, y, yaw)
    edge = edge_from_pose2(T_a_b)
    assert abs(edge.constraint_error()) < EXACT_ALGEBRA_RAD
    assert edge_to_pose2(edge).equals(T_a_b, 1e-12)


@given(st.floats(0.1, 10), st.floats(-math.pi, math.pi), st.floats(-math.pi, math.pi))
def test_edge_inverse_is_the_edge_of_the_inverse_pose(d: float, bearing: float, yaw: float) -> None:
    """Edge.inverse() is E_ba, the edge of T_a_b^-1."""
    T_a_b = gtsam.Pose2(d * math.cos(bearing), d * math.sin(bearing), yaw)
    assert_edges_close(edge_from_pose2(T_a_b).inverse(), edge_from_pose2(T_a_b.inverse()), 1e-12)


def test_edge_of_two_facing_markers() -> None:
    """Markers squarely facing each other across a 4 m room: phi = pi, both thetas 0."""
    edge = true_edge(gtsam.Pose2(0, 0, 0), gtsam.Pose2(4, 0, math.pi))
    assert edge == Edge(phi=math.pi, theta_ab=0.0, theta_ba=0.0, d=4.0)


# --- SIGNED and EXACT are exact everywhere --------------------------------------------------


@exact_forms
@settings(max_examples=300, deadline=None)
@given(seed=seeds)
def test_edge_from_observation_is_exact_in_random_rooms(form: Form, seed: int) -> None:
    """E_ab from odometry plus a centred observation equals the true relative pose of a and b."""
    scene = room_scene(seed)
    if scene is None:
        return
    a, b, _, p_robot = scene
    edge = edge_from_observation(*observation_inputs(a, b, p_robot), form=form)
    assert_edges_close(edge, true_edge(a, b))
    assert abs(edge.constraint_error()) < ANGLE_TOL_RAD


@exact_forms
@settings(max_examples=300, deadline=None)
@given(seed=seeds)
def test_compose_is_exact_in_random_rooms(form: Form, seed: int) -> None:
    """M(E_ab, E_bc) equals the true E_ac."""
    scene = room_scene(seed)
    if scene is None:
        return
    a, b, c, _ = scene
    e_ac = compose(true_edge(a, b), true_edge(b, c), form)
    assert_edges_close(e_ac, true_edge(a, c))
    assert abs(e_ac.constraint_error()) < ANGLE_TOL_RAD


@exact_forms
@settings(max_examples=300, deadline=None)
@given(seed=seeds)
def test_heading_is_exact_in_random_rooms(form: Form, seed: int) -> None:
    """The target heading is the true distance to c and the true turn from facing a to facing c."""
    scene = room_scene(seed)
    if scene is None:
        return
    a, _, c, p_robot = scene
    obs_a = observe_marker(a, p_robot)
    d_heading, turn = heading(true_edge(a, c), obs_a.d, obs_a.theta, form)
    facing_a = a.theta() + obs_a.theta + math.pi
    assert abs(d_heading - np.linalg.norm(c.translation() - p_robot)) < DISTANCE_TOL_M
    assert abs(angle_diff(turn, turn_toward(facing_a, p_robot, c.translation()))) < ANGLE_TOL_RAD


def drive(goals: list[Goal]) -> tuple[float, float, float]:
    """Dead-reckon rotate-translate goals from the origin by plain trigonometry: (x, y, yaw)."""
    x = y = yaw = 0.0
    for goal in goals:
        yaw += goal.theta
        x, y = x + goal.d * math.cos(yaw), y + goal.d * math.sin(yaw)
    return x, y, wrap(yaw)


goal_chains = st.lists(
    st.builds(Goal, d=st.floats(0.05, 5.0), theta=st.floats(-math.pi, math.pi)),
    min_size=1,
    max_size=8,
)


@exact_forms
@settings(max_examples=300, deadline=None)
@given(goals=goal_chains)
def test_odometry_chain_matches_dead_reckoning(form: Form, goals: list[Goal]) -> None:
    """Chaining alpha over goals from the origin lands where plain trigonometry does."""
    state = PolarPose(0.0, 0.0)
    for goal in goals:
        state = odometry(state, goal, form)
    x, y, yaw = drive(goals)
    assert abs(state.d - math.hypot(x, y)) < CHAINED_DISTANCE_TOL_M[form]
    if state.d > 1e-6:
        assert abs(angle_diff(state.theta, math.atan2(y, x))) < ANGLE_TOL_RAD
        assert abs(angle_diff(state.heading, yaw)) < ANGLE_TOL_RAD


def test_odometry_needs_the_heading_offset() -> None:
    """Dropping the third state (as the printed alpha does) breaks a chain of two goals."""
    goals = [Goal(2.0, 0.3), Goal(1.0, 0.5), Goal(1.5, -1.0)]
    with_offset = without_offset = PolarPose(0.0, 0.0)
    for goal in goals:
        with_offset = odometry(with_offset, goal, Form.SIGNED)
        without_offset = odometry(
            PolarPose(without_offset.d, without_offset.theta), goal, Form.SIGNED
        )
    x, y, _ = drive(goals)
    assert abs(with_offset.d - math.hypot(x, y)) < 1e-12
    assert abs(without_offset.d - math.hypot(x, y)) > 0.1


def test_collinear_markers_lose_precision_only_in_closed_form() -> None:
    """a, b, c on one wall: arccos at +-1 costs SIGNED up to ~1e-7 rad; EXACT stays at 1e-12."""
    a, b, c = (gtsam.Pose2(x, 0.0, math.pi / 2) for x in (0.0, 1.3, 3.7))
    truth = true_edge(a, c)
    assert_edges_close(compose(true_edge(a, b), true_edge(b, c), Form.EXACT), truth, 1e-12)
    assert_edges_close(compose(true_edge(a, b), true_edge(b, c), Form.SIGNED), truth)


# --- PAPER holds where the paper's figures put things -------------------------------------


@settings(max_examples=200, deadline=None)
@given(seed=seeds)
def test_paper_edge_holds_for_a_ccw_turn_onto_bs_normal(seed: int) -> None:
    """Printed E_ab is exact when the robot stands on b's normal (theta_b = 0) and turns CCW."""
    rng = np.random.default_rng(seed)
    a = gtsam.Pose2(0.0, 0.0, 0.0)
    p_robot = rng.uniform(0.3, 3.0) * np.array([math.cos(t := rng.uniform(-1.2, 1.2)), math.sin(t)])
    theta_delta = rng.uniform(0.1, math.pi - 0.1)
    toward_b = t + theta_delta
    d_delta = rng.uniform(0.3, 3.0)
    p_b = p_robot + d_delta * np.array([math.cos(toward_b), math.sin(toward_b)])
    b = gtsam.Pose2(p_b[0], p_b[1], toward_b + math.pi)  # b faces the robot: theta_b = 0
    if not separated(a, b):
        return
    inputs = observation_inputs(a, b, p_robot)
    assert abs(inputs[2] - theta_delta) < 1e-9 and abs(inputs[4]) < 1e-9
    assert_edges_close(edge_from_observation(*inputs, form=Form.PAPER), true_edge(a, b))


def rectangle_walls(rng: np.random.Generator, level: bool) -> tuple[gtsam.Pose2, ...]:
    """Markers a, b, c on the left, top and right walls of a rectangle (clockwise, the figure)."""
    width, height = rng.uniform(3.0, 8.0, 2)
    y_a = rng.uniform(0.3, height - 0.3)
    y_c = y_a if level else rng.uniform(0.3, height - 0.3)
    return (
        gtsam.Pose2(0.0, y_a, 0.0),
        gtsam.Pose2(rng.uniform(0.3, width - 0.3), height, -math.pi / 2),
        gtsam.Pose2(width, y_c, math.pi),
    )


@settings(max_examples=200, deadline=None)
@given(seed=seeds)
def test_paper_compose_holds_on_three_consecutive_walls_except_theta_ca(seed: int) -> None:
    """Printed M gets phi_ac, d_ac and theta_ac right on three consecutive walls of a rectangle."""
    a, b, c = rectangle_walls(np.random.default_rng(seed), level=False)
    printed, truth = compose(true_edge(a, b), true_edge(b, c), Form.PAPER), true_edge(a, c)
    assert abs(angle_diff(printed.phi, truth.phi)) < ANGLE_TOL_RAD
    assert abs(angle_diff(printed.theta_ab, truth.theta_ab)) < ANGLE_TOL_RAD
    assert abs(printed.d - truth.d) < DISTANCE_TOL_M
    # The printed theta_ca = pi - phi_ac + theta_ac is off by 2 theta_ac.
    assert abs(angle_diff(printed.theta_ba, truth.theta_ba + 2 * truth.theta_ab)) < ANGLE_TOL_RAD


@settings(max_examples=100, deadline=None)
@given(seed=seeds)
def test_paper_compose_holds_whole_when_a_and_c_face_each_other(seed: int) -> None:
    """With a and c level on opposite walls (theta_ac = 0) the printed M is exact in full."""
    a, b, c = rectangle_walls(np.random.default_rng(seed), level=True)
    assert_edges_close(compose(true_edge(a, b), true_edge(b, c), Form.PAPER), true_edge(a, c))


@settings(max_examples=200, deadline=None)
@given(seed=seeds)
def test_paper_heading_holds_when_c_is_counter_clockwise_of_a(seed: int) -> None:
    """The printed heading is exact whenever the turn from a to c is counter-clockwise."""
    scene = room_scene(seed)
    if scene is None:
        return
    a, _, c, p_robot = scene
    obs_a = observe_marker(a, p_robot)
    e_ac = true_edge(a, c)
    printed = heading(e_ac, obs_a.d, obs_a.theta, Form.PAPER)
    exact = heading(e_ac, obs_a.d, obs_a.theta, Form.EXACT)
    assert abs(printed[0] - exact[0]) < DISTANCE_TOL_M
    if exact[1] >= 0.0:
        assert abs(angle_diff(printed[1], exact[1])) < ANGLE_TOL_RAD
    else:
        assert abs(angle_diff(printed[1], -exact[1])) < ANGLE_TOL_RAD  # right size, wrong side


@given(d_first=st.floats(0.1, 5.0), goal=st.builds(Goal, st.floats(0.05, 5), st.floats(0, math.pi)))
def test_paper_odometry_holds_after_a_straight_first_goal(d_first: float, goal: Goal) -> None:
    """Printed alpha is exact for a first goal straight ahead and a counter-clockwise second."""
    first = odometry(PolarPose(0.0, 0.0), Goal(d_first, 0.0), Form.PAPER)
    printed = odometry(first, goal, Form.PAPER)
    exact = odometry(first, goal, Form.EXACT)
    assert abs(printed.d - exact.d) < DISTANCE_TOL_M
    assume(exact.d > 1e-6)  # back at the origin the polar angle is undefined
    assert abs(angle_diff(printed.theta, exact.theta)) < ANGLE_TOL_RAD


# --- where PAPER is wrong, pinned down with the measured rate -------------------------------

N_ROOMS = 2000
# Share of random rooms (seeded, N_ROOMS, 3-8 walls) where the printed form differs from EXACT,
# measured with this file's own sampler; the band allows the seed-to-seed spread (+-3 points).
# The printed theta_ba (sensor theta_b enters with the wrong sign) and theta_ca (sign slip) are
# wrong in every room; the unsigned arccos alone picks the wrong side about half the time.
MEASURED_FAILURE_RATE = {
    "edge": 1.0,
    "edge_theta_ab": 0.50,
    "compose": 1.0,
    "compose_theta_ac": 0.50,
    "heading": 0.50,
}


def paper_failure_rates(n_rooms: int, seed: int = 2026) -> dict[str, float]:
    failures = {name: 0 for name in MEASURED_FAILURE_RATE}
    counted = 0
    for room_seed in np.random.default_rng(seed).integers(0, 2**32, n_rooms):
        scene = room_scene(int(room_seed))
        if scene is None:
            continue
        counted += 1
        a, b, c, p_robot = scene
        inputs = observation_inputs(a, b, p_robot)
        printed_edge = edge_from_observation(*inputs, form=Form.PAPER)
        failures["edge"] += max(edge_error(printed_edge, true_edge(a, b))) > ANGLE_TOL_RAD
        failures["edge_theta_ab"] += (
            abs(angle_diff(printed_edge.theta_ab, true_edge(a, b).theta_ab)) > ANGLE_TOL_RAD
        )
        printed_m = compose(true_edge(a, b), true_edge(b, c), Form.PAPER)
        failures["compose"] += max(edge_error(printed_m, true_edge(a, c))) > ANGLE_TOL_RAD
        failures["compose_theta_ac"] += (
            abs(angle_diff(printed_m.theta_ab, true_edge(a, c).theta_ab)) > ANGLE_TOL_RAD
        )
        obs_a = observe_marker(a, p_robot)
        printed_h = heading(true_edge(a, c), obs_a.d, obs_a.theta, Form.PAPER)
        exact_h = heading(true_edge(a, c), obs_a.d, obs_a.theta, Form.EXACT)
        failures["heading"] += abs(angle_diff(printed_h[1], exact_h[1])) > ANGLE_TOL_RAD
    return {name: count / counted for name, count in failures.items()}


def test_paper_failure_rates_in_random_rooms() -> None:
    """How often each printed formula is wrong in random convex rooms, as documented."""
    rates = paper_failure_rates(N_ROOMS)
    for name, expected in MEASURED_FAILURE_RATE.items():
        assert abs(rates[name] - expected) < 0.03, (name, rates[name])


@pytest.mark.xfail(reason="printed E_ab is wrong in every random room (theta_b sign, arccos)")
@settings(max_examples=50, deadline=None)
@given(seed=seeds)
def test_paper_edge_in_random_rooms(seed: int) -> None:
    """Expected failure: the printed E_ab equals the truth in a random room."""
    scene = room_scene(seed)
    if scene is None:
        return
    a, b, _, p_robot = scene
    assert_edges_close(
        edge_from_observation(*observation_inputs(a, b, p_robot), form=Form.PAPER), true_edge(a, b)
    )


@pytest.mark.xfail(reason="printed M is wrong in every random room (theta_ca sign slip)")
@settings(max_examples=50, deadline=None)
@given(seed=seeds)
def test_paper_compose_in_random_rooms(seed: int) -> None:
    """Expected failure: the printed M equals the truth in a random room."""
    scene = room_scene(seed)
    if scene is None:
        return
    a, b, c, _ = scene
    assert_edges_close(compose(true_edge(a, b), true_edge(b, c), Form.PAPER), true_edge(a, c))


@pytest.mark.xfail(reason="printed heading turns the wrong way in ~50% of random rooms")
@settings(max_examples=50, deadline=None)
@given(seed=seeds)
def test_paper_heading_in_random_rooms(seed: int) -> None:
    """Expected failure: the printed heading's turn equals the true one in a random room."""
    scene = room_scene(seed)
    if scene is None:
        return
    a, _, c, p_robot = scene
    obs_a = observe_marker(a, p_robot)
    printed = heading(true_edge(a, c), obs_a.d, obs_a.theta, Form.PAPER)
    exact = heading(true_edge(a, c), obs_a.d, obs_a.theta, Form.EXACT)
    assert abs(angle_diff(printed[1], exact[1])) < ANGLE_TOL_RAD


def test_paper_theta_ca_breaks_the_edge_constraint() -> None:
    """The printed theta_ca = pi - phi_ac + theta_ac violates phi = pi - (theta_ac + theta_ca)."""
    a, b, c = gtsam.Pose2(0, 1, 0), gtsam.Pose2(2, 4, -math.pi / 2), gtsam.Pose2(5, 3, math.pi)
    printed = compose(true_edge(a, b), true_edge(b, c), Form.PAPER)
    signed = compose(true_edge(a, b), true_edge(b, c), Form.SIGNED)
    assert abs(signed.constraint_error()) < ANGLE_TOL_RAD
    assert abs(angle_diff(printed.constraint_error(), 2 * printed.theta_ab)) < ANGLE_TOL_RAD
    assert abs(printed.constraint_error()) > 0.1


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan])
def test_non_positive_distances_are_rejected(bad: float) -> None:
    """A zero, negative or NaN distance raises ValueError naming the argument."""
    with pytest.raises(ValueError, match="d_a"):
        edge_from_observation(bad, 0.0, 0.5, 1.0, 0.0, Form.SIGNED)
    with pytest.raises(ValueError, match="d_ra"):
        heading(Edge(math.pi, 0.0, 0.0, 2.0), bad, 0.0, Form.EXACT)
