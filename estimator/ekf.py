"""``Method.EKF``: EKF-SLAM on filterpy's ``ExtendedKalmanFilter`` with sparse predict and update.

State: the robot (x, y, yaw) in the map frame, then (x, y, yaw) of every marker seen so far, in
order of first sight. The home marker is the map frame itself, so it is known exactly and not
part of the state. Markers join the state on first sight with their cross-covariances.

filterpy's own ``predict`` and ``update`` are dense: ``F P F^T`` and a Joseph-form update over the
whole state, cubic in its size (tens of milliseconds with 200 markers). An observation touches
only the robot and one marker, and odometry only the robot, so :class:`MarkerEkf` keeps
filterpy's filter object (its ``x``, ``P``, ``y``, ``S``, ``K``, priors and posteriors) and
replaces the two steps with ones that touch just those blocks; ``update(..., dense=True)`` runs
filterpy's own update for comparison.
"""

from __future__ import annotations

import math
import time
from collections import Counter

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.estimator.angles import wrap_array
from markergraph.estimator.estimate import Estimate
from markergraph.estimator.frames import Frames
from markergraph.estimator.graph import observation_measurement
from markergraph.estimator.models import ekf_marker_init, ekf_motion, ekf_observation
from markergraph.estimator.trajectory import Trajectory
from markergraph.estimator.types import (
    FactorResidual,
    MarkerEstimate,
    Method,
    Observation,
)

__all__ = ["MarkerEkf", "solve_ekf"]

# The robot's prior before its first observation of home: effectively unknown.
UNKNOWN_VARIANCE = 100.0

# The iterated update's linearisations: it stops once a step would move the touched entries
# less than LINEARISATION_STEP (m, rad). The models bend by the step's square over the range
# (micrometres after a millimetre), far inside any sigma, so an update that moves the robot
# less than that (most of them, on a robot localised a frame ago) costs one model more, not
# three.
MAX_LINEARISATIONS = 10
LINEARISATION_STEP = 1e-3


def _wrapped_residual(z: NDArray[np.float64], hx: NDArray[np.float64]) -> NDArray[np.float64]:
    """Innovation with the two angles (bearing, theta) wrapped to (-pi, pi]."""
    y = np.asarray(z, dtype=np.float64) - hx
    y[:2] = wrap_array(y[:2])
    return y


