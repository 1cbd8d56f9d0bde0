"""AprilTag families: OpenCV's ArUco detector against the AprilTag 3 library, on rendered frames
with known corners, and on real photos for false positives.

The simulator's worlds with every marker printed in an AprilTag family, rendered as the log
writer does (colour, JPEG quality 90, decoded straight to grey): the office with the renderer's
usual blur (0.7 px) and with a softer one (1.5 px, an out-of-focus or smeared camera), and the
corridor loop (far and grazing tags). A tag counts as in view when all four of its true corners
(the simulator's projection) are at least 2 px inside the image; recall is over those, and over
those whose sides average 20 px or more (shorter ones are flagged ``small`` and hardly weigh in
a map). A detection whose id is in no drawn tag is a false positive. Corner error: each
matched corner's distance from the truth [px], after each detector's own refinement (OpenCV's
``cornerSubPix`` then ``edge_refined``; AprilTag 3's edge refinement then ``edge_refined``).

Detectors: OpenCV FAST (the front end's default) and FULL, AprilTag 3 on the whole image
(``quad_decimate`` 1, the backend's default) and on a half-size one (2, the binding's default).
Times: detection alone over frames in memory, one thread, each detector's best of
``--repeats`` passes, the detectors interleaved within each pass; ``ratio`` is the time over
OpenCV FAST's in the same pass set.

The real photos are OpenCV's ArUco tutorial photos (../shared/data/opencv-aruco-tutorial): they
hold ArUco markers and ChArUco boards, no AprilTags, so any AprilTag found there is false.
../shared/data holds no real AprilTag images (tagslam-test's bags carry detections, not
images), so agreement on real AprilTag photos could not be measured here.

With ``--map``, also the whole job on one rendered log: a minute of the office at 15 Hz (900
JPEG frames) with 36h11 tags, mapped by SLAM with ``--detector opencv`` and ``--detector
apriltag3`` (one worker, no cache): observations, the map's marker error against the truth
(aligned RMSE), and the CPU time of each run.

Usage: python tests/benchmarks/bench_apriltag.py [--families 36h11 16h5 25h9] [--repeats 3]
    [--seconds 60] [--map]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

import markergraph as mg
from markergraph.datasets import scenario
from markergraph.datasets.render import frames_with_true_corners
from markergraph.datasets.write import write_log
from markergraph.frontend.apriltag3 import AprilTag3Detector
from markergraph.frontend.detect import Detection, Detector, DetectorMode

DATA = Path(__file__).resolve().parents[3] / "shared" / "data"
PHOTOS = DATA / "opencv-aruco-tutorial" / "modules" / "aruco" / "tutorials"
INSIDE_PX = 2.0  # a tag is in view when its true corners are this far inside the image
OBSERVED_SIDE_PX = 20.0  # observations flag shorter sides as small (observe.SMALL_EDGE_PX)
SAME_TAG_PX = 5.0  # a detection within this of a drawn tag's corners is that tag

# (name, scenario, renderer's blur sigma [px])
SCENES = [
    ("office", "office", 0.7),
    ("office, soft", "office", 1.5),
    ("corridor", "corridor-loop", 0.7),
]

Frame = tuple[NDArray[np.uint8], dict[int, NDArray[np.float64]]]  # grey image, true corners


def in_view(corners: NDArray[np.float64], shape: tuple[int, ...]) -> bool:
    height, width = shape[:2]
    return bool(
        corners.min() >= INSIDE_PX
        and corners[:, 0].max() <= width - 1 - INSIDE_PX
        and corners[:, 1].max() <= height - 1 - INSIDE_PX
    )


def mean_side(corners: NDArray[np.float64]) -> float:
    return float(np.linalg.norm(corners - np.roll(corners, 1, axis=0), axis=1).mean())


def score(frames: list[Frame], found: list[list[Detection]]) -> dict[str, float]:
    """Recall (all tags in view, those with sides >= 20 px), false positives, tags found with
    wrong corners, and the corner error [px] (median, 90th percentile) against the truth."""
    in_sight = observed = hits = observed_hits = false = wrong = 0
    errors: list[float] = []
    for (grey, truth), detections in zip(frames, found, strict=True):
        by_id = {d.marker_id: d.corners for d in detections}
        false += sum(1 for i in by_id if i not in truth)
        for marker_id, true in truth.items():
            if not in_view(true, grey.shape):
                continue
            big = mean_side(true) >= OBSERVED_SIDE_PX
            in_sight += 1
            observed += big
            corners = by_id.get(marker_id)
            if corners is None:
                continue
            distance = np.linalg.norm(corners - true, axis=1)
            if distance.max() >= SAME_TAG_PX:
                wrong += 1
                continue
            hits += 1
            observed_hits += big
            errors.extend(distance)
    return {
        "tags": in_sight,
        "recall": hits / max(in_sight, 1),
        "recall_20": observed_hits / max(observed, 1),
        "false": false,
        "wrong": wrong,
        "median_px": float(np.median(errors)) if errors else float("nan"),
        "p90_px": float(np.percentile(errors, 90)) if errors else float("nan"),
    }


def detectors(dictionary: str) -> dict[str, Callable[[NDArray[np.uint8]], list[Detection]]]:
    """The detectors compared, by the name the table gives them."""
    return {
        "opencv fast": Detector(dictionary, mode=DetectorMode.FAST).detect,
        "opencv full": Detector(dictionary, mode=DetectorMode.FULL).detect,
        "apriltag3 (decimate 1)": AprilTag3Detector(dictionary, quad_decimate=1.0).detect,
        "apriltag3 (decimate 2)": AprilTag3Detector(dictionary, quad_decimate=2.0).detect,
    }


def timed(
    named: dict[str, Callable[[NDArray[np.uint8]], list[Detection]]],
    images: list[NDArray[np.uint8]],
    repeats: int,
) -> tuple[dict[str, float], dict[str, list[list[Detection]]]]:
    """Each detector's best time per frame [ms] over ``repeats`` passes (interleaved), and its
    detections."""
    best = dict.fromkeys(named, float("inf"))
    found: dict[str, list[list[Detection]]] = {}
    for _ in range(repeats):
        for name, detect in named.items():
            start = time.perf_counter()
            found[name] = [detect(image) for image in images]
            best[name] = min(best[name], (time.perf_counter() - start) / len(images) * 1e3)
    return best, found


def real_photo_false_positives(dictionary: str) -> dict[str, int]:
    """AprilTags each detector finds on OpenCV's tutorial photos (none are there)."""
    photos = sorted(PHOTOS.glob("*/images/*.*")) if PHOTOS.is_dir() else []
    named = detectors(dictionary)
    return {
        name: sum(len(detect(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE))) for p in photos)
        for name, detect in named.items()
    } | {"photos": len(photos)}


