"""report.html: a result folder's report as one page a person opens, self-contained (figures
inlined as PNG data, CSS inline, no script, nothing fetched: a Content-Security-Policy forbids it).

The page is drawn from the same dictionary that ``report.json`` is written from, plus the
figures (top-level ``*.png``) of the folder. Keys it does not know are shown generically, so a
figure or a report key added later (``diagnostics.png``, a ``diagnostics`` section) appears
without a change here: a scalar in the summary or the log table, anything else in a section of
its own. Every string from the report is escaped with :func:`html.escape`.
"""

from __future__ import annotations

import base64
import html
import json
import math
import struct
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from markergraph.common.files import written_whole
from markergraph.common.numbers import shown

__all__ = ["FIGURE_ORDER", "REPORT_PAGE", "figures_in", "render_report_page", "write_report_page"]

REPORT_PAGE = "report.html"
FIGURE_ORDER = ("map.png", "comparison.png", "diagnostics.png")  # then any other, by name
_CAPTIONS = {
    "map.png": "The map of the first method: markers with their normals and 2-sigma ellipses, "
    "the estimated trajectory, the odometry and, when logged, the true markers (grey crosses) "
    "and path (dashed), in the home marker's frame.",
    "comparison.png": "Every method's map side by side (each method's own figure is in "
    "methods/<method>/map.png).",
    "diagnostics.png": "Residual diagnostics; the figures behind it are under Diagnostics by "
    "method below.",
}
_CAPTIONS_3D = {
    "map.png": "The 3-D map: a top view and a side view, each tag's square with its normal, "
    "surveyed tags in red, the rig's path and, when known, the true tags (grey) after a rigid "
    "alignment.",
}
_CAPTIONS_LOCALIZE = {
    "map.png": "The saved map (markers with their normals and 2-sigma ellipses), the path "
    "localised in it (green), the logged truth when there is one (dashed) and each marker that "
    "moved since the map was made as a red arrow from the map's place to where this log saw it, "
    "in the map's home-marker frame.",
}
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
MAX_ROWS = 200  # a generic table longer than this is cut, saying how much is left in report.json
MAX_ITEMS = 50  # the same for a list of plain values

