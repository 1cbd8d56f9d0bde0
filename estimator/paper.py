"""The paper's closed forms (odometry alpha, edge E_ab, composition M, heading) in three forms.

Reference: A. Sampathkrishna, "ArUco Maker based localization and Node graph approach to mapping"
(``shared/seed``), sections *Locomotion*, *Mapping* and *Target Heading Calculation*.

Conventions (README.md): top view, z up, angles counter-clockwise positive and wrapped to (-pi, pi].
A marker frame has its origin at the marker centre, +x along the normal into the room and +y the
normal turned 90 degrees counter-clockwise. A *centred observation* (d, theta) of a marker puts the
robot at ``d (cos theta, sin theta)`` in that marker's frame, heading ``theta + pi`` (facing it).

Every function takes a :class:`Form`:

* ``Form.PAPER``: the equations exactly as printed: law-of-cosines terms under ``arccos``, which
  return unsigned angles in [0, pi], and the printed ``theta_ca = pi - phi_ac + theta_ac``. They
  hold only in the layouts the paper's figures draw (each function says which).
* ``Form.SIGNED``: the same closed forms with every ``arccos`` term multiplied by the sign of the
  sine of the angle it stands for, and the printed sign slips corrected. Exact everywhere.
* ``Form.EXACT``: SE(2) composition with ``gtsam.Pose2``; the reference the other two are tested
  against, and free of the ~1e-7 rad loss ``arccos`` suffers when its argument is near +-1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

import gtsam
import numpy as np

from markergraph.estimator.angles import wrap

__all__ = [
    "Edge",
    "Form",
    "Goal",
    "PolarPose",
    "compose",
    "edge_from_observation",
    "edge_from_pose2",
    "edge_to_pose2",
    "heading",
    "odometry",
]


class Form(Enum):
    """Which version of the paper's closed forms to evaluate."""

    PAPER = "paper"
    """The equations as printed (unsigned ``arccos`` terms, printed ``theta_ca``)."""
    SIGNED = "signed"
    """The printed closed forms with their signs resolved: exact."""
    EXACT = "exact"
    """SE(2) composition with ``gtsam.Pose2``: exact, the reference."""


@dataclass(frozen=True, slots=True)
class Edge:
    """The paper's connection ``E_ab = {phi_ab, theta_ab, theta_ba, d_ab}`` from marker a to b.

    Angles use the *mirror* convention, the only one under which the paper's constraint
    ``phi_ab = pi - (theta_ab + theta_ba)`` holds identically; then the pose of b in a's frame is
    ``(d cos theta_ab, d sin theta_ab, -phi_ab)``. An edge has 3 degrees of freedom in 4 numbers;
    :meth:`constraint_error` measures how far an edge is from satisfying the constraint.

    Attributes:
        phi: the paper's "phase difference" [rad]: minus the yaw of b's frame in a's frame.
        theta_ab: direction of b seen from a [rad], counter-clockwise from a's normal (b's polar
            angle in a's frame).
        theta_ba: direction of a seen from b [rad], *clockwise* from b's normal (minus a's polar
            angle in b's frame).
        d: straight-line distance between the marker centres [m], >= 0.
    """

    phi: float
    theta_ab: float
    theta_ba: float
    d: float

    def inverse(self) -> Edge:
        """``E_ba``, the same connection seen from b."""
        return Edge(
            phi=wrap(-self.phi),
            theta_ab=wrap(-self.theta_ba),
            theta_ba=wrap(-self.theta_ab),
            d=self.d,
        )

    def constraint_error(self) -> float:
        """Wrapped violation of ``phi = pi - (theta_ab + theta_ba)`` [rad]; zero for a real edge."""
        return wrap(self.phi - (math.pi - self.theta_ab - self.theta_ba))


