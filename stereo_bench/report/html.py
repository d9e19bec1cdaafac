"""The report page: one self-contained HTML document (inline CSS, no script, nothing fetched from a network).

Images are ``<img>`` elements referring to PNG/JPEG files by paths relative to the page, inside the
report directory, so the page opens from disk in any browser. Every text that comes from a session
(names, reasons, ids) is escaped.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from html import escape

import numpy as np

from stereo_bench.report.collect import (
    BUDGET_COMPONENTS,
    EXTRINSICS_SOURCE_NAMES,
    EXTRINSICS_SOURCES,
    SOURCE_MODE,
    ConfigReport,
    SessionReport,
)
from stereo_bench.report.figures import SOURCE_LABELS, coverage
from stereo_bench.report.page import ImageRef, SessionPage, StructuralSection
from stereo_bench.report.tables import (
    INCOMPLETE_MARK,
    PARTIAL_MARK,
    Cell,
    Table,
    format_value,
    status_counts,
    uncertainty_decimals,
)
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
.answer { border: 1px solid #cfd8dc; background: #fafcfd; padding: 4px 12px 8px; margin: 8px 0 16px; }
.answer table.paper { display: inline-table; margin-right: 16px; vertical-align: top; }
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
td.unknown { color: #9e9e9e; font-style: italic; }
td.dominant { font-weight: 700; background: #fff3cd !important; }
td.outside { color: #b71c1c; font-weight: 600; }
table.structure td.used, table.structure tr.used td { font-weight: 600; }
table.structure td:not(.label) { white-space: nowrap; }
.missing { background: #f5f5f5; border-left: 4px solid #9e9e9e; padding: 6px 10px; margin: 8px 0; color: #424242; }
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


def _k_text(session: SessionReport) -> str:
    ks = sorted({c.budget.k for c in session.configs if c.budget and c.budget.k is not None})
    if not ks:
        return "k unknown"
    if ks[-1] - ks[0] < 0.005:  # one k, to the digits a reader compares
        return f"k = {ks[0]:.2f}".rstrip("0").rstrip(".")
    # Each budget's own coverage factor (Student's t of its effective degrees of freedom): a range, not a list
    return f"k = {ks[0]:.2f}–{ks[-1]:.2f} per configuration (Student's t of each budget's effective degrees of freedom)"


def _table_html(table: Table, csv_path: str, session_key: str, error_csv: str = "", k_text: str = "") -> str:
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
                tooltip.append(f"error {cell.error_text()} mm" + ("" if cell.expanded_mm is None else
                                                                   f" (U); noise σ {_num(cell.sigma_mm)} mm"))
            if cell.reason:
                tooltip.append(cell.reason)
            link = f"#{_e(anchor(session_key, cell.config_id))}" if cell.config_id else ""
            text = _e(cell.text())
            if link:
                text = f'<a href="{link}">{text}</a>'
            sub = ""
            if cell.measured and cell.error_mm is not None:
                sub = f'<br><span class="small muted">{_e(cell.error_text())}</span>'
            cells.append(f'<td class="{css}" title="{_e(" | ".join(tooltip))}">{text}{sub}</td>')
        body.append(f"<tr>{''.join(cells)}</tr>")
    counts = ", ".join(f"{n} {status}" for status, n in table.statuses().items())
    incomplete = any(not c.budget_complete for row in table.cells for c in row if c.expanded_mm is not None)
    noise_only = any(c.expanded_mm is None for row in table.cells for c in row if c.measured)
    below = []
    if table.has_uncertainty():
        below.append(f"error ± U (mm; U the expanded uncertainty of the budget, {k_text})")
    if incomplete:
        below.append(f"{INCOMPLETE_MARK}: U leaves out components that are unknown (a lower bound)")
    if noise_only:
        below.append("“(σ noise)”: no uncertainty budget recorded, ± the σ propagated from image noise only")
    links = f'<a class="csv" href="{_e(csv_path)}">CSV</a>' + (
        f' · <a class="csv" href="{_e(error_csv)}">CSV of error ± {"U" if table.has_uncertainty() else "σ"}</a>'
        if error_csv else "")
    return (f"<h4>{_e(table.title)}</h4><table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody>"
            f'</table><p class="small muted">{_e(counts)} · cell: measured square (mm), below it '
            f'{_e("; ".join(below) or "the error (mm)")}; {_e(PARTIAL_MARK)} measured on a partial view · {links}</p>')


def _kv(items: Iterable[tuple[str, object]]) -> str:
    return '<div class="kv">' + "".join(f"<span>{_e(k)}: <b>{_e(v)}</b></span>" for k, v in items) + "</div>"


def _session_header(session: SessionReport, index: int) -> str:
    start = session.start
    config = session.config  # None when the recorded config does not validate here: its values show as '?'

    def of(section: str, *path: str) -> object:
        value: object = getattr(config, section, None)
        for name in path:
            value = getattr(value, name, None)
        return "?" if value is None else value

    counts = status_counts(session.rows)
    parts = [
        f'<h2 id="{_e(session.key)}">Session {index}: {_e(session.name)} {_badge(session.status)}</h2>',
        f'<p class="muted">{_e(session.description)}</p>' if session.description else "",
        _kv([
            ("directory", session.directory), ("started", start.time),
            ("attempts", len(session.reader.attempts())),
            ("configurations", ", ".join(f"{n} {s}" for s, n in counts.items())),
            ("target", f"{of('target', 'kind')} {of('target', 'cols')}x{of('target', 'rows')}, "
                       f"{of('target', 'square_mm')} mm squares"),
            ("calibration board", f"{of('calibration_board', 'kind')} {of('calibration_board', 'cols')}x"
                                  f"{of('calibration_board', 'rows')}, {of('calibration_board', 'square_mm')} mm"),
            ("cameras", f"{of('cameras', 'kind')}, {of('cameras', 'optics', 'width_px')}x"
                        f"{of('cameras', 'optics', 'height_px')} px, f {of('cameras', 'optics', 'focal_mm')} mm, "
                        f"pixel {of('cameras', 'optics', 'pixel_um')} µm"),
            ("capture", f"{of('capture', 'calibration_views')} calibration views, "
                        f"{of('capture', 'frames_per_config')} frames per configuration"),
            ("software", ", ".join(f"{k} {v}" for k, v in start.software.items())),
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
    ratios: list[float] = []
    for config in session.configs:
        row, prediction = config.row, config.prediction or {}
        baseline, distance = _finite(row.get("baseline_mm")), _finite(row.get("distance_mm"))
        ratio = "–"
        error, sigma, expected = (_finite(row.get("error_mm")), _finite(prediction.get("sigma_mm")),
                                  _finite(prediction.get("expected_error_mm")))
        if config.status == "measured" and error is not None and sigma and expected is not None:
            ratios.append(abs(error - expected) / sigma)
            ratio = f"{ratios[-1]:.1f}"
        if prediction.get("pixel_sigma_source"):
            sources.add(str(prediction["pixel_sigma_source"]))
        note = prediction.get("reason") if not prediction.get("available") else ""
        if config.status != "measured" and row.get("reason"):  # why it is missing: what the session recorded
            note = str(row["reason"])
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
    cause = ""
    if ratios and sorted(ratios)[len(ratios) // 2] > 10:
        calibration = [v for c in session.configs if c.calibration and (v := _finite(c.calibration.get("rms_px")))]
        pixel = [v for c in session.configs if (c.prediction or {}).get("available")
                 and (v := _finite(c.prediction.get("pixel_sigma_px")))]
        if calibration and pixel:
            cause = (f" Here the median ratio is {sorted(ratios)[len(ratios) // 2]:.0f}: the frames' sensor noise "
                     f"moves a corner by ~{sorted(pixel)[len(pixel) // 2]:.2g} px, while the corners scatter about "
                     f"the calibrated model by {sorted(calibration)[len(calibration) // 2]:.2g} px RMS (print, "
                     "optics, lighting: what a frame's own noise does not show); the error is the print's scale, "
                     "the calibration and that scatter (the first screen's figure draws each term).")
    return (f"<table><thead>{head}</thead><tbody>{''.join(body)}</tbody></table>"
            f'<p class="small muted">Pixel σ used by the model: {_e("; ".join(sorted(sources)) or "none")}. The '
            "prediction propagates image noise only, through the true geometry of the configuration and the "
            "campaign's nominal optics; errors of the calibration (the estimated R, T and intrinsics) are not in "
            f"it, so a ratio well above 3 says the error is systematic, not noise.{_e(cause)}</p>")


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


def _mm(value: object, digits: int = 4) -> str:
    """A budget value: 'unknown' (never 0) when it is not known."""
    return "unknown" if _finite(value) is None else _num(value, digits)


def _budget_section(page: SessionPage) -> str:
    """The uncertainty budget per configuration and the normalised-error plot, or what is missing."""
    session = page.session
    measured = [c for c in session.configs if c.status == "measured"]
    with_budget = [c for c in measured if c.budget is not None]
    parts = [f'<h3 id="{_e(session.key)}-budget">Uncertainty budget (standard uncertainties, mm)</h3>']
    if not with_budget:
        parts.append('<p class="missing">No uncertainty budget is recorded in this session (its result rows have no '
                     "<code>u_combined_mm</code>, <code>U_expanded_mm</code> or <code>uncertainty</code> budget: "
                     "recorded before the campaign computed one). The tables and figures show ± the σ propagated "
                     "from image noise only, which leaves out the calibration, the structure and the target; no "
                     "normalised-error plot can be drawn.</p>" if measured else
                     '<p class="missing">No configuration was measured: no uncertainty budget.</p>')
        return "".join(parts)
    has_true = any(c.structure and c.structure.square_true_mm is not None for c in with_budget)

    def adequacy_of(config: ConfigReport) -> float | None:
        # The model-adequacy component (issue 22): in the nested budget record when the calibration computed it.
        record = config.row.get("uncertainty")
        return _finite(record.get("adequacy")) if isinstance(record, dict) else None
    has_adequacy = any(adequacy_of(c) is not None for c in with_budget)
    head = ("<tr><th class='label'>configuration</th><th class='label'>extrinsics</th><th>error</th>"
            + "".join(f"<th>{_e(name)}</th>" for name in BUDGET_COMPONENTS)
            + ("<th>adequacy</th>" if has_adequacy else "")
            + "<th>u_c</th><th>U</th><th>k</th><th class='label'>dominant (share of u_c²)</th><th>error / u_c</th>"
            + ("<th>(measured − true) / u_c</th>" if has_true else "") + "</tr>")
    body = []
    # One number of decimals for the table: two significant digits for its smallest uncertainty.
    places = uncertainty_decimals(*(v for c in with_budget for v in (*c.budget.components.values(), c.budget.combined)),
                                  minimum=4)
    for config in measured:
        budget, row = config.budget, config.row
        mode = config.structure.mode if config.structure and config.structure.mode else "–"
        first = (f"<td class='label'>{_config_link(session, config)}</td><td class='label'>{_e(mode)}</td>"
                 f"<td>{_num(row.get('error_mm'), signed=True)}</td>")
        if budget is None:
            body.append(f"<tr>{first}<td colspan='{8 + has_true + has_adequacy}' class='label unknown'>no budget "
                        "recorded for this "
                        "configuration</td></tr>")
            continue
        cells = []
        for name in BUDGET_COMPONENTS:
            value = budget.components[name]
            if value is None:
                text = "unknown" if budget.components_recorded else "not recorded"
                cells.append(f"<td class='unknown' title='{_e(name)}: {text}, not in u_c'>{text}</td>")
            else:
                css = " class='dominant'" if name == budget.dominant else ""
                cells.append(f"<td{css}>{_num(value, places)}</td>")
        if has_adequacy:
            adequacy = adequacy_of(config)
            cells.append("<td class='unknown' title='adequacy: not computed'>–</td>" if adequacy is None
                         else f"<td>{_num(adequacy, places)}</td>")
        share = budget.share(budget.dominant) if budget.dominant else None
        dominant = f"{budget.dominant} ({share:.0%})" if budget.dominant and share is not None else "–"
        error = _finite(row.get("error_mm"))
        z = error / budget.combined if error is not None and budget.combined else None
        square = _finite(row.get("square_mean_mm"))
        true = config.structure.square_true_mm if config.structure else None
        z_true = (square - true) / budget.combined if square is not None and true is not None and budget.combined \
            else None
        k = budget.k or 2.0

        def zcell(value: float | None, k: float = k) -> str:
            if value is None:
                return "<td>–</td>"
            css = ' class="outside"' if abs(value) > k else ""
            return f"<td{css}>{value:+.2f}</td>"
        incomplete = "" if budget.complete else INCOMPLETE_MARK
        body.append(f"<tr>{first}{''.join(cells)}<td>{_mm(budget.combined, places)}{incomplete}</td>"
                    f"<td>{_mm(budget.expanded, places)}{incomplete}</td><td>{_num(budget.k, 2)}</td>"
                    f"<td class='label'>{_e(dominant)}</td>{zcell(z)}" + (zcell(z_true) if has_true else "") + "</tr>")
    z_values = [z for c in with_budget if (z := _z(c)) is not None]
    n, rms, share = coverage(z_values)
    summary = (f"Over {n} configurations: RMS of error / u_c {rms:.2f}, |error| ≤ U for {share:.0%}"
               if n and rms is not None and share is not None else "")
    if has_true:
        true_values = [z for c in with_budget if (z := _z(c, true=True)) is not None]
        n_t, rms_t, share_t = coverage(true_values)
        if n_t and rms_t is not None and share_t is not None:
            summary += (f"; against the true square (simulator): RMS {rms_t:.2f}, |measured − true| ≤ U for "
                        f"{share_t:.0%}")
    parts.append(f"<table><thead>{head}</thead><tbody>{''.join(body)}</tbody></table>")
    parts.append(
        f'<p class="small muted">{_e(summary)}{". " if summary else ""}Components: noise (image noise, random and '
        "systematic), calibration (from the calibration's covariance), structure (the extrinsics' source beyond the "
        "calibration: the kinematic model, the rig's tolerances, its repeatability), target (the boards' scale)"
        + (", adequacy (the calibration's own board measured in held-out views beyond its prediction)"
           if has_adequacy else "") + ". "
        f"u_c combines the known ones; U = k·u_c. The dominant component is highlighted. “unknown”: the "
        f"component could not be evaluated and is not in u_c, so U{INCOMPLETE_MARK} is a lower bound. An error / u_c "
        "outside ±k is red: there, the stated uncertainty does not cover the error. "
        f'<a class="csv" href="{_e(page.budget_csv)}">CSV</a></p>')
    if page.normalised:
        parts.append(_img(page.normalised))
    return "".join(parts)


def _z(config: ConfigReport, *, true: bool = False) -> float | None:
    budget = config.budget
    if budget is None or not budget.combined:
        return None
    if true:
        square = _finite(config.row.get("square_mean_mm"))
        reference = config.structure.square_true_mm if config.structure else None
        return (square - reference) / budget.combined if square is not None and reference is not None else None
    error = _finite(config.row.get("error_mm"))
    return error / budget.combined if error is not None else None


def _structure_section(page: SessionPage) -> str:
    """Per measured configuration: the extrinsics used beside the truth, and the error with each source."""
    session = page.session
    measured = [c for c in session.configs if c.status == "measured" and c.structure is not None]
    parts = [f'<h3 id="{_e(session.key)}-structure">Structure: the extrinsics each configuration was measured '
             "with</h3>"]
    if not measured:
        parts.append('<p class="missing">No configuration was measured: no structure to show.</p>')
        return "".join(parts)
    has_truth = any(c.structure.extrinsics["truth"] for c in measured)
    modes = []
    for config in measured:
        modes += [m for m in config.structure.squares_mm if m not in modes]
    keys = (("baseline_mm", "optical baseline (mm)", 3), ("alpha_left_deg", "α left (deg)", 3),
            ("alpha_right_deg", "α right (deg)", 3), ("rotation_deg", "rotation (deg)", 3))
    sub = ("used", "truth") if has_truth else ("used", "nominal")
    with_u = any(c.structure.budgets for c in measured)
    head1 = ("<tr><th class='label' rowspan='2'>configuration</th><th class='label' rowspan='2'>extrinsics</th>"
             + "".join(f"<th colspan='2'>{_e(name)}</th>" for _, name, _ in keys)
             + (f"<th colspan='{len(modes)}'>error of the square{' ± U' if with_u else ''} (mm) with</th>"
                if modes else "")
             + ("<th rowspan='2'>true square (mm)</th>" if has_truth else "") + "</tr>")
    head2 = "<tr>" + "".join(f"<th>{s}</th>" for _ in keys for s in sub) + "".join(
        f"<th>{_e(m)}</th>" for m in modes) + "</tr>"
    body = []
    for config in measured:
        structure = config.structure
        nominal = config.row.get("square_mean_mm")
        nominal = (_finite(nominal) - _finite(config.row.get("error_mm"))) if _finite(nominal) is not None and \
            _finite(config.row.get("error_mm")) is not None else None
        cells = [f"<td class='label'>{_config_link(session, config)}</td>",
                 f"<td class='label'>{_e(structure.mode or 'unknown')}</td>"]
        for key, _, digits in keys:
            for source in sub:
                value = structure.value(source, key)
                cells.append(f"<td>{_num(value, digits)}</td>")
        for mode in modes:
            square = structure.squares_mm.get(mode)
            error = square - nominal if square is not None and nominal is not None else None
            css = " class='used'" if mode == structure.mode else ""
            cells.append(f"<td{css}>{_e(_error_with_u(error, structure.budgets.get(mode)))}</td>")
        if has_truth:
            cells.append(f"<td>{_num(structure.square_true_mm, 4)}</td>")
        body.append(f"<tr>{''.join(cells)}</tr>")
    origins = sorted({f"{s}: {c.structure.origin[s]}" for c in measured for s in sub if s in c.structure.origin})
    missing = [s for s in ("calibrated", "kinematic", "truth")
               if not any(c.structure.extrinsics[s] for c in measured)]
    notes = [f"Read from — {'; '.join(origins)}." if origins else "",
             "The configurations' blocks below show every source side by side (used, calibrated, kinematic, "
             "nominal, truth)."]
    if missing:
        notes.append("Not recorded in this session: " + ", ".join(
            {"calibrated": "calibrated extrinsics", "kinematic": "a kinematic prediction",
             "truth": "the truth (a real bench, or a session recorded before the simulator's truth was kept)"}[m]
            for m in missing) + ".")
    if len(modes) < 2:
        notes.append("The square is recorded with one extrinsics source only (the one the measurement used).")
    parts.append(f"<table class='structure'><thead>{head1}{head2}</thead><tbody>{''.join(body)}</tbody></table>")
    parts.append(f'<p class="small muted">{_e(" ".join(n for n in notes if n))} '
                 f'<a class="csv" href="{_e(page.structure_csv)}">CSV</a> (every source, with where it was read)</p>')
    if page.deviation:
        parts.append(_img(page.deviation))
        parts.append(f'<p class="small muted">Each source’s optical baseline, alphas and stereo rotation angle '
                     f"minus the {_e(page.deviation_reference)}"
                     + (" (no truth recorded: the nominal geometry is the reference)"
                        if page.deviation_reference == "nominal" else "")
                     + "; the ringed point is the source the measurement used.</p>")
    return "".join(parts)


def _with_sigma(value: object, sigma: object, digits: int = 3) -> str:
    return _num(value, digits) + (f" ± {_num(sigma, digits)}" if _finite(sigma) is not None else "")


def _error_with_u(error: float | None, budget) -> str:
    if error is None:
        return "–"
    if budget is None or budget.expanded is None:
        return f"{error:+.4f}"
    places = uncertainty_decimals(budget.expanded)
    return f"{error:+.{places}f} ± {budget.expanded:.{places}f}" + ("" if budget.complete else INCOMPLETE_MARK)


def _structure_block(config: ConfigReport) -> str:
    """The extrinsics sources of one configuration side by side, with the square measured with each (± U)."""
    structure = config.structure
    if structure is None:
        return ""
    row = config.row
    square, error = _finite(row.get("square_mean_mm")), _finite(row.get("error_mm"))
    nominal = square - error if square is not None and error is not None else None
    lines = []
    for source in EXTRINSICS_SOURCES:
        described = structure.extrinsics.get(source) or {}
        mode = structure.mode if source == "used" else SOURCE_MODE.get(source)
        measured_square = structure.squares_mm.get(mode) if mode else None
        if not described and measured_square is None:
            continue
        sigma = structure.sigma.get(source) or {}
        values = "".join(f"<td>{_with_sigma(described.get(k), sigma.get(k))}</td>"
                         for k in ("baseline_mm", "alpha_left_deg", "alpha_right_deg", "rotation_deg"))
        if source == "truth":
            square_text = (f"{_num(structure.square_true_mm)} (true)" if structure.square_true_mm is not None else "–")
        elif measured_square is not None:
            square_text = _num(measured_square) + (
                f" ({_error_with_u(measured_square - nominal, structure.budgets.get(mode or ''))})"
                if nominal is not None else "")
        else:
            square_text = "not measured with it"
        name = EXTRINSICS_SOURCE_NAMES[source] + (f": {structure.mode}" if source == "used" and structure.mode else "")
        origin = structure.origin.get(source) or structure.squares_origin.get(mode or "", "")
        note = structure.notes.get(source)
        origin += f"; {note}" if note else ""
        css = " class='used'" if source == "used" else ""
        lines.append(f"<tr{css}><td class='label'>{_e(name)}</td>{values}<td>{_e(square_text)}</td>"
                     f"<td class='label small muted'>{_e(origin)}</td></tr>")
    if not lines:
        return ""
    absent = [EXTRINSICS_SOURCE_NAMES[s] for s in EXTRINSICS_SOURCES
              if s != "fixed" and not structure.extrinsics.get(s)]
    u = " ± U" if structure.budgets else ""
    return ("<table class='structure'><thead><tr><th class='label'>extrinsics</th><th>optical baseline (mm)</th>"
            f"<th>α left (deg)</th><th>α right (deg)</th><th>rotation (deg)</th><th>square (error{u}) (mm)</th>"
            f"<th class='label'>read from</th></tr></thead><tbody>{''.join(lines)}</tbody></table>"
            + (f'<p class="small muted">Not recorded: {_e(", ".join(absent))}.</p>' if absent else ""))


def _budget_items(config: ConfigReport) -> list[tuple[str, object]]:
    budget = config.budget
    if config.status != "measured":
        return []
    if budget is None:
        return [("uncertainty", "no budget recorded (± σ of image noise only)")]
    places = uncertainty_decimals(*budget.components.values(), budget.combined, minimum=4)
    components = ", ".join(f"{name} {_mm(budget.components[name], places)}" if budget.components_recorded or
                           budget.components[name] is not None else f"{name} not recorded"
                           for name in BUDGET_COMPONENTS)
    items: list[tuple[str, object]] = [
        ("U", f"{_mm(budget.expanded, places)} mm (k = {_num(budget.k, 2)})" + ("" if budget.complete else
                                                                           f"{INCOMPLETE_MARK} lower bound")),
        ("u_c", f"{_mm(budget.combined, places)} mm: {components}")]
    if budget.dominant:
        items.append(("dominant", budget.dominant))
    return items


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
        expanded = config.budget.expanded if config.budget else None
        cell = Cell.from_row(row, expanded_mm=expanded, budget_complete=config.budget.complete if config.budget
                             else True)
        items += [("square", f"{_num(row.get('square_mean_mm'))} mm"),
                  ("error", cell.error_text().replace(" (σ noise)", " mm (σ, image noise only)") if expanded is None
                   else f"{cell.error_text()} mm (U)"),
                  ("noise σ", f"{_num(row.get('sigma_mm'), uncertainty_decimals(_finite(row.get('sigma_mm'))))} mm"),
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
    items += _budget_items(config)
    if items:
        parts.append(_kv(items))
    if status == "measured":
        parts.append(_structure_block(config))
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


def _paper_table(cells, label, key_text) -> str:
    """The paper's published values beside ours, per cell (mm)."""
    sources = list(dict.fromkeys(s for c in cells for s in c.ours_mm))
    has_true = any(c.square_true_mm is not None for c in cells)
    head = "".join(f"<th>ours: {_e(s)}</th><th>ours − true</th>" if has_true else f"<th>ours: {_e(s)}</th>"
                   for s in sources)
    rows = []
    for c in cells:
        ours = ""
        for s in sources:
            value = c.ours_mm.get(s)
            ours += f"<td>{_num(value, 4)}</td>"
            if has_true:
                ours += (f"<td>{_num(value - c.square_true_mm, 4, signed=True)}</td>"
                         if value is not None and c.square_true_mm is not None else "<td>–</td>")
        note = f' <span class="small muted">({_e(c.note)})</span>' if c.note else ""
        rows.append(f"<tr><th>{_e(key_text(c.key))}{note}</th><td>{c.paper_mm:.4f}</td>"
                    f"<td>{c.paper_mm - 27.0:+.4f}</td>{ours}<td>{_num(c.square_true_mm, 4)}</td></tr>")
    def rms(values):
        values = [v for v in values if v is not None]
        return (sum(v * v for v in values) / len(values)) ** 0.5 if values else None
    summary = [f"paper: RMS error {rms([c.paper_mm - 27.0 for c in cells]):.3f} mm over {len(cells)} values"]
    for s in sources:
        mine = [c for c in cells if c.ours_mm.get(s) is not None]
        text = f"ours, {s}: {rms([c.ours_mm[s] - 27.0 for c in mine]):.4f} mm against 27"
        if has_true:
            text += f", {_num(rms([c.ours_mm[s] - c.square_true_mm for c in mine if c.square_true_mm]), 4)} " \
                    "against the board as printed"
        summary.append(text + f" ({len(mine)} values)")
    return (f"<details class=\"paper\"><summary><b>{_e(label)}</b>: {_e('; '.join(summary))}</summary>"
            f"<table class=\"paper\"><tr><th></th><th>paper (mm)</th>"
            f"<th>paper − 27</th>{head}<th>board as printed</th></tr>" + "".join(rows) + "</table></details>")