# The method table: report.json's key, column header, unit (None: a count or a word).
_METHOD_COLUMNS: tuple[tuple[str, str, str | None], ...] = (
    ("markers_placed", "markers", None),
    ("links", "links", None),
    ("unplaced", "unplaced", None),
    ("converged", "converged", None),
    # Aligned first: what evo and other mappers report; home-fixed carries the home marker's
    # own error to the far markers.
    ("marker_rmse_aligned_m", "aligned RMSE", "m"),
    ("marker_rmse_m", "home-fixed RMSE", "m"),
    ("marker_yaw_rmse_rad", "yaw RMSE", "°"),
    ("ate_aligned_m", "ATE aligned", "m"),
    ("ate_m", "ATE home-fixed", "m"),
    ("ate_poses", "ATE poses", None),
    ("rpe_m_per_m", "RPE", "m/m"),
)
_METHOD_SECTIONS = (
    "notes",
    "unplaced",
    "verdict",
    "verdict_reasons",
)  # per-method keys shown in the notes, not as columns
# The log table: report.json's key and its label, in this order.
_LOG_ROWS: tuple[tuple[str, str], ...] = (
    ("log", "log"),
    ("frames", "frames"),
    ("frames_with_depth", "frames with depth"),
    ("observations", "observations"),
    ("markers_seen", "markers seen"),
    ("odometry_samples", "odometry samples"),
    ("odometry_source", "odometry noise model"),
    ("odometry_scale", "odometry scale applied"),
    ("odometry_scale_sigma", "odometry scale's sigma (SLAM's residuals)"),
    ("odometry_turn_scale", "odometry turn scale"),
    ("odometry_turn_scale_sigma", "odometry turn scale's sigma (SLAM's residuals)"),
    ("camera_delay_ms", "camera delay against odometry [ms]"),
    ("camera_delay_sigma_ms", "camera delay's sigma (SLAM's residuals) [ms]"),
    ("depth_scale", "depth scale applied"),
    ("measured_depth_scale", "depth scale measured"),
    ("depth_scale_sigma", "depth scale's sigma (the markers' size)"),
    ("levelled_frames", "frames levelled by the odometry's attitude"),
    ("undecodable_frames", "undecodable frames"),
    ("unusable_depth_images", "unusable depth images"),
    ("skipped_frames", "skipped frames"),
    ("ground_truth", "ground truth logged"),
    ("schema", "report schema"),
)
# Top-level keys with a section of their own above; any other key is shown generically.
_OWN_SECTIONS = {"methods", "notes", "settings", "seconds", "files", "verdict", "verdict_reasons"}
# Unit suffixes of report keys: suffix, unit shown, factor to the unit shown, format.
_UNITS: tuple[tuple[str, str, float, str], ...] = (
    ("_m_per_m", "m/m", 1.0, ".3f"),
    ("_rad", "°", math.degrees(1.0), ".2f"),  # radians inside, degrees in text a person reads
    ("_deg", "°", 1.0, ".2f"),
    ("_ms", "ms", 1.0, ".3g"),
    ("_ns", "ms", 1e-6, ".3g"),
    ("_px", "px", 1.0, ".3g"),
    ("_hz", "Hz", 1.0, ".3g"),
    ("_s", "s", 1.0, ".3g"),
    ("_m", "m", 1.0, ".3f"),
    ("_share", "%", 100.0, ".0f"),
)
# Keys whose unit is not a plain suffix: their header and unit as a person reads them.
_LABELS: dict[str, tuple[str, str | None]] = {
    "xy_variance_per_m": ("xy variance per metre travelled", "m²/m"),
}
# Units inside a key (``marker_size_m_used``): the key's words without it, and the unit.
_INFIX_UNITS: tuple[tuple[str, str], ...] = (("_m_", "m"),)
_ACRONYMS = {
    "rmse": "RMSE",
    "rms": "RMS",
    "ate": "ATE",
    "rpe": "RPE",
    "nees": "NEES",
    "nis": "NIS",
    "t": "time",
    "ids": "ids",
}

_CSS = """
:root { color-scheme: light; --ink: #1d232b; --muted: #5b6470; --line: #d8dde3;
  --band: #f3f5f8; --accent: #1f5fa8; --warn: #8a4b00;
  --ok: #2e7d32; --bad: #b3261e; }
* { box-sizing: border-box; }
body { margin: 0; background: #fff; color: var(--ink);
  font: 15px/1.5 system-ui, -apple-system, "Segoe UI", Roboto, "Helvetica Neue", Arial,
  sans-serif; }
main { max-width: 1180px; margin: 0 auto; padding: 24px 28px 48px; }
h1 { font-size: 24px; margin: 0 0 4px; }
h2 { font-size: 18px; margin: 32px 0 10px; padding-bottom: 4px;
  border-bottom: 2px solid var(--line); }
h3 { font-size: 15px; margin: 18px 0 6px; }
p.lead { color: var(--muted); margin: 0 0 8px; }
table { border-collapse: collapse; margin: 4px 0 8px; font-variant-numeric: tabular-nums; }
th, td { padding: 5px 10px; border-bottom: 1px solid var(--line); text-align: left;
  vertical-align: top; }
thead th { background: var(--band); font-weight: 600; border-bottom: 2px solid var(--line);
  vertical-align: bottom; }
tbody th { white-space: nowrap; }
td.num, th.num { text-align: right; }
td.num { white-space: nowrap; }
td.best { font-weight: 700; color: var(--accent); }
tbody tr:nth-child(even) > * { background: #fafbfc; }
table.keys th { font-weight: 500; color: var(--muted); white-space: nowrap; }
.scroll { overflow-x: auto; }
.pair { display: flex; flex-wrap: wrap; gap: 0 32px; align-items: flex-start; }
ul.notes { padding-left: 20px; margin: 4px 0; }
ul.notes li { margin: 3px 0; }
ul.notes .who { font-weight: 600; }
ul.files { columns: 3 240px; padding-left: 20px; margin: 4px 0;
  font-family: ui-monospace, "DejaVu Sans Mono", Menlo, Consolas, monospace; font-size: 13px; }
figure { margin: 12px 0 24px; }
figure img { display: block; max-width: 100%; height: auto; border: 1px solid var(--line); }
figure.wide { overflow-x: auto; }
figure.wide img { max-width: none; }
figcaption { color: var(--muted); font-size: 13px; margin-top: 6px; }
code { font-family: ui-monospace, "DejaVu Sans Mono", Menlo, Consolas, monospace;
  font-size: 13px; }
details { margin: 6px 0; }
details > summary { font-weight: 600; cursor: pointer; padding: 4px 0; }
.muted { color: var(--muted); }
.more { color: var(--warn); font-style: italic; }
.verdict { border: 1px solid var(--line); border-left: 6px solid var(--ok); padding: 8px 14px;
  margin: 12px 0 20px; background: var(--band); }
.verdict.suspect { border-left-color: var(--warn); }
.verdict.failed { border-left-color: var(--bad); }
.verdict .word { font-weight: 700; text-transform: uppercase; letter-spacing: 0.04em; }
.verdict ul { margin: 4px 0; padding-left: 20px; }
"""


