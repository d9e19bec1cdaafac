"""PNG figures of a report (matplotlib, Agg canvas; no pyplot, so no global state and no display).

- :func:`error_figure`: the error of the measured square against one axis, one series per value of
  another — the paper's Figure 8 (against Z for each B), Figure 9 (against B for each Z) and
  Figure 11 (against α). Measured points carry error bars of their propagated σ (from the corner
  noise measured in their frames); the band around each series is the rigorous model's expected
  error ± its σ (image noise only). Hollow markers: measured on a partial view. Configurations with
  no measurement sit on a strip at the bottom: × infeasible, ■ failed, ▲ outside the rig's limits,
  ○ not run.
- :func:`comparison_figure`: per configuration, |measured error| beside the measured and predicted σ
  (log scale): how much of the error image noise explains.
- :func:`calibration_figure`: per configuration, the per-view reprojection RMS of the calibration
  (left and right), the overall RMS, and how many views were rejected.
"""

from __future__ import annotations

import io
import math
from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from stereo_bench.report.tables import NOT_RUN, format_value, is_partial
from stereo_bench.report.tables import finite_number as _finite

DPI = 100
#: marker and colour of the configurations that were not measured, on the strip at the bottom of a plot
UNMEASURED_STYLE = {
    "infeasible": ("x", "#555555"),
    "failed": ("s", "#c62828"),
    "limit": ("^", "#ef6c00"),
    NOT_RUN: ("o", "#9e9e9e"),
}
AXIS_LABELS = {
    "distance_mm": "object distance Z (mm)",
    "baseline_mm": "baseline B (mm)",
    "alpha_deg": "angle α between baseline and optical axis (deg)",
}
SERIES_NAMES = {"distance_mm": "Z", "baseline_mm": "B", "alpha_deg": "α"}
SERIES_UNITS = {"distance_mm": "mm", "baseline_mm": "mm", "alpha_deg": "deg"}


def png_bytes(figure: Figure) -> bytes:
    """The figure as PNG bytes."""
    FigureCanvasAgg(figure)
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=DPI)
    return buffer.getvalue()


def _new_figure(width_in: float = 8.0, height_in: float = 4.8) -> Figure:
    return Figure(figsize=(width_in, height_in), dpi=DPI, layout="constrained")


def _series_label(key: str, value: float) -> str:
    return f"{SERIES_NAMES.get(key, key)} = {format_value(value)} {SERIES_UNITS.get(key, '')}".rstrip()


def _status_legend(statuses: set[str], partial: bool, prediction: bool) -> list[Line2D]:
    handles = [Line2D([], [], color="black", marker="o", linestyle="-", label="measured ± propagated σ")]
    if partial:
        handles.append(Line2D([], [], color="black", marker="o", markerfacecolor="white", linestyle="none",
                              label="measured, partial view"))
    if prediction:
        handles.append(Line2D([], [], color="black", alpha=0.3, linewidth=6,
                              label="model: expected error ± σ (image noise)"))
    for status, (marker, colour) in UNMEASURED_STYLE.items():
        if status in statuses:
            handles.append(Line2D([], [], color=colour, marker=marker, linestyle="none",
                                  label=f"{status} (not measured)"))
    return handles


def _series_of(row: Mapping[str, object], keys: Sequence[str]) -> tuple:
    return tuple(_finite(row.get(key)) for key in keys)


