"""Colour and aligned depth frames of a world, rendered for real.

Walls are vertical planes from the floor to the ceiling, so along any pixel's ray the wall it
hits depends only on the ray's azimuth. Each frame casts one table of azimuths against the walls
and every pixel looks its wall up there; floor and ceiling are planes. That makes a 640x480
colour-plus-depth frame cost a few milliseconds on one core.

Markers are the OpenCV marker images with their white border, drawn through the exact
homography of their corners, and only on pixels whose ray really ends on the marker's wall (so
a wall in between hides them). Depth is the optical-axis distance (Z) in millimetres, 16UC1,
0 for no return, with noise growing with the square of range and dropouts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.datasets.route import drive
from markergraph.datasets.scenarios import scenario
from markergraph.datasets.simulate import SIMULATED_MOUNT, MarkerGeometry
from markergraph.datasets.world import World
from markergraph.frontend.camera import Camera, CameraMount

__all__ = [
    "DepthNoise",
    "FrameNoise",
    "ImageEffects",
    "RenderedFrame",
    "Renderer",
    "frames_with_true_corners",
]

_AZIMUTH_SAMPLES = 4096  # table resolution across the field of view (~0.02 px at 640 wide)
_MARKER_LEVELS = (24, 48, 96, 192, 384)  # pre-drawn marker sizes [px]; warps shrink at most 2x
_NOISE_FIELDS = 8
_TEXELS_PER_M = 40.0  # texture resolution on walls and floor


@dataclass(frozen=True, slots=True)
class DepthNoise:
    """A structured-light camera's depth errors.

    ``sigma = base_m + per_m2 * Z^2`` drawn on blocks of ``block_px`` pixels (the error of a
    stereo matcher is spatially correlated); ``dropout`` of the blocks return nothing, and so
    does everything beyond ``max_range_m``.
    """

    base_m: float = 0.001
    per_m2: float = 0.002
    block_px: int = 8
    dropout: float = 0.01
    max_range_m: float = 8.0


@dataclass(frozen=True, slots=True)
class ImageEffects:
    """Photometric effects of the colour image.

    Attributes:
        blur_sigma_px: Gaussian blur (0 for none) [px].
        noise_sigma: additive noise [grey levels].
        exposure_sigma: frame-to-frame spread of the exposure gain (a random walk) [1].
    """

    blur_sigma_px: float = 0.7
    noise_sigma: float = 2.0
    exposure_sigma: float = 0.01


@dataclass(frozen=True, slots=True)
class FrameNoise:
    """One frame's random draws (:meth:`Renderer.draw_noise`): drawn in log order, a frame
    renders the same wherever and whenever it is rendered."""

    image_field: int
    """Which of the renderer's fixed image-noise fields is added."""
    depth_field: NDArray[np.float64]
    """(blocks down, blocks across) standard normal draws, one per block of the depth error."""
    depth_dropped: NDArray[np.float64]
    """The same blocks' uniform draws, below the dropout rate where the block returns nothing."""


@dataclass(frozen=True)
class RenderedFrame:
    """One rendered frame.

    Attributes:
        rgb: (H, W, 3) uint8 colour image.
        depth_mm: (H, W) uint16 depth aligned to the colour image, 0 = no return.
        drawn_ids: markers drawn (at least partly) in the image.
    """

    rgb: NDArray[np.uint8]
    depth_mm: NDArray[np.uint16]
    drawn_ids: tuple[int, ...]


def _marker_sheet(dictionary: str, marker_id: int, side_px: int) -> tuple[NDArray[np.uint8], int]:
    """The printed marker: the black square ``side_px`` wide plus a one-cell white border."""
    aruco_dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    cells = aruco_dictionary.markerSize + 2
    square = cv2.aruco.generateImageMarker(aruco_dictionary, marker_id, side_px)
    border = max(1, round(side_px / cells))
    sheet = cv2.copyMakeBorder(
        square, border, border, border, border, cv2.BORDER_CONSTANT, value=255
    )
    return np.asarray(sheet, dtype=np.uint8), border


def _distortion_maps(camera: Camera) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """For each pixel of the distorted image, where it lies in the ideal pinhole image."""
    u, v = np.meshgrid(np.arange(camera.width), np.arange(camera.height))
    pixels = np.stack([u, v], axis=-1).reshape(-1, 2).astype(np.float64)
    ideal = camera.undistort(pixels).reshape(camera.height, camera.width, 2).astype(np.float32)
    return ideal[..., 0], ideal[..., 1]


