"""What a log gave the front end (:class:`Extraction`), and one stretch's share of it before the
stretches are joined (:class:`Part`).

Each field says, where it is declared, how stretches join it (:class:`Join`) and whether
report.json's ``inputs`` shows it: a new field is added in one place.
"""

from __future__ import annotations

from array import array
from collections import Counter
from dataclasses import asdict, dataclass, field, fields, is_dataclass
from enum import Enum
from typing import TYPE_CHECKING, Any

from markergraph.common.notes import Note
from markergraph.estimator.trajectory import Trajectory
from markergraph.estimator.types import Observation, OdometryTrack
from markergraph.frontend.camera import Camera, CameraMount
from markergraph.frontend.logs import DecodeFailures
from markergraph.frontend.odometry_kind import OdometryEvidence
from markergraph.frontend.posed import LevelledFrame, MarkerDetections
from markergraph.frontend.sizes import MarkerSizes
from markergraph.frontend.topics import TopicChoice

if TYPE_CHECKING:  # true markers are Pose2s, made where a log's truth is read
    import gtsam

__all__ = ["MOUNT_FROM_SETTINGS", "Extraction", "Join", "Part", "merge_parts"]

MOUNT_FROM_SETTINGS = "the settings (camera.*)"
"""Where a mount not found in the log comes from (:attr:`Extraction.mount_source`)."""


class Join(Enum):
    """How the stretches' values of a field make the whole log's."""

    FIRST = "first"
    """The first stretch's (set alike by every stretch)."""
    FIRST_SET = "first_set"
    """The first stretch's that is not None."""
    SUM = "sum"
    """Added up (counts, and counters by key)."""
    CONCAT = "concat"
    """Lists end to end, in log order."""
    MERGE = "merge"
    """Messages skipped and files' notes (:class:`DecodeFailures`): counts summed, notes
    once."""
    UNIQUE = "unique"
    """Lists end to end, each item once (each stretch says the same notes)."""
    NONE = "none"
    """Left at its default: set once the stretches are joined."""


# Each field's metadata: how the stretches join it (merge_parts), and whether report.json's
# ``inputs`` shows it (evidence is set once the stretches are joined).
_FIRST = {"join": Join.FIRST}
_FIRST_SET = {"join": Join.FIRST_SET}
_SUM = {"join": Join.SUM}
_CONCAT = {"join": Join.CONCAT}
_UNIQUE = {"join": Join.UNIQUE}
_LATER = {"join": Join.NONE}
_EVIDENCE = {"join": Join.NONE, "evidence": True}


