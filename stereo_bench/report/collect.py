"""Read recorded sessions into what a report shows: result rows, calibration quality, frames, predictions,
uncertainty budgets and the rig's structure.

Everything comes from the session directory through :class:`~stereo_bench.campaign.session.SessionReader`
(no path outside it is followed). A configuration without a result (the session stopped first) is
reported as 'not run'. The rigorous first-order model (:mod:`stereo_bench.errormodel.rigorous`)
predicts the σ of each configuration's measured square from its geometry, the nominal optics of the
campaign config and a pixel noise: the corner noise measured in the configuration's frames
(``pixel_sigma_px`` of the analysis), else the mean measured in the session, else
:data:`DEFAULT_PIXEL_SIGMA_PX` — each prediction says which.

Two readers hold every assumption about the shape of the newer records (issues 11 and 12), so that a
change of the recorded shape is a change of one function:

- :func:`budget_of`: the uncertainty budget of a result row (the nested ``uncertainty`` record:
  ``uncertainty_mm``'s keys noise, calibration, structure, target, combined, expanded, k, and what
  they rest on; the columns ``u_combined_mm`` and ``U_expanded_mm``) as a :class:`Budget`; a
  component recorded as None is unknown, never zero.
- :func:`structure_of`: per configuration, the extrinsics actually used, the calibrated ones, the
  kinematic prediction, the nominal geometry and (simulated benches) the truth, each as optical
  baseline, alphas and stereo rotation angle, and the square measured with each extrinsics source
  (with its own budget), as a :class:`Structure`. It reads the ``structure`` event (data: ``mode``,
  ``used``, ``sources``: calibrated | kinematic | nominal | fixed -> {``structure``,
  ``structure_sigma``, ``square_mean_mm``, ``uncertainty``, ``note``}, ``truth``: {``structure``,
  ``square_true_mm``}), the ``truth`` event (``BenchSimulator.truth()``) and the result row's columns,
  and falls back on what older sessions hold (the calibration files, the truth in simulated frames'
  metadata, the commanded geometry); every value says where it came from.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from stereo_bench.campaign.config import EXTRINSICS_MODES, CampaignConfig
from stereo_bench.campaign.documents import (
    AnalysisEvent,
    CalibrationEvent,
    EventDocument,
    KinematicModelEvent,
    MeasurementFrameEvent,
    StartDocument,
    StructureEvent,
    TruthEvent,
    campaign_outcome,
)
from stereo_bench.campaign.extrinsics import SOURCES
from stereo_bench.campaign.recorded import RecordedStart
from stereo_bench.campaign.router import DocumentRouter, handles
from stereo_bench.campaign.session import SessionError, SessionReader
from stereo_bench.geometry import RigPose, stereo_structure
from stereo_bench.report.tables import NOT_RUN, with_plan
from stereo_bench.report.tables import finite_number as _finite
from stereo_bench.targets import Checkerboard

DEFAULT_PIXEL_SIGMA_PX = 0.1

#: The budget's standard-uncertainty components, in the order the report shows them.
BUDGET_COMPONENTS = ("noise", "calibration", "structure", "target")
#: The extrinsics a configuration is described by, side by side (issue 11 item 3).
EXTRINSICS_SOURCES = ("used", "calibrated", "kinematic", "nominal", "fixed", "truth")
#: What each describes, for the page.
EXTRINSICS_SOURCE_NAMES = {
    "used": "used by the measurement", "calibrated": "calibrated (board views here)",
    "kinematic": "kinematic model's prediction", "nominal": "nominal (commanded B, α)", "fixed": "fixed (a file)",
    "truth": "truth (simulator)",
}
#: The source of extrinsics each mode measures with (its strategy object's ``used``), and back; the modes a square
#: can be measured with are EXTRINSICS_MODES ([extrinsics] mode, in the report's order).
MODE_SOURCE = {mode: SOURCES[mode].used for mode in EXTRINSICS_MODES}
SOURCE_MODE = {source: mode for mode, source in MODE_SOURCE.items()}
#: A structure description: optical baseline |T|, each camera's alpha, the angle of R.
STRUCTURE_KEYS = ("baseline_mm", "alpha_left_deg", "alpha_right_deg", "rotation_deg")
#: Per-configuration events the structure reader takes (written by the campaign on newer sessions).
STRUCTURE_EVENT = "structure"
TRUTH_EVENT = "truth"


@dataclass
class Budget:
    """A configuration's uncertainty budget as recorded (standard uncertainties, mm).

    ``components`` has every name of :data:`BUDGET_COMPONENTS`; None means unknown (not in
    ``combined``, so U is then a lower bound), never zero. ``components_recorded`` is False when the
    row holds only ``u_combined_mm`` / ``U_expanded_mm`` and no component at all.
    """

    components: dict[str, float | None]
    combined: float | None
    expanded: float | None
    k: float | None
    components_recorded: bool = True
    #: u_c for a comparison with the board's true printed square: without the measured board's own print
    #: scale part of ``target`` (recorded as ``combined_vs_true``); None: not recorded, use ``combined``.
    combined_vs_true: float | None = None

    @property
    def unknown(self) -> list[str]:
        return [name for name, value in self.components.items() if value is None]

    @property
    def complete(self) -> bool:
        return self.components_recorded and not self.unknown

    @property
    def dominant(self) -> str | None:
        known = {name: value for name, value in self.components.items() if value is not None}
        return max(known, key=known.__getitem__) if known else None

    def share(self, name: str) -> float | None:
        """The component's share of u_c² (0-1), None when it or u_c is unknown."""
        value = self.components.get(name)
        if value is None or not self.combined:
            return None
        return value * value / (self.combined * self.combined)

    def as_dict(self) -> dict:
        return {**self.components, "combined": self.combined, "expanded": self.expanded, "k": self.k}