class MarkerEkf:
    """EKF-SLAM over a filterpy ``ExtendedKalmanFilter``.

    Args:
        T_base_camera: the camera's horizontal pose on the base.
        home_id: the marker whose frame is the map frame (known, outside the state).
        robot: the robot's initial (x, y, yaw) guess in the map frame.
    """

    def __init__(
        self, T_base_camera: gtsam.Pose2, home_id: int, robot: NDArray[np.float64]
    ) -> None:
        # filterpy pulls in scipy.stats (a second to import): loaded when a filter is built,
        # so processes that never run one (the front end's workers) start fast.
        from filterpy.kalman import ExtendedKalmanFilter

        self.kf = ExtendedKalmanFilter(dim_x=3, dim_z=3)
        self.kf.x = np.asarray(robot, dtype=np.float64).reshape(3, 1)
        self.kf.P = np.eye(3) * UNKNOWN_VARIANCE
        self.T_base_camera, self.home_id = T_base_camera, home_id
        self.index: dict[int, int] = {}  # marker id -> first state row of its block
        self.innovations: list[NDArray[np.float64]] = []
        self.nis: list[float] = []

    @property
    def robot(self) -> NDArray[np.float64]:
        return self.kf.x[:3, 0]

    def marker(self, marker_id: int) -> NDArray[np.float64]:
        """A marker's (x, y, yaw): from the state, or the origin for home."""
        if marker_id == self.home_id:
            return np.zeros(3)
        i = self.index[marker_id]
        return self.kf.x[i : i + 3, 0]

    def predict(self, delta: gtsam.Pose2, covariance: NDArray[np.float64]) -> None:
        """Move the robot by an odometry increment with its covariance (tangent space)."""
        new, F, G = ekf_motion(self.robot, delta)
        # The increment's tangent covariance in plain (dx, dy, dyaw) of the previous frame.
        c, s = math.cos(delta.theta()), math.sin(delta.theta())
        G = G @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        P = self.kf.P
        P[:3, :] = F @ P[:3, :]
        P[:, :3] = P[:, :3] @ F.T
        P[:3, :3] += G @ covariance @ G.T
        self.kf.x[:3, 0] = new
        self.kf.x_prior, self.kf.P_prior = self.kf.x.copy(), P.copy()

    def _add_marker(self, obs: Observation) -> None:
        z = np.array([obs.bearing, obs.theta, obs.range_m])
        R = np.diag([obs.sigma_bearing**2, obs.sigma_theta**2, obs.sigma_range**2])
        marker, G_robot, G_z = ekf_marker_init(self.robot, z, self.T_base_camera)
        n = self.kf.dim_x
        P = self.kf.P
        cross = G_robot @ P[:3, :]  # (3, n): the new marker against the whole state
        grown = np.zeros((n + 3, n + 3))
        grown[:n, :n] = P
        grown[n:, :n] = cross
        grown[:n, n:] = cross.T
        grown[n:, n:] = G_robot @ P[:3, :3] @ G_robot.T + G_z @ R @ G_z.T
        self.kf.x = np.vstack([self.kf.x, marker.reshape(3, 1)])
        self.kf.P = grown
        self.kf.dim_x = n + 3
        self.kf._I = np.eye(n + 3)  # filterpy's dense update needs it the state's size
        self.index[obs.marker_id] = n

    def _model(
        self, x: NDArray[np.float64], marker_id: int, columns: list[int]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Predicted (bearing, theta, range) at ``x`` (the touched entries, robot first) and H
        over those ``columns``."""
        marker = x[3:6] if len(columns) > 3 else np.zeros(3)  # home is the map frame itself
        z, H_robot, H_marker = ekf_observation(x[:3], marker, self.T_base_camera)
        return z, np.hstack([H_robot, H_marker])[:, : len(columns)]

    def _linearised(
        self,
        z: NDArray[np.float64],
        R: NDArray[np.float64],
        marker_id: int,
        columns: list[int],
        at_prior: tuple[NDArray[np.float64], NDArray[np.float64]],
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The iterated EKF's measurement model: H at the posterior of this update, and the
        prediction carried from there back to the prior by H, so that the ordinary update with
        them lands on that posterior (Bell and Cathey's Gauss-Newton view of the IEKF).

        Range and bearing bend with the robot's yaw; after a long stretch of odometry its yaw is
        uncertain by degrees and one linearisation at the prior misplaces the update. On the
        bundled 5 Hz corridor sample that left the map 0.33 m off (SLAM 0.19 m) while the
        filter's covariance still matched SLAM's: 5 of 11 true markers outside its 95 %
        ellipses. Iterated, 0.19 m and 11 of 11. Only the touched entries move the model, and
        their update needs only their block of P, so each iteration costs O(1).

        Args:
            at_prior: the model (prediction, H) at the prior, where the iterations start.
        """
        prior = self.kf.x[columns, 0]
        P_touched = self.kf.P[np.ix_(columns, columns)]
        point, (predicted, H) = prior, at_prior
        for _ in range(MAX_LINEARISATIONS):
            S = H @ P_touched @ H.T + R
            offset = _wrap_yaws(prior - point)
            innovation = _wrapped_residual(z.reshape(3), predicted) - H @ offset
            new_point = prior + P_touched @ H.T @ np.linalg.solve(S, innovation)
            # The update with H at ``point`` lands on ``new_point``: once they agree, done.
            if np.max(np.abs(_wrap_yaws(new_point - point))) < LINEARISATION_STEP:
                break
            point = new_point
            predicted, H = self._model(point, marker_id, columns)
        return predicted + H @ _wrap_yaws(prior - point), H

    def update(self, obs: Observation, dense: bool = False) -> None:
        """Fuse one observation; a marker seen for the first time joins the state instead.

        Args:
            dense: use filterpy's own (dense, Joseph-form) update, for checking.
        """
        if obs.marker_id != self.home_id and obs.marker_id not in self.index:
            self._add_marker(obs)
            return
        z = np.array([[obs.bearing], [obs.theta], [obs.range_m]])
        R = np.diag([obs.sigma_bearing**2, obs.sigma_theta**2, obs.sigma_range**2])
        columns = [0, 1, 2]
        if obs.marker_id != self.home_id:
            i = self.index[obs.marker_id]
            columns += [i, i + 1, i + 2]
        # The innovation against the prior, before any iteration: what NIS is defined on.
        at_prior = self._model(self.kf.x[columns, 0], obs.marker_id, columns)
        predicted, H = at_prior
        y = _wrapped_residual(z.reshape(3), predicted)
        S = H @ self.kf.P[np.ix_(columns, columns)] @ H.T + R
        hx, H = self._linearised(z, R, obs.marker_id, columns, at_prior)
        self._apply_update(z, R, hx, H, columns, dense)
        self.kf.y, self.kf.S = y.reshape(3, 1), S
        self.innovations.append(y.copy())
        self.nis.append(float(y @ np.linalg.solve(S, y)))
        # Every yaw (rows 2, 5, 8, ...) moved with the update; keep them in (-pi, pi].
        self.kf.x[2::3, 0] = wrap_array(self.kf.x[2::3, 0])

    def _apply_update(
        self,
        z: NDArray[np.float64],
        R: NDArray[np.float64],
        hx: NDArray[np.float64],
        H: NDArray[np.float64],
        columns: list[int],
        dense: bool,
    ) -> None:
        """The update at the linearisation ``hx``, ``H`` (over ``columns``): filterpy's
        Joseph form on a small state, a rank-3 downdate of the touched columns on a large one."""
        if dense:
            H_full = np.zeros((3, self.kf.dim_x))
            H_full[:, columns] = H
            self.kf.update(
                z, lambda x: H_full, lambda x: hx.reshape(3, 1), R=R, residual=_wrapped_residual
            )
            return
        P = self.kf.P
        PHt = P[:, columns] @ H.T  # (n, 3): only the touched columns of P take part
        S = H @ PHt[columns, :] + R
        K = np.linalg.solve(S, PHt.T).T  # S is symmetric: K = PHt S^-1
        y = _wrapped_residual(z, hx.reshape(3, 1))
        self.kf.x += K @ y
        # P - K S K^T = P - PHt S^-1 PHt^T: a rank-3 downdate, the optimal-gain form of
        # filterpy's Joseph update; quadratic in the state size instead of cubic.
        P -= K @ PHt.T
        self.kf.K, self.kf.z = K, z
        self.kf.x_post, self.kf.P_post = self.kf.x.copy(), P.copy()


def _wrap_yaws(touched: NDArray[np.float64]) -> NDArray[np.float64]:
    """A difference of touched entries (robot, then maybe a marker) with its yaws wrapped."""
    wrapped = touched.copy()
    wrapped[2::3] = wrap_array(wrapped[2::3])
    return wrapped


def solve_ekf(frames: Frames, T_base_camera: gtsam.Pose2) -> Estimate:
    """``Method.EKF``: predict with odometry between frames, update with each observation.

    The filter starts at the first frame that sees the home marker, with the robot placed by
    that observation and otherwise unknown; the first update then gives it its covariance.
    """
    start = time.perf_counter()
    first = frames.frames[frames.home_frame]
    home = next(o for o in first.observations if o.marker_id == frames.home_id)
    T_base_home, _ = observation_measurement(home, T_base_camera)
    T_map_base = T_base_home.inverse()
    ekf = MarkerEkf(
        T_base_camera,
        frames.home_id,
        np.array([T_map_base.x(), T_map_base.y(), T_map_base.theta()]),
    )
    t_ns, trajectory, covariances = [], [], []
    residuals: list[FactorResidual] = []
    for k in range(frames.home_frame, len(frames.frames)):
        frame = frames.frames[k]
        if k > frames.home_frame:
            previous = frames.frames[k - 1]
            ekf.predict(previous.T_odom_base.between(frame.T_odom_base), frame.odometry_covariance)
        # Home first, so the robot is localised before it places anything.
        for obs in sorted(frame.observations, key=lambda o: o.marker_id != frames.home_id):
            updates = len(ekf.nis)
            ekf.update(obs)
            if len(ekf.nis) > updates and not (k == frames.home_frame and updates == 0):
                # Its innovation's Mahalanobis length: what a factor's whitened error is to SLAM.
                residuals.append(FactorResidual(
                    "observation", (f"x{k}", f"m{obs.marker_id}"), math.sqrt(ekf.nis[-1])
                ))  # fmt: skip
        if k == frames.home_frame:  # the first update only placed the robot: no innovation
            del ekf.innovations[0], ekf.nis[0]
        t_ns.append(frame.t_ns)
        trajectory.append(ekf.robot.copy())
        covariances.append(ekf.kf.P[:3, :3].copy())
    counts = Counter(o.marker_id for f in frames.frames for o in f.observations)
    markers = {
        frames.home_id: MarkerEstimate(
            frames.home_id, gtsam.Pose2(), np.zeros((3, 3)), counts[frames.home_id]
        )
    }
    for marker_id, i in ekf.index.items():
        x, y, yaw = ekf.kf.x[i : i + 3, 0]
        # The EKF's (x, y, yaw) covariance into the marker's tangent space (GTSAM's convention).
        c, s = math.cos(yaw), math.sin(yaw)
        to_local = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
        covariance = to_local @ ekf.kf.P[i : i + 3, i : i + 3] @ to_local.T
        markers[marker_id] = MarkerEstimate(
            marker_id, gtsam.Pose2(x, y, yaw), covariance, counts[marker_id]
        )
    return Estimate(
        method=Method.EKF,
        home_id=frames.home_id,
        markers=markers,
        trajectory=Trajectory(np.array(t_ns, dtype=np.int64), np.array(trajectory)),
        trajectory_covariance=np.array(covariances),
        residuals=residuals,
        nis=np.array(ekf.nis),
        innovations=np.array(ekf.innovations).reshape(-1, 3),
        notes=list(frames.notes),
        timings_s={"filter": time.perf_counter() - start},
    )
