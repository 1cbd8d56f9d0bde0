"""Trust, tampered maps: a map.json, survey or tagslam.yaml that was edited, damaged or made to
explode is one line naming the file and the field (the marker id where there is one), exit code
1, the user's files byte-identical and no result written; and a map of as many markers as its
dictionary holds localises within bounded memory."""

from __future__ import annotations

import copy
import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

import gtsam
import numpy as np
import pytest
from trust_helpers import cli, one_line_error, run_with_peak, snapshot

from markergraph.cli import main
from markergraph.datasets import scenario, write_log
from markergraph.estimator.gauge import relative_covariances, relative_covariances_of_groups

EXACT = 1e-12  # exact algebra, reordered
PEAK_RSS_BYTES = 1 << 30  # the bound on any run's peak memory


# --- fixtures --------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def real_map(log: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """The map.json ``markergraph map`` writes for the shared simulated log (three markers of
    DICT_4X4_50), as a document to tamper with."""
    out = tmp_path_factory.mktemp("real") / "result"
    assert main(["map", str(log), "--out", str(out), "--no-plots", "-q"]) == 0
    document = json.loads((out / "map.json").read_text())
    assert [m["id"] for m in document["markers"]] == [0, 1, 2]
    return document


def tampered(real_map: dict[str, Any], folder: Path, name: str, change) -> Path:
    """A copy of the real map changed by ``change(document)``, written as ``name``."""
    document = copy.deepcopy(real_map)
    change(document)
    path = folder / name
    path.write_text(json.dumps(document))
    return path


def refused_everywhere(capsys, log: Path, path: Path, tmp_path: Path, *names: str) -> None:
    """localize, map --prior, export and heading each refuse ``path`` in one line naming it
    and ``names``, exit 1, write nothing and leave every file as it was."""
    before = snapshot(tmp_path)
    commands = (
        ("localize", log, "--map", path, "--out", tmp_path / "loc"),
        ("map", log, "--prior", path, "--out", tmp_path / "refined", "--no-plots"),
        ("export", path, "--format", "csv", "--out", tmp_path / "out.csv"),
        ("heading", path, "--from", "0", "--at", "1,0", "--to", "1"),
    )
    for command in commands:
        code, _, err = cli(capsys, *command)
        assert code == 1, (command[0], err)
        one_line_error(err, str(path), *names)
    assert snapshot(tmp_path) == before
    assert not any(p.name in ("loc", "refined", "out.csv") for p in tmp_path.iterdir())


# --- the cases ------------------------------------------------------------------------


def test_negative_variances_are_refused_naming_the_marker(real_map, log, tmp_path, capsys):
    """A negative variance (GTSAM's ValueError in localize and map --prior, or a silent NaN
    weight) or an asymmetric covariance is refused, naming the marker's id and the field."""

    def negative(document: dict[str, Any]) -> None:
        document["markers"][1]["relative_covariance"][0][0] = -1.0

    def asymmetric(document: dict[str, Any]) -> None:
        document["markers"][2]["covariance"][0][1] += 1.0

    path = tampered(real_map, tmp_path, "negative.json", negative)
    refused_everywhere(capsys, log, path, tmp_path, "marker 1", "relative_covariance",
                       "positive semi-definite")  # fmt: skip
    path = tampered(real_map, tmp_path, "asymmetric.json", asymmetric)
    refused_everywhere(capsys, log, path, tmp_path, "marker 2", "covariance", "symmetric")


def test_rounding_in_a_covariance_is_clipped_not_refused(real_map, tmp_path, capsys) -> None:
    """A negative eigenvalue as small as an optimiser's rounding leaves (1e-12 of the largest
    entry) and an asymmetry as small are read, clipped to a covariance."""

    def rounding(document: dict[str, Any]) -> None:
        covariance = document["markers"][0]["covariance"]  # the home's: 1e-8 on the diagonal
        covariance[2][2] = -1e-20
        covariance[0][1] += 1e-20

    path = tampered(real_map, tmp_path, "rounding.json", rounding)
    code, out, err = cli(capsys, "export", path, "--format", "csv", "--out", "-")
    assert code == 0, err
    assert len(out.splitlines()) == 4  # a header and three markers


@pytest.mark.parametrize(
    ("value", "words"),
    [(2**64, "markers[1].id"), (50, "the ids in DICT_4X4_50"), (-1, "markers[1].id"),
     (1.5, "markers[1].id"), (True, "markers[1].id")],
)  # fmt: skip
def test_marker_ids_stay_within_the_dictionary(real_map, log, tmp_path, capsys, value, words):
    """An id of 2^64 (a TypeError from GTSAM's L()), one beyond DICT_4X4_50's 50, negative, or
    not a whole number is refused in every command that reads a map."""

    def change(document: dict[str, Any]) -> None:
        document["markers"][1]["id"] = value

    path = tampered(real_map, tmp_path, "id.json", change)
    refused_everywhere(capsys, log, path, tmp_path, words)


