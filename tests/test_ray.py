"""Fleets on Ray: the front end of many logs as Ray tasks gives what it gives locally, and the map
built from it is the local run's."""

from __future__ import annotations

import dataclasses
import math
import os
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

ray = pytest.importorskip("ray")

from markergraph.common.errors import SettingsError  # noqa: E402
from markergraph.datasets import scenario, write_log  # noqa: E402
from markergraph.estimator import Method, build_frames, estimate_frames  # noqa: E402
from markergraph.executors import Executor, extract_logs  # noqa: E402
from markergraph.frontend import Extraction, FrontendConfig, LogError, extract  # noqa: E402

SEEDS = (1, 2)
SAME_AFTER_PICKLING = 0.0  # the same arithmetic on the same bytes: nothing may differ at all
SAME_AFTER_OPTIMISATION = 1e-9  # the same graph solved twice; GTSAM is deterministic here


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """Two 10 s logs of the paper room at 5 Hz (JPEG colour), different seeds."""
    folder = tmp_path_factory.mktemp("fleet")
    world, route = scenario("paper-room")
    paths = []
    for seed in SEEDS:
        path = folder / f"room-{seed}.mcap"
        write_log(world, route, path, seed=seed, duration_s=10.0, compressed=True, frame_hz=5.0)
        paths.append(path)
    return paths