def _answer_section(page: SessionPage) -> str:
    """The first screen: how the error depends on B, Z and alpha, why, and the paper's numbers beside ours."""
    answer = page.answer
    if answer is None or not answer.points:
        return ""
    parts = ['<div class="answer"><h3>How the error depends on B, Z and α, and why</h3>']
    parts += [f"<p>{_e(line)}</p>" for line in answer.lines]
    if page.answer_figure:
        parts.append(_img(page.answer_figure))
        parts.append(f'<p class="small muted">Markers: each configuration\'s measured |error| per extrinsics source; '
                     "lines: the term the model predicts there (1σ: image noise through the triangulation and its "
                     "bias, the calibration's own error (in kinematic mode the design fit's, jointly with the R, T "
                     "it predicts), the structure of the nominal R, T from the rig's stated tolerances or of the "
                     "kinematic one from the landing repeatability, the print's scale) and the paper's γ. A "
                     f"measurement follows the term that dominates it. Image noise: {_e(answer.pixel_sigma_note)}; "
                     "the model, its terms and the comparison with the paper are explained in docs/ERROR_MODEL.md "
                     "of stereo-bench.</p>")
    if answer.table1:
        parts.append(_paper_table(answer.table1, "The paper's Table 1 beside ours: the square (mm) per B and Z "
                                  "(α 90°)", lambda k: k.replace("_", " / ").replace("B", "B ").replace("Z", "Z ")))
    if answer.table2:
        parts.append(_paper_table(answer.table2, "The paper's Table 2 beside ours: the square (mm) per α "
                                  "(the paper: B 100 mm, Z 500 mm; ours: this session's B and Z)",
                                  lambda k: k.replace("alpha", "α ") + "°"))
    parts.append("<h4>The paper's claims</h4><ul>")
    for claim in answer.claims:
        evidence = "".join(f"<li>{_e(e)}</li>" for e in claim.evidence)
        parts.append(f"<li><b>“{_e(claim.claim)}”: {_e(claim.verdict)}.</b><ul>{evidence}</ul></li>")
    parts.append("</ul></div>")
    return "".join(parts)


