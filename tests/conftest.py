"""Test-wide settings and fixtures: hypothesis runs derandomised, so every run draws the same
examples; the small rendered log several modules damage in their own ways, rendered once; tests
marked ``slow`` run only with ``--slow`` (CI passes it); tests marked ``alone`` run while no other
test does (pytest-xdist runs the rest a file to a worker, a worker a core)."""

import os
import tempfile
from collections.abc import Generator, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from hypothesis import settings

from markergraph.datasets import scenario, write_log

settings.register_profile("markergraph", derandomize=True, database=None, print_blob=True)
settings.load_profile("markergraph")


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--slow", action="store_true", help="also run the tests marked slow (as CI does)"
    )


TURNS = "markergraph_turns"  # the workers' input naming the run's turns file (:func:`_turn`)


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "slow: a test of many seconds; runs only with --slow")
    config.addinivalue_line(
        "markers", "alone: runs while no other test does (it measures the machine's idle cores)"
    )
    if config.pluginmanager.hasplugin("xdist") and not hasattr(config, "workerinput"):
        config.pluginmanager.register(_TurnsFile(config), "markergraph-turns")


class _TurnsFile:
    """pytest-xdist's controller's part: the run's turns file, made now, named to each worker
    as it starts and removed when the run ends (a nested run, or a second one in the same
    process, makes its own)."""

    def __init__(self, config: pytest.Config) -> None:
        handle, self.path = tempfile.mkstemp(prefix="markergraph-test-turns-")
        os.close(handle)
        config.add_cleanup(lambda: os.unlink(self.path))

    def pytest_configure_node(self, node: Any) -> None:
        node.workerinput[TURNS] = self.path


@pytest.hookimpl(wrapper=True)
def pytest_runtest_protocol(item: pytest.Item) -> Generator[None, object, object]:
    """Each test, its fixtures' set-up and tear-down included, in its turn among the workers'
    (in one process the tests take turns anyway)."""
    turns = getattr(item.config, "workerinput", {}).get(TURNS)
    if turns is None:
        return (yield)
    with _turn(turns, alone=item.get_closest_marker("alone") is not None):
        return (yield)


@contextmanager
def _turn(turns_file: str, alone: bool) -> Iterator[None]:
    """A test's turn among the workers' (POSIX locks on two bytes of the turns file): each
    takes the gate (byte 0), then a share of the running lock (byte 1) and lets the gate go. A
    test that runs alone keeps the gate, so no other test starts, and waits for the running
    lock whole, so every test running ends first. Closing the file ends the turn. A module's
    fixture already made in another worker lives on meanwhile (the Ray instance of
    tests/test_ray.py): an ``alone`` test still checks that the cores are idle."""
    try:
        import fcntl
    except ImportError:  # no POSIX locks (Windows): the tests run as they come
        yield
        return
    with open(turns_file, "r+b") as turns:
        fcntl.lockf(turns, fcntl.LOCK_EX, 1, 0)
        fcntl.lockf(turns, fcntl.LOCK_EX if alone else fcntl.LOCK_SH, 1, 1)
        if not alone:
            fcntl.lockf(turns, fcntl.LOCK_UN, 1, 0)
        yield


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Without ``--slow``, the slow tests are deselected, not skipped (pytest-xdist's workers do
    it, so only ``-n 0`` counts them in the summary)."""
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