@dataclass
class Extraction:
    """What a log gave. Mutable: the stages of :func:`~markergraph.frontend.extract` fill it."""

    observations: list[Observation] = field(metadata=_CONCAT)
    """Every marker observation, in time order."""
    odometry: Trajectory = field(metadata=_FIRST)
    """``T_odom_base``, its bad samples dropped (see ``notes``)."""
    camera: Camera | None = field(metadata=_FIRST_SET)
    """The intrinsics used."""
    mount: CameraMount = field(metadata=_FIRST)
    """The camera's mount used."""
    mount_source: str | None = field(metadata=_FIRST_SET, default=None, kw_only=True)
    """Where ``mount`` came from when the log gave it: its static transforms (naming the topic
    and frames) or detect's output; None where the settings gave it."""
    topics: TopicChoice = field(metadata=_FIRST)
    """The topics read."""
    frames: int = field(metadata=_SUM, default=0)
    """Colour frames read."""
    frames_with_depth: int = field(metadata=_SUM, default=0)
    """Of them, those paired with depth."""
    skipped: Counter[str] = field(metadata=_SUM, default_factory=Counter)
    """Reason -> frames skipped for it."""
    notes: list[Note] = field(metadata=_UNIQUE, default_factory=list)
    """What was assumed or dropped."""
    # None by default, a class attribute: an extraction pickled before this field reads None.
    read_failures: DecodeFailures | None = field(
        metadata={"join": Join.MERGE}, default=None, repr=False
    )
    """Messages the stretches could not read, and what was lost or recovered of a file (None:
    not recorded, a detection log)."""
    warnings: list[str] = field(metadata=_LATER, default_factory=list)
    """Damaged stretches skipped (unreadable messages, per file and topic), each said once:
    ``read_failures`` in words, set once the stretches are joined."""
    true_marker_poses: dict[int, tuple[float, float, float]] = field(
        metadata=_FIRST, default_factory=dict
    )
    """Ground truth (x, y, yaw) of each marker in ``map`` when the log carries it (simulated
    logs): :attr:`true_markers` as numbers, which reading a log needs no GTSAM for."""
    true_path: Trajectory = field(
        metadata=_LATER, default_factory=lambda: Trajectory.from_samples([], "map")
    )
    """The true base pose in ``map``, when the log carries it."""
    undecodable_frames: int = field(metadata=_SUM, default=0)
    """Colour frames skipped because their image does not decode."""
    unusable_depth: int = field(metadata=_SUM, default=0)
    """Depth images skipped (undecodable, empty, or not the colour's size)."""
    ids_left_out: Counter[int] = field(metadata=_SUM, default_factory=Counter)
    """Detections dropped by the allowed ids, by marker id."""
    ids_beyond_dictionary: Counter[int] = field(metadata=_SUM, default_factory=Counter)
    """Ids beyond the dictionary's that its larger family found, by the number of checked
    frames each was in (:mod:`~markergraph.frontend.dictionary_check`)."""
    dictionary_checks: int = field(metadata=_SUM, default=0)
    """Colour frames searched for a larger dictionary's markers."""
    depth_misses: int = field(metadata=_SUM, default=0)
    """Observations in frames with depth whose marker held no valid depth pixel (0, NaN,
    negative or beyond the depth model's range), of ``depth_tries``."""
    depth_tries: int = field(metadata=_SUM, default=0)
    """Observations in frames with depth."""
    levelled_frames: int = field(metadata=_SUM, default=0)
    """Frames observed through the odometry's attitude (a tilted base or a rolled camera)
    rather than as level."""
    levelled: list[LevelledFrame] = field(metadata=_CONCAT, default_factory=list, repr=False)
    """Those frames' detections, kept and dropped, until they are tallied."""
    level_detections: Counter[int] = field(metadata=_SUM, default_factory=Counter)
    """Detections in level frames, by marker id, until they are tallied."""
    level_no_yaw: Counter[int] = field(metadata=_SUM, default_factory=Counter)
    """Of them, those whose yaw had no solution (no PnP pose, or none of the yaw method's)."""
    marker_detections: dict[int, MarkerDetections] = field(metadata=_LATER, default_factory=dict)
    """Per marker, its detections in every frame and how many were dropped (off a wall, no
    pose or yaw), or read with their corners reversed (frames levelled from its full pose)."""
    depth_ratios: list[tuple[int, float, float]] = field(metadata=_CONCAT, default_factory=list)
    """Each well-placed marker's stamp, depth and PnP distance."""
    size_ratios: list[tuple[int, float]] = field(metadata=_CONCAT, default_factory=list)
    """Each well-placed marker's id and depth over PnP distance, also where they disagree by
    more than observe's gate (a wrong marker size)."""
    depth_scale: float = field(metadata=_LATER, default=1.0)
    """What depth was taken to read per true metre, as set or measured; the ranges from depth
    are divided by it."""
    measured_depth_scale: float | None = field(metadata=_LATER, default=None)
    """What the markers' known size measured it to be, if enough markers were seen with
    depth."""
    depth_scale_sigma: float | None = field(metadata=_LATER, default=None)
    """The depth scale's standard deviation where the markers measured it and ``--depth-scale``
    did not set it (the map's covariances carry its share)."""
    dropped_odometry_samples: int = field(metadata=_EVIDENCE, default=0)
    """Odometry samples dropped as corrupt or with stamps their neighbours contradict (see
    ``notes``)."""
    worst_odometry_stamp_offset_s: float = field(metadata=_EVIDENCE, default=0.0)
    """The largest distance between a dropped odometry stamp and where the other stamps put it
    [s]; 0 when none was dropped for its stamp."""
    frames_dropped_by_stamp: int = field(metadata=_EVIDENCE, default=0)
    """Colour frames whose stamp their neighbours contradict; their observations are
    dropped."""
    camera_infos_judged: int = field(metadata=_EVIDENCE, default=0)
    """camera_info messages judged."""
    camera_infos_set_aside: int = field(metadata=_EVIDENCE, default=0)
    """Of them, those not believed (see ``camera_info_reasons``)."""
    camera_info_reasons: dict[str, int] = field(metadata=_EVIDENCE, default_factory=dict)
    """Why they were set aside -> how many."""
    marker_sizes_used: MarkerSizes | None = field(metadata=_EVIDENCE, default=None)
    """The markers' sizes the observations were made with, None until :func:`extract` sets
    them (report.json: ``marker_size_m_used`` and ``marker_sizes_m_used``) [m]."""
    marker_size_m_by_depth: float | None = field(metadata=_EVIDENCE, default=None)
    """The markers' size depth measures (the given size times ``marker_size_ratio_by_depth``
    where that clearly disagrees; see :mod:`~markergraph.frontend.marker_size`), None without
    enough depth [m]."""
    marker_size_ratio_by_depth: float | None = field(metadata=_EVIDENCE, default=None)
    """Depth over PnP's range with the given size, None without enough depth."""
    marker_sizes_m_by_depth: dict[int, float] = field(metadata=_EVIDENCE, default_factory=dict)
    """Markers apart from the rest, by id [m]."""
    odometry_evidence: OdometryEvidence | None = field(metadata=_EVIDENCE, default=None)
    """What the odometry's first messages show of its kind (3-D motion, rate, covariance);
    None for odometry from /tf."""

    @property
    def true_markers(self) -> dict[int, gtsam.Pose2]:
        """Ground truth ``T_map_marker`` when the log carries it (simulated logs)."""
        import gtsam  # a simulated log's truth alone needs it: real logs have none

        return {i: gtsam.Pose2(*pose) for i, pose in self.true_marker_poses.items()}

    def mount_origin(self) -> str:
        """Where ``mount`` came from, in words: ``mount_source``, else the settings."""
        return self.mount_source or MOUNT_FROM_SETTINGS

    def input_evidence(self) -> dict[str, Any]:
        """What the front end judged of its inputs, JSON-ready (report.json's ``inputs``): what
        it set aside and what it measured, for a verdict to weigh."""
        evidence: dict[str, Any] = {}
        for f in fields(self):
            if not f.metadata.get("evidence"):
                continue
            value = getattr(self, f.name)
            if f.name == "marker_sizes_used":
                sizes = value or MarkerSizes(0.0)
                evidence["marker_size_m_used"] = sizes.default_m
                evidence["marker_sizes_m_used"] = _json_ready(dict(sizes.by_id))
            else:
                evidence[f.name] = _json_ready(value)
        return evidence


