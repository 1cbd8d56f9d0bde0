"""markergraph.estimator: the paper's closed forms and the estimators (numpy, gtsam, filterpy).

The names below load on first use: the front end imports the records (``types``,
``trajectory``) without GTSAM's solvers."""

from typing import TYPE_CHECKING

from markergraph.common.lazy import lazy_package

if TYPE_CHECKING:
    from markergraph.estimator.angles import angle_diff, wrap, wrap_array
    from markergraph.estimator.consistency import (
        OdometryStretch,
        fit_odometry_noise,
        odometry_nees,
        odometry_stretches,
    )
    from markergraph.estimator.estimate import Estimate
    from markergraph.estimator.frames import Frame, Frames, build_frames
    from markergraph.estimator.heights import MarkerHeight, marker_heights
    from markergraph.estimator.metrics import (
        ELLIPSE_95_D2,
        EllipseCoverage,
        MapError,
        TrajectoryError,
        chi2_interval,
        ellipse_coverage,
        map_error,
        nees,
        trajectory_error,
    )
    from markergraph.estimator.misreads import Misread, describe_misreads, misread_observations
    from markergraph.estimator.odometry_scale import (
        odometry_scale_by_residuals,
        odometry_turn_scale_by_residuals,
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
    from markergraph.estimator.residual_search import GridMinimum, SlamInputs
    from markergraph.estimator.run import estimate, estimate_frames
    from markergraph.estimator.timing import (
        READOUT_MAX_S,
        CameraDelay,
        camera_delay_by_residuals,
        retimed,
        unleaned,
        widened_for_motion,
    )
    from markergraph.estimator.trajectory import (
        Trajectory,
        corrected_odometry,
        map_to_odom,
        odometry_in_map,
        turn_rate,
    )
    from markergraph.estimator.types import (
        ODOMETRY_NOISE,
        FactorResidual,
        MarkerEstimate,
        MarkerLink,
        Method,
        Observation,
        OdometryNoise,
        OdometrySample,
        Placement,
        Robust,
    )
    from markergraph.estimator.views import shared_over_views

__all__ = [
    "ELLIPSE_95_D2",
    "ODOMETRY_NOISE",
    "READOUT_MAX_S",
    "CameraDelay",
    "Edge",
    "EllipseCoverage",
    "Estimate",
    "FactorResidual",
    "Form",
    "Frame",
    "Frames",
    "Goal",
    "GridMinimum",
    "MapError",
    "MarkerEstimate",
    "MarkerHeight",
    "MarkerLink",
    "Method",
    "Misread",
    "Observation",
    "OdometryNoise",
    "OdometrySample",
    "OdometryStretch",
    "Placement",
    "PolarPose",
    "Robust",
    "SlamInputs",
    "Trajectory",
    "TrajectoryError",
    "angle_diff",
    "build_frames",
    "camera_delay_by_residuals",
    "chi2_interval",
    "compose",
    "corrected_odometry",
    "describe_misreads",
    "edge_from_observation",
    "edge_from_pose2",
    "edge_to_pose2",
    "ellipse_coverage",
    "estimate",
    "estimate_frames",
    "fit_odometry_noise",
    "heading",
    "map_error",
    "map_to_odom",
    "marker_heights",
    "misread_observations",
    "nees",
    "odometry",
    "odometry_in_map",
    "odometry_nees",
    "odometry_scale_by_residuals",
    "odometry_stretches",
    "odometry_turn_scale_by_residuals",
    "retimed",
    "shared_over_views",
    "trajectory_error",
    "turn_rate",
    "unleaned",
    "widened_for_motion",
    "wrap",
    "wrap_array",
]

lazy_package(
    __name__,
    {
        "markergraph.estimator.angles": (
            "angle_diff",
            "wrap",
            "wrap_array",
        ),
        "markergraph.estimator.consistency": (
            "OdometryStretch",
            "fit_odometry_noise",
            "odometry_nees",
            "odometry_stretches",
        ),
        "markergraph.estimator.estimate": ("Estimate",),
        "markergraph.estimator.frames": (
            "Frame",
            "Frames",
            "build_frames",
        ),
        "markergraph.estimator.heights": (
            "MarkerHeight",
            "marker_heights",
        ),
        "markergraph.estimator.metrics": (
            "ELLIPSE_95_D2",
            "EllipseCoverage",
            "MapError",
            "TrajectoryError",
            "chi2_interval",
            "ellipse_coverage",
            "map_error",
            "nees",
            "trajectory_error",
        ),
        "markergraph.estimator.misreads": (
            "Misread",
            "describe_misreads",
            "misread_observations",
        ),
        "markergraph.estimator.odometry_scale": (
            "odometry_scale_by_residuals",
            "odometry_turn_scale_by_residuals",
        ),
        "markergraph.estimator.paper": (
            "Edge",
            "Form",
            "Goal",
            "PolarPose",
            "compose",
            "edge_from_observation",
            "edge_from_pose2",
            "edge_to_pose2",
            "heading",
            "odometry",
        ),
        "markergraph.estimator.residual_search": (
            "GridMinimum",
            "SlamInputs",
        ),
        "markergraph.estimator.run": (
            "estimate",
            "estimate_frames",
        ),
        "markergraph.estimator.views": ("shared_over_views",),
        "markergraph.estimator.timing": (
            "READOUT_MAX_S",
            "CameraDelay",
            "camera_delay_by_residuals",
            "retimed",
            "unleaned",
            "widened_for_motion",
        ),
        "markergraph.estimator.trajectory": (
            "Trajectory",
            "corrected_odometry",
            "map_to_odom",
            "odometry_in_map",
            "turn_rate",
        ),
        "markergraph.estimator.types": (
            "ODOMETRY_NOISE",
            "FactorResidual",
            "MarkerEstimate",
            "MarkerLink",
            "Method",
            "Observation",
            "OdometryNoise",
            "OdometrySample",
            "Placement",
            "Robust",
        ),
    },
)
