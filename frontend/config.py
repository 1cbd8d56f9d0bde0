"""How the front end reads a log: dictionary, sizes, topics, camera and noise."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from markergraph.frontend.camera import Camera, CameraMount
from markergraph.frontend.detect import DetectorMode, marker_modules
from markergraph.frontend.detectors import DetectorChoice, MarkerDetector, make_detector
from markergraph.frontend.observe import DepthModel, ObservationModel
from markergraph.frontend.sizes import MarkerSizes
from markergraph.frontend.yaw import YawMethod

__all__ = ["FrontendConfig"]


@dataclass(frozen=True)
class FrontendConfig:
    """How to read a log. Topics left as None are chosen automatically.

    Attributes:
        dictionary: the markers' dictionary.
        marker_sizes: the side of each marker's black square [m].
        method: how theta is computed.
        allowed_ids: if given, only these marker ids are kept.
        color_topic, depth_topic, camera_info_topic, odom_topic: topics to read.
        base_frame: the robot's base frame in /tf_static.
        mount: the camera's mount; None reads it from /tf_static.
        default_mount: the mount assumed when /tf_static does not give it.
        camera: intrinsics; None reads them from the camera info topic.
        pair_tolerance_ns: largest stamp difference between a colour frame and its depth.
        depth_model: the depth camera's error model.
        corner_sigma_px: the corners' noise after sub-pixel refinement [px].
        kalibr_cameras: a Kalibr ``cameras.yaml`` giving intrinsics by detection topic.
        camera_poses: a TagSLAM ``camera_poses.yaml`` giving each camera's pose on the rig.
        tagslam: a TagSLAM ``tagslam.yaml`` giving tag sizes and the odometry's body on the rig.
        depth_scale: what depth reads per true metre: 1.0 trusts the depth camera; None (auto)
            applies the scale measured against the markers' known size when it is more than its
            own error from 1 (0.4 %; it is always measured and reported: see
            :func:`~markergraph.frontend.pipeline.depth_scale_from_markers`).
        detector_mode: how images are searched for markers (``FAST`` finds FULL's markers and
            corners at a third to a half of its cost on a robot's frames; see
            :class:`~markergraph.frontend.detect.DetectorMode`).
        detector: which library finds the markers: OpenCV, AprilTag 3 (AprilTag families
            only), or AUTO, the better one for the dictionary by our measurements (see
            :data:`~markergraph.frontend.detectors.AUTO_CHOICE`).
    """

    dictionary: str = "DICT_4X4_50"
    marker_sizes: MarkerSizes = MarkerSizes()
    method: YawMethod = YawMethod.PNP
    allowed_ids: tuple[int, ...] | None = None
    color_topic: str | None = None
    depth_topic: str | None = None
    camera_info_topic: str | None = None
    odom_topic: str | None = None
    base_frame: str = "base_link"
    mount: CameraMount | None = None
    default_mount: CameraMount = CameraMount()
    camera: Camera | None = None
    pair_tolerance_ns: int = 20_000_000
    depth_model: DepthModel = DepthModel()
    corner_sigma_px: float = 0.3
    kalibr_cameras: Path | None = None
    camera_poses: Path | None = None
    tagslam: Path | None = None
    depth_scale: float | None = None
    detector_mode: DetectorMode = DetectorMode.FAST
    detector: DetectorChoice = DetectorChoice.AUTO

    def new_detector(self) -> MarkerDetector:
        """A detector as configured (one a thread: a detector is not safe to share)."""
        return make_detector(
            self.dictionary, self.detector, mode=self.detector_mode, allowed_ids=self.allowed_ids
        )

    @property
    def observation_model(self) -> ObservationModel:
        """How detected corners become observations."""
        return ObservationModel(
            self.marker_sizes,
            self.method,
            self.corner_sigma_px,
            self.depth_model,
            marker_modules(self.dictionary),
        )
