"""The 3-D tag map: rig poses, tag poses and unknown camera mounts in SE(3), in one GTSAM graph
of corner reprojection factors, odometry (or a weak motion prior where there is none) and the
surveyed tags' priors, solved in batch (Levenberg-Marquardt) or incrementally (iSAM2).

The gauge: surveyed tags fix the map frame where there are any, else the home tag (the first
tag seen unless named) sits at the identity; a camera whose mount is given holds the rig's frame,
else the first camera is taken as the rig's frame (said in a note). Views whose corners stay
far from the solution (a PnP flip, a misdetection) are dropped and the graph solved again.
"""

from __future__ import annotations

from collections import Counter
from enum import Enum
from typing import Any

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.common.errors import EstimationError
from markergraph.common.notes import Note
from markergraph.estimator.solution import MAX_ITERATIONS, first_line, lm_params, marginals_or_note
from markergraph.estimator.tag_frames import map_framing
from markergraph.estimator.tag_graph import TagGraph, camera_key, rig_key, tag_key, view_errors_px
from markergraph.estimator.tag_incremental import solve_incremental
from markergraph.estimator.tag_init import agree, place
from markergraph.estimator.tag_scale import odometry_scale_note
from markergraph.estimator.tag_solver import LmSettings, covariances, solve_lm
from markergraph.estimator.tags3d import Camera3d, Tag3d, TagMap3d, TagScene

__all__ = ["Solver", "map_tags"]


class Solver(Enum):
    """How the batch solve's Levenberg-Marquardt is driven (the same steps, the same answer)."""

    VECTORISED = "vectorised"
    """Every corner view linearised in one numpy call, GTSAM's step rules (:mod:`.tag_solver`):
    the default; the whole estimator 2-11x faster on TagSLAM's tests (docs/benchmarks.md)."""
    GTSAM = "gtsam"
    """GTSAM's optimiser over one Python factor a frame (a view in the first solve): the
    reference the vectorised solve is checked against."""


OUTLIER_PX = 3.0
"""A view whose corners stay farther than this (RMS) from the solution, and farther than
:data:`OUTLIER_SHARE` times the median view's, is dropped."""
OUTLIER_SHARE = 4.0
FIRST_TOLERANCE = 1e-3
"""The first (robust) solve's relative error tolerance ..."""
FIRST_ITERATIONS = 20
"""... and its most iterations."""
FINAL_TOLERANCE = 1e-7
MIN_NOISE_DOF = 30
"""Fewer degrees of freedom than this leave the assumed noise as it is."""
ROBUST_K = 3.0
"""The first solve's Cauchy kernel width on each view [sigmas]."""


def _home(scene: TagScene, mounted: set[int]) -> int | None:
    """The tag that fixes the frame: none with a survey, else the one named, else the first
    seen by a camera whose mount is known (a tag only an unplaced camera sees places nothing)."""
    if scene.known_tags:
        return None
    if scene.home_id is not None:
        if all(v.tag_id != scene.home_id for v in scene.views):
            raise EstimationError(f"home tag {scene.home_id} is never seen")
        return scene.home_id
    views = [v for v in scene.views if v.camera in mounted] or scene.views
    return min(views, key=lambda v: (v.frame, v.tag_id)).tag_id


def _mounts(scene: TagScene, notes: list[Note]) -> tuple[dict[int, gtsam.Pose3], set[int]]:
    """The mounts known before the search, and the cameras whose mount is estimated."""
    known = {i: c.T_rig_camera for i, c in enumerate(scene.cameras) if c.T_rig_camera is not None}
    estimated = {
        i for i, c in enumerate(scene.cameras) if c.T_rig_camera is None or c.sigmas is not None
    }
    if not any(c.T_rig_camera is not None and c.sigmas is None for c in scene.cameras):
        known[0] = known.get(0, gtsam.Pose3())
        estimated.discard(0)
        notes.append(
            Note(
                "rig.first_camera",
                f"no camera's mount is given: the rig's frame is {scene.cameras[0].name}'s",
                scene.cameras[0].topic,
            )
        )
    return known, estimated


