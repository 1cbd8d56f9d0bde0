"""The main job as a library call, one flow for every case: one log, several logs of one place
(optionally refining a saved map), or a log localised against a saved map.

Each case reads its logs the same way (the front end where the executor puts it, then each log
made ready by :func:`~markergraph.prepare.prepare`), estimates (one log: every method; several:
the methods that take several), scores against the ground truth a simulated log carries, and
judges what it found (:mod:`markergraph.verdicts`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import gtsam

from markergraph.common import EstimationError, MarkerGraphError, Note, SettingsError
from markergraph.estimator import (
    READOUT_MAX_S,
    Estimate,
    Form,
    Frames,
    Method,
    corrected_odometry,
    estimate_frames,
    marker_heights,
    odometry_in_map,
)
from markergraph.estimator.localization import localize, moved_markers
from markergraph.estimator.sessions import MapPrior, SessionsEstimate, solve_sessions
from markergraph.executors import extract_logs
from markergraph.formats.observations import extraction_of_file, is_observation_file
from markergraph.frontend import Extraction
from markergraph.localize_accuracy import accuracy_of, ate_note
from markergraph.markermap import MarkerMap
from markergraph.obs_cache import (
    CACHE_VERSION,
    CacheEntry,
    cache_enabled,
    entry_key,
    load_entry,
    store_entry,
)
from markergraph.prepare import Prepared, prepare
from markergraph.records import LocalizationRun, MapRun, MethodResult, Session, marker_map_of
from markergraph.scoring import path_error, score, truth_in_home_frame
from markergraph.sessions import (
    SESSION_METHODS,
    as_estimate,
    in_home_frame,
    priors_of,
    separate_maps,
)
from markergraph.settings import MapConfig
from markergraph.shares import (
    no_readout_share,
    no_sigma_share,
    with_readout_share,
    with_sigma_share,
)
from markergraph.verdicts import judge_run

__all__ = ["judge", "localize_log", "map_log", "map_logs"]

Stage = Callable[[str], None]
Progress = Callable[[int, int], None]


def _silent(name: str) -> None:
    del name


@dataclass(frozen=True)
class _Read:
    """One log read by the front end and made ready for the estimators."""

    log: Path
    extraction: Extraction
    prepared: Prepared
    at_longest_readout: Prepared | None = None
    """Made ready again as if the rolling shutter's readout were :data:`READOUT_MAX_S`, where
    it is not known: the maps solved from it give the readout's share of the covariances."""

    @property
    def notes(self) -> list[Note]:
        """The front end's notes, then the preparation's."""
        return [*self.extraction.notes, *self.prepared.notes]


@dataclass
class _Solved:
    """What estimating gave, before scoring: each method's result, which log's path the
    results carry, and with several logs where each went."""

    results: list[MethodResult]
    home_id: int
    first: int = 0
    sessions: list[Session] = field(default_factory=list)
    separate: list[tuple[list[Path], MarkerMap]] = field(default_factory=list)


