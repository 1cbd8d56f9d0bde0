"""Factor construction in one place: keys, noise models, robust kernels, the graph builder every
GTSAM method uses, and the residual read-out.

Robot poses ``X(k)`` are the camera's poses ``T_map_camera`` (the mount is fixed, so the base's
pose follows: :func:`base_pose`). An observation then is an exact function of two variables:
the marker's bearing and range from the camera, and the camera's bearing from the marker (the
paper's theta), each with its own sigma. A relative-pose factor on the same numbers would
linearise the observation once, at the measurement: its covariance is a straight ellipse where
the truth is polar, and SE(2)'s logarithm leaks a long range error into the marker's yaw and
sideways position. On the independent generator's corridor that form left SLAM 2.3-3.8 cm off
on ideal logs with marker yaws 5.6-6.8 deg off; the polar factors: 1.0-2.6 cm and 0.3-1.1 deg.
"""

from __future__ import annotations

from functools import cache
from typing import Any

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X
from numpy.typing import NDArray

from markergraph.estimator.frames import Frames
from markergraph.estimator.models import observation_covariance, observation_pose
from markergraph.estimator.types import FactorResidual, Observation, Robust

__all__ = [
    "HOME_PRIOR_NOISE",
    "FactorMemo",
    "GraphBuilder",
    "Robust",
    "base_covariance",
    "base_pose",
    "gaussian",
    "key_name",
    "observation_factors",
    "observation_measurement",
    "read_residuals",
]

# Fixes the home marker at the map origin. The data say nothing about the map frame, so the
# optimum keeps home exactly at the origin whatever the width; 1e-4 keeps the system well
# conditioned (1e-6 made full solves jitter by ~1e-6) and adds only 1e-8 m^2 to marginals.
HOME_PRIOR_NOISE = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-4, 1e-4, 1e-4]))


# A factor counts as an outlier the kernel caught when its weight falls below this: a whitened
# error beyond 5.4 for Huber, 4.1 for Cauchy, which Gaussian noise in 3 dof almost never reaches.
DOWNWEIGHTED_BELOW = 0.25


# 95% efficiency constants on whitened errors.
_KERNEL_WIDTH = {Robust.HUBER: 1.345, Robust.CAUCHY: 2.3849}


@cache
def _kernel(robust: Robust) -> gtsam.noiseModel.mEstimator.Base:
    """The robust kernel, made once: it holds only its width, and factors share it."""
    return (
        gtsam.noiseModel.mEstimator.Huber
        if robust is Robust.HUBER
        else gtsam.noiseModel.mEstimator.Cauchy
    ).Create(_KERNEL_WIDTH[robust])


def _with_kernel(model: gtsam.noiseModel.Base, robust: Robust) -> gtsam.noiseModel.Base:
    if robust is Robust.NONE:
        return model
    return gtsam.noiseModel.Robust.Create(_kernel(robust), model)


def gaussian(
    covariance: NDArray[np.float64], robust: Robust = Robust.NONE
) -> gtsam.noiseModel.Base:
    """A full-covariance Gaussian noise model, under a robust kernel if asked."""
    return _with_kernel(gtsam.noiseModel.Gaussian.Covariance(covariance), robust)


def observation_measurement(
    obs: Observation, T_base_camera: gtsam.Pose2
) -> tuple[gtsam.Pose2, NDArray[np.float64]]:
    """``T_base_marker`` of an observation and its covariance (tangent space at the marker):
    the observation linearised at the measurement, for the closed forms, the marker graph's
    links and exports."""
    # Composing on the left with a fixed mount leaves a right-perturbed covariance unchanged.
    return T_base_camera.compose(observation_pose(obs)), observation_covariance(obs)


# Bearings this far off at the start are still within a bearing factor's basin (sin and cos
# near linear); beyond, the exact graph starts from its pose-graph form's solution.
WARM_START_BEARING_RAD = 0.3

# The second factor of an observation, read back as one residual with the first.
_SAME_OBSERVATION = "observation, theta"