def _optimise(
    problem: TagGraph, robust_k: float | None, tolerance: float, iterations: int, solver: Solver
) -> tuple[gtsam.Values, bool]:
    """Levenberg-Marquardt from where ``problem`` stands: the solution and whether it
    converged (within ``iterations``)."""
    params = lm_params()
    if solver is Solver.VECTORISED:
        settings = LmSettings(tolerance, params.getAbsoluteErrorTol(), iterations)
        try:
            values, taken = solve_lm(
                problem.corner_views(robust_k), problem.builtin_graph(), problem.values(), settings
            )
        except RuntimeError as error:
            raise EstimationError(
                f"the 3-D graph could not be solved: {first_line(error)}"
            ) from None
        return values, taken < iterations
    params.setRelativeErrorTol(tolerance)
    params.setMaxIterations(iterations)
    try:
        optimizer = gtsam.LevenbergMarquardtOptimizer(
            problem.graph(robust_k), problem.values(), params
        )
        result = optimizer.optimize()
    except RuntimeError as error:
        raise EstimationError(f"the 3-D graph could not be solved: {first_line(error)}") from None
    return result, optimizer.iterations() < iterations


def _first_solve(problem: TagGraph, solver: Solver) -> gtsam.Values:
    """A robust solve from the first guess, far enough to tell the outliers (not to the end:
    a Cauchy kernel's last steps are slow and change nothing the final solve does not)."""
    values, _ = _optimise(problem, ROBUST_K, FIRST_TOLERANCE, FIRST_ITERATIONS, solver)
    return values


def _final_solve(
    problem: TagGraph, notes: list[Note], solver: Solver
) -> tuple[gtsam.Values, bool, Any]:
    """The plain solve from where the problem stands, whether it converged, and its marginals
    (None when they cannot be had)."""
    values, converged = _optimise(problem, None, FINAL_TOLERANCE, MAX_ITERATIONS, solver)
    if solver is Solver.GTSAM:
        return values, converged, marginals_or_note(problem.graph(), values, notes)
    try:  # only the tags' and mounts' covariances are written: the rig poses are eliminated
        marginals = covariances(problem.corner_views(), problem.builtin_graph(), values)
    except np.linalg.LinAlgError:
        # Indeterminate or barely determined: GTSAM's Marginals decide as they always have
        # (a note and no covariances, or huge ones past a pivot that is barely positive).
        return values, converged, marginals_or_note(problem.graph(), values, notes)
    return values, converged, marginals


def map_tags(
    scene: TagScene, incremental: bool = False, solver: Solver = Solver.VECTORISED
) -> TagMap3d:
    """The 3-D tag map of ``scene``, solved in batch (driven as ``solver`` says) or
    (``incremental``) by iSAM2.

    Raises:
        EstimationError: no views, a home tag never seen, or a graph that cannot be solved.
    """
    if not scene.views:
        raise EstimationError("no tag views to map")
    notes: list[Note] = []
    mounts, estimated = _mounts(scene, notes)
    home = _home(scene, set(mounts))
    placed = place(scene, home, mounts)
    if not incremental:
        agree(scene, placed, estimated)
    problem = TagGraph(scene, placed, estimated, home)
    if not problem.views:
        raise EstimationError(
            "no tag view could be placed (no chain of views reaches the home tag)"
        )
    if incremental:
        return _incremental(scene, problem, notes)
    values = _first_solve(problem, solver)
    errors = view_errors_px(problem, values)
    limit = max(OUTLIER_PX, OUTLIER_SHARE * float(np.median(errors)))
    dropped = int(np.sum(errors > limit))
    problem.views = [v for v, e in zip(problem.views, errors, strict=True) if e <= limit]
    problem.warm(values)
    values, converged, marginals = _final_solve(problem, notes, solver)
    errors = view_errors_px(problem, values)
    if dropped:
        notes.append(
            Note(
                "views.outliers",
                f"{dropped:,} tag views whose corners stayed more than {limit:.1f} px from the "
                "map were left out and the map solved again",
                figure=dropped,
            )
        )
    return _tag_map(scene, problem, values, marginals, errors, dropped, converged, notes)


def _noise_scale(
    problem: TagGraph, errors: NDArray[np.float64], frames: list[int], notes: list[Note]
) -> float:
    """What the covariances are scaled by: the corners' noise the solution's residuals measure
    over the noise assumed, squared, where that is more than 1. Never less: on TagSLAM's test
    13 the residuals measure 0.25 px where 1 px is assumed, and covariances narrowed to that
    put half the tags more than 3 sigma from TagSLAM's (a rig's calibration errors are not in
    its residuals); held at the assumed pixel, the stated sigmas are of the errors' size."""
    views = problem.views
    assumed_px = np.array([float(v.sigma[0] / v.ray_per_px[0]) for v in views])
    chi2 = float(np.sum(8.0 * (errors / assumed_px) ** 2))
    unknowns = len(frames) + len({v.tag_id for v in views}) + len(problem.estimated)
    dof = 8 * len(views) - 6 * unknowns
    if dof < MIN_NOISE_DOF:
        return 1.0
    scale = chi2 / dof
    measured = float(np.median(assumed_px)) * scale**0.5
    widened = scale > 1.0
    notes.append(Note("noise.measured", f"the corners' noise, measured from the map's residuals, "
                      f"is {measured:.2f} px (the model assumed {np.median(assumed_px):.2g} px): "
                      + ("covariances widened to it" if widened else "covariances kept at the "
                         "assumed noise"), figure=measured))  # fmt: skip
    return max(scale, 1.0)


