"""One entry point for every method: observations and odometry in, an :class:`Estimate` out."""

from __future__ import annotations

from collections.abc import Collection, Iterable

import gtsam

from markergraph.estimator.closed_form import solve_closed_form
from markergraph.estimator.ekf import solve_ekf
from markergraph.estimator.estimate import Estimate
from markergraph.estimator.frames import Frames, build_frames
from markergraph.estimator.graph import Robust
from markergraph.estimator.marker_graph import solve_marker_graph
from markergraph.estimator.paper import Form
from markergraph.estimator.slam import solve_isam2, solve_slam
from markergraph.estimator.types import (
    Method,
    Observation,
    OdometryNoise,
    OdometrySample,
)

__all__ = ["estimate", "estimate_frames"]


def estimate_frames(
    frames: Frames,
    method: Method,
    T_base_camera: gtsam.Pose2 | None = None,
    *,
    form: Form = Form.SIGNED,
    robust: Robust = Robust.NONE,
) -> Estimate:
    """Run one method on prepared frames (reuse the frames to compare methods).

    Args:
        form: the closed forms' version for ``Method.CLOSED_FORM``.
        robust: the kernel on observation factors for the GTSAM methods.
    """
    T_base_camera = gtsam.Pose2() if T_base_camera is None else T_base_camera
    if method is Method.CLOSED_FORM:
        return solve_closed_form(frames, T_base_camera, form)
    if method is Method.MARKER_GRAPH:
        return solve_marker_graph(frames, T_base_camera, robust)
    if method is Method.SLAM:
        return solve_slam(frames, T_base_camera, robust)
    if method is Method.ISAM2:
        return solve_isam2(frames, T_base_camera, robust)
    return solve_ekf(frames, T_base_camera)


def estimate(
    observations: Iterable[Observation],
    odometry: Iterable[OdometrySample],
    method: Method,
    *,
    T_base_camera: gtsam.Pose2 | None = None,
    odometry_noise: OdometryNoise = OdometryNoise(),
    home_id: int | None = None,
    marker_ids: Collection[int] | None = None,
    form: Form = Form.SIGNED,
    robust: Robust = Robust.NONE,
) -> Estimate:
    """Map the markers with one method.

    Args:
        observations: marker observations from the front end (or the fast simulator).
        odometry: ``T_odom_base`` samples covering the observations' stamps.
        method: which estimator.
        T_base_camera: the camera's horizontal pose on the base (default: at the base origin).
        odometry_noise: the odometry's noise model.
        home_id: the marker whose frame is the map (default: the first one observed).
        marker_ids: if given, observations of any other id are rejected.
        form, robust: see :func:`estimate_frames`.

    Raises:
        RejectedObservationError: an unusable observation; the message names it.
        MarkerGraphError: nothing to map, no odometry, or the home marker never seen.
    """
    frames = build_frames(observations, odometry, home_id, marker_ids, odometry_noise)
    return estimate_frames(frames, method, T_base_camera, form=form, robust=robust)