@pytest.fixture(scope="module")
def garbage(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A file of seeded random bytes named like a log."""
    path = tmp_path_factory.mktemp("bad") / "garbage.mcap"
    path.write_bytes(np.random.default_rng(7).bytes(4096))
    return path


@pytest.fixture(scope="module")
def ray_session() -> Iterator[Any]:
    """One local Ray instance with 2 CPUs for the module (it takes seconds to start)."""
    previous = os.environ.get("RAY_AUTH_MODE")
    os.environ["RAY_AUTH_MODE"] = "disabled"  # a local test instance needs no token
    if ray.is_initialized():
        ray.shutdown()
    ray.init(num_cpus=2, include_dashboard=False)
    try:
        yield ray
    finally:
        ray.shutdown()
        if previous is None:
            os.environ.pop("RAY_AUTH_MODE", None)
        else:
            os.environ["RAY_AUTH_MODE"] = previous


@pytest.fixture(scope="module")
def local(logs: list[Path]) -> list[Extraction]:
    return extract_logs(logs, FrontendConfig())


@pytest.fixture(scope="module")
def on_ray(logs: list[Path], ray_session: Any) -> list[Extraction]:
    return extract_logs(logs, FrontendConfig(), executor="ray")


def assert_same_extraction(a: Extraction, b: Extraction) -> None:
    """Equal field by field: observations (NaN heights equal), odometry and truth exactly."""
    assert len(a.observations) == len(b.observations) > 0
    for o, p in zip(a.observations, b.observations, strict=True):
        for f in dataclasses.fields(o):
            x, y = getattr(o, f.name), getattr(p, f.name)
            if isinstance(x, float) and math.isnan(x):
                assert isinstance(y, float) and math.isnan(y), (f.name, x, y)
            else:
                assert x == y, (f.name, x, y)
    for path_a, path_b in ((a.odometry, b.odometry), (a.true_path, b.true_path)):
        assert path_a.frame == path_b.frame
        np.testing.assert_array_equal(path_a.t_ns, path_b.t_ns)
        np.testing.assert_array_equal(path_a.poses, path_b.poses)
    assert len(a.odometry) > 0
    assert a.true_markers.keys() == b.true_markers.keys()
    for i, T in a.true_markers.items():
        assert T.equals(b.true_markers[i], SAME_AFTER_PICKLING)
    assert (a.camera, a.mount, a.topics) == (b.camera, b.mount, b.topics)
    assert (a.frames, a.frames_with_depth, a.skipped) == (b.frames, b.frames_with_depth, b.skipped)
    assert (a.notes, a.warnings) == (b.notes, b.warnings)
    assert (a.depth_scale, a.measured_depth_scale) == (b.depth_scale, b.measured_depth_scale)


@pytest.mark.slow
def test_ray_extractions_equal_local_ones(local: list[Extraction], on_ray: list[Extraction]):
    """Ray tasks give the local executor's extractions, in the order of the logs."""
    assert len(on_ray) == len(local) == len(SEEDS)
    for a, b in zip(local, on_ray, strict=True):
        assert_same_extraction(a, b)
    assert local[0].observations != local[1].observations  # the order is the logs' own


@pytest.mark.slow
def test_every_executor_equals_extract_alone(
    logs: list[Path], local: list[Extraction], on_ray: list[Extraction]
):
    """Each log's extraction is what ``extract`` gives it alone; a process per log too."""
    in_processes = extract_logs(logs, FrontendConfig(), workers=2)
    for path, a, b, c in zip(logs, local, on_ray, in_processes, strict=True):
        alone = extract(path, FrontendConfig())
        for other in (a, b, c):
            assert_same_extraction(alone, other)


def test_map_from_ray_equals_local_map(local: list[Extraction], on_ray: list[Extraction]):
    """SLAM on a Ray extraction puts every marker where it puts it from the local one."""
    estimates = []
    for extraction in (local[0], on_ray[0]):
        frames = build_frames(extraction.observations, extraction.odometry)
        estimates.append(estimate_frames(frames, Method.SLAM, extraction.mount.T_base_camera))
    a, b = estimates
    assert len(a.markers) >= 2
    assert a.markers.keys() == b.markers.keys()
    for i, marker in a.markers.items():
        other = b.markers[i]
        assert marker.T_map_marker.equals(other.T_map_marker, SAME_AFTER_OPTIMISATION)
        assert marker.covariance is not None and other.covariance is not None
        np.testing.assert_allclose(
            marker.covariance, other.covariance, rtol=0, atol=SAME_AFTER_OPTIMISATION
        )
    np.testing.assert_allclose(
        a.trajectory.poses, b.trajectory.poses, rtol=0, atol=SAME_AFTER_OPTIMISATION
    )


def test_bad_log_raises_log_error_naming_it_under_ray(
    logs: list[Path], garbage: Path, ray_session: Any
):
    """A log of garbage raises the front end's LogError naming it, unwrapped from Ray's error,
    with the local run's message."""
    with pytest.raises(LogError) as local_error:
        extract_logs([logs[0], garbage], FrontendConfig())
    with pytest.raises(LogError) as ray_error:
        extract_logs([logs[0], garbage], FrontendConfig(), executor=Executor.RAY)
    assert type(ray_error.value) is LogError  # not Ray's RayTaskError(LogError)
    assert str(garbage) in str(ray_error.value)
    assert str(ray_error.value) == str(local_error.value)
    assert len(str(ray_error.value).splitlines()) == 1


def test_ray_progress_counts_logs(logs: list[Path], ray_session: Any):
    """Progress is called once per log, with (logs done, logs in all), ending at all."""
    calls: list[tuple[int, int]] = []
    extract_logs(logs, FrontendConfig(), executor="ray", progress=lambda d, n: calls.append((d, n)))
    assert calls == [(1, 2), (2, 2)]


def test_missing_ray_says_how_to_install_it(logs: list[Path], monkeypatch: pytest.MonkeyPatch):
    """Without the ``ray`` package, one line saying which extra to install."""
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` now raises ImportError
    with pytest.raises(SettingsError) as error:
        extract_logs(logs, FrontendConfig(), executor="ray")
    assert 'pip install "markergraph[ray]"' in str(error.value)
    assert len(str(error.value).splitlines()) == 1


@pytest.mark.parametrize(
    ("arguments", "named"), [({"executor": "dask"}, "'dask'"), ({"workers": 0}, "0")]
)
def test_bad_executor_arguments_are_settings_errors(
    logs: list[Path], arguments: dict[str, Any], named: str
):
    """An unknown executor or no workers is refused, naming the value."""
    with pytest.raises(SettingsError, match=named):
        extract_logs(logs, FrontendConfig(), **arguments)