@dataclass
class Structure:
    """The rig's structure at one configuration, per extrinsics source, and the square measured with each.

    ``extrinsics``: source (:data:`EXTRINSICS_SOURCES`) -> {baseline_mm, alpha_left_deg, alpha_right_deg,
    rotation_deg} (a value may be None) or None when that source is not known here; ``sigma``: source ->
    their standard uncertainties where recorded; ``origin``: source -> where it was read.
    ``squares_mm``: extrinsics mode (:data:`EXTRINSICS_MODES`) -> the square measured with it, and
    ``budgets`` its uncertainty budget where recorded. ``mode``: the extrinsics the measurement used.
    """

    mode: str | None = None
    mode_origin: str = ""
    extrinsics: dict[str, dict | None] = field(default_factory=lambda: dict.fromkeys(EXTRINSICS_SOURCES))
    sigma: dict[str, dict] = field(default_factory=dict)
    origin: dict[str, str] = field(default_factory=dict)
    notes: dict[str, str] = field(default_factory=dict)
    squares_mm: dict[str, float] = field(default_factory=dict)
    squares_origin: dict[str, str] = field(default_factory=dict)
    budgets: dict[str, Budget] = field(default_factory=dict)
    square_true_mm: float | None = None
    square_true_origin: str = ""

    def value(self, source: str, key: str) -> float | None:
        described = self.extrinsics.get(source)
        return _finite(described.get(key)) if described else None


@dataclass
class ConfigReport:
    """One configuration of a session, as the report shows it."""

    row: dict  # the result row (a synthetic 'not run' row when none was recorded)
    plan: dict | None = None  # its plan entry (predicted visibility, reason)
    calibration: dict | None = None  # analysis.calibration: rms_px, per_view_rms_px, views_used, views_rejected, ...
    frames: list[dict] = field(default_factory=list)  # analysis.frames, without the per-square lists
    frames_failed: list[dict] = field(default_factory=list)
    measurement_frames: list[dict] = field(default_factory=list)  # {'index', 'left', 'right'} relative paths
    has_calibration_files: bool = False
    prediction: dict | None = None  # see predict_configuration()
    budget: Budget | None = None  # see budget_of(); None: no budget recorded
    structure: Structure | None = None  # see structure_of()

    @property
    def config_id(self) -> str:
        return str(self.row.get("config_id"))

    @property
    def status(self) -> str:
        return str(self.row.get("status") or NOT_RUN)


