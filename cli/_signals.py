"""Ctrl-C (SIGINT) and SIGTERM: one line on stderr and exit 130 or 143, at any moment, with what
the run was writing removed on the way out.

:func:`markergraph.cli.main` installs the handlers before anything else, ahead of the second of
imports that follows (this module imports nothing of markergraph's, so it is quick to reach).
The command then goes through three phases:

- **starting** (imports, argument parsing; nothing is written yet): a signal ends the process at
  once. Raising ``KeyboardInterrupt`` here would not do: an import it cuts short is left half
  done, and a C extension turns it into another error (GTSAM's "ImportError: initialization
  failed"), printed with a traceback.
- **running**: a signal raises :class:`Stopped`, a ``KeyboardInterrupt``, so every cleanup
  that Ctrl-C runs (the temporary folder of :func:`~markergraph.common.files.result_folder`,
  a worker pool's shutdown) runs for SIGTERM alike. A second signal, while the first one's
  cleanup runs, ends the process at once (the next run to the same output removes what it left).
- **finished** (the process's own command line only): a signal ends the process at once with
  its exit code, so a late Ctrl-C cannot print a traceback while Python shuts down.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from enum import Enum
from types import FrameType
from typing import Any

__all__ = ["Phase", "Signals", "Stopped", "exit_code", "handled"]

EXIT_SIGNAL_BASE = 128  # a shell's exit status for a process a signal ended: 128 + its number
_WORDS = {signal.SIGINT: "interrupted", signal.SIGTERM: "terminated (SIGTERM)"}


class Stopped(KeyboardInterrupt):
    """A signal asked the run to stop. A ``KeyboardInterrupt`` so that every ``finally`` and
    ``except KeyboardInterrupt`` written for Ctrl-C cleans up for SIGTERM too.

    Attributes:
        signum: the signal's number.
    """

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


class Phase(Enum):
    """What a signal does now (see the module's docstring)."""

    STARTING = "starting"
    RUNNING = "running"
    FINISHED = "finished"


def exit_code(signum: int) -> int:
    """The exit code for a run a signal stopped: 130 for SIGINT, 143 for SIGTERM."""
    return EXIT_SIGNAL_BASE + signum


def stopped_line(command: str | None, signum: int) -> str:
    """The one line a stopped run prints: ``markergraph map: interrupted``."""
    who = f"markergraph {command}" if command else "markergraph"
    return f"{who}: {_WORDS.get(signal.Signals(signum), signal.Signals(signum).name)}"


class Signals:
    """The handlers' state: the phase, the command's name and the first signal received.

    Attributes:
        phase: what a signal does now.
        command: the subcommand's name, for the line, once parsed.
        received: the first signal's number, or None.
    """

    def __init__(self) -> None:
        self.phase = Phase.STARTING
        self.command: str | None = None
        self.received: int | None = None

    def running(self, command: str) -> None:
        """From now on a signal raises :class:`Stopped` in the run."""
        self.command = command
        self.phase = Phase.RUNNING

    def handle(self, signum: int, frame: FrameType | None) -> None:
        """The handler for SIGINT and SIGTERM (``signal.signal``'s signature)."""
        first = self.received is None
        if first:
            self.received = signum
        if self.phase is Phase.RUNNING and first:
            raise Stopped(signum)
        line = stopped_line(self.command, signum)
        if self.phase is Phase.RUNNING:  # a second signal while the first one's cleanup runs
            line += " again: stopped at once; the next run to the same output removes what it left"
        _end_now(line, exit_code(self.received or signum), quiet=self.phase is Phase.FINISHED)


def _end_now(line: str, code: int, *, quiet: bool) -> None:
    """Print ``line`` (unless ``quiet``) and end the process at once, without unwinding."""
    with suppress(OSError, ValueError):
        sys.stdout.flush()  # what was printed stays printed
    if not quiet:
        os.write(2, f"{line}\n".encode(errors="replace"))
    os._exit(code)


_ours: Signals | None = None  # the handlers installed, so that a nested main() does not stack


@contextmanager
def handled(*, process: bool) -> Iterator[Signals]:
    """SIGINT and SIGTERM handled as the module says while the block runs.

    Args:
        process: the command line is the process's own (``main()`` without ``argv``): the
            handlers stay when the block ends, in the finished phase. Otherwise (a caller in
            Python, such as a test) the previous handlers are put back.

    Yields:
        The state to move into the running phase. Outside the main thread, where handlers
        cannot be set, and where a signal was ignored when the process started (``nohup``, a
        background job), it stays as it was.
    """
    global _ours
    state = Signals()
    if _ours is not None or threading.current_thread() is not threading.main_thread():
        yield state
        return
    previous: dict[int, Any] = {}
    for signum in _WORDS:
        handler = signal.getsignal(signum)
        if handler is not signal.SIG_IGN:
            previous[signum] = signal.signal(signum, state.handle)
    _ours = state
    try:
        yield state
    finally:
        if process:
            state.phase = Phase.FINISHED
        else:
            for number, handler in previous.items():
                signal.signal(number, handler)
            _ours = None