def _read(
    logs: Sequence[Path],
    config: MapConfig,
    homes: Sequence[int | None],
    seconds: dict[str, float],
    *,
    executor: str = "local",
    address: str | None = None,
    progress: Progress | None = None,
    stage: Stage = _silent,
    cache: bool = True,
    readout_share: bool = False,
) -> list[_Read]:
    """Every log through the front end (timed as ``front end``), then made ready, each with
    its own home marker (None: the first seen). With ``cache`` (and the cache not turned off
    by ``MARKERGRAPH_NO_CACHE``), a log read before with the same front-end settings is taken
    from the cache (:mod:`~markergraph.obs_cache`), and so are the searches made ready with.
    With ``readout_share``, a log whose rolling shutter's readout is not given is also made
    ready as if it were :data:`READOUT_MAX_S` (``_Read.at_longest_readout``)."""
    start = time.perf_counter()  # the cache's look-up counts as the front end's time
    cache = cache and cache_enabled()
    keys = [_key(Path(log), config) if cache else "" for log in logs]
    entries = [load_entry(key) if key else None for key in keys]
    for i, log in enumerate(logs):  # detect's output: read here, no image in it
        if entries[i] is None and is_observation_file(Path(log)):
            entries[i] = CacheEntry(CACHE_VERSION, keys[i], extraction_of_file(Path(log)))
    missing = [i for i, entry in enumerate(entries) if entry is None]
    if missing:
        stage(f"reading {Path(logs[missing[0]]).name}" if len(missing) == 1 else
              f"reading {len(missing)} logs ({executor})")  # fmt: skip
        extractions = extract_logs(
            [logs[i] for i in missing], config.frontend, executor=executor, address=address,
            workers=config.workers, progress=progress,
        )  # fmt: skip
        for i, extraction in zip(missing, extractions, strict=True):
            entries[i] = CacheEntry(CACHE_VERSION, keys[i], extraction)
    seconds["front end"] = time.perf_counter() - start
    read = []
    longest = None
    if readout_share and config.camera.readout_ns is None:
        longest = MapConfig.from_values({**config.values, "camera.readout_ms": READOUT_MAX_S * 1e3})
    for log, entry, home in zip(logs, entries, homes, strict=True):
        assert entry is not None  # every miss was just read
        before = dict(entry.searches)
        extraction = entry.extraction
        if entry.hit:  # said first; how many processes read the log was the earlier run's
            kept = [note for note in extraction.notes if not note.kind.startswith("workers.")]
            extraction = replace(extraction, notes=[_cache_note(entry), *kept])
        prepared = prepare(log, extraction, config, stage, home, entry.searches)
        at_longest = None
        if longest is not None:  # on the same home marker: the same frame for both maps
            try:
                at_longest = prepare(log, extraction, longest, _for_longest_readout(stage),
                                     prepared.frames.home_id, entry.searches,
                                     misreads_of=prepared)  # fmt: skip
            except MarkerGraphError as error:  # the map stands; its covariances say less
                prepared = replace(prepared, notes=(*prepared.notes, no_readout_share(error)))
        if entry.key and (not entry.hit or entry.searches != before):
            store_entry(entry)
        read.append(_Read(Path(log), extraction, prepared, at_longest))
    return read


def _for_longest_readout(stage: Stage) -> Stage:
    """``stage`` with its names saying they are for the longest readout."""
    return lambda name: stage(f"{name}, with a {READOUT_MAX_S * 1e3:.0f} ms readout")


def _key(log: Path, config: MapConfig) -> str:
    """The log's cache key; empty (not cached) where the log cannot be looked at, which the
    front end then says in its own words."""
    try:
        return entry_key(log, config.frontend)
    except OSError:
        return ""


def _cache_note(entry: CacheEntry) -> Note:
    """Where a log's observations came from when it was not read."""
    return Note(
        "frontend.cache",
        f"observations from the cache ({entry.path}: the log and the front end's settings are "
        "unchanged; the camera delay and odometry scale found on them are reused, whatever the "
        "estimator's settings; --no-cache reads the log again)",
    )


def map_log(
    log: Path,
    config: MapConfig | None = None,
    *,
    progress: Progress | None = None,
    stage: Stage | None = None,
    cache: bool = True,
) -> MapRun:
    """Read a log, estimate the map with each method, and score it when ground truth is logged.

    Args:
        log: an MCAP file, a rosbag2 folder or a ROS 1 bag.
        config: the settings (default: every default).
        progress: called with (colour frames read, frames in all) while the log is read.
        stage: called with the name of each stage as it begins.
        cache: take the log's extraction (and the delay and scale searches) from the cache
            folder when it was read before with the same front-end settings, and keep it there
            (:mod:`~markergraph.obs_cache`).

    Raises:
        MarkerGraphError: the log cannot be read, has no marker observations, or no odometry
            (``LogError`` and ``SettingsError`` among them).
    """
    return map_logs([log], config, progress=progress, stage=stage, cache=cache)


