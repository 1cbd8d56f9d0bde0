"""One frame to marker observations: detection, yaw, bearing, range from depth, sigmas, flags."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from markergraph.estimator.types import Observation
from markergraph.frontend.camera import Camera, CameraMount
from markergraph.frontend.detect import EDGE_HALF_WIDTH_PX, Detection, Detector
from markergraph.frontend.sizes import MarkerSizes
from markergraph.frontend.yaw import (
    YawMethod,
    marker_centre,
    pnp_solutions,
    pnp_theta,
    pnp_theta_sigma,
    yaw_from_corners,
    yaw_sigma,
)

__all__ = [
    "DepthModel",
    "Flags",
    "ObservationModel",
    "marker_depth",
    "observe",
    "observe_detections",
    "theta_per_turn",
    "theta_shared_sigma",
]


class Flags:
    """Quality flags an observation may carry."""

    NEAR_EDGE = "near-edge"  # a corner within EDGE_MARGIN_PX of the image border
    SMALL = "small"  # a vertical edge shorter than SMALL_EDGE_PX
    GRAZING = "grazing"  # |theta| beyond GRAZING_RAD: corners foreshortened, yaw poor
    AMBIGUOUS = "ambiguous"  # |theta| under AMBIGUOUS_RAD: the yaw's sign is unreliable
    NO_DEPTH = "no-depth"  # range from the marker's pose (PnP), not the depth image
    TINY = "tiny"  # modules under READABLE_MODULE_PX: its bits, so its id, may be misread


EDGE_MARGIN_PX = 10.0
DEPTH_DISAGREES = 0.2  # depth this far from the marker's PnP distance belongs to something else
MIN_PLANE_PIXELS = 30  # valid depth pixels on a marker before a plane is fitted to them
PLANE_PIXELS = 600  # about as many as a plane is fitted to
SMALL_EDGE_PX = 20.0
# Two pixels a module samples each bit at least once whatever the phase (Nyquist). Below it the
# D435i's blur read the simulated warehouse's DICT_4X4_250 markers (6-14 px) as other ids: 10 of
# its 11 markers never seen at 2 px a module or more, over three logs, were misread ids.
READABLE_MODULE_PX = 2.0
GRAZING_RAD = math.radians(60.0)
GRAZING_SIGMA_RAD = math.radians(90.0)
AMBIGUOUS_RAD = math.radians(5.0)
# Theta's error that corner noise does not explain: blur, JPEG and the shutter bias the corners of
# a marker 50-100 px wide by a tenth of a pixel together, not independently. Added in
# quadrature. Without it, on the held-out corridor logs of an independent generator, theta seen
# at 0.3 deg pulled whole corridors of markers 2 cm along the direction of travel (under the
# wheels' true scale SLAM was 2.5 cm off; 2.0 cm with this floor, 1.8 cm with 2 deg). 2
# deg made theta's sigma 3.7x cautious on TagSLAM's real recording (median |z| 0.18); 1 deg
# keeps it within the honest range there (test_real_logs).
THETA_FLOOR_RAD = math.radians(1.0)
# A small marker's corners share a bias: where its border (one module wide) is narrower than
# two of edge_refined's reaches across an edge, the refinement's profiles take in the inner
# cells' edges, blurred, and every corner moves with the marker's pattern. Read as the error of
# the difference between its left and right edges [px], theta's perspective cue (s^2 sin(theta)
# / f for a marker s pixels high, f the focal length), it moves theta by CORNER_BIAS_PX f / (s^2
# cos theta): 7 deg at 22 px. Larger markers' theta errors stay well inside the sigmas above.
# Observations from one view (one direction and distance) share it, so averaging them does not
# reduce it: each observation carries it apart (``sigma_theta_shared``), for the estimators to
# count once a view (:func:`~markergraph.estimator.shared_over_views`).
CORNER_BIAS_PX = 0.1
CLEAN_MODULE_PX = 2.0 * EDGE_HALF_WIDTH_PX
# IPPE's two solutions explain the corners almost equally well when this close (ratio of their
# reprojection errors): the marker is small or seen nearly face-on, and its theta is ambiguous.
AMBIGUITY_RATIO = 2.0
# ... or, for a small marker (modules under CLEAN_MODULE_PX), when the second's extra squared
# error over the eight corner coordinates is what corner noise alone gives (chi-square, one
# degree of freedom, 95 %): both fit within the noise. A ratio alone misses this where the first
# fits almost exactly: on the simulated warehouse, markers of 16-22 px at 25 deg came out
# mirrored (theta off by 50 deg) in 1 of 4 sightings, 0.01-0.10 px against 0.05-0.23 px, and
# claimed a 3 deg sigma. Applied to every marker, it took theta from most larger ones, mostly
# right, and the paper's closed form and marker graph went from 8 to 65-70 cm on an office log.
AMBIGUITY_CHI2 = 3.84
# A rolling shutter reads each row later than the one above: while the camera turns, a marker's
# lower corners are imaged further along the turn and the square leans. Read as perspective, the
# lean moves theta, most near face-on: 4 deg from 1.4 m at 0.6 rad/s over a 25 ms readout on the
# simulated warehouse, which turned its whole map 3 deg about the home marker. Each observation
# carries theta's change per radian turned during the readout (:func:`theta_per_turn`, by
# leaning its corners this far and solving again), for the estimator to take the lean off, or
# widen theta by it, once it knows the turn rate (:mod:`~markergraph.estimator.timing`).
LEAN_STEP_RAD = 0.015  # 25 ms at 0.6 rad/s: the differences span a lean as large
# Beyond this, theta's sigma is propagated from the one PnP solve; nearer frontal, where the
# linearisation is up to 2x optimistic (IPPE's two poses meet), by re-solving.
NEAR_FRONTAL_RAD = math.radians(12.0)


@dataclass(frozen=True, slots=True)
class DepthModel:
    """The depth camera's error: ``sigma = base_m + per_m2 * Z^2`` (structured light).

    Attributes:
        base_m, per_m2: the model's terms [m, 1/m].
        max_range_m: depths beyond this are not trusted (treated as no return).
    """

    base_m: float = 0.002
    per_m2: float = 0.003
    max_range_m: float = 8.0

    def sigma(self, z_m: float) -> float:
        return self.base_m + self.per_m2 * z_m * z_m


@dataclass(frozen=True)
class ObservationModel:
    """How detected corners become observations: the markers' sizes, the yaw method and the
    noise of corners and depth.

    Attributes:
        marker_sizes: the side of each marker's black square [m].
        method: how theta is computed from the corners.
        corner_sigma_px: the corners' noise after sub-pixel refinement [px].
        depth_model: the depth camera's error model.
        marker_modules: modules across a marker, its black border included (the dictionary's
            bits and 2: 6 for 4x4 markers).
        refined_corners: the corners were refined here (:func:`~.detect.edge_refined`), whose
            bias on small markers :func:`theta_shared_sigma` models; False for another
            detector's.
    """

    marker_sizes: MarkerSizes = MarkerSizes()
    method: YawMethod = YawMethod.PNP
    corner_sigma_px: float = 0.3
    depth_model: DepthModel = DepthModel()
    marker_modules: int = 6
    refined_corners: bool = True


def corner_flags(corners: NDArray[np.float64], camera: Camera, modules: int) -> set[str]:
    """``near-edge`` (a corner within EDGE_MARGIN_PX of the image border), ``small`` (an edge
    shorter than SMALL_EDGE_PX) and ``tiny`` (the mean side under READABLE_MODULE_PX times the
    ``modules`` across the marker) for detected corners (4, 2) in pixels."""
    flags = set()
    (u0, v0), (u1, v1) = corners.min(axis=0), corners.max(axis=0)
    if min(u0, v0) < EDGE_MARGIN_PX or (
        u1 > camera.width - EDGE_MARGIN_PX or v1 > camera.height - EDGE_MARGIN_PX
    ):
        flags.add(Flags.NEAR_EDGE)
    edges = corners - corners[[3, 0, 1, 2]]
    lengths = np.hypot(edges[:, 0], edges[:, 1])
    if float(lengths.min()) < SMALL_EDGE_PX:
        flags.add(Flags.SMALL)
    if float(lengths.mean()) < READABLE_MODULE_PX * modules:
        flags.add(Flags.TINY)
    return flags


def robust_least_squares(
    A: NDArray[np.float64], b: NDArray[np.float64], passes: int
) -> tuple[NDArray[np.float64], NDArray[np.bool_], float]:
    """``A x = b`` by least squares, refitted ``passes`` times without the rows beyond three
    robust sigmas (1.4826 MAD) of the last fit: (x, the rows kept, that sigma).

    Solved through the normal equations: A has a few well-scaled columns here, and on a
    marker's 300-500 depth pixels that costs half of ``lstsq``'s SVD. An exactly singular
    system falls back to ``lstsq``'s least-norm solution; a nearly singular one (a marker's
    pixels all in one row) gives an arbitrary intercept, as ``lstsq`` did, which
    :func:`marker_depth` refuses when it falls outside the depths fitted."""
    kept = np.ones(len(b), dtype=bool)
    for fit in range(passes):
        A_kept, b_kept = (A, b) if fit == 0 else (A[kept], b[kept])
        try:
            x = np.linalg.solve(A_kept.T @ A_kept, A_kept.T @ b_kept)
        except np.linalg.LinAlgError:
            x = np.linalg.lstsq(A_kept, b_kept, rcond=None)[0]
        residual = b - A @ x
        sigma = 1.4826 * _median(np.abs(residual[kept]))
        kept = np.abs(residual) <= 3.0 * max(sigma, 1e-9)
    return np.asarray(x, dtype=np.float64), np.asarray(kept, dtype=np.bool_), sigma


def _median(values: NDArray[np.float64]) -> float:
    """``np.median`` of a 1-D array without its generic machinery (a quarter to a third of its
    cost on 300-500 values)."""
    n = len(values)
    if n == 0:
        return math.nan
    half = n // 2
    if n % 2:
        return float(np.partition(values, half)[half])
    low, high = np.partition(values, [half - 1, half])[half - 1 : half + 1]
    return float(low + high) / 2.0


def marker_depth(depth: NDArray, corners: NDArray[np.float64], model: DepthModel) -> float | None:
    """Depth [m] at the marker's centre, from the valid pixels inside it (shrunk by a fifth
    toward its centre to stay clear of the edge where depth mixes with the wall); None without
    a valid pixel.

    The marker is a plane, so 1/Z is linear in the pixel: a plane fitted to the valid pixels
    (least squares, points beyond three robust sigmas dropped once) gives the centre's depth
    even when whole cells return nothing (black laminated cells) and the marker is oblique,
    where the median of what is left would lean to one side. With few pixels, their median.
    """
    centre = marker_centre(corners)
    inner = centre + 0.8 * (corners - centre)
    (left, top), (right, bottom) = inner.min(axis=0), inner.max(axis=0)
    x0, y0 = max(math.floor(left), 0), max(math.floor(top), 0)
    x1 = min(math.ceil(right) + 1, depth.shape[1])
    y1 = min(math.ceil(bottom) + 1, depth.shape[0])
    if x0 >= x1 or y0 >= y1:
        return None
    mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
    cv2.fillConvexPoly(mask, np.rint(inner - [x0, y0]).astype(np.int32), 1)
    # Every pixel of a near marker is more than a plane needs, and depth noise is correlated
    # over several pixels anyway: a regular subsample of at most about PLANE_PIXELS.
    step = max(1, int(math.sqrt(mask.size / PLANE_PIXELS)))
    v, u = np.nonzero(mask[::step, ::step])
    v, u = v * step, u * step
    window = depth[y0:y1, x0:x1][v, u]
    metres = window.astype(np.float64) / 1000.0 if depth.dtype == np.uint16 else window
    valid = np.isfinite(metres) & (metres > 0.0) & (metres <= model.max_range_m)
    seen = metres[valid]
    if len(seen) < MIN_PLANE_PIXELS:
        return float(np.median(seen)) if len(seen) else None
    A = np.empty((len(seen), 3))
    A[:, 0] = 1.0
    A[:, 1] = u[valid] + (x0 - centre[0])
    A[:, 2] = v[valid] + (y0 - centre[1])
    plane, kept, _ = robust_least_squares(A, 1.0 / seen, passes=2)
    # A plane extrapolated from a few rows or a corner of cells is not trusted beyond the
    # depths it was fitted to.
    inside = seen[kept]
    if plane[0] > 0 and inside.min() <= 1.0 / plane[0] <= inside.max():
        return float(1.0 / plane[0])
    return float(np.median(seen))


def observe_detections(
    detections: list[Detection],
    camera: Camera,
    model: ObservationModel,
    *,
    depth: NDArray | None = None,
    mount: CameraMount = CameraMount(),
    t_ns: int = 0,
    depth_ratios: list[tuple[int, float, float]] | None = None,
    size_ratios: list[tuple[int, float]] | None = None,
) -> list[Observation]:
    """Observations of already detected markers; see :func:`observe`.

    ``depth_ratios``, when given, receives for each marker seen with depth and well placed for
    PnP (not grazing, not small, not at the image's edge) the stamp, its depth and its PnP
    distance: their ratio is what the depth camera reads per true metre, if the marker's size
    is right. ``size_ratios`` receives the same markers' id and depth over PnP distance before
    depth is judged against PnP (:data:`DEPTH_DISAGREES`): with a trusted depth camera, the
    ratio times the marker's given size is its size, however wrong the given one.
    """
    observations = []
    for detection in detections:
        observation = _observe_one(
            detection, camera, model, depth, mount, t_ns, depth_ratios, size_ratios
        )
        if observation is not None:
            observations.append(observation)
    return observations


def _observe_one(
    detection: Detection,
    camera: Camera,
    model: ObservationModel,
    depth: NDArray | None,
    mount: CameraMount,
    t_ns: int,
    depth_ratios: list[tuple[int, float, float]] | None,
    size_ratios: list[tuple[int, float]] | None,
) -> Observation | None:
    """One detection's observation (:func:`observe_detections`); None where theta has no
    solution."""
    method, corner_sigma_px = model.method, model.corner_sigma_px
    length_m = model.marker_sizes.of(detection.marker_id)
    corners = camera.undistort(detection.corners)
    edge_flags = corner_flags(detection.corners, camera, model.marker_modules)
    # One PnP solve serves theta (the default method), the range without depth and the
    # depth's scale.
    solutions = pnp_solutions(corners, camera, length_m)
    pose = (solutions[0][1], solutions[0][2]) if solutions else None
    theta = (
        pnp_theta(pose)
        if method is YawMethod.PNP
        else yaw_from_corners(corners, method, camera, length_m)
    )
    if not math.isfinite(theta):
        return None  # PAPER has no solution here; nothing honest to report
    # Depth is aligned to the colour image as recorded: look it up at the detected
    # (distorted) corners, not the undistorted ones.
    z = None if depth is None else marker_depth(depth, detection.corners, model.depth_model)
    well_placed = abs(theta) < GRAZING_RAD and not edge_flags
    placed = well_placed and pose is not None and pose[1][2] > 0
    if size_ratios is not None and z is not None and placed and pose is not None:
        size_ratios.append((detection.marker_id, z / float(pose[1][2])))
    if z is not None and pose is not None and abs(z - pose[1][2]) > DEPTH_DISAGREES * pose[1][2]:
        z = None  # depth saw something else (a door frame in front, the wall behind)
    no_depth = z is None
    z, ray, sigma_z = _centre_depth(corners, camera, pose, z, length_m, model)
    if not no_depth and depth_ratios is not None and placed and pose is not None:
        depth_ratios.append((t_ns, z, float(pose[1][2])))
    # The centre in the base frame, then horizontal range and bearing from the camera.
    p_base = mount.R_base_optical @ (z * ray)
    range_m = math.hypot(p_base[0], p_base[1])
    bearing = math.atan2(p_base[1], p_base[0]) - mount.yaw_rad
    sigma_range = sigma_z * range_m / z  # the horizontal range scales with Z
    sigma_theta = _theta_sigma(theta, pose, corners, camera, length_m, model)
    per_turn = theta_per_turn(corners, theta, camera, length_m, method)
    flags = set(edge_flags) | ({Flags.NO_DEPTH} if no_depth else set())
    if abs(theta) > GRAZING_RAD:
        flags.add(Flags.GRAZING)
    if abs(theta) < AMBIGUOUS_RAD:
        flags.add(Flags.AMBIGUOUS)
    if method is YawMethod.PNP and second_fits_alike(solutions, corners, model):
        other = pnp_theta((solutions[1][1], solutions[1][2]))  # theta may be either: cover both
        spread = abs(math.remainder(other - theta, math.tau)) / 2.0
        sigma_theta = min(max(sigma_theta, spread), GRAZING_SIGMA_RAD)
        flags.add(Flags.AMBIGUOUS)
    return Observation(
        t_ns,
        detection.marker_id,
        float(bearing),
        float(theta),
        float(range_m),
        corner_sigma_px / camera.fx,
        float(sigma_theta),
        float(sigma_range),
        tuple((float(u), float(v)) for u, v in detection.corners),
        frozenset(flags),
        float(mount.height_m + p_base[2]),
        theta_shared_sigma(corners, theta, camera, model),
        per_turn,
    )


def _mean_side_px(corners: NDArray[np.float64]) -> float:
    """The mean of the marker's two vertical edges in the image [px]."""
    left = float(np.linalg.norm(corners[0] - corners[3]))
    right = float(np.linalg.norm(corners[1] - corners[2]))
    return (left + right) / 2.0


def _centre_depth(
    corners: NDArray[np.float64],
    camera: Camera,
    pose: tuple[NDArray[np.float64], NDArray[np.float64]] | None,
    z: float | None,
    length_m: float,
    model: ObservationModel,
) -> tuple[float, NDArray[np.float64], float]:
    """The marker centre's depth Z [m] (from depth when given as ``z``, else from its corners),
    its ray (Z = 1) in the optical frame, and Z's sigma [m]."""
    centre = marker_centre(corners)
    ray = np.array([(centre[0] - camera.cx) / camera.fx, (centre[1] - camera.cy) / camera.fy, 1.0])
    if z is not None:
        return z, ray, model.depth_model.sigma(z)
    # Without depth: the marker's full pose from its corners and size (PnP); a pitched
    # camera or an oblique marker foreshortens the edges, which a size-only range would
    # read as distance. Its sigma: the mean vertical edge images f * L / Z.
    side_px = _mean_side_px(corners)
    z = float(pose[1][2]) if pose is not None else camera.fy * length_m / side_px
    if pose is not None:
        ray = pose[1] / pose[1][2]
    return z, ray, z * model.corner_sigma_px * math.sqrt(2.0) / side_px


def second_fits_alike(
    solutions: list[tuple[float, NDArray[np.float64], NDArray[np.float64]]],
    corners: NDArray[np.float64],
    model: ObservationModel,
) -> bool:
    """Whether IPPE's second pose (of :func:`~.yaw.pnp_solutions`, RMS reprojection errors)
    explains the ``corners`` almost as well as the first (:data:`AMBIGUITY_RATIO`) or, for a
    small marker, within what the corners' noise tells apart (:data:`AMBIGUITY_CHI2`): a small
    or face-on marker, whose pose may be either."""
    if len(solutions) < 2:
        return False
    first, second = solutions[0][0], solutions[1][0]
    if second < AMBIGUITY_RATIO * max(first, 1e-3):
        return True
    if not _small(_mean_side_px(corners), model):
        return False
    return 8.0 * (second**2 - first**2) / model.corner_sigma_px**2 < AMBIGUITY_CHI2


def _small(side_px: float, model: ObservationModel) -> bool:
    """Whether a marker ``side_px`` high has modules under :data:`CLEAN_MODULE_PX`, where edge
    refinement's reach takes in its inner cells and its two planar poses look alike."""
    return side_px < CLEAN_MODULE_PX * model.marker_modules


def theta_per_turn(
    corners: NDArray[np.float64], theta: float, camera: Camera, length_m: float, method: YawMethod
) -> float:
    """Theta's change per radian the camera turns about its vertical axis while a rolling
    shutter reads its rows out [rad/rad]: the undistorted ``corners`` leaned as such a turn
    leans them (each row moved right by ``f psi / H`` a row, about the marker's middle row, for
    a turn ``psi`` to the left), :data:`LEAN_STEP_RAD` each way, and theta found again (PnP's
    best pose: near face-on a lean can carry theta past 0, where the pose nearest it is the
    other one). 0 where a leaned square has no theta."""
    rows = corners[:, 1] - corners[:, 1].mean()
    thetas = []
    for step in (LEAN_STEP_RAD, -LEAN_STEP_RAD):
        leaned = np.array(corners, dtype=np.float64)
        leaned[:, 0] += camera.fx * step / camera.height * rows
        if method is YawMethod.PNP:
            solutions = pnp_solutions(leaned, camera, length_m)
            thetas.append(pnp_theta((solutions[0][1], solutions[0][2])) if solutions else math.nan)
        else:
            thetas.append(yaw_from_corners(leaned, method, camera, length_m))
    change = math.remainder(thetas[0] - thetas[1], math.tau) / (2.0 * LEAN_STEP_RAD)
    return change if math.isfinite(change) else 0.0


def theta_shared_sigma(
    corners: NDArray[np.float64], theta: float, camera: Camera, model: ObservationModel
) -> float:
    """Theta's error shared by one view's observations of a marker [rad]: the corners' common
    bias (:data:`CORNER_BIAS_PX`) through the perspective cue where the corners were refined
    here and a module (``model.marker_modules`` across the marker) is under
    :data:`CLEAN_MODULE_PX`; else 0."""
    side_px = _mean_side_px(corners)
    if not model.refined_corners or not _small(side_px, model):
        return 0.0
    cos_theta = max(math.cos(theta), math.cos(GRAZING_RAD))
    shared = CORNER_BIAS_PX * camera.fx / (side_px * side_px * cos_theta)
    return min(shared, GRAZING_SIGMA_RAD)


def _theta_sigma(
    theta: float,
    pose: tuple[NDArray[np.float64], NDArray[np.float64]] | None,
    corners: NDArray[np.float64],
    camera: Camera,
    length_m: float,
    model: ObservationModel,
) -> float:
    """Theta's sigma [rad]: from PnP's pose, or re-solving near frontal; floored, and made
    to weigh next to nothing at a grazing view."""
    method, corner_sigma_px = model.method, model.corner_sigma_px
    if method is YawMethod.PNP and pose is not None and abs(theta) > NEAR_FRONTAL_RAD:
        sigma_theta = pnp_theta_sigma(pose, camera, length_m, corner_sigma_px)
    else:  # near frontal, IPPE's two poses meet and only re-solving shows how far apart
        sigma_theta = yaw_sigma(corners, method, corner_sigma_px, camera, length_m)
    sigma_theta = math.hypot(sigma_theta, THETA_FLOOR_RAD)
    if abs(theta) > GRAZING_RAD:
        # A foreshortened square's two planar poses reproject alike; beyond 60 degrees
        # the detector's corners cannot tell them apart and theta may be mirrored. Keep
        # bearing and range, which stay accurate, and let theta weigh next to nothing.
        sigma_theta = max(sigma_theta, GRAZING_SIGMA_RAD)
    return sigma_theta


def observe(
    image: NDArray[np.uint8],
    camera: Camera,
    marker_sizes: MarkerSizes,
    dictionary: str = "DICT_4X4_50",
    *,
    depth: NDArray | None = None,
    method: YawMethod = YawMethod.PNP,
    mount: CameraMount = CameraMount(),
    t_ns: int = 0,
    detector: Detector | None = None,
    corner_sigma_px: float = 0.3,
    depth_model: DepthModel = DepthModel(),
) -> list[Observation]:
    """Every marker in one frame as an :class:`Observation` (bearing, theta, range, sigmas).

    Args:
        image: grey or RGB image.
        camera: its intrinsics (corners are undistorted with its distortion first).
        marker_sizes: the side of each marker's black square [m].
        dictionary: the markers' dictionary (ignored when ``detector`` is given).
        depth: aligned depth, uint16 millimetres or float32 metres, 0 or NaN for no return;
            without it, range comes from the marker's pose (PnP on its corners and size) and
            is flagged ``no-depth``.
        method: how theta is computed from the corners.
        mount: the camera's height, pitch and offset on the base, for the horizontal range.
        t_ns: the frame's stamp, copied into each observation.
        detector: a prepared detector (build one per log, not per frame).
        corner_sigma_px: corner noise after sub-pixel refinement, propagated into theta.
        depth_model: the depth camera's error model.
    """
    if depth is not None and depth.shape[:2] != image.shape[:2]:
        raise ValueError(
            f"depth image {depth.shape[1]}x{depth.shape[0]} is not aligned to the "
            f"{image.shape[1]}x{image.shape[0]} colour image"
        )
    detections = (detector or Detector(dictionary)).detect(image)
    model = ObservationModel(marker_sizes, method, corner_sigma_px, depth_model)
    return observe_detections(detections, camera, model, depth=depth, mount=mount, t_ns=t_ns)
