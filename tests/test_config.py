"""Settings of the main job from TOML, YAML and flags: same values every way, bad ones named."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import pytest

from markergraph.common.errors import SettingsError
from markergraph.estimator import Method, OdometryNoise, Robust
from markergraph.frontend import FrontendConfig
from markergraph.frontend.camera import CameraMount
from markergraph.frontend.observe import DepthModel
from markergraph.frontend.yaw import YawMethod
from markergraph.settings import (
    ALL_METHODS,
    SETTINGS,
    MapConfig,
    config_toml,
    map_config,
    read_config_file,
)

TOML = """
dictionary = "DICT_6X6_250"
marker_size = 0.15
ids = [3, 1, 2]
method = "all"
home = 2

[marker_sizes]
7 = 0.1

[topics]
color = "/cam/image/compressed"

[camera]
height = 0.45
pitch_deg = 12.5

[noise]
odometry_per_m = 0.02
robust = "cauchy"
"""

YAML = """
dictionary: DICT_6X6_250
marker_size: 0.15
ids: [3, 1, 2]
method: all
home: 2
marker_sizes: {7: 0.1}
topics: {color: /cam/image/compressed}
camera:
  height: 0.45
  pitch_deg: 12.5
noise:
  odometry_per_m: 0.02
  robust: cauchy
"""


def cli(*arguments: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "markergraph.cli", *arguments], capture_output=True, text=True
    )


def test_defaults_are_the_librarys_defaults() -> None:
    """With nothing set, the settings build exactly the library's default objects."""
    config = map_config()
    assert config.frontend == FrontendConfig()
    assert config.frontend.default_mount == CameraMount()
    assert config.odometry_noise() == ("wheel", OdometryNoise())
    assert config.odometry_noise("/vio_node/odom")[0] == "vio"
    assert config.methods == (Method.SLAM,) and config.noise.robust is Robust.HUBER
    assert config.home_id is None and config.workers is None  # auto: as many as help


@pytest.mark.parametrize(("name", "text"), [("robot.toml", TOML), ("robot.yaml", YAML)])
def test_a_file_sets_every_section(tmp_path: Path, name: str, text: str) -> None:
    """TOML and YAML give the same configuration; degrees become radians, ids become ints."""
    path = tmp_path / name
    path.write_text(text)
    config = map_config(read_config_file(path))
    frontend = config.frontend
    assert frontend.dictionary == "DICT_6X6_250" and frontend.marker_sizes.default_m == 0.15
    assert frontend.marker_sizes.by_id == {7: 0.1} and frontend.allowed_ids == (1, 2, 3)
    assert frontend.color_topic == "/cam/image/compressed" and frontend.depth_topic is None
    assert frontend.default_mount.height_m == 0.45
    assert frontend.default_mount.pitch_rad == pytest.approx(math.radians(12.5), abs=1e-15)
    assert frontend.default_mount.x_m == CameraMount().x_m  # untouched keys keep defaults
    assert frontend.method is YawMethod.PNP and frontend.depth_model == DepthModel()
    assert config.methods == ALL_METHODS and config.home_id == 2
    assert config.odometry_noise() == ("wheel", OdometryNoise(per_m=0.02))
    assert config.noise.robust is Robust.CAUCHY


def test_printed_configuration_reads_back_to_the_same_settings(tmp_path: Path) -> None:
    """config_toml writes every setting; reading it back gives the same values, unset ones
    included."""
    source = tmp_path / "robot.toml"
    source.write_text(TOML)
    values = map_config(read_config_file(source)).values
    assert set(values) == {s.key for s in SETTINGS}
    printed = tmp_path / "printed.toml"
    printed.write_text(config_toml(values))
    assert map_config(read_config_file(printed)).values == values
    defaults = tmp_path / "defaults.toml"
    defaults.write_text(config_toml({}))
    assert map_config(read_config_file(defaults)) == map_config()


@pytest.mark.parametrize(
    ("text", "named"),
    [
        ("marker_size = -0.2\n", "marker_size must be positive, got -0.2"),
        ("marker_size = true\n", "marker_size must be a number"),
        ("[camera]\nheight = 'high'\n", "camera.height must be a number"),
        ("[topics]\ncolour = '/a'\n", "unknown setting 'topics.colour'"),
        ("method = 'gps'\n", "method must be one of"),
        ("[marker_sizes]\nseven = 0.1\n", "marker_sizes must be a marker id"),
        ("workers = 0\n", "workers must be a whole number"),
        ("marker_size = \n", "robot.toml: "),  # not TOML at all
    ],
)
def test_bad_file_values_name_the_file_and_key(tmp_path: Path, text: str, named: str) -> None:
    path = tmp_path / "robot.toml"
    path.write_text(text)
    with pytest.raises(ValueError, match=r"robot\.toml") as error:
        read_config_file(path)
    assert named in str(error.value) and "\n" not in str(error.value)