def figures_in(folder: Path) -> dict[str, bytes]:
    """The folder's top-level PNG figures, :data:`FIGURE_ORDER` first and then by name; files
    that are not PNG data are left out.

    Args:
        folder: a result folder.

    Returns:
        File name -> PNG bytes, in the order the page shows them.
    """
    found = {p.name: p for p in Path(folder).glob("*.png") if p.is_file()}
    names = [n for n in FIGURE_ORDER if n in found] + sorted(set(found) - set(FIGURE_ORDER))
    figures = {}
    for name in names:
        data = found[name].read_bytes()
        if data.startswith(_PNG_SIGNATURE):
            figures[name] = data
    return figures


def write_report_page(path: Path, report: Mapping[str, Any], folder: Path) -> None:
    """``report.html``, written whole or not at all, with the figures that ``folder`` holds.

    Args:
        path: where to write the page (normally ``folder / "report.html"``).
        report: the dictionary ``report.json`` is written from.
        folder: the result folder whose top-level PNG figures are inlined.
    """
    text = render_report_page(report, figures_in(folder))
    with written_whole(Path(path)) as partial:
        partial.write_text(text, encoding="utf-8")


def render_report_page(report: Mapping[str, Any], figures: Mapping[str, bytes]) -> str:
    """The page's HTML text.

    Args:
        report: the dictionary ``report.json`` is written from (``methods``, ``notes``,
            ``settings``, ``seconds``, ``files`` and the log's figures; any other key is shown
            generically).
        figures: file name -> PNG bytes, shown in this order.

    Returns:
        One HTML document that needs nothing but itself.
    """
    log = str(report.get("log", ""))
    command = "localize" if report.get("command") == "localize" else "map"
    title = f"markergraph {command}: {Path(log).name}" if log else f"markergraph {command}"
    body = [
        f"<h1>{_esc(title)}</h1>",
        f'<p class="lead">{_esc(_lead(report))}</p>',
        _verdict_section(report),
        _methods_section(report),
        _notes_section(report),
        _figures_section(figures, _captions(report)),
        *_method_sections(report),
        *_generic_sections(report),
        _log_section(report),
        _settings_section(report.get("settings"), report.get("camera_mount")),
        _files_section(report.get("files")),
    ]
    return (
        "<!DOCTYPE html>\n"
        '<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        # Nothing may be fetched: only inline styles and data: images load.
        '<meta http-equiv="Content-Security-Policy" content="default-src \'none\'; '
        "img-src data:; style-src 'unsafe-inline'\">\n"
        '<meta name="viewport" content="width=device-width, initial-scale=1">\n'
        f"<title>{_esc(title)}</title>\n<style>{_CSS}</style>\n</head>\n<body>\n<main>\n"
        + "\n".join(part for part in body if part)
        + "\n</main>\n</body>\n</html>\n"
    )


