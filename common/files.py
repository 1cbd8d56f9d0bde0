"""Writing results whole or not at all, and never over what the user has.

Every writer in markergraph goes through :func:`written_whole` (one file) or
:func:`result_folder` (a folder of files). Both write under a temporary name of this run's own
(``.NAME.partial-<pid>-<token>``) beside the target and rename it into place at the end, so at
every instant the target's name holds nothing, the old whole result, or the new whole result.
A run that was killed leaves its temporary folder behind; the next run aimed at the same target
recognises it by its dead process id and removes it.

A folder is replaced only when it is empty, or when markergraph wrote it (its ``report.json``
has a ``schema`` beginning with :data:`REPORT_SCHEMA_PREFIX` and lists every file in it under
:data:`MANIFEST_KEY`: a folder to which the user added anything is not replaced), and never when
it is or holds an input.
"""

from __future__ import annotations

import ctypes
import errno
import json
import os
import re
import shutil
import signal
import sys
import threading
from collections.abc import Iterable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

from markergraph.common.errors import OutputError

__all__ = [
    "MANIFEST_KEY",
    "REPORT_SCHEMA_PREFIX",
    "check_output_file",
    "check_output_folder",
    "files_in",
    "result_folder",
    "written_whole",
]

# Any version of the application layer's report.json schema marks a folder as ours.
REPORT_SCHEMA_PREFIX = "markergraph.report/"
MANIFEST_KEY = "files"  # report.json lists every file of the result folder under this key


def files_in(folder: Path, also: Iterable[Path] = ()) -> list[Path]:
    """Every file below ``folder``, relative to it and sorted, and the files ``also`` (below it,
    still being written there: figures being drawn) as if they were already there."""
    found = {p for p in folder.rglob("*") if p.is_file()} | set(also)
    return sorted(p.relative_to(folder) for p in found)


_TEMPORARY = re.compile(r"^\.(?P<name>.+)\.(?P<kind>partial|old)-(?P<pid>\d+)-[0-9a-f]+$")


def _temporary_name(target: Path, kind: str) -> Path:
    return target.with_name(f".{target.name}.{kind}-{os.getpid()}-{os.urandom(4).hex()}")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def clean_stale(target: Path) -> None:
    """Remove what killed runs left beside ``target``: their half-written temporary files and
    folders; an old result moved aside just before a run died is put back if the name is free."""
    target = Path(target)
    if not target.parent.is_dir():
        return
    for entry in target.parent.iterdir():
        match = _TEMPORARY.match(entry.name)
        if match is None or match["name"] != target.name or _alive(int(match["pid"])):
            continue
        if match["kind"] == "old" and not os.path.lexists(target):
            with suppress(OSError):
                _rename_no_replace(entry, target)
                continue
        _remove(entry)


def _rename_no_replace(source: Path, target: Path) -> None:
    """Rename, failing with FileExistsError if ``target`` exists (even as an empty folder,
    which a plain rename would silently replace): Linux's renameat2(RENAME_NOREPLACE)."""
    renameat2 = getattr(_LIBC, "renameat2", None) if _LIBC is not None else None
    if renameat2 is not None:
        at_fdcwd, rename_noreplace = -100, 1
        if renameat2(at_fdcwd, os.fsencode(source), at_fdcwd, os.fsencode(target),
                     rename_noreplace) == 0:  # fmt: skip
            return
        code = ctypes.get_errno()
        if code not in (errno.EINVAL, errno.ENOSYS):  # else: the file system lacks the flag
            raise OSError(code, os.strerror(code), str(target))
    if os.path.lexists(target):
        raise FileExistsError(errno.EEXIST, "exists", str(target))
    try:
        os.rename(source, target)
    except OSError as error:
        if error.errno in (errno.ENOTEMPTY, errno.EEXIST):
            raise FileExistsError(errno.EEXIST, "exists", str(target)) from error
        raise


try:
    _LIBC: ctypes.CDLL | None = ctypes.CDLL(None, use_errno=True)
except OSError:  # pragma: no cover - no C library to load (not Linux or macOS)
    _LIBC = None


