"""A 3-D map's outputs against a hand-built TagMap3d: map.json (schema markergraph.map/2) round
trips, map/1 files still read, the 2-D view is the wall tags, the 3x3 is the 6x6 propagated,
every export and result file parses back to the same poses, and the rigid 3-D alignment is
exact."""

from __future__ import annotations

import csv
import json
import math
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import cv2
import gtsam
import numpy as np
import pytest
import yaml

from markergraph.common import Note
from markergraph.common.errors import OutputError
from markergraph.estimator.metrics import align_rigid_3d, tag_errors_3d
from markergraph.estimator.tags3d import R_TAG_MARKER, Camera3d, Tag3d, TagMap3d, tag_corners
from markergraph.formats import (
    MARKER_VERTEX_OFFSET,
    ExportFormat,
    export_map,
    write_g2o_3d,
    write_tum_3d,
)
from markergraph.frontend.posed import WALL_TILT_RAD
from markergraph.markermap import MAP_SCHEMA, MapMarker, MarkerMap, MarkerMapError
from markergraph.plots3d import plot_map_3d
from markergraph.results3d import FILES_3D, Map3dRun, write_results_3d
from markergraph.settings import MapConfig

EXACT = 1e-12  # exact algebra and full-precision text
NUMERICAL = 1e-6  # a central difference against an analytic Jacobian (relative)
STEP = 1e-6  # the central difference's step [rad, m]
MIN_FIGURE_BYTES = 5_000  # a matplotlib figure with axes and labels is tens of kB
MARKER_TO_TAG = gtsam.Pose3(gtsam.Rot3(R_TAG_MARKER.T), np.zeros(3))

# The tags in the marker frame (x the normal): three on walls (one tilted back 0.2 rad, one
# turned 0.3 rad in its own plane), one on the floor facing up, one on a board tilted 60
# degrees from vertical (not a wall).
T_MAP_MARKER = {
    1: gtsam.Pose3(gtsam.Rot3(), np.array([0.0, 0.0, 1.2])),
    2: gtsam.Pose3(gtsam.Rot3.Yaw(2.0).compose(gtsam.Rot3.Pitch(0.2)), np.array([3.0, 1.0, 0.8])),
    3: gtsam.Pose3(gtsam.Rot3.Yaw(-1.5).compose(gtsam.Rot3.Roll(0.3)), np.array([1.0, 4.0, 1.5])),
    4: gtsam.Pose3(gtsam.Rot3.Pitch(-math.pi / 2), np.array([2.0, 2.0, 0.0])),
    5: gtsam.Pose3(gtsam.Rot3.Yaw(0.4).compose(gtsam.Rot3.Pitch(-math.radians(60))),
                   np.array([-1.0, 2.5, 0.4])),
}  # fmt: skip
WALLS = {1, 2, 3}


def _covariance(rng: np.random.Generator, scale: float) -> np.ndarray:
    A = rng.normal(size=(6, 6)) * scale
    return A @ A.T + np.eye(6) * scale**2


def _tag_map(up: bool = True, seed: int = 7) -> TagMap3d:
    """Five tags (tag 1 surveyed), two cameras (one estimated), five rig poses."""
    rng = np.random.default_rng(seed)
    tags = {}
    for i, T in T_MAP_MARKER.items():
        covariance = _covariance(rng, 0.01)  # the tag frame's tangent, as the estimator gives
        tags[i] = Tag3d(i, T.compose(MARKER_TO_TAG), covariance, 10 + i,
                        0.16 if i != 4 else 0.3, known=i == 1)  # fmt: skip
    cameras = {
        "front": Camera3d(
            "front",
            "/front/tags",
            gtsam.Pose3(gtsam.Rot3.Ypr(-1.57, 0, -1.57), np.array([0.2, 0.0, 0.5])),
            None,
            False,
            40,
        ),
        "side": Camera3d(
            "side",
            "/side/tags",
            gtsam.Pose3(gtsam.Rot3.Ypr(0.1, 0.2, -1.5), np.array([0.0, 0.1, 0.6])),
            _covariance(rng, 0.02),
            True,
            12,
        ),
    }
    rig = [gtsam.Pose3(gtsam.Rot3.Ypr(0.3 * k, 0.05, -0.02), np.array([0.5 * k, 1.0, 0.1 * k]))
           for k in range(5)]  # fmt: skip
    times = np.array([1_700_000_000_000_000_000 + k * 100_000_001 for k in range(5)], np.int64)
    return TagMap3d(tags, times, rig, cameras, home_id=None, up=up, frames_skipped=2,
                    views_used=57, views_dropped=3, reprojection_rms_px=0.42, converged=True,
                    notes=[Note("tags3d.test", "a note from the estimator")])  # fmt: skip