def _captions(report: Mapping[str, Any]) -> Mapping[str, str]:
    """The figures' captions for the command and kind of map that wrote the report."""
    if report.get("command") == "localize":
        return _CAPTIONS_LOCALIZE
    return _CAPTIONS_3D if report.get("dimensions") == 3 else _CAPTIONS


# --- sections -------------------------------------------------------------------------------


def _lead(report: Mapping[str, Any]) -> str:
    parts = [
        f"{_plain(report[key])} {key}"
        for key in ("frames", "observations", "views", "poses")
        if _is_number(report.get(key))
    ]
    if _is_number(report.get("markers_seen")):
        parts.append(f"{_plain(report['markers_seen'])} markers seen")
    if "ground_truth" in report:
        parts.append(
            "scored against the logged ground truth"
            if report["ground_truth"]
            else "no ground truth in the log: counts only"
        )
    return "; ".join(parts)


_VERDICT_WORDS = {
    "ok": "nothing in the run's own evidence speaks against it",
    "suspect": "the evidence below speaks against it: check before you rely on it",
    "failed": "do not use it",
}


def _verdict_section(report: Mapping[str, Any]) -> str:
    """The run's verdict first, then each method's with its reasons: what a reader must see
    before any figure."""
    verdict = report.get("verdict")
    if verdict not in _VERDICT_WORDS:
        return ""
    methods = report.get("methods")
    rows = []
    if not isinstance(methods, Mapping):
        methods = {}
    for label, entry in methods.items():
        if not isinstance(entry, Mapping) or entry.get("verdict") not in _VERDICT_WORDS:
            continue
        reasons = "".join(
            f"<li>{_esc(str(r))}</li>" for r in _as_list(entry.get("verdict_reasons"))
        )
        rows.append(
            f"<li><b>{_esc(str(label))}</b>: {_esc(str(entry['verdict']))}"
            + (f"<ul>{reasons}</ul>" if reasons else "")
            + "</li>"
        )
    return (
        f'<section class="verdict {_esc(str(verdict))}" id="verdict"><p><span class="word">'
        f"{_esc(str(verdict))}</span>: {_esc(_VERDICT_WORDS[str(verdict)])}.</p>"
        + (f"<ul>{''.join(rows)}</ul>" if rows else "")
        + "</section>"
    )


