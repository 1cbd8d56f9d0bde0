"""Accuracy of the four yaw methods on rendered frames, against ground truth.

Renders the paper-room and office routes at 3 Hz, detects every marker, and compares theta,
range and bearing of each observation with the simulator's truth, by distance band, for
markers seen at |theta| >= 15 degrees.

Usage: python tests/benchmarks/yaw_methods.py
"""

from __future__ import annotations

import math

import gtsam
import numpy as np

from markergraph.datasets import scenario
from markergraph.datasets.render import Renderer
from markergraph.datasets.route import drive
from markergraph.frontend.detect import Detector
from markergraph.frontend.observe import ObservationModel, observe_detections
from markergraph.frontend.sizes import MarkerSizes
from markergraph.frontend.yaw import YawMethod


def main() -> None:
    rows: dict[YawMethod, list[tuple[float, ...]]] = {method: [] for method in YawMethod}
    for name in ("paper-room", "office"):
        world, route = scenario(name)
        renderer = Renderer(world)
        rng = np.random.default_rng(0)
        detector = Detector(allowed_ids=[m.id for m in world.markers])
        for pose in drive(world, route, rng, frame_hz=3.0).frame_poses:
            T_world_base = gtsam.Pose2(*pose)
            frame = renderer.render(T_world_base, rng)
            detections = detector.detect(frame.rgb)
            T_camera = T_world_base.compose(renderer.mount.T_base_camera)
            for method in YawMethod:
                for obs in observe_detections(
                    detections,
                    renderer.camera,
                    ObservationModel(MarkerSizes(0.2), method=method),
                    depth=frame.depth_mm,
                    mount=renderer.mount,
                ):
                    T_marker = world.T_world_marker(obs.marker_id)
                    local = T_marker.transformTo(T_camera.translation())
                    seen = T_camera.transformTo(T_marker.translation())
                    theta = math.atan2(local[1], local[0])
                    rows[method].append(
                        (
                            math.hypot(*local),
                            theta,
                            abs(obs.theta - theta),
                            abs(obs.range_m - math.hypot(*local)),
                            abs(obs.bearing - math.atan2(seen[1], seen[0])),
                        )
                    )
    print("method       band    n   median |theta err|  median range err  median bearing err")
    for method, values in rows.items():
        table = np.array(values)
        for low, high in ((0.0, 2.0), (2.0, 3.0)):
            band = (
                (table[:, 0] >= low)
                & (table[:, 0] < high)
                & (np.abs(table[:, 1]) >= math.radians(15.0))
            )
            print(
                f"{method.value:<12} {low:.0f}-{high:.0f} m {band.sum():>4} "
                f"{math.degrees(np.median(table[band, 2])):>14.2f} deg "
                f"{np.median(table[band, 3]) * 1000:>12.1f} mm "
                f"{math.degrees(np.median(table[band, 4])):>14.3f} deg"
            )


if __name__ == "__main__":
    main()
