"""Worker processes: how many to start (the cores there are and how busy they are now), and a
``spawn``ed pool whose workers end themselves when their parent dies. The front end (a process
per stretch of a log) and the application (a process per log) share it, and so its safety."""

from __future__ import annotations

import os
import sys
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # multiprocessing's 25 ms of imports wait for a pool
    from concurrent.futures import ProcessPoolExecutor

from markergraph.common.notes import Note

__all__ = [
    "CORES_PER_PROCESS",
    "MIN_FRAMES_PER_WORKER",
    "available_cores",
    "busy_cores",
    "choose_workers",
    "core_ticks",
    "process_pool",
    "start_worker",
]

# A worker costs 0.3-0.7 s to spawn and import, and a few hundred frames a second repay it: below
# this many frames each, one process is as fast.
MIN_FRAMES_PER_WORKER = 1500
# Cores one process keeps busy: its reading thread (zstd), its pool's threads decoding JPEG and
# detecting (which release the GIL), and its main thread (bench_process: 1.7-1.8 cores of 2).
CORES_PER_PROCESS = 2.0
WATCH_INTERVAL_S = 0.5  # how often a worker checks that its parent lives


def start_worker(parent_pid: int, setup: Callable[[], None] | None = None) -> None:
    """In each worker: ``setup`` (such as one OpenCV thread), and a watchdog that ends the worker
    when its parent dies (a killed run must not leave workers waiting forever for work).

    Args:
        parent_pid: the process that started the pool.
        setup: run first; a module-level function, as ``spawn`` pickles it by name.
    """
    if setup is not None:
        setup()

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(WATCH_INTERVAL_S)
        os._exit(1)

    threading.Thread(target=watch, daemon=True).start()


def process_pool(workers: int, setup: Callable[[], None] | None = None) -> ProcessPoolExecutor:
    """``workers`` ``spawn``ed processes (forking after OpenCV has run can deadlock), each
    started by :func:`start_worker` with ``setup``."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    return ProcessPoolExecutor(
        workers,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=start_worker,
        initargs=(os.getpid(), setup),
    )


def available_cores() -> int:
    """The cores this process may run on."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return os.cpu_count() or 1


def busy_cores(seconds: float = 0.2) -> float | None:
    """How many of the cores this process may run on other work keeps busy now: their share
    not idle over ``seconds``, from Linux's per-core counters in ``/proc/stat`` (time the host
    steals counts as busy: a core lent elsewhere is no help). None where there are no such
    counters. Unlike the load average, which trails by a minute, it sees a core freed a moment
    ago, such as by a run of ours that has just ended. This process's own children
    (multiprocessing's, such as the plotter drawing figures) are not other work."""

    def counters() -> tuple[dict[int, tuple[int, int]], int]:
        with open("/proc/stat") as stat:
            return core_ticks(stat.read()), _children_ticks()

    try:
        before, ours_before = counters()
        time.sleep(seconds)
        after, ours_after = counters()
    except (OSError, ValueError, IndexError):
        return None
    mine = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else set(after)
    busy, seen, elapsed = 0.0, 0, 0
    for core in mine & set(before) & set(after):
        idle, total = (a - b for a, b in zip(after[core], before[core], strict=True))
        if total > 0:
            busy += 1.0 - idle / total
            seen += 1
            elapsed = max(elapsed, total)  # one core's ticks over the window
    if not seen:
        return None
    return max(0.0, busy - max(0, ours_after - ours_before) / max(elapsed, 1))


def _children_ticks() -> int:
    """The CPU clock ticks (user and system) this process's running multiprocessing children
    have used; 0 when multiprocessing is not even imported (no children)."""
    multiprocessing = sys.modules.get("multiprocessing")
    if multiprocessing is None:
        return 0
    ticks = 0
    for child in multiprocessing.active_children():
        try:
            with open(f"/proc/{child.pid}/stat") as stat:
                fields = stat.read().rsplit(")", 1)[1].split()
        except (OSError, IndexError):  # ended meanwhile
            continue
        ticks += int(fields[11]) + int(fields[12])  # utime, stime
    return ticks


def core_ticks(proc_stat: str) -> dict[int, tuple[int, int]]:
    """Each core's (idle and iowait, all) clock ticks since boot from ``/proc/stat``'s text:
    its ``cpuN`` lines' first eight fields, user to steal (guest time is already in user)."""
    ticks = {}
    for line in proc_stat.splitlines():
        name, *fields = line.split() or [""]
        if name.startswith("cpu") and name[3:].isdigit():
            values = [int(v) for v in fields[:8]]
            ticks[int(name[3:])] = (values[3] + values[4], sum(values))
    return ticks


def choose_workers(frames: int, asked: int | None) -> tuple[int, Note | None]:
    """How many processes to read a log of ``frames`` colour frames with, and a note where it
    is more than one. A number asked for is used, capped at the cores there are. ``None``
    (auto) gives more than one only where each has :data:`MIN_FRAMES_PER_WORKER` frames and
    :data:`CORES_PER_PROCESS` idle cores now, measured over a fifth of a second
    (:func:`busy_cores`; elsewhere the 1-minute load average): one process's threads already
    keep two cores busy (on a 2-core machine a second process, before they did, ran 0.81-1.33x
    one on bench_frontend's 3-minute log)."""
    cores = available_cores()
    if asked is not None:
        if asked <= cores:
            return asked, None
        text = f"--workers {asked} capped at the {cores} cores available"
        return cores, Note("workers.capped", text, figure=cores)
    by_length = max(1, frames // MIN_FRAMES_PER_WORKER)
    if by_length == 1 or cores < 2 * CORES_PER_PROCESS:
        return 1, None  # the usual case: nothing to say
    busy = busy_cores()
    if busy is None:
        busy = os.getloadavg()[0] if hasattr(os, "getloadavg") else 0.0
    idle = max(0.0, cores - busy)
    chosen = max(1, min(by_length, int(idle / CORES_PER_PROCESS)))
    if chosen == 1:
        return 1, None
    return chosen, Note(
        "workers.auto",
        f"read in {chosen} processes at once ({frames:,} frames; {idle:.1f} of {cores} cores "
        "were idle; --workers sets how many)",
        figure=chosen,
    )
