"""PNG figures of a report (matplotlib, Agg canvas; no pyplot, so no global state and no display).

- :func:`error_figure`: the error of the measured square against one axis, one series per value of
  another — the paper's Figure 8 (against Z for each B), Figure 9 (against B for each Z) and
  Figure 11 (against α). Measured points carry error bars of their expanded uncertainty U (the
  row's budget; dashed when the budget has unknown components, so U is a lower bound), or, for a
  row without a budget, of the σ propagated from the corner noise (thin, labelled image noise only);
  the band around each series is the rigorous model's expected error ± its σ (image noise only).
  Hollow markers: measured on a partial view. Configurations with no measurement sit on a strip at
  the bottom: × infeasible, ■ failed, ▲ outside the rig's limits, ○ not run.
- :func:`structural_figure`: the same layout with one panel per extrinsics source (per-config,
  kinematic, nominal): the structural error of issue 11.
- :func:`normalised_figure`: error / u_c per configuration with the ±2 band: does the uncertainty hold?
- :func:`deviation_figure`: per configuration, each extrinsics source's optical baseline and alphas
  minus the truth (or, without a truth, minus the nominal geometry).
- :func:`comparison_figure`: per configuration, |measured error| beside the measured and predicted σ
  and U (log scale): how much of the error image noise explains.
- :func:`calibration_figure`: per configuration, the per-view reprojection RMS of the calibration
  (left and right), the overall RMS, and how many views were rejected.
"""

from __future__ import annotations

import io
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import FuncFormatter, NullLocator

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
#: Marker and colour of each extrinsics source, the same in every figure.
SOURCE_STYLE = {
    "per-config": ("o", "C0"), "calibrated": ("o", "C0"), "kinematic": ("s", "C2"), "nominal": ("^", "C3"),
    "fixed": ("D", "C4"), "used": ("o", "black"), "truth": ("*", "black"),
}
SOURCE_LABELS = {
    "per-config": "per-config extrinsics (calibrated here)", "calibrated": "calibrated here (per-config)",
    "kinematic": "kinematic model", "nominal": "nominal (commanded B, α)", "fixed": "fixed (from a file)",
    "used": "used by the measurement", "truth": "truth",
}
#: (U in mm or None, budget complete) per config_id: the error bars of the error figures.
Uncertainties = Mapping[str, tuple[float | None, bool]]


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


def _status_legend(statuses: set[str], partial: bool, prediction: bool, bars: set[str]) -> list[Line2D]:
    handles = []
    if "U" in bars or not bars:
        handles.append(Line2D([], [], color="black", marker="o", linestyle="-", label="measured ± U (expanded)"))
    if "U*" in bars:
        handles.append(Line2D([], [], color="black", marker="o", linestyle="--",
                              label="± U without unknown components (lower bound)"))
    if "sigma" in bars:
        handles.append(Line2D([], [], color="black", marker="o", linestyle=":", linewidth=0.8,
                              label="± σ, image noise only (no budget)"))
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


def _error_bar(row: Mapping[str, object], uncertainties: Uncertainties | None) -> tuple[float | None, str]:
    """(half height, kind): U ('U', or 'U*' for an incomplete budget), else the noise σ ('sigma'), else None."""
    expanded, complete = (uncertainties or {}).get(str(row.get("config_id")), (None, True))
    if expanded is not None:
        return expanded, "U" if complete else "U*"
    sigma = _finite(row.get("sigma_mm"))
    return (sigma, "sigma") if sigma is not None else (None, "")


@dataclass
class _Drawn:
    unmeasured: set[str] = field(default_factory=set)
    bars: set[str] = field(default_factory=set)
    partial: bool = False
    prediction: bool = False
    measured: bool = False


