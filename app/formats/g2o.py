"""The solved pose graph in g2o's text format."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import gtsam
import numpy as np
from numpy.typing import NDArray

from markergraph.common.errors import MarkerGraphError
from markergraph.common.files import written_whole
from markergraph.estimator.tags3d import quaternion_wxyz

__all__ = ["MARKER_VERTEX_OFFSET", "write_g2o", "write_g2o_3d"]

# g2o has one id space: marker vertices start here so they never meet robot poses.
MARKER_VERTEX_OFFSET = 1_000_000


def _information(model: Any) -> NDArray[np.float64]:
    """The information matrix of a Gaussian noise model (or a robust one's Gaussian part)."""
    gaussian: Any = model.noise() if isinstance(model, gtsam.noiseModel.Robust) else model
    R = np.asarray(gaussian.R())  # square-root information
    return np.asarray(R.T @ R)


def _vertex(key: int) -> int:
    symbol = gtsam.Symbol(key)
    index = int(symbol.index())
    return index + MARKER_VERTEX_OFFSET if chr(symbol.chr()) == "l" else index


def write_g2o(path: Path, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> None:
    """A solved pose graph in g2o's text format, whole or not at all.

    Robot poses ``X(k)`` become ``VERTEX_SE2 k`` and markers ``L(id)`` become
    ``VERTEX_SE2 1000000+id``; every between factor an ``EDGE_SE2`` with its full information
    matrix; full float precision. There is no header comment and no ``FIX`` line, because
    ``gtsam.readG2o`` returns no factors for such files (the home prior is left out with them:
    fix the home vertex when re-optimising). Unlike ``gtsam.writeG2o``, ids of robot poses and
    markers never collide and nothing is rounded.

    Raises:
        MarkerGraphError: a pose is NaN or infinite (never written).
    """
    lines = []
    for key in sorted(values.keys(), key=_vertex):
        pose = values.atPose2(key)
        if not all(math.isfinite(v) for v in (pose.x(), pose.y(), pose.theta())):
            raise MarkerGraphError(f"{path}: refusing to write a non-finite pose ({pose})")
        lines.append(f"VERTEX_SE2 {_vertex(key)} {pose.x()!r} {pose.y()!r} {pose.theta()!r}")
    for index in range(graph.size()):
        factor: Any = graph.at(index)
        if not isinstance(factor, gtsam.BetweenFactorPose2):
            continue
        measured = factor.measured()
        info = _information(factor.noiseModel())
        keys = factor.keys()  # a gtsam KeyVector
        upper = [info[0, 0], info[0, 1], info[0, 2], info[1, 1], info[1, 2], info[2, 2]]
        lines.append(
            f"EDGE_SE2 {_vertex(keys[0])} {_vertex(keys[1])} {measured.x()!r} {measured.y()!r} "
            f"{measured.theta()!r} " + " ".join(repr(float(v)) for v in upper)
        )
    with written_whole(path) as partial:
        partial.write_text("\n".join(lines) + "\n", encoding="utf-8")


def _se3(T: gtsam.Pose3) -> str:
    """``x y z qx qy qz qw`` at full precision."""
    t, (w, x, y, z) = T.translation(), quaternion_wxyz(T.rotation())
    values = [*(float(v) for v in t), x, y, z, w]
    return " ".join(repr(v) for v in values)


def write_g2o_3d(
    path: Path,
    rig_poses: Sequence[gtsam.Pose3],
    tags: Mapping[int, gtsam.Pose3],
    views: Sequence[tuple[int, int, gtsam.Pose3, NDArray[np.float64]]] = (),
) -> None:
    """A 3-D map in g2o's text format, whole or not at all: each rig pose ``k`` as
    ``VERTEX_SE3:QUAT k``, each tag as ``VERTEX_SE3:QUAT 1000000+id`` (``x y z qx qy qz qw``,
    full precision), and each of ``views`` (rig frame index, tag id, ``T_rig_tag``, its 6x6
    information over g2o's (translation, rotation) tangent) as ``EDGE_SE3:QUAT``. No header
    comment and no ``FIX`` line, for ``gtsam.readG2o``'s sake (see :func:`write_g2o`).

    Raises:
        MarkerGraphError: a pose is NaN or infinite (never written).
    """
    lines = []
    vertices = [(k, T) for k, T in enumerate(rig_poses)]
    vertices += [(MARKER_VERTEX_OFFSET + i, T) for i, T in sorted(tags.items())]
    for vertex, T in vertices:
        if not np.all(np.isfinite(T.matrix())):
            raise MarkerGraphError(f"{path}: refusing to write a non-finite pose ({vertex})")
        lines.append(f"VERTEX_SE3:QUAT {vertex} {_se3(T)}")
    for frame, tag_id, T_rig_tag, information in views:
        upper = [float(information[i, j]) for i in range(6) for j in range(i, 6)]
        lines.append(
            f"EDGE_SE3:QUAT {frame} {MARKER_VERTEX_OFFSET + tag_id} {_se3(T_rig_tag)} "
            + " ".join(repr(v) for v in upper)
        )
    with written_whole(path) as partial:
        partial.write_text("\n".join(lines) + "\n", encoding="utf-8")
