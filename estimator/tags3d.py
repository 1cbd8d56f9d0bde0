"""The 3-D tag map's records: what goes in (each camera's view of a tag's four corners, the
rig's cameras, odometry, surveyed tags) and what comes out (each tag's full pose with its 6x6
covariance, the rig's path, each camera's mount).

Frames: a tag's own frame is the AprilTag / OpenCV ArUco one (x right and y up as printed, z
out of the print toward whoever can see it; corners ``(-s/2, s/2)``, ``(s/2, s/2)``,
``(s/2, -s/2)``, ``(-s/2, -s/2)`` in OpenCV's order). markergraph's marker frame has x along
the normal into the room: ``T_map_marker = T_map_tag * R_TAG_MARKER``. Camera frames are
optical (x right, y down, z forward). Covariances are over GTSAM's Pose3 tangent (rotation,
then translation) in the pose's own frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.common.notes import Note

__all__ = [
    "R_TAG_MARKER",
    "Camera3d",
    "KnownTag",
    "SceneCamera",
    "Tag3d",
    "TagMap3d",
    "TagScene",
    "TagView",
    "quaternion_wxyz",
    "tag_corners",
]

R_TAG_MARKER = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
"""The marker frame's axes in the tag frame: x the normal (the tag's z), y the tag's x, z the
tag's y (up, for a tag printed upright on a wall)."""


def quaternion_wxyz(rotation: gtsam.Rot3) -> tuple[float, float, float, float]:
    """A rotation's unit quaternion (w, x, y, z), w >= 0."""
    q: Any = rotation.toQuaternion()  # gtsam's stubs leave its Quaternion untyped
    wxyz = (float(q.w()), float(q.x()), float(q.y()), float(q.z()))
    return wxyz if wxyz[0] >= 0 else (-wxyz[0], -wxyz[1], -wxyz[2], -wxyz[3])


def tag_corners(size_m: float) -> NDArray[np.float64]:
    """A tag's four corners (4, 3) in its own frame, in OpenCV's order."""
    h = size_m / 2.0
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


@dataclass(frozen=True, slots=True)
class TagView:
    """One tag's four corners seen by one camera in one rig frame.

    Attributes:
        frame: the rig frame's index in :attr:`TagScene.frame_times`.
        camera: the camera's index in :attr:`TagScene.cameras`.
        tag_id: the tag's id.
        rays: (4, 2) the corners as undistorted normalised image coordinates (x/z, y/z in the
            optical frame), in OpenCV's order.
        sigma: (8,) each ray coordinate's standard deviation (the pixel noise through the lens
            at that corner: a fisheye's rim stretches a pixel over a wider angle).
        ray_per_px: (8,) how far each ray coordinate moves for a pixel there (to state
            reprojection errors in pixels).
        T_camera_tag: the tag's pose in the camera from its corners alone (the PnP solution
            that fits them best), a seed for the solver.
        T_camera_tag_alt: the other solution of a square's PnP (the tag tilted the other way,
            nearly as good for a small or far tag), where there is one.
    """

    frame: int
    camera: int
    tag_id: int
    rays: NDArray[np.float64]
    sigma: NDArray[np.float64]
    ray_per_px: NDArray[np.float64]
    T_camera_tag: gtsam.Pose3
    T_camera_tag_alt: gtsam.Pose3 | None = None


@dataclass(frozen=True, slots=True)
class SceneCamera:
    """One camera of the rig.

    Attributes:
        name: its name (the Kalibr camera's, or the detection topic).
        topic: the detection topic it publishes.
        T_rig_camera: its optical frame on the rig where known (given, or a seed), else None.
        sigmas: how well a given mount is known (6: rotation [rad], translation [m]); None
            holds a given mount fixed.
    """

    name: str
    topic: str
    T_rig_camera: gtsam.Pose3 | None
    sigmas: NDArray[np.float64] | None = None


@dataclass(frozen=True, slots=True)
class KnownTag:
    """A surveyed tag: its pose in the map frame and how well it is known (6 sigmas:
    rotation [rad], translation [m])."""

    tag_id: int
    T_map_tag: gtsam.Pose3
    sigmas: NDArray[np.float64]