def _draw_errors(
    ax, rows: Sequence[Mapping[str, object]], predictions: Mapping[str, Mapping[str, object]], *, x_key: str,
    series_keys: Sequence[str], uncertainties: Uncertainties | None, label_series: bool = True,
) -> _Drawn:
    """The error of each row against ``x_key`` on ``ax``, one coloured series per value of ``series_keys``."""
    drawn = _Drawn()
    colours = [f"C{i}" for i in range(10)]
    series_values = sorted({_series_of(row, series_keys) for row in rows},
                           key=lambda values: tuple(-math.inf if v is None else v for v in values))
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
        label = label if label_series else None
        measured = [row for row in members
                    if row.get("status") == "measured" and _finite(row.get("error_mm")) is not None]
        if measured:
            drawn.measured = True
            x = np.array([_finite(row.get(x_key)) for row in measured], float) + shift
            y = np.array([_finite(row.get("error_mm")) for row in measured], float)
            ax.plot(x, y, color=colour, linewidth=1.2, label=label)
            for xi, yi, row in zip(x, y, measured, strict=True):
                partial = is_partial(row)
                drawn.partial |= partial
                half, kind = _error_bar(row, uncertainties)
                face = "white" if partial else colour
                if half is None:  # nothing known: no bar, never a bar of zero
                    ax.plot([xi], [yi], color=colour, marker="o", markersize=6, markerfacecolor=face)
                    continue
                drawn.bars.add(kind)
                bar = ax.errorbar([xi], [yi], yerr=[half], color=colour, marker="o", markersize=6, capsize=3,
                                  markerfacecolor=face, linestyle="none",
                                  elinewidth=0.8 if kind == "sigma" else 1.2)
                if kind != "U":
                    bar.lines[2][0].set_linestyle("--" if kind == "U*" else ":")
        elif label is not None:
            ax.plot([], [], color=colour, marker="o", label=f"{label} (nothing measured)")
        predicted = [(x, p) for row in members if (p := predictions.get(str(row.get("config_id"))))
                     and p.get("available") and (x := _finite(row.get(x_key))) is not None]
        if predicted:
            drawn.prediction = True
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
            drawn.unmeasured.add(status)
            marker, strip_colour = UNMEASURED_STYLE.get(status, ("d", "#000000"))
            ax.plot([x_value + shift], [0.04], transform=ax.get_xaxis_transform(), marker=marker, color=strip_colour,
                    markeredgecolor=colour if status != "infeasible" else strip_colour, markersize=8,
                    linestyle="none", clip_on=False)
    ax.axhline(0.0, color="black", linewidth=0.6)
    ax.set_xlabel(AXIS_LABELS.get(x_key, x_key))
    if xs_all:
        ax.set_xticks(xs_all)
        ax.set_xticklabels([format_value(v) for v in xs_all])
        margin = 0.06 * span
        ax.set_xlim(xs_all[0] - margin, xs_all[-1] + margin)
    if not drawn.measured:
        ax.text(0.5, 0.5, "no configuration measured", transform=ax.transAxes, ha="center", va="center",
                color="#c62828")
        ax.set_ylim(-1, 1)
    ax.grid(True, alpha=0.3)
    return drawn


def error_figure(
    rows: Sequence[Mapping[str, object]], predictions: Mapping[str, Mapping[str, object]], *, x_key: str,
    series_keys: Sequence[str] = (), title: str, uncertainties: Uncertainties | None = None,
) -> Figure:
    """Error of the measured square (mm) against ``x_key``, one series per value of ``series_keys``.

    ``predictions`` maps config_id to :func:`stereo_bench.report.collect.predict_configuration` output;
    ``uncertainties`` config_id to (U mm or None, budget complete): the error bars (rows without U: σ).
    """
    figure = _new_figure(9.5, 4.8)
    ax = figure.add_subplot()
    drawn = _draw_errors(ax, rows, predictions, x_key=x_key, series_keys=series_keys, uncertainties=uncertainties)
    ax.set_ylabel("error of the measured square (mm)")
    ax.set_title(title, fontsize=11)
    # Legends outside the axes (right), so that they never hide a point.
    if series_keys:
        first = ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
        ax.add_artist(first)
    ax.legend(handles=_status_legend(drawn.unmeasured, drawn.partial, drawn.prediction, drawn.bars),
              loc="lower left", bbox_to_anchor=(1.01, 0.0), fontsize=8)
    return figure


