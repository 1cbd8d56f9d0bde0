"""Damaged logs through the commands a user runs: seeded mutations of a small simulated MCAP, a
ROS 1 bag (plain and lz4) and a SQLite rosbag2 folder (tests/benchmarks/fuzz_logs.py makes and
runs them), each through ``info`` and ``map``: no crash, no hang, no traceback, one error line
naming the log, no partial output, peak memory under 1 GB. MARKERGRAPH_FUZZ_CASES sets how many
cases run (200 by default, about two minutes on two cores)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).parent / "benchmarks" / "fuzz_logs.py"
CASES = int(os.environ.get("MARKERGRAPH_FUZZ_CASES", "200"))


@pytest.mark.slow
def test_damaged_logs_end_in_one_line_never_a_crash_a_hang_or_a_gigabyte(tmp_path: Path) -> None:
    run = subprocess.run(
        [sys.executable, str(SCRIPT), "--cases", str(CASES), "--work", str(tmp_path), "--json"],
        capture_output=True,
        text=True,
        timeout=60 * 60,
    )
    report = json.loads(run.stdout.splitlines()[-1])
    assert report["cases"] == CASES
    assert report["failed"] == 0, json.dumps(report["failures"][:5], indent=1)
    assert report["peak_mb"] < 1024
    assert report["info_can_map_but_map_failed"] == 0
    # Both endings are reached: damage that costs a few messages (most cases), and damage that
    # leaves nothing to map (about one case in ten: a file cut in its first chunks).
    exits = report["map_exits"]
    assert exits.get("0", 0) > CASES // 2 and exits.get("1", 0) > CASES // 20
    assert run.returncode == 0