def _methods_section(report: Mapping[str, Any]) -> str:
    methods = report.get("methods")
    if not isinstance(methods, Mapping) or not methods:
        return ""
    entries = {str(k): v for k, v in methods.items() if isinstance(v, Mapping)}
    seconds = report.get("seconds") if isinstance(report.get("seconds"), Mapping) else {}
    columns = [(k, h, u) for k, h, u in _METHOD_COLUMNS if any(k in e for e in entries.values())]
    known = {k for k, _, _ in _METHOD_COLUMNS} | set(_METHOD_SECTIONS)
    for key in _keys(entries.values()):
        if key not in known and all(_is_scalar(e.get(key)) for e in entries.values()):
            header, unit = _label_unit(key)
            columns.append((key, header, unit))
    best = {  # as shown: a tie to the last digit shown is a tie
        key: _quantity(key, _best(entries, key)) for key, _, _ in columns if _is_error(key)
    }
    head = ["<th>method</th>"] + [
        f'<th class="num">{_esc(header)}{f" [{_esc(unit)}]" if unit else ""}</th>'
        for _, header, unit in columns
    ]
    if seconds:
        head.append('<th class="num">time [s]</th>')
    rows = []
    for label, entry in entries.items():
        cells = [f"<th>{_esc(label)}</th>"]
        for key, _, _ in columns:
            value = entry.get(key)
            if key == "unplaced" and isinstance(value, Mapping):
                cells.append(_num_cell(key, len(value), str(len(value))))
                continue
            text = _quantity(key, value)
            # iSAM2 equals batch SLAM to 1e-9, not to the last bit: both are the best.
            extra = " best" if _is_number(value) and text == best.get(key) else ""
            cells.append(_num_cell(key, value, text, extra))
        if seconds:
            value = seconds.get(label)
            cells.append(_num_cell("seconds", value, _quantity("_s", value)))
        rows.append("<tr>" + "".join(cells) + "</tr>")
    caption = (
        "Markers placed and links measured between them; marker RMSE after the best rigid "
        "alignment (the map's shape alone, as evo and other mappers report it), then in the home "
        "marker's frame (home-fixed: the home marker's own error carried to the far markers); "
        "ATE (aligned, then home-fixed) and RPE of the robot's path at the odometry's rate, "
        "over the poses counted; the best of each in bold."
        if report.get("ground_truth")
        else "The log carries no ground truth: counts only."
    )
    if any(e.get("links", 0) is None or e.get("converged", True) is None for e in entries.values()):
        caption += (
            " Links: marker pairs measured together (– for the EKF, which ties its markers "
            "through its covariance alone); converged: whether an iterating solver converged "
            "(– for the closed form, computed once, and the EKF, one update a frame)."
        )
    return (
        '<h2 id="summary">Summary</h2>\n'
        f'<div class="scroll"><table class="methods"><thead><tr>{"".join(head)}</tr></thead>\n'
        f"<tbody>\n{chr(10).join(rows)}\n</tbody></table></div>\n"
        f'<p class="muted">{_esc(caption)}</p>'
    )


def _method_sections(report: Mapping[str, Any]) -> list[str]:
    """A section for each per-method key that holds more than one value (``diagnostics``,
    say), with each method's part under it."""
    methods = report.get("methods")
    if not isinstance(methods, Mapping):
        return []
    entries = {str(k): v for k, v in methods.items() if isinstance(v, Mapping)}
    known = {k for k, _, _ in _METHOD_COLUMNS} | set(_METHOD_SECTIONS)
    sections = []
    for key in _keys(entries.values()):
        if key in known or all(_is_scalar(e.get(key)) for e in entries.values()):
            continue
        # The first method open, the others folded (HTML alone, no script): five methods'
        # tables one after another bury the rest of the page.
        parts = [
            f"<details{' open' if i == 0 else ''}><summary>{_esc(label)}</summary>\n"
            f"{_value_html(key, entry[key])}</details>"
            for i, (label, entry) in enumerate((k, e) for k, e in entries.items() if key in e)
        ]
        title = f"{_label_unit(key)[0].capitalize()} by method"
        sections.append(
            f'<h2 id="method-{_esc(_anchor(key))}">{_esc(title)}</h2>\n' + "\n".join(parts)
        )
    return sections


def _notes_section(report: Mapping[str, Any]) -> str:
    items = [("", note) for note in _as_list(report.get("notes"))]
    methods = report.get("methods")
    if isinstance(methods, Mapping):
        for label, entry in methods.items():
            if not isinstance(entry, Mapping):
                continue
            items += [(str(label), note) for note in _as_list(entry.get("notes"))]
            unplaced = entry.get("unplaced")
            if isinstance(unplaced, Mapping):
                items += [
                    (str(label), f"marker {marker_id} not placed: {reason}")
                    for marker_id, reason in unplaced.items()
                ]
    if not items:
        return '<h2 id="notes">Notes</h2>\n<p class="muted">None.</p>'
    lines = [
        "<li>"
        + (f'<span class="who">{_esc(who)}:</span> ' if who else "")
        + f"{_esc(_plain(note))}</li>"
        for who, note in items
    ]
    return '<h2 id="notes">Notes</h2>\n<ul class="notes">\n' + "\n".join(lines) + "\n</ul>"