def _session_section(page: SessionPage, index: int) -> str:
    session = page.session
    parts = [f"<section>{_session_header(session, index)}", _answer_section(page)]
    if page.tables1:
        parts.append("<h3>Measured square per baseline and distance (the paper's Table 1)</h3>")
        parts += [_table_html(table, path, session.key, page.error_csvs.get(table.key, ""), _k_text(session))
                  for table, path in page.tables1]
    if page.tables2:
        parts.append("<h3>Measured square per angle α (the paper's Table 2)</h3>")
        parts += [_table_html(table, path, session.key, page.error_csvs.get(table.key, ""), _k_text(session))
                  for table, path in page.tables2]
    if not page.tables1 and not page.tables2:
        parts.append('<p class="muted">No grid over B, Z or α in this session: see the configurations below.</p>')
    if page.error_figures:
        has_u = any(c.budget is not None for c in session.configs)
        bars = (f"error bars of the expanded uncertainty U ({_k_text(session)}; dashed: U leaves out unknown "
                "components)" if has_u else "error bars of the σ propagated from image noise only (no uncertainty "
                "budget recorded in this session)")
        parts.append("<h3>Error of the measured square (the paper's Figures 8, 9, 11)</h3>")
        parts.append(f'<p class="small muted">Points: measured error with {_e(bars)}; shaded: the rigorous model\'s '
                     "expected error ± σ (image noise only); hollow: partial view; markers on "
                     "the bottom strip: configurations not measured (× infeasible, ■ failed, ▲ outside the limits, "
                     "● not run); series are offset slightly along x so that their error bars do not overlap.</p>")
        parts.append('<div class="figs">' + "".join(_img(ref) for ref in page.error_figures) + "</div>")
    parts.append(_budget_section(page))
    parts.append(_structure_section(page))
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


