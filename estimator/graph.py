"""Factor construction in one place: keys, noise models, robust kernels, residual read-out."""

from __future__ import annotations

from enum import Enum
from typing import Any

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X
from numpy.typing import NDArray

from markergraph.estimator.models import observation_covariance, observation_pose
from markergraph.estimator.types import FactorResidual, Observation

__all__ = [
    "HOME_PRIOR_NOISE",
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
