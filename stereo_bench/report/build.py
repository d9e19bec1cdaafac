"""Build a report directory from recorded sessions: tables (CSV), figures (PNG), images (JPEG), one HTML page.

Layout of a report directory::

    index.html                          the page (inline CSS, no script, no network: images are relative files)
    report.json                         what was reported: sessions, files, counts (marks the directory as a report)
    tables/results.csv                  every configuration of every session, with the rigorous prediction
    tables/<session>_table1_A<α>.csv     the paper's Table 1 layout (square per B and Z), per α
    tables/<session>_table2.csv          the paper's Table 2 layout (square per α), per (B, Z)
    tables/<session>_calibration.csv     calibration quality per configuration
    figures/<session>_fig8_A<α>.png      error against Z for each B (the paper's Figure 8)
    figures/<session>_fig9_A<α>.png      error against B for each Z (Figure 9)
    figures/<session>_fig11.png          error against α (Figure 11)
    figures/<session>_comparison.png     |error|, measured σ and predicted σ per configuration
    figures/<session>_calibration.png    per-view reprojection RMS per configuration
    images/<session>/<config>_{corners,rectified}.jpg

The directory is written under a temporary name beside its destination and renamed into place, so a
reader sees the old report or the new one, never a mix. An existing destination is replaced only if
it is a report (it holds ``report.json`` written by this module); recorded data is never touched.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import shutil
import tempfile
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stereo_bench import __version__, atomic
from stereo_bench.campaign.documents import REPORT_COLUMNS
from stereo_bench.campaign.session import DOCUMENTS_FILE, SessionError
from stereo_bench.report import annotate, figures, html
from stereo_bench.report.collect import ConfigReport, SessionReport, read_sessions
from stereo_bench.report.page import ImageRef, SessionPage
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


def _replace_dir(tmp: Path, out: Path) -> None:
    """Rename ``tmp`` to ``out``; a previous report at ``out`` is moved aside first, then removed."""
    old = None
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
    """Temporary report directories a crashed run left beside ``name`` (never referenced by anything)."""
    for path in parent.glob(f".{name}.*{atomic.TEMP_SUFFIX}"):
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)


# -- content -------------------------------------------------------------------------------------------
class _Writer:
    """Writes files into the temporary report directory and remembers them."""

    def __init__(self, root: Path):
        self.root = root
        self.files: list[str] = []

    def write(self, relative: str, data: bytes | str) -> str:
        path = self.root / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data.encode("utf-8") if isinstance(data, str) else data)
        self.files.append(relative)
        return relative

    def figure(self, relative: str, figure, alt: str, caption: str = "") -> ImageRef:
        self.write(relative, figures.png_bytes(figure))
        width, height = (round(v) for v in figure.get_size_inches() * figure.dpi)
        return ImageRef(relative, width, height, alt, caption)

    def image(self, relative: str, image: np.ndarray, alt: str, caption: str = "") -> ImageRef:
        self.write(relative, annotate.encode_jpeg(image))
        return ImageRef(relative, int(image.shape[1]), int(image.shape[0]), alt, caption)


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


def _error_figures(writer: _Writer, session: SessionReport) -> list[ImageRef]:
    rows = session.rows
    predictions = {c.config_id: c.prediction or {} for c in session.configs}
    refs = []
    for (alpha, tilt), group in _angle_groups(rows).items():
        tag, text = _group_tag(alpha, tilt)
        by_b = {_finite(r.get("baseline_mm")) for r in group}
        by_z = {_finite(r.get("distance_mm")) for r in group}
        if any(_distinct([r for r in group if _finite(r.get("baseline_mm")) == b], "distance_mm") > 1 for b in by_b):
            title = f"Error against Z for each B (paper Fig. 8): {session.name}, {text}"
            refs.append(writer.figure(
                f"figures/{session.key}_fig8_{tag}.png",
                figures.error_figure(group, predictions, x_key="distance_mm", series_keys=("baseline_mm",),
                                     title=title), alt=title))
        if any(_distinct([r for r in group if _finite(r.get("distance_mm")) == z], "baseline_mm") > 1 for z in by_z):
            title = f"Error against B for each Z (paper Fig. 9): {session.name}, {text}"
            refs.append(writer.figure(
                f"figures/{session.key}_fig9_{tag}.png",
                figures.error_figure(group, predictions, x_key="baseline_mm", series_keys=("distance_mm",),
                                     title=title), alt=title))
    bz: dict[tuple, set] = {}
    for row in rows:
        key = (_finite(row.get("baseline_mm")), _finite(row.get("distance_mm")), _finite(row.get("tilt_deg")) or 0.0)
        bz.setdefault(key, set()).add(_finite(row.get("alpha_deg")))
    if any(len(alphas - {None}) > 1 for alphas in bz.values()):
        title = f"Error against α (paper Fig. 11): {session.name}"
        refs.append(writer.figure(
            f"figures/{session.key}_fig11.png",
            figures.error_figure(rows, predictions, x_key="alpha_deg", series_keys=("baseline_mm", "distance_mm"),
                                 title=title), alt=title))
    return refs


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
                     + (" (extrinsics fixed from a file)" if session.config.extrinsics.mode == "fixed" else ""))
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
    for table in distance_baseline_tables(rows, prefix=f"{session.key}_"):
        page.tables1.append((table, writer.write(f"tables/{table.key}.csv", table.to_csv())))
    for table in alpha_tables(rows, prefix=f"{session.key}_"):
        page.tables2.append((table, writer.write(f"tables/{table.key}.csv", table.to_csv())))
    page.error_figures = _error_figures(writer, session)
    predictions = {c.config_id: c.prediction or {} for c in session.configs}
    title = f"Measured error beside the rigorous prediction: {session.name}"
    page.comparison = writer.figure(f"figures/{session.key}_comparison.png",
                                    figures.comparison_figure(rows, predictions, title=title), alt=title)
    title = f"Calibration quality (per-view reprojection RMS): {session.name}"
    page.calibration = writer.figure(
        f"figures/{session.key}_calibration.png",
        figures.calibration_figure([(c.config_id, c.status, c.calibration) for c in session.configs], title=title),
        alt=title)
    page.calibration_csv = writer.write(f"tables/{session.key}_calibration.csv",
                                        rows_to_csv(calibration_rows(session)))
    for config in session.configs:
        if images:
            _annotations(writer, session, config, page, warnings)
    return page


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
        tmp = Path(tempfile.mkdtemp(prefix=f".{destination.name}.", suffix=atomic.TEMP_SUFFIX, dir=parent))
    except OSError as error:
        raise ReportError(f"{parent}: cannot write the report ({error.strerror})") from None
    try:
        writer = _Writer(tmp)
        pages = []
        for session in sessions:
            if progress:
                progress(f"{session.name}: {len(session.configs)} configurations")
            pages.append(_session_page(writer, session, images=images, warnings=warnings))
        writer.write("tables/results.csv", rows_to_csv(_result_rows(sessions)))
        generated = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M:%S UTC")
        writer.write("index.html", html.render_page(pages, generated=generated, version=__version__,
                                                    warnings=warnings))
        manifest = {
            "kind": REPORT_KIND, "stereo_bench": __version__, "generated": generated,
            "sessions": [{"directory": str(s.directory), "name": s.name, "key": s.key, "uid": s.start.get("uid"),
                          "exit_status": s.status, "counts": status_counts(s.rows)} for s in sessions],
            "files": sorted(writer.files), "warnings": warnings,
        }
        writer.write(MANIFEST, json.dumps(manifest, indent=1, ensure_ascii=False) + "\n")
        os.chmod(tmp, 0o755)  # mkdtemp makes it 0700
        _replace_dir(tmp, destination)
    except OSError as error:
        shutil.rmtree(tmp, ignore_errors=True)
        raise ReportError(f"{error.filename or destination}: cannot write the report ({error.strerror})") from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return ReportSummary(out=destination, index=destination / "index.html", sessions=sessions,
                         files=sorted(writer.files), warnings=warnings)


__all__ = ["MANIFEST", "ImageRef", "ReportError", "ReportSummary", "SessionPage", "build_report", "check_out",
           "default_out"]