def _structural_html(section: StructuralSection | None) -> str:
    parts = ['<section><h2 id="structural-error">Structural error: the square per extrinsics source</h2>']
    if section is None or not section.sources:
        parts.append('<p class="missing">No configuration was measured in these sessions: no structural error to '
                     "show.</p></section>")
        return "".join(parts)
    names = ", ".join(SOURCE_LABELS.get(s, s) for s in section.sources)
    parts.append(f'<p class="small muted">The error of the measured square (measured − nominal) against Z, B and α '
                 "in the layout of the paper's Figures 8, 9 and 11, one panel per source of the extrinsics: "
                 f"{_e(names)}. "
                 "Every session given contributes (e.g. one session per [extrinsics] mode); a panel has its own y "
                 "scale. Error bars: U of the measurement's budget where the panel's source is the one the "
                 "measurement used (a square measured again with another source from the same frames has no U of "
                 "its own); σ of image noise where no budget was recorded.</p>")
    if section.missing:
        parts.append('<p class="missing">Not in these sessions: ' + _e(", ".join(
            SOURCE_LABELS.get(m, m) for m in section.missing)) + ". A session measures with the extrinsics of its "
            "[extrinsics] mode; the square with the other sources is there when the campaign recorded it "
            "(a <code>structure</code> event per configuration) or when a session of that mode is added to this "
            "report.</p>")
    if section.duplicates:
        parts.append(f'<p class="small muted">{section.duplicates} configuration(s) were measured with the same source '
                     "in more than one session: each is drawn once, from the session that measured with that source "
                     "(else the first given).</p>")
    parts += [_img(ref) for ref in section.figures]
    if not section.figures:
        parts.append('<p class="muted">No grid over B, Z or α across these sessions: see the structure tables of each '
                     "session.</p>")
    parts.append(f'<p><a class="csv" href="{_e(section.csv)}">CSV of the points</a></p></section>')
    return "".join(parts)


