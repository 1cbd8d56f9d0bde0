"""The estimator's records: what goes in (observations, odometry) and the per-marker records that
come out (the :class:`~markergraph.estimator.estimate.Estimate` holding them is in estimate.py)."""

from __future__ import annotations

import math
from array import array
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING, Any, overload

import numpy as np
from numpy.typing import NDArray

from markergraph.common.errors import RejectedObservationError

if TYPE_CHECKING:  # GTSAM loads when a pose is first made: the front end's records need none
    import gtsam

__all__ = [
    "LEANING",
    "ODOMETRY_NOISE",
    "FactorResidual",
    "MarkerEstimate",
    "MarkerLink",
    "Method",
    "Observation",
    "OdometryNoise",
    "OdometrySample",
    "OdometryTrack",
    "Placement",
]


class Robust(Enum):
    """Robust kernel on observation factors."""

    NONE = "none"
    HUBER = "huber"
    CAUCHY = "cauchy"


class Method(Enum):
    """The estimators; each maps observations and odometry to an :class:`Estimate`."""

    CLOSED_FORM = "closed-form"
    """The paper's procedure: localise, dead-reckon, link with E_ab, compose M from home."""
    MARKER_GRAPH = "marker-graph"
    """The paper's node graph optimised: measured E_ab as between factors of marker nodes."""
    SLAM = "slam"
    """Robot poses and markers, odometry and observation factors, batch Levenberg-Marquardt."""
    ISAM2 = "isam2"
    """The SLAM graph solved incrementally, frame by frame."""
    EKF = "ekf"
    """EKF-SLAM on filterpy with a sparse update."""


LEANING = "leaning"
"""The flag of an observation whose theta keeps a rolling shutter's lean, only widened by it
(:func:`~markergraph.estimator.timing.unleaned`): a handover link looks for a calmer sighting
of its marker (:mod:`~markergraph.estimator.links`)."""


@dataclass(frozen=True, slots=True)
class Observation:
    """One marker seen in one camera frame, in the camera's horizontal (top-view) frame.

    Attributes:
        t_ns: capture time [ns].
        marker_id: the marker's id in its dictionary.
        bearing: direction of the marker centre from the optical axis [rad], counter-clockwise
            (left of the image centre is positive).
        theta: the paper's yaw [rad]: the camera's polar angle in the marker's frame.
        range_m: horizontal distance from the camera to the marker centre [m].
        sigma_bearing, sigma_theta, sigma_range: standard deviations of the three [rad, rad, m].
        corners: the detected corners as (u, v) pixel pairs in OpenCV's order (top-left,
            top-right, bottom-right, bottom-left), empty when the observation was not detected.
        flags: quality flags set by the front end (``near-edge``, ``small``, ``tiny``,
            ``grazing``, ``ambiguous``, ``no-depth``), and ``leaning`` where theta keeps a rolling
            shutter's lean (:func:`~markergraph.estimator.timing.unleaned`); the estimators weight
            by the sigmas, not by these, though ``small`` and ``tiny`` sightings may be taken for
            misread ids (:mod:`~markergraph.estimator.misreads`) and a ``leaning`` one ending a
            handover link for a calmer one (:mod:`~markergraph.estimator.links`).
        height_m: the marker centre's height above the base frame's origin (the floor, for a
            base on it) [m]; NaN where unknown. The 2-D estimators ignore it; each marker's
            height in the map is a robust mean of its observations' (:func:`marker_heights`).
        sigma_theta_shared: the part of theta's error that nearby frames' observations of the
            same marker share (the corners' common bias) [rad], apart from ``sigma_theta``:
            averaging them does not reduce it. ``build_frames`` counts it once a view
            (:func:`shared_over_views`); 0 once counted, or where unknown.
        theta_per_turn: theta's change per radian the camera turns (to the left, about its
            vertical axis) while a rolling shutter reads out its rows [rad/rad]: the lean that
            turn gives the marker's image read as perspective. 0 where unknown, and once the
            lean is taken off or theta widened by it (:mod:`~markergraph.estimator.timing`).
    """

    t_ns: int
    marker_id: int
    bearing: float
    theta: float
    range_m: float
    sigma_bearing: float
    sigma_theta: float
    sigma_range: float
    corners: tuple[tuple[float, float], ...] = ()
    flags: frozenset[str] = frozenset()
    height_m: float = math.nan
    sigma_theta_shared: float = 0.0
    theta_per_turn: float = 0.0

    def validate(self) -> None:
        """Raise :class:`RejectedObservationError` naming this record if it is unusable."""
        values = (
            self.bearing,
            self.theta,
            self.range_m,
            self.sigma_bearing,
            self.sigma_theta,
            self.sigma_range,
            self.theta_per_turn,
        )
        if not all(math.isfinite(v) for v in values):
            raise RejectedObservationError(
                f"observation of marker {self.marker_id} at t_ns="
                f"{self.t_ns} has a NaN or infinite value"
            )
        if self.range_m <= 0.0:
            raise RejectedObservationError(
                f"observation of marker {self.marker_id} at t_ns="
                f"{self.t_ns} has range_m={self.range_m} <= 0"
            )
        if min(self.sigma_bearing, self.sigma_theta, self.sigma_range) <= 0.0:
            raise RejectedObservationError(
                f"observation of marker {self.marker_id} at t_ns="
                f"{self.t_ns} has a standard deviation <= 0"
            )
        if not self.sigma_theta_shared >= 0.0 or not math.isfinite(self.sigma_theta_shared):
            raise RejectedObservationError(
                f"observation of marker {self.marker_id} at t_ns="
                f"{self.t_ns} has sigma_theta_shared={self.sigma_theta_shared}"
            )