@pytest.mark.parametrize(
    ("unplaced", "words"),
    [({"abc": "never seen"}, "unplaced['abc']"), ({"9" * 5000: "x"}, "keyed by a marker id"),
     ({"7": ["not", "text"]}, "unplaced['7'] must be a string"), ({"60": "x"}, "unplaced['60']"),
     (["7"], "unplaced must be an object")],
)  # fmt: skip
def test_every_key_of_unplaced_is_checked(real_map, log, tmp_path, capsys, unplaced, words):
    """A key of ``unplaced`` that is no marker id (a ValueError in every command), beyond the
    dictionary or of 5,000 digits, or a reason that is not text, is refused in one line."""

    def change(document: dict[str, Any]) -> None:
        document["unplaced"] = unplaced

    path = tampered(real_map, tmp_path, "unplaced.json", change)
    refused_everywhere(capsys, log, path, tmp_path, words)


def test_home_and_links_name_markers_of_the_map(real_map, log, tmp_path, capsys) -> None:
    """A home or a link end that is not a marker of the map (the ATE silently dropped) and a
    method that is not text are refused, naming the field."""
    cases = {
        "home.json": (lambda d: d.update(home_id=49), "home_id must be a marker of the map"),
        "link.json": (lambda d: d["links"][0].update(a=40), "links[0].a"),
        "method.json": (lambda d: d.update(method={"x": 1}), "method must be a string"),
        "converged.json": (lambda d: d.update(converged="no"), "converged"),
        # localize took it for a map and called every marker it saw new.
        "empty.json": (
            lambda d: d.update(markers=[], links=[], home_id=None),
            "markers must be a list of at least one marker",
        ),
    }
    for name, (change, words) in cases.items():
        refused_everywhere(capsys, log, tampered(real_map, tmp_path, name, change), tmp_path,
                           words)  # fmt: skip


def test_deep_nesting_and_huge_files_are_refused_unparsed(real_map, log, tmp_path, capsys):
    """JSON arrays nested 100,000 deep (a RecursionError) and a file over 32 MB (a sparse
    one: refused by its size, unread) are one line each."""
    text = json.dumps(real_map)
    deep = tmp_path / "deep.json"
    deep.write_text(text[:-1] + ', "extra": ' + "[" * 100_000 + "]" * 100_000 + "}")
    refused_everywhere(capsys, log, deep, tmp_path, "nested deeper than 20 levels")
    # Brackets inside strings are text, not nesting.
    fine = tampered(real_map, tmp_path, "brackets.json", lambda d: d.update(log="[[[" * 30))
    code, _, err = cli(capsys, "export", fine, "--format", "csv", "--out", "-")
    assert code == 0, err
    huge = tmp_path / "huge.json"
    with huge.open("wb") as stream:
        stream.truncate(33 * 2**20)
    refused_everywhere(capsys, log, huge, tmp_path, "bytes, more than such a file holds")


def test_more_markers_than_the_dictionary_holds_are_refused(real_map, log, tmp_path, capsys):
    """A DICT_4X4_50 map of 60 markers is refused by its count before any marker is read."""

    def many(document: dict[str, Any]) -> None:
        base = document["markers"][2]
        document["markers"] += [{**base, "id": i, "x": 10.0 + i} for i in range(3, 60)]

    path = tampered(real_map, tmp_path, "many.json", many)
    refused_everywhere(capsys, log, path, tmp_path, "60 markers", "DICT_4X4_50 holds (50)")


