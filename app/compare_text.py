"""``markergraph compare``'s figures as text a person reads and as a JSON document (the
comparison itself: :mod:`markergraph.compare`)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from markergraph.common.numbers import shown
from markergraph.compare import Comparison, Figures, Scored

__all__ = ["COMPARE_SCHEMA", "comparison_document", "comparison_lines", "plot_title", "summary"]

COMPARE_SCHEMA = "markergraph.compare/1"


def plot_title(map_path: Path, reference: Path) -> str:
    """``"map vs reference"`` by file name, or by folder and name where the names are the same
    (two ``map.json`` files)."""
    if map_path.name != reference.name:
        return f"{map_path.name} vs {reference.name}"
    return f"{map_path.parent.name}/{map_path.name} vs {reference.parent.name}/{reference.name}"


def _ids(ids: tuple[int, ...]) -> str:
    return ", ".join(map(str, ids)) if ids else "none"


def _cell(value: float, digits: int) -> str:
    return "-" if not math.isfinite(value) else shown(value, f".{digits}f")


def _figure_text(name: str, figures: Figures, unit: str, digits: int) -> str:
    return (
        f"{name} RMSE {figures.rmse:.{digits}f} {unit}, median {figures.median:.{digits}f} "
        f"{unit}, max {figures.max:.{digits}f} {unit}"
    )


def summary(scored: Scored) -> str:
    """One line of figures: position, and yaw and rotation where any marker has them."""
    parts = [_figure_text("position", scored.position, "m", 4)]
    if scored.yaw.n:
        parts.append(_figure_text("yaw", scored.yaw, "deg", 2))
    if scored.rotation.n:
        parts.append(_figure_text("rotation", scored.rotation, "deg", 2))
    return "; ".join(parts)


def _coverage(scored: Scored) -> str:
    share = 100.0 * scored.n_within / scored.n_nees
    mean = float(np.nanmean(scored.nees))
    return f"{scored.n_within} of {scored.n_nees} ({share:.0f} %), mean NEES {mean:.2f}"


def _coverage_line(aligned: Scored, home_fixed: Scored | None, dimensions: int) -> str:
    """The map's covariances against the errors, in one line: markers within their 95 %
    ellipse (ellipsoid in 3-D) and the mean position NEES, after each alignment."""
    if aligned.n_nees == 0:
        return "covariance: the map gives none of the common markers one"
    shape = "ellipse" if dimensions == 2 else "ellipsoid"
    line = f"covariance: within their 95 % {shape} (NEES expected {dimensions}): aligned "
    line += _coverage(aligned)
    if home_fixed is not None and home_fixed.n_nees:
        line += f"; home-fixed {_coverage(home_fixed)}"
    yaws = [(name, s) for name, s in (("aligned", aligned), ("home-fixed", home_fixed))
            if s is not None and s.n_yaw_nees]  # fmt: skip
    if yaws:
        line += "; yaw within its 95 % interval: " + ", ".join(
            f"{name} {s.n_yaw_within} of {s.n_yaw_nees} "
            f"({100 * s.n_yaw_within / s.n_yaw_nees:.0f} %)"
            for name, s in yaws
        )
    return line


def _table(result: Comparison) -> list[str]:
    """One row a marker: its errors aligned and home-fixed, and the aligned NEES; the
    rotation columns in 3-D alone."""
    a, h = result.aligned, result.home_fixed
    columns: list[tuple[str, NDArray[np.float64], int]] = [
        ("aligned [m]", a.position_m, 4),
        ("yaw [deg]", a.yaw_deg, 2),
        ("rot [deg]", a.rotation_deg, 2),
    ]
    if h is not None:
        columns += [("home [m]", h.position_m, 4), ("yaw [deg]", h.yaw_deg, 2),
                    ("rot [deg]", h.rotation_deg, 2)]  # fmt: skip
    columns.append(("NEES", a.nees, 2))
    if result.dimensions == 2:
        columns = [c for c in columns if c[0] != "rot [deg]"]
    lines = [f"{'id':>6}" + "".join(f" {name:>11}" for name, _, _ in columns)]
    for k, marker_id in enumerate(result.ids):
        cells = "".join(f" {_cell(values[k], digits):>11}" for _, values, digits in columns)
        lines.append(f"{int(marker_id):>6}{cells}")
    return lines


def comparison_lines(result: Comparison) -> list[str]:
    """The comparison as text a person reads: common markers, a table, figures."""
    a, h, d = result.aligned, result.home_fixed, result.dimensions
    rotation = a.alignment
    t = rotation.t[:d]
    return [
        f"markers in common: {len(result.ids)} ({_ids(tuple(int(i) for i in result.ids))}); "
        f"only in the map: {_ids(result.only_map)}; only in the reference: "
        f"{_ids(result.only_reference)}",
        f"{d}-D comparison; alignment {rotation.how}: rotation "
        f"{shown(rotation.angle_deg, '.3f')} deg, "
        f"translation ({', '.join(shown(v, '.4f') for v in t)}) m"
        + (f", scale {rotation.scale:.6f}" if rotation.how.startswith("Sim") else ""),
        *([] if h is None else [f"home-fixed on {h.alignment.how}"]),
        *_table(result),
        f"aligned:    {summary(a)}",
        *([] if h is None else [f"home-fixed: {summary(h)}  (marker {result.home_id})"]),
        _coverage_line(a, h, d),
        *result.notes,
    ]


def _number(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def _scored_document(scored: Scored) -> dict[str, Any]:
    def figures(f: Figures) -> dict[str, Any]:
        return {"n": f.n, "rmse": _number(f.rmse), "median": _number(f.median),
                "max": _number(f.max)}  # fmt: skip

    alignment = scored.alignment
    return {
        "alignment": {
            "how": alignment.how,
            "R": [[float(v) for v in row] for row in alignment.R],
            "t_m": [float(v) for v in alignment.t],
            "scale": alignment.scale,
            "angle_deg": alignment.angle_deg,
        },
        "position_m": figures(scored.position),
        "yaw_deg": figures(scored.yaw),
        "rotation_deg": figures(scored.rotation),
        "covariance": {
            "n": scored.n_nees,
            "within_95": scored.n_within,
            "yaw_n": scored.n_yaw_nees,
            "yaw_within_95": scored.n_yaw_within,
        },
    }


def comparison_document(
    result: Comparison, map_path: str, reference_path: str, reference_kind: str
) -> dict[str, Any]:
    """The comparison as a strict-JSON-ready document (NaN as null), units in the keys."""
    a, h = result.aligned, result.home_fixed
    markers = [
        {
            "id": int(marker_id),
            "aligned": {"position_m": _number(a.position_m[k]), "yaw_deg": _number(a.yaw_deg[k]),
                        "rotation_deg": _number(a.rotation_deg[k]), "nees": _number(a.nees[k])},
            "home_fixed": None if h is None else {
                "position_m": _number(h.position_m[k]), "yaw_deg": _number(h.yaw_deg[k]),
                "rotation_deg": _number(h.rotation_deg[k]), "nees": _number(h.nees[k])},
        }
        for k, marker_id in enumerate(result.ids)
    ]  # fmt: skip
    return {
        "schema": COMPARE_SCHEMA,
        "map": map_path,
        "reference": reference_path,
        "reference_kind": reference_kind,
        "dimensions": result.dimensions,
        "common": [int(i) for i in result.ids],
        "only_map": list(result.only_map),
        "only_reference": list(result.only_reference),
        "home_id": result.home_id,
        "aligned": _scored_document(a),
        "home_fixed": None if h is None else _scored_document(h),
        "markers": markers,
        "notes": list(result.notes),
    }
