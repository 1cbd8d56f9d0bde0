"""Progress on stderr (tqdm), drawn only when stderr is a terminal: frames read, their rate and
the time left, then the estimation's stages."""

from __future__ import annotations

import sys
import time
from typing import TextIO

from tqdm import tqdm

__all__ = ["ProgressBar", "Stages"]


class ProgressBar:
    """``bar(done, total)`` moves the bar to ``done`` of ``total`` frames; ``bar.close()`` ends
    it. Silent off a terminal, or when ``quiet``.

    Args:
        label: what is being read, shown before the bar.
        stream: where to draw (stderr by default).
    """

    def __init__(self, label: str, stream: TextIO | None = None, *, quiet: bool = False) -> None:
        self.stream = stream or sys.stderr
        self.bar: tqdm | None = None
        self.label = label
        self.enabled = not quiet and self.stream.isatty()

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled or total <= 0:
            return
        if self.bar is None:
            self.bar = tqdm(total=total, desc=self.label, unit="frame", file=self.stream,
                            leave=True)  # fmt: skip
        self.bar.total = max(total, done)
        self.bar.update(done - self.bar.n)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None

    def __enter__(self) -> ProgressBar:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class Stages:
    """``stages(name)`` says a stage began, and with ``verbose`` how long the previous one took:
    on a terminal, or always when ``verbose``; never when ``quiet``."""

    def __init__(
        self, stream: TextIO | None = None, *, quiet: bool = False, verbose: bool = False
    ) -> None:
        self.stream = stream or sys.stderr
        self.enabled = not quiet and (verbose or self.stream.isatty())
        self.verbose = verbose
        self.current: tuple[str, float] | None = None

    def __call__(self, name: str) -> None:
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
