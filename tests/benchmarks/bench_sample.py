"""The bundled sample's ``markergraph map`` as a user meets it: whole processes, start-up included.

In a cache folder of its own (the sample log copied in, its mtime kept, so the user's cache is
neither read nor written), it times:

- ``cold``: the first ``map`` of the log: the front end reads every image, the camera delay
  and the odometry scale are searched, the extraction is cached;
- ``warm``: the same command again (the log's observations and both searches from the cache);
- ``noise``: warm with only ``--odometry-noise`` changed (the searches are the sensors', not
  the estimator's: taken from the cache too);
- ``warm --no-plots``: warm without map.png, map.svg and diagnostics.png;
- ``start-up``: ``markergraph map --help``, the imports alone, as the floor of every run.

Each is a separate process, run as an installed package runs (Python's bytecode cache on:
``bench_process.installed_environment``), timed by its wall clock and its CPU time (user +
system: on a machine shared with other work, closer to what an idle one would take); ``-v``'s
stage times are read from its stderr. The warm runs are interleaved over ``--rounds`` rounds
(default 3), best of each printed, so that a moment of load on this shared machine does not
pick the winner.

Usage: python tests/benchmarks/bench_sample.py [--rounds N]
Targets (issues 29, 30): warm under 4 s; noise about 1-2 s beyond start-up.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench_process import installed_environment

from markergraph.datasets.samples import sample_log

SAMPLE = "corridor-loop"
# The installed command beside this Python, as a user runs it.
SCRIPT = Path(sys.executable).parent / "markergraph"
COMMAND = [str(SCRIPT)] if SCRIPT.exists() else [sys.executable, "-m", "markergraph.cli"]
STAGE = re.compile(r"^  (?P<stage>.+): (?P<seconds>[0-9.]+) s$")


def run(args: list[str], env: dict[str, str]) -> tuple[float, float, dict[str, float]]:
    """One ``markergraph`` process: its wall-clock and CPU (user + system) times [s] and
    ``-v``'s stage times."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(
        [*COMMAND, *args],
        env=env, capture_output=True, text=True, check=False,
    )  # fmt: skip
    seconds = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
    if done.returncode:
        raise SystemExit(f"markergraph {' '.join(args)} failed:\n{done.stderr}")
    stages = {}
    for line in done.stderr.splitlines():
        if match := STAGE.match(line):
            name = re.sub(r"/\S*", "<out>", match["stage"])  # the folder's name varies
            stages[name] = stages.get(name, 0.0) + float(match["seconds"])
    return seconds, cpu, stages


def show(name: str, seconds: float, cpu: float, stages: dict[str, float]) -> None:
    parts = ", ".join(f"{stage} {value:.2f}" for stage, value in stages.items())
    print(f"{name:<24} {seconds:6.2f} s wall {cpu:6.2f} s CPU   {parts}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    rounds = parser.parse_args().rounds
    print(f"load: {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} (1 and 5 min), "
          f"{os.cpu_count()} cores")  # fmt: skip
    source = sample_log(SAMPLE)
    with tempfile.TemporaryDirectory() as folder:
        cache = Path(folder) / "cache"
        cache.mkdir()
        shutil.copy2(source, cache / source.name)  # the sample's path there: the same log
        env = {**installed_environment(), "MARKERGRAPH_CACHE": str(cache),
               "OPENBLAS_NUM_THREADS": "1"}  # fmt: skip
        env.pop("MARKERGRAPH_NO_CACHE", None)
        out = ["--out", str(Path(folder) / "out"), "--force", "-v"]
        commands = {
            "warm": ["map", *out],
            "noise": ["map", *out, "--odometry-noise", "0.02"],
            "warm --no-plots": ["map", *out, "--no-plots"],
            "start-up": ["map", "--help"],
        }
        show("cold", *run(["map", *out], env))
        best: dict[str, tuple[float, float, dict[str, float]]] = {}
        for _ in range(rounds):
            for name, args in commands.items():
                measured = run(args, env)
                if name not in best or measured[0] < best[name][0]:
                    best[name] = measured
        for name, measured in best.items():
            show(f"{name} (best)", *measured)
        for i, unit in ((0, "wall"), (1, "CPU")):
            startup = best["start-up"][i]
            print(f"beyond start-up ({unit}): warm {best['warm'][i] - startup:.2f} s, "
                  f"noise {best['noise'][i] - startup:.2f} s, "
                  f"warm --no-plots {best['warm --no-plots'][i] - startup:.2f} s")  # fmt: skip
    print(f"load after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