def structural_figure(
    panels: Sequence[tuple[str, Sequence[Mapping[str, object]]]], *, x_key: str, series_keys: Sequence[str],
    title: str, uncertainties: Uncertainties | None = None,
) -> Figure:
    """The error of the square against ``x_key`` (series per ``series_keys``), one panel per extrinsics source.

    ``panels``: (source, rows) with each row's ``error_mm`` the square measured with that source minus
    the nominal square. Each panel has its own y scale (nominal extrinsics err by tenths of a mm where
    calibrated ones err by thousandths); error bars as in :func:`error_figure` (U where the source is
    the one the row's budget is for).
    """
    figure = Figure(figsize=(max(9.5, 4.4 * len(panels) + 2.2), 4.6), dpi=DPI, layout="constrained")
    axes = figure.subplots(1, len(panels), squeeze=False)[0]
    drawn = _Drawn()
    for i, (ax, (source, rows)) in enumerate(zip(axes, panels, strict=True)):
        part = _draw_errors(ax, rows, {}, x_key=x_key, series_keys=series_keys, uncertainties=uncertainties,
                            label_series=i == 0)
        drawn.unmeasured |= part.unmeasured
        drawn.bars |= part.bars
        drawn.partial |= part.partial
        marker, colour = SOURCE_STYLE.get(source, ("o", "black"))
        ax.set_title(SOURCE_LABELS.get(source, source), fontsize=10, color=colour)
        if i == 0:
            ax.set_ylabel("error of the measured square (mm)")
    figure.suptitle(title, fontsize=11)
    handles, labels = axes[0].get_legend_handles_labels()
    status = _status_legend(drawn.unmeasured, drawn.partial, False, drawn.bars)
    axes[-1].legend(handles=[*handles, *status], labels=[*labels, *(h.get_label() for h in status)],
                    loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8)
    return figure


@dataclass(frozen=True)
class NormalisedPoint:
    """One configuration of the normalised-error plot: error / u_c against the nominal and the true square."""

    label: str
    nominal: float | None  # (measured - nominal square) / u_c
    true: float | None  # (measured - true square) / u_c, simulated benches
    complete: bool = True  # the budget has every component


def coverage(values: Sequence[float | None], k: float = 2.0) -> tuple[int, float | None, float | None]:
    """(n, RMS, share with |value| <= k) of the normalised errors that are known."""
    known = np.array([v for v in values if v is not None and math.isfinite(v)], float)
    if not len(known):
        return 0, None, None
    return len(known), float(np.sqrt(np.mean(known**2))), float(np.mean(np.abs(known) <= k))