@pytest.mark.slow
def test_flags_override_the_file_and_bad_flags_exit_1(tmp_path: Path) -> None:
    """--config then a flag: the flag wins; printed settings show it. A bad value or file is
    one line on stderr and exit 1."""
    path = tmp_path / "robot.yaml"
    path.write_text(YAML)
    run = cli("map", "--config", str(path), "--marker-size", "0.3", "--marker-sizes", "9=0.05",
              "--print-config")  # fmt: skip
    assert run.returncode == 0, run.stderr
    printed = tmp_path / "printed.toml"
    printed.write_text(run.stdout)
    config = map_config(read_config_file(printed))
    assert config.marker_sizes.default_m == 0.3 and config.marker_sizes.by_id == {9: 0.05}
    assert config.dictionary == "DICT_6X6_250" and config.camera.default_mount.height_m == 0.45
    for arguments, named in (
        (("--marker-size", "-1"), "--marker-size must be positive"),
        (("--marker-sizes", "7:0.1"), "--marker-sizes must be ID=M pairs"),
        (("--config", str(tmp_path / "missing.toml")), "missing.toml"),
        (("--config", str(tmp_path / "robot.ini")), "robot.ini"),
    ):
        run = cli("map", *arguments, "--print-config")
        assert run.returncode == 1 and named in run.stderr
        assert len(run.stderr.strip().splitlines()) == 1


def test_help_explains_every_setting_with_its_default() -> None:
    """`markergraph map --help` lists each setting's flag, its file key and its default."""
    run = cli("map", "--help")
    text = " ".join(run.stdout.split())  # argparse wraps lines
    for setting in SETTINGS:
        assert setting.flag.flag in text and f"file: {setting.key}" in text
        if setting.default not in (None, {}):
            assert f"{setting.key}, default {setting.default}" in text


def test_readme_example_is_a_valid_settings_file(tmp_path: Path) -> None:
    """The TOML example in README.md reads as it says."""
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    block = readme.split("```toml\n", 1)[1].split("```", 1)[0]
    path = tmp_path / "robot.toml"
    path.write_text(block)
    config = map_config(read_config_file(path))
    assert config.marker_sizes.by_id == {7: 0.3} and config.methods == ALL_METHODS
    assert config.frontend.default_mount.pitch_rad == pytest.approx(math.radians(5.0))