def _marker_map(tag_map: TagMap3d | None = None) -> MarkerMap:
    return MarkerMap.from_tag_map(tag_map or _tag_map(), log="rig.bag",
                                  dictionary="DICT_APRILTAG_36h11", marker_size_m=0.16,
                                  method="tags3d")  # fmt: skip


def _refuse(name: str) -> None:
    raise ValueError(f"{name} in strict JSON")


def test_map_json_round_trips_every_pose_covariance_and_camera(tmp_path: Path) -> None:
    """map.json holds every tag's pose (to 1e-12), 6x6, wall and survey flags, up and the
    cameras, and reads back to the same map."""
    marker_map = _marker_map()
    path = tmp_path / "map.json"
    marker_map.save(path)
    document = json.loads(path.read_text(), parse_constant=_refuse)
    assert document["schema"] == MAP_SCHEMA == "markergraph.map/2"
    assert document["dimensions"] == 3 and document["up"] is True
    assert [m["id"] for m in document["markers"]] == sorted(T_MAP_MARKER)
    for entry in document["markers"]:
        assert set(entry) >= {"id", "x", "y", "yaw", "size_m", "covariance", "n_observations",
                              "z", "quaternion", "covariance_6x6", "wall"}  # fmt: skip
        assert entry["wall"] == (entry["id"] in WALLS)
        assert (entry["covariance"] is None) == (entry["id"] not in WALLS)
    loaded = MarkerMap.load(path)
    assert loaded.dimensions == 3 and loaded.up and loaded.home_id == 1
    assert loaded.frame == marker_map.frame and "surveyed" in loaded.frame
    assert set(loaded.markers3d) == set(T_MAP_MARKER) and set(loaded.markers) == WALLS
    for i, T in T_MAP_MARKER.items():
        m = loaded.markers3d[i]
        assert m.T_map_marker3 is not None and m.T_map_marker3.equals(T, EXACT)
        original = marker_map.markers3d[i].covariance6
        assert original is not None and m.covariance6 is not None
        np.testing.assert_allclose(m.covariance6, original, rtol=EXACT, atol=0)
        assert m.known == (i == 1) and m.n_observations == 10 + i
    for a, b in zip(loaded.cameras, marker_map.cameras, strict=True):
        assert (a.name, a.topic, a.estimated, a.n_views) == (b.name, b.topic, b.estimated,
                                                            b.n_views)  # fmt: skip
        assert a.T_rig_camera.equals(b.T_rig_camera, EXACT)
        assert (a.covariance is None) == (b.covariance is None)
    _assert_same(loaded.to_document(), document)


def _assert_same(a: Any, b: Any) -> None:
    """Two JSON documents equal, numbers to :data:`EXACT` (a quaternion read and written again
    may move in its last bit)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys()
        for key in a:
            _assert_same(a[key], b[key])
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            _assert_same(x, y)
    elif isinstance(a, float):
        assert a == pytest.approx(b, rel=EXACT, abs=EXACT)
    else:
        assert a == b


def test_the_tag_frames_covariance_is_the_marker_frames_after_the_axis_swap() -> None:
    """covariance_6x6 is Tag3d.marker_covariance: the same spread, rotation before
    translation, about the marker's axes."""
    tag_map = _tag_map()
    marker_map = _marker_map(tag_map)
    for i, tag in tag_map.tags.items():
        expected = tag.marker_covariance
        assert expected is not None
        np.testing.assert_array_equal(marker_map.markers3d[i].covariance6, expected)


