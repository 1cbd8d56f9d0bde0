"""A result folder's figures drawn beside the rest of it: in processes of their own where a
second core is free, so matplotlib's drawing (most of the writing: 0.8 of 1.3 s on the bundled
sample's cached map) overlaps the maps, trajectories, overlay and report being written.

The processes start with the command and import matplotlib while the log is read and the map
solved; a figure is then drawn by whichever is free as soon as it is asked for. One process
serves a map's two figures; several methods' maps and their comparison keep two busy once the
command has written the rest. Without a free core, or should a process fail, each figure is
drawn here instead: the figures are the same either way."""

from __future__ import annotations

import itertools
import os
import pickle
import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import TracebackType
from typing import TYPE_CHECKING, Any

from markergraph.common.pool import available_cores, start_worker

if TYPE_CHECKING:
    from multiprocessing.process import BaseProcess
    from multiprocessing.queues import Queue

__all__ = ["Plotter"]

_Figure = tuple[Callable[..., Any], tuple[Any, ...], dict[str, Any]]
_Task = tuple[int, bytes]  # a figure's number and the figure pickled
_Outcome = tuple[int, BaseException | None]  # a figure's number and its error, if any
CLOSE_TIMEOUT_S = 5.0  # for a process to end once terminated; then it is killed


class Plotter:
    """Draws figures (module-level functions that write files): in processes of their own
    (:meth:`start`), else in this one (``Plotter()``). Used as a context manager, which ends the
    processes."""

    def __init__(self) -> None:
        self._processes: list[BaseProcess] = []
        self._tasks: Queue[_Task] | None = None
        self._results: Queue[_Outcome] | None = None
        self._pending: dict[int, _Figure] = {}  # by number: asked for, not yet drawn
        self._numbers = itertools.count()

    @classmethod
    def start(cls, processes: int = 1) -> Plotter:
        """A plotter whose ``processes`` (at most one a core) start now and import matplotlib
        at once, where this machine has a second core and can start them; else one that draws
        in this process."""
        plotter = cls()
        cores = available_cores()
        if cores < 2:
            return plotter
        import multiprocessing

        # Spawned, not forked: forking after OpenCV or GTSAM have started threads can deadlock.
        context = multiprocessing.get_context("spawn")
        started: list[BaseProcess] = []
        try:
            tasks, results = context.Queue(), context.Queue()
            for _ in range(min(processes, cores)):
                process = context.Process(
                    target=_serve, args=(tasks, results, os.getpid()),
                    name="markergraph-plotter", daemon=True,
                )  # fmt: skip
                with _sigint_ignored():  # until it ignores Ctrl-C itself: the command's to handle
                    process.start()
                started.append(process)
        except OSError:  # no semaphores or pipes to be had here: drawn in this process
            for begun in started:
                begun.terminate()
            return plotter
        plotter._processes, plotter._tasks, plotter._results = started, tasks, results
        return plotter

    def draw(self, figure: Callable[..., Any], *args: Any, **kwargs: Any) -> None:
        """``figure(*args, **kwargs)``, now here or soon in a plotter's process; :meth:`finish`
        waits for it. A figure whose arguments do not pickle is drawn here."""
        if self._tasks is not None:
            try:
                task = pickle.dumps((figure, args, kwargs), pickle.HIGHEST_PROTOCOL)
            except (pickle.PicklingError, TypeError, AttributeError):
                task = None
            if task is not None:
                number = next(self._numbers)
                # Pending before it is queued: a Ctrl-C between the two must not leave a queued
                # figure that close() takes for drawn (it would wait on the queue's thread).
                self._pending[number] = (figure, args, kwargs)
                self._tasks.put((number, task))
                return
        figure(*args, **kwargs)

    def finish(self) -> None:
        """Every figure asked for drawn; a figure's error is raised here. Should a process
        itself fail (killed, out of memory), the processes are ended and the figures not yet
        drawn are drawn here."""
        while self._pending:
            try:
                number, error = self._result()
            except _ProcessEndedError:
                left = list(self._pending.values())
                self.close()
                for figure, args, kwargs in left:
                    figure(*args, **kwargs)
                return
            if self._pending.pop(number, None) is not None and error is not None:
                raise error

    def _result(self) -> _Outcome:
        """The next figure's outcome from the processes.

        Raises:
            _ProcessEndedError: a process ended (it may have held a figure it never drew).
        """
        import queue

        assert self._results is not None
        while True:
            try:
                return self._results.get(timeout=0.5)
            except queue.Empty:
                if not all(p.is_alive() for p in self._processes):
                    raise _ProcessEndedError from None

    def close(self) -> None:
        """The processes ended at once; figures not yet drawn are dropped (after
        :meth:`finish` there are none)."""
        processes, tasks, drawn = self._processes, self._tasks, not self._pending
        self._processes, self._tasks, self._results = [], None, None
        self._pending = {}
        if tasks is None:
            return
        for process in processes:
            process.terminate()  # idle, or drawing into a folder that is being discarded
        for process in processes:
            process.join(CLOSE_TIMEOUT_S)
            if process.is_alive():
                process.kill()
                process.join()
        tasks.close()
        if drawn:
            # Every task was taken, so the queue's thread ends at once: wait for it here. Left
            # to end as Python exits, it may drop the queue's last locks, unlink one and be
            # stopped before it tells the resource tracker, which then warns of a "leaked
            # semaphore" (before: in 1 of 6 runs of `--method all` kept apart, and in 1 of 25
            # of a script drawing eight 3 MB figures).
            tasks.join_thread()
        else:
            tasks.cancel_join_thread()  # tasks they never took are not waited for

    @contextmanager
    def stopped_on_error(self) -> Iterator[None]:
        """On an error inside, the process is ended before the error leaves: entered inside a
        result folder's ``with``, no figure lands in the folder as it is discarded."""
        try:
            yield
        except BaseException:
            self.close()
            raise

    def __enter__(self) -> Plotter:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()


@contextmanager
def _sigint_ignored() -> Iterator[None]:
    """Ctrl-C ignored inside, in the main thread (a process started here inherits that): a
    spawned process would otherwise print its traceback while it starts."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


class _ProcessEndedError(Exception):
    """A plotter's process ended before its figures were drawn."""


def _serve(tasks: Queue[_Task], results: Queue[_Outcome], parent_pid: int) -> None:
    """A plotter's process: matplotlib imported first, then each figure it takes drawn, its
    outcome sent back, until the command ends it (:meth:`Plotter.close`). It ignores Ctrl-C
    (from its start, :func:`_sigint_ignored`): the command handles that, and ends it then."""
    start_worker(parent_pid, _import_plots)
    while True:
        number, task = tasks.get()
        try:
            figure, args, kwargs = pickle.loads(task)
            figure(*args, **kwargs)
            results.put((number, None))
        except Exception as error:  # raised in the command, where the figure was asked for
            results.put((number, _sendable(error)))


def _sendable(error: Exception) -> Exception:
    """``error``, or its text where it does not pickle."""
    try:
        pickle.loads(pickle.dumps(error))
    except Exception:
        return RuntimeError(f"{type(error).__name__}: {error}")
    return error


def _import_plots() -> None:
    """matplotlib and the figures' module imported before the first figure is asked for."""
    from markergraph.plots import warm_up

    warm_up()
