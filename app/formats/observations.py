"""Observations as JSON lines (``markergraph detect``'s output), one object per observation.

Each line: ``t_ns`` (int), ``marker_id``, ``bearing``, ``theta`` [rad], ``range_m`` [m], their
``sigma_bearing``, ``sigma_theta``, ``sigma_range``, ``corners`` ([[u, v] x 4], OpenCV order),
``flags`` (list of strings), ``height_m`` (the marker centre above the base frame [m], or
null) and ``odom`` ({"x", "y", "yaw"}: ``T_odom_base`` interpolated at
``t_ns``, or null where odometry does not reach).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from markergraph.common.errors import MarkerGraphError
from markergraph.common.files import written_whole
from markergraph.estimator.trajectory import Trajectory
from markergraph.estimator.types import Observation, OdometrySample

__all__ = ["read_observations", "write_observations"]


def write_observations(path: Path, observations: list[Observation], odometry: Trajectory) -> int:
    """Write observations as JSON lines, whole or not at all.

    Returns:
        The number of lines written.
    """
    path = Path(path)
    poses = [odometry.at(o.t_ns) for o in observations]
    with written_whole(path) as partial, open(partial, "w", encoding="utf-8") as stream:
        for obs, pose in zip(observations, poses, strict=True):
            stream.write(
                json.dumps(
                    {
                        "t_ns": obs.t_ns,
                        "marker_id": obs.marker_id,
                        "bearing": obs.bearing,
                        "theta": obs.theta,
                        "range_m": obs.range_m,
                        "sigma_bearing": obs.sigma_bearing,
                        "sigma_theta": obs.sigma_theta,
                        "sigma_range": obs.sigma_range,
                        "corners": [list(c) for c in obs.corners],
                        "flags": sorted(obs.flags),
                        "height_m": obs.height_m if math.isfinite(obs.height_m) else None,
                        "odom": None
                        if pose is None
                        else {"x": pose.x(), "y": pose.y(), "yaw": pose.theta()},
                    },
                    allow_nan=False,
                )
                + "\n"
            )
    return len(observations)


def read_observations(path: Path) -> tuple[list[Observation], Trajectory]:
    """Observations and the odometry poses they carry (one sample per distinct stamp).

    Raises:
        MarkerGraphError: a line that is not an observation; the message names the line.
    """
    observations, odometry = [], {}
    with open(path) as stream:
        for number, line in enumerate(stream, start=1):
            try:
                row = json.loads(line)
                observations.append(
                    Observation(
                        int(row["t_ns"]),
                        int(row["marker_id"]),
                        float(row["bearing"]),
                        float(row["theta"]),
                        float(row["range_m"]),
                        float(row["sigma_bearing"]),
                        float(row["sigma_theta"]),
                        float(row["sigma_range"]),
                        tuple((float(u), float(v)) for u, v in row.get("corners", [])),
                        frozenset(row.get("flags", [])),
                        math.nan if row.get("height_m") is None else float(row["height_m"]),
                    )
                )
                if row.get("odom") is not None:
                    odom = row["odom"]
                    odometry[int(row["t_ns"])] = OdometrySample(
                        int(row["t_ns"]), float(odom["x"]), float(odom["y"]), float(odom["yaw"])
                    )
            except (ValueError, KeyError, TypeError) as error:
                raise MarkerGraphError(
                    f"{path}:{number}: not an observation line ({error})"
                ) from error
    return observations, Trajectory.from_samples(odometry.values())
