"""What every method returns: the :class:`Estimate` (markers, trajectory, residuals, notes).

Apart from types.py, because it holds a :class:`~markergraph.estimator.trajectory.Trajectory`,
which is built on types.py's odometry records."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.common.notes import Note
from markergraph.estimator.trajectory import Trajectory
from markergraph.estimator.types import (
    FactorResidual,
    MarkerEstimate,
    MarkerLink,
    Method,
    Placement,
)

__all__ = ["Estimate"]


@dataclass
class Estimate:
    """What every method returns.

    Attributes:
        method: the method that made it.
        home_id: the marker whose frame is the map frame.
        markers: marker id -> its estimate.
        trajectory: the estimated robot base poses in the map frame.
        residuals: per-factor whitened errors (empty for methods without factors).
        links: which markers are linked and by how many measurements.
        unplaced: marker id -> why it could not be placed.
        placements: marker id -> how the closed form reached it (empty for other methods).
        timings_s: stage name -> seconds.
        converged: False when an optimiser stopped without converging (the estimate is its last).
        trajectory_covariance: (N, 3, 3) robot pose covariances where the method keeps them
            (EKF), for NEES against ground truth.
        innovations: (M, 3) innovation (bearing, theta, range) of each update (EKF only).
        nis: (M,) normalised innovation squared of each observation update (EKF only).
        notes: diagnostics a person should read: what was skipped, what is disconnected
            (records: code and tests match their ``kind``, never their text).
        graph, values: the factor graph the GTSAM methods solved and its solution (None for
            the closed form and the EKF); robot poses in it are the camera's.
        pose_graph: makes the same solution as a plain pose graph of base poses and markers
            (``GraphBuilder.pose_graph``: g2o's form), or None.
        observations_unlinked: the marker graph's observations that end no link because
            their theta was not measured (:func:`~markergraph.estimator.links.linkable`); None
            for the other methods.
    """

    method: Method
    home_id: int
    markers: dict[int, MarkerEstimate]
    trajectory: Trajectory
    residuals: list[FactorResidual] = field(default_factory=list)
    links: list[MarkerLink] = field(default_factory=list)
    unplaced: dict[int, str] = field(default_factory=dict)
    placements: dict[int, Placement] = field(default_factory=dict)
    timings_s: dict[str, float] = field(default_factory=dict)
    converged: bool = True
    trajectory_covariance: NDArray[np.float64] | None = None
    innovations: NDArray[np.float64] = field(default_factory=lambda: np.empty((0, 3)))
    nis: NDArray[np.float64] = field(default_factory=lambda: np.empty(0))
    notes: list[Note] = field(default_factory=list)
    graph: gtsam.NonlinearFactorGraph | None = None
    values: gtsam.Values | None = None
    pose_graph: Callable[[], tuple[gtsam.NonlinearFactorGraph, gtsam.Values]] | None = None
    observations_unlinked: int | None = None