def error_figure(
    rows: Sequence[Mapping[str, object]], predictions: Mapping[str, Mapping[str, object]], *, x_key: str,
    series_keys: Sequence[str] = (), title: str,
) -> Figure:
    """Error of the measured square (mm) against ``x_key``, one series per value of ``series_keys``.

    ``predictions`` maps config_id to :func:`stereo_bench.report.collect.predict_configuration` output.
    """
    figure = _new_figure(9.5, 4.8)
    ax = figure.add_subplot()
    colours = [f"C{i}" for i in range(10)]
    series_values = sorted({_series_of(row, series_keys) for row in rows},
                           key=lambda values: tuple(-math.inf if v is None else v for v in values))
    unmeasured: set[str] = set()
    any_partial = any_prediction = False
    xs_all = sorted({v for row in rows if (v := _finite(row.get(x_key))) is not None})
    span = (xs_all[-1] - xs_all[0]) if len(xs_all) > 1 else 1.0
    offset_step = 0.006 * span  # a small horizontal shift per series, so that error bars do not overlap
    for index, value in enumerate(series_values):
        colour = colours[index % len(colours)]
        members = [row for row in rows if _series_of(row, series_keys) == value]
        members.sort(key=lambda row: _finite(row.get(x_key)) or 0.0)
        shift = (index - (len(series_values) - 1) / 2) * offset_step
        label = ", ".join(_series_label(key, v) for key, v in zip(series_keys, value, strict=True)
                          if v is not None) or "measured"
        measured = [row for row in members
                    if row.get("status") == "measured" and _finite(row.get("error_mm")) is not None]
        if measured:
            x = np.array([_finite(row.get(x_key)) for row in measured], float) + shift
            y = np.array([_finite(row.get("error_mm")) for row in measured], float)
            sigma = np.array([_finite(row.get("sigma_mm")) or 0.0 for row in measured], float)
            ax.plot(x, y, color=colour, linewidth=1.2, label=label)
            for xi, yi, si, row in zip(x, y, sigma, measured, strict=True):
                partial = is_partial(row)
                any_partial |= partial
                ax.errorbar([xi], [yi], yerr=[si], color=colour, marker="o", markersize=6, capsize=3,
                            markerfacecolor="white" if partial else colour, linestyle="none")
        else:
            ax.plot([], [], color=colour, marker="o", label=f"{label} (nothing measured)")
        predicted = [(x, p) for row in members if (p := predictions.get(str(row.get("config_id"))))
                     and p.get("available") and (x := _finite(row.get(x_key))) is not None]
        if predicted:
            any_prediction = True
            px = np.array([x for x, _ in predicted]) + shift
            centre = np.array([float(p["expected_error_mm"]) for _, p in predicted])
            width = np.array([float(p["sigma_mm"]) for _, p in predicted])
            if len(px) > 1:
                ax.fill_between(px, centre - width, centre + width, color=colour, alpha=0.18, linewidth=0)
            else:
                ax.errorbar(px, centre, yerr=width, color=colour, alpha=0.35, linewidth=6, linestyle="none")
        for row in members:
            status = str(row.get("status") or NOT_RUN)
            if status == "measured":
                continue
            x_value = _finite(row.get(x_key))
            if x_value is None:
                continue
            unmeasured.add(status)
            marker, strip_colour = UNMEASURED_STYLE.get(status, ("d", "#000000"))
            ax.plot([x_value + shift], [0.04], transform=ax.get_xaxis_transform(), marker=marker, color=strip_colour,
                    markeredgecolor=colour if status != "infeasible" else strip_colour, markersize=8,
                    linestyle="none", clip_on=False)
    ax.axhline(0.0, color="black", linewidth=0.6)
    ax.set_xlabel(AXIS_LABELS.get(x_key, x_key))
    ax.set_ylabel("error of the measured square (mm)")
    ax.set_title(title, fontsize=11)
    if xs_all:
        ax.set_xticks(xs_all)
        ax.set_xticklabels([format_value(v) for v in xs_all])
        margin = 0.06 * span
        ax.set_xlim(xs_all[0] - margin, xs_all[-1] + margin)
    if not any(row.get("status") == "measured" for row in rows):
        ax.text(0.5, 0.5, "no configuration measured", transform=ax.transAxes, ha="center", va="center",
                color="#c62828")
        ax.set_ylim(-1, 1)
    ax.grid(True, alpha=0.3)
    # Legends outside the axes (right), so that they never hide a point.
    if series_keys:
        first = ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
        ax.add_artist(first)
    ax.legend(handles=_status_legend(unmeasured, any_partial, any_prediction), loc="lower left",
              bbox_to_anchor=(1.01, 0.0), fontsize=8)
    return figure


