"""Ids misread: observations that carry one marker's id where another marker stands.

At a few pixels a module, or under motion blur, a marker's bits can decode as another id of
its dictionary: the larger the dictionary, the nearer its codes (a D435i's blur reads 4x4_250
markers of 6-14 px as other ids). Such an observation puts its id where another marker stands,
tens of metres from where the id's other observations place it, and the map is bent by it or
carries a phantom marker.

Four patterns are found (the home marker, on which the map is built, is never left out):

* **An id never readable**: a marker never seen with its modules 2 px wide or more (the front
  end's ``tiny`` flag), where a bit is not sure to be sampled once: whether it is a marker at
  all is not known. No solve is needed for it; the three below are found on SLAM's solution
  (without covariances), solved again without what it found while it finds more.
* **A stray sighting**: a small observation further than :data:`FAR_D2` (10 sigma) from its own
  marker that lands within :data:`NEAR_D2` (99 %) of another marker, which is not seen in the
  same frame, at a yaw it allows.
* **A phantom**: every observation of a marker is small and lands on other markers so, none
  of which is ever seen in the same frame as it. A real marker beside another is seen in some
  frame with it; one read for another never is (one quad gives one id).
* **An id read two ways**: a marker seen only small (the front end's ``small`` flag), none of
  its sightings explained above, a third of which lie further than :data:`FAR_D2` from where
  it solves: no majority of its sightings agrees, so where it stands is not known.

A marker a sighting lands on must be seen more often than the id is read there, and only small
sightings are taken for misread (the front end's ``small`` flag, under 20 px): a larger marker's
bits are read surely. On TagSLAM's stairs recording a wall tag 0.41 m from another, seen only
at grazing angles and never in one frame with it, landed on it; its sightings were 20 px or more.

Positions are compared under the observation's covariance (bearing and range) and
:data:`PLACE_SIGMA_M`, which stands in for the solution's own uncertainty.
"""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X
from numpy.typing import NDArray

from markergraph.common.errors import EstimationError
from markergraph.estimator.frames import Frames
from markergraph.estimator.slam import slam_cost
from markergraph.estimator.types import Observation, Robust

__all__ = [
    "FAR_D2",
    "NEAR_D2",
    "PLACE_SIGMA_M",
    "Misread",
    "describe_misreads",
    "find_misreads",
    "frames_without",
    "misread_observations",
    "unreadable_sightings",
]

SMALL = "small"  # the front end's flag for a marker under 20 px (frontend.observe.Flags)
TINY = "tiny"  # the front end's flag for modules under 2 px: its bits may be misread
PASSES = 3  # solves at most: each pass's misreads left out may show more (they bent the map)
NEAR_D2 = 9.21  # chi-square, 2 degrees of freedom, 99 %: it lands on that marker
FAR_D2 = 100.0  # 10 sigma: it cannot be of its own marker
PLACE_SIGMA_M = 0.1  # the solved camera pose's and marker's uncertainty, in place of marginals
TORN_SHARE = 1 / 3  # of a marker's sightings 10 sigma from where it solves: no majority holds
YAW_SIGMAS = 3.0  # a yaw within this many of its sigmas (theta's and bearing's) is allowed


@dataclass(frozen=True, slots=True)
class Misread:
    """An observation taken as another marker's id misread."""

    t_ns: int
    """Its frame's stamp [ns]."""
    read_as: int
    """The id it carries."""
    stands_on: int | None
    """The marker where it lands (None where it was not placed: ``torn``, ``unreadable``)."""
    kind: str = "stray"
    """``stray``, ``phantom``, ``torn`` or ``unreadable`` (see the module's docstring)."""


@dataclass(frozen=True, slots=True)
class _Landing:
    """Where one observation puts its marker, against the solution."""

    t_ns: int
    read_as: int
    own_d2: float  # squared Mahalanobis distance to its own marker
    stands_on: int | None  # the marker it lands on, if any
    small: bool  # flagged small by the front end