def normalised_figure(points: Sequence[NormalisedPoint], *, title: str, k: float = 2.0) -> Figure:
    """error / u_c per configuration with the ±k band: inside it, |error| <= U.

    Filled circles: against the nominal square; hollow diamonds: against the true square (simulated
    benches). A configuration whose budget has unknown components is marked ``*`` on the x axis: its
    u_c leaves them out, so its |error| / u_c is an upper bound. Beyond ±(k + 1) the axis is
    logarithmic (nominal extrinsics can miss by hundreds of u_c), linear inside.
    """
    figure = _new_figure(max(9.5, 0.3 * len(points) + 3.0), 5.2)
    ax = figure.add_subplot()
    x = np.arange(len(points))
    ax.axhspan(-k, k, color="#2e7d32", alpha=0.10, linewidth=0)
    for level in (-k, k):
        ax.axhline(level, color="#2e7d32", linewidth=1.0)
    for level in (-1.0, 1.0):
        ax.axhline(level, color="#2e7d32", linewidth=0.6, linestyle=":")
    ax.axhline(0.0, color="black", linewidth=0.6)
    handles = [Line2D([], [], color="#2e7d32", linewidth=6, alpha=0.25, label=f"±{k:g}: |error| ≤ U")]
    finite: list[float] = []
    for attribute, marker, face, size, what in (("nominal", "o", "C0", 6, "against the nominal square"),
                                                ("true", "D", "none", 9, "against the true square (simulated)")):
        values = np.array([np.nan if (v := getattr(p, attribute)) is None else v for p in points], float)
        if not np.isfinite(values).any():
            continue
        finite += list(np.abs(values[np.isfinite(values)]))
        n, rms, share = coverage(list(values[np.isfinite(values)]), k)
        ax.plot(x, values, marker, color="C0" if attribute == "nominal" else "black", markerfacecolor=face,
                markersize=size, linestyle="none")
        handles.append(Line2D([], [], color="C0" if attribute == "nominal" else "black", marker=marker,
                              markerfacecolor=face, linestyle="none",
                              label=f"{what}: RMS {rms:.2f}, {share:.0%} within ±{k:g} (n {n})"))
    incomplete = any(not p.complete for p in points)
    if incomplete:
        handles.append(Line2D([], [], linestyle="none", label="*: u_c leaves out unknown components"))
    largest = max(finite) if finite else 0.0
    if largest > k + 1.0:
        ax.set_yscale("symlog", linthresh=k + 1.0, linscale=2.0)  # linear inside the band, logarithmic beyond
        limit = 10 ** math.ceil(math.log10(largest * 1.2))
        ticks = [0.0, 1.0, k] + [10.0**e for e in range(1, int(round(math.log10(limit))) + 1)]
        ax.set_yticks(sorted({*ticks, *(-v for v in ticks)}))
        ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.yaxis.set_minor_locator(NullLocator())
        ax.set_ylim(-limit, limit)
    else:
        ax.set_ylim(-(k + 1.0), k + 1.0)
    if not finite:
        ax.text(0.5, 0.5, "no configuration with a measurement and an uncertainty budget", transform=ax.transAxes,
                ha="center", va="center", color="#c62828")
    ax.set_xticks(x)
    ax.set_xticklabels([p.label + ("*" if not p.complete else "") for p in points], rotation=70,
                       fontsize=7 if len(points) > 12 else 8, ha="right")
    ax.set_xlim(-0.6, len(points) - 0.4)
    ax.set_ylabel("(measured − square) / u_c")
    ax.set_title(title, fontsize=11)
    ax.grid(True, alpha=0.3, axis="y")
    figure.legend(handles=handles, fontsize=8, loc="outside lower center", ncols=2)
    return figure


DEVIATION_KEYS = (("baseline_mm", "optical baseline (mm)"), ("alpha_left_deg", "α left (deg)"),
                  ("alpha_right_deg", "α right (deg)"), ("rotation_deg", "rotation angle (deg)"))


