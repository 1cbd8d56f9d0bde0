"""The checks of settings' values: each converts a value from a file, a flag or a keyword, or
raises SettingsError saying what is wrong; checking a checked value gives it back unchanged."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

from markergraph.common.errors import SettingsError

__all__ = [
    "SIDE_M",
    "bounded",
    "count",
    "count_or_auto",
    "frame_name",
    "marker_id_of",
    "marker_ids",
    "nonempty",
    "optional",
    "optional_id",
    "optional_text",
    "scale_or_auto",
    "shown",
    "sizes_by_id",
]


def shown(value: Any) -> str:
    """A value for an error message, cut short if it is a huge number."""
    text = repr(value)
    return text if len(text) <= 24 else f"{text[:12]}... ({len(text)} characters)"


def bounded(minimum: float = -math.inf, maximum: float = math.inf) -> Callable[[Any], float]:
    """A parser of finite numbers in [minimum, maximum]. Every number setting is bounded: a
    value far outside what a robot has would only overflow, or make GTSAM's system singular,
    after all the work."""

    def parse(value: Any) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise SettingsError(f"must be a number, got {shown(value)}")
        try:
            number = float(value)
        except OverflowError:  # an integer of hundreds of digits
            number = math.inf
        if math.isfinite(number) and minimum <= number <= maximum:
            return number
        if minimum > 0 and number <= 0:
            raise SettingsError(f"must be positive, got {shown(value)}")
        raise SettingsError(f"must be between {minimum:g} and {maximum:g}, got {shown(value)}")

    return parse


SIDE_M = bounded(0.001, 10.0)  # a marker's side [m]


def count(value: Any) -> int:
    """A whole number of at least 1."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise SettingsError(f"must be a whole number of at least 1, got {value!r}")
    return value


def count_or_auto(value: Any) -> int | None:
    """A count, or None for ``auto``."""
    if value is None or value == "auto":
        return None
    if isinstance(value, str) and value.isdigit():
        value = int(value)
    return count(value)


def marker_id_of(value: Any) -> int:
    """A marker id: a whole number >= 0 (from a file's table key, text too)."""
    if isinstance(value, str) and value.strip().isdigit():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise SettingsError(f"must be a marker id (a whole number >= 0), got {value!r}")
    return value


def optional_id(value: Any) -> int | None:
    """A marker id, or None."""
    return None if value is None else marker_id_of(value)


def nonempty(value: Any) -> str:
    """A non-empty string."""
    if not isinstance(value, str) or not value:
        raise SettingsError(f"must be a non-empty string, got {value!r}")
    return value


def optional_text(value: Any) -> str | None:
    """A non-empty string, or None."""
    return None if value is None else nonempty(value)


def marker_ids(value: Any) -> tuple[int, ...] | None:
    """A non-empty list of marker ids, sorted without repeats; or None."""
    if value is None:
        return None
    if not isinstance(value, (list, tuple)) or not value:
        raise SettingsError(f"must be a list of marker ids, got {value!r}")
    return tuple(sorted({marker_id_of(v) for v in value}))


def sizes_by_id(value: Any) -> dict[int, float]:
    """``{id: side}`` from a table, or from ``ID=M`` words on the command line."""
    if isinstance(value, (list, tuple)):
        pairs = {}
        for word in value:
            marker_id, _, side = str(word).partition("=")
            try:
                pairs[marker_id] = float(side)
            except ValueError:
                raise SettingsError(f"must be ID=M pairs such as 7=0.15, got {word!r}") from None
        value = pairs
    if not isinstance(value, Mapping):
        raise SettingsError(f"must be a table of marker id = side in metres, got {value!r}")
    return {marker_id_of(k): SIDE_M(v) for k, v in value.items()}


def optional(parse: Callable[[Any], float]) -> Callable[[Any], float | None]:
    """``parse``, letting None through."""

    def parse_optional(value: Any) -> float | None:
        return None if value is None else parse(value)

    return parse_optional


def scale_or_auto(value: Any) -> float | None:
    """A scale in [0.5, 2], or None for ``auto``."""
    # None is "auto" parsed: parsing a parsed value gives it back. A flag's number is text.
    if value is None or value == "auto":
        return None
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            raise SettingsError(f"must be a number or auto, got {shown(value)}") from None
    return bounded(0.5, 2.0)(value)


def frame_name(value: Any) -> str:
    """A TF frame name: no leading ``/``, no spaces."""
    name = nonempty(value)
    if not name or name.startswith("/") or any(c.isspace() for c in name):
        raise SettingsError(f"must be a TF frame name (no leading '/', no spaces), got {name!r}")
    return name
