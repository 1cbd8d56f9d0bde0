"""Observations as JSON lines (``markergraph detect``'s output), one object per observation.

Each line: ``t_ns`` (int), ``marker_id``, ``bearing``, ``theta`` [rad], ``range_m`` [m], their
``sigma_bearing``, ``sigma_theta``, ``sigma_range``, ``corners`` ([[u, v] x 4], OpenCV order),
``flags`` (list of strings), ``height_m`` (the marker centre above the base frame [m], or
null), ``sigma_theta_shared`` (the part of theta's error one view's observations share [rad];
0 where absent), ``theta_per_turn`` (theta's change per radian the camera turns while a
rolling shutter reads its rows out [rad/rad]; 0 where absent) and ``odom`` ({"x", "y", "yaw"}:
``T_odom_base`` interpolated at ``t_ns``, or null where odometry does not reach).

``markergraph detect`` also writes what ``markergraph map`` needs to map from the file: a first
line ``{"header": {...}}`` holding ``format`` ("markergraph.observations"), ``version`` (2),
``mount`` ({x_m, y_m, height_m, yaw_rad, pitch_rad, roll_rad}: the camera's mount the
observations were made with), ``odom_topic``, ``odometry_evidence`` (what the odometry's first
messages showed of its kind: it chooses the noise model) and ``frames`` (colour frames read);
and, after the observations, one line per odometry sample ``{"odometry": {"t_ns", "x", "y",
"yaw"}}`` (``T_odom_base`` at its own rate). Readers of observations skip both.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from markergraph.common.errors import MarkerGraphError
from markergraph.common.files import written_whole
from markergraph.common.notes import Note
from markergraph.estimator.trajectory import Trajectory
from markergraph.estimator.types import Observation, OdometrySample
from markergraph.frontend.camera import CameraMount
from markergraph.frontend.extraction import Extraction
from markergraph.frontend.odometry_kind import OdometryEvidence
from markergraph.frontend.topics import TopicChoice

__all__ = [
    "ObservationFile",
    "extraction_of_file",
    "is_observation_file",
    "read_observation_file",
    "read_observations",
    "write_observations",
]

FORMAT = "markergraph.observations"
VERSION = 2


@dataclass(frozen=True)
class ObservationFile:
    """What a ``detect`` output holds.

    Attributes:
        observations: every observation, in file order.
        odometry: ``T_odom_base`` at the odometry's rate, or (a file without odometry lines)
            only at the observations' stamps.
        full_odometry: whether the odometry is at its own rate.
        odometry_at_observations: the poses the observations carry (one per distinct stamp).
        mount: the camera's mount the observations were made with (None: not written).
        odom_topic: the odometry's topic in the log, if written.
        odometry_evidence: what the odometry's messages showed of its kind (it chooses the
            odometry's noise model), if written.
        frames: the colour frames detect read, if written.
    """

    observations: list[Observation]
    odometry: Trajectory
    full_odometry: bool
    odometry_at_observations: Trajectory
    mount: CameraMount | None
    odom_topic: str | None
    odometry_evidence: OdometryEvidence | None = None
    frames: int | None = None


def write_observations(
    path: Path,
    observations: list[Observation],
    odometry: Trajectory,
    mount: CameraMount | None = None,
    odom_topic: str | None = None,
    odometry_evidence: OdometryEvidence | None = None,
    frames: int | None = None,
) -> int:
    """Write observations as JSON lines, whole or not at all; with a ``mount``, also the header
    and the odometry lines that ``markergraph map`` maps from.

    Returns:
        The number of observations written.
    """
    path = Path(path)
    poses = [odometry.at_xy_yaw(o.t_ns) for o in observations]
    with written_whole(path) as partial, open(partial, "w", encoding="utf-8") as stream:
        if mount is not None:
            evidence = asdict(odometry_evidence) if odometry_evidence is not None else None
            header = {"format": FORMAT, "version": VERSION, "mount": asdict(mount),
                      "odom_topic": odom_topic, "odometry_evidence": evidence,
                      "frames": frames}  # fmt: skip
            stream.write(json.dumps({"header": header}, allow_nan=False) + "\n")
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
                        "sigma_theta_shared": obs.sigma_theta_shared,
                        "theta_per_turn": obs.theta_per_turn,
                        "corners": [list(c) for c in obs.corners],
                        "flags": sorted(obs.flags),
                        "height_m": obs.height_m if math.isfinite(obs.height_m) else None,
                        "odom": None
                        if pose is None
                        else {"x": pose[0], "y": pose[1], "yaw": pose[2]},
                    },
                    allow_nan=False,
                )
                + "\n"
            )
        if mount is not None:
            for t_ns, (x, y, yaw) in zip(odometry.t_ns, odometry.poses, strict=True):
                row = {"t_ns": int(t_ns), "x": float(x), "y": float(y), "yaw": float(yaw)}
                stream.write(json.dumps({"odometry": row}, allow_nan=False) + "\n")
    return len(observations)


def read_observations(path: Path) -> tuple[list[Observation], Trajectory]:
    """Observations and the odometry poses they carry (one sample per distinct stamp).

    Raises:
        MarkerGraphError: a line that is not an observation; the message names the line.
    """
    read = read_observation_file(path)
    return read.observations, read.odometry_at_observations


def read_observation_file(path: Path) -> ObservationFile:
    """Everything a ``detect`` output holds (:class:`ObservationFile`).

    Raises:
        MarkerGraphError: a line that is neither an observation, an odometry sample nor the
            header; the message names the file and line.
    """
    observations: list[Observation] = []
    at_observations: dict[int, OdometrySample] = {}
    odometry: list[OdometrySample] = []
    header: dict[str, Any] = {}
    with open(path, encoding="utf-8") as stream:
        for number, line in enumerate(stream, start=1):
            try:
                row = json.loads(line)
                if "header" in row:
                    header = dict(row["header"])
                elif "odometry" in row:
                    odometry.append(_sample(row["odometry"], row["odometry"]["t_ns"]))
                else:
                    observations.append(_observation(row))
                    if row.get("odom") is not None:
                        t_ns = int(row["t_ns"])
                        at_observations[t_ns] = _sample(row["odom"], t_ns)
            except (ValueError, KeyError, TypeError, AttributeError) as error:
                raise MarkerGraphError(
                    f"{path}:{number}: not an observation line ({error})"
                ) from error
    mount = header.get("mount")
    at_stamps = Trajectory.from_samples(at_observations.values())
    return ObservationFile(
        observations,
        Trajectory.from_samples(odometry) if odometry else at_stamps,
        bool(odometry),
        at_stamps,
        CameraMount(**{k: float(v) for k, v in mount.items()}) if mount else None,
        header.get("odom_topic"),
        OdometryEvidence(**header["odometry_evidence"])
        if header.get("odometry_evidence")
        else None,
        int(header["frames"]) if header.get("frames") is not None else None,
    )


def _sample(row: dict[str, Any], t_ns: Any) -> OdometrySample:
    return OdometrySample(int(t_ns), float(row["x"]), float(row["y"]), float(row["yaw"]))


def _observation(row: dict[str, Any]) -> Observation:
    return Observation(
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
        float(row.get("sigma_theta_shared", 0.0)),
        float(row.get("theta_per_turn", 0.0)),
    )


def is_observation_file(path: Path) -> bool:
    """Whether ``path`` is a ``detect`` output (a file whose first byte opens a JSON object)
    rather than a log."""
    path = Path(path)
    if not path.is_file():
        return False
    if path.suffix == ".jsonl":
        return True
    try:
        with open(path, "rb") as stream:
            return stream.read(1) == b"{"
    except OSError:
        return False


def extraction_of_file(path: Path) -> Extraction:
    """A ``detect`` output as the front end's result, for ``markergraph map``: its
    observations, odometry and mount (no images, no truth).

    Raises:
        MarkerGraphError: a bad line, or no odometry in the file.
    """
    read = read_observation_file(path)
    if not len(read.odometry):
        raise MarkerGraphError(
            f"{path}: no odometry in this file (its observations carry none): map needs the "
            "robot's odometry; run markergraph detect on the log again"
        )
    notes = [Note("frontend.observation_file",
                  f"observations read from {path} (markergraph detect's output)")]  # fmt: skip
    if not read.full_odometry:
        notes.append(Note(
            "frontend.observation_file_odometry",
            f"{path} holds odometry only at the observations' stamps (an older detect): the "
            "camera delay and odometry scale are searched on it; run detect again for the rest",
        ))  # fmt: skip
    if read.mount is None:
        notes.append(Note("frontend.observation_file_mount",
                          f"{path} does not say the camera's mount: the default mount is assumed "
                          "(run detect again to write it)"))  # fmt: skip
    stamps = {o.t_ns for o in read.observations}
    return Extraction(
        observations=sorted(read.observations, key=lambda o: o.t_ns),
        odometry=read.odometry,
        camera=None,
        mount=read.mount or CameraMount(),
        mount_source=f"{path} (detect's output)" if read.mount is not None else None,
        topics=TopicChoice(None, None, None, read.odom_topic, None),
        frames=read.frames if read.frames is not None else len(stamps),
        notes=notes,
        odometry_evidence=read.odometry_evidence,
    )