def deviation_figure(
    configs: Sequence[tuple[str, Mapping[str, Mapping[str, float | None] | None]]], *, reference: str, title: str,
    used: Mapping[str, str] | None = None,
) -> Figure:
    """Per configuration, each extrinsics source's structure minus the ``reference`` source's (truth or nominal).

    ``configs``: (label, {source: {baseline_mm, alpha_left_deg, alpha_right_deg, rotation_deg}}); ``used``:
    label -> the source the measurement used (ringed). One row of panels per quantity, one column per
    source, each panel on its own linear scale: nominal extrinsics miss by millimetres where calibrated
    ones miss by hundredths, and a shared or logarithmic scale would hide one or the other.
    """
    sources = [s for s in ("calibrated", "kinematic", "nominal", "fixed") if s != reference
               and any(structures.get(s) for _, structures in configs)]
    columns = max(len(sources), 1)
    width, height = max(8.0, min(14.0, 0.16 * len(configs) * columns + 3.0 * columns)), 8.6
    figure = Figure(figsize=(width, height), dpi=DPI)
    # Fixed margins (inches) rather than a layout engine: a grid of panels laid out by constrained layout costs
    # a second draw, half of this figure's time.
    axes = figure.subplots(len(DEVIATION_KEYS), columns, sharex=True, squeeze=False, gridspec_kw={
        "left": 0.95 / width, "right": 1 - 0.15 / width, "top": 1 - 0.62 / height, "bottom": 1.25 / height,
        "hspace": 0.12, "wspace": 0.22 if columns > 1 else 0.0})
    x = np.arange(len(configs))
    for column, source in enumerate(sources):
        marker, colour = SOURCE_STYLE[source]
        axes[0][column].set_title(SOURCE_LABELS[source], fontsize=10, color=colour)
        for row, (key, name) in enumerate(DEVIATION_KEYS):
            ax = axes[row][column]
            values = []
            for _, structures in configs:
                ref, own = structures.get(reference) or {}, structures.get(source) or {}
                a, b = _finite(own.get(key)), _finite(ref.get(key))
                values.append(np.nan if a is None or b is None else a - b)
            values = np.array(values, float)
            ax.axhline(0.0, color="black", linewidth=0.6)
            ax.plot(x, values, marker, color=colour, linestyle="none", markersize=5)
            ringed = [i for i, (label, _) in enumerate(configs) if (used or {}).get(label) == source]
            if ringed:
                ax.plot(x[ringed], values[ringed], "o", markersize=11, markerfacecolor="none",
                        markeredgecolor="black", linestyle="none")
            if not np.isfinite(values).any():
                ax.text(0.5, 0.5, "not recorded", transform=ax.transAxes, ha="center", va="center",
                        color="#9e9e9e", fontsize=9)
            ax.grid(True, alpha=0.3)
            ax.tick_params(labelsize=8)
            if column == 0:
                ax.set_ylabel(f"Δ {name}", fontsize=9)
    if not sources:
        axes[0][0].text(0.5, 0.5, "no extrinsics besides the reference", transform=axes[0][0].transAxes,
                        ha="center", va="center", color="#9e9e9e")
    for ax in axes[-1]:
        ax.set_xticks(x)
        ax.set_xticklabels([label for label, _ in configs], rotation=70, fontsize=6 if len(configs) > 12 else 7,
                           ha="right")
    figure.suptitle(title + (" (ringed: the extrinsics the measurement used)" if used else ""), fontsize=11)
    return figure


def comparison_figure(
    rows: Sequence[Mapping[str, object]], predictions: Mapping[str, Mapping[str, object]], *, title: str,
    uncertainties: Uncertainties | None = None,
) -> Figure:
    """|measured error|, measured (propagated) σ, predicted σ and U (when recorded) per configuration, log scale."""
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
    expanded = [(uncertainties or {}).get(label, (None, True))[0] if row.get("status") == "measured" else None
                for label, row in zip(labels, rows, strict=True)]
    if any(v is not None for v in expanded):
        ax.plot(x, [np.nan if v is None else v for v in expanded], "^", color="C2", markerfacecolor="none",
                label="U, expanded uncertainty (budget)")
    for xi, row in zip(x, rows, strict=True):
        status = str(row.get("status") or NOT_RUN)
        if status != "measured":
            marker, colour = UNMEASURED_STYLE.get(status, ("d", "#000000"))
            ax.plot([xi], [0.04], transform=ax.get_xaxis_transform(), marker=marker, color=colour, linestyle="none")
    values = [v for v in error + measured_sigma + predicted_sigma + expanded
              if v is not None and np.isfinite(v) and v > 0]
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