def _figures_section(figures: Mapping[str, bytes], captions: Mapping[str, str]) -> str:
    if not figures:
        return ""
    parts = ['<h2 id="figures">Figures</h2>']
    for name, data in figures.items():
        size = _png_size(data)
        width, height = size if size is not None else (0, 0)
        dims = f' width="{width}" height="{height}"' if size is not None else ""
        # A figure much wider than the page (the comparison of five methods) is shown at its
        # own size and scrolls sideways: shrunk to the page, its labels would be 6 px high.
        wide = ' class="wide"' if height and width / height > 3.0 else ""
        caption = captions.get(name, "")
        encoded = base64.b64encode(data).decode("ascii")
        parts.append(
            f"<figure{wide}>"
            f'<img src="data:image/png;base64,{encoded}" alt="{_esc(name)}"{dims}>'
            f"<figcaption><code>{_esc(name)}</code>{' ' + _esc(caption) if caption else ''}"
            f"{' (Scroll sideways.)' if wide else ''}"
            "</figcaption></figure>"
        )
    return "\n".join(parts)


def _generic_sections(report: Mapping[str, Any]) -> list[str]:
    """A section for each top-level key the page does not know that holds more than one value
    (``diagnostics``, say)."""
    known = _OWN_SECTIONS | {key for key, _ in _LOG_ROWS}
    return [
        f'<h2 id="{_esc(_anchor(key))}">{_esc(_label_unit(key)[0].capitalize())}</h2>\n'
        + _value_html(key, value)
        for key, value in report.items()
        if key not in known and not _is_scalar(value)
    ]


def _log_section(report: Mapping[str, Any]) -> str:
    rows = []
    for key, label in _LOG_ROWS:
        if key not in report:
            continue
        value = report[key]
        if key == "skipped_frames" and isinstance(value, Mapping):
            text = (
                "; ".join(f"{_plain(count)}: {reason}" for reason, count in value.items())
                if value
                else "none"
            )
            rows.append(_key_row(label, _esc(text)))
        else:
            rows.append(_key_row(label, _esc(_quantity(key, value))))
    known = _OWN_SECTIONS | {key for key, _ in _LOG_ROWS}
    for key, value in report.items():
        if key not in known and _is_scalar(value):
            header, unit = _label_unit(key)
            rows.append(
                _key_row(header + (f" [{unit}]" if unit else ""), _esc(_quantity(key, value)))
            )
    seconds = report.get("seconds")
    methods = report.get("methods")
    in_summary = set(methods) if isinstance(methods, Mapping) else set()
    if isinstance(seconds, Mapping):  # each method's own time is in the summary
        for stage, value in seconds.items():
            if stage not in in_summary:
                rows.append(_key_row(f"time: {stage} [s]", _esc(_quantity("_s", value))))
    if not rows:
        return ""
    return '<h2 id="log">The log and the run</h2>\n' + _key_table(rows)


def _settings_section(settings: Any, mount: Any = None) -> str:
    if not isinstance(settings, Mapping) or not settings:
        return ""
    source = mount.get("source") if isinstance(mount, Mapping) else None
    said = (
        f" The camera's mount (<code>camera.x</code> to <code>camera.yaw_deg</code>) is the one "
        f"used, from {_esc(str(source))}."
        if source
        else ""
    )
    rows = [_key_row(str(key), _esc(_setting(value)), code=True) for key, value in settings.items()]
    half = (len(rows) + 1) // 2
    return (
        '<h2 id="settings">Settings</h2>\n<p class="muted">Every setting the run used, as keys '
        "of a settings file (<code>--config</code>); &ldquo;&ndash;&rdquo; is not set (chosen "
        f'automatically or from the log).{said}</p>\n<div class="pair">'
        + _key_table(rows[:half])
        + _key_table(rows[half:])
        + "</div>"
    )