def map_with_each_library(seconds: float = 60.0) -> None:
    """The whole job on a rendered 36h11 office log, with each library: prints observations,
    aligned marker RMSE and CPU seconds."""
    world, route = scenario("office")
    markers = tuple(dataclasses.replace(m, dictionary="DICT_APRILTAG_36h11") for m in world.markers)
    world = dataclasses.replace(world, markers=markers)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "office-36h11.mcap"
        write_log(world, route, path, seed=3, duration_s=seconds, compressed=True)
        print(f"\nmap --method slam on {seconds:.0f} s of the office in 36h11 at 15 Hz:")
        for choice in ("opencv", "apriltag3"):
            config = mg.MapConfig.from_values(
                {"dictionary": "DICT_APRILTAG_36h11", "detector": choice, "workers": 1}
            )
            start = time.process_time()
            result = mg.map_log(path, config, cache=False)
            cpu_s = time.process_time() - start
            slam = result.results[0]
            aligned = slam.map_error_aligned
            rmse = float("nan") if aligned is None else aligned.rmse_position_m
            print(
                f"  --detector {choice}: {len(result.extraction.observations)} observations, "
                f"aligned RMSE {rmse:.3f} m, {cpu_s:.1f} CPU s"
            )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--families", nargs="*", default=["36h11", "16h5", "25h9"])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=60.0, help="of each route, at 2 Hz")
    parser.add_argument("--map", action="store_true", help="also map a rendered log with each")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    print(f"load average before: {os.getloadavg()[0]:.2f}")
    header = (
        "| family | scene | detector | ms/frame | ratio | recall | recall >= 20 px | "
        "false | wrong | median px | p90 px |"
    )
    print(header)
    print("|---" * (header.count("|") - 1) + "|")
    for family in args.families:
        dictionary = f"DICT_APRILTAG_{family}"
        for scene, scenario_name, blur_px in SCENES:
            frames = frames_with_true_corners(scenario_name, dictionary, args.seconds, blur_px)
            times, found = timed(detectors(dictionary), [g for g, _ in frames], args.repeats)
            for name, detections in found.items():
                s = score(frames, detections)
                print(
                    f"| {family} | {scene} ({s['tags']:.0f} tags) | {name} | "
                    f"{times[name]:.1f} | {times[name] / times['opencv fast']:.2f} | "
                    f"{s['recall']:.1%} | {s['recall_20']:.1%} | {s['false']:.0f} | "
                    f"{s['wrong']:.0f} | {s['median_px']:.3f} | {s['p90_px']:.3f} |",
                    flush=True,
                )
    print()
    print("False positives on OpenCV's real tutorial photos (no AprilTags in them):")
    for family in args.families:
        counts = real_photo_false_positives(f"DICT_APRILTAG_{family}")
        photos = counts.pop("photos")
        print(f"  {family} ({photos} photos): " + ", ".join(f"{k} {v}" for k, v in counts.items()))
    if args.map:
        map_with_each_library()
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
