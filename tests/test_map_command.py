"""`markergraph map` end to end on the bundled sample: every file it writes, read back."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import gtsam
import numpy as np
import pytest

from markergraph.formats import MARKER_VERTEX_OFFSET, read_tum
from markergraph.markermap import MAP_SCHEMA

pytestmark = pytest.mark.slow  # its tests share a fixture that renders or maps a whole log

METHODS = ("slam", "closed-form", "marker-graph", "isam2", "ekf")


def run_map(*arguments: str, cache: Path) -> subprocess.CompletedProcess[str]:
    environment = {**os.environ, "MARKERGRAPH_CACHE": str(cache)}
    return subprocess.run(
        [sys.executable, "-m", "markergraph.cli", "map", *arguments],
        capture_output=True,
        text=True,
        env=environment,
    )


@pytest.fixture(scope="module")
def mapped(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    folder = tmp_path_factory.mktemp("map")
    settings = folder / "robot.yaml"
    settings.write_text("method: all\nmarker_size: 0.2\n")
    run = run_map(
        "--config", str(settings), "--out", str(folder / "result"), cache=folder / "cache"
    )
    assert run.returncode == 0, run.stderr
    return folder / "result", run.stdout


def test_summary_names_the_sample_and_every_method(mapped) -> None:
    """With no log the sample is used and said so; the summary has a row per method."""
    _, stdout = mapped
    assert "bundled corridor-loop sample" in stdout
    for method in METHODS:
        assert any(line.startswith(method) for line in stdout.splitlines())


def test_map_json_matches_ground_truth(mapped) -> None:
    """map.json (SLAM) places every marker within 0.35 m RMS of the logged ground truth, the
    same figure report.json gives; the paper's closed form does worse. On this clean log every
    method's verdict is ok, and every true marker lies inside SLAM's, iSAM2's, the EKF's and the
    marker graph's 95 % ellipses (11 of 11 each)."""
    folder, _ = mapped
    document = json.loads((folder / "map.json").read_text())
    report = json.loads((folder / "report.json").read_text())
    assert document["schema"] == MAP_SCHEMA and document["method"] == "slam"
    assert len(document["markers"]) == 12 and document["links"]
    assert report["ground_truth"] and report["frames"] > 1000
    assert report["settings"]["method"] == "all"  # from the --config file
    assert report["methods"]["slam"]["marker_rmse_m"] < 0.35
    for method in METHODS:
        assert report["methods"][method]["verdict"] == "ok", report["verdict_reasons"]
        if method != "closed-form":
            assert report["methods"][method]["inside_95_ellipse_share"] == 1.0, method
    assert (
        report["methods"]["closed-form"]["marker_rmse_m"]
        > (report["methods"]["slam"]["marker_rmse_m"])
    )
    # The truth at the estimate's own stamps, one pose for each.
    truth, estimated = read_tum(folder / "ground_truth.tum"), read_tum(folder / "trajectory.tum")
    assert len(truth.t_ns) > 400 and np.array_equal(truth.t_ns, estimated.t_ns)


def test_g2o_tum_png_and_per_method_files_read_back(mapped) -> None:
    """map.g2o loads in gtsam.readG2o; TUM files read; PNGs are images; each method has its
    own folder."""
    folder, _ = mapped
    graph, initial = gtsam.readG2o(str(folder / "map.g2o"), False)
    assert graph.size() > 100 and initial.exists(MARKER_VERTEX_OFFSET + 0)
    read = read_tum(folder / "trajectory.tum")
    stamps, poses = read.t_ns, read.poses
    assert len(stamps) == len(poses) > 100 and np.all(np.diff(stamps) > 0)
    for image in (folder / "map.png", folder / "comparison.png"):
        assert cv2.imread(str(image)) is not None
    for method in METHODS:
        assert (folder / "methods" / method / "map.json").is_file()
    assert (folder / "map.svg").read_text().lstrip().startswith("<?xml")


def test_existing_result_folder_is_kept_without_force(mapped, tmp_path: Path) -> None:
    """A second run into the same folder fails in one line and leaves it untouched."""
    folder, _ = mapped
    before = (folder / "map.json").read_bytes()
    run = run_map("--out", str(folder), cache=tmp_path / "unused")
    assert run.returncode == 1
    assert len(run.stderr.strip().splitlines()) == 1 and "--force" in run.stderr
    assert (folder / "map.json").read_bytes() == before


