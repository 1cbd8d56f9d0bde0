"""Many logs' front ends in parallel: in local processes, or as tasks on a Ray cluster.

The front end (decode, detect, observe) is the costly part of mapping a log and each log's is
independent of every other's, so it is what a fleet spreads out: one task per log. The
estimation, which joins the logs, stays with the caller (the driver). Both executors return the
same :class:`~markergraph.frontend.Extraction` s, field by field, in the order of the logs.

Ray is an optional extra (``pip install "markergraph[ray]"``) imported only when chosen.
"""

from __future__ import annotations

import importlib
import os
from collections.abc import Callable, Sequence
from concurrent.futures import Future, as_completed
from enum import Enum
from pathlib import Path
from types import ModuleType
from typing import Any

from markergraph.common.errors import MarkerGraphError, SettingsError
from markergraph.common.pool import MIN_FRAMES_PER_WORKER, choose_workers, process_pool
from markergraph.frontend import Extraction, FrontendConfig, extract

# The front end's own worker set-up (one OpenCV thread; the pool adds a watchdog that ends the
# worker when its parent dies): the same safety for a process per log as for a process per
# stretch.
from markergraph.frontend.spans import one_opencv_thread

__all__ = ["Executor", "extract_logs"]

RAY_MISSING = '--executor ray needs Ray, an optional extra: pip install "markergraph[ray]"'


class Executor(Enum):
    """Where the front end of each log runs."""

    LOCAL = "local"
    """This machine: one log after another, or a process per log (``spawn``ed)."""
    RAY = "ray"
    """A Ray cluster (or a Ray instance started here): one task per log."""


def extract_logs(
    logs: Sequence[Path],
    config: FrontendConfig,
    *,
    executor: Executor | str = Executor.LOCAL,
    address: str | None = None,
    workers: int | None = 1,
    progress: Callable[[int, int], None] | None = None,
) -> list[Extraction]:
    """The front end (:func:`markergraph.frontend.extract`) of each log, one task per log.

    Every executor gives the same observations, odometry, notes and counts as ``extract(log,
    config)`` run on its own, in the order of ``logs``; the first log that fails raises its
    error, as it would alone, and the logs still waiting are cancelled.

    With Ray, every worker reads the logs itself, at the same path as given here: on a cluster
    they must sit on storage every node mounts at the same place (NFS, a shared volume), and
    ``markergraph`` must be installed on every node (the same version as the driver's).
    Relative paths are made absolute first, since Ray's workers do not share the driver's
    working directory, so notes and errors name the absolute path.

    Args:
        logs: MCAP files or rosbag2 folders.
        config: how to read them (the same for every log).
        executor: ``local`` (default) or ``ray``.
        address: the Ray cluster to connect to (``host:6379``, ``auto``, or ``ray://host:10001``
            with Ray's client); default ``$RAY_ADDRESS``, else a Ray instance started here
            and shut down at the end (or one started earlier by ``ray start --head`` on this
            machine, which Ray finds by itself). Ignored when Ray is already initialised in
            this process: that session is used and left running. Local executor: ignored.
        workers: local executor only: processes, one log each; at most one per log and per
            core. 1 (default) reads the logs one after another in this process. Under Ray, the
            cluster's CPUs decide (a task asks for one CPU).
        progress: called with (logs done, logs in all) as each log's front end finishes.

    Returns:
        One :class:`Extraction` per log, in the order of ``logs``.

    Raises:
        LogError: a log cannot be read (the first to fail, naming it), as ``extract`` says.
        SettingsError: an unknown executor, workers below 1, Ray chosen but not installed, or
            a Ray cluster that cannot be reached.
        MarkerGraphError: a Ray worker died while reading a log (the message names the log).
    """
    executor = _executor(executor)
    if workers is not None and workers < 1:
        raise SettingsError(f"workers must be at least 1, not {workers}")
    paths = [Path(log) for log in logs]
    if not paths:
        return []
    if executor is Executor.RAY:
        return _on_ray(paths, config, address, progress)
    if len(paths) == 1:  # one log: its own stretches in parallel, where that helps
        return [extract(paths[0], config, progress=progress, workers=workers)]
    # A log each: as many processes as logs and idle cores (a log repays a worker's start-up).
    processes, _ = choose_workers(MIN_FRAMES_PER_WORKER * len(paths), workers)
    if processes <= 1:
        results = []
        for done, path in enumerate(paths, start=1):
            results.append(extract(path, config))
            if progress is not None:
                progress(done, len(paths))
        return results
    return _in_processes(paths, config, processes, progress)


