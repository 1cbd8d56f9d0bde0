"""A dictionary too small for the log's markers is said, not silent: OpenCV's DICT_4X4_50 is the
first 50 markers of DICT_4X4_1000, so markers of a larger one are read as nothing at all; the
front end checks one frame in CHECK_EVERY with the family's largest dictionary."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

import markergraph as mg
from markergraph.datasets import scenario, write_log
from markergraph.datasets.route import Look
from markergraph.frontend import FrontendConfig, extract
from markergraph.frontend.dictionary_check import MIN_FRAMES, larger_dictionary


@pytest.mark.parametrize(
    ("given", "larger"),
    [
        ("DICT_4X4_50", "DICT_4X4_1000"),
        ("DICT_5X5_100", "DICT_5X5_1000"),
        ("DICT_6X6_250", "DICT_6X6_1000"),
        ("DICT_7X7_50", "DICT_7X7_1000"),
        ("DICT_4X4_1000", None),
        ("DICT_APRILTAG_36h11", None),
        ("DICT_ARUCO_ORIGINAL", None),
    ],
)
def test_a_dictionary_is_the_first_markers_of_its_larger_family(given, larger) -> None:
    """The larger family named is one whose first markers are exactly the given dictionary's
    (OpenCV's own code lists), so an id beyond the given size is a marker it cannot read."""
    assert larger_dictionary(given) == larger
    if larger is not None:
        small, big = (
            cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name)).bytesList
            for name in (given, larger)
        )
        np.testing.assert_array_equal(big[: len(small)], small)


@pytest.fixture(scope="module")
def log_of_larger_ids(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, set[int]]:
    """The paper room for 30 s with its markers in DICT_4X4_250, the charger's id 200 (rendered
    as such; the others keep ids under 50, the same markers in DICT_4X4_50), and that id."""
    world, route = scenario("paper-room")
    ids = {2: 200}
    markers = tuple(
        replace(m, id=ids.get(m.id, m.id), dictionary="DICT_4X4_250") for m in world.markers
    )
    steps = tuple(
        replace(s, marker_id=ids[s.marker_id]) if isinstance(s, Look) and s.marker_id in ids else s
        for s in route.steps
    )
    log = tmp_path_factory.mktemp("dictionary") / "larger-ids.mcap"
    write_log(replace(world, markers=markers), replace(route, steps=steps), log, seed=4,
              duration_s=30.0, compressed=True, frame_hz=5.0)  # fmt: skip
    return log, set(ids.values())


@pytest.mark.slow
def test_markers_beyond_the_dictionary_are_said_and_make_the_map_suspect(
    log_of_larger_ids,
) -> None:
    """Read as DICT_4X4_50, the log's marker 200 is found by the check (and nothing else is),
    a note names it and a dictionary that holds it, and the map of the other two is suspect for
    it; read as DICT_4X4_250, every marker is mapped and nothing is said."""
    log, larger_ids = log_of_larger_ids
    small = extract(log, FrontendConfig(dictionary="DICT_4X4_50"))
    seen = {i for i, frames in small.ids_beyond_dictionary.items() if frames >= MIN_FRAMES}
    assert seen == larger_ids
    assert small.dictionary_checks >= 2 * MIN_FRAMES
    (note,) = [n for n in small.notes if n.kind == "dictionary.too_small"]
    assert "(ids 200;" in note.text and "--dictionary DICT_4X4_250" in note.text
    assert {o.marker_id for o in small.observations} == {0, 1}
    run = mg.map_log(log, mg.MapConfig.from_values({"dictionary": "DICT_4X4_50"}))
    assert run.judgement.verdict.value == "suspect"
    assert "dictionary" in {r.check for r in run.judgement.reasons}
    whole = extract(log, FrontendConfig(dictionary="DICT_4X4_250"))
    assert not whole.ids_beyond_dictionary
    assert not [n for n in whole.notes if n.kind == "dictionary.too_small"]
    assert {o.marker_id for o in whole.observations} == {0, 1} | larger_ids
    clean = mg.map_log(log, mg.MapConfig.from_values({"dictionary": "DICT_4X4_250"}))
    assert "dictionary" not in {r.check for r in clean.judgement.reasons}