def test_map1_and_2d_map2_files_still_load(tmp_path: Path) -> None:
    """A markergraph.map/1 file reads as a 2-D map; a 2-D map writes map/2 with "dimensions":
    2 and otherwise the same document."""
    old = {
        "schema": "markergraph.map/1",
        "home_id": 0,
        "marker_size_m": 0.2,
        "dictionary": "DICT_4X4_50",
        "markers": [
            {"id": 0, "x": 0.0, "y": 0.0, "yaw": 0.0, "n_observations": 3, "covariance": None},
            {"id": 4, "x": 1.5, "y": -2.0, "yaw": 1.0, "n_observations": 7, "z": 1.1,
             "covariance": [[1e-4, 0, 0], [0, 2e-4, 0], [0, 0, 1e-3]]},
        ],
    }  # fmt: skip
    path = tmp_path / "old.json"
    path.write_text(json.dumps(old))
    loaded = MarkerMap.load(path)
    assert loaded.dimensions == 2 and loaded.markers3d == {} and set(loaded.markers) == {0, 4}
    assert loaded.every_marker is loaded.markers
    marker = loaded.markers[4]
    assert (marker.T_map_marker.x(), marker.T_map_marker.y(), marker.T_map_marker.theta()) == (
        1.5, -2.0, 1.0)  # fmt: skip
    assert marker.z_m == 1.1 and marker.T_map_marker3 is None and marker.wall
    document = loaded.to_document()
    assert document["schema"] == MAP_SCHEMA and document["dimensions"] == 2
    assert "up" not in document and "cameras" not in document
    assert [set(m) for m in document["markers"]][1] == {
        "id",
        "x",
        "y",
        "yaw",
        "size_m",
        "covariance",
        "n_observations",
        "z",
    }
    assert MarkerMap.from_document(document).to_document() == document


def test_the_2d_view_holds_the_wall_tags_with_the_normals_heading() -> None:
    """markers (what localize, --prior, heading and the 2-D plots read) holds only the wall
    tags, at their x, y with yaw = atan2(n_y, n_x); with z not known to be up, none."""
    marker_map = _marker_map()
    assert set(marker_map.markers) == WALLS
    for i in WALLS:
        T = T_MAP_MARKER[i]
        normal = T.rotation().matrix()[:, 0]
        assert abs(normal[2]) <= math.sin(WALL_TILT_RAD)
        pose = marker_map.markers[i].T_map_marker
        assert pose.x() == pytest.approx(T.translation()[0], abs=EXACT)
        assert pose.y() == pytest.approx(T.translation()[1], abs=EXACT)
        assert pose.theta() == pytest.approx(math.atan2(normal[1], normal[0]), abs=EXACT)
        assert marker_map.markers[i].z_m == pytest.approx(T.translation()[2], abs=EXACT)
    assert marker_map.markers[2].T_map_marker.theta() == pytest.approx(2.0, abs=EXACT)
    assert marker_map.markers[3].T_map_marker.theta() == pytest.approx(-1.5, abs=EXACT)
    level = _marker_map(_tag_map(up=False))
    assert level.markers == {} and not any(m.wall for m in level.markers3d.values())
    # the paper's heading works on a 3-D map's wall tags as on any 2-D map
    distance, _ = marker_map.heading(1, 1.0, 0.0, 2)
    assert distance > 0