@pytest.mark.slow
def test_depth_scale_flag_takes_auto_or_a_number() -> None:
    """--depth-scale auto and --depth-scale 1.012 both reach the settings (each broke once)."""
    import subprocess
    import sys

    for given, expected in (("auto", None), ("1.012", 1.012)):
        run = subprocess.run(
            [sys.executable, "-m", "markergraph.cli", "map", "--depth-scale", given,
             "--print-config"],
            capture_output=True, text=True, check=False,
        )  # fmt: skip
        assert run.returncode == 0, run.stderr
        line = next(x for x in run.stdout.splitlines() if x.startswith("depth_scale"))
        assert ("auto" in line) if expected is None else (str(expected) in line), line
    bad = subprocess.run(
        [sys.executable, "-m", "markergraph.cli", "map", "--depth-scale", "deep", "--print-config"],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert bad.returncode == 1 and "--depth-scale" in bad.stderr


def test_every_setting_is_declared_once_with_its_flag_type_and_help() -> None:
    """One declaration per setting: a unique key and flag, a parser (type and bounds), a help
    line, and at least one command that takes it."""
    keys = [s.key for s in SETTINGS]
    flags = [s.flag.flag for s in SETTINGS]
    assert len(set(keys)) == len(keys) and len(set(flags)) == len(flags)
    for setting in SETTINGS:
        assert setting.flag.flag.startswith("--") and setting.flag.commands, setting.key
        assert callable(setting.parse) and callable(setting.flag.type), setting.key
        assert setting.help.strip(), setting.key
        assert setting.check(setting.default) == setting.default, setting.key


def test_defaults_read_back_from_the_printed_file_are_the_same_config(tmp_path: Path) -> None:
    """MapConfig built from the defaults equals the one config_toml's file reads back to,
    section by section."""
    path = tmp_path / "defaults.toml"
    path.write_text(config_toml({}))
    config, read_back = map_config(), map_config(read_config_file(path))
    assert read_back == config
    for section in ("camera", "noise", "odometry", "overlay", "topics", "rig", "marker_sizes"):
        assert getattr(read_back, section) == getattr(config, section), section
    assert read_back.frontend == config.frontend


def test_a_rig_files_tag_sizes_survive_a_written_settings_file(tmp_path: Path) -> None:
    """config_toml of settings naming a tagslam.yaml writes the rig's tag sizes, not the
    default 0.2 m, so the file read back maps at the rig's size (once it beat the rig's)."""
    rig = tmp_path / "tagslam.yaml"
    rig.write_text(
        "bodies:\n - yard:\n     is_static: true\n     default_tag_size: 0.42\n"
        "     type: simple\n     tags:\n     - id: 3\n       size: 0.4\n"
    )
    written = tmp_path / "robot.toml"
    written.write_text(config_toml({"rig.tagslam": str(rig)}))
    config = MapConfig.from_values(read_config_file(written))
    assert config.marker_sizes.default_m == 0.42
    assert config.marker_sizes.of(3) == 0.4


def test_a_marker_size_disagreeing_with_the_rig_files_is_one_line(tmp_path: Path) -> None:
    """--marker-size beside a tagslam.yaml with another default_tag_size made a map of two
    scales (its tags sized one by one kept the file's sizes): now one line naming both."""
    rig = tmp_path / "tagslam.yaml"
    rig.write_text(
        "bodies:\n - yard:\n     is_static: true\n     default_tag_size: 0.16\n"
        "     type: simple\n     tags:\n     - id: 3\n       size: 0.16\n"
    )
    with pytest.raises(SettingsError, match=r"--marker-size 0.1 disagrees with .*tagslam.yaml's "
                       r"default_tag_size 0.16: leave one of them out"):  # fmt: skip
        MapConfig.from_values({"rig.tagslam": str(rig), "marker_size": 0.1})
    assert MapConfig.from_values({"rig.tagslam": str(rig), "marker_size": 0.16}).marker_sizes.of(5)


EXPLODING = {
    # A 350-byte billion laughs under a real key: eight levels of nine aliases would build 43
    # million strings; refused at the first alias, before anything is built.
    "laughs.yaml": "a: &a [x, x, x, x, x, x, x, x, x]\n"
    + "".join(
        f"{c}: &{c} [{', '.join([f'*{p}'] * 9)}]\n"
        for p, c in zip("abcdefg", "bcdefgh", strict=True)
    )
    + "dictionary: *h\n",
    "recursive.yaml": "&a a: *a\n",
    "deep.yaml": "dictionary: " + "[" * 5000 + "]" * 5000 + "\n",
    "deep.toml": "dictionary = " + "[" * 5000 + "]" * 5000 + "\n",
    "twice.yaml": "dictionary: DICT_4X4_50\nmarker_size: 0.1\ndictionary: DICT_5X5_50\n",
}


@pytest.mark.parametrize("name", sorted(EXPLODING))
def test_settings_files_that_explode_or_mislead_are_refused_in_one_line(
    tmp_path: Path, name: str
) -> None:
    """Aliases, deep nesting and a key given twice are refused by name, as one line and exit 1,
    in a fraction of a second and without the memory they would take."""
    path = tmp_path / name
    path.write_text(EXPLODING[name], encoding="utf-8")
    run = cli("map", "--config", str(path), "--print-config")
    assert run.returncode == 1, run.stdout
    assert name in run.stderr and len(run.stderr.strip().splitlines()) == 1
    assert "Traceback" not in run.stderr


def test_a_byte_order_mark_and_a_survey_path_relative_to_the_file(tmp_path: Path) -> None:
    """A TOML file an editor saved with a byte-order mark reads as without one, and --survey in
    a settings file is a path relative to that file, as the rig's files are."""
    path = tmp_path / "rig" / "robot.toml"
    path.parent.mkdir()
    path.write_text('\ufeffdictionary = "DICT_5X5_50"\n[rig]\nsurvey = "tags.csv"\n', "utf-8")
    values = read_config_file(path)
    assert values["dictionary"] == "DICT_5X5_50"
    assert values["rig.survey"] == str(tmp_path / "rig" / "tags.csv")