@dataclass(frozen=True)
class TagScene:
    """Everything the 3-D estimator takes.

    Attributes:
        frame_times: (n,) each rig frame's time [ns], ascending.
        views: every tag view.
        cameras: the rig's cameras.
        tag_sizes: tag id -> the side of its black square [m], for every tag viewed.
        odometry: (n,) the rig's pose in the odometry frame at each frame's time, None where
            the log has none (or no odometry at all: an empty list).
        known_tags: surveyed tags (their frame is the map's).
        home_id: the tag whose frame is the map's when nothing is surveyed (None: the first
            tag seen).
        odometry_body: how the odometry's body stands on the rig: ``given``, or not given
            and taken by ``convention`` (REP 103) or ``assumed`` (the rig's frame); the up the
            odometry gives is checked where it was not given.
    """

    frame_times: NDArray[np.int64]
    views: list[TagView]
    cameras: list[SceneCamera]
    tag_sizes: dict[int, float]
    odometry: list[gtsam.Pose3 | None] = field(default_factory=list)
    known_tags: list[KnownTag] = field(default_factory=list)
    home_id: int | None = None
    odometry_body: str = "given"


@dataclass(frozen=True, slots=True)
class Tag3d:
    """One mapped tag.

    Attributes:
        tag_id: its id.
        T_map_tag: its pose in the map frame (the tag frame, z out of the print).
        covariance: 6x6 over its tangent (rotation, translation), or None.
        n_views: the views that placed it.
        size_m: its side [m].
        known: held by a survey prior.
    """

    tag_id: int
    T_map_tag: gtsam.Pose3
    covariance: NDArray[np.float64] | None
    n_views: int
    size_m: float
    known: bool = False

    @property
    def T_map_marker(self) -> gtsam.Pose3:
        """The pose in markergraph's marker frame (x the normal into the room)."""
        return self.T_map_tag.compose(gtsam.Pose3(gtsam.Rot3(R_TAG_MARKER), np.zeros(3)))

    @property
    def marker_covariance(self) -> NDArray[np.float64] | None:
        """:attr:`covariance` in the marker frame's tangent."""
        if self.covariance is None:
            return None
        A = np.zeros((6, 6))
        A[:3, :3] = A[3:, 3:] = R_TAG_MARKER.T
        return A @ self.covariance @ A.T


@dataclass(frozen=True, slots=True)
class Camera3d:
    """One camera's mount as the map has it.

    Attributes:
        name, topic: as in :class:`SceneCamera`.
        T_rig_camera: its optical frame on the rig.
        covariance: 6x6 where estimated, None where held fixed.
        estimated: estimated from the tags (not given, or given as a seed).
        n_views: tag views it contributed.
    """

    name: str
    topic: str
    T_rig_camera: gtsam.Pose3
    covariance: NDArray[np.float64] | None
    estimated: bool
    n_views: int


@dataclass(frozen=True)
class TagMap3d:
    """The 3-D tag map.

    Attributes:
        tags: tag id -> tag, in id order.
        frame_times: (m,) the times of the rig frames placed [ns].
        rig_poses: (m,) ``T_map_rig`` at each of them.
        cameras: the rig's cameras by name (those left out are in the notes).
        home_id: the tag that fixed the frame (None when surveyed tags did).
        up: the map frame's z is up (from odometry, surveyed tags or the tags' walls), so that
            its wall tags make a 2-D map; False leaves the home tag's frame as it is.
        frames_skipped: rig frames placed by no tag (their views unused).
        views_used, views_dropped: views in the solution, and those left out as outliers.
        reprojection_rms_px: the corners' RMS reprojection error [px].
        converged: the optimiser converged.
        notes: what the estimator noticed.
    """

    tags: dict[int, Tag3d]
    frame_times: NDArray[np.int64]
    rig_poses: list[gtsam.Pose3]
    cameras: dict[str, Camera3d]
    home_id: int | None
    up: bool
    frames_skipped: int
    views_used: int
    views_dropped: int
    reprojection_rms_px: float
    converged: bool
    notes: list[Note] = field(default_factory=list)
