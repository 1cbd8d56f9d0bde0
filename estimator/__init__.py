"""markergraph.estimator: the paper's closed forms and the estimators (numpy, gtsam, filterpy)."""

from markergraph.estimator.angles import angle_diff, wrap, wrap_array
from markergraph.estimator.frames import Frame, Frames, build_frames
from markergraph.estimator.graph import Robust
from markergraph.estimator.metrics import (
    MapError,
    TrajectoryError,
    chi2_interval,
    map_error,
    nees,
    trajectory_error,
)
from markergraph.estimator.paper import (
    Edge,
    Form,
    Goal,
    PolarPose,
    compose,
    edge_from_observation,
    edge_from_pose2,
    edge_to_pose2,
    heading,
    odometry,
)
from markergraph.estimator.run import estimate, estimate_frames
from markergraph.estimator.trajectory import Trajectory
from markergraph.estimator.types import (
    Estimate,
    EstimationError,
    FactorResidual,
    MarkerEstimate,
    MarkerGraphError,
    MarkerLink,
    Method,
    Observation,
    OdometryNoise,
    OdometrySample,
    OutputError,
    RejectedObservationError,
    SettingsError,
)

__all__ = [
    "Edge",
    "Estimate",
    "EstimationError",
    "FactorResidual",
    "Form",
    "Frame",
    "Frames",
    "Goal",
    "MapError",
    "MarkerEstimate",
    "MarkerGraphError",
    "MarkerLink",
    "Method",
    "Observation",
    "OdometryNoise",
    "OdometrySample",
    "OutputError",
    "PolarPose",
    "RejectedObservationError",
    "Robust",
    "SettingsError",
    "Trajectory",
    "TrajectoryError",
    "angle_diff",
    "build_frames",
    "chi2_interval",
    "compose",
    "edge_from_observation",
    "edge_from_pose2",
    "edge_to_pose2",
    "estimate",
    "estimate_frames",
    "heading",
    "map_error",
    "nees",
    "odometry",
    "trajectory_error",
    "wrap",
    "wrap_array",
]