@dataclass(frozen=True, slots=True)
class PolarPose:
    """The robot's odometry ``O_i = (d_i, theta_i)`` from the origin, plus the state alpha lacks.

    Attributes:
        d: distance from the origin [m].
        theta: polar angle of the robot's position about the origin [rad].
        heading_offset: robot heading minus ``theta`` [rad]. Zero means the robot faces straight
            away from the origin, which is where a rotate-translate goal from the origin leaves it
            and the only case the printed alpha covers; composing goals needs this third state.
    """

    d: float
    theta: float
    heading_offset: float = 0.0

    @property
    def heading(self) -> float:
        """The robot's heading in the origin's frame [rad]."""
        return wrap(self.theta + self.heading_offset)


@dataclass(frozen=True, slots=True)
class Goal:
    """A rotate-translate goal ``O_delta = (d_delta, theta_delta)`` in the robot's own frame.

    Attributes:
        d: distance to drive straight ahead after turning [m], >= 0.
        theta: turn before driving [rad], counter-clockwise positive.
    """

    d: float
    theta: float


def _angle_between_sides(side_1: float, side_2: float, opposite: float) -> float:
    """Interior angle between two triangle sides from the law of cosines, in [0, pi].

    The cosine is clamped to [-1, 1] because rounding pushes it just outside for collinear points,
    where ``arccos`` would return NaN.
    """
    cosine = (side_1 * side_1 + side_2 * side_2 - opposite * opposite) / (2.0 * side_1 * side_2)
    return math.acos(min(1.0, max(-1.0, cosine)))


def _law_of_cosines(side_1: float, side_2: float, included_angle: float) -> float:
    """The third side of a triangle from two sides and the angle between them."""
    squared = side_1 * side_1 + side_2 * side_2 - 2.0 * side_1 * side_2 * math.cos(included_angle)
    return math.sqrt(max(0.0, squared))


def _sign_of_sine(angle: float) -> float:
    """+1 or -1: the side an ``arccos`` angle lies on. Zero sine maps to +1, where the angle is 0
    or pi and both signs give the same direction."""
    sine = math.sin(angle)
    return math.copysign(1.0, sine) if sine != 0.0 else 1.0


def _require_positive(**values: float) -> None:
    for name, value in values.items():
        if not value > 0.0:  # also rejects NaN
            raise ValueError(f"{name} must be a positive distance in metres, got {value!r}")


def edge_to_pose2(edge: Edge) -> gtsam.Pose2:
    """``T_a_b``: marker b's pose in marker a's frame, from ``d``, ``theta_ab`` and ``phi``."""
    return gtsam.Pose2(
        edge.d * math.cos(edge.theta_ab), edge.d * math.sin(edge.theta_ab), -edge.phi
    )


def edge_from_pose2(T_a_b: gtsam.Pose2) -> Edge:
    """The edge ``E_ab`` of a relative pose ``T_a_b`` (b in a's frame); satisfies the constraint.

    For coincident markers (``d = 0``) the direction is undefined and ``theta_ab`` is set to 0.
    """
    x, y = T_a_b.x(), T_a_b.y()
    d = math.hypot(x, y)
    theta_ab = math.atan2(y, x) if d > 0.0 else 0.0
    phi = wrap(-T_a_b.theta())
    return Edge(phi=phi, theta_ab=wrap(theta_ab), theta_ba=wrap(math.pi - phi - theta_ab), d=d)


def _pose_of_centred_observation(d: float, theta: float) -> gtsam.Pose2:
    """``T_marker_robot`` of a centred observation: robot at polar (d, theta), facing the marker."""
    return gtsam.Pose2(d * math.cos(theta), d * math.sin(theta), theta + math.pi)


