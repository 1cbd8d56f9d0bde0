"""Frames seen and observed in a pool of threads come out as one thread gives them: the same
observations, in log order, and the same counts."""

from __future__ import annotations

from pathlib import Path

import pytest

from markergraph.frontend import pipeline
from markergraph.frontend.pipeline import extract


def test_threads_change_nothing_but_the_time(log: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The paper room read with one thread in the pool and with three: every observation equal
    and in the same order, with the same frames, depth counts and per-marker detections."""
    results = []
    for threads in (1, 3):
        monkeypatch.setattr(pipeline, "available_cores", lambda threads=threads: threads)
        results.append(extract(log, workers=1))
    one, three = results
    assert len(one.observations) > 60
    assert one.observations == three.observations
    assert (one.frames, one.frames_with_depth, one.depth_tries, one.depth_misses) == (
        three.frames, three.frames_with_depth, three.depth_tries, three.depth_misses
    )  # fmt: skip
    assert one.marker_detections == three.marker_detections
    assert one.depth_ratios == three.depth_ratios and one.size_ratios == three.size_ratios