@pytest.mark.slow
def test_a_full_dictionary_localises_in_bounded_memory(tmp_path) -> None:
    """localize against a map of 2,320 markers (all of AprilTag 36h10, the largest predefined
    dictionary; 20,000 markers took 3.4 GB and died) succeeds under 1 GB peak RSS: the markers
    the log never sees are independent 3x3 blocks, never a dense 3n x 3n matrix. The paper
    room's markers are printed from 36h10 for it (localize reads a log with its map's
    dictionary)."""
    world, route = scenario("paper-room")
    tags = tuple(dataclasses.replace(m, dictionary="DICT_APRILTAG_36h10") for m in world.markers)
    log = tmp_path / "room36h10.mcap"
    write_log(dataclasses.replace(world, markers=tags), route, log, seed=3, duration_s=20.0,
              compressed=True, frame_hz=5.0)  # fmt: skip
    out = tmp_path / "map"
    assert main(["map", str(log), "--out", str(out), "--no-plots", "-q",
                 "--dictionary", "DICT_APRILTAG_36h10"]) == 0  # fmt: skip

    def full(document: dict[str, Any]) -> None:
        base = document["markers"][2]
        document["markers"] += [{**base, "id": i, "x": 100.0 + i} for i in range(3, 2320)]

    path = tampered(json.loads((out / "map.json").read_text()), tmp_path, "full.json", full)
    out = tmp_path / "loc"
    command = [sys.executable, "-m", "markergraph.cli", "localize", str(log), "--map", str(path),
               "--out", str(out), "-q"]  # fmt: skip
    run, peak_kb = run_with_peak(command)
    assert run.returncode == 0, run.stderr
    peak = peak_kb * 1024  # Linux: kB
    assert peak < PEAK_RSS_BYTES, peak
    assert (out / "localization.json").is_file()


def test_relative_covariances_of_groups_equal_the_dense_projection() -> None:
    """The blockwise relative covariances equal the dense ``P S P^T`` on a block-diagonal
    joint covariance, for random poses and groups."""
    rng = np.random.default_rng(7)
    for n in (2, 3, 9):
        poses = [gtsam.Pose2(*rng.normal(size=3)) for _ in range(n)]
        cut = int(rng.integers(1, n))
        groups = [list(range(cut)), list(range(cut, n))]
        dense = np.zeros((3 * n, 3 * n))
        blocks = []
        for group in groups:
            A = rng.normal(size=(3 * len(group), 3 * len(group)))
            joint = A @ A.T
            rows = np.concatenate([np.arange(3 * i, 3 * i + 3) for i in group])
            dense[np.ix_(rows, rows)] = joint
            blocks.append((group, joint))
        for a, b in zip(relative_covariances(poses, dense),
                        relative_covariances_of_groups(poses, blocks), strict=True):  # fmt: skip
            np.testing.assert_allclose(a, b, atol=EXACT * max(1.0, float(np.abs(a).max())))


# --- surveys and rig files --------------------------------------------------------------------


def survey_refused(capsys, log: Path, path: Path, tmp_path: Path, *names: str) -> None:
    """map --dimensions 3 --survey ``path`` exits 1 with one line naming it, writing nothing."""
    before = snapshot(tmp_path)
    code, _, err = cli(capsys, "map", log, "--dimensions", "3", "--survey", path,
                       "--out", tmp_path / "3d", "--no-plots")  # fmt: skip
    assert code == 1, err
    one_line_error(err, str(path), *names)
    assert snapshot(tmp_path) == before and not (tmp_path / "3d").exists()


def test_bad_surveys_are_one_line(real_map, log, tmp_path, capsys) -> None:
    """A CSV survey with an id of 2^64 or -3, a map.json survey with a negative variance (held
    at the tightest sigma before) or nested 100,000 deep, and a tagslam.yaml that is a billion
    laughs or nested 5,000 deep: one line naming the file, exit 1."""
    big = tmp_path / "big.csv"
    big.write_text(f"id,x,y\n{2**64},1,2\n")
    survey_refused(capsys, log, big, tmp_path, "row 2.id")
    negative = tmp_path / "negative.csv"
    negative.write_text("id,x,y\n-3,1,2\n")
    survey_refused(capsys, log, negative, tmp_path, "row 2.id")

    def variance(document: dict[str, Any]) -> None:
        document["markers"][1]["covariance"] = [[-1, 0, 0], [0, 1, 0], [0, 0, 1]]

    path = tampered(real_map, tmp_path, "survey.json", variance)
    survey_refused(capsys, log, path, tmp_path, "markers[1].covariance", "positive semi")
    deep = tmp_path / "deep.json"
    deep.write_text('{"schema": "markergraph.map/2", "x": ' + "[" * 100_000 + "]" * 100_000 + "}")
    survey_refused(capsys, log, deep, tmp_path, "nested deeper")
    laughs = tmp_path / "laughs.yaml"
    lines = ['l0: &l0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    lines += [f"l{i}: &l{i} [{', '.join([f'*l{i - 1}'] * 9)}]" for i in range(1, 9)]
    laughs.write_text("\n".join(lines) + "\nbodies: [*l8]\n")
    survey_refused(capsys, log, laughs, tmp_path, "an alias")
    nested = tmp_path / "nested.yaml"
    nested.write_text("bodies: " + "[" * 5000 + "]" * 5000 + "\n")
    survey_refused(capsys, log, nested, tmp_path, "nested deeper")