def _floor_local(T0: gtsam.Pose3, T: gtsam.Pose3) -> np.ndarray:
    """The floor trace of T in the local coordinates of T0's, computed from the matrices."""

    def trace(pose: gtsam.Pose3) -> gtsam.Pose2:
        n = pose.rotation().matrix()[:, 0]
        return gtsam.Pose2(pose.translation()[0], pose.translation()[1], math.atan2(n[1], n[0]))

    return np.asarray(trace(T0).localCoordinates(trace(T)))


def test_the_wall_tags_3x3_is_the_6x6_propagated_numerically() -> None:
    """Each wall tag's (x, y, yaw) covariance equals J P J^T with J the central difference of
    its floor trace over the Pose3 tangent (rotation, translation), perturbed on the right."""
    marker_map = _marker_map()
    for i in WALLS:
        m = marker_map.markers[i]
        T0 = T_MAP_MARKER[i]
        J = np.zeros((3, 6))
        for k in range(6):
            step = np.zeros(6)
            step[k] = STEP
            plus = T0.compose(gtsam.Pose3.Expmap(step))
            minus = T0.compose(gtsam.Pose3.Expmap(-step))
            J[:, k] = (_floor_local(T0, plus) - _floor_local(T0, minus)) / (2 * STEP)
        assert m.covariance6 is not None and m.covariance is not None
        expected = J @ m.covariance6 @ J.T
        np.testing.assert_allclose(m.covariance, expected, rtol=NUMERICAL, atol=1e-14)
        np.testing.assert_array_equal(m.covariance, m.covariance.T)


def _export(marker_map: MarkerMap, fmt: ExportFormat, tmp_path: Path) -> Path:
    path = tmp_path / f"map.{fmt.value}"
    export_map(marker_map, fmt, path)
    return path


def test_every_export_writes_each_tags_full_pose(tmp_path: Path) -> None:
    """CSV (x, y, z, quaternion), ArUco's MarkerMap (the real corners), fiducial_slam (roll,
    pitch, yaw) and TagSLAM (position, rotation vector) of a 3-D map parse back to every
    tag's pose, floor and board tags included."""
    marker_map = _marker_map()
    T_map_tag = {i: T.compose(MARKER_TO_TAG) for i, T in T_MAP_MARKER.items()}

    rows = list(csv.DictReader(_export(marker_map, ExportFormat.CSV, tmp_path).open()))
    assert [int(r["id"]) for r in rows] == sorted(T_MAP_MARKER)
    for row in rows:
        T = T_MAP_MARKER[int(row["id"])]
        np.testing.assert_allclose([float(row[k]) for k in ("x_m", "y_m", "z_m")],
                                   T.translation(), atol=EXACT)  # fmt: skip
        q = [float(row[k]) for k in ("qw", "qx", "qy", "qz")]
        assert gtsam.Rot3.Quaternion(*q).equals(T.rotation(), EXACT)
        assert row["wall"] == ("true" if int(row["id"]) in WALLS else "false")
        assert (row["sigma_yaw_rad"] == "") == (int(row["id"]) not in WALLS)

    path = _export(marker_map, ExportFormat.ARUCO_YAML, tmp_path)
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    node = storage.getNode("aruco_bc_markers")
    assert node.size() == len(T_MAP_MARKER)
    for n in range(node.size()):
        tag_id = int(node.at(n).getNode("id").real())
        listed = node.at(n).getNode("corners")
        corners = np.array([[listed.at(j).at(k).real() for k in range(3)] for j in range(4)])
        size = 0.3 if tag_id == 4 else 0.16
        expected = [T_map_tag[tag_id].transformFrom(c) for c in tag_corners(size)]
        np.testing.assert_allclose(corners, expected, atol=EXACT)
    storage.release()

    for line in _export(marker_map, ExportFormat.FIDUCIAL_SLAM, tmp_path).read_text().splitlines():
        fields = line.split()
        tag_id = int(fields[0])
        roll, pitch, yaw = (math.radians(float(v)) for v in fields[4:7])
        R = gtsam.Rot3.RzRyRx(roll, pitch, yaw)
        assert R.equals(T_map_tag[tag_id].rotation(), 1e-9)
        np.testing.assert_allclose([float(v) for v in fields[1:4]],
                                   T_map_tag[tag_id].translation(), atol=EXACT)  # fmt: skip

    text = _export(marker_map, ExportFormat.TAGSLAM, tmp_path).read_text()
    body = yaml.safe_load(text)["bodies"][0]["map"]
    for tag in body["tags"]:
        pose, T = tag["pose"], T_map_tag[tag["id"]]
        rotation = np.array([pose["rotation"][k] for k in "xyz"])
        assert gtsam.Rot3.Expmap(rotation).equals(T.rotation(), EXACT)
        np.testing.assert_allclose([pose["position"][k] for k in "xyz"], T.translation(),
                                   atol=EXACT)  # fmt: skip
        assert all(pose["rotation_noise"][k] > 0 for k in "xyz")


