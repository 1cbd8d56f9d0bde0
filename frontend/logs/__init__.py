"""markergraph.frontend.logs: reading logs without ROS, through one handle per log.

:func:`open_log` decides once what a path is (an ``.mcap`` file, a rosbag2 folder of MCAP or
SQLite files, a ROS 1 ``.bag``), finds its files and reads each MCAP file's summary; the
:class:`Log` it returns gives the topics, the time range, each topic's times and the decoded
messages. Modules: ``files`` (the kind and the files), ``mcap`` and ``chunks`` (MCAP, chunk by
chunk), ``scan`` (reads bounded by the file; an index rebuilt where it is lost), ``times``
(topic times from MCAP indexes), ``bags`` (ROS 1 and SQLite bags, decoded through ``rosbags``),
``ros1`` (a ROS 1 bag's records, chunk by chunk), ``cdr`` (fast readers of a few ROS 2 types),
``ahead`` (reading in a thread).
"""

from typing import TYPE_CHECKING

from markergraph.common.lazy import lazy_package

if TYPE_CHECKING:
    from markergraph.frontend.logs.ahead import read_ahead
    from markergraph.frontend.logs.files import LogKind
    from markergraph.frontend.logs.log import Log, open_log
    from markergraph.frontend.logs.records import DecodeFailures, LogError, LogTopic, Message

__all__ = [
    "DecodeFailures",
    "Log",
    "LogError",
    "LogKind",
    "LogTopic",
    "Message",
    "open_log",
    "read_ahead",
]

lazy_package(
    __name__,
    {
        "markergraph.frontend.logs.ahead": ("read_ahead",),
        "markergraph.frontend.logs.files": ("LogKind",),
        "markergraph.frontend.logs.log": (
            "Log",
            "open_log",
        ),
        "markergraph.frontend.logs.records": (
            "DecodeFailures",
            "LogError",
            "LogTopic",
            "Message",
        ),
    },
)
