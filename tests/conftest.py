"""Test-wide settings and fixtures: hypothesis runs derandomised, so every run draws the same
examples; the small rendered log several modules damage in their own ways, rendered once; tests
marked ``slow`` run only with ``--slow`` (CI passes it)."""

from pathlib import Path

import pytest
from hypothesis import settings

from markergraph.datasets import scenario, write_log

settings.register_profile("markergraph", derandomize=True, database=None, print_blob=True)
settings.load_profile("markergraph")


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--slow", action="store_true", help="also run the tests marked slow (as CI does)"
    )


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "slow: a test of many seconds; runs only with --slow")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Without ``--slow``, the slow tests are deselected (counted as such), not skipped."""
    if config.getoption("--slow"):
        return
    slow = [item for item in items if item.get_closest_marker("slow")]
    if slow:
        config.hook.pytest_deselected(items=slow)
        items[:] = [item for item in items if not item.get_closest_marker("slow")]


@pytest.fixture(scope="session")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """20 s of the paper room at 5 Hz: 100 JPEG frames with depth, 50 Hz odometry, three
    markers, ground truth. Read it, never write to it: rewrite a copy."""
    path = tmp_path_factory.mktemp("log") / "room.mcap"
    world, route = scenario("paper-room")
    write_log(world, route, path, seed=3, duration_s=20.0, compressed=True, frame_hz=5.0)
    return path


@pytest.fixture(autouse=True)
def no_extraction_cache(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every test reads its logs (a test that patches the front end must not get an earlier
    test's extraction), and none writes to the user's cache folder; tests/test_rerun.py turns
    the cache on, in a folder of its own."""
    monkeypatch.setenv("MARKERGRAPH_NO_CACHE", "1")