def misread_observations(
    frames: Frames, T_base_camera: gtsam.Pose2, robust: Robust = Robust.HUBER
) -> list[Misread]:
    """The observations of ``frames`` taken as misread ids: the markers never seen readable
    (:func:`unreadable_sightings`), then those :func:`find_misreads` finds against SLAM's
    solution, solved again without them while it finds more (at most :data:`PASSES` solves),
    in frame order. Where SLAM cannot solve the graph it stops (the estimators say why)."""
    found = unreadable_sightings(frames)
    for _ in range(PASSES):
        try:
            _, solution = slam_cost(frames_without(frames, found), T_base_camera, robust)
        except EstimationError:
            break
        more = find_misreads(frames_without(frames, found), solution)
        if not more:
            break
        found += more
    return sorted(found, key=lambda m: (m.t_ns, m.read_as))


def unreadable_sightings(frames: Frames) -> list[Misread]:
    """Every sighting of a marker (not home) that is never seen with its modules 2 px wide or
    more (every sighting flagged ``tiny``): whether it is a marker at all is not known."""
    sightings: defaultdict[int, list[Observation]] = defaultdict(list)
    for frame in frames.frames:
        for obs in frame.observations:
            sightings[obs.marker_id].append(obs)
    return [
        Misread(obs.t_ns, marker_id, None, "unreadable")
        for marker_id, seen in sightings.items()
        if marker_id != frames.home_id and all(TINY in o.flags for o in seen)
        for obs in seen
    ]


def frames_without(frames: Frames, misreads: Iterable[Misread]) -> Frames:
    """``frames`` with ``misreads`` taken out of their frames (a frame left empty stays, with
    its odometry)."""
    left_out = {(m.t_ns, m.read_as) for m in misreads}
    if not left_out:
        return frames
    kept = [
        replace(f, observations=tuple(
            o for o in f.observations if (o.t_ns, o.marker_id) not in left_out
        ))
        for f in frames.frames
    ]  # fmt: skip
    return replace(frames, frames=kept)


def find_misreads(frames: Frames, solution: gtsam.Values) -> list[Misread]:
    """The observations of ``frames`` taken as misread ids against ``solution`` (camera poses
    ``X(k)`` and markers ``L(id)``, as SLAM solves them), in frame order. The home marker is
    never a phantom: the map is built on it."""
    markers = {
        marker_id: solution.atPose2(L(marker_id))
        for marker_id in frames.marker_ids()
        if solution.exists(L(marker_id))
    }
    counts = Counter(o.marker_id for f in frames.frames for o in f.observations)
    together: defaultdict[int, set[int]] = defaultdict(set)  # ids seen in one frame with each
    landings: list[_Landing] = []
    for k, frame in enumerate(frames.frames):
        ids = {o.marker_id for o in frame.observations}
        for marker_id in ids:
            together[marker_id] |= ids - {marker_id}
        if not solution.exists(X(k)):
            continue
        camera = solution.atPose2(X(k))
        for obs in frame.observations:
            if obs.marker_id in markers:
                others = (m for m in markers if m not in ids)
                landings.append(_landing(camera, obs, markers, others, counts))
    # A marker it lands on is seen more often than it is read there.
    read_there = Counter((x.read_as, x.stands_on) for x in landings if x.stands_on is not None)
    landings = [
        x
        if x.stands_on is None or counts[x.stands_on] > read_there[x.read_as, x.stands_on]
        else replace(x, stands_on=None)
        for x in landings
    ]
    stray = [
        Misread(x.t_ns, x.read_as, x.stands_on, "stray")
        for x in landings
        if x.small and x.stands_on is not None and x.own_d2 > FAR_D2 and x.read_as != frames.home_id
    ]
    by_marker: defaultdict[int, list[_Landing]] = defaultdict(list)
    for landing in landings:
        by_marker[landing.read_as].append(landing)
    phantoms = [
        Misread(x.t_ns, x.read_as, x.stands_on, "phantom")
        for marker_id, seen in by_marker.items()
        if marker_id != frames.home_id
        and len(seen) == counts[marker_id]
        and all(
            x.small and x.stands_on is not None and x.stands_on not in together[marker_id]
            for x in seen
        )
        for x in seen
        if x.stands_on is not None
    ]
    explained = {(m.t_ns, m.read_as) for m in [*stray, *phantoms]}
    rest: defaultdict[int, list[_Landing]] = defaultdict(list)  # sightings left unexplained
    for landing in landings:
        if (landing.t_ns, landing.read_as) not in explained:
            rest[landing.read_as].append(landing)
    torn = [
        Misread(x.t_ns, x.read_as, None, "torn")
        for marker_id, seen in rest.items()
        if marker_id != frames.home_id
        and len(seen) == counts[marker_id]
        and all(x.small for x in seen)
        and sum(x.own_d2 > FAR_D2 for x in seen) >= TORN_SHARE * len(seen)
        for x in seen
    ]
    found = {(m.t_ns, m.read_as): m for m in [*stray, *phantoms, *torn]}
    return sorted(found.values(), key=lambda m: (m.t_ns, m.read_as))


