"""A verdict on every estimate: ``ok``, ``suspect`` or ``failed``, each with the sentences that
decided it, from evidence the run already has (no ground truth).

The evidence, and why each check is set where it is:

* **Residuals.** A GTSAM solution's squared whitened residuals sum to a chi-square with as many
  degrees of freedom as the graph has to spare. Our sigmas are cautious (theta's by about 2.6x
  on real rigs), so an honest solution reads 1 or below (0.07 on the bundled sample); a ratio
  above :data:`RESIDUAL_RATIO_SUSPECT` and beyond the chi-square's 99.9 % quantile means the
  data disagree with the map beyond any noise the model allows (odometry 20 % long against
  the observations reads 2.0 in the simulated paper room). A marker whose own observations'
  median whitened error exceeds :data:`MARKER_RESIDUAL_SUSPECT` and stands out from the other
  markers' (:data:`MARKER_STANDS_OUT`) disagrees with the rest of the map. The EKF's
  innovations (NIS) are read the same way.
* **Methods that disagree.** Two methods' positions of a marker are compared under the sum of
  their covariances (generous: their errors correlate). A method that disagrees with every
  other method with covariances, beyond :data:`DISAGREEMENT_D2` and :data:`DISAGREEMENT_FLOOR_M`,
  is suspect; when all disagree with all, no method can be singled out and each is suspect.
  The closed form has no covariance: it is compared with the best judged method by distance,
  against :data:`CLOSED_FORM_SHARE` of the map's size.
* **Markers that face away.** A camera sees a marker's face only from in front of it: a marker
  the estimated path saw from behind in most of its sightings has its yaw turned round.
* **Ellipses larger than the map.** A marker whose 95 % ellipse is longer than the whole map is
  not located by the data: the estimate there is a guess, however well it fits.
* **Markers left unplaced**, **an optimiser that did not converge**, **frames that do not
  decode or whose stamps their neighbours contradict**, **odometry samples dropped**,
  **searches that stopped at the end of their range** (the camera's delay, the odometry's
  scale), and **depth that finds no marker** come from the run itself.

A check that cannot be made (one method alone, no covariance) adds no reason: a verdict says
what the evidence shows, not what it cannot see.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum
from typing import Any

import numpy as np

from markergraph.common.notes import some_of
from markergraph.estimator import Estimate, Method, Observation
from markergraph.estimator.evidence import (
    chi2_upper,
    ellipse_semi_axes_m,
    facing_away,
    map_extent_m,
    marker_disagreement,
    residual_fit,
)
from markergraph.estimator.odometry_scale import SCALES
from markergraph.estimator.tag_scale import ODOMETRY_SCALE_KIND, ODOMETRY_SCALE_OFF
from markergraph.estimator.tags3d import TagMap3d
from markergraph.estimator.timing import DELAYS_S
from markergraph.frontend import Extraction
from markergraph.frontend.dictionary_check import markers_beyond

__all__ = ["Judgement", "Reason", "Verdict", "judge_run", "judge_tag_map", "worst"]

RESIDUAL_RATIO_SUSPECT = 1.5  # chi2 / dof: honest noise reads 1, our cautious sigmas below
MARKER_RESIDUAL_SUSPECT = 3.0  # a marker's median whitened error
MARKER_STANDS_OUT = 1.5  # ... and this times the median over the markers' medians
DOWNWEIGHTED_SUSPECT = 0.05  # share of observations (or links) the robust kernel overruled
DISAGREEMENT_D2 = 13.82  # chi-square, 2 dof, 99.9 %
DISAGREEMENT_FLOOR_M = 0.05  # simulated covariances can be millimetres; a few cm is no fault
CLOSED_FORM_SHARE = 0.05  # of the map's size: the closed form's chain drift we still call ok
CLOSED_FORM_FLOOR_M = 0.25
ELLIPSE_SIGMAS = math.sqrt(5.991)  # 95 % for 2 dof
BEHIND_SHARE = 0.5  # a marker seen from behind its face in most of its sightings faces away
BEHIND_MIN_SIGHTINGS = 3
DROPPED_SHARE_SUSPECT = 0.10  # of colour frames that do not decode
DROPPED_ODOMETRY_SUSPECT = 0.05  # of odometry samples: a gap of one in twenty is no harm
DEPTH_MISS_SHARE_SUSPECT = 0.5  # of observations that tried depth


class Verdict(Enum):
    """How far an estimate can be trusted; the order is by gravity."""

    OK = "ok"
    SUSPECT = "suspect"
    FAILED = "failed"

    @property
    def rank(self) -> int:
        return list(Verdict).index(self)


@dataclass(frozen=True)
class Reason:
    """One piece of evidence against an estimate.

    Attributes:
        verdict: the verdict it alone calls for (``suspect`` or ``failed``).
        check: which check found it (``residuals``, ``disagreement``, ``ellipses``, ``unplaced``,
            ``converged``, ``facing``, ``dropped``, ``depth``, ``odometry``, ``delay``).
        text: a plain sentence naming the evidence and its figure.
        figure: that figure, in the unit the sentence gives.
    """

    verdict: Verdict
    check: str
    text: str
    figure: float


@dataclass(frozen=True)
class Judgement:
    """A verdict and the reasons behind it (none for ``ok``)."""

    verdict: Verdict
    reasons: tuple[Reason, ...] = ()

    @classmethod
    def of(cls, reasons: list[Reason]) -> Judgement:
        return cls(worst(r.verdict for r in reasons), tuple(reasons))

    def to_json(self) -> dict[str, Any]:
        return {"verdict": self.verdict.value, "verdict_reasons": [r.text for r in self.reasons]}


def worst(verdicts: Any) -> Verdict:
    """The gravest of some verdicts (``ok`` for none)."""
    return max(verdicts, key=lambda v: v.rank, default=Verdict.OK)


def _suspect(check: str, figure: float, text: str) -> Reason:
    return Reason(Verdict.SUSPECT, check, text, figure)


def _failed(check: str, figure: float, text: str) -> Reason:
    return Reason(Verdict.FAILED, check, text, figure)


# --- one estimate on its own ---------------------------------------------------------------


def _residual_reasons(estimate: Estimate) -> list[Reason]:
    reasons = []
    fit = residual_fit(estimate)
    if fit is not None and fit.ratio > RESIDUAL_RATIO_SUSPECT and fit.chi2 > chi2_upper(fit.dof):
        largest = max(estimate.residuals, key=lambda r: r.whitened_error)
        reasons.append(_suspect(
            "residuals", fit.ratio,
            f"its residuals are {fit.ratio:.1f} times the size its noise model allows (chi-square "
            f"{fit.chi2:.0f} for {fit.dof} degrees of freedom; the largest, {largest.kind} "
            f"{'-'.join(largest.keys)}, {largest.whitened_error:.0f} sigma): the data disagree "
            "with the map",
        ))  # fmt: skip
    measured = [r for r in estimate.residuals if r.kind in ("observation", "edge")]
    overruled = sum(r.downweighted for r in measured)
    if measured and overruled / len(measured) > DOWNWEIGHTED_SUSPECT:
        share = overruled / len(measured)
        reasons.append(_suspect(
            "residuals", 100 * share,
            f"the robust kernel overruled {100 * share:.0f} % of its observations ({overruled} "
            f"of {len(measured)})",
        ))  # fmt: skip
    per_marker: dict[int, list[float]] = {}
    for r in estimate.residuals:
        if r.kind == "observation":
            for marker_id in r.marker_ids:
                per_marker.setdefault(marker_id, []).append(r.whitened_error)
    medians = {i: float(np.median(e)) for i, e in per_marker.items()}
    # A marker stands out from the rest, not just a map whose every residual is large (that is
    # the whole solution's reason, above): its own median beyond the line and half again the
    # markers' typical one.
    typical = float(np.median(list(medians.values()))) if medians else 0.0
    line = max(MARKER_RESIDUAL_SUSPECT, MARKER_STANDS_OUT * typical)
    bad = {i: e for i, e in medians.items() if e > line}
    if bad:
        worst_id = max(bad, key=bad.__getitem__)
        reasons.append(_suspect(
            "residuals", bad[worst_id],
            f"the observations of {_markers(bad)} disagree with the map (median whitened error "
            f"{bad[worst_id]:.1f} for marker {worst_id}; 1 is honest)",
        ))  # fmt: skip
    if len(estimate.nis):
        ratio = float(np.mean(estimate.nis)) / 3.0  # NIS of a 3-D innovation averages 3
        if ratio > RESIDUAL_RATIO_SUSPECT:
            reasons.append(_suspect(
                "residuals", ratio,
                f"its innovations are {ratio:.1f} times the size its noise model allows (mean "
                f"NIS {3 * ratio:.1f} for 3): the filter's belief and the data disagree",
            ))  # fmt: skip
    return reasons


def _ellipse_reasons(estimate: Estimate) -> list[Reason]:
    extent = map_extent_m(estimate)
    if extent <= 0:
        return []
    wide = {
        i: 2 * float(ellipse_semi_axes_m(m.covariance, ELLIPSE_SIGMAS)[0])
        for i, m in estimate.markers.items()
        if m.covariance is not None and i != estimate.home_id
    }
    wide = {i: length for i, length in wide.items() if length > extent}
    if not wide:
        return []
    widest = max(wide, key=wide.__getitem__)
    return [_suspect(
        "ellipses", wide[widest],
        f"the 95 % ellipses of {_markers(wide)} are longer than the whole map "
        f"({wide[widest]:.1f} m for marker {widest}, the map {extent:.1f} m across): the data "
        "do not locate them",
    )]  # fmt: skip


def _placement_reasons(estimate: Estimate, seen: set[int]) -> list[Reason]:
    reasons = []
    if not estimate.converged:
        reasons.append(_suspect(
            "converged", 0.0, "its optimiser stopped before converging: the map is its last step"
        ))  # fmt: skip
    unplaced = sorted(seen - set(estimate.markers))
    if unplaced:
        placed = len(seen) - len(unplaced)
        text = (
            f"it placed {placed} of the {len(seen)} markers seen; {_markers(unplaced)} "
            f"{'is' if len(unplaced) == 1 else 'are'} missing"
        )
        failed = placed <= 1 < len(seen)
        reasons.append((_failed if failed else _suspect)("unplaced", float(len(unplaced)), text))
    finite = all(
        np.all(np.isfinite([m.T_map_marker.x(), m.T_map_marker.y(), m.T_map_marker.theta()]))
        for m in estimate.markers.values()
    )
    if not finite:
        reasons.append(_failed("converged", math.nan, "it holds non-finite marker poses"))
    return reasons


def _facing_reasons(
    estimate: Estimate, observations: list[Observation], camera_x_m: float
) -> list[Reason]:
    """Markers the robot saw from behind their face: their yaw is turned round. Most of the
    map's markers so: the map's yaws are not to be used (failed)."""
    sightings = facing_away(estimate, observations, camera_x_m)
    away = {
        i: behind / n
        for i, (behind, n) in sightings.items()
        if n >= BEHIND_MIN_SIGHTINGS and behind / n > BEHIND_SHARE
    }
    if not away:
        return []
    judged = sum(n >= BEHIND_MIN_SIGHTINGS for _, n in sightings.values())
    share = min(away.values())
    one = len(away) == 1
    text = (
        f"{_markers(away)} {'faces' if one else 'face'} away from where the robot saw "
        f"{'it' if one else 'them'} (seen from behind {'its' if one else 'their'} face in at "
        f"least {100 * share:.0f} % of the sightings): {'its yaw is' if one else 'their yaws are'} "
        "turned round"
    )
    grave = _failed if 2 * len(away) > judged else _suspect
    return [grave("facing", float(len(away)), text)]


# --- methods against each other ------------------------------------------------------------


def _disagreements(estimates: list[Estimate]) -> dict[Method, list[Reason]]:
    """Each method with covariances against the others; a method that disagrees with all the
    others is suspect (with one other, both are)."""
    judged = [e for e in estimates if any(m.covariance is not None for m in e.markers.values())]
    reasons: dict[Method, list[Reason]] = {e.method: [] for e in estimates}
    if len(judged) < 2:
        return reasons
    apart: dict[tuple[Method, Method], tuple[int, float, float]] = {}
    for a in judged:
        for b in judged:
            if a is b:
                continue
            worst_pair = _worst_disagreement(marker_disagreement(a, b))
            if worst_pair is not None:
                apart[(a.method, b.method)] = worst_pair
    for a in judged:
        others = [b.method for b in judged if b is not a]
        against = [m for m in others if (a.method, m) in apart]
        if against and len(against) == len(others):
            marker_id, distance, d2 = max(
                (apart[(a.method, m)] for m in against), key=lambda t: t[1]
            )
            names = ", ".join(m.value for m in against)
            reasons[a.method].append(_suspect(
                "disagreement", distance,
                f"it puts marker {marker_id} {distance:.2f} m from where {names} "
                f"{'puts' if len(against) == 1 else 'put'} it ({math.sqrt(d2):.0f} sigma apart)",
            ))  # fmt: skip
    return reasons


def _worst_disagreement(
    pairs: dict[int, tuple[float, float | None]],
) -> tuple[int, float, float] | None:
    beyond = [
        (i, distance, d2)
        for i, (distance, d2) in pairs.items()
        if d2 is not None and d2 > DISAGREEMENT_D2 and distance > DISAGREEMENT_FLOOR_M
    ]
    return max(beyond, key=lambda t: t[1], default=None)


def _closed_form_reasons(closed: Estimate, reference: Estimate | None) -> list[Reason]:
    """The closed form has no covariance: it is compared with the best-judged method by the
    distance it drifts, against a share of the map's size."""
    if reference is None:
        return []
    pairs = marker_disagreement(closed, reference)
    if not pairs:
        return []
    marker_id = max(pairs, key=lambda i: pairs[i][0])
    distance = pairs[marker_id][0]
    allowed = max(CLOSED_FORM_FLOOR_M, CLOSED_FORM_SHARE * map_extent_m(reference))
    if distance <= allowed:
        return []
    return [_suspect(
        "disagreement", distance,
        f"it puts marker {marker_id} {distance:.2f} m from where {reference.method.value} puts it "
        f"(its chain of single edges drifts; {allowed:.2f} m is what we call agreement here)",
    )]  # fmt: skip