def _files_section(files: Any) -> str:
    names = [str(name) for name in _as_list(files)]
    if not names:
        return ""
    items = "".join(f"<li>{_esc(name)}</li>" for name in names)
    return f'<h2 id="files">Files in this folder</h2>\n<ul class="files">{items}</ul>'


# --- values ---------------------------------------------------------------------------------


def _value_html(key: str, value: Any, depth: int = 0) -> str:
    """Any JSON value as HTML: a table for a mapping, a list of records or a mapping of
    records; a list of plain values as text; a scalar with the unit its key names."""
    if _is_scalar(value):
        return _esc(_quantity(key, value))
    if depth >= 3:  # deeper than a person reads in a table: as compact JSON
        return f"<code>{_esc(json.dumps(value, separators=(', ', ': ')))}</code>"
    if isinstance(value, Mapping):
        if not value:
            return '<span class="muted">none</span>'
        if all(isinstance(v, Mapping) for v in value.values()):
            index = [str(k) for k in value]
            name = _words(key.removesuffix("s")) if key.endswith("s") else "key"  # markers: marker
            return _records_table(list(value.values()), depth, index=index, index_name=name)
        rows = [
            _key_row(_header(str(k)), _value_html(str(k), v, depth + 1)) for k, v in value.items()
        ]
        return _key_table(rows)
    items = list(value) if isinstance(value, Sequence) and not isinstance(value, str) else []
    if not items:
        return '<span class="muted">none</span>'
    if all(isinstance(item, Mapping) for item in items):
        return _records_table(items, depth)
    shown = ", ".join(
        _quantity(key, v) if _is_scalar(v) else json.dumps(v) for v in items[:MAX_ITEMS]
    )
    more = len(items) - MAX_ITEMS
    tail = f' <span class="more">and {more} more in report.json</span>' if more > 0 else ""
    return _esc(shown) + tail


def _records_table(
    records: list[Mapping[str, Any]],
    depth: int,
    index: list[str] | None = None,
    index_name: str = "key",
) -> str:
    columns = _keys(records)
    head = ([f"<th>{_esc(index_name)}</th>"] if index is not None else []) + [
        ('<th class="num">' if _numeric_column(records, c) else "<th>") + f"{_esc(_header(c))}</th>"
        for c in columns
    ]
    rows = []
    for i, record in enumerate(records[:MAX_ROWS]):
        cells = [f"<th>{_esc(index[i])}</th>"] if index is not None else []
        for column in columns:
            value = record.get(column)
            if _is_number(value):
                cells.append(_num_cell(column, value, _quantity(column, value)))
            else:
                cells.append(f"<td>{_value_html(column, value, depth + 1)}</td>")
        rows.append("<tr>" + "".join(cells) + "</tr>")
    more = len(records) - MAX_ROWS
    tail = f'<p class="more">and {more} more rows in report.json</p>' if more > 0 else ""
    return (
        f'<div class="scroll"><table><thead><tr>{"".join(head)}</tr></thead>\n<tbody>\n'
        + "\n".join(rows)
        + "\n</tbody></table></div>"
        + tail
    )


def _num_cell(key: str, value: Any, text: str, extra: str = "") -> str:
    """A right-aligned cell that carries report.json's exact value in ``data-value``."""
    exact = f' data-key="{_esc(key)}" data-value="{_esc(json.dumps(value))}"'
    return f'<td class="num{extra}"{exact}>{_esc(text)}</td>'


def _key_row(label: str, value_html: str, *, code: bool = False) -> str:
    shown = f"<code>{_esc(label)}</code>" if code else _esc(label)
    return f"<tr><th>{shown}</th><td>{value_html}</td></tr>"


def _key_table(rows: list[str]) -> str:
    return '<table class="keys"><tbody>\n' + "\n".join(rows) + "\n</tbody></table>"


