"""markergraph.frontend: camera frames and logs to marker observations (OpenCV, mcap).

Modules: ``logs`` (a log opened once: its files, topics, messages), ``decode`` (images, depth,
odometry), ``tf`` (camera mount, odometry from /tf), ``topics`` (which topic plays which role),
``camera``, ``detect``, ``apriltag3`` (AprilTag 3's detector), ``detectors`` (which one finds a
dictionary's markers), ``yaw``, ``observe`` (one frame to observations), ``pipeline`` (a log to
observations: ``extract``), ``spans`` (reading a stretch of a log), ``extraction`` (what a log
gave), ``cleaning`` (bad samples and stamps dropped), ``depth_scale`` (depth's scale against the
markers' size), ``config`` (how to read a log), ``preflight`` (can a log be mapped).

The names below load on first use, so that ``markergraph info`` and ``detect`` import only the
modules they run.
"""

# First: OpenCV reads its pixel bound when cv2 loads (see markergraph.frontend._opencv).
from markergraph.frontend import _opencv  # noqa: F401  # isort: skip
from typing import TYPE_CHECKING

from markergraph.common.lazy import lazy_package

if TYPE_CHECKING:
    from markergraph.frontend.apriltag3 import AprilTag3Detector
    from markergraph.frontend.camera import Camera, CameraMount
    from markergraph.frontend.config import FrontendConfig
    from markergraph.frontend.decode import decode_depth, decode_image, odometry_sample, stamp_ns
    from markergraph.frontend.detect import Detection, Detector, load_dictionary
    from markergraph.frontend.detectors import DetectorChoice, make_detector
    from markergraph.frontend.extraction import Extraction
    from markergraph.frontend.logs import Log, LogError, LogTopic, Message, open_log
    from markergraph.frontend.observe import (
        DepthModel,
        ObservationModel,
        observe,
        observe_detections,
    )
    from markergraph.frontend.pipeline import extract
    from markergraph.frontend.sizes import MarkerSizes
    from markergraph.frontend.tf import mount_from_transforms, odometry_from_tf, transforms_of
    from markergraph.frontend.topics import TopicChoice, choose_topics
    from markergraph.frontend.yaw import YawMethod

__all__ = [
    "AprilTag3Detector",
    "Camera",
    "CameraMount",
    "DepthModel",
    "Detection",
    "Detector",
    "DetectorChoice",
    "Extraction",
    "FrontendConfig",
    "Log",
    "LogError",
    "LogTopic",
    "MarkerSizes",
    "Message",
    "ObservationModel",
    "TopicChoice",
    "YawMethod",
    "choose_topics",
    "decode_depth",
    "decode_image",
    "extract",
    "load_dictionary",
    "make_detector",
    "mount_from_transforms",
    "observe",
    "observe_detections",
    "odometry_from_tf",
    "odometry_sample",
    "open_log",
    "stamp_ns",
    "transforms_of",
]

lazy_package(
    __name__,
    {
        "markergraph.frontend.apriltag3": ("AprilTag3Detector",),
        "markergraph.frontend.camera": (
            "Camera",
            "CameraMount",
        ),
        "markergraph.frontend.config": ("FrontendConfig",),
        "markergraph.frontend.decode": (
            "decode_depth",
            "decode_image",
            "odometry_sample",
            "stamp_ns",
        ),
        "markergraph.frontend.detect": (
            "Detection",
            "Detector",
            "load_dictionary",
        ),
        "markergraph.frontend.detectors": (
            "DetectorChoice",
            "make_detector",
        ),
        "markergraph.frontend.extraction": ("Extraction",),
        "markergraph.frontend.logs": (
            "Log",
            "LogError",
            "LogTopic",
            "Message",
            "open_log",
        ),
        "markergraph.frontend.observe": (
            "DepthModel",
            "ObservationModel",
            "observe",
            "observe_detections",
        ),
        "markergraph.frontend.pipeline": ("extract",),
        "markergraph.frontend.sizes": ("MarkerSizes",),
        "markergraph.frontend.tf": (
            "mount_from_transforms",
            "odometry_from_tf",
            "transforms_of",
        ),
        "markergraph.frontend.topics": (
            "TopicChoice",
            "choose_topics",
        ),
        "markergraph.frontend.yaw": ("YawMethod",),
    },
)
