"""What a person needs to trust or fix a map: each marker's residuals, the factors the robust
kernel gave up on, the odometry steps the observations disagree with, and the markers left out.

Residuals are whitened (a factor's error in its own standard deviations), so one scale serves
observations, odometry and the marker graph's links, and the EKF's innovations (their
Mahalanobis length) sit on it too.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Sequence
from typing import Any

import numpy as np

from markergraph.estimator import Estimate, Frames

__all__ = ["ODOMETRY_OUTLIER", "diagnostics"]

# A 3-DOF whitened error beyond sqrt(chi2_3(0.997)): one step in 370 by chance.
ODOMETRY_OUTLIER = math.sqrt(14.156)


def _stamp(keys: tuple[str, ...], stamps: Sequence[int]) -> int | None:
    """The stamp of the last robot pose a factor touches."""
    poses = [int(k[1:]) for k in keys if k.startswith("x")]
    return stamps[max(poses)] if poses else None


def diagnostics(estimate: Estimate, frames: Frames | Sequence[Frames]) -> dict[str, Any]:
    """A JSON-ready account of one method's estimate (of one log's frames, or of several
    sessions' in the order they were given).

    Keys: ``markers`` (id -> number of factors, median, 95th percentile and largest whitened
    error, and how many were down-weighted), ``downweighted`` (each observation or link the
    robust kernel weighed below a quarter: kind, stamp, marker ids, whitened error),
    ``odometry_outliers`` (odometry steps whose whitened error exceeds
    :data:`ODOMETRY_OUTLIER`) and ``unplaced`` (id -> why). A method without factors (the closed
    form) has ``"residuals": "none"``.
    """
    sessions = [frames] if isinstance(frames, Frames) else list(frames)
    stamps = [f.t_ns for session in sessions for f in session.frames]
    per_marker: defaultdict[int, list[float]] = defaultdict(list)
    downweighted_per_marker: defaultdict[int, int] = defaultdict(int)
    downweighted, odometry_outliers = [], []
    for r in estimate.residuals:
        markers = r.marker_ids
        if r.kind == "odometry":
            if r.whitened_error > ODOMETRY_OUTLIER:
                odometry_outliers.append(
                    {"t_ns": _stamp(r.keys, stamps), "whitened_error": r.whitened_error}
                )
            continue
        if r.kind not in ("observation", "edge"):
            continue
        for marker_id in markers:
            per_marker[marker_id].append(r.whitened_error)
            downweighted_per_marker[marker_id] += r.downweighted
        if r.downweighted:
            downweighted.append({
                "kind": r.kind, "t_ns": _stamp(r.keys, stamps), "marker_ids": markers,
                "whitened_error": r.whitened_error,
            })  # fmt: skip
    result: dict[str, Any] = {
        "unplaced": {str(k): v for k, v in sorted(estimate.unplaced.items())},
    }
    if not estimate.residuals:
        result["residuals"] = "none"
        return result
    result["markers"] = {
        str(marker_id): {
            "factors": len(errors),
            "whitened_median": float(np.median(errors)),
            "whitened_p95": float(np.percentile(errors, 95)),
            "whitened_max": float(np.max(errors)),
            "downweighted": downweighted_per_marker[marker_id],
        }
        for marker_id, errors in sorted(per_marker.items())
    }
    result["downweighted"] = sorted(downweighted, key=lambda d: (d["t_ns"] or 0, d["marker_ids"]))
    result["odometry_outliers"] = odometry_outliers
    return result