#: Line style of each predicted term on the first screen's figure.
TERM_STYLE = {"noise": ("C0", "-"), "bias": ("C0", ":"), "calibration": ("C1", "-"), "target": ("C7", "--"),
              "structure (nominal)": ("C3", "-"), "structure (kinematic)": ("C2", "-"),
              "calibration (kinematic)": ("C2", "--"), "paper's γ": ("k", ":")}


def answer_figure(points: Sequence, sources: Sequence[str], *, title: str, against_true: bool) -> Figure:
    """|error| per measured configuration (markers, per extrinsics source) over the predicted terms (lines), log y.

    ``points``: :class:`stereo_bench.report.answer.AnswerPoint`; ordered by Z, then B, then α (one x slot each).
    ``against_true``: the error against the board as printed (the print's scale drawn as its own term).
    """
    ordered = sorted(points, key=lambda p: (p.distance_mm, p.baseline_mm, p.alpha_deg))
    figure = _new_figure(9.0, 5.0)
    ax = figure.add_subplot()
    x = np.arange(len(ordered))
    terms = [t for t in TERM_STYLE if t != "paper's γ" and any(p.predicted_mm.get(t) for p in ordered)]
    drawn: list[float] = []  # every value drawn: a log axis needs one above zero
    for term in terms:
        colour, style = TERM_STYLE[term]
        y = [p.predicted_mm.get(term) or np.nan for p in ordered]
        drawn += y
        ax.plot(x, y, style, color=colour, lw=1.4, label=f"predicted: {term}")
    gamma = [p.paper_gamma_mm or np.nan for p in ordered]
    if np.isfinite(gamma).any():
        colour, style = TERM_STYLE["paper's γ"]
        drawn += gamma
        ax.plot(x, gamma, style, color=colour, lw=1.2, label="the paper's γ (error of the axes' meeting point)")
    for source in sources:
        marker, colour = SOURCE_STYLE.get(source, ("o", "black"))
        y = [abs(e) if (e := (p.error_true_mm(source) if against_true else p.errors_nominal_mm.get(source)))
             is not None else np.nan for p in ordered]
        drawn += y
        ax.plot(x, y, marker, color=colour, ls="none", ms=6, label=f"measured: {SOURCE_LABELS.get(source, source)}")
    values = np.asarray(drawn, dtype=float)
    log = bool((np.isfinite(values) & (values > 0)).any())
    if log:
        ax.set_yscale("log")
    else:  # nothing above zero (no error against the truth, or every one exactly 0): a log axis would be empty
        ax.text(0.5, 0.5, "no error above zero to draw", transform=ax.transAxes, ha="center", va="center",
                color="#777777")
        ax.set_ylim(bottom=0.0)  # an |error| axis
    ax.set_xticks(x, [f"B{p.baseline_mm:g}" + ("" if abs(p.alpha_deg - 90) < 1e-9 else f" α{p.alpha_deg:g}")
                      for p in ordered], rotation=90, fontsize=7)
    for k in range(1, len(ordered)):
        if ordered[k].distance_mm != ordered[k - 1].distance_mm:
            ax.axvline(k - 0.5, color="#bbbbbb", lw=0.8)
    for z in sorted({p.distance_mm for p in ordered}):
        slots = [k for k, p in enumerate(ordered) if p.distance_mm == z]
        ax.annotate(f"Z {z:g} mm", (np.mean(slots), 1.0), xycoords=("data", "axes fraction"), ha="center",
                    va="bottom", fontsize=8)
    ax.set_ylabel("|error| of the square, mm" + (" (log)" if log else "") + (", vs as printed" if against_true else ""))
    ax.set_xlabel("configuration (baseline B in mm, grouped by object distance Z)")
    ax.set_title(title, fontsize=10, pad=16)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.28), ncol=3, fontsize=7, frameon=False)
    ax.grid(True, which="major", axis="y", alpha=0.3)
    return figure