def test_a_2d_maps_csv_keeps_its_columns(tmp_path: Path) -> None:
    """A 2-D map's CSV has today's ten columns, nothing more."""
    marker = MapMarker(0, gtsam.Pose2(1.0, 2.0, 0.5), None, 3, 0.2, 1.0)
    marker_map = MarkerMap({0: marker}, (), 0, "DICT_4X4_50", 0.2, "slam", "x.mcap")
    header = _export(marker_map, ExportFormat.CSV, tmp_path).read_text().splitlines()[0]
    assert header == (
        "id,x_m,y_m,z_m,yaw_rad,sigma_x_m,sigma_y_m,sigma_yaw_rad,sigma_z_m,n_observations"
    )


def test_g2o_and_tum_parse_back_to_the_rigs_path_and_the_tags(tmp_path: Path) -> None:
    """map.g2o's VERTEX_SE3:QUAT lines read by gtsam.readG2o and trajectory.tum's lines read
    by hand give every pose to 1e-12 and every stamp to the nanosecond."""
    tag_map = _tag_map()
    tags = {i: tag.T_map_tag for i, tag in tag_map.tags.items()}
    view = (2, 3, tag_map.rig_poses[2].between(tags[3]), np.eye(6) * 4.0)
    write_g2o_3d(tmp_path / "map.g2o", tag_map.rig_poses, tags, [view])
    lines = (tmp_path / "map.g2o").read_text().splitlines()
    assert sum(line.startswith("VERTEX_SE3:QUAT ") for line in lines) == 5 + len(tags)
    assert lines[-1].startswith(f"EDGE_SE3:QUAT 2 {MARKER_VERTEX_OFFSET + 3} ")
    assert len(lines[-1].split()) == 3 + 7 + 21
    graph, values = gtsam.readG2o(str(tmp_path / "map.g2o"), True)
    assert graph.size() == 1
    for k, T in enumerate(tag_map.rig_poses):
        assert values.atPose3(k).equals(T, EXACT)
    for i, T in tags.items():
        assert values.atPose3(MARKER_VERTEX_OFFSET + i).equals(T, EXACT)

    write_tum_3d(tmp_path / "trajectory.tum", tag_map.frame_times, tag_map.rig_poses)
    rows = [line.split() for line in (tmp_path / "trajectory.tum").read_text().splitlines()]
    assert len(rows) == 5 and all(len(r) == 8 for r in rows)
    for row, t, T in zip(rows, tag_map.frame_times, tag_map.rig_poses, strict=True):
        whole, fraction = row[0].split(".")
        assert int(whole) * 1_000_000_000 + int(fraction) == int(t)
        x, y, z, qx, qy, qz, qw = map(float, row[1:])
        assert gtsam.Pose3(gtsam.Rot3.Quaternion(qw, qx, qy, qz), np.array([x, y, z])).equals(
            T, EXACT)  # fmt: skip


