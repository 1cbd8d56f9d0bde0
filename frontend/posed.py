"""Observations from a marker's full pose: PnP on its corners, turned into the robot's level frame.

For cameras that are tilted, on a tilting body (a hand-held rig, visual-inertial odometry), or
several on one rig. The marker's pose in the optical frame comes from ``solvePnP`` (IPPE for
squares) on the undistorted corners; the camera's pose in the *level frame* (at the body's
origin, z up, x along the robot's heading) carries it into the plane. Observations are then
made by a virtual camera at the body origin looking along the heading, so the estimators take
them with the identity mount whatever camera saw them:

- bearing and range: the marker centre's direction and horizontal distance from the body origin;
- theta: from the marker's normal (its z axis, out of the marker), turned into the plane;
- sigmas: the corners' noise carried through PnP's least-squares fit (correlations dropped),
  and widened to cover IPPE's second solution when the two are alike;
- markers whose normal is more than 45 degrees from horizontal (ceiling, floor) are not on a
  wall: those detections are dropped, each with the elevation its normal read;
- a marker is printed on one side only, so the camera that saw it is in front of it: corners
  wound the other way round (a detector listing them clockwise where the reader expected
  counter-clockwise) give a pose facing away from the camera, every yaw 180 degrees off; such
  corners are read in reverse, and counted.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from enum import Enum

import cv2
import numpy as np
from numpy.typing import NDArray

from markergraph.common.notes import Note
from markergraph.estimator.types import Observation
from markergraph.frontend.camera import Camera, CameraMount
from markergraph.frontend.detect import Detection
from markergraph.frontend.observe import (
    GRAZING_RAD,
    GRAZING_SIGMA_RAD,
    THETA_FLOOR_RAD,
    Flags,
    ObservationModel,
    corner_flags,
    second_fits_alike,
    theta_shared_sigma,
)
from markergraph.frontend.tf import rot_z
from markergraph.frontend.yaw import pnp_projection_jacobian, pnp_solutions

__all__ = [
    "LEVEL_TOLERANCE_RAD",
    "MAX_ATTITUDE_GAP_NS",
    "WALL_TILT_RAD",
    "DropReason",
    "Dropped",
    "LevelledCamera",
    "LevelledFrame",
    "MarkerDetections",
    "drop_notes",
    "levelled_view",
    "observe_levelled_frame",
    "tally_detections",
]

WALL_TILT_RAD = math.radians(45.0)
# Below this tilt of the base (and roll of the camera) a frame is observed as level: the
# height-and-pitch model is exact to well under a millimetre at the ranges markers are seen.
LEVEL_TOLERANCE_RAD = math.radians(0.5)
MAX_ATTITUDE_GAP_NS = 100_000_000  # the odometry attitude nearest a frame levels it within this
UNDISTORT_STEP_PX = 0.05  # the undistortion's central differences [px]
POSE_STEP = 1e-6  # (bearing, theta, range)'s central differences in (rvec [rad], t [m])


@dataclass(frozen=True)
class LevelledCamera:
    """A camera's intrinsics and its pose in the level frame at one instant.

    Attributes:
        camera: intrinsics and distortion.
        R_level_optical: (3, 3) rotation of the optical frame (x right, y down, z forward) in the
            level frame (x along the heading, y left, z up).
        t_level_optical: (3,) the optical centre in the level frame [m], from the body origin.
    """

    camera: Camera
    R_level_optical: NDArray[np.float64]
    t_level_optical: NDArray[np.float64]


class DropReason(Enum):
    """Why one detection gave no observation."""

    NO_POSE = "PnP found no pose"
    OFF_WALL = "its normal is more than 45 deg from horizontal"


@dataclass(frozen=True, slots=True)
class Dropped:
    """One detection that gave no observation.

    Attributes:
        marker_id: the detected marker.
        reason: why.
        elevation_rad: its normal's angle above the horizontal plane [rad] (OFF_WALL), else NaN.
    """

    marker_id: int
    reason: DropReason
    elevation_rad: float = math.nan


@dataclass(frozen=True, slots=True)
class LevelledFrame:
    """What one frame's detections gave.

    Attributes:
        observations: one per detection kept.
        dropped: one per detection dropped.
        rewound: ids of the detections whose corners were read in reverse (their winding as
            listed made the marker face away from the camera).
    """

    observations: list[Observation]
    dropped: list[Dropped]
    rewound: list[int]


def _solutions(
    corners_px: NDArray[np.float64], view: LevelledCamera, side_m: float
) -> list[tuple[float, NDArray[np.float64], NDArray[np.float64]]]:
    """IPPE's solutions (reprojection error [px], R_optical_marker, t_optical_marker), best
    first."""
    return pnp_solutions(view.camera.undistort(corners_px), view.camera, side_m)


def _faces_camera(
    R_optical_marker: NDArray[np.float64], t_optical_marker: NDArray[np.float64]
) -> bool:
    """Whether the marker's front (its z axis, out of the print) points toward the camera."""
    return float(R_optical_marker[:, 2] @ t_optical_marker) < 0.0