# --- the run's own evidence ----------------------------------------------------------------


def _input_reasons(
    extraction: Extraction,
    camera_delay_ns: int,
    delay_searched: bool,
    searched_scales: dict[str, float],
) -> list[Reason]:
    frames, samples = (
        extraction.frames,
        len(extraction.odometry) + extraction.dropped_odometry_samples,
    )
    # Damage only: frames skipped by design (a camera without calibration, frames used without
    # depth) are not evidence against the map.
    shares = [
        ("dropped", extraction.undecodable_frames, frames, DROPPED_SHARE_SUSPECT,
         "of the colour frames do not decode", ""),
        ("dropped", extraction.frames_dropped_by_stamp, frames, DROPPED_SHARE_SUSPECT,
         "of the colour frames have stamps their neighbours contradict", ""),
        ("dropped", extraction.dropped_odometry_samples, samples, DROPPED_ODOMETRY_SUSPECT,
         "of the odometry samples were dropped as corrupt or out of time",
         ": the path between the rest is interpolated"),
        ("depth", extraction.depth_misses, extraction.depth_tries, DEPTH_MISS_SHARE_SUSPECT,
         "of the markers seen with depth had no usable depth on them",
         " (none valid, or too far from the marker's distance by its size): their ranges rest "
         "on the marker size alone"),
    ]  # fmt: skip
    reasons = [
        _suspect(check, 100 * part / whole,
                 f"{100 * part / whole:.0f} % {what} ({part} of {whole}){consequence}")
        for check, part, whole, line, what, consequence in shares
        if whole and part / whole > line
    ]  # fmt: skip
    beyond = markers_beyond(extraction.ids_beyond_dictionary)
    if beyond:
        reasons.append(_suspect(
            "dictionary", float(len(beyond)),
            f"the images show {len(beyond)} marker(s) of a larger dictionary of the same family "
            f"(ids {', '.join(map(str, beyond[:8]))}{' ...' if len(beyond) > 8 else ''}), which "
            "the map leaves out: the dictionary given may be too small (see its note)",
        ))  # fmt: skip
    if delay_searched:
        delay_s = camera_delay_ns * 1e-9
        if (
            min(DELAYS_S) - 1e-6 < delay_s < min(DELAYS_S) + 1e-6
            or abs(delay_s - max(DELAYS_S)) < 1e-6
        ):
            reasons.append(_suspect(
                "delay", 1e3 * delay_s,
                f"the camera's delay was chosen at the end of its search ({1e3 * delay_s:+.0f} "
                "ms): the true delay may lie beyond it (--camera-delay sets it)",
            ))  # fmt: skip
    for name, value in searched_scales.items():  # the odometry's scale, its turn scale
        if value in (min(SCALES), max(SCALES)):
            check, what, flag = _SCALES[name]
            reasons.append(_suspect(
                check, value,
                f"the odometry's {name} was chosen at the end of its search ({value:.2f}): its "
                f"{what} may be off by more ({flag} sets it)",
            ))  # fmt: skip
    return reasons


