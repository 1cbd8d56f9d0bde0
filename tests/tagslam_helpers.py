"""TagSLAM's regression tests (``../shared/data/tagslam-test``) read as markergraph reads them,
shared by the 3-D test modules."""

from __future__ import annotations

from pathlib import Path

from markergraph.estimator.tags3d import TagScene

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "tagslam-test" / "tests"


def recorded_scene(folder: Path, work: Path) -> TagScene:
    """The tag detections of one TagSLAM test, with its cameras, mounts and surveyed tags."""
    from markergraph.datasets.tagslam import unpacked
    from markergraph.frontend import open_log
    from markergraph.frontend.survey import read_survey
    from markergraph.frontend.tag_scene import read_tag_scene
    from markergraph.frontend.topics import choose_topics
    from markergraph.settings import MapConfig

    config = MapConfig.from_values(
        {
            "dictionary": "DICT_APRILTAG_36h11",
            "rig.cameras": str(folder / "cameras.yaml"),
            "rig.camera_poses": str(folder / "camera_poses.yaml"),
            "rig.tagslam": str(folder / "tagslam.yaml"),
        }
    )
    log = open_log(unpacked(folder, "tag_detections", work))
    choice = choose_topics(log.path, log.topics, config.frontend)
    survey = read_survey(folder / "tagslam.yaml")
    return read_tag_scene(log, config.frontend, choice, list(survey.tags)).scene