def observation_factors(
    k: int, obs: Observation, robust: Robust = Robust.NONE
) -> list[tuple[gtsam.NoiseModelFactor, str]]:
    """An observation from camera pose ``X(k)`` of marker ``L(id)`` as two exact factors, each
    with its kind: the marker's bearing and range from the camera, and the camera's bearing
    in the marker's frame (theta)."""
    bearing_range = gtsam.BearingRangeFactorPose2(
        X(k), L(obs.marker_id), gtsam.Rot2(obs.bearing), obs.range_m,
        _with_kernel(
            gtsam.noiseModel.Diagonal.Sigmas(np.array([obs.sigma_bearing, obs.sigma_range])),
            robust,
        ),
    )  # fmt: skip
    theta = gtsam.BearingFactorPose2(
        L(obs.marker_id), X(k), gtsam.Rot2(obs.theta),
        _with_kernel(gtsam.noiseModel.Isotropic.Sigma(1, obs.sigma_theta), robust),
    )  # fmt: skip
    return [(bearing_range, "observation"), (theta, _SAME_OBSERVATION)]


def base_pose(T_map_camera: gtsam.Pose2, T_base_camera: gtsam.Pose2) -> gtsam.Pose2:
    """The robot base's pose from a solved camera pose ``X(k)``."""
    return T_map_camera.compose(T_base_camera.inverse())


def base_covariance(
    camera_covariance: NDArray[np.float64], T_base_camera: gtsam.Pose2
) -> NDArray[np.float64]:
    """The base's pose covariance from the camera's (both in their own tangent spaces)."""
    ad = T_base_camera.AdjointMap()
    return ad @ camera_covariance @ ad.T


FactorMemo = dict[tuple[Any, ...], list[tuple[gtsam.NoiseModelFactor, str]]]
"""An observation's factors by camera pose, kernel and measurement: a search solves the same
frames under many delays or scales, where only the odometry's factors change (GTSAM's factors
are immutable, so graphs share them)."""