def _wound_solutions(
    corners_px: NDArray[np.float64], view: LevelledCamera, side_m: float
) -> tuple[NDArray[np.float64], list[tuple[float, NDArray[np.float64], NDArray[np.float64]]], bool]:
    """(corners in the winding that faces the camera, IPPE's solutions for them, whether they
    were reversed). Reversing the list mirrors the square, which turns its normal round and
    only rotates it in its own plane otherwise."""
    solutions = _solutions(corners_px, view, side_m)
    if not solutions or _faces_camera(solutions[0][1], solutions[0][2]):
        return corners_px, solutions, False
    reversed_px = corners_px[::-1].copy()
    return reversed_px, _solutions(reversed_px, view, side_m), True


def _polar(
    R_optical_marker: NDArray[np.float64],
    t_optical_marker: NDArray[np.float64],
    view: LevelledCamera,
) -> tuple[float, float, float, float, float]:
    """(bearing, theta, range, normal's elevation, height) of a marker pose, seen from the
    body origin along the heading."""
    p = view.R_level_optical @ t_optical_marker + view.t_level_optical
    n = view.R_level_optical @ R_optical_marker[:, 2]
    bearing = math.atan2(p[1], p[0])
    yaw = math.atan2(n[1], n[0])
    theta = math.remainder(bearing + math.pi - yaw, math.tau)
    elevation = math.asin(max(-1.0, min(1.0, n[2])))
    return bearing, theta, math.hypot(p[0], p[1]), elevation, float(p[2])


def levelled_view(
    camera: Camera, mount: CameraMount, R_world_base: NDArray[np.float64]
) -> LevelledCamera | None:
    """The camera in the level frame of a tilted base (its attitude ``R_world_base``), placed
    so that observations from it compose with the mount's 2-D pose as a level camera's do; None
    when the base and camera are level within :data:`LEVEL_TOLERANCE_RAD`."""
    x_axis = R_world_base[:, 0]
    R_level_base = rot_z(-math.atan2(x_axis[1], x_axis[0])) @ R_world_base  # 2-D odometry's yaw
    tilt = math.acos(max(-1.0, min(1.0, float(R_level_base[2, 2]))))
    if tilt < LEVEL_TOLERANCE_RAD and abs(mount.roll_rad) < LEVEL_TOLERANCE_RAD:
        return None
    # The estimators compose an observation with the mount's 2-D pose (x, y, yaw) on the base.
    R_camera_level = rot_z(-mount.yaw_rad)
    offset = R_level_base @ mount.t_base_optical - np.array([mount.x_m, mount.y_m, 0.0])
    return LevelledCamera(
        camera, R_camera_level @ R_level_base @ mount.R_base_optical, R_camera_level @ offset
    )


