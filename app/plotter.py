"""A result folder's figures drawn beside the rest of it: in a process of its own where a second
core is free, so matplotlib's drawing (most of the writing: 0.8 of 1.3 s on the bundled
sample's cached map) overlaps the maps, trajectories, overlay and report being written.

The process starts with the command and imports matplotlib while the log is read and the map
solved; a figure is then drawn there as soon as it is asked for. Without a free core, or should
the process fail, each figure is drawn here instead: the figures are the same either way."""

from __future__ import annotations

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
CLOSE_TIMEOUT_S = 5.0  # for the process to end once terminated; then it is killed


class Plotter:
    """Draws figures (module-level functions that write files): in a process of its own
    (:meth:`start`), else in this one (``Plotter()``). Used as a context manager, which ends the
    process."""

    def __init__(self) -> None:
        self._process: BaseProcess | None = None
        self._tasks: Queue[bytes] | None = None
        self._results: Queue[BaseException | None] | None = None
        self._pending: list[_Figure] = []

    @classmethod
    def start(cls) -> Plotter:
        """A plotter whose process starts now and imports matplotlib at once, where this
        machine has a second core and can start one; else one that draws in this process."""
        plotter = cls()
        if available_cores() < 2:
            return plotter
        import multiprocessing

        # Spawned, not forked: forking after OpenCV or GTSAM have started threads can deadlock.
        context = multiprocessing.get_context("spawn")
        try:
            tasks, results = context.Queue(), context.Queue()
            process = context.Process(
                target=_serve, args=(tasks, results, os.getpid()), name="markergraph-plotter",
                daemon=True,
            )  # fmt: skip
            with _sigint_ignored():  # until it ignores Ctrl-C itself: the command's to handle
                process.start()
        except OSError:  # no semaphores or pipes to be had here: drawn in this process
            return plotter
        plotter._process, plotter._tasks, plotter._results = process, tasks, results
        return plotter

    def draw(self, figure: Callable[..., Any], *args: Any, **kwargs: Any) -> None:
        """``figure(*args, **kwargs)``, now here or soon in the plotter's process;
        :meth:`finish` waits for it. A figure whose arguments do not pickle is drawn here."""
        if self._tasks is not None:
            try:
                task = pickle.dumps((figure, args, kwargs), pickle.HIGHEST_PROTOCOL)
            except (pickle.PicklingError, TypeError, AttributeError):
                task = None
            if task is not None:
                self._tasks.put(task)
                self._pending.append((figure, args, kwargs))
                return
        figure(*args, **kwargs)

    def finish(self) -> None:
        """Every figure asked for drawn; a figure's error is raised here. Should the process
        itself fail (killed, out of memory), the figures it had not drawn are drawn here."""
        pending, self._pending = self._pending, []
        for n in range(len(pending)):
            try:
                error = self._result()
            except _ProcessEndedError:
                self.close()
                for figure, args, kwargs in pending[n:]:
                    figure(*args, **kwargs)
                return
            if error is not None:
                raise error

    def _result(self) -> BaseException | None:
        """The next figure's outcome from the process: None where it was drawn, else its error.

        Raises:
            _ProcessEndedError: the process ended before it sent one.
        """
        import queue

        assert self._results is not None and self._process is not None
        while True:
            try:
                return self._results.get(timeout=0.5)
            except queue.Empty:
                if not self._process.is_alive():
                    raise _ProcessEndedError from None

    def close(self) -> None:
        """The process ended at once; figures not yet drawn are dropped (after :meth:`finish`
        there are none)."""
        process, tasks = self._process, self._tasks
        self._process = self._tasks = self._results = None
        self._pending = []
        if process is None or tasks is None:
            return
        process.terminate()  # idle, or drawing into a folder that is being discarded
        process.join(CLOSE_TIMEOUT_S)
        if process.is_alive():
            process.kill()
            process.join()
        tasks.close()
        tasks.cancel_join_thread()  # tasks it never took are not waited for

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
    """The plotter's process ended before drawing a figure."""


def _serve(tasks: Queue[bytes], results: Queue[BaseException | None], parent_pid: int) -> None:
    """The plotter's process: matplotlib imported first, then each figure drawn as it comes,
    its outcome sent back, until the command ends it (:meth:`Plotter.close`). It ignores Ctrl-C
    (from its start, :func:`_sigint_ignored`): the command handles that, and ends it then."""
    start_worker(parent_pid, _import_plots)
    while True:
        task = tasks.get()
        try:
            figure, args, kwargs = pickle.loads(task)
            figure(*args, **kwargs)
            results.put(None)
        except Exception as error:  # raised in the command, where the figure was asked for
            results.put(_sendable(error))


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
