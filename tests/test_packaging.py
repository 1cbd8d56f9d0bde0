"""The wheel holds every subpackage under markergraph.*, and nothing shadows other packages."""

from __future__ import annotations

import json
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
SUBPACKAGES = ("estimator", "frontend", "datasets", "cli")
# Top-level names our folders would shadow if they leaked onto sys.path (Hugging Face `datasets`).
SHADOW_CANDIDATES = ("datasets", "frontend", "estimator", "cli", "app")

PROBE = """
import importlib.util, json, sys
names = sys.argv[1:]
print(json.dumps({n: getattr(importlib.util.find_spec(n), "origin", None) for n in names}))
"""


def probe_origins(names: list[str], cwd: Path, python_args: list[str] | None = None) -> dict:
    """Where each module name resolves in a fresh interpreter started in ``cwd``."""
    out = subprocess.run(
        [sys.executable, *(python_args or []), "-c", PROBE, *names],
        cwd=cwd,
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    return json.loads(out)


@pytest.fixture(scope="module")
def wheel_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out_dir = tmp_path_factory.mktemp("wheel")
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--quiet",
            "--no-deps",
            "--no-build-isolation",
            "--wheel-dir",
            str(out_dir),
            str(REPO_ROOT),
        ],
        check=True,
        capture_output=True,
    )
    (wheel,) = out_dir.glob("markergraph-*.whl")
    return wheel


def test_wheel_contains_every_subpackage(wheel_path: Path) -> None:
    """Each folder ships as markergraph/<name>/ with its py.typed, and never at the top level."""
    names = set(zipfile.ZipFile(wheel_path).namelist())
    for package in SUBPACKAGES:
        assert f"markergraph/{package}/__init__.py" in names
        assert f"markergraph/{package}/py.typed" in names
    assert "markergraph/estimator/paper.py" in names
    # app/ is the root package itself: the public API and the application layer
    root = {"markergraph/__init__.py", "markergraph/py.typed", "markergraph/formats/tum.py"}
    assert root <= names
    top_level = {name.split("/")[0] for name in names}
    assert not top_level & set(SHADOW_CANDIDATES)


def test_installed_wheel_imports_under_markergraph_only(wheel_path: Path, tmp_path: Path) -> None:
    """From the installed wheel alone, markergraph.* resolves and `datasets` does not."""
    target = tmp_path / "site"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "install",
            "--quiet",
            "--no-deps",
            "--target",
            str(target),
            str(wheel_path),
        ],
        check=True,
        capture_output=True,
    )
    # -S skips site-packages' .pth files (and so the editable finder); dependencies come after.
    site_packages = sysconfig.get_paths()["purelib"]
    script = f"import sys; sys.path[:0] = [{str(target)!r}, {site_packages!r}]\n" + PROBE
    out = subprocess.run(
        [
            sys.executable,
            "-S",
            "-c",
            script,
            "markergraph",
            *(f"markergraph.{p}" for p in SUBPACKAGES),
            *SHADOW_CANDIDATES,
        ],
        cwd=tmp_path,
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    origins = json.loads(out)
    for package in ("markergraph", *(f"markergraph.{p}" for p in SUBPACKAGES)):
        assert origins[package].startswith(str(target))
    for name in SHADOW_CANDIDATES:
        origin = origins[name]
        assert origin is None or not origin.startswith((str(target), str(REPO_ROOT))), name


def test_editable_install_does_not_shadow_top_level_names(tmp_path: Path) -> None:
    """With the editable install, `import datasets` / `frontend` never find our folders."""
    origins = probe_origins(["markergraph.datasets", *SHADOW_CANDIDATES], cwd=tmp_path)
    assert origins["markergraph.datasets"] is not None
    for name in SHADOW_CANDIDATES:
        origin = origins[name]
        assert origin is None or not origin.startswith(str(REPO_ROOT)), name


def test_cli_version_and_help() -> None:
    """`markergraph --version` prints the installed version; `--help` lists the subcommands."""
    from importlib.metadata import version

    result = subprocess.run(
        [sys.executable, "-m", "markergraph.cli", "--version"],
        check=True,
        capture_output=True,
        text=True,
    )
    assert result.stdout.strip() == f"markergraph {version('markergraph')}"
    help_text = subprocess.run(
        [sys.executable, "-m", "markergraph.cli", "--help"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    for command in ("map", "detect", "simulate", "info", "export", "heading"):
        assert command in help_text


TEST_ONLY = ("pytest", "hypothesis", "mypy", "ruff", "jupytext", "nbclient", "nbformat", "evo",
             "ipykernel", "foxglove_schemas_protobuf", "types_tqdm", "xdist")  # fmt: skip
BLOCKED_RUN = """
import importlib.abc, sys
class TestOnly(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ImportError(f"{name} is a test-only package")
sys.meta_path.insert(0, TestOnly())
from markergraph.cli import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.slow
def test_the_main_job_needs_no_test_package(tmp_path: Path) -> None:
    """README's main job installs without the test extra: simulate, info and map run with every
    package of that extra made unimportable."""
    sections = (REPO_ROOT / "README.md").read_text(encoding="utf-8").split("\n## ")
    installs = [
        line
        for section in sections
        if "test" not in section.splitlines()[0].lower()  # the tests' own set-up may
        for line in section.splitlines()
        if "pip install" in line
    ]
    assert installs and not [line for line in installs if "[test" in line]
    script = f"BLOCKED = {TEST_ONLY!r}\n" + BLOCKED_RUN
    log, out = tmp_path / "room.mcap", tmp_path / "map"
    for arguments in (
        ["simulate", "--scenario", "paper-room", "--duration", "8", "--frame-rate", "3",
         "--out", log],
        ["info", log],
        ["map", log, "--out", out, "--workers", "1"],
    ):  # fmt: skip
        run = subprocess.run(
            [sys.executable, "-c", script, *map(str, arguments)], capture_output=True, text=True
        )
        assert run.returncode == 0, run.stderr[-2000:]
    assert (out / "map.json").is_file() and (out / "map.png").is_file()
