"""Measured marker-to-marker links (the paper's E_ab as relative poses) and graph connectivity."""

from __future__ import annotations

import itertools
import math
from collections import Counter, defaultdict, deque
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.estimator.frames import Frames
from markergraph.estimator.graph import observation_measurement
from markergraph.estimator.models import compose_covariance, invert_covariance
from markergraph.estimator.types import LEANING, MarkerLink, Observation

__all__ = [
    "MAX_LINK_SIGMA_THETA_RAD",
    "MeasuredLink",
    "components",
    "describe_disconnected",
    "link_counts",
    "linkable",
    "measure_links",
]


@dataclass(frozen=True)
class MeasuredLink:
    """One measured ``T_a_b`` between two markers, with its covariance (tangent space at b).

    Attributes:
        marker_a, marker_b: the two markers.
        T_a_b: b's pose in a's frame.
        covariance: 3x3, from both observations and the odometry between them.
        frame_a, frame_b: the frames whose observations it combines (equal for one frame).
    """

    marker_a: int
    marker_b: int
    T_a_b: gtsam.Pose2
    covariance: NDArray[np.float64]
    frame_a: int
    frame_b: int


def _link(
    frames: Frames,
    j: int,
    obs_a: Observation,
    k: int,
    obs_b: Observation,
    T_base_camera: gtsam.Pose2,
) -> MeasuredLink:
    T_base_a, cov_a = observation_measurement(obs_a, T_base_camera)
    T_base_b, cov_b = observation_measurement(obs_b, T_base_camera)
    steps = [
        frames.frames[i - 1].T_odom_base.between(frames.frames[i].T_odom_base)
        for i in range(j + 1, k + 1)
    ]
    step_covs = [frames.frames[i].odometry_covariance for i in range(j + 1, k + 1)]
    chain = [T_base_a.inverse(), *steps, T_base_b]
    covs = [invert_covariance(T_base_a, cov_a), *step_covs, cov_b]
    T_a_b, covariance = compose_covariance(chain, covs)
    return MeasuredLink(obs_a.marker_id, obs_b.marker_id, T_a_b, covariance, j, k)


# A link rotates everything it measures through the theta of the marker at each end: a's theta
# turns b's offset into a's frame, b's sets their relative yaw. Its covariance is that rotation
# linearised, which holds while theta's error is a small angle (at 10 deg the second-order
# term is 1.5 % of the offset, well inside the first-order sigma of 17 %). Where the front end
# could not measure theta (a grazing view: sigma 90 deg) the linearised link is not a
# measurement at all: on a rendered corridor such links put markers 13 m off with whitened
# residuals under 2, and the graph 5.2 m off. Those observations make no link; their frames
# still carry the odometry between the frames that do.
MAX_LINK_SIGMA_THETA_RAD = math.radians(10.0)

# Dead reckoning further than this between two markers makes no link: the paper's robot
# localises on a marker and drives to the next, it does not wander.
MAX_HANDOVER_M = 15.0

# A handover's last sighting of one marker and first of the next are taken mid-turn, where a
# rolling shutter leans theta (-13 ms x turn rate on a D435i: -0.4 deg at 34 deg/s), the same
# way at every turn. Where the readout is not given the lean stays (the sighting is flagged
# LEANING), widened into theta's sigma by too little to tell, and the chain of handover links
# turns the whole map about home (-1.2 deg on a simulated office). Below this rate the lean is a
# twentieth of theta's usual sigma, so such a handover takes the nearest sighting made this
# calmly in the marker's run of sightings, up to HANDOVER_SEARCH_NS away: more odometry between
# the two (its random turn error: the links' yaw scatter grows by about a third), for a theta
# without the lean. Where the lean is taken off it is all cost, so the last and first stay.
CALM_TURN_RATE = math.radians(5.0)
HANDOVER_SEARCH_NS = 2_000_000_000


def linkable(obs: Observation) -> bool:
    """Whether an observation's theta is measured well enough to end a link."""
    return obs.sigma_theta <= MAX_LINK_SIGMA_THETA_RAD


def _turn_rate(frames: Frames, k: int) -> float:
    """How fast the base turns at frame k, from its neighbours' odometry [rad/s]."""
    i, j = max(k - 1, 0), min(k + 1, len(frames.frames) - 1)
    before, after = frames.frames[i], frames.frames[j]
    dt = (after.t_ns - before.t_ns) * 1e-9
    return abs(before.T_odom_base.between(after.T_odom_base).theta()) / dt if dt > 0 else 0.0


