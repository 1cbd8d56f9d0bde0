"""Notes: what a stage noticed and did about it (frames dropped, a topic chosen, a default
taken), as records. Each stage returns its own; the application layer gathers them and renders
them to text once, for the summary, report.json and report.html."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Note"]


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
