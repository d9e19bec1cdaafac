"""The report page: one self-contained HTML document (inline CSS, no script, nothing fetched from a network).

Images are ``<img>`` elements referring to PNG/JPEG files by paths relative to the page, inside the
report directory, so the page opens from disk in any browser. Every text that comes from a session
(names, reasons, ids) is escaped.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from html import escape

import numpy as np

from stereo_bench.report.collect import ConfigReport, SessionReport
from stereo_bench.report.page import ImageRef, SessionPage
from stereo_bench.report.tables import PARTIAL_MARK, Table, format_value, status_counts
from stereo_bench.report.tables import finite_number as _finite

CSS = """
:root { --fg: #1a1a1a; --muted: #5f6368; --line: #d0d4d9; --bg-alt: #f5f7f9; }
* { box-sizing: border-box; }
body { font: 14px/1.45 system-ui, -apple-system, "Segoe UI", Roboto, "DejaVu Sans", sans-serif; color: var(--fg);
       margin: 0 auto; padding: 16px 24px 48px; max-width: 1400px; }
h1 { font-size: 24px; margin: 8px 0 4px; }
h2 { font-size: 20px; margin: 32px 0 8px; padding-top: 8px; border-top: 3px solid #37474f; }
h3 { font-size: 16px; margin: 24px 0 6px; }
h4 { font-size: 14px; margin: 0 0 4px; }
p, ul { margin: 4px 0 8px; }
.muted { color: var(--muted); }
.small { font-size: 12px; }
nav ul { columns: 2; }
table { border-collapse: collapse; margin: 6px 0 4px; font-variant-numeric: tabular-nums; }
th, td { border: 1px solid var(--line); padding: 3px 8px; text-align: right; vertical-align: top; }
th { background: #eceff1; font-weight: 600; }
td.label, th.label { text-align: left; }
tbody tr:nth-child(even) td { background: var(--bg-alt); }
td.s-measured { background: #e8f5e9 !important; }
td.s-partial { background: #fff8e1 !important; }
td.s-infeasible { background: #eeeeee !important; color: #555; font-style: italic; }
td.s-failed { background: #ffebee !important; color: #b71c1c; font-weight: 600; }
td.s-limit { background: #fff3e0 !important; color: #e65100; font-style: italic; }
td.s-not-run { background: #fafafa !important; color: #9e9e9e; font-style: italic; }
.badge { display: inline-block; padding: 0 7px; border-radius: 9px; font-size: 12px; font-weight: 600;
         color: #fff; background: #607d8b; }
.badge.measured { background: #2e7d32; } .badge.failed { background: #c62828; }
.badge.infeasible { background: #757575; } .badge.limit { background: #ef6c00; }
.badge.not-run { background: #9e9e9e; } .badge.partial { background: #f9a825; color: #222; }
.badge.success { background: #2e7d32; } .badge.aborted, .badge.interrupted, .badge.incomplete { background: #ef6c00; }
figure { margin: 8px 0 16px; }
.figs { display: grid; grid-template-columns: repeat(auto-fit, minmax(560px, 1fr)); gap: 12px; }
td a { color: inherit; text-decoration: none; } td a:hover { text-decoration: underline; }
figure img { max-width: 100%; height: auto; border: 1px solid var(--line); background: #fff; }
figcaption { font-size: 12px; color: var(--muted); }
.warn { background: #fff3e0; border-left: 4px solid #ef6c00; padding: 6px 10px; margin: 8px 0; }
.config { border: 1px solid var(--line); border-radius: 6px; padding: 10px 12px; margin: 12px 0; }
.config.failed { border-color: #e57373; } .config.infeasible, .config.not-run, .config.limit { background: #fafafa; }
.config .reason { font-size: 13px; }
.config .images { display: grid; grid-template-columns: 1fr 1fr; gap: 10px; }
.config .images figure { margin: 4px 0; }
.kv { display: flex; flex-wrap: wrap; gap: 4px 18px; font-size: 13px; }
.kv span b { font-weight: 600; }
a.csv { font-size: 12px; }
""".strip()


def _e(value: object) -> str:
    return escape(str(value), quote=True)


def _num(value: object, digits: int = 4, *, signed: bool = False, empty: str = "–") -> str:
    number = _finite(value)
    if number is None:
        return empty
    return f"{number:+.{digits}f}" if signed else f"{number:.{digits}f}"


def _sci(value: object, empty: str = "–") -> str:
    number = _finite(value)
    return empty if number is None else f"{number:.2e}"


def _status_class(status: str) -> str:
    return status.replace(" ", "-")


def _badge(status: str) -> str:
    return f'<span class="badge {_e(_status_class(status))}">{_e(status)}</span>'


def _img(ref: ImageRef) -> str:
    caption = f"<figcaption>{_e(ref.caption)}</figcaption>" if ref.caption else ""
    return (f'<figure><img src="{_e(ref.src)}" alt="{_e(ref.alt)}" width="{ref.width}" height="{ref.height}">'
            f"{caption}</figure>")


def anchor(session_key: str, config_id: str) -> str:
    """The page-unique id of a configuration's block (config ids repeat across sessions)."""
    return f"{session_key}-{config_id}"


def _config_link(session: SessionReport, config: ConfigReport) -> str:
    return f"<a href='#{_e(anchor(session.key, config.config_id))}'>{_e(config.config_id)}</a>"


def _table_html(table: Table, csv_path: str, session_key: str) -> str:
    head = "".join(f'<th class="label">{_e(text)}</th>' if i == 0 else f"<th>{_e(text)}</th>"
                   for i, text in enumerate(table.header()))
    body = []
    for i, row in enumerate(table.cells):
        cells = [f'<th class="label">{_e(table.row_name(i))}</th>']
        for cell in row:
            if cell.status == "empty":
                cells.append("<td></td>")
                continue
            css = "s-partial" if cell.measured and cell.partial else f"s-{_status_class(cell.status)}"
            tooltip = []
            if cell.config_id:
                tooltip.append(cell.config_id)
            if cell.measured:
                tooltip.append(f"error {_num(cell.error_mm, signed=True)} mm ± {_num(cell.sigma_mm)} mm")
            if cell.reason:
                tooltip.append(cell.reason)
            link = f"#{_e(anchor(session_key, cell.config_id))}" if cell.config_id else ""
            text = _e(cell.text())
            if link:
                text = f'<a href="{link}">{text}</a>'
            sub = ""
            if cell.measured and cell.error_mm is not None:
                sub = f'<br><span class="small muted">{_num(cell.error_mm, signed=True)} ± {_num(cell.sigma_mm)}</span>'
            cells.append(f'<td class="{css}" title="{_e(" | ".join(tooltip))}">{text}{sub}</td>')
        body.append(f"<tr>{''.join(cells)}</tr>")
    counts = ", ".join(f"{n} {status}" for status, n in table.statuses().items())
    return (f"<h4>{_e(table.title)}</h4><table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody>"
            f'</table><p class="small muted">{_e(counts)} · cell: measured square (mm), below it error ± propagated '
            f'σ (mm); {_e(PARTIAL_MARK)} measured on a partial view · <a class="csv" href="{_e(csv_path)}">CSV</a></p>')


def _kv(items: Iterable[tuple[str, object]]) -> str:
    return '<div class="kv">' + "".join(f"<span>{_e(k)}: <b>{_e(v)}</b></span>" for k, v in items) + "</div>"


def _session_header(session: SessionReport, index: int) -> str:
    start = session.start
    config = start.get("config") or {}
    software = start.get("software") or {}
    target = config.get("target") or {}
    board = config.get("calibration_board") or {}
    capture = config.get("capture") or {}
    optics = (config.get("cameras") or {}).get("optics") or {}
    counts = status_counts(session.rows)
    parts = [
        f'<h2 id="{_e(session.key)}">Session {index}: {_e(session.name)} {_badge(session.status)}</h2>',
        f'<p class="muted">{_e(session.description)}</p>' if session.description else "",
        _kv([
            ("directory", session.directory), ("started", start.get("time", "?")),
            ("attempts", len(session.reader.attempts())),
            ("configurations", ", ".join(f"{n} {s}" for s, n in counts.items())),
            ("target", f"{target.get('kind', '?')} {target.get('cols', '?')}x{target.get('rows', '?')}, "
                       f"{target.get('square_mm', '?')} mm squares"),
            ("calibration board", f"{board.get('kind', '?')} {board.get('cols', '?')}x{board.get('rows', '?')}, "
                                  f"{board.get('square_mm', '?')} mm"),
            ("cameras", f"{(config.get('cameras') or {}).get('kind', '?')}, {optics.get('width_px', '?')}x"
                        f"{optics.get('height_px', '?')} px, f {optics.get('focal_mm', '?')} mm, "
                        f"pixel {optics.get('pixel_um', '?')} µm"),
            ("capture", f"{capture.get('calibration_views', '?')} calibration views, "
                        f"{capture.get('frames_per_config', '?')} frames per configuration"),
            ("software", ", ".join(f"{k} {v}" for k, v in software.items())),
        ]),
    ]
    for warning in session.warnings:
        parts.append(f'<div class="warn">{_e(warning)}</div>')
    return "".join(parts)


def _comparison_table(session: SessionReport) -> str:
    head = ("<tr><th class='label'>configuration</th><th>B (mm)</th><th>Z (mm)</th><th>α (deg)</th><th>K = B/Z</th>"
            "<th class='label'>status</th><th>square (mm)</th><th>error (mm)</th><th>measured σ (mm)</th>"
            "<th>predicted σ (mm)</th><th>expected error (mm)</th><th>|error − expected| / predicted σ</th>"
            "<th>pixel σ (px)</th></tr>")
    body = []
    sources = set()
    for config in session.configs:
        row, prediction = config.row, config.prediction or {}
        baseline, distance = _finite(row.get("baseline_mm")), _finite(row.get("distance_mm"))
        ratio = "–"
        error, sigma, expected = (_finite(row.get("error_mm")), _finite(prediction.get("sigma_mm")),
                                  _finite(prediction.get("expected_error_mm")))
        if config.status == "measured" and error is not None and sigma and expected is not None:
            ratio = f"{abs(error - expected) / sigma:.1f}"
        if prediction.get("pixel_sigma_source"):
            sources.add(str(prediction["pixel_sigma_source"]))
        note = prediction.get("reason") if not prediction.get("available") else ""
        status_cell = _badge(config.status) + (f' <span class="small muted">{_e(note)}</span>' if note else "")
        body.append(
            f"<tr><td class='label'>{_config_link(session, config)}</td>"
            f"<td>{_num(baseline, 0)}</td><td>{_num(distance, 0)}</td><td>{_num(row.get('alpha_deg'), 1)}</td>"
            f"<td>{_num(baseline / distance if baseline is not None and distance else None, 3)}</td>"
            f"<td class='label'>{status_cell}</td>"
            f"<td>{_num(row.get('square_mean_mm') if config.status == 'measured' else None)}</td>"
            f"<td>{_num(row.get('error_mm') if config.status == 'measured' else None, signed=True)}</td>"
            f"<td>{_sci(row.get('sigma_mm') if config.status == 'measured' else None)}</td>"
            f"<td>{_sci(prediction.get('sigma_mm'))}</td><td>{_sci(prediction.get('expected_error_mm'))}</td>"
            f"<td>{ratio}</td>"
            f"<td>{_num(prediction.get('pixel_sigma_px') if prediction.get('available') else None, 4)}</td></tr>")
    return (f"<table><thead>{head}</thead><tbody>{''.join(body)}</tbody></table>"
            f'<p class="small muted">Pixel σ used by the model: {_e("; ".join(sorted(sources)) or "none")}. The '
            "prediction propagates image noise only, through the true geometry of the configuration and the "
            "campaign's nominal optics; errors of the calibration (the estimated R, T and intrinsics) are not in "
            "it, so a ratio well above 3 says the error is systematic, not noise.</p>")


def _calibration_table(session: SessionReport, csv_path: str) -> str:
    head = ("<tr><th class='label'>configuration</th><th class='label'>status</th><th>RMS (px)</th>"
            "<th>epipolar RMS (px)</th><th>views used</th><th>views rejected</th><th>|T| (mm)</th>"
            "<th>B (mm)</th></tr>")
    body = []
    for config in session.configs:
        calibration = config.calibration
        if calibration is None:
            body.append(f"<tr><td class='label'>{_config_link(session, config)}</td>"
                        f"<td class='label'>{_badge(config.status)}</td><td colspan='6' class='label muted'>"
                        "no calibration</td></tr>")
            continue
        T = calibration.get("T_mm")
        norm = float(np.linalg.norm(T)) if isinstance(T, list) and len(T) == 3 else None
        rejected = calibration.get("views_rejected") or []
        body.append(
            f"<tr><td class='label'>{_config_link(session, config)}</td>"
            f"<td class='label'>{_badge(config.status)}</td><td>{_num(calibration.get('rms_px'), 4)}</td>"
            f"<td>{_num(calibration.get('epipolar_rms_px'), 4)}</td>"
            f"<td>{len(calibration.get('views_used') or [])}</td><td>{len(rejected)}</td>"
            f"<td>{_num(norm, 3)}</td><td>{_num(config.row.get('baseline_mm'), 0)}</td></tr>")
    return (f"<table><thead>{head}</thead><tbody>{''.join(body)}</tbody></table>"
            f'<p class="small muted">RMS: stereo reprojection error of the calibration views used; epipolar RMS: '
            f"vertical offset of matched corners after rectification, in camera pixels; |T|: the estimated "
            f'baseline. <a class="csv" href="{_e(csv_path)}">CSV</a> (with per-view values and rejection '
            "reasons)</p>")


def _config_block(config: ConfigReport, page: SessionPage) -> str:
    session = page.session
    row = config.row
    status = config.status
    partial = status == "measured" and (
        (_finite(row.get("fraction_in_both_measured")) or _finite(row.get("fraction_in_both")) or 1.0) < 1.0)
    title = (f"{config.config_id}: B {format_value(_finite(row.get('baseline_mm')) or 0)} mm, "
             f"Z {format_value(_finite(row.get('distance_mm')) or 0)} mm, "
             f"α {format_value(_finite(row.get('alpha_deg')) or 0)} deg")
    badges = _badge(status) + (" " + _badge("partial") if partial else "")
    parts = [f'<div class="config {_e(_status_class(status))}" id="{_e(anchor(session.key, config.config_id))}">',
             f"<h4>{_e(title)} {badges}</h4>"]
    if row.get("reason"):
        parts.append(f'<p class="reason">{_e(row["reason"])}</p>')
    plan = config.plan or {}
    items: list[tuple[str, object]] = []
    fraction = _finite(plan.get("fraction_in_both"))
    if fraction is not None:
        items.append(("predicted in both views", f"{plan.get('corners_in_both', '?')}/{plan.get('n_corners', '?')} "
                                                 f"corners ({fraction:.0%})"))
    if status == "measured":
        items += [("square", f"{_num(row.get('square_mean_mm'))} mm"),
                  ("error", f"{_num(row.get('error_mm'), signed=True)} ± {_num(row.get('sigma_mm'))} mm"),
                  ("std of squares", f"{_num(row.get('square_std_mm'))} mm"),
                  ("squares", row.get("n_squares")), ("frames", row.get("n_frames", "?"))]
        measured_fraction = _finite(row.get("fraction_in_both_measured"))
        if measured_fraction is not None:
            items.append(("measured in both views", f"{measured_fraction:.0%}"))
    prediction = config.prediction or {}
    if prediction.get("available"):
        items.append(("predicted σ", f"{_sci(prediction.get('sigma_mm'))} mm at "
                                     f"{_num(prediction.get('pixel_sigma_px'), 4)} px"))
    calibration = config.calibration
    if calibration:
        items += [("calibration RMS", f"{_num(calibration.get('rms_px'), 4)} px"),
                  ("epipolar RMS", f"{_num(calibration.get('epipolar_rms_px'), 4)} px"),
                  ("views used", len(calibration.get("views_used") or [])),
                  ("views rejected", len(calibration.get("views_rejected") or []))]
    if items:
        parts.append(_kv(items))
    if calibration:
        per_view = np.asarray(calibration.get("per_view_rms_px") or [], float).reshape(-1, 2)
        used = list(calibration.get("views_used") or [])
        if len(per_view):
            cells = " ".join(f"#{used[i] if i < len(used) else i}: {per_view[i, 0]:.3f}/{per_view[i, 1]:.3f}"
                             for i in range(len(per_view)))
            parts.append(f'<p class="small">Per-view RMS, left/right (px): {_e(cells)}</p>')
        for rejected in calibration.get("views_rejected") or []:
            if isinstance(rejected, dict):
                parts.append(f'<p class="small">Rejected view #{_e(rejected.get("index"))}: '
                             f'{_e(rejected.get("reason"))}</p>')
    for failed in config.frames_failed:
        parts.append(f'<p class="small">Frame {_e(failed.get("index"))} not measured: {_e(failed.get("reason"))}</p>')
    for note in page.image_notes.get(config.config_id, []):
        parts.append(f'<p class="small muted">{_e(note)}</p>')
    refs = page.images.get(config.config_id, [])
    if refs:
        parts.append('<div class="images">' + "".join(_img(ref) for ref in refs) + "</div>")
    parts.append("</div>")
    return "".join(parts)


def _session_section(page: SessionPage, index: int) -> str:
    session = page.session
    parts = [f"<section>{_session_header(session, index)}"]
    if page.tables1:
        parts.append("<h3>Measured square per baseline and distance (the paper's Table 1)</h3>")
        parts += [_table_html(table, path, session.key) for table, path in page.tables1]
    if page.tables2:
        parts.append("<h3>Measured square per angle α (the paper's Table 2)</h3>")
        parts += [_table_html(table, path, session.key) for table, path in page.tables2]
    if not page.tables1 and not page.tables2:
        parts.append('<p class="muted">No grid over B, Z or α in this session: see the configurations below.</p>')
    if page.error_figures:
        parts.append("<h3>Error of the measured square (the paper's Figures 8, 9, 11)</h3>")
        parts.append('<p class="small muted">Points: measured error with error bars of the propagated σ; shaded: '
                     "the rigorous model's expected error ± σ (image noise only); hollow: partial view; markers on "
                     "the bottom strip: configurations not measured (× infeasible, ■ failed, ▲ outside the limits, "
                     "● not run); series are offset slightly along x so that their error bars do not overlap.</p>")
        parts.append('<div class="figs">' + "".join(_img(ref) for ref in page.error_figures) + "</div>")
    parts.append("<h3>Measured error beside the rigorous prediction</h3>")
    if page.comparison:
        parts.append(_img(page.comparison))
    parts.append(_comparison_table(session))
    parts.append("<h3>Calibration quality</h3>")
    if page.calibration:
        parts.append(_img(page.calibration))
    parts.append(_calibration_table(session, page.calibration_csv))
    parts.append(f'<p><a href="#{_e(session.key)}-configurations">Every configuration of this session, with '
                 "its annotated images</a></p></section>")
    return "".join(parts)


def _configurations_section(page: SessionPage, index: int) -> str:
    session = page.session
    return (f'<section><h2 id="{_e(session.key)}-configurations">Configurations of session {index}: '
            f"{_e(session.name)}</h2>" + "".join(_config_block(config, page) for config in session.configs)
            + "</section>")


def render_page(pages: Sequence[SessionPage], *, generated: str, version: str, warnings: Sequence[str] = ()) -> str:
    """The whole HTML document."""
    names = ", ".join(page.session.name for page in pages)
    toc = "".join(
        f'<li><a href="#{_e(p.session.key)}">Session {i}: {_e(p.session.name)}</a> {_badge(p.session.status)} '
        f'<span class="small muted">{_e(", ".join(f"{n} {s}" for s, n in status_counts(p.session.rows).items()))}'
        "</span></li>" for i, p in enumerate(pages, start=1))
    session_warnings = {w for p in pages for w in p.session.warnings}
    other_warnings = "".join(f'<div class="warn">{_e(w)}</div>' for w in warnings if w not in session_warnings)
    # Summaries (tables, figures, comparison, calibration) of every session first, then the configurations.
    body = "".join(_session_section(page, i) for i, page in enumerate(pages, start=1))
    body += "".join(_configurations_section(page, i) for i, page in enumerate(pages, start=1))
    return (
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n"
        f"<title>stereo-bench report: {_e(names)}</title>\n<style>\n{CSS}\n</style>\n</head>\n<body>\n"
        f"<header><h1>stereo-bench report</h1><p class=\"muted\">{_e(names)} · generated {_e(generated)} by "
        f"stereo-bench {_e(version)} · <a href=\"tables/results.csv\">all results (CSV)</a> · "
        f"<a href=\"report.json\">manifest</a></p>{other_warnings}</header>\n"
        f"<nav><ul>{toc}</ul></nav>\n{body}\n"
        "<footer><p class=\"small muted\">Units: mm and deg. Error = measured square − nominal square. σ: "
        "propagated from the corner noise measured in the frames (first order). Statuses: measured; failed "
        "(tried, could not measure: see its reason); infeasible (predicted before moving: too little of the "
        "target in both views, not run); limit (outside the rig's soft limits, not run); not run (the session "
        f"stopped first). {_e(PARTIAL_MARK)}: measured on a partial view.</p></footer>\n</body>\n</html>\n"
    )


__all__ = ["CSS", "anchor", "render_page"]