def _calmest(frames: Frames, k: int, obs: Observation, step: int) -> tuple[int, Observation]:
    """The handover's sighting ``obs`` at frame k or, where its theta kept a rolling shutter's
    lean, the nearest made while the base turned slower than :data:`CALM_TURN_RATE`, walking
    ``step`` (-1 back, +1 on) while the marker stays in view, up to :data:`HANDOVER_SEARCH_NS`
    away."""
    if LEANING not in obs.flags:
        return k, obs
    i = k
    while 0 <= i < len(frames.frames):
        frame = frames.frames[i]
        same = [o for o in frame.observations if o.marker_id == obs.marker_id]
        if not same or abs(frame.t_ns - frames.frames[k].t_ns) > HANDOVER_SEARCH_NS:
            break  # the run of sightings, or the search, ends
        if linkable(same[0]) and _turn_rate(frames, i) < CALM_TURN_RATE:
            return i, same[0]
        i += step
    return k, obs


def measure_links(
    frames: Frames, T_base_camera: gtsam.Pose2, max_handover_m: float = MAX_HANDOVER_M
) -> list[MeasuredLink]:
    """Every E_ab the robot measures, each observation used in few links so errors stay nearly
    independent.

    * Only observations whose theta was measured (:func:`linkable`) end a link.
    * Markers seen in one frame are chained (nearest first): no odometry between them.
    * When the robot turns from one set of markers to a new one with none in common, the
      nearest marker of the last frame links to the nearest of the new frame through the
      odometry in between, if it drove at most ``max_handover_m``: the paper's "localise on a,
      dead-reckon, observe b". Where a rolling shutter's lean stayed in theta, each end takes
      its marker's nearest sighting made while the base barely turned (:func:`_calmest`).
    """
    links: list[MeasuredLink] = []
    previous: int | None = None
    travelled = [0.0] + [
        float(np.hypot(*a.T_odom_base.between(b.T_odom_base).translation()))
        for a, b in itertools.pairwise(frames.frames)
    ]
    path_m = np.cumsum(travelled)
    for k, frame in enumerate(frames.frames):
        seen = sorted(filter(linkable, frame.observations), key=lambda o: o.range_m)
        if not seen:  # a frame that only carries odometry to the next
            continue
        links += [_link(frames, k, a, k, b, T_base_camera) for a, b in itertools.pairwise(seen)]
        if previous is not None:
            before = list(filter(linkable, frames.frames[previous].observations))
            near = path_m[k] - path_m[previous] <= max_handover_m
            if near and not {o.marker_id for o in before} & {o.marker_id for o in seen}:
                nearest_before = min(before, key=lambda o: o.range_m)
                j, obs_a = _calmest(frames, previous, nearest_before, -1)
                m, obs_b = _calmest(frames, k, seen[0], +1)
                links.append(_link(frames, j, obs_a, m, obs_b, T_base_camera))
        previous = k
    return links


def link_counts(links: list[MeasuredLink]) -> list[MarkerLink]:
    """How many measurements link each pair of markers (pairs unordered, smaller id first)."""
    counts = Counter(tuple(sorted((link.marker_a, link.marker_b))) for link in links)
    return [MarkerLink(a, b, n) for (a, b), n in sorted(counts.items())]


def components(marker_ids: list[int], links: list[MeasuredLink]) -> list[list[int]]:
    """Groups of markers joined by links, each sorted; the groups in order of their first id."""
    neighbours: dict[int, set[int]] = defaultdict(set)
    for link in links:
        neighbours[link.marker_a].add(link.marker_b)
        neighbours[link.marker_b].add(link.marker_a)
    unvisited, groups = set(marker_ids), []
    for start in marker_ids:
        if start not in unvisited:
            continue
        group, queue = [], deque([start])
        unvisited.discard(start)
        while queue:
            marker = queue.popleft()
            group.append(marker)
            for other in neighbours[marker] & unvisited:
                unvisited.discard(other)
                queue.append(other)
        groups.append(sorted(group))
    return groups


def describe_disconnected(groups: list[list[int]], home_id: int) -> list[tuple[list[int], str]]:
    """(markers, sentence) for each group of markers no link chain joins to the home marker;
    the markers linked to none at all share one sentence."""
    apart = [group for group in groups if home_id not in group]
    described = [
        (group, f"markers {', '.join(map(str, group))} are linked to no chain reaching home "
                f"marker {home_id}")
        for group in apart
        if len(group) > 1
    ]  # fmt: skip
    lone = sorted(group[0] for group in apart if len(group) == 1)
    if lone:
        ids = ", ".join(map(str, lone))
        described.append((lone, (
            f"marker {ids} is never seen, with its theta measured, together with or right after "
            "another marker" if len(lone) == 1 else
            f"markers {ids} are never seen, with their theta measured, together with or right "
            "after another marker"
        )))  # fmt: skip
    return described
