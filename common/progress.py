"""Progress on stderr (tqdm), drawn only when stderr is a terminal: frames read, their rate and
the time left, then the estimation's stages."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, TextIO

if TYPE_CHECKING:  # loaded with the first bar drawn: a run off a terminal draws none
    from tqdm import tqdm

__all__ = ["ProgressBar", "Stages"]


class ProgressBar:
    """``bar(done, total)`` moves the bar to ``done`` of ``total`` frames; ``bar.close()`` ends
    it at 100 % of the frames counted (``total`` is the log's estimate, which frames the reader
    skips leave short), and it is not drawn again after. Silent off a terminal, or when
    ``quiet``.

    Args:
        label: what is being read, shown before the bar.
        stream: where to draw (stderr by default).
    """

    def __init__(self, label: str, stream: TextIO | None = None, *, quiet: bool = False) -> None:
        self.stream = stream or sys.stderr
        self.bar: tqdm | None = None
        self.label = label
        self.enabled = not quiet and self.stream.isatty()
        self.closed = False

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled or self.closed or total <= 0:
            return
        if self.bar is None:
            from tqdm import tqdm

            self.bar = tqdm(total=total, desc=self.label, unit="frame", file=self.stream,
                            leave=True)  # fmt: skip
        self.bar.total = max(total, done)
        self.bar.update(done - self.bar.n)

    def close(self, *, complete: bool = True) -> None:
        """End the bar on its own line, at the count reached (100 %) when ``complete``; later
        calls draw nothing (a bar drawn again after estimation would show a rate that counts
        its time)."""
        if self.bar is not None:
            if complete:
                self.bar.total = self.bar.n
            self.bar.refresh()
            self.bar.close()
            self.bar = None
            self.closed = True

    def __enter__(self) -> ProgressBar:
        return self

    def __exit__(self, kind: type[BaseException] | None, *exc: object) -> None:
        self.close(complete=kind is None)  # an error or a stop: the bar stays where it was


class Stages:
    """``stages(name)`` says a stage began, and with ``verbose`` how long the previous one took:
    on a terminal, or always when ``verbose``; never when ``quiet``.

    Args:
        before: called before a stage's line is printed (a progress bar's ``close``, so that the
            line starts after the bar rather than on it).
    """

    def __init__(
        self,
        stream: TextIO | None = None,
        *,
        quiet: bool = False,
        verbose: bool = False,
        before: Callable[[], None] | None = None,
    ) -> None:
        self.stream = stream or sys.stderr
        self.before = before
        self.enabled = not quiet and (verbose or self.stream.isatty())
        self.verbose = verbose
        self.current: tuple[str, float] | None = None

    def __call__(self, name: str) -> None:
        if self.before is not None:
            self.before()
        self._finish()
        self.current = (name, time.perf_counter())
        if self.enabled:
            print(f"{name} ...", file=self.stream, flush=True)

    def _finish(self) -> None:
        if self.current is not None and self.enabled and self.verbose:
            name, start = self.current
            print(f"  {name}: {time.perf_counter() - start:.1f} s", file=self.stream, flush=True)

    def close(self) -> None:
        self._finish()
        self.current = None
