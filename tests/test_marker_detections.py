"""Each marker's detections counted over every frame, not only the levelled ones: report.json's
``marker_detections`` against OpenCV's own detector run frame by frame."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import cv2
import numpy as np

from markergraph.frontend import extract, open_log
from markergraph.frontend.topics import COLOR_TOPICS


def test_level_frames_count_every_detection(log: Path) -> None:
    """On the paper room (a level base), every marker's detections are the ones OpenCV's plain
    ``detectMarkers`` finds in the log's frames, none dropped, each one an observation."""
    result = extract(log)
    topic = next(t.topic for t in open_log(log).topics if t.topic in COLOR_TOPICS)
    detector = cv2.aruco.ArucoDetector(
        cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50), cv2.aruco.DetectorParameters()
    )
    plain: Counter[int] = Counter()
    for message in open_log(log).messages([topic]):
        grey = cv2.imdecode(np.frombuffer(message.decoded.data, np.uint8), cv2.IMREAD_GRAYSCALE)
        _, ids, _ = detector.detectMarkers(grey)
        plain.update(() if ids is None else ids.ravel().tolist())
    counts = result.marker_detections
    assert result.levelled_frames == 0 and len(plain) == 3
    assert {i: c.detections for i, c in counts.items()} == dict(plain)
    assert all(c.dropped == 0 and not c.left_out for c in counts.values())
    assert sum(plain.values()) == len(result.observations)