@dataclass
class SessionReport:
    """One session: its identity, config, and per-configuration reports in plan order."""

    key: str  # file-name-safe and unique within the report, e.g. 's1-paper-exp1'
    directory: Path
    reader: SessionReader
    start: StartDocument
    config: CampaignConfig | None
    status: str  # exit status of the last attempt, or 'incomplete'
    configs: list[ConfigReport]
    warnings: list[str] = field(default_factory=list)
    kinematic_fit_rms_px: float | None = None  # the kinematic model's fit RMS (its event), where the session has one

    @property
    def name(self) -> str:
        return str(self.start.config.get("name") or self.directory.name)

    @property
    def description(self) -> str:
        return str(self.start.config.get("description") or "")

    @property
    def rows(self) -> list[dict]:
        return [c.row for c in self.configs]


def safe_key(text: str) -> str:
    """A file-name-safe token: letters, digits, '-' and '_' only."""
    return re.sub(r"[^A-Za-z0-9_-]+", "-", text).strip("-") or "session"


def _load_config(reader: SessionReader, start: StartDocument) -> tuple[CampaignConfig | None, str | None]:
    try:
        return RecordedStart.of(start).campaign, None
    except ValidationError as error:
        first = error.errors()[0]
        where = ".".join(str(part) for part in first.get("loc", ())) or "config"
        return None, (f"{reader.documents_path}: the recorded campaign config does not load "
                      f"({where}: {first.get('msg')}): predictions and annotations are left out")


def _strip_frame(frame: dict) -> dict:
    return {key: value for key, value in frame.items() if key not in ("lengths_mm", "pairs")}


class _ConfigReader(DocumentRouter):
    """What one configuration's events give its report (the events of the attempt that wrote its result)."""

    def __init__(self, report: ConfigReport):
        super().__init__()
        self.report = report

    @handles(AnalysisEvent)
    def analysis(self, event: AnalysisEvent) -> None:
        data = event.data
        self.report.calibration = data.calibration
        self.report.frames = [_strip_frame(f) for f in data.frames]
        self.report.frames_failed = list(data.frames_failed)

    @handles(MeasurementFrameEvent)
    def measurement_frame(self, event: MeasurementFrameEvent) -> None:
        if isinstance(event.frames.get("left"), str) and isinstance(event.frames.get("right"), str):
            self.report.measurement_frames.append({"index": event.data.index, "left": event.frames["left"],
                                                   "right": event.frames["right"]})

    @handles(CalibrationEvent)
    def calibration(self, event: CalibrationEvent) -> None:
        self.report.has_calibration_files = True


def read_session(directory: str | Path, key: str) -> SessionReport:
    """Read one session; raises :class:`SessionError` (naming the file) if it is missing or corrupt."""
    reader = SessionReader(directory).reload()
    start = reader.start()
    warnings = list(reader.warnings)
    config, problem = _load_config(reader, start)
    if problem:
        warnings.append(problem)
    plan = start.plan
    plan_by_id = {str(entry.get("config_id")): entry for entry in plan}
    rows = with_plan([row.stored() for row in reader.results()], plan)
    events: dict[str, list[EventDocument]] = {}
    kinematic_rms = None
    for event in reader.events():
        if event.config_id is not None:
            events.setdefault(event.config_id, []).append(event)
        elif isinstance(event, KinematicModelEvent) and event.data.rms_px is not None:
            kinematic_rms = float(event.data.rms_px)
    configs = []
    for row in rows:
        report = ConfigReport(row=row, plan=plan_by_id.get(str(row.get("config_id"))), budget=budget_of(row))
        _ConfigReader(report).read(events.get(report.config_id, []))
        # the structure's sources are read from the events' JSON (structure_of: the one place that knows them)
        report.structure = structure_of(row, events.get(report.config_id, []),
                                        config=config, calibration=_calibration_loader(reader, report, warnings))
        configs.append(report)
    session = SessionReport(key=key, directory=Path(directory), reader=reader, start=start, config=config,
                            status=_outcome(reader.status(), configs), configs=configs, warnings=warnings,
                            kinematic_fit_rms_px=kinematic_rms)
    add_predictions(session)
    return session