def map_logs(
    logs: Sequence[Path],
    config: MapConfig | None = None,
    *,
    prior: MarkerMap | None = None,
    executor: str = "local",
    address: str | None = None,
    progress: Progress | None = None,
    stage: Stage | None = None,
    cache: bool = True,
) -> MapRun:
    """One map from one log, from several logs of one place, or from logs refining a saved map
    (``prior``).

    With several logs (or a prior) each log keeps its own odometry chain; markers seen in
    several logs tie them together; the home marker is the first log's unless the settings name
    one (with a prior, the saved map's frame stays). A log sharing no marker with the rest is
    mapped on its own (by SLAM), in ``MapRun.separate``. SLAM, iSAM2 and the marker graph take
    several logs; the closed form and the EKF follow one robot through one log and are left out
    (with ``all``, said so).

    Raises:
        SettingsError: several logs and only methods that take one log.
        MarkerGraphError: a log without markers or odometry (naming it), or one that cannot be
            read (``LogError``).
    """
    config = config or MapConfig.from_values()
    stage = stage or _silent
    several = len(logs) > 1 or prior is not None
    seconds: dict[str, float] = {}
    homes = [config.home_id if i == 0 and prior is None else None for i in range(len(logs))]
    methods = _several_log_methods(config) if several else list(config.methods)
    read = _read(logs, config, homes, seconds, executor=executor, address=address,
                 progress=progress, stage=stage, cache=cache, readout_share=True)  # fmt: skip
    if several:
        solved = _solve_several(read, config, methods, prior, stage, seconds)
    else:
        solved = _solve_one(read[0], config, stage, seconds)
    first = read[solved.first]
    truth, true_path = truth_in_home_frame(first.extraction, solved.home_id)
    # The odometry as the estimators used it (scaled), for the path between the frames.
    prepared = first.prepared
    odometry = first.extraction.odometry.scaled(prepared.odometry_scale).turned(
        prepared.odometry_turn_scale
    )
    for result in solved.results:
        result.path = corrected_odometry(result.estimate.trajectory, odometry)
        result.odometry_map = odometry_in_map(result.estimate.trajectory, odometry)
        score(result, truth, true_path)
    run = MapRun(
        first.log, config, first.extraction, prepared.frames, solved.results, truth, true_path,
        camera_delay_ns=prepared.camera_delay_ns, odometry_source=prepared.odometry_source,
        odometry_model_reason=prepared.odometry_model_reason,
        odometry_scale=prepared.odometry_scale,
        odometry_scale_sigma=prepared.odometry_scale_sigma,
        odometry_turn_scale=prepared.odometry_turn_scale,
        odometry_turn_scale_sigma=prepared.odometry_turn_scale_sigma,
        camera_delay_sigma_ns=prepared.camera_delay_sigma_ns, notes=first.notes, seconds=seconds,
        sessions=solved.sessions, separate=solved.separate,
        misread_markers=frozenset(
            {m.read_as for r in read for m in r.prepared.misreads}
            - {o.marker_id for r in read for f in r.prepared.frames.frames for o in f.observations}
        ),
    )  # fmt: skip
    return judge(run)


def _solve_one(read: _Read, config: MapConfig, stage: Stage, seconds: dict[str, float]) -> _Solved:
    """Every method asked, on one log."""
    frames, extraction = read.prepared.frames, read.extraction
    heights = marker_heights(read.prepared.observations)
    results = []
    for i, method in enumerate(config.methods, start=1):
        stage(f"estimating: {method.value} ({i} of {len(config.methods)})")
        start = time.perf_counter()

        def solve(frames: Frames, method: Method = method) -> Estimate:
            return estimate_frames(frames, method, extraction.mount.T_base_camera,
                                   form=Form.SIGNED, robust=config.noise.robust)  # fmt: skip

        try:
            estimate = solve(frames)
        except EstimationError as error:
            raise EstimationError(f"{read.log}: {method.value}: {error}") from None
        if read.at_longest_readout is not None:
            try:
                estimate = with_readout_share(estimate, solve(read.at_longest_readout.frames))
            except (EstimationError, ValueError) as error:
                estimate.notes.append(no_readout_share(error))
        for considered in read.prepared.considered:
            try:
                estimate = with_sigma_share(estimate, solve(considered.frames), considered)
            except (EstimationError, ValueError) as error:
                estimate.notes.append(no_sigma_share(considered, error))
        seconds[method.value] = time.perf_counter() - start
        marker_map = marker_map_of(estimate, str(read.log), config, heights, extraction)
        results.append(MethodResult(method, estimate, marker_map))
    return _Solved(results, frames.home_id)