def odometry(prev: PolarPose, delta: Goal, form: Form) -> PolarPose:
    """The paper's alpha: ``O_i = alpha(O_{i-1}, O_delta)`` (section *Locomotion*).

    From ``prev`` the robot turns ``delta.theta``, then drives ``delta.d`` straight. As printed::

        d_i     = sqrt(d_{i-1}^2 + d_delta^2 - 2 d_{i-1} d_delta cos(pi - theta_delta))
        theta_i = arccos((d_i^2 + d_{i-1}^2 - d_delta^2) / (2 d_i d_{i-1}))

    The printed ``theta_i`` is the unsigned angle at the origin between ``O_{i-1}`` and ``O_i``, not
    the new polar angle, and the law of cosines assumes the robot faced straight away from the
    origin before turning. So ``Form.PAPER`` holds only for ``theta_{i-1} = 0``, a zero heading
    offset and ``theta_delta`` in [0, pi]; from the origin (``d_{i-1} = 0``) it returns the goal,
    as the paper says. ``Form.SIGNED`` adds ``theta_{i-1}``, signs the ``arccos`` term by
    ``sin(theta_turn)`` and carries the heading offset as a third state
    (``theta_turn = heading_offset + theta_delta``); it is exact. ``Form.EXACT`` composes Pose2s.

    Args:
        prev: odometry before the goal, ``O_{i-1}``.
        delta: the goal ``O_delta`` executed from there.
        form: which version to evaluate.

    Returns:
        ``O_i``. ``Form.PAPER`` always returns a zero heading offset (it has none to track).
    """
    if delta.d < 0.0 or prev.d < 0.0:
        raise ValueError(f"distances must be >= 0, got prev.d={prev.d!r}, delta.d={delta.d!r}")
    if form is Form.EXACT:
        T_origin_robot = (
            gtsam.Pose2(prev.d * math.cos(prev.theta), prev.d * math.sin(prev.theta), prev.heading)
            .compose(gtsam.Pose2(0.0, 0.0, delta.theta))
            .compose(gtsam.Pose2(delta.d, 0.0, 0.0))
        )
        d_i = math.hypot(T_origin_robot.x(), T_origin_robot.y())
        theta_i = math.atan2(T_origin_robot.y(), T_origin_robot.x()) if d_i > 0.0 else prev.theta
        return PolarPose(d_i, wrap(theta_i), wrap(T_origin_robot.theta() - theta_i))
    if form is Form.PAPER:
        if prev.d == 0.0:
            return PolarPose(delta.d, wrap(delta.theta))
        d_i = _law_of_cosines(prev.d, delta.d, math.pi - delta.theta)
        theta_i = _angle_between_sides(d_i, prev.d, delta.d) if d_i > 0.0 else 0.0
        return PolarPose(d_i, theta_i)
    turn = prev.heading_offset + delta.theta  # turn relative to facing straight away from origin
    if prev.d == 0.0:
        return PolarPose(delta.d, wrap(prev.theta + turn))
    d_i = _law_of_cosines(prev.d, delta.d, math.pi - turn)
    if d_i == 0.0:
        return PolarPose(0.0, prev.theta, wrap(turn))
    theta_i = wrap(prev.theta + _sign_of_sine(turn) * _angle_between_sides(d_i, prev.d, delta.d))
    return PolarPose(d_i, theta_i, wrap(prev.theta + turn - theta_i))