class Renderer:
    """Renders a world through one camera on one mount.

    Args:
        world: what to draw.
        camera, mount: the camera's intrinsics and its pose on the base.
        ceiling_m: height of the ceiling [m].
        depth_noise, effects: sensor imperfections.
        texture_seed: seeds the wall and floor textures (fixed per world, not per frame).
    """

    def __init__(
        self,
        world: World,
        camera: Camera = Camera(),
        mount: CameraMount = SIMULATED_MOUNT,
        *,
        ceiling_m: float = 2.6,
        depth_noise: DepthNoise = DepthNoise(),
        effects: ImageEffects = ImageEffects(),
        texture_seed: int = 0,
    ) -> None:
        self.world, self.camera, self.mount = world, camera, mount
        self.ceiling_m, self.depth_noise, self.effects = ceiling_m, depth_noise, effects
        u, v = np.meshgrid(
            np.arange(camera.width, dtype=np.float64), np.arange(camera.height, dtype=np.float64)
        )
        rays_optical = np.stack(
            [(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], axis=-1
        )
        # Per pixel, the ray with optical Z = 1 in the base frame. Everything that depends only
        # on the camera and its mount is computed here once, on flat float32 arrays.
        rays = (rays_optical @ mount.R_base_optical.T).reshape(-1, 3)
        self._inverse_horizontal = (1.0 / np.hypot(rays[:, 0], rays[:, 1])).astype(np.float32)
        self._ray_vertical = rays[:, 2].astype(np.float32)
        azimuth = np.arctan2(rays[:, 1], rays[:, 0])
        self._azimuths = np.linspace(azimuth.min(), azimuth.max(), _AZIMUTH_SAMPLES)
        step = self._azimuths[1] - self._azimuths[0]
        self._table_index = np.rint((azimuth - self._azimuths[0]) / step).astype(np.int32)
        # Rays going down may end on the floor, rays going up on the ceiling: where, is fixed.
        self._down = np.flatnonzero(rays[:, 2] < 0.0)
        self._z_floor = (-mount.height_m / rays[self._down, 2]).astype(np.float32)
        self._down_xy = rays[self._down, :2].astype(np.float32)
        self._up = np.flatnonzero(rays[:, 2] > 0.0)
        self._z_ceiling = ((ceiling_m - mount.height_m) / rays[self._up, 2]).astype(np.float32)
        self._walls = world.wall_array()
        texture_rng = np.random.default_rng(texture_seed)
        # Smooth random textures: blurred noise plus a faint grid, so walls and floor have
        # structure for the detector to ignore, as real rooms do.
        self._wall_texture = self._texture(texture_rng, 110, 190).ravel()
        self._floor_texture = self._texture(texture_rng, 70, 140).ravel()
        self._sheets = {
            m.id: [_marker_sheet(m.dictionary, m.id, side) for side in _MARKER_LEVELS]
            for m in world.markers
        }
        self._marker_walls = {m.id: m.wall for m in world.markers}
        self._geometry = MarkerGeometry.of(world)
        self._distortion_maps = _distortion_maps(camera) if any(camera.distortion) else None
        noise_rng = np.random.default_rng(texture_seed + 1)
        self._image_noise = (
            noise_rng.standard_normal((_NOISE_FIELDS, camera.height, camera.width))
            * effects.noise_sigma
        ).astype(np.float32)

    @staticmethod
    def _texture(rng: np.random.Generator, low: float, high: float) -> NDArray[np.float32]:
        noise = cv2.GaussianBlur(rng.uniform(0.0, 1.0, (256, 256)).astype(np.float32), (0, 0), 3)
        noise = (noise - noise.min()) / (noise.max() - noise.min())
        grid = np.zeros((256, 256), np.float32)
        grid[::64, :] = grid[:, ::64] = -0.15
        return (low + (high - low) * np.clip(noise + grid, 0.0, 1.0)).astype(np.float32)

    def _wall_table(
        self, p_xy: NDArray[np.float64], yaw: float
    ) -> tuple[NDArray, NDArray, NDArray]:
        """For each table azimuth: horizontal distance to the nearest wall, its index, and the
        hit's distance along that wall (inf and -1 where no wall is hit)."""
        angles = self._azimuths + yaw
        direction = np.stack([np.cos(angles), np.sin(angles)], axis=1)  # (A, 2)
        a, b = self._walls[:, :2], self._walls[:, 2:]
        s = b - a  # (W, 2)
        denominator = direction[:, :1] * s[:, 1] - direction[:, 1:] * s[:, 0]  # (A, W)
        offset = a - p_xy  # (W, 2)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (offset[:, 0] * s[:, 1] - offset[:, 1] * s[:, 0]) / denominator
            along = (
                offset[:, 0] * direction[:, 1:] - offset[:, 1] * direction[:, :1]
            ) / denominator
        hit = (t > 1e-6) & (along >= 0.0) & (along <= 1.0)
        t = np.where(hit, t, np.inf)
        nearest = np.argmin(t, axis=1)
        rows = np.arange(len(angles))
        distance = t[rows, nearest]
        wall = np.where(np.isfinite(distance), nearest, -1)
        along_m = np.where(wall >= 0, along[rows, nearest], 0.0) * np.hypot(
            s[nearest, 0], s[nearest, 1]
        )
        return distance, wall, along_m

    def draw_noise(self, rng: np.random.Generator) -> FrameNoise:
        """One frame's noise drawn from ``rng``."""
        height, width, block = self.camera.height, self.camera.width, self.depth_noise.block_px
        blocks = (-(-height // block), -(-width // block))
        image_field = int(rng.integers(_NOISE_FIELDS))
        return FrameNoise(image_field, rng.standard_normal(blocks), rng.random(blocks))

    def render(
        self,
        T_world_base: gtsam.Pose2,
        noise: FrameNoise | np.random.Generator,
        exposure: float = 1.0,
    ) -> RenderedFrame:
        """Draw one frame from a base pose, with its noise (or the generator that draws it).
        Safe to call from several threads at once: most of it is NumPy and OpenCV over whole
        images, which release the GIL."""
        if isinstance(noise, np.random.Generator):
            noise = self.draw_noise(noise)
        T_world_camera = T_world_base.compose(self.mount.T_base_camera)
        yaw = T_world_base.theta()
        p_xy = np.array([T_world_camera.x(), T_world_camera.y()])
        shape = (self.camera.height, self.camera.width)
        distance, wall, along = self._wall_table(p_xy, yaw)
        # One gather from a (samples, 3) table instead of three: distance, wall, texture column.
        table = np.column_stack(
            [distance, wall, (along * _TEXELS_PER_M).astype(np.int32) & 255]
        ).astype(np.float32)
        per_pixel = np.take(table, self._table_index, axis=0)
        z = per_pixel[:, 0] * self._inverse_horizontal  # optical Z where the ray meets the wall
        hit_height = self.mount.height_m + z * self._ray_vertical
        pixel_wall = per_pixel[:, 1].astype(np.int32)
        wall_v = np.clip(hit_height * _TEXELS_PER_M, 0, 1e6).astype(np.int32) & 255
        gray = np.take(self._wall_texture, (wall_v << 8) | per_pixel[:, 2].astype(np.int32))
        plain_wall = np.ones(z.shape, dtype=bool)

        on_floor = hit_height[self._down] < 0.0
        floor = self._down[on_floor]
        z_floor = self._z_floor[on_floor]
        z[floor] = z_floor
        plain_wall[floor] = False
        c, s = math.cos(yaw), math.sin(yaw)
        ray_xy = self._down_xy[on_floor]
        floor_x = p_xy[0] + z_floor * (c * ray_xy[:, 0] - s * ray_xy[:, 1])
        floor_y = p_xy[1] + z_floor * (s * ray_xy[:, 0] + c * ray_xy[:, 1])
        texel_x = (floor_x * _TEXELS_PER_M).astype(np.int32) & 255
        texel_y = (floor_y * _TEXELS_PER_M).astype(np.int32) & 255
        gray[floor] = np.take(self._floor_texture, (texel_y << 8) | texel_x)
        on_ceiling = hit_height[self._up] > self.ceiling_m
        ceiling = self._up[on_ceiling]
        z[ceiling] = self._z_ceiling[on_ceiling]
        plain_wall[ceiling] = False
        gray[ceiling] = 215.0
        z[~np.isfinite(z)] = 0.0

        gray = gray.reshape(shape)
        drawn = self._draw_markers(
            gray, T_world_base, pixel_wall.reshape(shape), plain_wall.reshape(shape)
        )
        if exposure != 1.0:
            gray *= exposure
        if self.effects.blur_sigma_px > 0:
            gray = cv2.GaussianBlur(gray, (0, 0), self.effects.blur_sigma_px)
        gray += self._image_noise[noise.image_field]
        image = np.clip(gray, 0, 255).astype(np.uint8)
        depth_mm = self._noisy_depth(z.reshape(shape), noise)
        if self._distortion_maps is not None:
            # Drawn through the ideal pinhole; the lens then bends both images alike.
            map_x, map_y = self._distortion_maps
            image = cv2.remap(
                image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
            )
            depth_mm = np.asarray(
                cv2.remap(depth_mm, map_x, map_y, cv2.INTER_NEAREST), dtype=np.uint16
            )
        rgb = cv2.cvtColor(image, cv2.COLOR_GRAY2RGB)
        return RenderedFrame(rgb, depth_mm, drawn)

    def _draw_markers(
        self,
        gray: NDArray[np.float32],
        T_world_base: gtsam.Pose2,
        pixel_wall: NDArray[np.intp],
        plain_wall: NDArray[np.bool_],
    ) -> tuple[int, ...]:
        """Composite every marker facing the camera into ``gray``; returns the drawn ids."""
        drawn = []
        for index, pixels in self._markers_in_view(T_world_base):
            marker_id = int(self._geometry.ids[index])
            if self._draw_marker(gray, marker_id, pixels, pixel_wall, plain_wall):
                drawn.append(marker_id)
        return tuple(drawn)

    def _markers_in_view(self, T_world_base: gtsam.Pose2) -> list[tuple[int, NDArray[np.float32]]]:
        """The markers that face the camera and overlap the image: (index in the geometry,
        (4, 2) its black square's corners in pixels, TL, TR, BR, BL)."""
        T_world_camera = T_world_base.compose(self.mount.T_base_camera)
        p_camera = np.array([T_world_camera.x(), T_world_camera.y()])
        width, height = self.camera.width, self.camera.height
        geometry = self._geometry
        # The camera in front of each marker (not behind its wall, nor edge-on)?
        offset = p_camera - geometry.poses[:, :2]
        in_front = (
            np.cos(geometry.poses[:, 2]) * offset[:, 0]
            + np.sin(geometry.poses[:, 2]) * offset[:, 1]
        ) > 0.05
        candidates = np.flatnonzero(in_front)
        if candidates.size == 0:
            return []
        optical = self.mount.world_to_optical(
            T_world_base, geometry.corners[candidates].reshape(-1, 3)
        ).reshape(-1, 4, 3)
        # Keep markers wholly in front of the camera whose outline (with a margin for the white
        # border) overlaps the image; the rest cost a warp each for nothing.
        in_front_of_camera = np.all(optical[:, :, 2] >= 0.05, axis=1)
        optical, candidates = optical[in_front_of_camera], candidates[in_front_of_camera]
        projected = self.camera.project(optical.reshape(-1, 3)).reshape(-1, 4, 2)
        low, high = projected.min(axis=1), projected.max(axis=1)
        margin = 0.5 * (high - low).max(axis=1, keepdims=True)
        overlaps = np.all((high + margin >= 0) & (low - margin <= [width, height]), axis=1)
        return list(zip(candidates[overlaps], projected[overlaps].astype(np.float32), strict=True))

    def _draw_marker(
        self,
        gray: NDArray[np.float32],
        marker_id: int,
        pixels: NDArray[np.float32],
        pixel_wall: NDArray[np.intp],
        plain_wall: NDArray[np.bool_],
    ) -> bool:
        """Composite one marker's sheet, its black square at ``pixels``, into ``gray`` where
        its own wall shows; False if none of it does."""
        width, height = self.camera.width, self.camera.height
        side = max(
            np.linalg.norm(pixels[0] - pixels[3]),
            np.linalg.norm(pixels[1] - pixels[2]),
            np.linalg.norm(pixels[0] - pixels[1]),
        )
        level = next(
            (i for i, s in enumerate(_MARKER_LEVELS) if s >= side / 2.0),
            len(_MARKER_LEVELS) - 1,
        )
        sheet, border = self._sheets[marker_id][level]
        H = cv2.getPerspectiveTransform(_square_corners(border, _MARKER_LEVELS[level]), pixels)
        far = sheet.shape[0] - 0.5
        sheet_outline = np.array(
            [[[-0.5, -0.5], [far, -0.5], [far, far], [-0.5, far]]], dtype=np.float32
        )
        outline = cv2.perspectiveTransform(sheet_outline, H)[0]
        x0, y0 = np.floor(outline.min(axis=0)).astype(int)
        x1, y1 = np.ceil(outline.max(axis=0)).astype(int) + 1
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, width), min(y1, height)
        if x0 >= x1 or y0 >= y1:
            return False
        shift = np.array([[1, 0, -x0], [0, 1, -y0], [0, 0, 1]], dtype=np.float64)
        with_mask = np.dstack([sheet, np.full_like(sheet, 255)])
        warped = cv2.warpPerspective(
            with_mask,
            shift @ H,
            (x1 - x0, y1 - y0),
            flags=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=0,
        )
        coverage = warped[..., 1].astype(np.float32) / 255.0
        on_its_wall = plain_wall[y0:y1, x0:x1] & (
            pixel_wall[y0:y1, x0:x1] == self._marker_walls[marker_id]
        )
        coverage *= on_its_wall
        if not coverage.any():
            return False
        # Printed paper: black ink at ~25, white at ~235 grey levels.
        ink = 25.0 + warped[..., 0].astype(np.float32) * (210.0 / 255.0)
        region = gray[y0:y1, x0:x1]
        region += coverage * (ink - region)
        return True

    def _noisy_depth(self, z: NDArray[np.float32], drawn: FrameNoise) -> NDArray[np.uint16]:
        noise = self.depth_noise
        size = (self.camera.width, self.camera.height)
        # One draw per block, spread over the block: the matcher's error is correlated.
        field = cv2.resize(
            drawn.depth_field.astype(np.float32), size, interpolation=cv2.INTER_NEAREST
        )
        dropped = cv2.resize(
            (drawn.depth_dropped < noise.dropout).astype(np.uint8),
            size,
            interpolation=cv2.INTER_NEAREST,
        ).astype(bool)
        # In place, in millimetres: z + (base + k z^2) * field, rounded by adding 0.5.
        noisy = z * z
        noisy *= noise.per_m2
        noisy += noise.base_m
        noisy *= field
        noisy += z
        noisy *= 1000.0
        noisy += 0.5
        noisy[(z <= 0.0) | (z > noise.max_range_m) | dropped] = 0.0
        return noisy.astype(np.uint16)


def _square_corners(border: int, n: int) -> NDArray[np.float32]:
    """A marker sheet's black-square corners, TL, TR, BR, BL, in its own pixels (pixel centres
    at integers, so the square spans [border - 0.5, border + n - 0.5])."""
    return np.array(
        [
            [border - 0.5, border - 0.5],
            [border + n - 0.5, border - 0.5],
            [border + n - 0.5, border + n - 0.5],
            [border - 0.5, border + n - 0.5],
        ],
        dtype=np.float32,
    )


def frames_with_true_corners(
    scene: str, dictionary: str, seconds: float, blur_px: float = 0.7, frame_hz: float = 2.0
) -> list[tuple[NDArray[np.uint8], dict[int, NDArray[np.float64]]]]:
    """A scenario driven for ``seconds`` with every marker in ``dictionary``, each frame as the
    log writer encodes it (JPEG 90) and the front end decodes it (grey), with the true corners
    (4, 2) in OpenCV's order of every marker drawn in it, by id."""
    world, route = scenario(scene)
    markers = tuple(replace(m, dictionary=dictionary) for m in world.markers)
    world = replace(world, markers=markers)
    renderer = Renderer(world, effects=ImageEffects(blur_sigma_px=blur_px))
    rng = np.random.default_rng(0)
    frames = []
    for pose in drive(world, route, rng, frame_hz=frame_hz, duration_s=seconds).frame_poses:
        T_world_base = gtsam.Pose2(*pose)
        frame = renderer.render(T_world_base, rng)
        _, jpeg = cv2.imencode(
            ".jpg", cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 90]
        )
        grey = np.asarray(cv2.imdecode(jpeg, cv2.IMREAD_GRAYSCALE), dtype=np.uint8)
        truth = {
            i: renderer.camera.project(
                renderer.mount.world_to_optical(T_world_base, world.marker_corners(i))
            )
            for i in frame.drawn_ids
        }
        frames.append((grey, truth))
    return frames
