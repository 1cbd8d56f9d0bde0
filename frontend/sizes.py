"""The markers' sizes: one side for all, and the markers printed at another, by id."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

__all__ = ["MarkerSizes"]


@dataclass(frozen=True, slots=True)
class MarkerSizes:
    """The side of each marker's black square, from the flag to ``map.json``'s ``size_m``.

    Attributes:
        default_m: the side of every marker not in ``by_id`` [m].
        by_id: the sides of markers whose size differs, by marker id [m].
    """

    default_m: float = 0.2
    by_id: Mapping[int, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        # A copy of its own: the caller's table may change after, and a default is shared.
        object.__setattr__(self, "by_id", dict(self.by_id))

    def of(self, marker_id: int) -> float:
        """The side of one marker's black square [m]."""
        return self.by_id.get(marker_id, self.default_m)

    def with_sizes(self, by_id: Mapping[int, float]) -> MarkerSizes:
        """These sizes with ``by_id``'s added; a marker sized in both keeps ``by_id``'s."""
        return MarkerSizes(self.default_m, {**self.by_id, **by_id})

    def under(self, by_id: Mapping[int, float]) -> MarkerSizes:
        """These sizes with ``by_id``'s added where this gives none of its own (a rig file's
        sizes under the user's)."""
        return MarkerSizes(self.default_m, {**by_id, **self.by_id})