def test_not_a_log_is_one_line(tmp_path: Path) -> None:
    """A file that is not MCAP: exit 1, one line naming it, no result folder."""
    bad = tmp_path / "notes.mcap"
    bad.write_text("hello")
    run = run_map(str(bad), "--out", str(tmp_path / "out"), cache=tmp_path / "cache")
    assert run.returncode == 1 and str(bad) in run.stderr
    assert len(run.stderr.strip().splitlines()) == 1 and not (tmp_path / "out").exists()


def test_overlay_reads_with_the_standard_reader(mapped) -> None:
    """overlay.mcap holds the map as a MarkerArray (arrows at the map.json poses), the path
    and map -> odom transforms, readable by mcap + mcap-ros2-support alone."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    folder, _ = mapped
    document = json.loads((folder / "map.json").read_text())
    positions = {m["id"]: (m["x"], m["y"]) for m in document["markers"]}
    with open(folder / "overlay.mcap", "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        types = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
        assert types == {
            "/markergraph/markers": "visualization_msgs/msg/MarkerArray",
            "/markergraph/path": "nav_msgs/msg/Path",
            "/markergraph/pose": "geometry_msgs/msg/PoseStamped",
            "/tf": "tf2_msgs/msg/TFMessage",
            "/tf_static": "tf2_msgs/msg/TFMessage",
        }
        path_sizes = []
        for _, channel, _, decoded in reader.iter_decoded_messages(
            topics=["/markergraph/markers", "/markergraph/path"]
        ):
            if channel.topic == "/markergraph/path":
                path_sizes.append(len(decoded.poses))
                continue
            arrows = [m for m in decoded.markers if m.ns == "normals"]
            assert len(arrows) == len(positions)
            for arrow in arrows:
                assert (arrow.pose.position.x, arrow.pose.position.y) == pytest.approx(
                    positions[arrow.id]
                )
        assert len(path_sizes) > 1 and path_sizes[-1] > 100  # the path grows along the log


def test_one_marker_maps_honestly_and_none_fails_in_one_line(mapped, tmp_path: Path) -> None:
    """Only marker 0 kept: the map is that marker alone, no links, said so; no marker at all:
    exit 1, one line, no folder."""
    folder, _ = mapped
    cache = folder.parent / "cache"  # the fixture's rendered sample
    run = run_map("--ids", "0", "--no-plots", "--out", str(tmp_path / "one"), cache=cache)
    assert run.returncode == 0, run.stderr
    assert "only marker 0 was seen" in run.stderr
    document = json.loads((tmp_path / "one" / "map.json").read_text())
    assert [m["id"] for m in document["markers"]] == [0] and document["links"] == []
    assert len(read_tum(tmp_path / "one" / "trajectory.tum").t_ns) > 10
    run = run_map("--ids", "49", "--out", str(tmp_path / "none"), cache=cache)
    assert run.returncode == 1 and "no markers of DICT_4X4_50" in run.stderr
    assert len(run.stderr.strip().splitlines()) == 1 and not (tmp_path / "none").exists()


def test_ate_and_rpe_are_evos_to_its_printed_digits(mapped) -> None:
    """evo itself, on the folder's trajectory.tum and ground_truth.tum (what `evo_ape tum` and
    `evo_rpe tum --delta 1 --delta_unit m` read), gives report.json's ATE and RPE."""
    from evo.core import metrics, sync
    from evo.tools import file_interface

    folder, _ = mapped
    reported = json.loads((folder / "report.json").read_text())["methods"]["slam"]
    reference = file_interface.read_tum_trajectory_file(str(folder / "ground_truth.tum"))
    estimated = file_interface.read_tum_trajectory_file(str(folder / "trajectory.tum"))
    reference, estimated = sync.associate_trajectories(reference, estimated)
    assert estimated.num_poses > 100
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((reference, estimated))
    rpe = metrics.RPE(metrics.PoseRelation.translation_part, delta=1.0,
                      delta_unit=metrics.Unit.meters, all_pairs=False)  # fmt: skip
    rpe.process_data((reference, estimated))
    rmse = metrics.StatisticsType.rmse
    assert f"{ape.get_statistic(rmse):.6f}" == f"{reported['ate_m']:.6f}"
    assert f"{rpe.get_statistic(rmse):.6f}" == f"{reported['rpe_m_per_m']:.6f}"