def _with_sigma_shares(
    estimate: Estimate, read: Sequence[_Read], solve: Callable[[list[Frames]], Estimate]
) -> Estimate:
    """``estimate`` of several logs (``solve`` solves such frames) with the share of each
    setting SLAM's residuals chose on each log: the logs solved again with that one setting
    one sigma further (chosen apart, their errors are independent and their shares add)."""
    for i, r in enumerate(read):
        for considered in r.prepared.considered:
            try:
                moved = solve(
                    [considered.frames if j == i else o.prepared.frames for j, o in enumerate(read)]
                )
                estimate = with_sigma_share(estimate, moved, considered, r.log.name)
            except (EstimationError, ValueError) as error:
                estimate.notes.append(no_sigma_share(considered, error))
    return estimate


def _several_log_methods(config: MapConfig) -> list[Method]:
    """The methods asked that take several logs.

    Raises:
        SettingsError: none of them does.
    """
    methods = [m for m in config.methods if m in SESSION_METHODS]
    if not methods:
        raise SettingsError(
            f"several logs (or --prior) are mapped by {', '.join(m.value for m in SESSION_METHODS)}"
            ": the closed form and the EKF follow one robot through one log"
        )
    return methods


def _solve_several(
    read: list[_Read],
    config: MapConfig,
    methods: list[Method],
    prior: MarkerMap | None,
    stage: Stage,
    seconds: dict[str, float],
) -> _Solved:
    """Each several-log method over every log, with the saved map's markers as priors."""
    notes: list[Note] = []
    if len(methods) < len(config.methods):
        notes.append(Note("map.one_log_methods_left_out",
                          "the closed form and the EKF follow one log: left out of a several-log "
                          "map"))  # fmt: skip
    frames = [r.prepared.frames for r in read]
    mounts = [r.extraction.mount.T_base_camera for r in read]
    priors, searched = None, None
    if prior is not None:
        priors, prior_notes = priors_of(prior)
        priors, moved_notes, searched = _without_moved(priors, frames, mounts, config)
        notes += prior_notes + moved_notes
    # The first log was read with the settings' home marker (or, under a prior, the map's).
    home_id = prior.home_id if prior is not None else frames[0].home_id
    heights = marker_heights([o for r in read for o in r.prepared.observations])
    logs = [r.log for r in read]
    results, first_solved = [], None
    longest = [r.at_longest_readout for r in read]
    for method in methods:
        stage(f"estimating: {method.value} over every log")
        start = time.perf_counter()
        # SLAM's is the moved markers' search's last solve, on the same priors: not again.
        solved = searched if method is Method.SLAM and searched is not None else solve_sessions(
            frames, mounts, robust=config.noise.robust, priors=priors, home_id=config.home_id,
            method=method,
        )  # fmt: skip
        first_solved = first_solved or solved
        estimate = as_estimate(solved, method, home_id)
        if prior is not None:
            estimate = in_home_frame(estimate)

        def solve(frames: list[Frames], method: Method = method) -> Estimate:
            solved = solve_sessions(frames, mounts, robust=config.noise.robust, priors=priors,
                                    home_id=config.home_id, method=method)  # fmt: skip
            return as_estimate(solved, method, home_id)

        if all(p is not None for p in longest):
            try:
                moved = solve([p.frames for p in longest if p is not None])
                estimate = with_readout_share(estimate, moved)
            except (EstimationError, ValueError) as error:
                estimate.notes.append(no_readout_share(error))
        estimate = _with_sigma_shares(estimate, read, solve)
        seconds[method.value] = time.perf_counter() - start
        estimate.notes = notes + estimate.notes
        marker_map = marker_map_of(estimate, ", ".join(map(str, logs)), config, heights)
        results.append(MethodResult(method, estimate, marker_map))
    assert first_solved is not None  # methods is never empty
    trajectories = first_solved.trajectories
    return _Solved(
        results, home_id,
        first=next(i for i, t in enumerate(trajectories) if t is not None),
        sessions=[Session(r.log, r.extraction, r.prepared.frames, t)
                  for r, t in zip(read, trajectories, strict=True)],
        separate=separate_maps(first_solved.apart, logs, frames, mounts, config),
    )  # fmt: skip