def _json_ready(value: Any) -> Any:
    """A value as JSON holds it: mappings keyed by text, records as mappings."""
    if isinstance(value, dict):
        return {str(k): v for k, v in value.items()}
    if is_dataclass(value) and not isinstance(value, type):
        return asdict(value)
    return value


@dataclass
class Part:
    """One stretch's result before the stretches are joined: odometry and truth as read, in
    log order (bad samples are dropped only once all are joined)."""

    extraction: Extraction
    """The stretch's observations and counts."""
    odometry: OdometryTrack = field(default_factory=OdometryTrack)
    """Odometry samples, in log order (in columns: a log may hold millions)."""
    odometry_log_ns: array[int] = field(default_factory=lambda: array("q"))
    """Each odometry sample's log time [ns]."""
    true_poses: OdometryTrack = field(default_factory=OdometryTrack)
    """Ground-truth base poses, in log order."""
    true_pose_log_ns: array[int] = field(default_factory=lambda: array("q"))
    """Each true pose's log time [ns]."""
    frame_stamps: list[tuple[int, int]] = field(default_factory=list)
    """Each colour frame's (stamp, log time) [ns]."""
    observation_frames: list[tuple[int, int]] = field(default_factory=list)
    """Each observation's frame, as in ``frame_stamps``."""


def merge_parts(parts: list[Part]) -> Part:
    """Stretches' results joined in log order, each field as it says (:class:`Join`)."""
    joined: dict[str, Any] = {}
    for f in fields(Extraction):
        how = f.metadata["join"]
        values = [getattr(p.extraction, f.name) for p in parts]
        if how is Join.FIRST:
            joined[f.name] = values[0]
        elif how is Join.FIRST_SET:
            joined[f.name] = next((v for v in values if v is not None), None)
        elif how is Join.SUM and isinstance(values[0], Counter):
            joined[f.name] = Counter()
            for value in values:
                joined[f.name].update(value)
        elif how is Join.SUM:
            joined[f.name] = sum(values)
        elif how is Join.CONCAT:
            joined[f.name] = [item for value in values for item in value]
        elif how is Join.MERGE:
            joined[f.name] = DecodeFailures.merged(v for v in values if v is not None)
        elif how is Join.UNIQUE:
            joined[f.name] = []
            for value in values:  # what every stretch says is said once
                joined[f.name] += [item for item in value if item not in joined[f.name]]
    merged = Part(Extraction(**joined))
    failures = merged.extraction.read_failures
    merged.extraction.warnings = failures.warnings() if failures is not None else []
    for name in (f.name for f in fields(Part) if f.name != "extraction"):
        values = [getattr(p, name) for p in parts]
        if name in ("odometry", "true_poses"):
            setattr(merged, name, OdometryTrack.joined(values))
        elif name.endswith("_log_ns"):
            setattr(merged, name, array("q", b"".join(v.tobytes() for v in values)))
        else:
            setattr(merged, name, [item for value in values for item in value])
    return merged
