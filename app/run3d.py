"""The 3-D map as a library call: a log of tag detections or images, with or without odometry,
to every tag's full pose (:func:`~markergraph.estimator.tag_slam.map_tags`), and its wall tags
as the 2-D map from the same solution.

``dimensions = "auto"`` maps a log of tag detections in 3-D (with or without odometry), a log of
images without odometry too, and a log of images with odometry in 2-D, saying so in a note.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import gtsam
import numpy as np

from markergraph.common import EstimationError, Note, SettingsError
from markergraph.common.notes import some_of
from markergraph.datasets.scene3d import TRUE_WORLD3D, read_scene3d_truth
from markergraph.estimator import Method
from markergraph.estimator.tag_scale import (
    ODOMETRY_SCALE_KIND,
    ODOMETRY_SCALE_OFF,
    size_factor_by_odometry,
)
from markergraph.estimator.tag_slam import map_tags
from markergraph.estimator.tags3d import KnownTag, TagMap3d, TagScene
from markergraph.frontend import Log, open_log
from markergraph.frontend.logs import LogError
from markergraph.frontend.survey import TagRemap, read_survey
from markergraph.frontend.tag_scene import read_tag_scene
from markergraph.frontend.topics import choose_topics
from markergraph.markermap import MarkerMap
from markergraph.results3d import Map3dRun
from markergraph.settings import SETTINGS, MapConfig
from markergraph.verdicts import judge_tag_map

__all__ = ["MOUNT_SEED_SIGMAS", "map_log_3d", "wants_3d"]

MOUNT_SEED_SIGMAS = np.array([0.1, 0.1, 0.1, 0.05, 0.05, 0.05])
"""How far a seeded mount may move (rotation [rad], translation [m]): about 6 deg and 5 cm."""

Stage = Callable[[str], None]


def wants_3d(log: Path, config: MapConfig) -> tuple[bool, Note | None]:
    """Whether ``log`` is mapped in 3-D, and the note saying why when the data chose: a log of
    tag detections is (its corners give each tag's full pose, and its wall tags' 2-D map
    comes from the same solution), and so is a log of images without odometry; a log of images
    with odometry stays 2-D.

    Raises:
        LogError: the log cannot be read.
    """
    if config.dimensions != "auto":
        return config.dimensions == "3", None
    opened = open_log(log)
    choice = choose_topics(opened.path, opened.topics, config.frontend)
    images = not choice.detections or choice.color is not None
    if images and (choice.odom or choice.color is None):
        return False, None  # a log of images with odometry: the 2-D map of a wheeled robot
    if images:
        text = f"{log}: a log of images without odometry: mapped in 3-D from the tags alone"
    else:
        how = "with its odometry" if choice.odom else "from the tags alone"
        text = f"{log}: a log of tag detections: mapped in 3-D {how}"
    text += (
        ", its wall tags the 2-D map (--dimensions 2 for the 2-D estimators, which need odometry)"
    )
    return True, Note("map.dimensions", text)


def _surveys(
    config: MapConfig,
) -> tuple[list[KnownTag], frozenset[int], list[Note], tuple[TagRemap, ...]]:
    """The surveyed tags of ``--survey`` and of ``tagslam.yaml`` (the survey file wins where
    both place a tag), the ids to leave out, and the notes of reading them."""
    tags: dict[int, KnownTag] = {}
    ignored: set[int] = set()
    notes: list[Note] = []
    remaps: tuple[TagRemap, ...] = ()
    for path in (config.rig.tagslam, config.rig.survey):
        if path is None:
            continue
        survey = read_survey(path)
        remaps += survey.remaps
        tags.update({t.tag_id: t for t in survey.tags})
        ignored |= survey.ignored_ids
        notes += survey.notes
        if survey.tags:
            notes.append(Note("survey.tags", f"{path}: {len(survey.tags)} surveyed tags held "
                              "by their stated noise", str(path), len(survey.tags)))  # fmt: skip
    return [tags[i] for i in sorted(tags)], frozenset(ignored), notes, remaps


def _seeded(scene: TagScene) -> TagScene:
    cameras = [
        c if c.T_rig_camera is None else replace(c, sigmas=MOUNT_SEED_SIGMAS) for c in scene.cameras
    ]
    return replace(scene, cameras=cameras)


def map_log_3d(
    log: Path, config: MapConfig, *, notes: list[Note] | None = None, stage: Stage | None = None
) -> Map3dRun:
    """The 3-D map of a log of tag detections.

    Raises:
        LogError: no tag detections in the log, or none with its camera's intrinsics.
        SettingsError: a method that makes no 3-D map, or a rig or survey file that cannot be read.
        EstimationError: nothing to map, or a graph that cannot be solved.
    """
    stage = stage or (lambda name: None)
    if len(config.methods) == 1 and config.methods[0] not in (Method.SLAM, Method.ISAM2):
        raise SettingsError(
            f"--method {config.methods[0].value}: a 3-D map is made by slam (the paper's forms, "
            "the marker graph and the EKF are 2-D; isam2 solves it incrementally)"
        )
    seconds: dict[str, float] = {}
    start = time.perf_counter()
    stage(f"reading {Path(log).name}")
    opened = open_log(log)
    choice = choose_topics(opened.path, opened.topics, config.frontend)
    if not choice.detections and choice.color is None:
        raise LogError(
            f"{log}: a 3-D map is made from tag detections or images; this log has neither"
        )
    known, ignored, survey_notes, remaps = _surveys(config)
    read = read_tag_scene(opened, config.frontend, choice, known, ignored, config.home_id, remaps)
    scene = _seeded(read.scene) if config.rig.seed_mounts else read.scene
    seconds["front end"] = time.perf_counter() - start
    method = Method.ISAM2 if config.methods == (Method.ISAM2,) else Method.SLAM
    stage(f"estimating: 3-D tag map ({method.value})")
    start = time.perf_counter()
    try:
        tag_map = map_tags(scene, incremental=method is Method.ISAM2)
    except EstimationError as error:
        raise EstimationError(f"{log}: {error}") from None
    seconds[method.value] = time.perf_counter() - start
    size_notes = _size_by_odometry(scene, tag_map, method)
    skipped = [
        Note("views.skipped", f"skipped: {count:,} {reason}", figure=count)
        for reason, count in sorted(read.skipped.items())
    ]
    marker_map = MarkerMap.from_tag_map(
        tag_map, log=str(log), dictionary=config.dictionary,
        marker_size_m=config.marker_sizes.default_m, method=method.value,
    )  # fmt: skip
    tags_seen = len({v.tag_id for v in scene.views})
    return Map3dRun(
        Path(log), config, tag_map, marker_map, len(scene.frame_times), read.views_read,
        [*(notes or []), *read.notes, *_size_note(scene, config), *size_notes, *survey_notes,
         *skipped,
         *(Note("log.unreadable", text) for text in read.warnings)], seconds,
        truth=_truth(opened), tags_seen=tags_seen, judgement=judge_tag_map(tag_map, tags_seen),
    )  # fmt: skip


_DEFAULT_SIZE_M = next(s.default for s in SETTINGS if s.key == "marker_size")


def _size_note(scene: TagScene, config: MapConfig) -> list[Note]:
    """That the map's scale rests on the one size every tag no file or flag sizes takes (the
    2-D map says it of its given size too): a tag's corners alone cannot tell 0.2 m from
    0.42 m, and the map scales with it (figure: the tags)."""
    sizes = config.marker_sizes
    unsized = sorted(i for i in scene.tag_sizes if i not in sizes.by_id)
    if not unsized:
        return []
    shown = some_of(unsized, 8)
    text = (
        f"the map's scale rests on the marker size {sizes.default_m:g} m (--marker-size, "
        f"{_DEFAULT_SIZE_M:g} m unless set; a tagslam.yaml's default_tag_size) that tag"
        f"{'s' if len(unsized) > 1 else ''} {shown} take{'' if len(unsized) > 1 else 's'}: "
        "the corners cannot tell one size from another, and the map scales with it"
    )
    return [Note("marker_size.given", text, figure=len(unsized))]


def _size_by_odometry(scene: TagScene, tag_map: TagMap3d, method: Method) -> list[Note]:
    """Where the odometry and the map disagree on the scale, the tags' size the odometry agrees
    with (the map solved again at sizes until the two agree), said with the flag that maps at
    it; the map itself stays at the given sizes."""
    ratio = next((n.figure for n in tag_map.notes if n.kind == ODOMETRY_SCALE_KIND), None)
    if ratio is None or abs(ratio - 1.0) <= ODOMETRY_SCALE_OFF:
        return []

    def solve(sized: TagScene) -> list[Note]:
        try:
            return map_tags(sized, incremental=method is Method.ISAM2).notes
        except EstimationError:
            return []

    factor = size_factor_by_odometry(scene, ratio, solve)
    if factor is None:
        return []
    sizes = sorted(set(scene.tag_sizes.values()))
    if len(sizes) == 1:
        measured = sizes[0] * factor
        text = (
            f"by the odometry the tags measure about {measured:.3f} m, not the {sizes[0]:g} m "
            f"given (the map solved again at sizes until the two agree); if the odometry is "
            f"metric, --marker-size {measured:.3f} maps them at it"
        )
    else:
        text = (
            f"by the odometry the tags measure about {factor:.3f} times their given sizes (the "
            "map solved again at sizes until the two agree)"
        )
    return [Note("odometry.tag_size", text, figure=factor)]


def _truth(log: Log) -> dict[int, gtsam.Pose3] | None:
    """The tags' true poses a simulated log carries, else None."""
    if not any(t.topic == TRUE_WORLD3D for t in log.topics):
        return None
    return dict(read_scene3d_truth(log.path).tags)