def _without_moved(
    priors: dict[int, MapPrior], frames: list[Frames], mounts: list[gtsam.Pose2], config: MapConfig
) -> tuple[dict[int, MapPrior], list[Note], SessionsEstimate]:
    """The saved map's priors without those of markers the logs find moved (as ``localize``
    finds them, by SLAM), a note for each (held at its old place, a moved marker would be bent
    into the map and pull its neighbours with it), and SLAM's solution on the priors kept."""

    def solve(freed: Sequence[int]) -> SessionsEstimate:
        kept = {i: p for i, p in priors.items() if i not in freed}
        return solve_sessions(frames, mounts, robust=config.noise.robust, priors=kept,
                              home_id=config.home_id)  # fmt: skip

    seen = {i for f in frames for i in f.marker_ids()}
    found = moved_markers(solve, seen, priors)
    notes = []
    for i in found.moved:
        before, now = priors[i].T_map_marker, found.final.markers[i].T_map_marker
        moved_m = math.hypot(now.x() - before.x(), now.y() - before.y())
        notes.append(Note(
            "prior.marker_moved",
            f"marker {i} moved {100 * moved_m:.1f} cm since the saved map was made: placed where "
            "the log sees it now, its place in the saved map left out",
            figure=moved_m,
        ))  # fmt: skip
    return {i: p for i, p in priors.items() if i not in found.moved}, notes, found.final


def judge(run: MapRun) -> MapRun:
    """Give the run and each of its methods a verdict from the run's own evidence."""
    run.judgement, per_method = judge_run(
        [result.estimate for result in run.results], run.extraction,
        camera_delay_ns=run.camera_delay_ns, odometry_scale=run.odometry_scale,
        odometry_turn_scale=run.odometry_turn_scale,
        delay_searched=run.config.camera.delay_ns is None,
        scale_searched=run.config.odometry.scale is None,
        turn_searched=run.config.odometry.turn_scale is None, misread_markers=run.misread_markers,
    )  # fmt: skip
    for result in run.results:
        result.judgement = per_method[result.method]
    return run


def localize_log(
    log: Path,
    saved: MarkerMap,
    map_path: Path,
    config: MapConfig | None = None,
    *,
    progress: Progress | None = None,
    stage: Stage | None = None,
    cache: bool = True,
) -> LocalizationRun:
    """A log's robot trajectory in a saved map (:func:`~markergraph.estimator.sessions.localize`).

    Raises:
        MarkerGraphError: the log cannot be read, has no markers or odometry, or sees no
            marker of the map.
    """
    config = config or MapConfig.from_values()
    stage = stage or _silent
    (read,) = _read([log], config, [None], {}, progress=progress, stage=stage, cache=cache)
    priors, prior_notes = priors_of(saved)
    notes = [*read.notes, *prior_notes]
    stage("localising against the saved map")
    extraction = read.extraction
    localization = localize(
        read.prepared.frames, extraction.mount.T_base_camera, priors, robust=config.noise.robust
    )
    for m in localization.moved:
        notes.append(Note(
            "localization.marker_moved",
            f"marker {m.marker_id} moved {100 * m.displacement_m:.1f} cm since the map was made "
            f"(pulled {m.prior_whitened:.1f} sigmas): left out of the localisation",
            figure=m.displacement_m,
        ))  # fmt: skip
    if localization.new:
        notes.append(Note(
            "localization.new_markers",
            f"marker(s) {', '.join(map(str, sorted(localization.new)))} are not in the map: "
            "placed by this log (see localization.json)",
            figure=len(localization.new),
        ))  # fmt: skip
    _, truth = truth_in_home_frame(extraction, saved.home_id)
    # The ATE is the localised poses' (each has its covariance); the path adds the odometry
    # between them, as map's trajectory.tum does.
    error, _ = path_error(localization.trajectory, truth)
    ate_m = error.ate_rmse_m if error is not None else None
    ate_aligned_m = error.ate_aligned_rmse_m if error is not None else None
    far = ate_note(accuracy_of(localization, ate_m, ate_aligned_m))
    odometry = extraction.odometry.scaled(read.prepared.odometry_scale).turned(
        read.prepared.odometry_turn_scale
    )
    path = corrected_odometry(localization.trajectory, odometry)
    true_path = truth.at_stamps(path.t_ns) if truth is not None else None
    return LocalizationRun(
        Path(log), Path(map_path), saved, config, extraction, localization, ate_m, true_path,
        [*notes, *([far] if far is not None else [])], ate_aligned_m, path,
    )  # fmt: skip