def comparison_figure(
    rows: Sequence[Mapping[str, object]], predictions: Mapping[str, Mapping[str, object]], *, title: str,
) -> Figure:
    """|measured error|, measured (propagated) σ and predicted σ per configuration, log scale (mm)."""
    labels = [str(row.get("config_id")) for row in rows]
    figure = _new_figure(max(8.0, 0.32 * len(rows) + 2.5), 4.2)
    ax = figure.add_subplot()
    x = np.arange(len(rows))
    error = [abs(v) if (v := _finite(row.get("error_mm"))) is not None and row.get("status") == "measured" else np.nan
             for row in rows]
    measured_sigma = [_finite(row.get("sigma_mm")) if row.get("status") == "measured" else None for row in rows]
    predicted_sigma = [_finite(p.get("sigma_mm")) if (p := predictions.get(label)) and p.get("available") else None
                       for label in labels]
    ax.plot(x, error, "o", color="C3", label="|measured error|")
    ax.plot(x, [np.nan if v is None else v for v in measured_sigma], "v", color="C0",
            label="measured σ (propagated from the frames' corner noise)")
    ax.plot(x, [np.nan if v is None else v for v in predicted_sigma], "_", color="black", markersize=14,
            markeredgewidth=2, label="predicted σ (rigorous model)")
    for xi, row in zip(x, rows, strict=True):
        status = str(row.get("status") or NOT_RUN)
        if status != "measured":
            marker, colour = UNMEASURED_STYLE.get(status, ("d", "#000000"))
            ax.plot([xi], [0.04], transform=ax.get_xaxis_transform(), marker=marker, color=colour, linestyle="none")
    values = [v for v in error + measured_sigma + predicted_sigma if v is not None and np.isfinite(v) and v > 0]
    if values:
        ax.set_yscale("log")
    else:
        ax.text(0.5, 0.5, "no configuration measured", transform=ax.transAxes, ha="center", va="center",
                color="#c62828")
    ax.set_xticks(x)
    ax.set_xticklabels(labels, rotation=70, fontsize=7, ha="right")
    ax.set_ylabel("mm")
    ax.set_title(title, fontsize=11)
    ax.grid(True, alpha=0.3, which="both")
    statuses = {str(row.get("status") or NOT_RUN) for row in rows} - {"measured"}
    handles = ax.get_legend_handles_labels()[0] + [
        Line2D([], [], color=UNMEASURED_STYLE[s][1], marker=UNMEASURED_STYLE[s][0], linestyle="none",
               label=f"{s} (not measured)") for s in UNMEASURED_STYLE if s in statuses]
    ax.legend(handles=handles, fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return figure


def calibration_figure(configs: Sequence[tuple[str, str, Mapping[str, object] | None]], *, title: str) -> Figure:
    """Per-view reprojection RMS (px) of each configuration's calibration.

    ``configs``: (config_id, status, analysis calibration dict or None) in plan order.
    """
    figure = _new_figure(max(8.0, 0.32 * len(configs) + 2.5), 4.0)
    ax = figure.add_subplot()
    plotted = False
    for i, (_, status, calibration) in enumerate(configs):
        per_view = np.asarray((calibration or {}).get("per_view_rms_px") or [], float).reshape(-1, 2) \
            if calibration else np.zeros((0, 2))
        if len(per_view):
            plotted = True
            ax.plot(np.full(len(per_view), i - 0.12), per_view[:, 0], ".", color="C0", alpha=0.7)
            ax.plot(np.full(len(per_view), i + 0.12), per_view[:, 1], ".", color="C1", alpha=0.7)
        rms = _finite((calibration or {}).get("rms_px"))
        if rms is not None:
            ax.plot([i - 0.3, i + 0.3], [rms, rms], color="black", linewidth=1.5)
        rejected = (calibration or {}).get("views_rejected") or []
        if rejected:
            ax.annotate(f"{len(rejected)} rejected", (i, 0.02), xycoords=("data", "axes fraction"), ha="center",
                        va="bottom", fontsize=7, color="#c62828", rotation=90)
        if calibration is None:
            marker, colour = UNMEASURED_STYLE.get(status, ("d", "#000000")) if status != "measured" else ("d", "#000")
            ax.plot([i], [0.04], transform=ax.get_xaxis_transform(), marker=marker, color=colour, linestyle="none")
    ax.set_xticks(range(len(configs)))
    ax.set_xticklabels([c[0] for c in configs], rotation=70, fontsize=7, ha="right")
    ax.set_ylabel("reprojection RMS (px)")
    ax.set_title(title, fontsize=11)
    ax.grid(True, alpha=0.3)
    if not plotted:
        ax.text(0.5, 0.5, "no calibration recorded", transform=ax.transAxes, ha="center", va="center",
                color="#c62828")
    handles = [Line2D([], [], color="C0", marker=".", linestyle="none", label="per view, left camera"),
               Line2D([], [], color="C1", marker=".", linestyle="none", label="per view, right camera"),
               Line2D([], [], color="black", label="overall RMS")]
    statuses = {c[1] for c in configs if c[2] is None} - {"measured"}
    handles += [Line2D([], [], color=UNMEASURED_STYLE[s][1], marker=UNMEASURED_STYLE[s][0], linestyle="none",
                       label=f"{s}: no calibration") for s in UNMEASURED_STYLE if s in statuses]
    ax.legend(handles=handles, fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.set_ylim(bottom=0)
    return figure


__all__ = ["AXIS_LABELS", "UNMEASURED_STYLE", "calibration_figure", "comparison_figure", "error_figure", "png_bytes"]