def _outcome(status: str, configs: list[ConfigReport]) -> str:
    """The session's badge: the stop's word, "partial" or "failed" when fewer than planned were measured
    (:func:`stereo_bench.campaign.documents.campaign_outcome`, the word the CLI printed)."""
    counts: dict[str, int] = {}
    for config in configs:
        counts[str(config.status)] = counts.get(str(config.status), 0) + 1
    return campaign_outcome(status, counts)[0]


def _calibration_loader(reader: SessionReader, report: ConfigReport, warnings: list[str]):
    """Reads the configuration's recorded calibration when asked (None when it has none)."""
    if not report.has_calibration_files:
        return None

    def load():
        try:
            return reader.calibration(report.config_id)
        except SessionError as error:
            warnings.append(str(error))
            return None
    return load


# -- the uncertainty budget and the structure (the one place that knows how they are recorded) ---------
def budget_of(row: dict) -> Budget | None:
    """The uncertainty budget of a result row, or None when the row records none (sessions before issue 12).

    Reads the nested ``uncertainty`` record (``uncertainty_mm``'s keys, as
    :meth:`stereo_bench.vision.uncertainty.UncertaintyBudget.as_dict` writes them, with what they rest
    on; an ``uncertainty_mm`` dict is read the same) and the columns ``u_combined_mm`` and
    ``U_expanded_mm``, which win where both are given.
    """
    record = row.get("uncertainty")
    if not isinstance(record, dict):
        record = row.get("uncertainty_mm")
    return budget_from(record if isinstance(record, dict) else {}, combined=row.get("u_combined_mm"),
                       expanded=row.get("U_expanded_mm"))


def budget_from(record: dict, *, combined: object = None, expanded: object = None) -> Budget | None:
    """A :class:`Budget` of an ``uncertainty`` record (None when it holds neither u_c nor U).

    A component that is absent or null is unknown. k: the recorded one, else U / u_c.
    """
    if isinstance(record.get("uncertainty_mm"), dict):
        record = {**record, **record["uncertainty_mm"]}
    u_c = _finite(combined)
    u_c = u_c if u_c is not None else _finite(record.get("combined"))
    U = _finite(expanded)
    U = U if U is not None else _finite(record.get("expanded"))
    k = _finite(record.get("k"))
    if u_c is None and U is None:
        return None
    if k is None and u_c and U is not None:
        k = U / u_c
    if u_c is None and U is not None and k:
        u_c = U / k
    if U is None and u_c is not None and k is not None:
        U = k * u_c
    recorded = any(name in record for name in BUDGET_COMPONENTS)
    components = {name: _finite(record.get(name)) for name in BUDGET_COMPONENTS}
    return Budget(components=components, combined=u_c, expanded=U, k=k, components_recorded=recorded,
                  combined_vs_true=_finite(record.get("combined_vs_true")))


def _described(value: Any) -> dict | None:
    """{baseline_mm, alpha_left_deg, alpha_right_deg, rotation_deg} of a recorded structure, or None."""
    if not isinstance(value, dict):
        return None
    out = {key: _finite(value.get(key)) for key in STRUCTURE_KEYS}
    return out if out["baseline_mm"] is not None else None


def _mode_name(name: object) -> str:
    """An extrinsics mode from a mode or a source name ('calibrated', 'per_config' -> 'per-config')."""
    text = str(name).replace("_", "-")
    return SOURCE_MODE.get(text, text)