def _jacobian(
    corners_px: NDArray[np.float64],
    view: LevelledCamera,
    side_m: float,
    R_optical_marker: NDArray[np.float64],
    t_optical_marker: NDArray[np.float64],
) -> NDArray[np.float64]:
    """d(bearing, theta, range)/d(corner pixels), (3, 8), at the pose PnP found, through its
    least-squares fit (:func:`~markergraph.frontend.yaw.pnp_projection_jacobian`); the
    undistortion's 2x2 per corner comes before it and (bearing, theta, range)'s change with the
    pose after it, both by central differences. One solve where re-solving IPPE for each
    corner's step took sixteen (a tenth of the time): on 400 random views their sigmas agreed
    to 0.3 % (median; 5 % at the 95th percentile, theta's, where IPPE's two solutions are
    alike), and both matched the spread of IPPE's poses under sampled corner noise
    (``tests/test_levelled_sigmas.py`` checks bearing and range on 40 and 10 views)."""
    camera = view.camera
    rvec, J = pnp_projection_jacobian(R_optical_marker, t_optical_marker, camera, side_m)
    pose_per_corner = np.linalg.solve(J.T @ J, J.T)  # (6, 8): d(rvec, t)/d(undistorted)
    if camera.distortion:  # each corner's undistorted pixel moves with its own pixel alone
        steps = np.repeat(corners_px[None], 4, axis=0)  # +u, -u, +v, -v of every corner
        steps[0, :, 0] += UNDISTORT_STEP_PX
        steps[1, :, 0] -= UNDISTORT_STEP_PX
        steps[2, :, 1] += UNDISTORT_STEP_PX
        steps[3, :, 1] -= UNDISTORT_STEP_PX
        moved = camera.undistort(steps.reshape(-1, 2)).reshape(4, 4, 2)
        d_u, d_v = (moved[0] - moved[1]), (moved[2] - moved[3])  # (4, 2) each
        undistortion = np.zeros((8, 8))
        for i in range(4):
            undistortion[2 * i : 2 * i + 2, 2 * i] = d_u[i] / (2 * UNDISTORT_STEP_PX)
            undistortion[2 * i : 2 * i + 2, 2 * i + 1] = d_v[i] / (2 * UNDISTORT_STEP_PX)
        pose_per_corner = pose_per_corner @ undistortion
    pose = np.concatenate([rvec.ravel(), t_optical_marker])

    def polar(x: NDArray[np.float64]) -> NDArray[np.float64]:
        R, _ = cv2.Rodrigues(x[:3])
        return np.array(_polar(np.asarray(R, dtype=np.float64), x[3:], view)[:3])

    polar_per_pose = np.zeros((3, 6))
    for k in range(6):
        step = np.zeros(6)
        step[k] = POSE_STEP
        change = polar(pose + step) - polar(pose - step)
        change[:2] = [math.remainder(v, math.tau) for v in change[:2]]
        polar_per_pose[:, k] = change / (2.0 * POSE_STEP)
    return np.asarray(polar_per_pose @ pose_per_corner, dtype=np.float64)


def observe_levelled_frame(
    detections: list[Detection], view: LevelledCamera, model: ObservationModel, t_ns: int
) -> LevelledFrame:
    """Observations of detected markers from their full pose, in the level frame, and what was
    dropped or read in reverse (see the module docstring)."""
    observations, dropped, rewound = [], [], []
    camera = view.camera
    for detection in detections:
        side = model.marker_sizes.of(detection.marker_id)
        corners, solutions, reversed_ = _wound_solutions(detection.corners, view, side)
        if not solutions:
            dropped.append(Dropped(detection.marker_id, DropReason.NO_POSE))
            continue
        if reversed_:
            rewound.append(detection.marker_id)
        _, R, t = solutions[0]
        bearing, theta, range_m, elevation, height_m = _polar(R, t, view)
        if abs(elevation) > WALL_TILT_RAD:
            dropped.append(Dropped(detection.marker_id, DropReason.OFF_WALL, elevation))
            continue
        J = _jacobian(corners, view, side, R, t)
        covariance = model.corner_sigma_px**2 * (J @ J.T)
        sigma_bearing, sigma_theta, sigma_range = np.sqrt(np.maximum(np.diag(covariance), 1e-12))
        sigma_theta = math.hypot(sigma_theta, THETA_FLOOR_RAD)
        flags = {Flags.NO_DEPTH}
        if second_fits_alike(solutions, corners, model):
            other = _polar(solutions[1][1], solutions[1][2], view)[1]
            sigma_theta = max(sigma_theta, abs(math.remainder(other - theta, math.tau)) / 2.0)
            flags.add(Flags.AMBIGUOUS)
        if abs(theta) > GRAZING_RAD:
            flags.add(Flags.GRAZING)
            sigma_theta = max(sigma_theta, GRAZING_SIGMA_RAD)
        flags |= corner_flags(corners, camera, model.marker_modules)
        observations.append(
            Observation(
                t_ns=t_ns,
                marker_id=detection.marker_id,
                bearing=float(bearing),
                theta=float(theta),
                range_m=float(range_m),
                sigma_bearing=float(sigma_bearing),
                sigma_theta=float(min(sigma_theta, GRAZING_SIGMA_RAD)),
                sigma_range=float(sigma_range),
                corners=tuple((float(u), float(v)) for u, v in corners),
                flags=frozenset(flags),
                height_m=height_m,
                sigma_theta_shared=theta_shared_sigma(corners, theta, camera, model),
            )
        )
    return LevelledFrame(observations, dropped, rewound)


