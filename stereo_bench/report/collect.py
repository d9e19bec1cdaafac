"""Read recorded sessions into what a report shows: result rows, calibration quality, frames, predictions.

Everything comes from the session directory through :class:`~stereo_bench.campaign.session.SessionReader`
(no path outside it is followed). A configuration without a result (the session stopped first) is
reported as 'not run'. The rigorous first-order model (:mod:`stereo_bench.errormodel.rigorous`)
predicts the σ of each configuration's measured square from its geometry, the nominal optics of the
campaign config and a pixel noise: the corner noise measured in the configuration's frames
(``pixel_sigma_px`` of the analysis), else the mean measured in the session, else
:data:`DEFAULT_PIXEL_SIGMA_PX` — each prediction says which.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from stereo_bench.campaign.config import CampaignConfig, recorded_campaign
from stereo_bench.campaign.session import SessionError, SessionReader
from stereo_bench.report.tables import NOT_RUN, with_plan
from stereo_bench.report.tables import finite_number as _finite
from stereo_bench.targets import Checkerboard

DEFAULT_PIXEL_SIGMA_PX = 0.1


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
    start: dict
    config: CampaignConfig | None
    status: str  # exit status of the last attempt, or 'incomplete'
    configs: list[ConfigReport]
    warnings: list[str] = field(default_factory=list)

    @property
    def name(self) -> str:
        return str((self.start.get("config") or {}).get("name") or self.directory.name)

    @property
    def description(self) -> str:
        return str((self.start.get("config") or {}).get("description") or "")

    @property
    def rows(self) -> list[dict]:
        return [c.row for c in self.configs]


def safe_key(text: str) -> str:
    """A file-name-safe token: letters, digits, '-' and '_' only."""
    return re.sub(r"[^A-Za-z0-9_-]+", "-", text).strip("-") or "session"


def _load_config(reader: SessionReader, start: dict) -> tuple[CampaignConfig | None, str | None]:
    try:
        return recorded_campaign(start.get("config") or {}), None
    except ValidationError as error:
        first = error.errors()[0]
        where = ".".join(str(part) for part in first.get("loc", ())) or "config"
        return None, (f"{reader.documents_path}: the recorded campaign config does not load "
                      f"({where}: {first.get('msg')}): predictions and annotations are left out")


def _strip_frame(frame: dict) -> dict:
    return {key: value for key, value in frame.items() if key not in ("lengths_mm", "pairs")}


def read_session(directory: str | Path, key: str) -> SessionReport:
    """Read one session; raises :class:`SessionError` (naming the file) if it is missing or corrupt."""
    reader = SessionReader(directory).reload()
    start = reader.start()
    if not isinstance(start.get("config"), dict) or not isinstance(start.get("plan"), list):
        raise SessionError(f"{reader.documents_path} line 1: start document has no 'config' and 'plan'")
    warnings = list(reader.warnings)
    config, problem = _load_config(reader, start)
    if problem:
        warnings.append(problem)
    plan = [entry for entry in start["plan"] if isinstance(entry, dict)]
    plan_by_id = {str(entry.get("config_id")): entry for entry in plan}
    rows = with_plan(reader.results(), plan)
    events: dict[str, list[dict]] = {}
    for event in reader.events():
        if event.get("config_id") is not None:
            events.setdefault(str(event["config_id"]), []).append(event)
    configs = []
    for row in rows:
        report = ConfigReport(row=row, plan=plan_by_id.get(str(row.get("config_id"))))
        for event in events.get(report.config_id, []):
            kind = event.get("kind")
            data = event.get("data") if isinstance(event.get("data"), dict) else {}
            if kind == "analysis":
                calibration = data.get("calibration")
                report.calibration = calibration if isinstance(calibration, dict) else None
                report.frames = [_strip_frame(f) for f in data.get("frames") or [] if isinstance(f, dict)]
                report.frames_failed = [f for f in data.get("frames_failed") or [] if isinstance(f, dict)]
            elif kind == "measurement_frame":
                frames = event.get("frames") or {}
                if isinstance(frames, dict) and isinstance(frames.get("left"), str) \
                        and isinstance(frames.get("right"), str):
                    report.measurement_frames.append({"index": data.get("index"), "left": frames["left"],
                                                      "right": frames["right"]})
            elif kind == "calibration":
                report.has_calibration_files = True
        configs.append(report)
    session = SessionReport(key=key, directory=Path(directory), reader=reader, start=start, config=config,
                            status=reader.status(), configs=configs, warnings=warnings)
    add_predictions(session)
    return session


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
    "DEFAULT_PIXEL_SIGMA_PX", "ConfigReport", "SessionReport", "add_predictions", "measured_pixel_sigma_px",
    "predict_configuration", "read_session", "read_sessions", "safe_key",
]