def _source_name(name: object) -> str:
    """An extrinsics source from a source or a mode name ('per-config' -> 'calibrated')."""
    text = str(name).replace("_", "-")
    return MODE_SOURCE.get(text, text)


def _mean_structure(structures: list[dict]) -> dict | None:
    if not structures:
        return None
    return {key: (sum(v) / len(v) if (v := [s[key] for s in structures if s.get(key) is not None]) else None)
            for key in STRUCTURE_KEYS}


def _dict(value: Any) -> dict:
    return value if isinstance(value, dict) else {}


def structure_of(row: dict, events: Sequence[EventDocument], *, config: CampaignConfig | None = None,
                 calibration: Any = None) -> Structure:
    """The structure of one configuration from its result row and events (see :class:`Structure`).

    Args:
        row: the configuration's result row.
        events: its event documents (typed, the attempt that wrote the result).
        config: the session's campaign config (the target's nominal square, the extrinsics mode of a
            session that predates the ``extrinsics_mode`` column), or None.
        calibration: a callable returning the configuration's recorded ``StereoCalibration`` (or None):
            read only when the structure event does not give the calibrated extrinsics.

    Preference, per value: the ``structure`` event, then the row's columns (``extrinsics_mode``,
    ``*_used_*``, ``*_true_*``, ``square_true_mm``), then the ``truth`` event, then what older
    sessions hold: the calibration files (per-config sessions: calibrated = used), the truth in
    simulated frames' metadata (mean over the measurement frames), the commanded B and α (nominal).
    """
    out = Structure()
    documents = [e.data for e in events if isinstance(e, StructureEvent)]
    document = documents[-1] if documents else None
    truths = [e.data for e in events if isinstance(e, TruthEvent)]
    truth_event = truths[-1] if truths else None
    sources = document.sources if document is not None else {}
    recorded_truth = (document.truth if document is not None else None) or {}

    # The mode: the row's column, the structure event, the campaign config (sessions before issue 11).
    for value, origin in ((row.get("extrinsics_mode"), "result row"),
                          (document.mode if document is not None else None, "structure event")):
        if isinstance(value, str) and value:
            out.mode, out.mode_origin = _mode_name(value), origin
            break
    else:
        if config is not None:
            out.mode, out.mode_origin = config.extrinsics.mode, "campaign config"

    def put(source: str, described: dict | None, origin: str) -> None:
        if out.extrinsics.get(source) is None and described is not None:
            out.extrinsics[source], out.origin[source] = described, origin

    # Every source the structure event recorded: its structure (and sigma), its square and budget.
    for name, record in sources.items():
        source, mode = _source_name(name), _mode_name(name)
        put(source, _described(record.structure), "structure event")
        if record.structure_sigma is not None:
            out.sigma[source] = {k: _finite(v) for k, v in record.structure_sigma.items()}
        if record.note:
            out.notes[source] = record.note
        if (square := _finite(record.square_mean_mm)) is not None:
            out.squares_mm[mode], out.squares_origin[mode] = square, "structure event"
        if (budget := budget_from(record.uncertainty or {})) is not None:
            out.budgets[mode] = budget
    used_name = document.used if document is not None else None
    if used_name in sources:
        put("used", _described(sources[used_name].structure), "structure event")
        if (sigma := out.sigma.get(_source_name(used_name))) is not None:
            out.sigma["used"] = sigma
    put("truth", _described(recorded_truth.get("structure")), "structure event")

    put("used", _described({"baseline_mm": row.get("baseline_used_mm"), "alpha_left_deg": row.get(
        "alpha_left_used_deg"), "alpha_right_deg": row.get("alpha_right_used_deg")}), "result row")
    put("truth", _described({"baseline_mm": row.get("baseline_true_mm"), "alpha_left_deg": row.get(
        "alpha_left_true_deg"), "alpha_right_deg": row.get("alpha_right_true_deg")}), "result row")
    put("truth", _described(truth_event.structure if truth_event is not None else None), "truth event")
    metas = [meta for e in events if isinstance(e, MeasurementFrameEvent)
             and isinstance(meta := e.data.left.meta, dict) and isinstance(meta.get("truth"), dict)]
    put("truth", _mean_structure([d for m in metas if (d := _described(m["truth"].get("structure")))]),
        "simulated frames' metadata")
    if (out.extrinsics["calibrated"] is None and out.mode in SOURCES and SOURCES[out.mode].calibrates_each_configuration
            and calibration is not None):
        calib = calibration()
        if calib is not None:
            put("calibrated", stereo_structure(calib.R, calib.T), "calibration file")
    baseline, alpha = _finite(row.get("baseline_mm")), _finite(row.get("alpha_deg"))
    if baseline is not None and baseline > 0 and alpha is not None:
        tilt = _finite(row.get("tilt_deg")) or 0.0
        put("nominal", stereo_structure(*RigPose.symmetric(baseline, alpha, tilt).stereo_extrinsics()),
            "commanded B and α")
    # What the measurement used is, by its mode, that source's extrinsics (and the other way round).
    own = MODE_SOURCE.get(out.mode or "")
    if own:
        put("used", out.extrinsics[own], out.origin.get(own, ""))
        put(own, out.extrinsics["used"], out.origin.get("used", ""))

    # The square of the mode the measurement used is the row's (and its budget the row's).
    square = _finite(row.get("square_mean_mm")) if row.get("status") == "measured" else None
    if square is not None and out.mode:
        out.squares_mm[out.mode], out.squares_origin[out.mode] = square, "result row"
        if (budget := budget_of(row)) is not None:
            out.budgets[out.mode] = budget

    # The true square: the row's, the structure and truth events', the frames' print scale x the nominal square.
    target = (truth_event.target if truth_event is not None else None) or {}
    scales = [s for m in metas if (s := _finite(_dict(m["truth"].get("board")).get("print_scale"))) is not None]
    nominal = config.target.square_mm if config is not None else None
    for value, origin in ((row.get("square_true_mm"), "result row"),
                          (recorded_truth.get("square_true_mm"), "structure event"),
                          (target.get("square_true_mm") if target.get("kind") in (None, "target") else None,
                           "truth event"),
                          (nominal * sum(scales) / len(scales) if scales and nominal else None,
                           "simulated frames' metadata (print scale × nominal square)")):
        if (number := _finite(value)) is not None:
            out.square_true_mm, out.square_true_origin = number, origin
            break
    return out


