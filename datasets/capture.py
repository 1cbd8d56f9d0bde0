"""One camera frame as the sensors take it: rendered at each row's readout time under a rolling
shutter, smeared by the turn during the exposure, depth scaled and holed."""

from __future__ import annotations

import numpy as np

from markergraph.datasets.render import FrameNoise, RenderedFrame, Renderer
from markergraph.datasets.sensors import (
    SensorEffects,
    black_cells_without_depth,
    motion_smear,
    shutter_offsets,
)
from markergraph.estimator.trajectory import Trajectory

__all__ = ["capture", "draw_capture_noise"]


def draw_capture_noise(
    renderer: Renderer, sensors: SensorEffects, rng: np.random.Generator
) -> FrameNoise:
    """One frame's noise, drawn from ``rng`` as :func:`capture` draws it: every render of a
    rolling shutter's frame draws the same noise, from a seed of its own (the global shutter's
    single render draws from ``rng`` itself, as it always has)."""
    if len(shutter_offsets(sensors.rolling_shutter_s)) == 1:
        return renderer.draw_noise(rng)
    return renderer.draw_noise(np.random.default_rng(int(rng.integers(2**63))))


def capture(
    renderer: Renderer,
    truth: Trajectory,
    t_ns: int,
    sensors: SensorEffects,
    noise: FrameNoise | np.random.Generator,
    exposure: float = 1.0,
) -> RenderedFrame:
    """One frame whose top row is captured at ``t_ns``, as the sensors take it: each row at its
    readout time, smeared by the turn during the exposure, depth scaled and holed.

    Under a rolling shutter the frame is rendered at :func:`shutter_offsets` and each row blended
    linearly from the two renders about its time (a shift of under a pixel between them blends
    into a shifted edge), so a marker's edges are straight skewed lines, not a staircase of
    bands; every render draws the same noise. Depth is the nearer render's row.

    ``noise``: the frame's noise (:func:`draw_capture_noise`), or the generator to draw it from.
    """
    offsets = shutter_offsets(sensors.rolling_shutter_s)
    if isinstance(noise, np.random.Generator):
        noise = draw_capture_noise(renderer, sensors, noise)
    renders = []
    for after_s in offsets:
        t_render = t_ns + round(after_s * 1e9)
        pose = truth.at(t_render)
        if pose is None:
            raise ValueError(f"no true pose at {t_render} ns to render")
        frame = renderer.render(pose, noise, exposure)
        if sensors.exposure_s > 0:
            # The turn's smear (a translation's is left out: it is a fraction of it here).
            rate = _yaw_rate(truth, t_render + round(sensors.exposure_s * 5e8))
            length_px = abs(rate) * sensors.exposure_s * renderer.camera.fx
            frame = RenderedFrame(
                motion_smear(frame.rgb, length_px), frame.depth_mm, frame.drawn_ids
            )
        renders.append(frame)
    if len(renders) == 1:
        rgb, depth = renders[0].rgb, renders[0].depth_mm.copy()
    else:
        height = renderer.camera.height
        position = np.arange(height) / height * (len(renders) - 1)  # in render intervals
        first = np.floor(position).astype(int)
        weight = (position - first)[:, None, None]
        stack = np.stack([r.rgb for r in renders])
        rows = np.arange(height)
        before, after = stack[first, rows].astype(np.float32), stack[first + 1, rows]
        blended = (1.0 - weight) * before + weight * after
        rgb = np.clip(np.rint(blended), 0, 255).astype(np.uint8)
        nearer = first + (weight[:, 0, 0] >= 0.5)
        depth = np.stack([r.depth_mm for r in renders])[nearer, rows]
    if sensors.depth_scale != 1.0:
        scaled = np.rint(depth.astype(np.float64) * sensors.depth_scale)
        depth = np.clip(scaled, 0, 65535).astype(np.uint16)
    if sensors.black_cells_without_depth:
        depth = black_cells_without_depth(rgb, depth)
    drawn = sorted(set().union(*(r.drawn_ids for r in renders)))
    return RenderedFrame(rgb, depth, tuple(drawn))


def _yaw_rate(truth: Trajectory, t_ns: int, half_window_ns: int = 10_000_000) -> float:
    """The true turn rate about ``t_ns`` [rad/s]."""
    before, after = truth.at(t_ns - half_window_ns), truth.at(t_ns + half_window_ns)
    if before is None or after is None:
        return 0.0
    return before.between(after).theta() / (2 * half_window_ns * 1e-9)