def _quantity(key: str, value: Any) -> str:
    """A value as text, in the unit its key's suffix names (radians shown in degrees)."""
    if value is None:
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if _is_number(value) and _is_stamp(key):
        return shown(value * 1e-9, ".3f")
    if isinstance(value, float):
        for suffix, _, factor, spec in _units(key):
            if key.endswith(suffix):
                return shown(value * factor, spec)
        return shown(value, ".4g")
    if isinstance(value, int) and key.endswith("_ns"):
        return shown(value * 1e-6, ".3g")
    return _plain(value)


def _units(key: str) -> tuple[tuple[str, str, float, str], ...]:
    """The unit suffixes that apply to ``key``: a key with its unit inside reads as metres."""
    if key in _LABELS:
        return (("", _LABELS[key][1] or "", 1.0, ".3g"),)
    if not any(key.endswith(u[0]) for u in _UNITS) and any(i in key for i, _ in _INFIX_UNITS):
        return (("", "m", 1.0, ".4g"),)
    return _UNITS


def _plain(value: Any) -> str:
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return f"{value:,}"
    if isinstance(value, float):
        return shown(value, ".4g")
    if value is None:
        return "–"
    return value if isinstance(value, str) else json.dumps(value)


def _setting(value: Any) -> str:
    if value is None:
        return "–"
    if isinstance(value, str):
        return value
    return json.dumps(value)  # as a settings file would say it: true, 0.2, {"7": 0.16}


def _label_unit(key: str) -> tuple[str, str | None]:
    """A report key as a header and the unit of its values: ``ate_m`` -> ("ATE", "m"),
    ``marker_size_m_used`` -> ("marker size used", "m")."""
    if key in _LABELS:
        return _LABELS[key]
    if _is_stamp(key):
        return _words(key[: -len("_ns")]), "s"
    for suffix, unit, _, _ in _UNITS:
        if key.endswith(suffix) and len(key) > len(suffix):
            return _words(key[: -len(suffix)]), unit
    for infix, unit in _INFIX_UNITS:  # a unit inside the key: marker_size_m_by_depth
        head, found, tail = key.partition(infix)
        if found and head and tail:
            return _words(f"{head}_{tail}"), unit
    return _words(key), None


def _is_stamp(key: str) -> bool:
    """Whether a key names a time stamp (shown in seconds) rather than a duration."""
    return key in ("t_ns", "stamp_ns") or key.endswith(("_t_ns", "_stamp_ns"))


def _header(key: str) -> str:
    label, unit = _label_unit(key)
    return label + (f" [{unit}]" if unit else "")


def _words(key: str) -> str:
    return " ".join(_ACRONYMS.get(w, w) for w in key.replace("-", " ").replace("_", " ").split())


def _anchor(key: str) -> str:
    return "".join(c if c.isalnum() else "-" for c in key.lower())


def _is_error(key: str) -> bool:
    """Whether a method column is an error, smaller being better."""
    return key.startswith(("ate_", "rpe_")) or "rmse" in key or "error" in key


def _best(entries: Mapping[str, Mapping[str, Any]], key: str) -> float | None:
    """The smallest value of an error column, when at least two methods have one."""
    values = [e[key] for e in entries.values() if _is_number(e.get(key))]
    return min(values) if len(values) >= 2 else None


def _keys(records: Iterable[Mapping[str, Any]]) -> list[str]:
    """Every key of the records, in order of first appearance."""
    return list(dict.fromkeys(str(k) for record in records for k in record))


def _numeric_column(records: list[Mapping[str, Any]], column: str) -> bool:
    return all(_is_number(r.get(column)) or r.get(column) is None for r in records)


def _as_list(value: Any) -> list[Any]:
    return list(value) if isinstance(value, (list, tuple)) else []


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _is_scalar(value: Any) -> bool:
    return value is None or isinstance(value, (str, int, float, bool))


def _png_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) from a PNG's IHDR chunk."""
    if len(data) < 24 or not data.startswith(_PNG_SIGNATURE) or data[12:16] != b"IHDR":
        return None
    width, height = struct.unpack(">II", data[16:24])
    return int(width), int(height)


def _esc(text: str) -> str:
    return html.escape(text, quote=True)
