"""The covariances' share of settings the data leave uncertain (a *consider* covariance, after
Schmidt: :mod:`~markergraph.estimator.consider`): the map is solved again at another value of
the setting, and each marker's move between the two maps grows its covariance.

- A rolling shutter's readout, when not given: anywhere from 0 to :data:`READOUT_MAX_S`, no
  residual can choose it; the map solved at the longest, each move d adds d dᵀ/3 (a uniform
  error's second moment, measured from one end of its range).
- The odometry's scale, its turn scale and the camera's delay, where SLAM's residuals chose
  them: each known to a standard deviation, from the cost's curvature at its minimum; and the
  depth's scale, where the markers' size measured it. The map solved with the one at one sigma
  more, each move d adds d dᵀ (a Gaussian error's, to first order; each taken as independent).
"""

from __future__ import annotations

import numpy as np

from markergraph.common import Note
from markergraph.common.numbers import shown
from markergraph.estimator import Estimate
from markergraph.estimator.consider import AT_ONE_END, with_considered
from markergraph.estimator.timing import READOUT_MAX_S
from markergraph.prepare import Considered

__all__ = ["no_readout_share", "no_sigma_share", "with_readout_share", "with_sigma_share"]

# Each measured setting as a note says it: its name, its sigma in the note's unit, what
# measured it, its flag.
_RESIDUALS = "SLAM's residuals"
_SAID = {
    "odometry.scale": ("the odometry's scale", lambda sigma: f"{100 * sigma:.2f} %",
                       _RESIDUALS, "--odometry-scale"),
    "odometry.turn_scale": ("the odometry's turn scale", lambda sigma: f"{100 * sigma:.2f} %",
                            _RESIDUALS, "--odometry-turn-scale"),
    "camera.delay": ("the camera's delay", lambda sigma: f"{sigma / 1e6:.1f} ms", _RESIDUALS,
                     "--camera-delay"),
    "depth.scale": ("the depth's scale", lambda sigma: f"{100 * sigma:.2f} %",
                    "the markers' size; the odometry's scale follows it", "--depth-scale"),
}  # fmt: skip


def with_readout_share(estimate: Estimate, moved: Estimate) -> Estimate:
    """``estimate`` (a rolling shutter's readout taken as 0) with its markers' covariances
    grown by the readout's share, ``moved`` solved as if it were :data:`READOUT_MAX_S`, and a
    note saying how far the markers moved."""
    considered = with_considered(estimate, moved, AT_ONE_END)
    far = _farthest(estimate, moved)
    if far is not None:
        considered.notes.append(Note(
            "camera.readout_share",
            f"the rolling shutter's readout not given: the markers move by up to "
            f"{shown(far, '.3f')} m between a readout of 0 and of {READOUT_MAX_S * 1e3:.0f} ms"
            + _carried(estimate) + " (--readout MS gives the camera's, 0 a global shutter)",
            figure=far,
        ))  # fmt: skip
    return considered


def no_readout_share(error: Exception) -> Note:
    """Why the map's covariances lack an unknown readout's share."""
    return Note(
        "camera.readout_share_unknown",
        f"the rolling shutter's readout not given, and the map could not be made as if it were "
        f"{READOUT_MAX_S * 1e3:.0f} ms ({error}): its covariances lack the readout's share "
        "(--readout MS gives the camera's, 0 a global shutter)",
    )


def with_sigma_share(
    estimate: Estimate, moved: Estimate, considered: Considered, of: str | None = None
) -> Estimate:
    """``estimate`` with its markers' covariances grown by the share of a setting SLAM's
    residuals chose, ``moved`` solved on ``considered`` (the setting one sigma further), and a
    note (``of``: whose setting, in a map of several logs) saying how far the markers moved."""
    grown = with_considered(estimate, moved, 1.0)
    far = _farthest(estimate, moved)
    if far is not None:
        name, sigma, source, flag = _SAID[considered.setting]
        whose = "" if of is None else f" of {of}"
        grown.notes.append(Note(
            f"{considered.setting}_share",
            f"{name}{whose} is known to {sigma(considered.sigma)} (1 sigma, from {source}): "
            f"the markers move by up to {shown(far, '.3f')} m over one sigma of it"
            + _carried(estimate) + f" ({flag} sets it, taken as exact)",
            figure=far,
        ))  # fmt: skip
    return grown


def no_sigma_share(considered: Considered, error: Exception) -> Note:
    """Why the map's covariances lack the share of a setting SLAM's residuals chose."""
    return Note(
        f"{considered.setting}_share_unknown",
        f"the map could not be solved again with {_SAID[considered.setting][0]} one sigma "
        f"further ({error}): its covariances lack its share",
    )


def _farthest(estimate: Estimate, moved: Estimate) -> float | None:
    """The largest move of a marker in both maps [m]; None where they share none but the home
    marker (the map's frame: it cannot move)."""
    both = (set(estimate.markers) & set(moved.markers)) - {estimate.home_id}
    if not both:
        return None
    return max(
        float(np.linalg.norm(
            moved.markers[i].T_map_marker.translation()
            - estimate.markers[i].T_map_marker.translation()
        ))
        for i in both
    )  # fmt: skip


def _carried(estimate: Estimate) -> str:
    """Whether the map's covariances carry a share, as a note's clause."""
    if any(m.covariance is not None for m in estimate.markers.values()):
        return ", and their covariances include it"
    return " (no covariance to carry it)"
