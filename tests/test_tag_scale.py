"""A 3-D tag map's scale against its odometry's (``estimator/tag_scale.py``): tags given the
wrong size make a map the wrong size, which a tag's corners cannot show and metric odometry
can. Simulated rig in a corridor with drifting odometry, against the simulator's true sizes."""

from __future__ import annotations

import numpy as np
import pytest

from markergraph.datasets.scene3d import detections, make_scene3d, odometry3d, tag_scene
from markergraph.estimator.tag_scale import (
    ODOMETRY_SCALE_KIND,
    resized,
    size_factor_by_odometry,
)
from markergraph.estimator.tag_slam import map_tags
from markergraph.verdicts import judge_tag_map

GIVEN_OVER_TRUE = 0.7  # the tags given 0.7 times their size: 11.2 cm for the simulator's 16


@pytest.fixture(scope="module")
def corridor():
    truth = make_scene3d(1, kind="corridor", frames=300)
    return tag_scene(truth, detections(truth, 1), odometry=odometry3d(truth, 1))


def _ratio(tag_map) -> float:
    (figure,) = [n.figure for n in tag_map.notes if n.kind == ODOMETRY_SCALE_KIND]
    return float(figure)


def test_resized_scales_sizes_and_seeds_and_keeps_the_corners(corridor) -> None:
    """Exact algebra: every size and every seed's translation times the factor; rotations and
    the corners' rays as they were."""
    twice = resized(corridor, 2.0)
    assert twice.tag_sizes == {i: 2.0 * s for i, s in corridor.tag_sizes.items()}
    for before, after in zip(corridor.views, twice.views, strict=True):
        np.testing.assert_array_equal(after.rays, before.rays)
        assert after.T_camera_tag.rotation().equals(before.T_camera_tag.rotation(), 0.0)
        np.testing.assert_allclose(
            after.T_camera_tag.translation(), 2.0 * before.T_camera_tag.translation(), rtol=1e-15
        )


@pytest.mark.slow
def test_tags_at_their_size_agree_with_the_odometry(corridor) -> None:
    """At the true sizes the odometry moves the rig as far as the map does (within 1 %), and
    the verdict has nothing to say of the scale."""
    tag_map = map_tags(corridor)
    assert _ratio(tag_map) == pytest.approx(1.0, abs=0.01)
    judgement = judge_tag_map(tag_map, len({v.tag_id for v in corridor.views}))
    assert not [r for r in judgement.reasons if r.check == "odometry_scale"]


@pytest.mark.slow
def test_tags_given_the_wrong_size_are_flagged_and_their_size_measured(corridor) -> None:
    """Given 0.7 times their size, the map is 0.7 times too small: the odometry moves the rig
    1/0.7 times as far (within 3 %), the verdict is suspect, and the maps solved again at
    other sizes find the true one within 2 %."""
    given = resized(corridor, GIVEN_OVER_TRUE)
    tag_map = map_tags(given)
    ratio = _ratio(tag_map)
    assert ratio == pytest.approx(1 / GIVEN_OVER_TRUE, rel=0.03)
    judgement = judge_tag_map(tag_map, len({v.tag_id for v in given.views}))
    assert judgement.verdict.value == "suspect"
    assert [r for r in judgement.reasons if r.check == "odometry_scale"]
    factor = size_factor_by_odometry(given, ratio, lambda scene: map_tags(scene).notes)
    assert factor is not None and factor == pytest.approx(1 / GIVEN_OVER_TRUE, rel=0.02)
