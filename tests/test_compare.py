"""``markergraph compare``: a map scored against references made from it with a known rigid
offset and known per-marker noise, so every figure has a closed-form truth.

The noise is projected off the rigid motions (its mean and its moment about the centroid are
zero), so the least-squares alignment is exactly the offset applied and each aligned error is
exactly that marker's noise (exact algebra, not a statistical bound).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import gtsam
import numpy as np
import pytest

from markergraph.cli import main
from markergraph.datasets import scenario, simulate_fast
from markergraph.estimator import Method, build_frames, estimate_frames
from markergraph.estimator.tags3d import R_TAG_MARKER, Tag3d, TagMap3d
from markergraph.frontend import MarkerSizes
from markergraph.markermap import MarkerMap

EXACT = 1e-9  # exact algebra through repr()-printed text and an SVD
THETA0_RAD = 0.7  # the reference frame's rotation from the map's
T0_M = np.array([3.0, -2.0, 0.5])  # ... and its translation [m]
NOISE_M = 0.05  # per-marker position noise sigma [m]
YAW_NOISE_RAD = 0.02  # per-marker yaw / rotation noise sigma [rad]
MARKER_TO_TAG = gtsam.Pose3(gtsam.Rot3(R_TAG_MARKER.T), np.zeros(3))


def _refuse(name: str) -> None:
    raise ValueError(f"{name} in strict JSON")


def _rigid_free(p: np.ndarray, noise: np.ndarray) -> np.ndarray:
    """``noise`` (n, d) less its projection on the rigid motions of the points ``p`` (n, d):
    what is left has zero mean and zero moment about the centroid."""
    n, d = p.shape
    centred = p - p.mean(axis=0)
    motions = [np.tile(np.eye(d)[k], (n, 1)) for k in range(d)]
    if d == 2:
        motions.append(np.column_stack([-centred[:, 1], centred[:, 0]]))
    else:
        motions += [np.cross(np.eye(3)[k], centred) for k in range(3)]
    A = np.column_stack([m.ravel() for m in motions])
    flat = noise.ravel()
    return (flat - A @ np.linalg.lstsq(A, flat, rcond=None)[0]).reshape(n, d)


def _rot2(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s], [s, c]])


def _compare(*arguments: str, capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(["compare", *arguments])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.fixture(scope="module")
def map2d(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, MarkerMap]:
    """A simulated corridor loop mapped by SLAM, with covariances."""
    world, route = scenario("corridor-loop")
    run = simulate_fast(world, route, seed=2, duration_s=120.0)
    frames = build_frames(run.observations, run.odometry, 0, odometry_noise=run.odometry_noise)
    estimate = estimate_frames(frames, Method.SLAM, run.mount.T_base_camera)
    marker_map = MarkerMap.from_estimate(
        estimate, log="sim.mcap", dictionary="DICT_4X4_50", marker_sizes=MarkerSizes(0.2, {})
    )
    path = tmp_path_factory.mktemp("compare") / "map.json"
    marker_map.save(path)
    return path, MarkerMap.load(path)


@pytest.fixture(scope="module")
def noisy_csv(map2d, tmp_path_factory: pytest.TempPathFactory):
    """The 2-D map moved by the known offset with known noise, as a CSV survey."""
    _, marker_map = map2d
    ids = sorted(marker_map.markers)
    p = np.array([[marker_map.markers[i].T_map_marker.x(), marker_map.markers[i].T_map_marker.y()]
                  for i in ids])  # fmt: skip
    yaw = np.array([marker_map.markers[i].T_map_marker.theta() for i in ids])
    rng = np.random.default_rng(11)
    noise = _rigid_free(p, rng.normal(0.0, NOISE_M, p.shape))
    yaw_noise = rng.normal(0.0, YAW_NOISE_RAD, len(ids))
    q = (p + noise) @ _rot2(THETA0_RAD).T + T0_M[:2]
    path = tmp_path_factory.mktemp("csv") / "truth.csv"
    rows = ["id,x,y,yaw"] + [
        f"{i},{float(q[k, 0])!r},{float(q[k, 1])!r},{float(yaw[k] + THETA0_RAD + yaw_noise[k])!r}"
        for k, i in enumerate(ids)
    ]
    path.write_text("\n".join(rows) + "\n")
    return path, ids, p, noise, yaw_noise


def test_the_simulated_map_has_enough_markers(map2d) -> None:
    """The fixture's map is worth scoring: several markers, covariances on all but home."""
    _, marker_map = map2d
    assert len(marker_map.markers) >= 5
    assert sum(m.covariance is not None for m in marker_map.markers.values()) >= 4