def rig_figure(baseline_mm: float, alpha_left_deg: float, alpha_right_deg: float, tilt_deg: float, distance_mm: float,
               board_size_mm: tuple[float, float], camera, *, title: str) -> Figure:
    """A 3-D view of one configuration in the rig frame (mm; x along the baseline, z forward, y down): both cameras
    with their view frustums out to the board, the baseline, and the target board facing the rig at Z.

    ``camera``: a :class:`stereo_bench.geometry.CameraModel` (its K and image size give the frustums).
    """
    from stereo_bench.geometry import RigPose, board_pose_facing_rig, transform_points

    pose = RigPose(baseline_mm, alpha_left_deg, alpha_right_deg, tilt_deg, tilt_deg)
    figure = _new_figure(5.2, 4.2)
    ax = figure.add_subplot(projection="3d")
    width, height = camera.image_size
    K_inv = np.linalg.inv(np.asarray(camera.K, float))
    pixels = np.array([[0, 0, 1], [width, 0, 1], [width, height, 1], [0, height, 1]], float)
    rays = (K_inv @ pixels.T).T  # unit depth
    depth = distance_mm * 1.05

    def plot(points: np.ndarray, *args, **kwargs) -> None:
        # Matplotlib's z is up: draw the rig's (x, z, -y) so that forward goes into the picture and up is up.
        ax.plot(points[:, 0], points[:, 2], -points[:, 1], *args, **kwargs)

    for side, T, colour in (("left", pose.T_rig_left, "C0"), ("right", pose.T_rig_right, "C3")):
        centre = T[:3, 3]
        far = transform_points(T, rays * depth)
        for corner in far:
            plot(np.vstack([centre, corner]), color=colour, lw=0.7, alpha=0.6)
        plot(np.vstack([far, far[:1]]), color=colour, lw=0.9, alpha=0.8)
        axis = transform_points(T, np.array([[0.0, 0.0, 0.0], [0.0, 0.0, distance_mm]]))
        plot(axis, "--", color=colour, lw=0.8, label=f"{side} camera, optical axis")
        ax.scatter([centre[0]], [centre[2]], [-centre[1]], color=colour, s=18)
    centres = np.vstack([pose.T_rig_left[:3, 3], pose.T_rig_right[:3, 3]])
    plot(centres, "-", color="black", lw=2.0, label=f"baseline B = {baseline_mm:g} mm")
    board_w, board_h = board_size_mm
    T_board = board_pose_facing_rig(distance_mm=distance_mm, board_size_mm=board_size_mm)
    outline = transform_points(T_board, np.array([[0, 0, 0], [board_w, 0, 0], [board_w, board_h, 0], [0, board_h, 0],
                                                  [0, 0, 0]], float))
    plot(outline, "-", color="#2e7d32", lw=2.0, label=f"target board at Z = {distance_mm:g} mm")
    ax.set_xlabel("x (mm)", fontsize=8)
    ax.set_ylabel("z, forward (mm)", fontsize=8)
    ax.set_zlabel("up (mm)", fontsize=8)
    ax.tick_params(labelsize=6)
    span = max(distance_mm, baseline_mm) * 1.1
    ax.set_xlim(-span / 2, span / 2)
    ax.set_ylim(-0.05 * span, span * 1.0)
    ax.set_zlim(-span / 2, span / 2)
    ax.view_init(elev=22, azim=-62)
    ax.set_title(title, fontsize=9)
    figure.legend(loc="outside lower center", fontsize=7, ncols=2, frameon=False)
    return figure


__all__ = [
    "AXIS_LABELS", "SOURCE_LABELS", "SOURCE_STYLE", "TERM_STYLE", "UNMEASURED_STYLE", "NormalisedPoint",
    "answer_figure", "calibration_figure", "comparison_figure", "coverage", "deviation_figure", "error_figure",
    "normalised_figure", "png_bytes", "rig_figure", "structural_figure",
]
