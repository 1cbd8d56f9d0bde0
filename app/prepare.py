"""One log's extraction made ready for the estimators: checked, its odometry's noise model
chosen, the camera's delay and the odometry's scale applied (each chosen by SLAM's residuals
unless set), and misread marker ids left out (:mod:`~markergraph.estimator.misreads`)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import gtsam

from markergraph.common import MarkerGraphError, Note
from markergraph.common.numbers import counted, shown
from markergraph.estimator import (
    ODOMETRY_NOISE,
    READOUT_MAX_S,
    Frames,
    Misread,
    Observation,
    OdometryNoise,
    Robust,
    SlamInputs,
    Trajectory,
    build_frames,
    camera_delay_by_residuals,
    describe_misreads,
    misread_observations,
    odometry_scale_by_residuals,
    odometry_turn_scale_by_residuals,
    retimed,
    unleaned,
    widened_for_motion,
)
from markergraph.frontend import Extraction
from markergraph.frontend.depth_scale import scale_depth_ranges
from markergraph.frontend.posed import drop_notes
from markergraph.obs_cache import search_key
from markergraph.sections import CameraSettings, Shutter
from markergraph.settings import MapConfig

__all__ = ["SEARCH_ROBUST", "Considered", "Prepared", "prepare"]

SEARCH_ROBUST = Robust.HUBER
"""The kernel the delay and scale searches solve with, whatever ``--robust`` asks of the map."""

_CACHED = ", on an earlier run: from the cache"  # said of a search's result taken from the cache


@dataclass(frozen=True)
class Considered:
    """The log made ready with one setting SLAM's residuals chose moved one standard
    deviation further (:mod:`~markergraph.shares` grows the covariances by what it moves).

    Attributes:
        setting: ``odometry.scale``, ``odometry.turn_scale``, ``camera.delay`` or
            ``depth.scale`` (measured against the markers' size, not by the residuals).
        sigma: its standard deviation (a factor; [ns] for the delay).
        frames: the estimators' input with the setting one sigma further.
    """

    setting: str
    sigma: float
    frames: Frames


@dataclass(frozen=True)
class Prepared:
    """One log made ready for the estimators (:func:`prepare`).

    Attributes:
        observations: at their capture times, sigmas widened for blur if asked.
        frames: the estimators' input, on the scaled odometry.
        camera_delay_ns: the camera's delay used [ns].
        odometry_source: the odometry noise model used (``wheel``, ``vio``, ``t265``).
        odometry_model_reason: what chose that model.
        odometry_scale: what the odometry's distances were multiplied by.
        notes: what this stage noticed and chose.
        misreads: the observations left out as misread ids.
        misread_at: their places in the extraction's observations.
        odometry_scale_sigma: the scale's standard deviation where SLAM's residuals chose it.
        camera_delay_sigma_ns: the delay's standard deviation where they chose it [ns].
        considered: the log made ready again with each setting they chose one sigma further,
            for its share of the covariances.
        odometry_turn_scale: what the odometry's turns were multiplied by.
        odometry_turn_scale_sigma: its standard deviation where SLAM's residuals chose it.
    """

    observations: list[Observation]
    frames: Frames
    camera_delay_ns: int
    odometry_source: str
    odometry_model_reason: str
    odometry_scale: float
    notes: tuple[Note, ...]
    misreads: tuple[Misread, ...] = ()
    misread_at: frozenset[int] = frozenset()
    odometry_scale_sigma: float | None = None
    camera_delay_sigma_ns: float | None = None
    considered: tuple[Considered, ...] = ()
    odometry_turn_scale: float = 1.0
    odometry_turn_scale_sigma: float | None = None


def prepare(
    log: Path,
    extraction: Extraction,
    config: MapConfig,
    stage: Callable[[str], None] = lambda name: None,
    home_id: int | None = None,
    searches: dict[str, Any] | None = None,
    misreads_of: Prepared | None = None,
) -> Prepared:
    """One log's extraction made ready for the estimators: checked, odometry jumps released,
    its noise model chosen, the camera's delay and the odometry's scale applied (each chosen by
    SLAM's residuals unless set), and misread marker ids left out.

    Args:
        searches: the delay and scale searches already run on this extraction, by the settings
            they depend on (:func:`~markergraph.obs_cache.search_key`); searches run here are
            added to it.
        misreads_of: an earlier preparation of the same extraction whose misread observations
            are left out here too, without searching again: two preparations that differ in a
            sensor setting then differ in it and what the searches chose under it, not in the
            observations used. Made to be compared, such a one has nothing ``considered``.

    Raises:
        MarkerGraphError: no marker observations, or no odometry.
    """
    _check_usable(log, extraction, config)
    notes = _content_notes(extraction)
    breaks = [t for t, _ in extraction.odometry.jumps()]
    evidence = extraction.odometry_evidence
    source, why = config.odometry_source(extraction.topics.odom, evidence)
    _, noise = config.odometry_noise(extraction.topics.odom, evidence)
    notes.append(_noise_note(source, noise, why, len(extraction.odometry), extraction.topics.odom))
    searches = {} if searches is None else searches
    # The searches weigh the residuals by the source's preset, not the noise asked for: the
    # delay and the scale are the sensors' own, so a changed estimator setting reuses them.
    basis = (source, ODOMETRY_NOISE[source], SEARCH_ROBUST, home_id, config.camera)
    timed = _timed(extraction, config, ODOMETRY_NOISE[source], breaks, home_id, notes, searches,
                   search_key("delay and sigma", *basis), stage)  # fmt: skip
    observations, delay_ns = timed.observations, timed.delay_ns
    search = SlamInputs(observations, extraction.odometry, home_id, extraction.mount.T_base_camera,
                        ODOMETRY_NOISE[source], breaks, SEARCH_ROBUST)  # fmt: skip
    scale, scale_sigma, turn, turn_sigma = _odometry_scales(
        search, config, extraction.topics.odom, (*basis, delay_ns), timed.near, stage, notes,
        searches,
    )  # fmt: skip

    def framed(observations: list[Observation], scale: float = scale,
               home_id: int | None = home_id, turn: float = turn) -> Frames:  # fmt: skip
        odometry = extraction.odometry.scaled(scale).turned(turn)
        return build_frames(
            observations, odometry, home_id, odometry_noise=noise, odometry_breaks=breaks
        )

    if misreads_of is not None:
        misreads, misread_at = misreads_of.misreads, misreads_of.misread_at
    else:
        key = search_key("misreads", *basis, delay_ns, scale, turn)
        if key not in searches:
            stage("looking for misread marker ids")
            searches[key] = _misread_search(framed(observations), extraction)
        misreads, misread_at = _misreads_in(observations, searches[key])
    if misreads:
        notes.append(Note("observations.misread_ids", describe_misreads(misreads),
                          figure=len(misreads)))  # fmt: skip

    def kept(observations: list[Observation]) -> list[Observation]:
        return [o for i, o in enumerate(observations) if i not in misread_at]

    frames = framed(kept(observations))
    considered = () if misreads_of is not None else _considered(
        timed, (scale, scale_sigma, turn, turn_sigma), kept,
        lambda o, s, t: framed(o, s, frames.home_id, t), extraction.depth_scale_sigma,
    )  # fmt: skip
    return Prepared(
        kept(observations), frames, delay_ns, source, why, scale, tuple(notes), misreads,
        misread_at, scale_sigma, timed.sigma_ns, considered, turn, turn_sigma,
    )  # fmt: skip


def _considered(
    timed: _Timed,
    scales: tuple[float, float | None, float, float | None],
    kept: Callable[[list[Observation]], list[Observation]],
    framed: Callable[[list[Observation], float, float], Frames],
    depth_sigma: float | None,
) -> tuple[Considered, ...]:
    """The log made ready again with each setting SLAM's residuals chose one sigma further:
    the odometry's scale and turn scale (``scales``: each with its sigma; ``framed`` builds
    frames at a scale and a turn scale, on the map's home marker: one map frame for every
    share), the camera's delay (``timed`` retimes at a delay); and the depth's scale the
    markers measured (``depth_sigma``); ``kept`` leaves the misread observations out."""
    scale, scale_sigma, turn, turn_sigma = scales
    observations = kept(timed.observations)
    considered = []
    if scale_sigma is not None:
        longer = framed(observations, scale + scale_sigma, turn)
        considered.append(Considered("odometry.scale", scale_sigma, longer))
    if turn_sigma is not None:
        wider = framed(observations, scale, turn + turn_sigma)
        considered.append(Considered("odometry.turn_scale", turn_sigma, wider))
    if timed.sigma_ns is not None:
        later = timed.at(round(timed.delay_ns + timed.sigma_ns))
        considered.append(
            Considered("camera.delay", timed.sigma_ns, framed(kept(later), scale, turn))
        )
    if depth_sigma is not None:
        # Ranges from depth one sigma longer; the odometry's scale, chosen to agree with them,
        # follows them (on an office log: depth 0.200 % longer, the scale chosen 0.198 % more).
        ranged = scale_depth_ranges(observations, 1.0 + depth_sigma)
        further = framed(ranged, scale * (1.0 + depth_sigma), turn)
        considered.append(Considered("depth.scale", depth_sigma, further))
    return tuple(considered)


def _misread_search(frames: Frames, extraction: Extraction) -> list[tuple[Any, ...]]:
    """The observations SLAM's residuals find misread, as the cache keeps them."""
    found = misread_observations(frames, extraction.mount.T_base_camera, SEARCH_ROBUST)
    return [(m.t_ns, m.read_as, m.stands_on, m.kind) for m in found]


def _misreads_in(
    observations: list[Observation], found: list[tuple[Any, ...]]
) -> tuple[tuple[Misread, ...], frozenset[int]]:
    """The misreads a search found (as the cache keeps them), and their places in
    ``observations``."""
    misreads = tuple(Misread(*m) for m in found)
    left_out = {(m.t_ns, m.read_as) for m in misreads}
    at = frozenset(i for i, o in enumerate(observations) if (o.t_ns, o.marker_id) in left_out)
    return misreads, at


def _nothing_observed(extraction: Extraction, config: MapConfig) -> str:
    """Why a log gave no observation: no marker found, or every one found set aside (and
    why: the allowed ids, floor and ceiling tags, no pose)."""
    found = sum(c.detections for c in extraction.marker_detections.values())
    frames = counted(extraction.frames, "frame")
    if found:
        why = "; ".join(n.text for n in drop_notes(extraction.marker_detections))
        return (
            f"{counted(found, 'detection')} of markers of {config.dictionary} in {frames}, "
            f"none usable in a 2-D map: {why}"
            + (" (--dimensions 3 maps every tag, whatever its normal)" if "floor" in why else "")
        )
    left_out = sorted(extraction.ids_left_out)
    return f"no markers of {config.dictionary} were found in {frames}" + (
        f" (markers {', '.join(map(str, left_out))} were seen but are not in --ids)"
        if left_out
        else ""
    )


def _check_usable(log: Path, extraction: Extraction, config: MapConfig) -> None:
    """Raise, naming the log, when there is nothing to map: no markers, or no odometry."""
    if not extraction.observations:
        raise MarkerGraphError(f"{log}: {_nothing_observed(extraction, config)}")
    if not len(extraction.odometry):
        topic = extraction.topics.odom
        dropped = [
            n.text
            for n in extraction.notes
            if n.kind.startswith("odometry.dropped") and n.topic == topic
        ]
        raise MarkerGraphError(
            f"{log}: no usable odometry on {topic} ({'; '.join(dropped) or 'no samples'})"
            if topic
            else f"{log}: no odometry (no nav_msgs/Odometry topic and no odom -> base "
            "transforms on /tf)"
        )


def _content_notes(extraction: Extraction) -> list[Note]:
    """What the observations and odometry themselves call for a word on: a lone marker, and
    jumps of the odometry (each left to the observations)."""
    notes = []
    seen = {o.marker_id for o in extraction.observations}
    if len(seen) == 1:
        only = next(iter(seen))
        notes.append(Note(
            "map.one_marker",
            f"only marker {only} was seen: the map is that marker alone, with the robot's "
            "path in its frame; there is nothing to link",
            figure=only,
        ))  # fmt: skip
    topic = extraction.topics.odom
    for t_ns, size_m in extraction.odometry.jumps():
        after_s = (t_ns - int(extraction.odometry.t_ns[0])) * 1e-9
        notes.append(Note(
            "odometry.jump",
            f"odometry on {topic} jumped {size_m:.2f} m at {after_s:.2f} s into "
            "the log (a visual-inertial reset or relocalisation): that step is left to the "
            "observations",
            topic=topic, figure=size_m,
        ))  # fmt: skip
    return notes


def _noise_note(
    source: str, noise: OdometryNoise, why: str, samples: int, topic: str | None
) -> Note:
    """The odometry's noise model, the samples it is applied to, and what chose it."""
    where = f" on {topic}" if topic else ""
    return Note(
        "odometry.noise_model",
        f"odometry noise: the {source} model ({100 * noise.per_m:.1f} cm and "
        f"{math.degrees(noise.yaw_per_m):.2f} deg per sqrt(m), "
        f"{math.degrees(noise.yaw_per_rad):.2f} deg per sqrt(rad) turned) for all "
        f"{samples:,} odometry samples{where}; {why}",
        figure=noise.per_m,
    )


@dataclass(frozen=True)
class _Timed:
    """The observations at their capture times (:func:`_timed`).

    Attributes:
        observations: at the camera's delay used.
        delay_ns: that delay [ns].
        sigma_ns: its standard deviation where SLAM's residuals chose it [ns].
        near: the delay search's solution where it ran, for the scale's search to start from.
        at: the observations at another delay, made as these were (notes left unsaid).
    """

    observations: list[Observation]
    delay_ns: int
    sigma_ns: float | None
    near: gtsam.Values | None
    at: Callable[[int], list[Observation]]


def _timed(
    extraction: Extraction,
    config: MapConfig,
    noise: OdometryNoise,
    breaks: list[int],
    home_id: int | None,
    notes: list[Note],
    searches: dict[str, Any],
    key: str,
    stage: Callable[[str], None],
) -> _Timed:
    """The observations at their capture times (the camera's delay, chosen by the residuals
    unless set, and a rolling shutter's row delays), sigmas widened for blur and, if asked, for
    the shutter instead."""
    camera = config.camera
    if camera.delay_ns is None and key not in searches:
        stage("choosing the camera's delay by SLAM's residuals")
    observations = extraction.observations
    readout_ns = camera.readout_ns or 0
    height = extraction.camera.height if extraction.camera is not None else 0
    window_s = camera.exposure_s
    if camera.shutter is Shutter.WIDEN:
        window_s += readout_ns * 1e-9
        readout_ns = 0
    if window_s > 0:
        observations = widened_for_motion(observations, extraction.odometry, window_s)

    def at(delay_ns: int, notes: list[Note] | None = None) -> list[Observation]:
        moved = retimed(observations, delay_ns, readout_ns, height)
        return _unleaned(moved, extraction.odometry, camera, [] if notes is None else notes)

    if camera.delay_ns is not None:
        return _Timed(at(camera.delay_ns, notes), camera.delay_ns, None, None, at)
    mount = extraction.mount.T_base_camera
    inputs = SlamInputs(
        observations, extraction.odometry, home_id, mount, noise, breaks, SEARCH_ROBUST
    )
    cached = _CACHED if key in searches else ""
    near = None
    if not cached:
        found = camera_delay_by_residuals(inputs, readout_ns=readout_ns, image_height=height)
        searches[key], near = (found.delay_ns, found.sigma_ns), found.solution
    chosen_ns, sigma_ns = searches[key]
    topic = extraction.topics.odom
    delay_ns = 0 if chosen_ns is None else chosen_ns
    if chosen_ns is None:
        notes.append(Note(
            "camera.delay_unresolved",
            f"camera stamps taken as they are against {topic}: SLAM's "
            f"residuals have no minimum between -50 and +100 ms{cached} (--camera-delay sets a "
            "delay)",
            topic=topic,
        ))  # fmt: skip
    else:
        notes.append(Note(
            "camera.delay_chosen",
            f"camera stamps {shown(delay_ns / 1e6, '+.1f')} ms against {topic} "
            f"(chosen by SLAM's residuals over -50..+100 ms{cached}; --camera-delay sets it)",
            topic=topic, figure=delay_ns * 1e-9,
        ))  # fmt: skip
    return _Timed(at(delay_ns, notes), delay_ns, sigma_ns, near, at)


def _unleaned(
    observations: list[Observation],
    odometry: Trajectory,
    camera: CameraSettings,
    notes: list[Note],
) -> list[Observation]:
    """Theta freed of the lean a rolling shutter gives markers in turns (:func:`unleaned`), the
    observations at their capture times: taken off with the readout given, widened by it under
    ``--shutter widen``, and widened to cover any readout up to :data:`READOUT_MAX_S` where none
    is given (said in a note); as they are for a global shutter (``--readout 0``)."""
    if camera.readout_ns == 0:
        return observations
    if camera.readout_ns is not None:
        known = camera.shutter is Shutter.MODEL
        return unleaned(observations, odometry, camera.readout_ns * 1e-9, known=known)
    handled = unleaned(observations, odometry, READOUT_MAX_S, known=False)
    pairs = zip(handled, observations, strict=True)
    widened = sum(after.sigma_theta > 1.25 * before.sigma_theta for after, before in pairs)
    if widened:
        notes.append(Note(
            "camera.readout_unknown",
            f"theta of {widened:,} of {len(observations):,} observations, made in turns, widened "
            f"by over a quarter for a rolling shutter's lean (readout not given: up to "
            f"{READOUT_MAX_S * 1e3:.0f} ms covered); --readout MS takes the lean off, --readout "
            "0 says the shutter is global",
            figure=widened,
        ))  # fmt: skip
    return handled


@dataclass(frozen=True)
class _ScaleSearch:
    """A factor on the odometry that SLAM's residuals choose: what it scales, how it is set."""

    setting: str  # its key, as Considered names it
    noun: str  # "the odometry's ..."
    what: str  # what it multiplies, as the note says it is read
    steps: str  # what the note says is scaled
    kept: str  # what the odometry is taken at where the residuals cannot tell
    flag: str
    search: Callable[[SlamInputs, gtsam.Values | None], Any]


# Looked up when called (tests put their own in the module's place).
_DISTANCES = _ScaleSearch("odometry.scale", "scale", "distances", "steps", "scale",
                          "--odometry-scale",
                          lambda i, near: odometry_scale_by_residuals(i, near))  # fmt: skip
_TURNS = _ScaleSearch("odometry.turn_scale", "turn scale", "turns", "turns", "turns",
                      "--odometry-turn-scale",
                      lambda i, near: odometry_turn_scale_by_residuals(i, near))  # fmt: skip


def _odometry_scales(
    inputs: SlamInputs,
    config: MapConfig,
    topic: str | None,
    basis: tuple[Any, ...],
    near: gtsam.Values | None,
    stage: Callable[[str], None],
    notes: list[Note],
    searches: dict[str, Any],
) -> tuple[float, float | None, float, float | None]:
    """The odometry's scale and turn scale (:func:`_odometry_scale`), each with its sigma where
    SLAM's residuals chose it; the turns searched on the scaled distances (``basis``: what the
    searches depend on, for their keys in ``searches``)."""
    scale, scale_sigma = _odometry_scale(
        _DISTANCES, config.odometry.scale, inputs, topic, stage, notes, searches, basis, near
    )
    # A track width off reads every turn long or short, a bias no random walk describes.
    scaled = replace(inputs, odometry=inputs.odometry.scaled(scale))
    turn, turn_sigma = _odometry_scale(
        _TURNS, config.odometry.turn_scale, scaled, topic, stage, notes, searches,
        (*basis, scale), near,
    )  # fmt: skip
    return scale, scale_sigma, turn, turn_sigma


def _odometry_scale(
    spec: _ScaleSearch,
    configured: float | None,
    inputs: SlamInputs,
    topic: str | None,
    stage: Callable[[str], None],
    notes: list[Note],
    searches: dict[str, Any],
    basis: tuple[Any, ...],
    near: gtsam.Values | None,
) -> tuple[float, float | None]:
    """The factor the odometry's distances (or turns) are multiplied by: as set, or chosen by
    SLAM's residuals on ``inputs`` (1 where they have no minimum; the search starts from
    ``near``, the delay search's solution on the same frames), and said in the notes; and its
    standard deviation where it was chosen (None otherwise). ``basis``: what the search
    depends on, for its key in ``searches``."""
    if configured is not None:
        return float(configured), None
    key = search_key(f"{spec.noun} and sigma", *basis)
    cached = _CACHED if key in searches else ""
    if not cached:
        stage(f"choosing the odometry's {spec.noun} by SLAM's residuals")
        found = spec.search(inputs, near)
        searches[key] = (found.chosen, found.sigma)
    chosen, sigma = searches[key]
    if chosen is None:
        notes.append(Note(
            f"{spec.setting}_unresolved",
            f"odometry on {topic} taken at its {spec.kept}: SLAM's residuals have no minimum "
            f"between 0.95 and 1.05{cached} ({spec.flag} sets one)",
            topic=topic,
        ))  # fmt: skip
        return 1.0, None
    off = 100 * (1 / chosen - 1)
    notes.append(Note(
        f"{spec.setting}_chosen",
        f"odometry on {topic} reads {spec.what} {abs(off):.2f} % {'long' if off > 0 else 'short'}"
        f": its {spec.steps} are scaled by {chosen:.4f} (chosen by SLAM's residuals over "
        f"0.95..1.05{cached}; {spec.flag} sets it)",
        topic=topic, figure=chosen,
    ))  # fmt: skip
    return chosen, sigma