def edge_from_observation(
    d_a: float, theta_a: float, theta_delta: float, d_delta: float, theta_b: float, form: Form
) -> Edge:
    """``E_ab`` from the robot's odometry about marker a and a centred observation of b (*Mapping*).

    The robot stands at polar ``(d_a, theta_a)`` in a's frame facing straight away from a (where
    the paper's rotate-translate goal leaves it), turns ``theta_delta`` to face b, and observes b
    centred at ``(d_delta, theta_b)``. As printed::

        d_ab     = sqrt(d_a^2 + d_delta^2 - 2 d_a d_delta cos(pi - theta_delta))
        theta_ab = theta_a + arccos((d_a^2 + d_ab^2 - d_delta^2) / (2 d_a d_ab))
        theta_ba = theta_b + arccos((d_delta^2 + d_ab^2 - d_a^2) / (2 d_delta d_ab))
        phi_ab   = pi - (theta_ab + theta_ba)

    ``Form.PAPER`` evaluates exactly that. Its ``arccos`` terms are unsigned, so ``theta_ab`` holds
    only when b lies counter-clockwise of the robot's heading (``theta_delta`` in [0, pi]); and the
    sensor's ``theta_b`` (counter-clockwise, as the paper's own sign rule for the corner lengths
    gives it) enters ``theta_ba``, which is measured clockwise, with the wrong sign, so
    ``theta_ba`` and ``phi_ab`` hold only for ``theta_b = 0``: the robot on b's normal.
    ``Form.SIGNED`` uses ``theta_ab = theta_a + s * arccos(..)`` and
    ``theta_ba = s * arccos(..) - theta_b`` with ``s = sgn(sin(theta_delta))``: exact.
    ``Form.EXACT`` composes ``T_a_robot * T_b_robot^-1``.

    Args:
        d_a: robot's distance from marker a [m], > 0.
        theta_a: robot's polar angle in a's frame [rad].
        theta_delta: turn from facing straight away from a to facing b [rad], CCW positive.
        d_delta: robot's distance to b [m], > 0.
        theta_b: the centred observation's angle of b [rad] (robot's polar angle in b's frame).
        form: which version to evaluate.

    Returns:
        ``E_ab``.

    Raises:
        ValueError: a distance is not positive, or a and b coincide.
    """
    _require_positive(d_a=d_a, d_delta=d_delta)
    if form is Form.EXACT:
        T_a_robot = gtsam.Pose2(
            d_a * math.cos(theta_a), d_a * math.sin(theta_a), theta_a + theta_delta
        )
        T_b_robot = _pose_of_centred_observation(d_delta, theta_b)
        return edge_from_pose2(T_a_robot.compose(T_b_robot.inverse()))
    d_ab = _law_of_cosines(d_a, d_delta, math.pi - theta_delta)
    if d_ab == 0.0:
        raise ValueError("markers a and b coincide (d_ab = 0): no edge between them")
    angle_at_a = _angle_between_sides(d_a, d_ab, d_delta)
    angle_at_b = _angle_between_sides(d_delta, d_ab, d_a)
    if form is Form.PAPER:
        theta_ab = theta_a + angle_at_a
        theta_ba = theta_b + angle_at_b
    else:
        side = _sign_of_sine(theta_delta)
        theta_ab = theta_a + side * angle_at_a
        theta_ba = side * angle_at_b - theta_b
    return Edge(
        phi=wrap(math.pi - (theta_ab + theta_ba)),
        theta_ab=wrap(theta_ab),
        theta_ba=wrap(theta_ba),
        d=d_ab,
    )