# -- the rigorous prediction -------------------------------------------------------------------------
def measured_pixel_sigma_px(frames: list[dict]) -> float | None:
    """RMS over frames and both cameras of the recorded per-coordinate corner noise (px); None if none."""
    values = []
    for frame in frames:
        for value in frame.get("pixel_sigma_px") or []:
            number = _finite(value)
            if number is not None and number > 0:
                values.append(number)
    return math.sqrt(sum(v * v for v in values) / len(values)) if values else None


def add_predictions(session: SessionReport) -> None:
    """Attach the rigorous prediction to every configuration of ``session`` (in place)."""
    measured = [s for c in session.configs if (s := measured_pixel_sigma_px(c.frames)) is not None]
    session_sigma = math.sqrt(sum(s * s for s in measured) / len(measured)) if measured else None
    for config_report in session.configs:
        own = measured_pixel_sigma_px(config_report.frames)
        if own is not None:
            sigma, source = own, "measured corner noise of this configuration's frames"
        elif session_sigma is not None:
            sigma, source = session_sigma, "mean corner noise measured in this session"
        else:
            sigma, source = DEFAULT_PIXEL_SIGMA_PX, f"assumed {DEFAULT_PIXEL_SIGMA_PX:g} px (no corner noise recorded)"
        config_report.prediction = predict_configuration(config_report.row, session.config, sigma, source)