def test_aligned_rmse_is_the_noise_rms_and_home_fixed_as_predicted(
    map2d, noisy_csv, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """After SE(2) alignment each error is that marker's noise (yaw too); fixed on the home
    marker, each error is the home's noise carried over: n_h - n_i + (R(d_h) - I)(p_i - p_h)."""
    map_path, marker_map = map2d
    csv_path, ids, p, noise, yaw_noise = noisy_csv
    out = tmp_path / "figures.json"
    code, text, err = _compare(str(map_path), str(csv_path), "--json", str(out), capsys=capsys)
    assert code == 0, err
    document = json.loads(out.read_text(), parse_constant=_refuse)
    assert document["dimensions"] == 2 and document["common"] == ids
    aligned = document["aligned"]
    assert aligned["alignment"]["angle_deg"] == pytest.approx(math.degrees(THETA0_RAD), abs=EXACT)
    np.testing.assert_allclose(aligned["alignment"]["t_m"][:2], T0_M[:2], atol=EXACT)
    noise_rms = math.sqrt(np.mean(np.sum(noise**2, axis=1)))
    assert aligned["position_m"]["rmse"] == pytest.approx(noise_rms, abs=EXACT)
    per_marker = {m["id"]: m for m in document["markers"]}
    home = marker_map.home_id
    h = ids.index(home)
    turn = _rot2(yaw_noise[h])
    for k, i in enumerate(ids):
        assert per_marker[i]["aligned"]["position_m"] == pytest.approx(
            np.linalg.norm(noise[k]), abs=EXACT
        )
        assert per_marker[i]["aligned"]["yaw_deg"] == pytest.approx(
            abs(math.degrees(yaw_noise[k])), abs=1e-7
        )
        predicted = noise[h] - noise[k] + (turn - np.eye(2)) @ (p[k] - p[h])
        assert per_marker[i]["home_fixed"]["position_m"] == pytest.approx(
            np.linalg.norm(predicted), abs=EXACT
        )
        assert per_marker[i]["home_fixed"]["yaw_deg"] == pytest.approx(
            abs(math.degrees(yaw_noise[k] - yaw_noise[h])), abs=1e-7
        )
    home_rms = document["home_fixed"]["position_m"]["rmse"]
    assert home_rms > aligned["position_m"]["rmse"]  # the best fit is best
    assert f"position RMSE {noise_rms:.4f} m" in text and "(marker" in text


def test_nees_is_the_error_whitened_by_the_maps_covariance(
    map2d, noisy_csv, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Aligned, each marker's NEES is n^T P^-1 n with P its relative covariance in the map's
    axes; home-fixed, the predicted error under the plain covariance, the pinned home marker
    left out; the within-95 % counts are those at most chi-square(2)'s 95 % quantile. The
    yaw's alike, its error squared over its variance against chi-square(1)'s."""
    map_path, marker_map = map2d
    csv_path, ids, p, noise, yaw_noise = noisy_csv
    out = tmp_path / "figures.json"
    assert _compare(str(map_path), str(csv_path), "--json", str(out), capsys=capsys)[0] == 0
    document = json.loads(out.read_text())
    per_marker = {m["id"]: m for m in document["markers"]}
    h = ids.index(marker_map.home_id)
    turn = _rot2(yaw_noise[h])
    expected: dict[str, dict[int, float]] = {"aligned": {}, "home_fixed": {}}
    yaw_nees: dict[str, list[float]] = {"aligned": [], "home_fixed": []}
    for k, i in enumerate(ids):
        m = marker_map.markers[i]
        assert m.covariance is not None and m.relative_covariance is not None
        R = _rot2(m.T_map_marker.theta())
        P_relative = R @ m.relative_covariance[:2, :2] @ R.T
        expected["aligned"][i] = float(noise[k] @ np.linalg.solve(P_relative, noise[k]))
        yaw_nees["aligned"].append(yaw_noise[k] ** 2 / m.relative_covariance[2, 2])
        if i == marker_map.home_id:
            assert per_marker[i]["home_fixed"]["nees"] is None
            continue
        yaw_nees["home_fixed"].append((yaw_noise[k] - yaw_noise[h]) ** 2 / m.covariance[2, 2])
        # The error in the map's axes: the home-fixed rotation (the offset's, then the home's
        # yaw noise) undone, as the covariance is carried by it.
        error = turn.T @ (noise[k] - noise[h] - (turn - np.eye(2)) @ (p[k] - p[h]))
        P = R @ m.covariance[:2, :2] @ R.T
        expected["home_fixed"][i] = float(error @ np.linalg.solve(P, error))
    for name, values in expected.items():
        for i, value in values.items():
            assert per_marker[i][name]["nees"] == pytest.approx(value, rel=1e-6)
        within = sum(v <= -2.0 * math.log(0.05) for v in values.values())
        yaw_within = sum(v <= 3.841458820694124 for v in yaw_nees[name])
        assert document[name]["covariance"] == {
            "n": len(values), "within_95": within,
            "yaw_n": len(yaw_nees[name]), "yaw_within_95": yaw_within,
        }  # fmt: skip
    assert len(yaw_nees["aligned"]) == len(ids)  # every marker has a yaw on both sides


def test_a_yaw_off_by_many_sigmas_leaves_its_interval(
    map2d, noisy_csv, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """One marker's yaw in the reference turned 0.5 rad (tens of its sigmas): the position
    figures are as they were, and that marker alone leaves the yaw's 95 % interval."""
    csv_path = noisy_csv[0]
    rows = csv_path.read_text().splitlines()
    cells = rows[-1].split(",")
    cells[3] = repr(float(cells[3]) + 0.5)
    turned = tmp_path / "turned.csv"
    turned.write_text("\n".join([*rows[:-1], ",".join(cells)]) + "\n")
    documents = []
    for path in (csv_path, turned):
        out = tmp_path / f"{path.stem}.json"
        assert _compare(str(map2d[0]), str(path), "--json", str(out), capsys=capsys)[0] == 0
        documents.append(json.loads(out.read_text())["aligned"]["covariance"])
    before, after = documents
    assert after["within_95"] == before["within_95"] and after["yaw_n"] == before["yaw_n"]
    assert after["yaw_within_95"] == before["yaw_within_95"] - 1


def test_scale_is_fitted_only_when_asked(
    map2d, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A reference 1.5 times larger: --scale finds 1.5 and no error; without it the rigid fit
    leaves the scale's error."""
    map_path, marker_map = map2d
    rows = ["id,x,y"] + [
        f"{i},{1.5 * m.T_map_marker.x() + 1.0!r},{1.5 * m.T_map_marker.y()!r}"
        for i, m in marker_map.markers.items()
    ]
    csv_path = tmp_path / "big.csv"
    csv_path.write_text("\n".join(rows) + "\n")
    out = tmp_path / "scaled.json"
    code, text, _ = _compare(
        str(map_path), str(csv_path), "--scale", "--json", str(out), capsys=capsys
    )
    assert code == 0 and "scale 1.500000" in text and "Sim(2)" in text
    aligned = json.loads(out.read_text())["aligned"]
    assert aligned["alignment"]["scale"] == pytest.approx(1.5, abs=EXACT)
    assert aligned["position_m"]["max"] < EXACT
    assert aligned["yaw_deg"]["n"] == 0  # the CSV gives no yaw
    rigid = tmp_path / "rigid.json"
    assert _compare(str(map_path), str(csv_path), "--json", str(rigid), capsys=capsys)[0] == 0
    assert json.loads(rigid.read_text())["aligned"]["position_m"]["rmse"] > 0.1


def _tag_map() -> MarkerMap:
    """Five tags in 3-D (three on walls, one on the floor, one tilted), tag 1 surveyed."""
    T_map_marker = {
        1: gtsam.Pose3(gtsam.Rot3(), np.array([0.0, 0.0, 1.2])),
        2: gtsam.Pose3(gtsam.Rot3.Yaw(2.0).compose(gtsam.Rot3.Pitch(0.2)), np.array([3, 1, 0.8])),
        3: gtsam.Pose3(gtsam.Rot3.Yaw(-1.5), np.array([1.0, 4.0, 1.5])),
        4: gtsam.Pose3(gtsam.Rot3.Pitch(-math.pi / 2), np.array([2.0, 2.0, 0.0])),
        5: gtsam.Pose3(gtsam.Rot3.Yaw(0.4).compose(gtsam.Rot3.Pitch(-1.0)), np.array([-1, 2, 0.4])),
    }
    rng = np.random.default_rng(5)
    tags = {}
    for i, T in T_map_marker.items():
        A = rng.normal(size=(6, 6)) * 0.01
        tags[i] = Tag3d(i, T.compose(MARKER_TO_TAG), A @ A.T + np.eye(6) * 1e-4, 10, 0.16, i == 1)
    tag_map = TagMap3d(tags, np.zeros(0, np.int64), [], {}, home_id=None, up=True,
                       frames_skipped=0, views_used=50, views_dropped=0,
                       reprojection_rms_px=0.4, converged=True, notes=[])  # fmt: skip
    return MarkerMap.from_tag_map(tag_map, log="rig.bag", dictionary="DICT_APRILTAG_36h11",
                                  marker_size_m=0.16, method="tags3d")  # fmt: skip


def test_a_3d_map_against_a_tagslam_survey(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """SE(3): aligned position errors are the noise, rotation errors the rotation noise's
    angles; fixed on tag 1's pose, each error is tag 1's noise carried over."""
    marker_map = _tag_map()
    map_path = tmp_path / "map.json"
    marker_map.save(map_path)
    ids = sorted(marker_map.markers3d)
    poses = [marker_map.markers3d[i].T_map_marker3 for i in ids]
    p = np.array([T.translation() for T in poses])
    rng = np.random.default_rng(17)
    noise = _rigid_free(p, rng.normal(0.0, NOISE_M, p.shape))
    omega = rng.normal(0.0, YAW_NOISE_RAD, (len(ids), 3))
    T0 = gtsam.Pose3(gtsam.Rot3.Ypr(THETA0_RAD, 0.1, -0.2), T0_M)
    lines = ["bodies:", " - survey:", "     is_static: true", "     type: simple", "     tags:"]
    for k, i in enumerate(ids):
        R_marker = poses[k].rotation().compose(gtsam.Rot3.Expmap(omega[k]))
        T_ref_tag = T0.compose(gtsam.Pose3(R_marker, p[k] + noise[k])).compose(MARKER_TO_TAG)
        x, y, z = (float(v) for v in T_ref_tag.translation())
        rx, ry, rz = (float(v) for v in gtsam.Rot3.Logmap(T_ref_tag.rotation()))
        lines += [
            f"       - id: {i}",
            "         size: 0.16",
            "         pose:",
            f"           position: {{x: {x!r}, y: {y!r}, z: {z!r}}}",
            f"           rotation: {{x: {rx!r}, y: {ry!r}, z: {rz!r}}}",
            "           position_noise: 0.01",
            "           rotation_noise: 0.01",
        ]
    survey = tmp_path / "tagslam.yaml"
    survey.write_text("\n".join(lines) + "\n")
    out = tmp_path / "figures.json"
    code, text, err = _compare(str(map_path), str(survey), "--json", str(out), capsys=capsys)
    assert code == 0, err
    document = json.loads(out.read_text())
    assert document["dimensions"] == 3 and document["home_id"] == 1
    assert "SE(3)" in text and "rotation RMSE" in text
    per_marker = {m["id"]: m for m in document["markers"]}
    h = ids.index(1)
    R_h = np.asarray(poses[h].rotation().matrix())
    turn = R_h @ gtsam.Rot3.Expmap(omega[h]).matrix() @ R_h.T  # tag 1's rotation noise, map axes
    for k, i in enumerate(ids):
        aligned = per_marker[i]["aligned"]
        assert aligned["position_m"] == pytest.approx(np.linalg.norm(noise[k]), abs=EXACT)
        assert aligned["rotation_deg"] == pytest.approx(
            math.degrees(np.linalg.norm(omega[k])), abs=1e-7
        )
        predicted = noise[h] - noise[k] + (turn - np.eye(3)) @ (p[k] - p[h])
        assert per_marker[i]["home_fixed"]["position_m"] == pytest.approx(
            np.linalg.norm(predicted), abs=EXACT
        )
    assert per_marker[4]["aligned"]["yaw_deg"] is None  # a floor tag has no yaw


@pytest.mark.parametrize(
    ("three_d", "fmt", "kind"),
    [(False, "aruco-yaml", "aruco"), (True, "aruco-yaml", "aruco"), (False, "csv", "csv")],
)
def test_an_export_round_trips_to_zero_error(
    three_d: bool, fmt: str, kind: str, map2d, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A map against its own ``export``, ArUco's YAML or the CSV (its unit-named columns read
    as a survey's): every marker in common, position, yaw and rotation errors nil under both
    alignments."""
    if three_d:
        map_path = tmp_path / "map3d.json"
        _tag_map().save(map_path)
    else:
        map_path = map2d[0]
    exported = tmp_path / f"map.{'yml' if fmt == 'aruco-yaml' else fmt}"
    assert main(["export", str(map_path), "--format", fmt, "--out", str(exported)]) == 0
    out = tmp_path / "figures.json"
    code, _, err = _compare(str(map_path), str(exported), "--json", str(out), capsys=capsys)
    assert code == 0, err
    document = json.loads(out.read_text())
    assert document["reference_kind"] == kind and not document["only_map"]
    assert not document["only_reference"]
    for name in ("aligned", "home_fixed"):
        assert document[name]["position_m"]["max"] < 1e-9
        assert document[name]["yaw_deg"]["max"] < 1e-6
    if three_d:
        assert document["aligned"]["rotation_deg"]["n"] == 5
        assert document["aligned"]["rotation_deg"]["max"] < 1e-6


def test_a_reference_without_the_home_markers_yaw_scores_no_home_fixed_figures(
    map2d, noisy_csv, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The survey without its yaw column: the map's frame turns with its home marker's yaw, so
    home-fixed figures would count the survey's own turn (THETA0_RAD) as every marker's error.
    They are left out and the note says so; the aligned figures are those with yaws."""
    csv_path, ids = noisy_csv[0], noisy_csv[1]
    no_yaw = tmp_path / "no-yaw.csv"
    no_yaw.write_text(
        "\n".join(",".join(row.split(",")[:3]) for row in csv_path.read_text().splitlines())
    )
    figures = {}
    for name, path in (("with", csv_path), ("without", no_yaw)):
        out = tmp_path / f"{name}.json"
        code, text, err = _compare(str(map2d[0]), str(path), "--json", str(out), capsys=capsys)
        assert code == 0, err
        figures[name] = (json.loads(out.read_text()), text)
    document, text = figures["without"]
    assert document["home_fixed"] is None
    assert all(marker["home_fixed"] is None for marker in document["markers"])
    assert "home-fixed:" not in text and "home [m]" not in text
    assert f"home-fixed not scored: the reference gives marker {map2d[1].home_id} no yaw" in text
    with_yaw = figures["with"][0]
    assert with_yaw["home_fixed"] is not None and len(document["markers"]) == len(ids)
    assert document["aligned"]["position_m"]["rmse"] == pytest.approx(
        with_yaw["aligned"]["position_m"]["rmse"], abs=EXACT
    )


def test_plot_and_json_are_written(
    map2d, noisy_csv, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--plot writes a PNG of some size, --json strict JSON; neither replaced without --force."""
    plot, figures = tmp_path / "compare.png", tmp_path / "compare.json"
    arguments = [str(map2d[0]), str(noisy_csv[0]), "--plot", str(plot), "--json", str(figures)]
    assert _compare(*arguments, capsys=capsys)[0] == 0
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and plot.stat().st_size > 5_000
    json.loads(figures.read_text(), parse_constant=_refuse)
    code, _, err = _compare(*arguments, capsys=capsys)
    assert code == 1 and "--force" in err
    assert _compare(*arguments, "--force", capsys=capsys)[0] == 0


@pytest.mark.parametrize(
    ("rows", "said"),
    [
        ("id,x,y\n100,0.0,0.0\n101,1.0,0.0\n102,0.0,1.0\n", "in common"),
        ("0,0.0,0.0\n1,1.0,0.0\n", "no column 'id'"),
        ("id,x,y\n0,nan,0.0\n1,1.0,0.0\n", "row 2.x"),
        ("id,x,y\n0,0.0,0.0\n", "in common"),
    ],
    ids=["no-common-ids", "no-header", "nan", "one-common"],
)
def test_bad_references_are_one_line_exit_1(
    rows: str, said: str, map2d, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A reference sharing fewer than 2 markers, a CSV without a header, a NaN: one line."""
    reference = tmp_path / "bad.csv"
    reference.write_text(rows)
    code, out, err = _compare(str(map2d[0]), str(reference), capsys=capsys)
    assert code == 1 and not out
    assert len(err.strip().splitlines()) == 1 and said in err and "compare" in err


def test_a_home_not_in_common_is_one_line(
    map2d, noisy_csv, capsys: pytest.CaptureFixture[str]
) -> None:
    """--home naming a marker the two do not share: one line, exit 1."""
    code, _, err = _compare(str(map2d[0]), str(noisy_csv[0]), "--home", "999", capsys=capsys)
    assert code == 1 and "--home 999" in err and len(err.strip().splitlines()) == 1


def test_a_misshapen_aruco_marker_is_refused(
    map2d, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """ArUco corners that are not a square: one line naming the file and the marker."""
    aruco = tmp_path / "bad.yml"
    aruco.write_text(
        '%YAML:1.0\naruco_bc_dict: "4X4_50"\naruco_bc_nmarkers: 1\naruco_bc_mInfoType: 1\n'
        "aruco_bc_markers:\n   - { id: 0, corners: [ [0, 0, 1], [0.3, 0, 1], [0.3, 0, 0.8], "
        "[0, 0, 0.8] ] }\n"
    )
    code, _, err = _compare(str(map2d[0]), str(aruco), capsys=capsys)
    assert code == 1 and "bad.yml" in err and "not a square" in err


def test_a_3d_map_against_a_survey_without_heights_is_compared_on_the_floor(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A CSV without z: the 3-D map's tags compared by x, y alone (SE(2)), exact for a
    reference that is the map turned and moved in the plane; yaw only for wall tags."""
    marker_map = _tag_map()
    map_path = tmp_path / "map.json"
    marker_map.save(map_path)
    rows = ["id,x,y"]
    for i, m in marker_map.markers3d.items():
        assert m.T_map_marker3 is not None
        x, y = _rot2(THETA0_RAD) @ m.T_map_marker3.translation()[:2] + T0_M[:2]
        rows.append(f"{i},{float(x)!r},{float(y)!r}")
    csv_path = tmp_path / "flat.csv"
    csv_path.write_text("\n".join(rows) + "\n")
    out = tmp_path / "figures.json"
    code, text, err = _compare(str(map_path), str(csv_path), "--json", str(out), capsys=capsys)
    assert code == 0, err
    document = json.loads(out.read_text())
    assert document["dimensions"] == 2 and "SE(2)" in text
    assert document["aligned"]["position_m"]["max"] < EXACT
    assert document["aligned"]["rotation_deg"]["n"] == 0


def test_3d_markers_on_one_line_are_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Three common tags on one line leave the rotation about it free: one line, exit 1."""
    marker_map = _tag_map()
    map_path = tmp_path / "map.json"
    marker_map.save(map_path)
    lines = ["bodies:", " - survey:", "     is_static: true", "     type: simple", "     tags:"]
    for i in (1, 2, 3):
        lines += [
            f"       - id: {i}",
            "         pose:",
            f"           position: {{x: {float(i)}, y: 0.0, z: 1.0}}",
            "           rotation: {x: 0.0, y: 0.0, z: 0.0}",
            "           position_noise: 0.01",
            "           rotation_noise: 0.01",
        ]
    survey = tmp_path / "tagslam.yaml"
    survey.write_text("\n".join(lines) + "\n")
    code, _, err = _compare(str(map_path), str(survey), capsys=capsys)
    assert code == 1 and "one line" in err and len(err.strip().splitlines()) == 1


def test_the_plot_exaggerates_errors_by_a_round_factor() -> None:
    """Centimetre errors in a 15 m room are drawn x20 (2 % of the view at least); errors that
    already show are drawn as they are."""
    from markergraph.compare_plot import SHOWN_ERROR, exaggeration

    assert exaggeration(np.array([0.024, 0.01]), 15.0) == 20.0
    assert exaggeration(np.array([0.024]), 15.0) * 0.024 >= SHOWN_ERROR * 15.0
    assert exaggeration(np.array([1.0]), 15.0) == 1.0
    assert exaggeration(np.zeros(3), 15.0) == 1.0


def test_plot_title_tells_two_files_of_one_name_apart() -> None:
    """Two map.json files are named by their folders in the plot's title; other names alone."""
    from markergraph.compare_text import plot_title

    assert plot_title(Path("a/room-map/map.json"), Path("b/ref/map.json")) == (
        "room-map/map.json vs ref/map.json"
    )
    assert plot_title(Path("room-map/map.json"), Path("truth.csv")) == "map.json vs truth.csv"
