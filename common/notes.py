"""Notes: what a stage noticed and did about it (frames dropped, a topic chosen, a default
taken), as records. Each stage returns its own; the application layer gathers them and renders
them to text once, for the summary, report.json and report.html."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

__all__ = ["Note", "some_of"]


@dataclass(frozen=True, slots=True)
class Note:
    """One thing a stage noticed.

    Attributes:
        kind: a stable dotted name of what happened (``"odometry.dropped_by_stamp"``): what code
            and tests match on, never the text.
        text: the sentence a person reads, complete in itself.
        topic: the log topic (or file) it is about, if one.
        figure: the number it turns on (a count, a share, a time in seconds), if one.
    """

    kind: str
    text: str
    topic: str | None = None
    figure: float | None = None

    def __str__(self) -> str:
        return self.text


def some_of(ids: Iterable[int], most: int = 6) -> str:
    """Ids in words, at most ``most`` of them named: "3, 7, 9 and 12 more"."""
    ids = list(ids)
    named = ", ".join(map(str, ids[:most]))
    return named + (f" and {len(ids) - most} more" if len(ids) > most else "")