def predict_configuration(row: dict, config: CampaignConfig | None, pixel_sigma_px: float, source: str) -> dict:
    """The rigorous first-order σ (and noise bias) of the configuration's measured square.

    The row's result is the mean of ``n_frames`` frames with independent noise, so its σ is the
    one-frame σ / √n_frames (frames_per_config of the campaign when nothing was measured).
    Returns a dict: available, reason, pixel_sigma_px, pixel_sigma_source, sigma_frame_mm, sigma_mm,
    bias_mm, expected_error_mm (mm, the error the model expects: noise bias), n_frames, measurable, n_in_both.
    """
    out: dict[str, Any] = {"available": False, "reason": "", "pixel_sigma_px": pixel_sigma_px,
                           "pixel_sigma_source": source, "sigma_frame_mm": None, "sigma_mm": None, "bias_mm": None,
                           "expected_error_mm": None, "n_frames": None, "measurable": None,
                           "n_in_both": None}
    if config is None:
        out["reason"] = "the session's campaign config does not load"
        return out
    target = config.target.build()
    if not isinstance(target, Checkerboard):
        out["reason"] = "the rigorous model takes a checkerboard target"
        return out
    values = {name: _finite(row.get(name)) for name in ("baseline_mm", "distance_mm", "alpha_deg")}
    if any(v is None for v in values.values()):
        out["reason"] = "the result row lacks B, Z or alpha"
        return out
    from stereo_bench.errormodel.rigorous import Setup, predict

    optics = config.cameras.optics
    try:
        setup = Setup.make(values["baseline_mm"], values["distance_mm"], values["alpha_deg"],
                           tilt_deg=_finite(row.get("tilt_deg")) or 0.0, board=target,
                           left=optics.camera_model("left"), right=optics.camera_model("right"))
        prediction = predict(setup, pixel_sigma_px)
    except ValueError as error:
        out["reason"] = f"the model refused the configuration: {error}"
        return out
    n_frames = int(_finite(row.get("n_frames")) or config.capture.frames_per_config)
    out.update(measurable=prediction.measurable, n_in_both=prediction.n_in_both, n_frames=n_frames)
    if prediction.sigma_square_mm is None:
        out["reason"] = prediction.reason or "nothing to measure in both views"
        return out
    # Expected error: what the noise-free measurement with the true calibration misses (0 up to rounding)
    # plus the second-order noise bias; image noise only (calibration errors are not in the model).
    bias = prediction.bias_square_mm or 0.0
    offset = (prediction.square_true_mean_mm or target.square_mm) - target.square_mm
    out.update(available=True, reason=prediction.reason, sigma_frame_mm=prediction.sigma_square_mm,
               sigma_mm=prediction.sigma_square_mm / math.sqrt(n_frames), bias_mm=bias, expected_error_mm=offset + bias)
    return out


def read_sessions(directories: list[str | Path]) -> list[SessionReport]:
    """Read several sessions, each with a unique key (``s1-<name>``, ``s2-<name>``, ...)."""
    sessions = []
    for index, directory in enumerate(directories, start=1):
        session = read_session(directory, key=f"s{index}")
        session.key = f"s{index}-{safe_key(session.name)}"
        sessions.append(session)
    return sessions


__all__ = [
    "BUDGET_COMPONENTS", "DEFAULT_PIXEL_SIGMA_PX", "EXTRINSICS_MODES", "EXTRINSICS_SOURCES", "EXTRINSICS_SOURCE_NAMES",
    "MODE_SOURCE", "SOURCE_MODE", "STRUCTURE_EVENT", "STRUCTURE_KEYS", "TRUTH_EVENT", "Budget", "ConfigReport",
    "SessionReport", "Structure", "add_predictions", "budget_from", "budget_of", "measured_pixel_sigma_px",
    "predict_configuration", "read_session", "read_sessions", "safe_key", "structure_of",
]
