"""Factor construction in one place: keys, noise models, robust kernels, the graph builder every
GTSAM method uses, and the residual read-out."""

from __future__ import annotations

from enum import Enum
from typing import Any

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X
from numpy.typing import NDArray

from markergraph.estimator.frames import Frames
from markergraph.estimator.models import observation_covariance, observation_pose
from markergraph.estimator.types import FactorResidual, Observation

__all__ = [
    "HOME_PRIOR_NOISE",
    "GraphBuilder",
    "Robust",
    "gaussian",
    "key_name",
    "observation_factor",
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


class Robust(Enum):
    """Robust kernel on observation factors."""

    NONE = "none"
    HUBER = "huber"
    CAUCHY = "cauchy"


# 95% efficiency constants on whitened errors.
_KERNEL_WIDTH = {Robust.HUBER: 1.345, Robust.CAUCHY: 2.3849}


def gaussian(
    covariance: NDArray[np.float64], robust: Robust = Robust.NONE
) -> gtsam.noiseModel.Base:
    """A Gaussian noise model of a covariance, optionally wrapped in a robust kernel."""
    model = gtsam.noiseModel.Gaussian.Covariance(covariance)
    if robust is Robust.NONE:
        return model
    kernel = (
        gtsam.noiseModel.mEstimator.Huber
        if robust is Robust.HUBER
        else gtsam.noiseModel.mEstimator.Cauchy
    ).Create(_KERNEL_WIDTH[robust])
    return gtsam.noiseModel.Robust.Create(kernel, model)


def observation_measurement(
    obs: Observation, T_base_camera: gtsam.Pose2
) -> tuple[gtsam.Pose2, NDArray[np.float64]]:
    """``T_base_marker`` of an observation and its covariance (tangent space at the marker)."""
    # Composing on the left with a fixed mount leaves a right-perturbed covariance unchanged.
    return T_base_camera.compose(observation_pose(obs)), observation_covariance(obs)


def observation_factor(
    k: int, obs: Observation, T_base_camera: gtsam.Pose2, robust: Robust = Robust.NONE
) -> gtsam.BetweenFactorPose2:
    """The relative-pose factor from robot pose ``X(k)`` to marker ``L(id)``."""
    T_base_marker, covariance = observation_measurement(obs, T_base_camera)
    return gtsam.BetweenFactorPose2(
        X(k), L(obs.marker_id), T_base_marker, gaussian(covariance, robust)
    )


class GraphBuilder:
    """A factor graph and its initial values, grown frame by frame (batch SLAM, iSAM2) or link
    by link (the marker graph): the one place factors are made.

    ``graph``, ``values`` and ``kinds`` hold everything added; :meth:`take_new` hands out what
    was added since its last call (iSAM2's increments).
    """

    def __init__(self, T_base_camera: gtsam.Pose2, robust: Robust = Robust.NONE) -> None:
        self.T_base_camera, self.robust = T_base_camera, robust
        self.graph, self.values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        self.kinds: list[str] = []
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
        self._add(gtsam.PriorFactorPose2(L(home_id), gtsam.Pose2(), HOME_PRIOR_NOISE), "prior")

    def add_marker_prior(
        self, marker_id: int, T_map_marker: gtsam.Pose2, covariance: NDArray[np.float64]
    ) -> None:
        """A marker of a saved map, where the map puts it and as sure as the map is."""
        self._add(gtsam.PriorFactorPose2(L(marker_id), T_map_marker, gaussian(covariance)), "prior")
        if not self.values.exists(L(marker_id)):
            self._initial(L(marker_id), T_map_marker)

    def add_frame(self, frames: Frames, k: int, T_map_odom: gtsam.Pose2, offset: int = 0) -> None:
        """Robot pose ``X(offset + k)`` (initially odometry carried into the map by
        ``T_map_odom``), the odometry factor from the frame before (within ``frames`` only: a
        session's chain never joins another's), and one factor per observation; a marker seen
        for the first time starts where this observation puts it."""
        frame = frames.frames[k]
        T_map_base = T_map_odom.compose(frame.T_odom_base)
        self._initial(X(offset + k), T_map_base)
        if k > 0:
            delta = frames.frames[k - 1].T_odom_base.between(frame.T_odom_base)
            self._add(
                gtsam.BetweenFactorPose2(
                    X(offset + k - 1), X(offset + k), delta, gaussian(frame.odometry_covariance)
                ),
                "odometry",
            )
        for obs in frame.observations:
            self._add(
                observation_factor(offset + k, obs, self.T_base_camera, self.robust),
                "observation",
            )
            if not self.values.exists(L(obs.marker_id)):
                T_base_marker, _ = observation_measurement(obs, self.T_base_camera)
                self._initial(L(obs.marker_id), T_map_base.compose(T_base_marker))

    def add_link(
        self, marker_a: int, marker_b: int, T_a_b: gtsam.Pose2, covariance: NDArray[np.float64]
    ) -> None:
        """A measured marker-to-marker relative pose (the paper's E_ab) between ``L(a)`` and
        ``L(b)``, under the robust kernel."""
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
    residuals = []
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
        keys = tuple(map(key_name, factor.keys()))
        residuals.append(FactorResidual(kind, keys, whitened, downweighted))
    return residuals
