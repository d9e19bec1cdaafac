"""Build a report directory from recorded sessions: tables (CSV), figures (PNG), images (JPEG), one HTML page.

Layout of a report directory::

    index.html                          the page (inline CSS, no script, no network: images are relative files)
    report.json                         what was reported: sessions, files, counts (marks the directory as a report)
    tables/results.csv                  every configuration of every session, with the rigorous prediction
    tables/<session>_table1_A<α>.csv     the paper's Table 1 layout (square per B and Z), per α
    tables/<session>_table1_A<α>_error.csv   the same grid with 'error +- U'
    tables/<session>_table2.csv          the paper's Table 2 layout (square per α), per (B, Z) (+ _error.csv)
    tables/<session>_calibration.csv     calibration quality per configuration
    tables/<session>_budget.csv          the uncertainty budget per configuration (sessions that record one)
    tables/<session>_structure.csv       per configuration and extrinsics source: B, alphas, rotation, square
    tables/structural.csv                the structural-error figures' points (every session)
    figures/<session>_fig8_A<α>.png      error against Z for each B (the paper's Figure 8)
    figures/<session>_fig9_A<α>.png      error against B for each Z (Figure 9)
    figures/<session>_fig11.png          error against α (Figure 11)
    figures/<session>_comparison.png     |error|, measured σ, predicted σ and U per configuration
    figures/<session>_calibration.png    per-view reprojection RMS per configuration
    figures/<session>_normalised.png     error / u_c per configuration with the ±2 band (sessions with a budget)
    figures/<session>_structure.png      each extrinsics source minus the truth (or the nominal geometry)
    figures/structural_fig8_A<α>.png     Figures 8, 9, 11 with one panel per extrinsics source (all sessions)
    figures/structural_fig9_A<α>.png, figures/structural_fig11.png
    images/<session>/<config>_{corners,rectified}.jpg

The directory is written under a temporary name beside its destination and renamed into place, so a
reader sees the old report or the new one, never a mix. An existing destination is replaced only if
it is a report (it holds ``report.json`` written by this module); recorded data is never touched.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import fcntl
import json
import math
import os
import shutil
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stereo_bench import __version__, atomic, paths
from stereo_bench.campaign.documents import REPORT_COLUMNS
from stereo_bench.campaign.session import DOCUMENTS_FILE, SessionError
from stereo_bench.report import annotate, figures, html
from stereo_bench.report.answer import answer_of
from stereo_bench.report.collect import (
    BUDGET_COMPONENTS,
    EXTRINSICS_MODES,
    EXTRINSICS_SOURCES,
    MODE_SOURCE,
    SOURCE_MODE,
    STRUCTURE_KEYS,
    ConfigReport,
    SessionReport,
    read_sessions,
)
from stereo_bench.report.page import ImageRef, SessionPage, StructuralSection
from stereo_bench.report.tables import (
    alpha_tables,
    distance_baseline_tables,
    format_value,
    rows_to_csv,
    status_counts,
)

MANIFEST = "report.json"
REPORT_KIND = "stereo-bench report"
DEFAULT_DIR_NAME = "report"

# The result row's report columns (stereo_bench.campaign.documents.ResultRow), with K = B / Z after the geometry.
_AFTER_K = REPORT_COLUMNS.index("alpha_deg") + 1
RESULT_COLUMNS = (*REPORT_COLUMNS[:_AFTER_K], "K", *REPORT_COLUMNS[_AFTER_K:])
PREDICTION_COLUMNS = (
    ("predicted_sigma_mm", "sigma_mm"), ("predicted_expected_error_mm", "expected_error_mm"),
    ("predicted_sigma_frame_mm", "sigma_frame_mm"), ("pixel_sigma_px", "pixel_sigma_px"),
    ("pixel_sigma_source", "pixel_sigma_source"), ("prediction_note", "reason"),
)


class ReportError(RuntimeError):
    """The report cannot be written as asked; one line naming the file or directory."""


@dataclass
class ReportSummary:
    out: Path
    index: Path
    sessions: list[SessionReport]
    files: list[str]
    warnings: list[str]

    def counts(self) -> dict[str, int]:
        return status_counts(row for session in self.sessions for row in session.rows)


def _finite(value: object) -> float | None:
    try:
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return None
    return number if math.isfinite(number) else None


# -- destination ---------------------------------------------------------------------------------------
def default_out(sessions: Sequence[str | Path]) -> Path:
    """``SESSION/report`` for one session; several need an explicit --out."""
    if len(sessions) != 1:
        raise ReportError("a report of several sessions needs --out DIR")
    return Path(sessions[0]) / DEFAULT_DIR_NAME


def check_out(out: Path, sessions: Sequence[str | Path]) -> None:
    """Refuse a destination that would replace anything but a previous report."""
    resolved = out.resolve()
    for session in sessions:
        root = Path(session).resolve()
        if resolved == root or root.is_relative_to(resolved):
            raise ReportError(f"{out}: refusing to write the report over the session {session}")
    if out.is_symlink():
        raise ReportError(f"{out}: is a symbolic link; give a directory path")
    if out.exists():
        if not out.is_dir():
            raise ReportError(f"{out}: exists and is not a directory")
        if (out / DOCUMENTS_FILE).exists():
            raise ReportError(f"{out}: is a session directory, not a report: refusing to replace it")
        if any(out.iterdir()) and not _is_report(out):
            raise ReportError(f"{out}: exists and is not a stereo-bench report (no {MANIFEST}): refusing to "
                              "replace it; choose another --out")


def _is_report(directory: Path) -> bool:
    try:
        manifest = json.loads((directory / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(manifest, dict) and manifest.get("kind") == REPORT_KIND


@contextlib.contextmanager
def _locked(directory: Path, *, wait: bool = True) -> Iterator[bool]:
    """An exclusive ``flock`` on a directory while the block runs; yields False if ``wait=False`` and it is held.

    Runs of ``report`` to one --out take the lock of their own temporary directory for their whole life (so
    another run never removes it as stale) and the lock of the parent directory for the swap into place (so
    two swaps never interleave: the last run's report wins, whole).
    """
    fd = os.open(directory, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | os.O_CLOEXEC)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            yield False
            return
        yield True
    finally:
        os.close(fd)  # releases the lock


def _replace_dir(tmp: Path, out: Path) -> None:
    """Rename ``tmp`` to ``out``; a previous report at ``out`` is moved aside first, then removed.

    The swap holds the parent directory's lock: a concurrent run swapping into the same ``out`` waits.
    """
    old = None
    with _locked(out.parent):
        if out.is_symlink() or (out.exists() and not _is_report(out) and any(out.iterdir())):
            raise ReportError(f"{out}: appeared while the report was written and is not a stereo-bench report: "
                              "refusing to replace it")
        if out.exists():
            old = out.parent / f".{out.name}.old-{uuid.uuid4().hex[:8]}{atomic.TEMP_SUFFIX}"
            os.rename(out, old)
        try:
            os.rename(tmp, out)
        except BaseException:
            if old is not None:
                os.rename(old, out)
            raise
        atomic.fsync_dir(out.parent)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def _remove_stale_temps(parent: Path, name: str) -> None:
    """Temporary report directories a crashed run left beside ``name`` (never referenced by anything).

    One that a running report holds locked is another run's work in progress: left alone.
    """
    for path in parent.glob(f".{name}.*{atomic.TEMP_SUFFIX}"):
        if path.is_dir() and not path.is_symlink():
            with contextlib.suppress(OSError), _locked(path, wait=False) as free:
                if free:
                    shutil.rmtree(path, ignore_errors=True)


# -- content -------------------------------------------------------------------------------------------
class _Writer:
    """Writes files into the temporary report directory and remembers them."""

    def __init__(self, root: Path):
        self.root = root
        self.files: list[str] = []
        # Figures drawn from the same inputs (the same configuration in several sessions of one campaign): the
        # PNG drawn once (a 3-D rig view costs ~0.4 s of matplotlib) and written under each session's name.
        self._drawn: dict[tuple, tuple[bytes, int, int]] = {}

    def write(self, relative: str, data: bytes | str) -> str:
        try:  # names come from sessions (config ids, session keys): none may lead out of the report
            path = paths.confined(self.root, relative)
        except paths.OutsideRoot as error:
            raise ReportError(f"report file {relative!r} refused: {error}") from None
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data.encode("utf-8") if isinstance(data, str) else data)
        self.files.append(relative)
        return relative

    def figure(self, relative: str, figure, alt: str, caption: str = "") -> ImageRef:
        return self._png(relative, _drawing(figure), alt, caption)

    def drawn_figure(self, relative: str, key: tuple, draw: Callable[[], object], alt: str,
                     caption: str = "") -> ImageRef:
        """:meth:`figure` of ``draw()``, drawn only the first time ``key`` (everything ``draw`` reads) is seen."""
        if key not in self._drawn:
            self._drawn[key] = _drawing(draw())
        return self._png(relative, self._drawn[key], alt, caption)

    def _png(self, relative: str, drawing: tuple[bytes, int, int], alt: str, caption: str) -> ImageRef:
        data, width, height = drawing
        self.write(relative, data)
        return ImageRef(relative, width, height, alt, caption)

    def image(self, relative: str, image: np.ndarray, alt: str, caption: str = "") -> ImageRef:
        self.write(relative, annotate.encode_jpeg(image))
        return ImageRef(relative, int(image.shape[1]), int(image.shape[0]), alt, caption)


def _drawing(figure) -> tuple[bytes, int, int]:
    """A figure's PNG bytes and its size in pixels."""
    width, height = (round(v) for v in figure.get_size_inches() * figure.dpi)
    return figures.png_bytes(figure), width, height


def _angle_groups(rows: list[dict]) -> dict[tuple, list[dict]]:
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        groups.setdefault((_finite(row.get("alpha_deg")), _finite(row.get("tilt_deg")) or 0.0), []).append(row)
    return dict(sorted(groups.items(), key=lambda item: tuple(-1e300 if v is None else v for v in item[0])))


def _distinct(rows: list[dict], key: str) -> int:
    return len({_finite(row.get(key)) for row in rows} - {None})


def _group_tag(alpha: float | None, tilt: float) -> tuple[str, str]:
    tag = f"A{format_value(alpha)}" if alpha is not None else "A"
    text = f"α = {format_value(alpha)} deg" if alpha is not None else ""
    if tilt:
        tag += f"_T{format_value(tilt)}"
        text += f", tilt {format_value(tilt)} deg"
    return tag.replace(".", "p").replace("-", "m"), text


def _layouts(rows: list[dict]) -> list[tuple[str, str, str, tuple | None, str, tuple[str, ...]]]:
    """The paper's figures these rows make: (figure, tag, text, (α, tilt) of its rows or None: all, x key,
    series keys).

    Figure 8 (against Z for each B) and Figure 9 (against B for each Z) per α (and tilt), when some
    series has more than one point; Figure 11 (against α for each (B, Z)) when some (B, Z) has
    more than one α.
    """
    out = []
    for (alpha, tilt), group in _angle_groups(rows).items():
        tag, text = _group_tag(alpha, tilt)
        by_b = {_finite(r.get("baseline_mm")) for r in group}
        by_z = {_finite(r.get("distance_mm")) for r in group}
        if any(_distinct([r for r in group if _finite(r.get("baseline_mm")) == b], "distance_mm") > 1 for b in by_b):
            out.append(("fig8", tag, text, (alpha, tilt), "distance_mm", ("baseline_mm",)))
        if any(_distinct([r for r in group if _finite(r.get("distance_mm")) == z], "baseline_mm") > 1 for z in by_z):
            out.append(("fig9", tag, text, (alpha, tilt), "baseline_mm", ("distance_mm",)))
    bz: dict[tuple, set] = {}
    for row in rows:
        key = (_finite(row.get("baseline_mm")), _finite(row.get("distance_mm")), _finite(row.get("tilt_deg")) or 0.0)
        bz.setdefault(key, set()).add(_finite(row.get("alpha_deg")))
    if any(len(alphas - {None}) > 1 for alphas in bz.values()):
        out.append(("fig11", "", "", None, "alpha_deg", ("baseline_mm", "distance_mm")))
    return out


_FIGURE_TITLES = {"fig8": "Error against Z for each B (paper Fig. 8)",
                  "fig9": "Error against B for each Z (paper Fig. 9)", "fig11": "Error against α (paper Fig. 11)"}


def _in_group(row: dict, group: tuple | None) -> bool:
    return group is None or (_finite(row.get("alpha_deg")), _finite(row.get("tilt_deg")) or 0.0) == group


def _bzt(row: dict) -> tuple:
    return _finite(row.get("baseline_mm")), _finite(row.get("distance_mm")), _finite(row.get("tilt_deg")) or 0.0


def _in_alpha_sweep(rows: list[dict]):
    """Keeps the rows of a (B, Z, tilt) that has more than one α (Figure 11's series across sessions)."""
    alphas: dict[tuple, set] = {}
    for row in rows:
        alphas.setdefault(_bzt(row), set()).add(_finite(row.get("alpha_deg")))

    def keep(row: dict, group: tuple | None = None) -> bool:
        return len(alphas.get(_bzt(row), set()) - {None}) > 1
    return keep


def _figure_name(figure: str, tag: str) -> str:
    return f"{figure}_{tag}" if tag else figure


def uncertainties(session: SessionReport) -> dict[str, tuple[float | None, bool]]:
    """config_id -> (U in mm or None, budget complete): the error bars and the tables' ± U."""
    return {c.config_id: (c.budget.expanded, c.budget.complete) if c.budget else (None, True)
            for c in session.configs}


def _error_figures(writer: _Writer, session: SessionReport) -> list[ImageRef]:
    predictions = {c.config_id: c.prediction or {} for c in session.configs}
    expanded = uncertainties(session)
    refs = []
    for figure, tag, text, group, x_key, series_keys in _layouts(session.rows):
        title = f"{_FIGURE_TITLES[figure]}: {session.name}" + (f", {text}" if text else "")
        keep = _in_group if figure != "fig11" else _in_alpha_sweep(session.rows)
        rows = [row for row in session.rows if keep(row, group)]
        refs.append(writer.figure(
            f"figures/{session.key}_{_figure_name(figure, tag)}.png",
            figures.error_figure(rows, predictions, x_key=x_key, series_keys=series_keys, title=title,
                                 uncertainties=expanded), alt=title))
    return refs


def nominal_square_mm(session: SessionReport, row: dict) -> float | None:
    """The target's nominal square: the campaign config's, else the row's square minus its error."""
    if session.config is not None:
        return float(session.config.target.square_mm)
    square, error = _finite(row.get("square_mean_mm")), _finite(row.get("error_mm"))
    return square - error if square is not None and error is not None else None


def budget_rows(session: SessionReport) -> list[list[object]]:
    """One CSV row per measured configuration: the budget's components (empty: unknown), u_c, U, k, dominant,
    the error and the normalised errors."""
    out: list[list[object]] = [["config_id", "extrinsics_mode", "error_mm", *(f"u_{n}_mm" for n in BUDGET_COMPONENTS),
                                "u_combined_mm", "U_expanded_mm", "k", "unknown", "dominant", "dominant_share",
                                "normalised_error", "square_true_mm", "normalised_error_true"]]
    for config in session.configs:
        if config.status != "measured":
            continue
        budget, structure = config.budget, config.structure
        error, z, z_true = _normalised(session, config)
        out.append([
            config.config_id, structure.mode if structure else None, error,
            *((budget.components[n] if budget else None) for n in BUDGET_COMPONENTS),
            budget.combined if budget else None, budget.expanded if budget else None, budget.k if budget else None,
            (" ".join(budget.unknown) if budget.components_recorded else "components not recorded") if budget
            else "no budget recorded",
            budget.dominant if budget else None,
            budget.share(budget.dominant) if budget and budget.dominant else None, z,
            structure.square_true_mm if structure else None, z_true])
    return out


def _normalised(session: SessionReport, config: ConfigReport) -> tuple[float | None, float | None, float | None]:
    """(error against the nominal square, error / u_c, (measured - true square) / u_c) of a measured configuration.

    Against the true square u_c is the budget's ``combined_vs_true`` when recorded (without the measured
    board's own print-scale uncertainty), else u_c."""
    row = config.row
    error = _finite(row.get("error_mm"))
    combined = config.budget.combined if config.budget else None
    z = error / combined if error is not None and combined else None
    square = _finite(row.get("square_mean_mm"))
    true = config.structure.square_true_mm if config.structure else None
    # Against the board's true printed square the board's own print uncertainty is no longer an error source:
    # the budget's combined_vs_true leaves it out (when recorded).
    vs_true = (config.budget.combined_vs_true or combined) if config.budget else None
    z_true = (square - true) / vs_true if square is not None and true is not None and vs_true else None
    return error, z, z_true


def normalised_points(session: SessionReport) -> list[figures.NormalisedPoint]:
    """The normalised-error plot's points: every measured configuration with a budget."""
    points = []
    for config in session.configs:
        if config.status != "measured" or config.budget is None or not config.budget.combined:
            continue
        _, z, z_true = _normalised(session, config)
        points.append(figures.NormalisedPoint(config.config_id, z, z_true, config.budget.complete))
    return points


def _source_mode(structure, source: str) -> str | None:
    """The extrinsics mode whose square a source's row shows ('used': the measurement's; truth: none)."""
    return structure.mode if source == "used" else SOURCE_MODE.get(source)


def structure_rows(session: SessionReport) -> list[list[object]]:
    """Long format: one CSV row per configuration and extrinsics source known there (structure, its σ where
    recorded, where it was read, the square measured with it, its error and U)."""
    out: list[list[object]] = [["config_id", "status", "commanded_baseline_mm", "distance_mm", "commanded_alpha_deg",
                                "extrinsics_mode", "source", *STRUCTURE_KEYS, *(f"{k}_sigma" for k in STRUCTURE_KEYS),
                                "origin", "square_mm", "error_mm", "U_expanded_mm", "square_true_mm", "note"]]
    for config in session.configs:
        structure = config.structure
        if structure is None:
            continue
        row = config.row
        nominal = nominal_square_mm(session, row)
        head = [config.config_id, config.status, row.get("baseline_mm"), row.get("distance_mm"), row.get("alpha_deg"),
                structure.mode]
        for source in EXTRINSICS_SOURCES:
            described = structure.extrinsics.get(source) or {}
            mode = _source_mode(structure, source)
            square = structure.squares_mm.get(mode) if mode else None
            if not described and square is None:
                continue
            budget = structure.budgets.get(mode) if mode else None
            sigma = structure.sigma.get(source) or {}
            out.append([*head, source, *(described.get(k) for k in STRUCTURE_KEYS),
                        *(sigma.get(k) for k in STRUCTURE_KEYS),
                        structure.origin.get(source) or structure.squares_origin.get(mode or ""), square,
                        square - nominal if square is not None and nominal is not None else None,
                        budget.expanded if budget else None,
                        structure.square_true_mm if source == "truth" else None, structure.notes.get(source)])
    return out


def _deviation(writer: _Writer, session: SessionReport, page: SessionPage) -> None:
    """The figure of each source's structure minus the truth (simulated) or the nominal geometry."""
    measured = [c for c in session.configs if c.status == "measured" and c.structure is not None]
    reference = "truth" if any(c.structure.extrinsics["truth"] for c in measured) else "nominal"
    configs = [(c.config_id, c.structure.extrinsics) for c in measured if c.structure.extrinsics[reference]]
    others = [s for s in ("calibrated", "kinematic", "nominal", "fixed") if s != reference]
    if not any(structures.get(s) for _, structures in configs for s in others):
        return
    used = {c.config_id: MODE_SOURCE.get(c.structure.mode or "", "") for c in measured}
    title = f"Extrinsics minus the {reference}: {session.name}"
    page.deviation = writer.figure(f"figures/{session.key}_structure.png",
                                   figures.deviation_figure(configs, reference=reference, title=title, used=used),
                                   alt=title)
    page.deviation_reference = reference


def _result_rows(sessions: Sequence[SessionReport]) -> list[list[object]]:
    header = ["session", *RESULT_COLUMNS, *(name for name, _ in PREDICTION_COLUMNS)]
    out: list[list[object]] = [header]
    for session in sessions:
        for config in session.configs:
            row = dict(config.row)
            baseline, distance = _finite(row.get("baseline_mm")), _finite(row.get("distance_mm"))
            row["K"] = baseline / distance if baseline is not None and distance else None
            prediction = config.prediction or {}
            out.append([session.name, *(row.get(column) for column in RESULT_COLUMNS),
                        *(prediction.get(key) for _, key in PREDICTION_COLUMNS)])
    return out


def calibration_rows(session: SessionReport) -> list[list[object]]:
    """One CSV row per configuration: RMS, epipolar RMS, views used/rejected (with reasons), |T|."""
    out: list[list[object]] = [["config_id", "status", "rms_px", "epipolar_rms_px", "views_used", "views_rejected",
                                "rejected", "per_view_rms_px_left", "per_view_rms_px_right", "T_norm_mm"]]
    for config in session.configs:
        calibration = config.calibration or {}
        per_view = np.asarray(calibration.get("per_view_rms_px") or [], float).reshape(-1, 2)
        rejected = calibration.get("views_rejected") or []
        T = calibration.get("T_mm")
        out.append([
            config.config_id, config.status, calibration.get("rms_px"), calibration.get("epipolar_rms_px"),
            len(calibration.get("views_used") or []) if calibration else None,
            len(rejected) if calibration else None,
            "; ".join(f"view {r.get('index')}: {r.get('reason')}" for r in rejected if isinstance(r, dict)),
            " ".join(f"{v:.4f}" for v in per_view[:, 0]), " ".join(f"{v:.4f}" for v in per_view[:, 1]),
            float(np.linalg.norm(T)) if isinstance(T, list) and len(T) == 3 else None,
        ])
    return out


def _annotations(writer: _Writer, session: SessionReport, config: ConfigReport, page: SessionPage,
                 warnings: list[str]) -> None:
    notes = page.image_notes.setdefault(config.config_id, [])
    if not config.measurement_frames:
        if config.status in ("measured", "failed"):
            notes.append("no measurement frame recorded")
        return
    if session.config is None:
        notes.append("annotations left out: the recorded campaign config does not load")
        return
    frame = config.measurement_frames[0]
    try:
        left, right = session.reader.frame(frame["left"]), session.reader.frame(frame["right"])
    except SessionError as error:
        notes.append(f"frame unreadable: {error}")
        warnings.append(str(error))
        return
    target = session.config.target.build()
    partial = (_finite((config.plan or {}).get("fraction_in_both")) or 1.0) < 1.0
    detections = annotate.detect_pair(left, right, target, partial=partial)
    base = f"images/{session.key}/{config.config_id}"
    refs = page.images.setdefault(config.config_id, [])
    n_left = detections.left.n if detections.left else 0
    n_right = detections.right.n if detections.right else 0
    caption = (f"Measurement frame {frame.get('index')}: left | right, corners detected (left {n_left}, right "
               f"{n_right}; green: in both views, {len(detections.common_ids)}; orange: one view only; red ring: "
               "corner 0)")
    refs.append(writer.image(f"{base}_corners.jpg", annotate.corners_image(left, right, detections),
                             alt=f"{config.config_id}: detected corners", caption=caption))
    if detections.note:
        notes.append(detections.note)
    if not config.has_calibration_files:
        notes.append("rectified pair not shown: no calibration recorded for this configuration"
                     + session.config.extrinsics.source().report_note)
        return
    try:
        calib = session.reader.calibration(config.config_id)
    except SessionError as error:
        notes.append(f"rectified pair not shown: {error}")
        warnings.append(str(error))
        return
    image = annotate.rectified_image(left, right, calib, detections)
    zoomed = len(detections.common_ids) > 0
    refs.append(writer.image(
        f"{base}_rectified.jpg", image, alt=f"{config.config_id}: rectified pair with epipolar lines",
        caption="Rectified pair with horizontal epipolar lines" + (
            ", zoomed onto the target; corners in both views at their rectified positions, one colour per "
            "left/right pair" if zoomed else "")))


def _session_page(writer: _Writer, session: SessionReport, *, images: bool, warnings: list[str]) -> SessionPage:
    page = SessionPage(session=session)
    rows = session.rows
    expanded = uncertainties(session)

    def uncertainty(row: dict) -> tuple[float | None, bool]:
        return expanded.get(str(row.get("config_id")), (None, True))

    for table in distance_baseline_tables(rows, prefix=f"{session.key}_", uncertainty=uncertainty):
        page.tables1.append((table, writer.write(f"tables/{table.key}.csv", table.to_csv())))
        page.error_csvs[table.key] = writer.write(f"tables/{table.key}_error.csv", table.error_csv())
    for table in alpha_tables(rows, prefix=f"{session.key}_", uncertainty=uncertainty):
        page.tables2.append((table, writer.write(f"tables/{table.key}.csv", table.to_csv())))
        page.error_csvs[table.key] = writer.write(f"tables/{table.key}_error.csv", table.error_csv())
    page.error_figures = _error_figures(writer, session)
    page.answer = answer_of(session)
    if page.answer.points:
        against_true = all(p.square_true_mm is not None for p in page.answer.points)
        title = f"Where the error comes from: measured beside each predicted term ({session.name})"
        page.answer_figure = writer.figure(
            f"figures/{session.key}_answer.png",
            figures.answer_figure(page.answer.points, page.answer.sources, title=title, against_true=against_true),
            alt=title)
    predictions = {c.config_id: c.prediction or {} for c in session.configs}
    title = f"Measured error beside the rigorous prediction: {session.name}"
    page.comparison = writer.figure(f"figures/{session.key}_comparison.png",
                                    figures.comparison_figure(rows, predictions, title=title, uncertainties=expanded),
                                    alt=title, caption="Per configuration, how far the measured square is off "
                                    "(|error|, mm, log) beside the σ the frames' corner noise gives, the σ the "
                                    "model predicts from it and the budget's U: an error far above σ comes from "
                                    "something image noise does not explain (the print's scale, the calibration, "
                                    "the structure).")
    if any(c.budget is not None for c in session.configs):
        page.budget_csv = writer.write(f"tables/{session.key}_budget.csv", rows_to_csv(budget_rows(session)))
        ks = sorted({c.budget.k for c in session.configs if c.budget and c.budget.k is not None})
        k = ks[0] if len(ks) == 1 else 2.0
        title = f"Normalised error (error / u_c) per configuration: {session.name}"
        page.normalised = writer.figure(f"figures/{session.key}_normalised.png",
                                        figures.normalised_figure(normalised_points(session), title=title, k=k),
                                        alt=title, caption="Each configuration's error divided by its combined "
                                        f"standard uncertainty u_c: inside the ±{k:g} band the stated uncertainty "
                                        "covers the error; a point outside it is an error the budget does not explain.")
    page.structure_csv = writer.write(f"tables/{session.key}_structure.csv", rows_to_csv(structure_rows(session)))
    _deviation(writer, session, page)
    title = f"Calibration quality (per-view reprojection RMS): {session.name}"
    page.calibration = writer.figure(
        f"figures/{session.key}_calibration.png",
        figures.calibration_figure([(c.config_id, c.status, c.calibration) for c in session.configs], title=title),
        alt=title, caption="Per configuration, each calibration view's reprojection RMS (px; left and right "
        "cameras) and the calibration's overall RMS (bar): a view far above the others is a view to exclude.")
    page.calibration_csv = writer.write(f"tables/{session.key}_calibration.csv",
                                        rows_to_csv(calibration_rows(session)))
    for config in session.configs:
        if images:
            _rig_view(writer, session, config, page)
            _annotations(writer, session, config, page, warnings)
    return page


def _rig_view(writer: _Writer, session: SessionReport, config: ConfigReport, page: SessionPage) -> None:
    """The configuration in 3-D: cameras, frustums and the board (also where nothing was measured: it shows why)."""
    if session.config is None:
        return
    values = [_finite(config.row.get(k)) for k in ("baseline_mm", "alpha_deg", "distance_mm")]
    if any(v is None for v in values):
        return
    baseline, alpha, distance = values
    target = session.config.target.build()
    camera = session.config.cameras.optics.camera_model("camera")
    title = f"{config.config_id}: the rig in 3-D ({config.status})"
    arguments = (baseline, alpha, alpha, _finite(config.row.get("tilt_deg")) or 0.0, distance,
                 tuple(float(v) for v in target.grid_size_mm), camera)
    key = ("rig", *arguments, title)  # a CameraModel hashes and compares by its K, distortion and image size
    try:
        image = writer.drawn_figure(f"images/{session.key}/{config.config_id}_rig.png", key,
                                    lambda: figures.rig_figure(*arguments, title=title), alt=title,
                                    caption=RIG_VIEW_CAPTION)
    except ValueError:
        return  # a pose the geometry refuses (e.g. a camera looking along the baseline): nothing to draw
    page.images.setdefault(config.config_id, []).append(image)


RIG_VIEW_CAPTION = ("The configuration seen from above and behind: both cameras with their fields of view out to the "
                    "target board (its inner-corner grid, green) at Z; a board outside a frustum is not seen by that "
                    "camera.")


def structural_points(sessions: Sequence[SessionReport]) -> tuple[dict[str, list[dict]], dict, int]:
    """Rows for the structural-error figures: per extrinsics mode, one row per configuration geometry.

    Each row is the configuration's geometry with ``error_mm`` = its square measured with that mode
    minus the nominal square; its ``config_id`` is ``<session key>/<config id>/<mode>`` (ids repeat
    across sessions). A configuration measured with the same mode in several sessions is drawn once:
    from the session whose measurement used that mode, else the first given. Configurations without a
    measurement are in every panel (the strip at the bottom). Returns (rows per mode, (U, budget
    complete) per row id where that source's square has a budget, how many duplicates were left out).
    """
    panels: dict[str, dict[tuple, dict]] = {}
    unmeasured: dict[tuple, dict] = {}
    expanded: dict[str, tuple[float | None, bool]] = {}
    duplicates = 0
    for session in sessions:
        for config in session.configs:
            row = config.row
            geometry = tuple(_finite(row.get(k)) for k in ("baseline_mm", "distance_mm", "alpha_deg")) + (
                _finite(row.get("tilt_deg")) or 0.0,)
            base = {key: row.get(key) for key in ("baseline_mm", "distance_mm", "alpha_deg", "tilt_deg",
                                                  "fraction_in_both", "fraction_in_both_measured", "status", "reason")}
            uid = f"{session.key}/{config.config_id}"
            if config.status != "measured" or config.structure is None:
                unmeasured.setdefault(geometry, {**base, "config_id": uid})
                continue
            nominal = nominal_square_mm(session, row)
            for mode, square in config.structure.squares_mm.items():
                if nominal is None:
                    continue
                used = mode == config.structure.mode
                point = {**base, "config_id": f"{uid}/{mode}", "error_mm": square - nominal,
                         "sigma_mm": row.get("sigma_mm") if used else None, "_used": used}
                panel = panels.setdefault(mode, {})
                if geometry in panel:
                    duplicates += 1
                    if not (used and not panel[geometry]["_used"]):
                        continue
                panel[geometry] = point
                if (budget := config.structure.budgets.get(mode)) is not None:
                    expanded[point["config_id"]] = (budget.expanded, budget.complete)
    order = {mode: i for i, mode in enumerate(EXTRINSICS_MODES)}
    rows = {mode: [*panel.values(), *(u for g, u in unmeasured.items() if g not in panel)]
            for mode, panel in sorted(panels.items(), key=lambda item: (order.get(item[0], len(order)), item[0]))}
    return rows, expanded, duplicates


def _structural_section(writer: _Writer, sessions: Sequence[SessionReport]) -> StructuralSection:
    rows, expanded, duplicates = structural_points(sessions)
    section = StructuralSection(sources=list(rows), duplicates=duplicates,
                                missing=[m for m in ("per-config", "kinematic", "nominal") if m not in rows])
    table = [["source", "config", "baseline_mm", "distance_mm", "alpha_deg", "tilt_deg", "error_mm", "U_expanded_mm",
              "used_by_the_measurement"]]
    for mode, points in rows.items():
        for point in points:
            if point.get("status") == "measured":
                table.append([mode, point["config_id"], point["baseline_mm"], point["distance_mm"],
                              point["alpha_deg"], point.get("tilt_deg"), point["error_mm"],
                              expanded.get(point["config_id"], (None, True))[0], point["_used"]])
    section.csv = writer.write("tables/structural.csv", rows_to_csv(table))
    if not rows:
        return section
    union = {id(p): p for points in rows.values() for p in points}
    geometry_rows = list({tuple(_finite(p.get(k)) for k in ("baseline_mm", "distance_mm", "alpha_deg", "tilt_deg")): p
                          for p in union.values()}.values())
    for figure, tag, text, group, x_key, series_keys in _layouts(geometry_rows):
        keep = _in_group if figure != "fig11" else _in_alpha_sweep(geometry_rows)
        panels = [(mode, [p for p in points if keep(p, group)]) for mode, points in rows.items()]
        name = _FIGURE_TITLES[figure]
        title = f"Structural error: {name[0].lower()}{name[1:]}" + (f", {text}" if text else "")
        section.figures.append(writer.figure(
            f"figures/structural_{_figure_name(figure, tag)}.png",
            figures.structural_figure(panels, x_key=x_key, series_keys=series_keys, title=title,
                                      uncertainties=expanded), alt=title))
    return section


def build_report(
    session_dirs: Sequence[str | Path], out: str | Path | None = None, *, images: bool = True,
    progress: Callable[[str], None] | None = None,
) -> ReportSummary:
    """Write the report of ``session_dirs`` to ``out`` (default ``SESSION/report`` for one session).

    Raises :class:`SessionError` for a missing or corrupt session, :class:`ReportError` for a
    destination that cannot be written.
    """
    if not session_dirs:
        raise ReportError("no session given")
    destination = Path(out) if out is not None else default_out(session_dirs)
    check_out(destination, session_dirs)
    sessions = read_sessions(list(session_dirs))
    warnings = [w for s in sessions for w in s.warnings]
    parent = destination.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        _remove_stale_temps(parent, destination.name)
        tmp = atomic.make_temp_dir(parent, prefix=f".{destination.name}.")
    except OSError as error:
        raise ReportError(f"{parent}: cannot write the report ({error.strerror})") from None
    with _locked(tmp):  # ours until renamed: a concurrent run's clean-up leaves it alone
        return _build_into(tmp, destination, sessions, warnings, images=images, progress=progress)


def _build_into(tmp: Path, destination: Path, sessions: list[SessionReport], warnings: list[str], *, images: bool,
                progress: Callable[[str], None] | None) -> ReportSummary:
    try:
        writer = _Writer(tmp)
        pages = []
        for session in sessions:
            if progress:
                progress(f"{session.name}: {len(session.configs)} configurations")
            pages.append(_session_page(writer, session, images=images, warnings=warnings))
        structural = _structural_section(writer, sessions)
        writer.write("tables/results.csv", rows_to_csv(_result_rows(sessions)))
        generated = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M:%S UTC")
        writer.write("index.html", html.render_page(pages, generated=generated, version=__version__,
                                                    warnings=warnings, structural=structural))
        manifest = {
            "kind": REPORT_KIND, "stereo_bench": __version__, "generated": generated,
            "sessions": [{"directory": str(s.directory), "name": s.name, "key": s.key, "uid": s.start.uid,
                          "exit_status": s.status, "counts": status_counts(s.rows)} for s in sessions],
            "files": sorted(writer.files), "warnings": warnings,
        }
        writer.write(MANIFEST, json.dumps(manifest, indent=1, ensure_ascii=False) + "\n")
        _replace_dir(tmp, destination)
    except OSError as error:
        shutil.rmtree(tmp, ignore_errors=True)
        raise ReportError(f"{error.filename or destination}: cannot write the report ({error.strerror})") from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return ReportSummary(out=destination, index=destination / "index.html", sessions=sessions,
                         files=sorted(writer.files), warnings=warnings)


__all__ = ["MANIFEST", "ImageRef", "ReportError", "ReportSummary", "SessionPage", "StructuralSection", "budget_rows",
           "build_report", "check_out", "default_out", "nominal_square_mm", "normalised_points", "structural_points",
           "structure_rows", "uncertainties"]