class GraphBuilder:
    """A factor graph and its initial values, grown frame by frame (batch SLAM, iSAM2) or link
    by link (the marker graph): the one place factors are made.

    ``graph``, ``values`` and ``kinds`` hold everything added; :meth:`take_new` hands out what
    was added since its last call (iSAM2's increments). ``T_base_camera`` is the mount of the
    frames added next (sessions may differ). ``memo``: observation factors made by earlier
    builders of the same frames, reused and added to.
    """

    def __init__(
        self,
        T_base_camera: gtsam.Pose2,
        robust: Robust = Robust.NONE,
        memo: FactorMemo | None = None,
    ) -> None:
        self.T_base_camera, self.robust, self._memo = T_base_camera, robust, memo
        # The mount last used, its inverse and the inverse's adjoint: the same for every frame.
        self._mount: tuple[gtsam.Pose2, gtsam.Pose2, NDArray[np.float64]] | None = None
        self.graph, self.values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        self.kinds: list[str] = []
        # Each camera pose's mount, and what the pose-graph form needs (pose_graph).
        self.mounts: dict[int, gtsam.Pose2] = {}
        self._steps: list[tuple[int, int, gtsam.Pose2, NDArray[np.float64]]] = []
        self._sightings: list[tuple[int, Observation]] = []
        self._links: list[tuple[int, int, gtsam.Pose2, NDArray[np.float64]]] = []
        self._priors: list[gtsam.NonlinearFactor] = []
        # Where take_new's last increment ended: batch use pays nothing for iSAM2's increments.
        self._taken_factors, self._new_keys = 0, list[int]()

    def _add(self, factor: gtsam.NonlinearFactor, kind: str) -> None:
        self.graph.add(factor)
        self.kinds.append(kind)

    def _initial(self, key: int, pose: gtsam.Pose2) -> None:
        self.values.insert(key, pose)
        self._new_keys.append(key)

    def add_home_prior(self, home_id: int) -> None:
        """Fix the home marker at the map origin."""
        self._add_prior(gtsam.PriorFactorPose2(L(home_id), gtsam.Pose2(), HOME_PRIOR_NOISE))

    def _add_prior(self, prior: gtsam.NonlinearFactor) -> None:
        self._priors.append(prior)
        self._add(prior, "prior")

    def add_marker_prior(
        self, marker_id: int, T_map_marker: gtsam.Pose2, covariance: NDArray[np.float64]
    ) -> None:
        """A marker of a saved map, where the map puts it and as sure as the map is."""
        self._add_prior(gtsam.PriorFactorPose2(L(marker_id), T_map_marker, gaussian(covariance)))
        if not self.values.exists(L(marker_id)):
            self._initial(L(marker_id), T_map_marker)

    def add_frame(self, frames: Frames, k: int, T_map_odom: gtsam.Pose2, offset: int = 0) -> None:
        """Camera pose ``X(offset + k)`` (initially odometry carried into the map by
        ``T_map_odom``), the odometry factor from the frame before carried into the camera's
        frame (within ``frames`` only: a session's chain never joins another's), and the
        factors of each observation; a marker seen for the first time starts where this
        observation puts it."""
        frame, mount = frames.frames[k], self.T_base_camera
        key = X(offset + k)
        T_map_camera = T_map_odom.compose(frame.T_odom_base).compose(mount)
        self._initial(key, T_map_camera)
        self.mounts[key] = mount
        if k > 0:
            step = frames.frames[k - 1].T_odom_base.between(frame.T_odom_base)
            self._steps.append((key - 1, key, step, frame.odometry_covariance))
            if self._mount is None or self._mount[0] is not mount:
                inverse = mount.inverse()
                self._mount = mount, inverse, inverse.AdjointMap()
            _, inverse, to_camera = self._mount
            self._add(
                gtsam.BetweenFactorPose2(
                    key - 1, key, inverse.compose(step).compose(mount),
                    gaussian(to_camera @ frame.odometry_covariance @ to_camera.T),
                ),
                "odometry",
            )  # fmt: skip
        for obs in frame.observations:
            for factor, kind in self._observation_factors(offset + k, obs):
                self._add(factor, kind)
            self._sightings.append((key, obs))
            if not self.values.exists(L(obs.marker_id)):
                self._initial(L(obs.marker_id), T_map_camera.compose(observation_pose(obs)))

    def start_markers_at_medoids(self) -> None:
        """Each marker's initial pose moved to its medoid sighting: the one whose position is
        nearest the median of every sighting's. A marker starts where its first sighting puts
        it, and a first sighting of another marker whose id was misread starts it tens of
        metres off, where Levenberg-Marquardt stays (a simulated corridor loop: cost 14x the
        right minimum's)."""
        sightings: dict[int, list[gtsam.Pose2]] = {}
        for key, obs in self._sightings:
            T_map_camera = self.values.atPose2(key)
            sightings.setdefault(obs.marker_id, []).append(
                T_map_camera.compose(observation_pose(obs))
            )
        for marker_id, poses in sightings.items():
            xy = np.array([p.translation() for p in poses])
            medoid = int(np.argmin(np.linalg.norm(xy - np.median(xy, axis=0), axis=1)))
            self.values.update(L(marker_id), poses[medoid])

    def _observation_factors(
        self, k: int, obs: Observation
    ) -> list[tuple[gtsam.NoiseModelFactor, str]]:
        """:func:`observation_factors`, from the memo where an earlier builder made them."""
        if self._memo is None:
            return observation_factors(k, obs, self.robust)
        measured = (k, self.robust, obs.marker_id, obs.bearing, obs.range_m, obs.theta,
                    obs.sigma_bearing, obs.sigma_range, obs.sigma_theta)  # fmt: skip
        made = self._memo.get(measured)
        if made is None:
            made = self._memo[measured] = observation_factors(k, obs, self.robust)
        return made

    def add_link(
        self, marker_a: int, marker_b: int, T_a_b: gtsam.Pose2, covariance: NDArray[np.float64]
    ) -> None:
        """A measured marker-to-marker relative pose (the paper's E_ab) between ``L(a)`` and
        ``L(b)``, under the robust kernel."""
        self._links.append((L(marker_a), L(marker_b), T_a_b, covariance))
        self._add(
            gtsam.BetweenFactorPose2(
                L(marker_a), L(marker_b), T_a_b, gaussian(covariance, self.robust)
            ),
            "edge",
        )

    def set_initial(self, marker_id: int, T_map_marker: gtsam.Pose2) -> None:
        """A marker's initial pose, where no frame gives it (the marker graph)."""
        self._initial(L(marker_id), T_map_marker)

    def take_new(self) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
        """The factors and initial values added since the last call."""
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        for index in range(self._taken_factors, self.graph.size()):
            graph.add(self.graph.at(index))
        for key in self._new_keys:
            values.insert(key, self.values.atPose2(key))
        self._taken_factors, self._new_keys = self.graph.size(), []
        return graph, values

    def base_poses(self, solution: gtsam.Values, keys: list[int]) -> NDArray[np.float64]:
        """(N, 3) poses (x, y, yaw) of the robot's base at camera poses ``keys``."""
        poses = [base_pose(solution.atPose2(key), self.mounts[key]) for key in keys]
        return np.array([[p.x(), p.y(), p.theta()] for p in poses]).reshape(-1, 3)

    def pose_graph(
        self, solution: gtsam.Values, solving: bool = False
    ) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
        """The solved graph as a plain pose graph (g2o's form): the robot's base poses and the
        markers at ``solution``, joined by relative-pose factors of the odometry, of each
        observation (linearised at the measurement: :func:`observation_measurement`) and of
        each link. ``solving``: with the priors and Cauchy's kernel too (:meth:`warm_start`)."""
        robust = Robust.CAUCHY if solving else Robust.NONE
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        keys = solution.keys()  # a gtsam KeyVector, not a dict's keys
        for key in keys:
            pose = solution.atPose2(key)
            values.insert(key, base_pose(pose, self.mounts[key]) if key in self.mounts else pose)
        for prior in self._priors if solving else []:
            graph.add(prior)
        for a, b, T_a_b, covariance in self._steps:
            graph.add(gtsam.BetweenFactorPose2(a, b, T_a_b, gaussian(covariance)))
        for a, b, T_a_b, covariance in self._links:
            graph.add(gtsam.BetweenFactorPose2(a, b, T_a_b, gaussian(covariance, robust)))
        for key, obs in self._sightings:
            T_base_marker, covariance = observation_measurement(obs, self.mounts[key])
            graph.add(
                gtsam.BetweenFactorPose2(
                    key, L(obs.marker_id), T_base_marker, gaussian(covariance, robust)
                )
            )
        return graph, values

    def warm_start(self, params: gtsam.LevenbergMarquardtParams) -> gtsam.Values:
        """Initial values for the exact graph: where any observation's bearing starts more than
        :data:`WARM_START_BEARING_RAD` off, the solution of its pose-graph form from the
        builder's initial values; else those values. Bearing factors have a narrower basin
        than relative poses: from raw odometry with 4x the usual wheel error, one simulated
        corridor loop in three fell into a minimum 2.5 m off; solved from here, none did.

        The start is solved under Cauchy's kernel whatever the map's: a sighting far from the
        rest of its marker's (an id misread) then pulls on it hardly at all. Under Huber's
        three misread sightings of 162 dragged a simulated marker's start 3 m, into a minimum
        where the map placed it on the marker they stood on."""
        # Every factor here is a NoiseModelFactor; the stubs type graph.at() as its base class.
        factors: list[Any] = [
            self.graph.at(i) for i, kind in enumerate(self.kinds) if kind == "observation"
        ]
        worst = max((abs(f.unwhitenedError(self.values)[0]) for f in factors), default=0.0)
        if worst <= WARM_START_BEARING_RAD:
            return self.values
        graph, values = self.pose_graph(self.values, solving=True)
        solved = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
        start = gtsam.Values()
        keys = solved.keys()  # a gtsam KeyVector, not a dict's keys
        for key in keys:
            pose = solved.atPose2(key)
            start.insert(key, pose.compose(self.mounts[key]) if key in self.mounts else pose)
        return start