def _executor(value: Executor | str) -> Executor:
    if isinstance(value, Executor):
        return value
    try:
        return Executor(value)
    except ValueError:
        choices = ", ".join(e.value for e in Executor)
        raise SettingsError(f"unknown executor {value!r}; choose one of {choices}") from None


def _in_processes(
    paths: list[Path],
    config: FrontendConfig,
    workers: int,
    progress: Callable[[int, int], None] | None,
) -> list[Extraction]:
    """A ``spawn``ed process per log, ``workers`` at a time (forking after OpenCV has run can
    deadlock)."""
    results: list[Extraction | None] = [None] * len(paths)
    pool = process_pool(workers, one_opencv_thread)
    try:
        futures: dict[Future[Extraction], int] = {
            pool.submit(extract, path, config): i for i, path in enumerate(paths)
        }
        for done, future in enumerate(as_completed(futures), start=1):
            results[futures[future]] = future.result()
            if progress is not None:
                progress(done, len(paths))
    finally:
        # On an error, the logs not started are dropped; those being read finish first.
        pool.shutdown(wait=True, cancel_futures=True)
    return [r for r in results if r is not None]


# --- Ray ---------------------------------------------------------------------------------------


def _import_ray() -> ModuleType:
    """Ray, or a one-line error saying how to install it."""
    try:
        # By name, so that type checkers without Ray installed do not look for it.
        return importlib.import_module("ray")
    except ImportError:
        raise SettingsError(RAY_MISSING) from None


def _extract_on_worker(path: Path, config: FrontendConfig) -> Extraction:
    """One log's front end in a Ray worker: one OpenCV thread, as a Ray task asks for one CPU."""
    one_opencv_thread()
    return extract(path, config)


_REMOTE: dict[str, Any] = {}  # the remote function, made once per process


def _on_ray(
    paths: list[Path],
    config: FrontendConfig,
    address: str | None,
    progress: Callable[[int, int], None] | None,
) -> list[Extraction]:
    ray = _import_ray()
    started = not ray.is_initialized()
    if started:
        address = address or os.environ.get("RAY_ADDRESS") or None
        try:
            ray.init(address=address, **({} if address else {"include_dashboard": False}))
        except ConnectionError as error:
            raise SettingsError(
                f"cannot reach the Ray cluster at {address} (--ray-address or RAY_ADDRESS): "
                f"{str(error).splitlines()[0] if str(error) else type(error).__name__}"
            ) from None
    try:
        if "extract" not in _REMOTE:
            _REMOTE["extract"] = ray.remote(num_cpus=1)(_extract_on_worker)
        remote = _REMOTE["extract"]
        # Ray's workers start in a directory of their own, not the driver's.
        paths = [path.absolute() for path in paths]
        config_ref = ray.put(config)  # one copy in the object store, not one per task
        refs = [remote.remote(path, config_ref) for path in paths]
        index = {ref: i for i, ref in enumerate(refs)}
        results: list[Extraction | None] = [None] * len(paths)
        pending = list(refs)
        try:
            while pending:
                ready, pending = ray.wait(pending, num_returns=1)
                for ref in ready:
                    results[index[ref]] = _ray_result(ray, ref, paths[index[ref]])
                    if progress is not None:
                        progress(len(paths) - len(pending), len(paths))
        except BaseException:
            for ref in pending:  # the logs not read yet are not worth reading any more
                ray.cancel(ref)
            raise
        return [r for r in results if r is not None]
    finally:
        if started:
            ray.shutdown()


def _ray_result(ray: ModuleType, ref: Any, path: Path) -> Extraction:
    """A task's Extraction; its error as the front end raised it (not Ray's wrapper)."""
    try:
        result: Extraction = ray.get(ref)
    except ray.exceptions.RayTaskError as error:
        # Ray wraps the task's exception; the cause is the front end's own (a LogError naming
        # the log, pickled whole), so the caller sees what a local run would raise.
        cause = error.cause
        if isinstance(cause, MarkerGraphError):
            raise cause from None
        raise cause from error
    except ray.exceptions.RayError as error:  # a worker or node died: no cause of ours
        first = str(error).strip().splitlines()[0] if str(error).strip() else ""
        raise MarkerGraphError(
            f"{path}: the Ray task reading it failed: {type(error).__name__}"
            + (f": {first}" if first else "")
        ) from error
    return result
