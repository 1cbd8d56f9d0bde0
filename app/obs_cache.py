"""A log's extraction, and the camera-delay and odometry-scale searches run on it, kept in the
cache folder so that a re-run with other estimator settings reads no image.

An entry is keyed by the log's identity (resolved path, size, mtime_ns, a hash of its first and
last MB) and the front end's settings (:class:`~markergraph.frontend.FrontendConfig`, with the
identity of each file it names); the searches inside it are keyed again by what they depend on
(:func:`search_key`). Entries are written whole, read only when their version and key match
(a corrupt one is ignored, then rewritten), and the least recently used are removed once the
folder holds more than :data:`MAX_CACHE_BYTES`. ``MARKERGRAPH_NO_CACHE=1`` (or ``--no-cache``)
turns it off.

Entries are pickles: the folder is the user's own, as trusted as the installed code.
"""

from __future__ import annotations

import hashlib
import os
import pickle
from collections.abc import Iterable
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from markergraph.common.cache import cache_dir
from markergraph.common.files import written_whole
from markergraph.frontend import Extraction, FrontendConfig

__all__ = [
    "CACHE_VERSION",
    "MAX_CACHE_BYTES",
    "NO_CACHE_ENV",
    "CacheEntry",
    "cache_enabled",
    "cache_folder",
    "entry_key",
    "load_entry",
    "search_key",
    "store_entry",
]

CACHE_VERSION = 9  # 9: a size given to all measured on its markers; 8: the depth scale's sigma
"""Raised whenever what an entry holds changes (its shape, or the wording of the notes it keeps):
older entries are then ignored."""
MAX_CACHE_BYTES = 10**9
"""The folder's bound (1 GB of 10^9 bytes): least recently used entries go first."""
NO_CACHE_ENV = "MARKERGRAPH_NO_CACHE"
EDGE_BYTES = 1 << 20  # the first and last MB: a rewritten log differs there (MCAP's summary)
SUFFIX = ".extraction"


@dataclass
class CacheEntry:
    """One log's extraction and the searches run on it.

    Attributes:
        version: :data:`CACHE_VERSION` when written.
        key: :func:`entry_key` of the log and front-end settings.
        extraction: the front end's result.
        searches: :func:`search_key` -> the search's result: (a delay [ns], its sigma) or (a
            scale, its sigma), each None where the residuals had no minimum; the misread
            sightings found.
        path: where the entry lives (not stored).
        hit: whether it was read from the cache (not stored).
    """

    version: int
    key: str
    extraction: Extraction
    searches: dict[str, Any] = field(default_factory=dict)
    path: Path | None = None
    hit: bool = False


def cache_enabled() -> bool:
    """False when ``MARKERGRAPH_NO_CACHE`` is set to anything but empty or 0."""
    return os.environ.get(NO_CACHE_ENV, "") in ("", "0")


def cache_folder() -> Path:
    """``extractions/`` in markergraph's cache folder (``$MARKERGRAPH_CACHE``, else
    ``$XDG_CACHE_HOME/markergraph`` or ``~/.cache/markergraph``)."""
    return cache_dir() / "extractions"


def _file_identity(path: Path) -> str:
    """Size, mtime_ns and a hash of the first and last MB of one file."""
    stat = path.stat()
    digest = hashlib.sha256()
    with open(path, "rb") as stream:
        digest.update(stream.read(EDGE_BYTES))
        if stat.st_size > EDGE_BYTES:
            stream.seek(max(EDGE_BYTES, stat.st_size - EDGE_BYTES))
            digest.update(stream.read(EDGE_BYTES))
    return f"{stat.st_size}:{stat.st_mtime_ns}:{digest.hexdigest()}"


def log_identity(log: Path) -> str:
    """A log's identity: its resolved path and each of its files' identities (a rosbag2 folder
    has several)."""
    path = Path(log).resolve()
    if not path.is_dir():
        return f"{path}|{_file_identity(path)}"
    files = sorted(p for p in path.rglob("*") if p.is_file())
    return f"{path}|" + "|".join(f"{p.relative_to(path)}={_file_identity(p)}" for p in files)


def _frontend_identity(config: FrontendConfig) -> str:
    """Every front-end setting (each changes what is extracted), with the identity of each file
    one names (its content may change under the same name)."""
    parts = [repr(config)]
    for f in fields(config):
        value = getattr(config, f.name)
        if isinstance(value, Path) and value.is_file():
            parts.append(f"{f.name}={_file_identity(value)}")
    return "|".join(parts)


def entry_key(log: Path, config: FrontendConfig) -> str:
    """The key of a log's extraction with these front-end settings (a hex digest)."""
    text = f"{CACHE_VERSION}|{log_identity(log)}|{_frontend_identity(config)}"
    return hashlib.sha256(text.encode()).hexdigest()


def search_key(name: str, *settings: object) -> str:
    """The key of one search (``delay and sigma``, ``scale and sigma``, ``misreads``) under
    the settings it depends on."""
    return f"{name}|" + "|".join(map(repr, settings))


def _entry_path(key: str, folder: Path) -> Path:
    return folder / f"{key[:32]}{SUFFIX}"


def load_entry(key: str, folder: Path | None = None) -> CacheEntry | None:
    """The entry under ``key``, or None when there is none or it cannot be trusted (unreadable,
    another version, another key): such an entry is then rewritten by :func:`store_entry`."""
    path = _entry_path(key, folder or cache_folder())
    try:
        entry = pickle.loads(path.read_bytes())
    except FileNotFoundError:
        return None
    except Exception:  # any damage (truncation, a class since changed) is a miss
        return None
    if not (
        isinstance(entry, CacheEntry)
        and entry.version == CACHE_VERSION
        and entry.key == key
        and isinstance(entry.extraction, Extraction)
    ):
        return None
    os.utime(path)  # used now: the last to be removed
    entry.path, entry.hit = path, True
    return entry


def store_entry(
    entry: CacheEntry, folder: Path | None = None, limit_bytes: int = MAX_CACHE_BYTES
) -> Path | None:
    """Write the entry whole, then remove the least recently used entries beyond the bound.

    Returns:
        Where it was written, or None when the cache folder cannot be written (the run goes on
        without it).
    """
    folder = folder or cache_folder()
    path = _entry_path(entry.key, folder)
    stored = CacheEntry(entry.version, entry.key, entry.extraction, dict(entry.searches))
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with written_whole(path) as partial:
            partial.write_bytes(pickle.dumps(stored, protocol=pickle.HIGHEST_PROTOCOL))
    except OSError:
        return None
    entry.path = path
    _prune(folder.glob(f"*{SUFFIX}"), limit_bytes, keep=path)
    return path


def _prune(entries: Iterable[Path], limit_bytes: int, keep: Path) -> None:
    """Remove the least recently used entries until the rest fit in ``limit_bytes`` (the one
    just written stays, even alone over the bound)."""
    listed = []
    for path in entries:
        try:
            stat = path.stat()
        except OSError:
            continue
        listed.append((stat.st_mtime_ns, stat.st_size, path))
    total = sum(size for _, size, _ in listed)
    for _, size, path in sorted(listed):
        if total <= limit_bytes:
            break
        if path == keep:
            continue
        path.unlink(missing_ok=True)
        total -= size