def key_name(key: int) -> str:
    """``x12`` for X(12), ``m3`` for L(3)."""
    symbol = gtsam.Symbol(key)
    return f"{'x' if chr(symbol.chr()) == 'x' else 'm'}{symbol.index()}"


def read_residuals(
    graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, kinds: list[str]
) -> list[FactorResidual]:
    """Each factor's whitened error at ``values``, and whether a robust kernel down-weighted it.

    Args:
        kinds: one label per factor of ``graph``, in order.
    """
    residuals: list[FactorResidual] = []
    for index, kind in zip(range(graph.size()), kinds, strict=True):
        # Every factor here is a NoiseModelFactor; the stubs type graph.at() as its base class.
        factor: Any = graph.at(index)
        error = factor.unwhitenedError(values)
        model = factor.noiseModel()
        downweighted = False
        if isinstance(model, gtsam.noiseModel.Robust):
            whitened = float(np.linalg.norm(model.noise().whiten(error)))
            kernel: Any = model.robust()
            downweighted = kernel.weight(whitened) < DOWNWEIGHTED_BELOW
        else:
            whitened = float(np.linalg.norm(model.whiten(error)))
        if kind == _SAME_OBSERVATION:  # theta joins its observation's bearing and range
            first = residuals[-1]
            residuals[-1] = FactorResidual(
                first.kind, first.keys, float(np.hypot(first.whitened_error, whitened)),
                first.downweighted or downweighted,
            )  # fmt: skip
            continue
        keys = tuple(map(key_name, factor.keys()))
        residuals.append(FactorResidual(kind, keys, whitened, downweighted))
    return residuals