def _incremental(scene: TagScene, problem: TagGraph, notes: list[Note]) -> TagMap3d:
    """The map by iSAM2: views that disagree with the poses they join never enter."""
    placed_views = len(problem.views)
    values, isam = solve_incremental(problem)
    dropped = placed_views - len(problem.views)
    if dropped:
        notes.append(Note("views.outliers", f"{dropped:,} tag views that disagreed with the map as "
                          "it stood when they came were left out", figure=dropped))  # fmt: skip
    errors = view_errors_px(problem, values)
    return _tag_map(scene, problem, values, isam, errors, dropped, True, notes)


def _tag_map(
    scene: TagScene,
    problem: TagGraph,
    values: gtsam.Values,
    marginals: Any,
    errors: NDArray[np.float64],
    dropped: int,
    converged: bool,
    notes: list[Note],
) -> TagMap3d:
    views_of = Counter(v.tag_id for v in problem.views)
    frames = sorted({v.frame for v in problem.views})
    rig_poses = [values.atPose3(rig_key(i)) for i in frames]
    G, up, framing_notes = map_framing(scene, problem.placed, values, frames, problem.home)
    notes += framing_notes + odometry_scale_note(scene, frames, rig_poses)
    scale = _noise_scale(problem, errors, frames, notes)

    def covariance(key: int) -> NDArray[np.float64] | None:
        if marginals is None:
            return None
        try:
            return scale * np.asarray(marginals.marginalCovariance(key))
        except RuntimeError:  # an indeterminate pose: its mean stands, without a covariance
            return None

    known = {k.tag_id for k in scene.known_tags}
    tags = {
        i: Tag3d(
            i,
            G.compose(values.atPose3(tag_key(i))),
            covariance(tag_key(i)),
            views_of[i],
            scene.tag_sizes[i],
            i in known,
        )
        for i in sorted(views_of)
    }
    views_by_camera = Counter(v.camera for v in problem.views)
    cameras = {}
    for i, camera in enumerate(scene.cameras):
        if i not in problem.placed.cameras:
            continue
        if i in problem.estimated:
            mount, cov = values.atPose3(camera_key(i)), covariance(camera_key(i))
        else:
            mount, cov = problem.placed.cameras[i], None
        cameras[camera.name] = Camera3d(
            camera.name, camera.topic, mount, cov, i in problem.estimated, views_by_camera[i]
        )
    notes += _left_out_notes(scene, problem, frames)
    return TagMap3d(
        tags,
        scene.frame_times[frames],
        [G.compose(p) for p in rig_poses],
        cameras,
        problem.home,
        up,
        len(scene.frame_times) - len(frames),
        len(problem.views),
        dropped,
        float(np.sqrt(np.mean(errors**2))) if errors.size else 0.0,
        converged,
        notes,
    )


def _left_out_notes(scene: TagScene, problem: TagGraph, frames: list[int]) -> list[Note]:
    notes = []
    seen = {v.tag_id for v in scene.views}
    unplaced = sorted(seen - set(problem.placed.tags))
    if unplaced:
        shown = ", ".join(map(str, unplaced[:20])) + (" ..." if len(unplaced) > 20 else "")
        notes.append(
            Note(
                "tags.unplaced",
                f"{len(unplaced)} tags seen share no view chain with the "
                f"map and were left out: {shown}",
                figure=len(unplaced),
            )
        )
    for i, camera in enumerate(scene.cameras):
        if i not in problem.placed.cameras and any(v.camera == i for v in scene.views):
            notes.append(
                Note(
                    "camera.unplaced",
                    f"{camera.name}: its mount could not be estimated "
                    "(it never sees a mapped tag in a frame the rig's other cameras "
                    "place); its views were left out",
                    camera.topic,
                )
            )
    skipped = len(scene.frame_times) - len(frames)
    if skipped:
        notes.append(
            Note(
                "frames.unplaced",
                f"{skipped:,} of {len(scene.frame_times):,} rig frames "
                "saw no mapped tag and were skipped",
                figure=skipped,
            )
        )
    return notes