@dataclass(frozen=True, slots=True)
class OdometrySample:
    """The base's pose in the odometry frame, ``T_odom_base``, at one time.

    Attributes:
        t_ns: time [ns].
        x, y: position in the odometry frame [m].
        yaw: heading in the odometry frame [rad].
    """

    t_ns: int
    x: float
    y: float
    yaw: float

    def pose(self) -> gtsam.Pose2:
        import gtsam

        return gtsam.Pose2(self.x, self.y, self.yaw)


_INT64_MIN, _INT64_MAX = -(2**63), 2**63 - 1


class OdometryTrack(Sequence[OdometrySample]):
    """Odometry samples kept in columns, as a log is read: 32 bytes a sample where a list of
    :class:`OdometrySample` objects takes about 200, so a log's millions of samples do not
    take its reader's memory. It reads as a sequence of samples; :meth:`columns` gives the
    arrays the hot paths want.

    Columns (each ``array.array``, one entry a sample, in the order appended):
        t_ns: int64 stamps [ns]; x, y: float64 position in the odometry frame [m]; yaw:
        float64 heading [rad].
    """

    __slots__ = ("_t_ns", "_x", "_y", "_yaw")

    def __init__(self, samples: Iterable[OdometrySample] = ()) -> None:
        self._t_ns = array("q")
        self._x, self._y, self._yaw = array("d"), array("d"), array("d")
        self.extend(samples)

    @classmethod
    def joined(cls, tracks: Iterable[OdometryTrack]) -> OdometryTrack:
        """The tracks one after another."""
        joined = cls()
        for track in tracks:
            joined._t_ns += track._t_ns
            joined._x += track._x
            joined._y += track._y
            joined._yaw += track._yaw
        return joined

    def append(self, sample: OdometrySample) -> None:
        """One sample at the end. A stamp beyond int64 nanoseconds (after 2262) is kept as a
        sample with NaN values at stamp 0, which cleaning drops as absurd, with a note."""
        if not _INT64_MIN <= sample.t_ns <= _INT64_MAX:
            sample = OdometrySample(0, math.nan, math.nan, math.nan)
        self._t_ns.append(sample.t_ns)
        self._x.append(sample.x)
        self._y.append(sample.y)
        self._yaw.append(sample.yaw)

    def extend(self, samples: Iterable[OdometrySample]) -> None:
        """Samples at the end, in their order."""
        for sample in samples:
            self.append(sample)

    def columns(self) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """(t_ns, poses): (N,) int64 stamps [ns] and (N, 3) float64 rows (x, y, yaw), new
        arrays in the order appended."""
        t_ns = np.array(self._t_ns, dtype=np.int64)
        poses = np.empty((len(self), 3), dtype=np.float64)
        for k, column in enumerate((self._x, self._y, self._yaw)):
            poses[:, k] = np.frombuffer(column, dtype=np.float64)
        return t_ns, poses

    def __len__(self) -> int:
        return len(self._t_ns)

    @overload
    def __getitem__(self, index: int) -> OdometrySample: ...

    @overload
    def __getitem__(self, index: slice) -> OdometryTrack: ...

    def __getitem__(self, index: int | slice) -> OdometrySample | OdometryTrack:
        if isinstance(index, slice):
            part = OdometryTrack()
            part._t_ns, part._x = self._t_ns[index], self._x[index]
            part._y, part._yaw = self._y[index], self._yaw[index]
            return part
        return OdometrySample(self._t_ns[index], self._x[index], self._y[index], self._yaw[index])

    def __iter__(self) -> Iterator[OdometrySample]:
        for t_ns, x, y, yaw in zip(self._t_ns, self._x, self._y, self._yaw, strict=True):
            yield OdometrySample(t_ns, x, y, yaw)

    def __eq__(self, other: object) -> bool:
        """Equal to another track or sequence holding the same samples in the same order."""
        if not isinstance(other, Sequence) or isinstance(other, str | bytes):
            return NotImplemented
        return len(self) == len(other) and all(a == b for a, b in zip(self, other, strict=True))

    __hash__ = None  # type: ignore[assignment]  # it grows: not hashable

    def __repr__(self) -> str:
        return f"OdometryTrack({len(self)} samples)"


