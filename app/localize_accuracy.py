"""What a localisation's two accuracy figures are: its own sigma given the map, and the ATE
against the logged truth; and the note when the ATE is far beyond what the sigmas allow."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from markergraph.common import Note
from markergraph.estimator.localization import Localization

__all__ = [
    "ATE_ALIGNMENT",
    "ATE_MEANS",
    "SIGMA_MEANS",
    "TOO_FAR_RATIO",
    "LocalizeAccuracy",
    "accuracy_entry",
    "accuracy_lines",
    "accuracy_of",
    "ate_note",
]

TOO_FAR_RATIO = 3.0  # an ATE above 3x the RMS sigma is not the localisation's own noise
SIGMA_MEANS = (
    "the localisation's own uncertainty given the map (the map's markers taken as they are, "
    "with their covariances)"
)
ATE_MEANS = (
    "the error against the logged ground truth: it adds the map's own error (each marker where "
    "the map put it, not where it is) and the alignment chosen"
)
ATE_ALIGNMENT = (
    "no alignment: the truth carried into the map's frame through the home marker's true pose "
    "(home-fixed, as the map's own marker RMSE)"
)


@dataclass(frozen=True, slots=True)
class LocalizeAccuracy:
    """A localisation's accuracy figures.

    Attributes:
        median_sigma_m: median over the poses of sqrt(var x + var y) [m].
        rms_sigma_m: the RMS of the same, the figure an ATE is compared with [m].
        ate_m: RMS position error against the truth, home-fixed, if the log has truth [m].
        ate_aligned_m: the same after a rigid 2-D alignment (evo's ``--align``) [m].
    """

    median_sigma_m: float
    rms_sigma_m: float
    ate_m: float | None
    ate_aligned_m: float | None

    @property
    def too_far(self) -> bool:
        """Whether the ATE is beyond :data:`TOO_FAR_RATIO` times the RMS sigma."""
        return self.ate_m is not None and self.ate_m > TOO_FAR_RATIO * self.rms_sigma_m


def accuracy_of(
    localization: Localization, ate_m: float | None, ate_aligned_m: float | None
) -> LocalizeAccuracy:
    """The figures of a localisation with its ATEs (None without truth)."""
    P = localization.pose_covariances
    sigmas = np.sqrt(P[:, 0, 0] + P[:, 1, 1]) if len(P) else np.array([np.nan])
    return LocalizeAccuracy(
        float(np.median(sigmas)), float(np.sqrt(np.mean(sigmas**2))), ate_m, ate_aligned_m
    )


def ate_note(accuracy: LocalizeAccuracy) -> Note | None:
    """A note when the ATE is far beyond what the sigmas allow, naming the likely causes."""
    if not accuracy.too_far or accuracy.ate_m is None:
        return None
    ratio = accuracy.ate_m / accuracy.rms_sigma_m
    aligned = (
        f" ({100 * accuracy.ate_aligned_m:.1f} cm after a rigid alignment)"
        if accuracy.ate_aligned_m is not None
        else ""
    )
    return Note(
        "localization.ate_beyond_sigma",
        f"the ATE {100 * accuracy.ate_m:.1f} cm{aligned} is {ratio:.1f}x the RMS position sigma "
        f"{100 * accuracy.rms_sigma_m:.1f} cm: more than the localisation's own noise, so the "
        "map's own error (a marker off where the map put it, or the map's home yaw) or a wrong "
        "map for this log",
        figure=ratio,
    )


def accuracy_lines(accuracy: LocalizeAccuracy) -> list[str]:
    """The figures as sentences a person reads, each saying what it is."""
    lines = [
        f"median position sigma {100 * accuracy.median_sigma_m:.1f} cm "
        f"(RMS {100 * accuracy.rms_sigma_m:.1f} cm): {SIGMA_MEANS}"
    ]
    if accuracy.ate_m is not None:
        lines.append(f"ATE {100 * accuracy.ate_m:.1f} cm with {ATE_ALIGNMENT}")
        if accuracy.ate_aligned_m is not None:
            lines.append(
                f"ATE {100 * accuracy.ate_aligned_m:.1f} cm after a rigid 2-D alignment "
                "(evo --align)"
            )
        lines.append(f"each ATE is {ATE_MEANS}")
    else:
        lines.append("no ATE: the log carries no ground truth")
    return lines


def accuracy_entry(accuracy: LocalizeAccuracy) -> dict[str, float | str | None]:
    """report.json's ``accuracy``: the figures and what each is."""
    return {
        "median_position_sigma_m": accuracy.median_sigma_m,
        "rms_position_sigma_m": accuracy.rms_sigma_m,
        "position_sigma_is": SIGMA_MEANS,
        "ate_m": accuracy.ate_m,
        "ate_aligned_m": accuracy.ate_aligned_m,
        "ate_alignment": ATE_ALIGNMENT,
        "ate_is": ATE_MEANS,
    }