def test_align_rigid_3d_recovers_a_known_transform() -> None:
    """Points moved by a known rotation and translation are mapped back exactly; a tag map
    moved rigidly has no error, and one tag moved 3 cm and turned 2 degrees shows just that."""
    rng = np.random.default_rng(11)
    source = rng.normal(size=(8, 3)) * 3.0
    T_true = gtsam.Pose3(gtsam.Rot3.Ypr(2.5, -0.7, 1.9), np.array([4.0, -1.0, 2.0]))
    target = np.array([T_true.transformFrom(p) for p in source])
    assert align_rigid_3d(source, target).equals(T_true, EXACT)
    with pytest.raises(ValueError, match="3 points"):
        align_rigid_3d(source[:2], target[:2])
    with pytest.raises(ValueError, match="one line"):
        line = np.outer(np.arange(4.0), [1.0, 2.0, 3.0])
        align_rigid_3d(line, line)
    poses = {i: tag.T_map_tag for i, tag in _tag_map().tags.items()}
    moved = {i: T_true.compose(T) for i, T in poses.items()}
    errors = tag_errors_3d(poses, moved)
    assert errors.max_position_m < EXACT * 100 and errors.max_rotation_rad < EXACT * 100
    turned = dict(moved)
    turned[5] = moved[5].compose(gtsam.Pose3(gtsam.Rot3.Roll(math.radians(2.0)), np.zeros(3)))
    errors = tag_errors_3d(poses, turned)  # fitted on positions: a turn is not aligned away
    assert errors.max_rotation_rad == pytest.approx(math.radians(2.0), rel=1e-9)
    assert errors.median_rotation_rad < 1e-9 and errors.max_position_m < 1e-9
    shifted = dict(moved)
    shifted[5] = gtsam.Pose3(
        moved[5].rotation(), moved[5].translation() + np.array([0.03, 0.0, 0.0])
    )
    errors = tag_errors_3d(poses, shifted)
    # the alignment spreads the moved tag's 3 cm over all five: the largest error is below it
    assert 0.015 < errors.max_position_m < 0.03


def test_bad_3d_fields_are_named_in_one_line(tmp_path: Path) -> None:
    """An asymmetric or indefinite 6x6, a quaternion that is not unit, a wall flag on a floor
    tag or a non-boolean up: one line naming the file and the field."""
    document = _marker_map().to_document()

    def broken(change: Any) -> dict[str, Any]:
        copy = json.loads(json.dumps(document))
        change(copy)
        return copy

    def asymmetric(d: dict[str, Any]) -> None:
        d["markers"][0]["covariance_6x6"][0][1] += 1e-3

    def indefinite(d: dict[str, Any]) -> None:
        d["markers"][1]["covariance_6x6"] = (-np.eye(6)).tolist()

    def long_quaternion(d: dict[str, Any]) -> None:
        d["markers"][2]["quaternion"] = [1.0, 0.1, 0.0, 0.0]

    def floor_wall(d: dict[str, Any]) -> None:
        d["markers"][3]["wall"] = True

    def camera(d: dict[str, Any]) -> None:
        d["cameras"][1]["covariance_6x6"] = [[0.0] * 5] * 6

    cases = {
        "markers[0].covariance_6x6 must be a symmetric": asymmetric,
        "markers[1].covariance_6x6 must be positive semi-definite": indefinite,
        "markers[2].quaternion must be a unit": long_quaternion,
        "markers[3].wall must be false (its normal is vertical)": floor_wall,
        "up must be true or false": lambda d: d.update(up="yes"),
        "cameras[1].covariance_6x6 must be a 6x6": camera,
        "dimensions must be 2 or 3": lambda d: d.update(dimensions=4),
    }
    for words, change in cases.items():
        path = tmp_path / "bad.json"
        path.write_text(json.dumps(broken(change)))
        with pytest.raises(MarkerMapError) as error:
            MarkerMap.load(path)
        message = str(error.value)
        assert "\n" not in message and message.startswith(f"{path}: {words}"), message