_SCALES = {  # the odometry's searched factors: the check's name, what it scales, its flag
    "scale": ("odometry", "distances", "--odometry-scale"),
    "turn scale": ("odometry_turns", "turns", "--odometry-turn-scale"),
}


def judge_run(
    estimates: list[Estimate],
    extraction: Extraction,
    *,
    camera_delay_ns: int = 0,
    odometry_scale: float = 1.0,
    odometry_turn_scale: float = 1.0,
    delay_searched: bool = True,
    scale_searched: bool = True,
    turn_searched: bool = True,
    misread_markers: frozenset[int] = frozenset(),
) -> tuple[Judgement, dict[Method, Judgement]]:
    """The verdict on each method's estimate and on the run.

    Each method's reasons are its own and the run's (bad input harms every method); the run's
    verdict is the gravest of its methods', with each reason naming its method. A delay, scale
    or turn scale at the end of its search is suspect only where it was searched
    (``delay_searched``, ``scale_searched``, ``turn_searched``); set by hand, the bound is no
    evidence. ``misread_markers``, whose
    every sighting was another marker's (a note says so), are not missing from the map.
    """
    seen = {o.marker_id for o in extraction.observations} - misread_markers
    camera_x_m = extraction.mount.T_base_camera.x()
    searched = {"scale": odometry_scale} if scale_searched else {}
    if turn_searched:
        searched["turn scale"] = odometry_turn_scale
    inputs = _input_reasons(extraction, camera_delay_ns, delay_searched, searched)
    disagreements = _disagreements(estimates)
    own: dict[Method, list[Reason]] = {}
    for estimate in estimates:
        own[estimate.method] = (
            _residual_reasons(estimate)
            + _ellipse_reasons(estimate)
            + _placement_reasons(estimate, seen)
            + _facing_reasons(estimate, extraction.observations, camera_x_m)
            + disagreements[estimate.method]
        )
    # The closed form is checked against the soundest other method; where none is sound, the
    # best of them still shows how far it drifts, and nothing vouches for it.
    others = [e for e in estimates if e.method is not Method.CLOSED_FORM]
    sound = [e for e in others if not own[e.method]]
    reference = min(sound or others, key=lambda e: _preference(e.method), default=None)
    for estimate in estimates:
        if estimate.method is Method.CLOSED_FORM:
            own[estimate.method] += _closed_form_reasons(estimate, reference)
            if others and not sound:
                own[estimate.method].append(_suspect(
                    "disagreement", float(len(others)),
                    "no other method vouches for it: "
                    + ", ".join(f"{e.method.value} is {Judgement.of(own[e.method]).verdict.value}"
                                for e in others),
                ))  # fmt: skip
    per_method = {m: Judgement.of(inputs + reasons) for m, reasons in own.items()}
    run_reasons = list(inputs) + [
        Reason(r.verdict, r.check, f"{m.value}: {r.text}", r.figure)
        for m, reasons in own.items()
        for r in reasons
    ]
    return Judgement.of(run_reasons), per_method