def _foreign_entries(folder: Path) -> list[str] | None:
    """What in a result folder markergraph did not write (its report lists every file it
    wrote), or None if the folder is not a markergraph result folder at all."""
    try:
        report = json.loads((folder / "report.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(report, dict) or not str(report.get("schema")).startswith(
        REPORT_SCHEMA_PREFIX
    ):
        return None
    listed = report.get(MANIFEST_KEY)
    if not isinstance(listed, list):
        return None
    ours = {str(name) for name in listed}
    ours |= {str(parent) for name in ours for parent in Path(name).parents if str(parent) != "."}
    return sorted(
        str(entry.relative_to(folder))
        for entry in folder.rglob("*")
        if str(entry.relative_to(folder)) not in ours
    )


def _holds(outer: Path, inner: Path) -> bool:
    return inner == outer or outer in inner.parents


def _absolute(path: Path) -> Path:
    """``path`` made absolute with ``..`` resolved lexically (links are not followed, so a
    link itself can be refused rather than what it points to)."""
    return Path(os.path.abspath(path))


def _check_place(out: Path, flag: str = "--out") -> None:
    """The place to write at: not the folder we are in or one holding it, and under a folder."""
    here = Path.cwd()
    if _holds(_absolute(out), here):
        raise OutputError(f"{flag} {out} is the folder you are in, or holds it; choose another")
    ancestor = _absolute(out).parent
    while not ancestor.exists():
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise OutputError(f"cannot write {out}: {ancestor} is a file, not a folder")


def _in_rosbag(out: Path) -> Path | None:
    """The rosbag2 folder ``out`` would land in, if any: its parent if that holds a
    ``metadata.yaml``, or a folder further up whose ``metadata.yaml`` is a rosbag2 one (a bag's
    subfolder is the bag's too; an unrelated ``metadata.yaml`` far up does not forbid a tree)."""
    parent = _absolute(out).parent
    if (parent / "metadata.yaml").is_file():
        return parent
    for folder in parent.parents:
        if _is_rosbag2_metadata(folder / "metadata.yaml"):
            return folder
    return None


def _is_rosbag2_metadata(path: Path) -> bool:
    """Whether ``path`` is a rosbag2 ``metadata.yaml`` (its first KB names the bag's key)."""
    try:
        with open(path, "rb") as stream:
            return b"rosbag2_bagfile_information" in stream.read(1024)
    except OSError:  # absent, a folder, unreadable: not a bag we can tell of
        return False


def _check_not_in_rosbag(out: Path) -> None:
    """Refuse an output inside a rosbag2 folder, an input or not: the one check every writer
    of a file or a folder makes (a bag is the user's recording; ``ros2 bag`` owns its folder).

    Raises:
        OutputError: naming ``out`` and the bag's folder.
    """
    bag = _in_rosbag(out)
    if bag is not None:
        raise OutputError(f"--out {out} is inside the rosbag2 folder {bag}; choose another place")


def _check_inputs(out: Path, inputs: Iterable[Path], relation: str, kind: str) -> None:
    """Refuse an output that is or holds an input, or lies inside an input folder."""
    resolved = out.resolve()
    for source in inputs:
        source = Path(source).resolve()
        if _holds(resolved, source):
            raise OutputError(f"--out {out} {relation} {source}; choose another {kind}")
        if source.is_dir() and _holds(source, resolved):
            raise OutputError(f"--out {out} is inside the input folder {source}")


def check_output_folder(out: Path, inputs: Iterable[Path], *, force: bool) -> None:
    """Refuse, before any work, a result folder that would harm the user's files.

    Raises:
        OutputError: ``out`` is or holds an input, lies inside an input folder or a rosbag2
            folder, is the current folder, is a file or a link, exists without ``force``, or
            exists with ``force`` but holds anything markergraph did not write.
    """
    out = Path(out)
    _check_inputs(out, inputs, "holds the input", "folder")
    _check_not_in_rosbag(out)
    _check_place(out)
    if not os.path.lexists(out):
        return
    if out.is_symlink() or not out.is_dir():
        raise OutputError(f"--out {out} is a file or link, not a result folder; refusing it")
    if not force:
        raise OutputError(f"{out} exists; pass --force to replace it")
    if not any(out.iterdir()):
        return
    foreign = _foreign_entries(out)
    if foreign is None:
        raise OutputError(
            f"{out} is not a markergraph result folder (no report.json of ours listing its "
            "files): --force replaces only those; choose another --out"
        )
    if foreign:
        shown = ", ".join(foreign[:3]) + (
            f" and {len(foreign) - 3} more" if len(foreign) > 3 else ""
        )
        raise OutputError(
            f"{out} holds what markergraph did not write ({shown}); --force will not delete "
            "it: move it out or choose another --out"
        )
    protected = _write_protected(out)
    if protected is not None:
        raise OutputError(
            f"{out} cannot be replaced: {protected} is write-protected, and --force will not "
            "delete a result you protected; make it writable or choose another --out"
        )


def _write_protected(folder: Path) -> Path | None:
    """The first entry of ``folder`` this process may not delete, or None.

    As ``rm -r`` without ``-f`` asks before deleting one: a folder that is not writable (its
    entries cannot be unlinked) or a file that is not (``chmod a-w``, or immutable, which even
    root may not delete). Checked before any work, so that a replacement cannot move the old
    result aside and then fail to delete it, which left it hidden as ``.NAME.old-...``.
    """
    for root, _folders, files in os.walk(folder):
        here = Path(root)
        if not os.access(here, os.W_OK | os.X_OK):
            return here
        for name in files:
            path = here / name
            if not path.is_symlink() and not os.access(path, os.W_OK):
                return path
    return None


def check_output_file(out: Path, inputs: Iterable[Path], *, force: bool) -> None:
    """Refuse, before any work, an output file that is an input or lies inside an input folder
    or a rosbag2 folder, a folder, an existing file without ``force``, or a place under no
    folder.

    Raises:
        OutputError: naming ``out`` and why.
    """
    out = Path(out)
    _check_inputs(out, inputs, "is the input", "file")
    _check_not_in_rosbag(out)
    if out.is_dir():
        raise OutputError(f"--out {out} is a folder; name a file")
    if os.path.lexists(out) and not force:
        raise OutputError(f"{out} exists; pass --force to overwrite it")
    if not out.parent.is_dir():
        raise OutputError(f"cannot write {out}: {out.parent} is not a folder")


_HELD = (signal.SIGINT, signal.SIGTERM)


@contextmanager
def _signals_held() -> Iterator[None]:
    """SIGINT and SIGTERM held back while the block runs, delivered when it ends.

    Around the renames that install a result and the removal of what is left: a signal's
    ``KeyboardInterrupt`` raised half-way through them would leave a temporary folder, or the
    old result moved aside, hidden beside the target. Held only in the main thread, where Python
    runs its handlers (``pthread_sigmask`` holds them for the calling thread).
    """
    if threading.current_thread() is not threading.main_thread() or not hasattr(
        signal, "pthread_sigmask"
    ):
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, _HELD)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)  # a held signal's handler runs here