class _Page(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.images: list[str] = []
        self.text: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        if tag == "img":
            self.images.append(dict(attrs).get("src") or "")

    def handle_data(self, data: str) -> None:
        self.text.append(data)


def test_the_result_folder_is_complete_strict_and_replaced_only_with_force(
    tmp_path: Path,
) -> None:
    """write_results_3d writes map.json, map.png, trajectory.tum, map.g2o, report.json and
    report.html; the report is strict JSON listing them, with the counts, each camera, each
    tag and the error against a rigidly moved truth (zero); the page shows the figure, the
    counts, the notes and the tag table; a second write needs --force."""
    tag_map = _tag_map()
    T_ref_map = gtsam.Pose3(gtsam.Rot3.Ypr(0.8, 0.1, -0.2), np.array([10.0, -3.0, 1.0]))
    truth = {i: T_ref_map.compose(tag.T_map_tag) for i, tag in tag_map.tags.items()}
    truth[99] = gtsam.Pose3()  # in the truth, not mapped
    run = Map3dRun(Path("rig.bag"), MapConfig.from_values(), tag_map, _marker_map(tag_map),
                   frames_read=9, views_read=60, notes=[Note("flow.test", "a note from the flow")],
                   seconds={"estimating": 1.5}, truth=truth)  # fmt: skip
    out = tmp_path / "result"
    written = write_results_3d(run, out, force=False)
    assert sorted(map(str, written)) == sorted(FILES_3D)
    report = json.loads((out / "report.json").read_text(), parse_constant=_refuse)
    assert sorted(report["files"]) == sorted(FILES_3D)
    assert report["dimensions"] == 3 and report["schema"].startswith("markergraph.report/")
    assert (report["frames"], report["frames_placed"], report["frames_skipped"]) == (9, 5, 2)
    assert (report["views"], report["views_used"], report["views_dropped"]) == (60, 57, 3)
    assert report["reprojection_rms_px"] == 0.42 and report["wall_tags"] == 3
    assert report["cameras"]["front"]["sigma_rotation_rad"] is None
    assert len(report["cameras"]["side"]["sigma_translation_m"]) == 3
    assert set(report["tags"]) == {str(i) for i in T_MAP_MARKER}
    assert report["notes"] == ["a note from the flow", "a note from the estimator"]
    error = report["error_3d"]
    assert error["tags_compared"] == 5 and error["tags_in_truth_not_mapped"] == [99]
    assert error["max_position_m"] < 1e-9 and error["max_rotation_rad"] < 1e-9
    _assert_same(MarkerMap.load(out / "map.json").to_document(), run.marker_map.to_document())
    assert (out / "map.png").stat().st_size > MIN_FIGURE_BYTES
    page = _Page()
    page.feed((out / "report.html").read_text())
    assert len(page.images) == 1 and page.images[0].startswith("data:image/png;base64,")
    text = " ".join(page.text)
    for words in ("a note from the estimator", "a note from the flow", "Tags", "side view"[:0]):
        assert words in text
    assert "Frames placed" in text or "frames placed" in text.lower()
    with pytest.raises(OutputError):
        write_results_3d(run, out, force=False)
    assert write_results_3d(run, out, force=True) == written


def test_plot_map_3d_draws_a_marker_map_or_a_tag_map(tmp_path: Path) -> None:
    """The plot takes the map either way, with a path and the truth, and writes a PNG."""
    tag_map = _tag_map()
    truth = {i: tag.T_map_tag for i, tag in tag_map.tags.items()}
    path_xyz = np.array([T.translation() for T in tag_map.rig_poses])
    plot_map_3d(_marker_map(tag_map), tmp_path / "a.png", truth=truth, path_xyz=path_xyz)
    plot_map_3d(tag_map, tmp_path / "b.png")
    for name in ("a.png", "b.png"):
        data = (tmp_path / name).read_bytes()
        assert data.startswith(b"\x89PNG") and len(data) > MIN_FIGURE_BYTES