def compose(e_ab: Edge, e_bc: Edge, form: Form) -> Edge:
    """The paper's ``M``: ``E_ac = M(E_ab, E_bc)`` (section *Mapping*). As printed::

        phi_ac   = phi_ab + phi_bc
        d_ac     = sqrt(d_ab^2 + d_bc^2 - 2 d_ab d_bc cos(theta_ba + theta_bc))
        theta_ac = theta_ab - arccos((d_ab^2 + d_ac^2 - d_bc^2) / (2 d_ab d_ac))
        theta_ca = pi - phi_ac + theta_ac

    ``phi_ac`` and ``d_ac`` are exact. The printed ``theta_ac`` holds when c lies clockwise of b
    as seen from a, i.e. ``sin(theta_ba + theta_bc) >= 0`` (true for a, b, c on three consecutive
    walls of a rectangle, the paper's figure). The printed ``theta_ca`` contradicts the edge
    constraint ``phi = pi - (theta_ac + theta_ca)`` unless ``theta_ac`` is 0 or pi (a and c
    squarely facing each other). ``Form.SIGNED`` uses
    ``theta_ac = theta_ab - sgn(sin(theta_ba + theta_bc)) * arccos(..)`` and
    ``theta_ca = pi - phi_ac - theta_ac``: exact. ``Form.EXACT`` composes ``T_a_b * T_b_c``.

    Returns:
        ``E_ac``. When a and c coincide, ``theta_ac`` is 0 and ``theta_ca`` follows from ``phi_ac``.
    """
    if form is Form.EXACT:
        return edge_from_pose2(edge_to_pose2(e_ab).compose(edge_to_pose2(e_bc)))
    phi_ac = wrap(e_ab.phi + e_bc.phi)
    # The angle at b between the rays to a and to c: theta_ba is clockwise and theta_bc
    # counter-clockwise from b's normal, so their sum spans it.
    angle_at_b = e_ab.theta_ba + e_bc.theta_ab
    d_ac = _law_of_cosines(e_ab.d, e_bc.d, angle_at_b)
    angle_at_a = _angle_between_sides(e_ab.d, d_ac, e_bc.d) if d_ac > 0.0 and e_ab.d > 0.0 else 0.0
    if form is Form.PAPER:
        theta_ac = e_ab.theta_ab - angle_at_a
        theta_ca = math.pi - phi_ac + theta_ac
    else:
        theta_ac = e_ab.theta_ab - _sign_of_sine(angle_at_b) * angle_at_a
        theta_ca = math.pi - phi_ac - theta_ac
    return Edge(phi=phi_ac, theta_ab=wrap(theta_ac), theta_ba=wrap(theta_ca), d=d_ac)


def heading(e_ac: Edge, d_ra: float, theta_ra: float, form: Form) -> tuple[float, float]:
    """The paper's target heading ``O_heading`` (section *Target Heading Calculation*). As printed::

        d_heading     = sqrt(d_ac^2 + d_ra^2 - 2 d_ra d_ac cos(theta_ac - theta_ra))
        theta_heading = arccos((d_ra^2 + d_heading^2 - d_ac^2) / (2 d_ra d_heading))

    The robot is localised on marker a at polar ``(d_ra, theta_ra)`` in a's frame, facing a; the
    goal is marker c's centre. ``theta_heading`` is the turn from facing a to facing c,
    counter-clockwise positive. The printed ``arccos`` is unsigned, so ``Form.PAPER`` holds only
    when c lies counter-clockwise of a as the robot sees them (``sin(theta_ac - theta_ra) <= 0``).
    ``Form.SIGNED`` multiplies it by ``-sgn(sin(theta_ac - theta_ra))``: exact. ``Form.EXACT``
    transforms c's position into the robot's frame.

    Args:
        e_ac: the edge from the localising marker a to the target c (from ``compose`` if needed).
        d_ra: robot's distance from a [m], > 0.
        theta_ra: robot's polar angle in a's frame [rad].
        form: which version to evaluate.

    Returns:
        ``(d_heading, theta_heading)``: distance to c [m] and the turn toward it [rad]; the turn
        is 0 when the robot stands on c.
    """
    _require_positive(d_ra=d_ra)
    if form is Form.EXACT:
        T_a_robot = _pose_of_centred_observation(d_ra, theta_ra)
        p_robot_c = T_a_robot.transformTo(edge_to_pose2(e_ac).translation())
        d_heading = float(np.hypot(p_robot_c[0], p_robot_c[1]))
        turn = math.atan2(p_robot_c[1], p_robot_c[0]) if d_heading > 0.0 else 0.0
        return d_heading, wrap(turn)
    d_heading = _law_of_cosines(e_ac.d, d_ra, e_ac.theta_ab - theta_ra)
    if d_heading == 0.0:
        return 0.0, 0.0
    turn = _angle_between_sides(d_ra, d_heading, e_ac.d)
    if form is Form.SIGNED:
        turn *= -_sign_of_sine(e_ac.theta_ab - theta_ra)
    return d_heading, wrap(turn)