def _preference(method: Method) -> int:
    """Which method to measure the closed form against when several are judged sound."""
    order = [Method.SLAM, Method.ISAM2, Method.EKF, Method.MARKER_GRAPH]
    return order.index(method) if method in order else len(order)


def _markers(ids: Any) -> str:
    ids = sorted(ids)
    return f"marker{'s' if len(ids) > 1 else ''} {some_of(ids)}"


MAX_REPROJECTION_RMS_PX = 3.0
"""A 3-D map whose corners fit it worse than this (RMS, after its outliers are dropped) is
suspect: a wrong tag size, intrinsics or mount, or a solve that did not find the map."""
MAX_DROPPED_VIEWS = 0.2
"""... or that had to leave out more than this share of its views."""
MAX_UNPLACED_TAGS = 0.1
"""... or could not place more than this share of the tags seen."""


def judge_tag_map(tag_map: TagMap3d, tags_seen: int) -> Judgement:
    """How far a 3-D tag map can be trusted, from what it alone shows."""
    reasons = []
    if not tag_map.converged:
        reasons.append(_failed("converged", 0.0, "the optimiser did not converge"))
    rms = tag_map.reprojection_rms_px
    if rms > MAX_REPROJECTION_RMS_PX:
        reasons.append(
            _suspect(
                "residuals",
                rms,
                f"the tags' corners fit the map to {rms:.1f} px "
                f"RMS (more than {MAX_REPROJECTION_RMS_PX:g} px): a wrong tag size, "
                "intrinsics or mount, or a map the solve did not find",
            )
        )
    views = tag_map.views_used + tag_map.views_dropped
    share = tag_map.views_dropped / views if views else 0.0
    if share > MAX_DROPPED_VIEWS:
        reasons.append(
            _suspect(
                "dropped",
                100 * share,
                f"{100 * share:.0f} % of the tag views disagreed with the map and were left out",
            )
        )
    unplaced = 1.0 - len(tag_map.tags) / tags_seen if tags_seen else 0.0
    if unplaced > MAX_UNPLACED_TAGS:
        reasons.append(
            _suspect(
                "unplaced",
                100 * unplaced,
                f"{100 * unplaced:.0f} % of the tags seen could not be placed",
            )
        )
    doubted = [note for note in tag_map.notes if note.kind == "map.up_doubted"]
    if doubted:
        reasons.append(
            _suspect(
                "up",
                float(doubted[0].figure or 0.0),
                f"up is in doubt: the odometry's vertical is {doubted[0].figure:.0f} deg from the "
                "cameras' image up, through an odometry body not placed on the rig: the wall tags "
                "and the 2-D map rest on it",
            )
        )
    scale = next((n.figure for n in tag_map.notes if n.kind == ODOMETRY_SCALE_KIND), None)
    if scale is not None and abs(scale - 1.0) > ODOMETRY_SCALE_OFF:
        reasons.append(
            _suspect(
                "odometry_scale",
                100 * (scale - 1.0),
                f"the odometry moved the rig {scale:.2f} times as far as the map does: "
                "the tags' size is likely wrong (--marker-size, or a tagslam.yaml's), or the "
                "odometry is not metric",
            )
        )
    if any(note.kind == "camera.unplaced" for note in tag_map.notes):
        reasons.append(
            _suspect(
                "unplaced", 0.0, "a camera's mount could not be estimated: its views were left out"
            )
        )
    return Judgement.of(reasons)