@dataclass(frozen=True, slots=True)
class MarkerDetections:
    """How one marker's detections fared on their way to observations.

    Attributes:
        marker_id: the marker.
        detections: its detections by cameras with an intrinsics and a mount, with attitude.
        off_wall: of them, dropped because the normal read more than 45 deg from horizontal.
        no_pose: of them, dropped because PnP found no pose.
        rewound: of them, read with their corners reversed (the module docstring says why).
        off_wall_elevation_rad: the median elevation of the normal in the off-wall drops [rad]
            (NaN without any).
    """

    marker_id: int
    detections: int
    off_wall: int
    no_pose: int
    rewound: int
    off_wall_elevation_rad: float

    @property
    def dropped(self) -> int:
        """Detections that gave no observation."""
        return self.off_wall + self.no_pose

    @property
    def left_out(self) -> bool:
        """Whether the marker is out of the 2-D map: every detection of it was dropped."""
        return self.detections > 0 and self.dropped == self.detections


def tally_detections(frames: list[LevelledFrame]) -> dict[int, MarkerDetections]:
    """Each marker's detections, drops and reversed corners over the frames."""
    seen: Counter[int] = Counter()
    no_pose: Counter[int] = Counter()
    rewound: Counter[int] = Counter()
    elevations: dict[int, list[float]] = {}
    for frame in frames:
        seen.update(o.marker_id for o in frame.observations)
        seen.update(d.marker_id for d in frame.dropped)
        rewound.update(frame.rewound)
        for d in frame.dropped:
            if d.reason is DropReason.OFF_WALL:
                elevations.setdefault(d.marker_id, []).append(d.elevation_rad)
            else:
                no_pose[d.marker_id] += 1
    return {
        i: MarkerDetections(
            i,
            seen[i],
            len(elevations.get(i, [])),
            no_pose[i],
            rewound[i],
            float(np.median(elevations[i])) if i in elevations else math.nan,
        )
        for i in sorted(seen)
    }


def drop_notes(counts: dict[int, MarkerDetections]) -> list[Note]:
    """What was dropped of each marker, and whether that leaves it out of the map (kinds
    ``detections.marker_left_out`` and ``detections.dropped``; figure: the detections
    dropped)."""
    notes = []
    for c in counts.values():
        if not c.dropped:
            continue
        elevation = f"{abs(math.degrees(c.off_wall_elevation_rad)):.0f} deg from horizontal"
        if c.left_out and c.off_wall == c.detections:
            every = (
                "its one detection has"
                if c.detections == 1
                else (f"every one of its {c.detections:,} detections has")
            )
            text = (
                f"marker {c.marker_id} left out of the 2-D map: {every} its normal {elevation} "
                "(median; a floor or ceiling tag)"
            )
            notes.append(Note("detections.marker_left_out", text, figure=c.dropped))
            continue
        parts = []
        if c.off_wall:
            parts.append(
                f"{c.off_wall:,} with the normal {elevation}"
                + (" (median)" if c.off_wall > 1 else "")
            )
        if c.no_pose:
            parts.append(f"{c.no_pose:,} with no pose or yaw found")
        if c.left_out:
            text = (
                f"marker {c.marker_id} left out of the 2-D map: every one of its "
                f"{c.detections:,} detections dropped ({', '.join(parts)})"
            )
            notes.append(Note("detections.marker_left_out", text, figure=c.dropped))
        else:
            text = (
                f"{c.dropped:,} of {c.detections:,} detections of marker {c.marker_id} dropped "
                f"({', '.join(parts)}); the marker is mapped from the rest"
            )
            notes.append(Note("detections.dropped", text, figure=c.dropped))
    return notes