def render_page(pages: Sequence[SessionPage], *, generated: str, version: str, warnings: Sequence[str] = (),
                structural: StructuralSection | None = None) -> str:
    """The whole HTML document."""
    names = ", ".join(page.session.name for page in pages)
    toc = "".join(
        f'<li><a href="#{_e(p.session.key)}">Session {i}: {_e(p.session.name)}</a> {_badge(p.session.status)} '
        f'<span class="small muted">{_e(", ".join(f"{n} {s}" for s, n in status_counts(p.session.rows).items()))}'
        "</span></li>" for i, p in enumerate(pages, start=1))
    session_warnings = {w for p in pages for w in p.session.warnings}
    other_warnings = "".join(f'<div class="warn">{_e(w)}</div>' for w in warnings if w not in session_warnings)
    toc += '<li><a href="#structural-error">Structural error: the square per extrinsics source</a></li>'
    # Summaries (tables, figures, budget, structure, comparison, calibration) of every session first, then the
    # structural error over all sessions, then the configurations.
    body = "".join(_session_section(page, i) for i, page in enumerate(pages, start=1))
    body += _structural_html(structural)
    body += "".join(_configurations_section(page, i) for i, page in enumerate(pages, start=1))
    return (
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n"
        f"<title>stereo-bench report: {_e(names)}</title>\n<style>\n{CSS}\n</style>\n</head>\n<body>\n"
        f"<header><h1>stereo-bench report</h1><p class=\"muted\">{_e(names)} · generated {_e(generated)} by "
        f"stereo-bench {_e(version)} · <a href=\"tables/results.csv\">all results (CSV)</a> · "
        f"<a href=\"report.json\">manifest</a></p>{other_warnings}</header>\n"
        f"<nav><ul>{toc}</ul></nav>\n{body}\n"
        "<footer><p class=\"small muted\">Units: mm and deg. Error = measured square − nominal square. U: the "
        "expanded uncertainty of the measurement's budget (k·u_c); u_c: its combined standard uncertainty; σ: "
        "propagated from the corner noise measured in the frames (first order, image noise only). Statuses: "
        "measured; failed "
        "(tried, could not measure: see its reason); infeasible (predicted before moving: too little of the "
        "target in both views, not run); limit (outside the rig's soft limits, not run); not run (the session "
        f"stopped first). {_e(PARTIAL_MARK)}: measured on a partial view.</p></footer>\n</body>\n</html>\n"
    )


__all__ = ["CSS", "anchor", "render_page"]