@dataclass(frozen=True, slots=True)
class OdometryNoise:
    """Wheel odometry's noise: a random walk in what was travelled between two stamps.

    The covariance of the motion between two stamps, in the frame of the first, is
    ``diag(vxy, vxy, vyaw)`` with ``vxy = floor_m^2 + per_m^2 * dist`` and
    ``vyaw = floor_rad^2 + yaw_per_m^2 * dist + yaw_per_rad^2 * |dyaw|``: variances add up
    over consecutive steps, so the model does not depend on how often odometry is sampled.

    Attributes:
        per_m: position standard deviation after one metre travelled [m per sqrt(m)].
        yaw_per_m: heading standard deviation after one metre travelled [rad per sqrt(m)].
        yaw_per_rad: heading standard deviation after one radian turned [rad per sqrt(rad)].
        floor_m, floor_rad: added to every step so a standstill is never exactly certain.
    """

    per_m: float = 0.012
    yaw_per_m: float = 0.008
    yaw_per_rad: float = 0.012
    floor_m: float = 1e-4
    floor_rad: float = 1e-4

    def variances(self, dist: Any, turn: Any) -> tuple[Any, Any]:
        """``(vxy, vyaw)`` of steps of ``dist`` metres and ``turn`` radians (absolute), as
        floats or elementwise over arrays."""
        var_xy = self.floor_m**2 + self.per_m**2 * dist
        var_yaw = self.floor_rad**2 + self.yaw_per_m**2 * dist + self.yaw_per_rad**2 * turn
        return var_xy, var_yaw

    def covariance(self, delta: gtsam.Pose2) -> NDArray[np.float64]:
        """3x3 covariance over (x, y, yaw) of one relative motion ``delta``."""
        var_xy, var_yaw = self.variances(math.hypot(delta.x(), delta.y()), abs(delta.theta()))
        return np.diag([var_xy, var_xy, var_yaw])


# Odometry noise by source (tests/benchmarks/real_logs.py measures them). Wheel: the
# simulator's wheel errors (no real wheel log is shared here). VIO: basalt's VIO against TagSLAM's
# optimised path on TagSLAM's test 21: mean NEES 2.9-3.0 over 0.5-1 m stretches, where the wheel
# model gives 0.9-1.0. T265: its odometry against TagSLAM's path on test 22, whose own jitter
# (+-20 cm between frames, far from two tags outdoors) is in the figure: an upper bound, and on
# that log the one that maps best (tag yaw 0.3 deg against 12.8 with the VIO model).
ODOMETRY_NOISE: dict[str, OdometryNoise] = {
    "wheel": OdometryNoise(),
    "vio": OdometryNoise(per_m=0.007, yaw_per_m=0.006, yaw_per_rad=0.004),
    "t265": OdometryNoise(per_m=0.1, yaw_per_m=0.04, yaw_per_rad=0.14),
}


@dataclass(frozen=True, slots=True)
class MarkerEstimate:
    """A marker's estimated pose in the map frame (the home marker's frame).

    Attributes:
        marker_id: the marker's id.
        T_map_marker: its pose [m, rad].
        covariance: 3x3 over (x, y, yaw) in the marker's own tangent space, or None where the
            method has none.
        n_observations: how many observations of it were used.
        relative_covariance: the same with the map's common rigid motion removed (its
            uncertainty relative to the map as a whole: :mod:`~markergraph.estimator.gauge`),
            or None.
    """

    marker_id: int
    T_map_marker: gtsam.Pose2
    covariance: NDArray[np.float64] | None
    n_observations: int
    relative_covariance: NDArray[np.float64] | None = None


@dataclass(frozen=True, slots=True)
class MarkerLink:
    """Two markers the method linked, and by how many measurements."""

    marker_a: int
    marker_b: int
    n_measurements: int


@dataclass(frozen=True, slots=True)
class Placement:
    """How the closed form reached a marker: the marker it had last localised on, and how far
    and how long it dead-reckoned from there before this marker's first usable view.

    Attributes:
        marker_id: the marker placed.
        from_marker: the placed marker the robot was localised on (the home marker's own
            placement names itself).
        dead_reckoned_m: odometry path length from that localisation to the placing view [m].
        dead_reckoned_s: time between them [s].
        t_ns: the placing view's stamp [ns].
        sigma_theta_rad: theta's sigma in that view [rad]; above the usual gate when this
            marker had no better view.
        backward: placed running back in time from the first localisation (the marker was seen
            only before the robot first localised).
    """

    marker_id: int
    from_marker: int
    dead_reckoned_m: float
    dead_reckoned_s: float
    t_ns: int
    sigma_theta_rad: float
    backward: bool = False


@dataclass(frozen=True, slots=True)
class FactorResidual:
    """One factor's whitened error after optimisation.

    Attributes:
        kind: ``"odometry"``, ``"observation"``, ``"edge"`` or ``"prior"``.
        keys: the variables it joins, as readable names (``"x12"``, ``"m3"``).
        whitened_error: ``sqrt(2 * error)``, the Mahalanobis length of its residual.
        downweighted: whether a robust kernel gave it a weight below 0.25 (an outlier it caught).
    """

    kind: str
    keys: tuple[str, ...]
    whitened_error: float
    downweighted: bool = False

    @property
    def marker_ids(self) -> list[int]:
        """The markers it joins (from keys ``"m<id>"``)."""
        return [int(k[1:]) for k in self.keys if k.startswith("m")]
