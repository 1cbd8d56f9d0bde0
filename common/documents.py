"""Documents a user hands us (a map.json, a survey, a tagslam.yaml), read within bounds: the
file's size checked before it is read, its nesting before it is parsed, so that no byte of it
can exhaust the memory or the stack. The caller names the file in its own error."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "MAX_DOCUMENT_BYTES",
    "MAX_DOCUMENT_DEPTH",
    "MAX_MARKERS",
    "MAX_MARKER_ID",
    "MAX_YAML_BYTES",
    "DocumentError",
    "json_document",
    "read_text",
    "yaml_document",
]

MAX_DOCUMENT_BYTES = 32 * 2**20
"""A map.json or survey larger than this is refused unread: 10,000 markers of a 3-D map take
about 15 MB, and parsing 32 MB of numbers costs a few hundred MB."""
MAX_YAML_BYTES = 8 * 2**20
"""A tagslam.yaml or cameras.yaml larger than this is refused unread (the largest of TagSLAM's
own tests is 37 kB; PyYAML parses about 1 MB a second)."""
MAX_DOCUMENT_DEPTH = 20
"""Lists and tables nest this deep at most (a map.json nests 4 deep, a tagslam.yaml 9)."""
MAX_MARKER_ID = 2**31 - 1
"""The largest marker id a document may name: OpenCV's ids are 32-bit, TagSLAM's remaps too."""
MAX_MARKERS = 10_000
"""The most markers a document may hold where its dictionary does not bound them (a custom
dictionary, a 3-D map's remapped ids): four times the largest predefined dictionary (AprilTag
36h10, 2,320 ids)."""

_CHUNK = 1 << 20  # bytes scanned at a time for brackets: memory stays a few MB
_STEP = np.zeros(256, dtype=np.int32)  # a byte's change of the nesting level
_STEP[[ord("["), ord("{")]] = 1
_STEP[[ord("]"), ord("}")]] = -1


class DocumentError(ValueError):
    """Why a document is refused, in words that follow the file's name."""


def read_text(path: Path, max_bytes: int = MAX_DOCUMENT_BYTES) -> str:
    """A UTF-8 text file (a byte-order mark read past), refused if larger than ``max_bytes``:
    the size is checked before reading, and no more than ``max_bytes`` + 1 bytes are ever read
    (a device or a pipe states no size).

    Raises:
        OSError: it cannot be read.
        UnicodeDecodeError: it is not UTF-8.
        DocumentError: it is larger than ``max_bytes``.
    """
    path = Path(path)
    size = path.stat().st_size
    if size > max_bytes:
        raise DocumentError(f"{size:,} bytes, more than such a file holds ({max_bytes:,} at most)")
    with path.open("rb") as stream:
        data = stream.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise DocumentError(f"over {max_bytes:,} bytes, more than such a file holds")
    return data.decode("utf-8").removeprefix("\ufeff")


def json_depth(text: str, limit: int = MAX_DOCUMENT_DEPTH) -> int:
    """How deep ``[`` and ``{`` nest outside strings in ``text``, counted no further than
    ``limit`` + 1; without parsing, in linear time and a few MB whatever the text.

    A quote opens or closes a string unless an odd run of backslashes precedes it; brackets
    inside strings do not count. Text that is not JSON gets some count, and fails to parse."""
    data = np.frombuffer(text.encode("utf-8"), dtype=np.uint8)
    depth = deepest = 0
    inside = 0  # 1 within a string at the chunk's start
    run = 0  # backslashes that end the previous chunk
    for start in range(0, len(data), _CHUNK):
        chunk = data[start : start + _CHUNK]
        n = len(chunk)
        backslash = chunk == ord("\\")
        # The last index at or before each position that is not a backslash (-1: none yet).
        last = np.maximum.accumulate(np.where(backslash, -1, np.arange(n)))
        ends = np.arange(-1, n - 1)  # the position before each
        last_before = np.concatenate([[-1], last[:-1]])
        before = ends - last_before + np.where(last_before < 0, run, 0)  # backslashes before
        quote = (chunk == ord('"')) & (before % 2 == 0)
        strings = inside + np.cumsum(quote, dtype=np.int64)
        step = np.where(strings % 2 == 0, _STEP[chunk], 0)
        levels = depth + np.cumsum(step, dtype=np.int64)
        deepest = max(deepest, int(levels.max()))
        depth, inside = int(levels[-1]), int(strings[-1] % 2)
        run = n - 1 - int(last[-1]) + (run if last[-1] < 0 else 0)
        if deepest > limit:
            break
    return deepest


def _refuse_constant(name: str) -> None:
    raise DocumentError(f"{name} is not a number JSON allows")


def json_document(text: str, max_depth: int = MAX_DOCUMENT_DEPTH) -> Any:
    """A strict JSON document (NaN and infinities refused), its nesting checked before it is
    parsed (Python's parser recurses once per level).

    Raises:
        DocumentError: nested deeper than ``max_depth``, or a NaN or infinity.
        ValueError: not JSON (``json.JSONDecodeError``, or an integer of over 4,300 digits).
    """
    if json_depth(text, max_depth) > max_depth:
        raise DocumentError(f"nested deeper than {max_depth} levels, which no such file is")
    return json.loads(text, parse_constant=_refuse_constant)


def yaml_document(text: str, max_depth: int = MAX_DOCUMENT_DEPTH, unique_keys: bool = False) -> Any:
    """A YAML document read safely, refusing what makes a small file explode: aliases (a few
    hundred bytes of them expand to gigabytes, or loop) and nesting beyond ``max_depth``;
    both found in the parser's events, before anything is built.

    Args:
        unique_keys: refuse a key given twice in one mapping (YAML silently keeps the last).

    Raises:
        DocumentError: an alias, nested deeper than ``max_depth``, or a key given twice.
        yaml.YAMLError: not YAML.
    """
    import yaml

    depth = 0
    for event in yaml.parse(text, Loader=yaml.SafeLoader):
        if isinstance(event, yaml.AliasEvent):
            raise DocumentError(f"an alias (*{event.anchor}): such a file spells its values out")
        if isinstance(event, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
            depth += 1
            if depth > max_depth:
                raise DocumentError(f"nested deeper than {max_depth} levels, which no such file is")
        elif isinstance(event, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
            depth -= 1
    if not unique_keys:
        return yaml.safe_load(text)

    class _UniqueKeys(yaml.SafeLoader):
        def construct_mapping(self, node: Any, deep: bool = False) -> dict[Any, Any]:
            keys = [self.construct_object(key, deep=deep) for key, _ in node.value]
            twice = sorted({str(k) for k in keys if keys.count(k) > 1})
            if twice:
                raise DocumentError(f"{', '.join(twice)} given twice")
            return super().construct_mapping(node, deep=deep)

    return yaml.load(text, Loader=_UniqueKeys)
