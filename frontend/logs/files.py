"""Which kind of log a path is (an ``.mcap`` file, a rosbag2 folder of MCAP or SQLite files, a
ROS 1 ``.bag``) and which files hold it, decided from the path, ``metadata.yaml`` and each
file's first bytes."""

from __future__ import annotations

from enum import Enum
from pathlib import Path

import yaml

from markergraph.frontend.logs.records import LogError

__all__ = ["MCAP_MAGIC", "ROS1_MAGIC", "LogKind", "log_kind", "mcap_files"]

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


def log_kind(path: Path) -> LogKind:
    """The kind of log at ``path``: a ROS 1 bag by its magic, a SQLite rosbag2 folder by its
    ``metadata.yaml``, MCAP otherwise (whose reader names what is wrong with a bad one)."""
    if path.is_file():
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
    if not path.is_dir():
        raise LogError(f"{path}: no such file or folder")
    metadata = path / "metadata.yaml"
    if metadata.is_file():
        files = [_bag_file(path, name) for name in _relative_file_paths(metadata)]
    else:
        files = sorted(path.glob("*.mcap"))
    if not files:
        raise LogError(f"{path}: a folder with no .mcap files and no metadata.yaml listing any")
    missing = [f for f in files if not f.is_file()]
    if missing:
        raise LogError(f"{path}: metadata.yaml lists {missing[0].name}, which is missing")
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
