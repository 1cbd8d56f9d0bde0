"""Misread ids: sightings that carry one marker's id where another stands are found and left
out, against the simulator's truth of which sightings were relabelled."""

from __future__ import annotations

from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from markergraph.datasets import scenario, simulate_fast
from markergraph.datasets.simulate import SimulatedRun
from markergraph.estimator import (
    Method,
    Misread,
    Observation,
    Trajectory,
    build_frames,
    describe_misreads,
    estimate,
    map_error,
    misread_observations,
)
from markergraph.frontend import Extraction
from markergraph.frontend.topics import TopicChoice
from markergraph.prepare import prepare
from markergraph.settings import MapConfig

PHANTOM_ID = 49  # in DICT_4X4_50, and not in the corridor loop's world


@pytest.fixture(scope="module")
def run() -> SimulatedRun:
    world, route = scenario("corridor-loop")
    return simulate_fast(world, route, seed=7)


def found(run: SimulatedRun, observations: list[Observation]) -> list[Misread]:
    home = run.observations[0].marker_id  # the clean log's first, whatever is relabelled
    frames = build_frames(observations, run.odometry, home, odometry_noise=run.odometry_noise)
    return misread_observations(frames, run.mount.T_base_camera)


def relabelled(
    run: SimulatedRun, stands_on: int, read_as: int, count: int
) -> tuple[list[Observation], set[tuple[int, int]]]:
    """``count`` sightings of ``stands_on``, spread over the log and in frames where ``read_as``
    is not seen, given ``read_as``'s id and the ``small`` flag (ids are misread at a few
    pixels a module); and their (stamp, id)."""
    frames_with = {o.t_ns for o in run.observations if o.marker_id == read_as}
    candidates = [
        i
        for i, o in enumerate(run.observations)
        if o.marker_id == stands_on and o.t_ns not in frames_with
    ]
    chosen = candidates[:: max(1, len(candidates) // count)][:count]
    observations = list(run.observations)
    for i in chosen:
        observations[i] = replace(observations[i], marker_id=read_as, flags=frozenset({"small"}))
    return observations, {(observations[i].t_ns, read_as) for i in chosen}


def busiest_and_far(run: SimulatedRun) -> tuple[int, int]:
    """The most-seen marker, and a marker seen often and far from it (their sightings cannot
    overlap)."""
    counts = Counter(o.marker_id for o in run.observations)
    (busiest, _), *rest = counts.most_common()
    true = run.true_markers()
    far = max(
        (m for m, n in rest if n >= 20),
        key=lambda m: float(np.linalg.norm(true[m].translation() - true[busiest].translation())),
    )
    return busiest, far


def test_a_clean_log_has_no_misreads(run: SimulatedRun) -> None:
    """Every sighting's id is right in the simulator: none is taken for a misread."""
    assert found(run, run.observations) == []


def test_stray_sightings_and_a_phantom_are_found_and_named(run: SimulatedRun) -> None:
    """Three sightings of the most-seen marker read as a marker seen elsewhere, and two read
    as an id that is nowhere: exactly those five are found, each on the marker it stands on;
    left out, the map is as good as the clean log's."""
    busiest, far = busiest_and_far(run)
    true = run.true_markers()
    observations, stray = relabelled(run, busiest, far, 3)
    run_with_stray = replace(run, observations=observations)
    observations, phantom = relabelled(run_with_stray, busiest, PHANTOM_ID, 2)

    misreads = found(run, observations)

    assert {(m.t_ns, m.read_as) for m in misreads} == stray | phantom
    assert {m.stands_on for m in misreads} == {busiest}
    text = describe_misreads(misreads)
    assert f"3 read as marker {far} where marker {busiest} stands" in text
    assert f"2 read as marker {PHANTOM_ID} where marker {busiest} stands" in text

    def rmse(observations: list[Observation]) -> float:
        result = estimate(observations, run.odometry, Method.SLAM,
                          T_base_camera=run.mount.T_base_camera,
                          odometry_noise=run.odometry_noise,
                          home_id=run.observations[0].marker_id)  # fmt: skip
        return map_error(result, true).rmse_position_m

    left_out = {(m.t_ns, m.read_as) for m in misreads}
    kept = [o for o in observations if (o.t_ns, o.marker_id) not in left_out]
    clean = rmse(run.observations)
    assert rmse(kept) == pytest.approx(clean, abs=5e-3)  # five good sightings fewer
    assert rmse(observations) > clean + 0.01  # what leaving them out saves


def test_an_id_seen_only_small_and_in_two_places_is_left_out(run: SimulatedRun) -> None:
    """An id seen twice, small, once on a marker and once where no marker stands, 10 sigma
    apart: neither sighting can be trusted, and both are left out."""
    counts = Counter(o.marker_id for o in run.observations)
    (busiest, _), *_ = counts.most_common()
    observations, misread = relabelled(run, busiest, PHANTOM_ID, 2)
    small = frozenset({"small"})
    first = True
    for i, o in enumerate(observations):
        if o.marker_id == PHANTOM_ID:
            # The second sighting three times as far: it lands where no marker is.
            observations[i] = replace(o, flags=small, range_m=o.range_m * (1.0 if first else 3.0))
            first = False

    misreads = found(run, observations)

    assert {(m.t_ns, m.read_as) for m in misreads} == misread
    assert {m.stands_on for m in misreads} == {None}
    assert f"the 2 of marker {PHANTOM_ID}, seen only small and 10 sigma apart" in (
        describe_misreads(misreads)
    )


def test_a_marker_never_seen_readable_is_left_out_whole(run: SimulatedRun) -> None:
    """Every sighting of one marker flagged ``tiny`` (modules under 2 px): all of them are
    left out, wherever they land; flag all but one, and none is."""
    counts = Counter(o.marker_id for o in run.observations)
    marker = next(m for m, n in counts.most_common() if m != run.observations[0].marker_id)
    tiny = frozenset({"tiny", "small"})
    flagged = [replace(o, flags=tiny) if o.marker_id == marker else o for o in run.observations]

    misreads = found(run, flagged)

    assert {(m.t_ns, m.read_as) for m in misreads} == {
        (o.t_ns, marker) for o in run.observations if o.marker_id == marker
    }
    assert {m.kind for m in misreads} == {"unreadable"}
    assert f"the {counts[marker]} of marker {marker}, never seen at 2 px a module" in (
        describe_misreads(misreads)
    )
    first = next(i for i, o in enumerate(run.observations) if o.marker_id == marker)
    flagged[first] = run.observations[first]  # one readable sighting
    assert found(run, flagged) == []


@pytest.mark.parametrize(("side_px", "tiny"), [(11.9, True), (12.1, False), (30.0, False)])
def test_tiny_flags_modules_under_two_pixels(side_px: float, tiny: bool) -> None:
    """A 4x4 marker (6 modules with its border) is ``tiny`` below 12 px a side."""
    from markergraph.frontend.camera import Camera
    from markergraph.frontend.detect import marker_modules
    from markergraph.frontend.observe import Flags, corner_flags

    camera = Camera()
    square = np.array([[0, 0], [side_px, 0], [side_px, side_px], [0, side_px]]) + 200.0
    flags = corner_flags(square, camera, marker_modules("DICT_4X4_50"))
    assert (Flags.TINY in flags) is tiny
    assert (Flags.SMALL in flags) is (side_px < 20.0)


def test_only_small_sightings_are_taken_for_misread(run: SimulatedRun) -> None:
    """The same stray sightings without the ``small`` flag are kept: a marker of 20 px or
    more is read surely, and a real neighbour seen only at grazing angles can land on another
    (TagSLAM's stairs recording)."""
    busiest, far = busiest_and_far(run)
    observations, stray = relabelled(run, busiest, far, 3)
    assert {(m.t_ns, m.read_as) for m in found(run, observations)} == stray
    large = [replace(o, flags=frozenset()) if "small" in o.flags else o for o in observations]
    assert found(run, large) == []


def test_a_second_preparation_leaves_out_the_first_ones_misreads_without_searching(
    run: SimulatedRun,
) -> None:
    """The log made ready again under another sensor setting (the longest readout, for its
    share of the covariances) leaves out exactly the sightings the first preparation found
    misread, by their place in the log, and does not search again: the two maps then use the
    same sightings."""
    busiest, far = busiest_and_far(run)
    observations, stray = relabelled(run, busiest, far, 3)
    extraction = Extraction(
        observations, Trajectory.from_samples(run.odometry), None, run.mount,
        TopicChoice(None, None, None, "/odom", None), frames=len(run.frame_t_ns),
    )  # fmt: skip
    settings = {"camera.delay_ms": 0.0, "odometry.scale": 1.0}
    home = run.observations[0].marker_id
    first = prepare(Path("sim.mcap"), extraction, MapConfig.from_values(settings), home_id=home)
    stages: list[str] = []
    longest = MapConfig.from_values({**settings, "camera.readout_ms": 33.3})
    second = prepare(Path("sim.mcap"), extraction, longest, stages.append, home, misreads_of=first)

    at = {i for i, o in enumerate(observations) if (o.t_ns, o.marker_id) in stray}
    assert first.misread_at == second.misread_at == at
    assert len(second.observations) == len(observations) - 3
    assert not any("misread" in stage for stage in stages)
    assert "observations.misread_ids" in {note.kind for note in second.notes}
