"""Which kind of log a path is (an ``.mcap`` file, a rosbag2 folder of MCAP or SQLite files, a
ROS 1 ``.bag``) and which files hold it, decided from the path, ``metadata.yaml`` and each
file's first bytes."""

from __future__ import annotations

from enum import Enum
from pathlib import Path

import yaml

from markergraph.frontend.logs.records import LogError

__all__ = ["MCAP_MAGIC", "ROS1_MAGIC", "LogKind", "check_not_packed", "log_kind", "mcap_files"]

MCAP_MAGIC = b"\x89MCAP0\r\n"
ROS1_MAGIC = b"#ROSBAG V2.0\n"


class LogKind(Enum):
    """How a log is stored, and so which reader reads it."""

    MCAP = "mcap"
    """One ``.mcap`` file, or a rosbag2 folder of them (read here, chunk by chunk)."""
    ROS1 = "ros1"
    """A ROS 1 ``.bag`` (read chunk by chunk here, decoded through ``rosbags``)."""
    SQLITE = "sqlite"
    """A rosbag2 folder stored in SQLite ``.db3`` files (read through ``rosbags``)."""


# A log someone compressed or archived whole, by its first bytes: (what, how to undo it).
# FILE stands for the file's name. (A ROS 1 bag's lz4 or bz2 chunks are inside the bag.)
_PACKED = (
    (b"\x1f\x8b", "gzip", "gunzip -k FILE"),
    (b"BZh", "bzip2", "bunzip2 -k FILE"),
    (b"\xfd7zXZ\x00", "xz", "unxz -k FILE"),
    (b"\x28\xb5\x2f\xfd", "zstd", "unzstd FILE"),
    (b"\x04\x22\x4d\x18", "lz4", "unlz4 FILE"),
    (b"PK\x03\x04", "a zip archive", "unzip FILE"),
    (b"7z\xbc\xaf\x27\x1c", "a 7-Zip archive", "7z x FILE"),
)
_TAR_MAGIC_OFFSET, _TAR_MAGIC = 257, b"ustar"
_PACKED_SUFFIXES = {".gz", ".bz2", ".xz", ".zst", ".zstd", ".lz4"}


def check_not_packed(file: Path) -> None:
    """Refuse a log file that is compressed or archived whole (``robot.bag.bz2``, a ``.zip``),
    saying how to unpack it; the readers would only say it is not a log.

    Raises:
        LogError: naming the file, the compression and the command that undoes it.
    """
    try:
        with open(file, "rb") as stream:
            head = stream.read(_TAR_MAGIC_OFFSET + len(_TAR_MAGIC))
    except OSError:
        return  # the reader names why it cannot be read
    for magic, what, undo in _PACKED:
        if head.startswith(magic):
            compressed = not what.startswith(("a ", "an "))
            inside = "the .mcap, .bag or rosbag2 folder inside"
            if compressed:  # robot.bag.bz2 holds robot.bag
                inside = file.stem if file.suffix in _PACKED_SUFFIXES else "the log"
            raise LogError(
                f"{file}: {'compressed with ' if compressed else ''}{what}, not a log: "
                f"{'decompress' if compressed else 'unpack'} it first "
                f"({undo.replace('FILE', str(file))}) and give markergraph {inside}"
            )
    if head[_TAR_MAGIC_OFFSET:] == _TAR_MAGIC:
        raise LogError(
            f"{file}: a tar archive, not a log: unpack it first (tar -xf {file}) and give "
            "markergraph the .mcap, .bag or rosbag2 folder inside"
        )


def log_kind(path: Path) -> LogKind:
    """The kind of log at ``path``: a ROS 1 bag by its magic, a SQLite rosbag2 folder by its
    ``metadata.yaml``, MCAP otherwise (whose reader names what is wrong with a bad one).

    Raises:
        LogError: a file compressed or archived whole (see :func:`check_not_packed`).
    """
    if path.is_file():
        check_not_packed(path)
        try:
            with open(path, "rb") as stream:
                if stream.read(len(ROS1_MAGIC)) == ROS1_MAGIC:
                    return LogKind.ROS1
        except OSError:
            pass
        return LogKind.MCAP
    metadata = path / "metadata.yaml"
    if path.is_dir() and metadata.is_file():
        try:
            document = yaml.safe_load(metadata.read_text(encoding="utf-8"))
            storage = document["rosbag2_bagfile_information"]["storage_identifier"]
        except (OSError, UnicodeDecodeError, yaml.YAMLError, KeyError, TypeError):
            return LogKind.MCAP  # the MCAP reader names what is wrong with it
        if storage == "sqlite3":
            return LogKind.SQLITE
    return LogKind.MCAP


def check_exists(path: Path) -> None:
    """Raise, naming ``path``, where there is no file or folder there.

    Raises:
        LogError: nothing at ``path``.
    """
    if not path.exists():
        raise LogError(f"{path}: no such file or folder")


def mcap_files(path: Path) -> list[Path]:
    """The MCAP files of a log: the file itself, or a rosbag2 folder's files in order.

    A rosbag2 folder lists its files in ``metadata.yaml`` (``relative_file_paths``); without
    one, its ``.mcap`` files are read in name order. A ``metadata.yaml`` that cannot be read is
    an error, never a silent fallback to whatever ``.mcap`` files the folder holds. Each file's
    magic is checked by the caller, which opens it anyway.

    Raises:
        LogError: no such log, a broken ``metadata.yaml`` or a listed file missing; the message
            names the file.
    """
    if path.is_file():
        return [path]
    check_exists(path)
    metadata = path / "metadata.yaml"
    if metadata.is_file():
        files = [_bag_file(path, name) for name in _relative_file_paths(metadata)]
    else:
        files = sorted(p for p in path.glob("*.mcap") if p.is_file())  # not a folder so named
    if not files:
        raise LogError(f"{path}: a folder with no .mcap files and no metadata.yaml listing any")
    missing = [f for f in files if not f.is_file()]
    if missing:
        raise LogError(f"{path}: metadata.yaml lists {missing[0].name}, which is missing")
    for file in files:  # a bag recorded with file compression holds .mcap.zstd files
        check_not_packed(file)
    return files


def _bag_file(folder: Path, name: str) -> Path:
    """A file a rosbag2 ``metadata.yaml`` lists, inside the bag's folder.

    Raises:
        LogError: the name leads outside the folder (an absolute path or ``..``).
    """
    file = folder / name
    parts = Path(name).parts
    if not file.exists() and len(parts) > 1 and parts[0] == folder.name:
        file = folder.joinpath(*parts[1:])  # Foxy wrote the names under the bag's own folder
    if not file.resolve().is_relative_to(folder.resolve()):
        raise LogError(f"{folder / 'metadata.yaml'}: lists {name}, outside the bag's folder")
    return file


def _relative_file_paths(metadata: Path) -> list[str]:
    """``rosbag2_bagfile_information.relative_file_paths`` of a rosbag2 ``metadata.yaml``.

    Raises:
        LogError: the file is not such a metadata file, naming it.
    """
    try:
        document = yaml.safe_load(metadata.read_text(encoding="utf-8"))
        names = document["rosbag2_bagfile_information"]["relative_file_paths"]
    except (OSError, UnicodeDecodeError, yaml.YAMLError, KeyError, TypeError) as error:
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise LogError(
            f"{metadata}: not a rosbag2 metadata file ({reason}); fix or remove it"
        ) from None
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise LogError(f"{metadata}: relative_file_paths is not a list of file names")
    return names
