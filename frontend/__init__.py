"""markergraph.frontend: camera frames and logs to marker observations (OpenCV, mcap).

Modules: ``sources`` (log files, topics, messages), ``decode`` (images, depth, odometry),
``tf`` (camera mount, odometry from /tf), ``topics`` (which topic plays which role),
``camera``, ``detect``, ``yaw``, ``observe`` (one frame to observations), ``pipeline`` (a log to
observations), ``config`` (how to read a log), ``files`` (writing whole or not at all).
"""

from markergraph.frontend.camera import Camera, CameraMount
from markergraph.frontend.config import FrontendConfig
from markergraph.frontend.decode import decode_depth, decode_image, odometry_sample, stamp_ns
from markergraph.frontend.detect import Detection, Detector, load_dictionary
from markergraph.frontend.observe import DepthModel, ObservationModel, observe, observe_detections
from markergraph.frontend.pipeline import Extraction, extract
from markergraph.frontend.sizes import MarkerSizes
from markergraph.frontend.sources import LogError, LogTopic, Message, log_topics, messages
from markergraph.frontend.tf import mount_from_transforms, odometry_from_tf, transforms_of
from markergraph.frontend.topics import TopicChoice, choose_topics
from markergraph.frontend.yaw import YawMethod

__all__ = [
    "Camera",
    "CameraMount",
    "DepthModel",
    "Detection",
    "Detector",
    "Extraction",
    "FrontendConfig",
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
    "log_topics",
    "messages",
    "mount_from_transforms",
    "observe",
    "observe_detections",
    "odometry_from_tf",
    "odometry_sample",
    "stamp_ns",
    "transforms_of",
]
