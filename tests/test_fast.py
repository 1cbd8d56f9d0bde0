"""Start-up: ``markergraph --help``, ``info`` and ``detect`` import only what they use (no GTSAM,
filterpy or matplotlib), checked on the modules a real process holds when it ends; and the lazy
packages give the same names as eager imports did."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from markergraph.common.pool import available_cores
from markergraph.datasets import scenario
from markergraph.datasets.rewrite import rewrite_log
from markergraph.datasets.write import write_log

HEAVY = ("gtsam", "filterpy", "matplotlib")  # what the front end's commands never need

# Runs the command as `markergraph` does, then prints which heavy modules the process holds.
PROBE = """
import json, sys
from markergraph.cli import main
try:
    code = main(sys.argv[1:-1])
except SystemExit as stop:  # --help
    code = stop.code
heavy = sorted(set(sys.modules) & set(sys.orig_argv[-1].split(",")))
print(json.dumps({"code": code, "heavy": heavy}))
"""


def held_modules(
    argv: list[str], cwd: Path, watched: tuple[str, ...] = HEAVY
) -> tuple[int, list[str]]:
    """(the exit code, which of the ``watched`` modules it loaded) of one command in a fresh
    process."""
    done = subprocess.run(
        [sys.executable, "-c", PROBE, *argv, ",".join(watched)],
        capture_output=True, text=True, cwd=cwd, timeout=600, check=True,
    )  # fmt: skip
    report = json.loads(done.stdout.strip().splitlines()[-1])
    return report["code"], report["heavy"]


@pytest.fixture(scope="module")
def real_like_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A short rendered JPEG log without the simulator's ground truth (a real robot's log has
    none; the truth's marker poses are GTSAM's Pose2 records)."""
    folder = tmp_path_factory.mktemp("fast")
    world, route = scenario("corridor-loop")
    simulated = folder / "simulated.mcap"
    write_log(world, route, simulated, seed=2, duration_s=8.0, frame_hz=5.0, compressed=True)
    log = folder / "robot.mcap"
    rewrite_log(simulated, log, lambda topic, _, m: None if "ground_truth" in topic else m)
    return log


@pytest.mark.parametrize(
    "command",
    [["--help"], ["detect", "--help"], ["info", "LOG"], ["detect", "LOG", "--out", "o.jsonl"]],
    ids=["help", "detect-help", "info", "detect"],
)
def test_front_end_commands_import_no_solver_or_plots(
    real_like_log: Path, tmp_path: Path, command: list[str]
) -> None:
    """--help, info and detect (in one process and with workers) run to their end without
    importing GTSAM, filterpy or matplotlib."""
    argv = [str(real_like_log) if word == "LOG" else word for word in command]
    for workers in (["--workers", "1"], ["--workers", "2"]) if "o.jsonl" in argv else ([],):
        code, heavy = held_modules([*argv, *workers, *(["--force"] if workers else [])], tmp_path)
        assert code == 0
        assert heavy == []
    if "o.jsonl" in argv:  # it did detect: the observations are there
        assert len((tmp_path / "o.jsonl").read_text().splitlines()) > 10


def test_probe_sees_a_solver_when_one_is_imported(real_like_log: Path, tmp_path: Path) -> None:
    """The probe is not blind: `map` solves its graph with GTSAM; it draws with matplotlib in a
    process of its own where a second core is free (markergraph.plotter), else in its own; and
    a recorded log's map never loads the simulator's writer (the bundled sample's alone)."""
    writer = "markergraph.datasets.write"
    argv = ["map", str(real_like_log), "--out", "m", "--no-cache"]
    code, heavy = held_modules(argv, tmp_path, (*HEAVY, writer))
    assert code == 0
    assert "gtsam" in heavy
    assert ("matplotlib" in heavy) == (available_cores() < 2)
    assert (tmp_path / "m" / "map.png").stat().st_size > 0
    assert writer not in heavy


def test_lazy_packages_give_the_exported_names() -> None:
    """A package's export keeps its name where a submodule has the same one (estimate, observe),
    whichever is imported first, as with eager imports."""
    import markergraph.estimator.estimate  # the submodule named as the function
    import markergraph.frontend.observe  # noqa: F401  # the same
    from markergraph import estimator, frontend
    from markergraph.estimator import Estimate, estimate
    from markergraph.estimator.run import estimate as run_estimate
    from markergraph.frontend.observe import observe

    assert estimate is run_estimate and estimator.estimate is run_estimate
    assert estimator.Estimate is Estimate is sys.modules["markergraph.estimator.estimate"].Estimate
    assert frontend.observe is observe and callable(frontend.observe)
    assert set(estimator.__all__) <= set(dir(estimator))
    with pytest.raises(AttributeError, match="no_such_name"):
        _ = estimator.no_such_name  # type: ignore[attr-defined]


EXACT = 1e-9  # closed form against GTSAM's own Expmap/Logmap: rounding only


def test_odometry_pose_without_gtsam_matches_gtsam() -> None:
    """Trajectory.at_xy_yaw (numpy, what detect writes) equals GTSAM's SE(2) interpolation
    (Trajectory.at) at stamps between, before and after the samples, turns of any size."""
    import numpy as np

    from markergraph.estimator.trajectory import Trajectory

    rng = np.random.default_rng(30)
    for turn in (0.0, 1e-12, 0.3, 3.1):
        t_ns = np.cumsum(rng.integers(10_000_000, 30_000_000, 50))
        poses = np.column_stack([
            np.cumsum(rng.normal(0.0, 0.2, 50)),
            np.cumsum(rng.normal(0.0, 0.2, 50)),
            np.cumsum(rng.uniform(-turn, turn, 50)),
        ])  # fmt: skip
        path = Trajectory(t_ns, poses, "odom")
        stamps = rng.integers(int(t_ns[0]) - 200_000_000, int(t_ns[-1]) + 200_000_000, 400)
        for t in [*stamps.tolist(), *t_ns.tolist()]:
            pose, mine = path.at(t), path.at_xy_yaw(t)
            assert (pose is None) == (mine is None)
            if pose is not None and mine is not None:
                np.testing.assert_allclose(mine[:2], [pose.x(), pose.y()], atol=EXACT)
                assert abs(math.remainder(mine[2] - pose.theta(), 2 * math.pi)) < EXACT