def _landing(
    camera: gtsam.Pose2,
    obs: Observation,
    markers: dict[int, gtsam.Pose2],
    others: Iterable[int],
    counts: Counter[int],
) -> _Landing:
    """Where ``obs``, seen from ``camera``, puts its marker: its distance to its own, and the
    most often seen of ``others`` it lands on, if any (a phantom standing on a marker is not
    taken for it)."""
    direction = camera.theta() + obs.bearing
    c, s = math.cos(direction), math.sin(direction)
    R = np.array([[c, -s], [s, c]])
    along = np.diag([obs.sigma_range**2, (obs.range_m * obs.sigma_bearing) ** 2])
    S = R @ along @ R.T + 2.0 * PLACE_SIGMA_M**2 * np.eye(2)
    at = camera.transformFrom(_ahead(obs))
    yaw = direction + math.pi - obs.theta
    yaw_sigma = math.hypot(obs.sigma_theta, obs.sigma_bearing)

    def d2(marker: gtsam.Pose2) -> float:
        return _mahalanobis2(at - marker.translation(), S)

    best: tuple[int, float] | None = None  # (marker, its squared distance)
    for marker_id in others:
        marker = markers[marker_id]
        distance = d2(marker)
        turned = abs(math.remainder(yaw - marker.theta(), math.tau))
        if distance >= NEAR_D2 or turned > YAW_SIGMAS * yaw_sigma:
            continue
        if best is None or (-counts[marker_id], distance) < (-counts[best[0]], best[1]):
            best = marker_id, distance
    stands_on = None if best is None else best[0]
    own = d2(markers[obs.marker_id])
    return _Landing(obs.t_ns, obs.marker_id, own, stands_on, SMALL in obs.flags)


def _ahead(obs: Observation) -> NDArray[np.float64]:
    """The marker's centre in the camera's top-view frame."""
    return obs.range_m * np.array([math.cos(obs.bearing), math.sin(obs.bearing)])


def _mahalanobis2(difference: NDArray[np.float64], S: NDArray[np.float64]) -> float:
    return float(difference @ np.linalg.solve(S, difference))


def describe_misreads(misreads: Sequence[Misread]) -> str:
    """One sentence for a note: which ids were read where which markers stand."""
    pairs = Counter(
        (m.read_as, -1 if m.stands_on is None else m.stands_on, m.kind) for m in misreads
    )
    said = {
        "torn": "the {n} of marker {read_as}, seen only small and 10 sigma apart",
        "unreadable": "the {n} of marker {read_as}, never seen at 2 px a module",
    }
    parts = [
        said.get(kind, "{n} read as marker {read_as} where marker {stands_on} stands").format(
            n=n, read_as=read_as, stands_on=stands_on
        )
        for (read_as, stands_on, kind), n in sorted(pairs.items())
    ]
    return (
        f"{len(misreads)} observations taken as misread ids and left out: "
        + "; ".join(parts)
        + " (a sighting that lands on another marker lands on one seen more often, never in its"
        " frame)"
    )