def _signal_pending() -> bool:
    """Whether SIGINT or SIGTERM is held back, waiting (see :func:`_signals_held`): a run
    asked to stop before its result went in should not put it in."""
    return hasattr(signal, "sigpending") and bool(set(_HELD) & signal.sigpending())


@contextmanager
def written_whole(path: Path) -> Iterator[Path]:
    """A temporary path beside ``path`` to write one file to; renamed onto ``path`` when the
    block ends, or removed if it raises."""
    path = _absolute(path)
    clean_stale(path)
    partial = _temporary_name(path, "partial")
    try:
        yield partial
        with _signals_held():
            stopping = _signal_pending()  # then its handler, run as the block ends, stops us
            if not stopping:
                os.replace(partial, path)
        if stopping:  # a handler that did not raise
            raise OutputError(f"a signal came before {path} was written; it was not")
    finally:
        with _signals_held():
            _remove(partial)


@contextmanager
def result_folder(out: Path, *, force: bool = False) -> Iterator[Path]:
    """A temporary folder of this run's own to write a result into; when the block ends it
    takes the name ``out``.

    Replacement is by renames only: the old result (ours, or empty: see
    :func:`check_output_folder`) is moved aside, the new one moved in, then the old deleted.

    Raises:
        OutputError: ``out`` may not be replaced (checked again at the end), or another run
            wrote it meanwhile (this run's result is then discarded).
    """
    check_output_folder(out, (), force=force)
    out = _absolute(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    clean_stale(out)
    partial = _temporary_name(out, "partial")
    aside: Path | None = None
    installed = False
    try:
        # Made inside the try: a signal the moment it exists (which is when a watcher sees it)
        # would otherwise leave it behind.
        partial.mkdir()
        yield partial
        with _signals_held():
            stopping = _signal_pending()  # then its handler, run as the block ends, stops us
            if not stopping:
                aside = _move_aside(out, force=force)
                try:
                    _rename_no_replace(partial, out)
                except FileExistsError:
                    raise OutputError(
                        f"{out} was written by another run meanwhile; this run's result was "
                        "not kept"
                    ) from None
                installed = True
        if stopping:  # a handler that did not raise
            raise OutputError(f"a signal came before {out} was written; this run's was not kept")
    finally:
        with _signals_held():
            _remove(partial)
            if aside is not None and os.path.lexists(aside):
                if installed or os.path.lexists(out):
                    _remove_old(aside, out)
                else:  # the new result did not go in: put the old one back
                    with suppress(OSError):
                        _rename_no_replace(aside, out)


def _move_aside(out: Path, *, force: bool) -> Path | None:
    """The old result at ``out`` moved to a temporary name, checked again first; None if there
    is none.

    Raises:
        OutputError: another run wrote ``out`` meanwhile (without ``force``), or it may no
            longer be replaced.
    """
    if not os.path.lexists(out):
        return None
    if not force:
        raise OutputError(
            f"{out} was written by another run meanwhile; this run's result was not kept"
        )
    check_output_folder(out, (), force=force)
    aside = _temporary_name(out, "old")
    with suppress(FileNotFoundError):  # another run may have moved it meanwhile
        os.rename(out, aside)
    return aside


def _remove_old(aside: Path, out: Path) -> None:
    """Delete the old result moved aside; if some of it will not go (its protection changed
    since the check), say where it is rather than leave it hidden without a word.

    Raises:
        OutputError: naming the hidden folder and what would not go.
    """
    if not aside.is_dir() or aside.is_symlink():
        aside.unlink(missing_ok=True)
        return
    failures: list[str] = []

    def failed(_function: object, path: str, error: object) -> None:
        failures.append(f"{path}: {error[1] if isinstance(error, tuple) else error}")

    if sys.version_info >= (3, 12):
        shutil.rmtree(aside, onexc=failed)
    else:  # onerror, given (type, value, traceback), before 3.12
        shutil.rmtree(aside, onerror=failed)
    if failures:
        raise OutputError(
            f"{out} holds the new result, but the old one, moved aside to {aside}, could not be "
            f"deleted ({failures[0]}); delete it yourself"
        )
