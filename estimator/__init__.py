"""markergraph.estimator: the paper's closed forms and the estimators (numpy, gtsam, filterpy)."""

from markergraph.estimator.angles import angle_diff, wrap, wrap_array
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

__all__ = [
    "Edge",
    "Form",
    "Goal",
    "PolarPose",
    "angle_diff",
    "compose",
    "edge_from_observation",
    "edge_from_pose2",
    "edge_to_pose2",
    "heading",
    "odometry",
    "wrap",
    "wrap_array",
]
