"""What kind of odometry a topic carries, from its messages rather than its name: wheel
odometry is planar (z, roll and pitch all zero), a visual-inertial estimate moves in 3-D; how
often it publishes, and whether its covariance is set or a placeholder."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from markergraph.frontend.logs.records import DecodeFailures, LogError
from markergraph.frontend.tf import rotation_of

if TYPE_CHECKING:  # settings read this module's choices without opening a log
    from markergraph.frontend.logs import Log

__all__ = ["OdometryEvidence", "OdometryJudge", "choose_odometry_source", "odometry_evidence"]

SAMPLES_JUDGED = 600  # the first samples read (12 s at 50 Hz): enough to see a rig's tilt
# A planar estimate keeps z, roll and pitch at zero; a wheel base's own odometry does so exactly,
# a 3-D estimate of a base on a flat floor still wobbles by more than this.
PLANAR_TILT_RAD = math.radians(0.5)
PLANAR_Z_M = 0.01
T265_RATE_HZ = 150.0  # a RealSense T265 publishes its pose at 200 Hz; VIO at camera rate
# Sources by topic name, the tie-breaker: a RealSense T265's (/camera/odom/sample), then other
# visual-inertial systems (basalt's /vio_node/odom, VINS, OpenVINS, OKVIS, ROVIO, Kimera, ZED).
SOURCE_BY_TOPIC = (
    ("t265", re.compile(r"t265|odom/sample", re.I)),
    ("vio", re.compile(r"vio|vins|basalt|okvis|msckf|rovio|kimera|zed", re.I)),
)


@dataclass(frozen=True)
class OdometryEvidence:
    """What a nav_msgs/Odometry topic's first messages show of its kind.

    Attributes:
        samples: messages judged (the first :data:`SAMPLES_JUDGED`).
        rate_hz: their median rate [Hz].
        z_span_m: the spread of their height [m].
        max_tilt_rad: the largest angle of the body's z axis from the odometry frame's [rad].
        covariance: ``"unset"`` (all zeros), ``"constant"`` (the same in every message: a
            placeholder) or ``"varying"``.
        xy_variance_per_m: with a varying covariance, how its position variance grows with
            the distance travelled [m^2 per m]; None otherwise or where it does not grow.
    """

    samples: int
    rate_hz: float
    z_span_m: float
    max_tilt_rad: float
    covariance: str
    xy_variance_per_m: float | None = None

    @property
    def planar(self) -> bool:
        return self.max_tilt_rad <= PLANAR_TILT_RAD and self.z_span_m <= PLANAR_Z_M


class OdometryJudge:
    """Gathers a topic's first :data:`SAMPLES_JUDGED` nav_msgs/Odometry messages, as a log is
    read in order, for their :class:`OdometryEvidence`."""

    def __init__(self) -> None:
        self.stamps: list[int] = []
        self.z: list[float] = []
        self.tilt: list[float] = []
        self.position: list[tuple[float, float]] = []
        self.variance: list[float] = []
        self.not_odometry = False

    @property
    def wants_more(self) -> bool:
        """Whether the next message of the topic would be judged."""
        return not self.not_odometry and len(self.stamps) < SAMPLES_JUDGED

    def add(self, log_time_ns: int, decoded: object) -> None:
        """One message of the topic (decoded), in log order."""
        pose_with_covariance = getattr(decoded, "pose", None)
        pose = getattr(pose_with_covariance, "pose", None)
        if pose is None:
            self.not_odometry = True  # odometry from /tf, or another type
            return
        R = rotation_of(pose.orientation)
        p = pose.position
        if R is None or not all(math.isfinite(float(v)) for v in (p.x, p.y, p.z)):
            return
        self.stamps.append(log_time_ns)
        self.z.append(float(p.z))
        self.tilt.append(math.acos(max(-1.0, min(1.0, float(R[2, 2])))))
        self.position.append((float(p.x), float(p.y)))
        covariance = np.asarray(
            getattr(pose_with_covariance, "covariance", ()), dtype=np.float64
        ).ravel()
        self.variance.append(covariance[[0, 7]].sum() if covariance.size == 36 else 0.0)

    def evidence(self) -> OdometryEvidence | None:
        """The evidence of the messages gathered; None where they are not nav_msgs/Odometry or
        fewer than two were usable."""
        if self.not_odometry or len(self.stamps) < 2:
            return None
        steps = np.diff(np.array(self.stamps, dtype=np.float64)) * 1e-9
        rate_hz = 1.0 / float(np.median(steps)) if np.median(steps) > 0 else math.inf
        variances = np.array(self.variance)
        if not np.all(np.isfinite(variances)) or not np.any(variances):
            kind, per_m = "unset", None
        elif np.ptp(variances) <= 1e-12 * max(1.0, float(np.max(np.abs(variances)))):
            kind, per_m = "constant", None
        else:
            kind = "varying"
            steps_m = np.hypot(*np.diff(self.position, axis=0).T)
            travelled = np.concatenate([[0.0], np.cumsum(steps_m)])
            per_m = None
            if travelled[-1] > 0.5:  # a slope over half a metre or more
                slope = _slope(travelled, variances / 2.0)
                per_m = slope if slope > 0 else None
        tilt, z_span = float(max(self.tilt)), float(np.ptp(self.z))
        return OdometryEvidence(len(self.stamps), rate_hz, z_span, tilt, kind, per_m)


def _slope(x: NDArray[np.float64], y: NDArray[np.float64]) -> float:
    """The least-squares line's slope through (x, y) (``np.polyfit``'s degree 1, without the
    numpy.ma it imports)."""
    dx = x - x.mean()
    return float(np.dot(dx, y - y.mean()) / np.dot(dx, dx))


def odometry_evidence(log: Log, topic: str) -> OdometryEvidence | None:
    """The evidence of a topic's first :data:`SAMPLES_JUDGED` messages (:class:`OdometryJudge`),
    read on their own; None where they are not nav_msgs/Odometry (odometry from /tf) or fewer
    than two decode."""
    judge = OdometryJudge()
    stream = log.messages([topic], DecodeFailures())
    try:
        for message in stream:
            judge.add(message.log_time_ns, message.decoded)
            if not judge.wants_more:
                break
    except LogError:
        return None
    finally:
        close = getattr(stream, "close", None)  # a generator: its file closed now, not at gc
        if close is not None:
            close()
    return judge.evidence()


def choose_odometry_source(evidence: OdometryEvidence | None, topic: str | None) -> tuple[str, str]:
    """The odometry's noise preset (``wheel``, ``vio``, ``t265``) and what decided it: 3-D
    motion (roll, pitch or height) makes it visual-inertial, and then a T265's rate or name a
    T265; planar motion makes it wheel odometry unless the topic's name says otherwise (a VIO
    may publish its pose flattened); without evidence, the name alone."""
    by_name = next((name for name, p in SOURCE_BY_TOPIC if p.search(topic or "")), None)
    if evidence is None:
        return by_name or "wheel", (
            f"chosen by the name {topic}" if by_name else "no nav_msgs/Odometry to judge"
        )
    seen = (
        f"judged on its first {evidence.samples:,} samples at {evidence.rate_hz:.0f} Hz, with "
        "roll and pitch up to "
        f"{math.degrees(evidence.max_tilt_rad):.1f} deg, z over {evidence.z_span_m:.2f} m, "
        + {
            "unset": "covariance unset",
            "constant": "covariance a constant placeholder",
            "varying": "covariance set"
            + (
                f" (position sigma {100 * math.sqrt(evidence.xy_variance_per_m):.1f} cm per "
                "sqrt(m))"
                if evidence.xy_variance_per_m
                else ""
            ),
        }[evidence.covariance]
    )
    if not evidence.planar:
        fast = evidence.rate_hz >= T265_RATE_HZ
        source = "t265" if by_name == "t265" or fast else "vio"
        why = "3-D motion, so a visual-inertial estimate (wheel odometry is planar)"
        if source == "t265":
            why += "; a T265 " + ("by its rate" if fast else f"by the name {topic}")
        return source, f"{why} ({seen})"
    if by_name is not None:
        return by_name, f"planar like wheel odometry, but chosen by the name {topic} ({seen})"
    return "wheel", f"planar, so wheel odometry ({seen})"
