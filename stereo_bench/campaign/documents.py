"""The documents of a session: one versioned pydantic model per document and event kind.

A campaign is a stream of documents (bluesky's event model): ``start`` (or ``resume``), then
``event`` documents of known kinds and ``result`` documents, then ``stop``. Every document is
validated against its model before it is written (:meth:`SessionWriter.record`) and parsed into its
model when it is read (:func:`parse_document`), so the format is defined here and nowhere else;
``stereo-bench session schema`` prints it as JSON Schema and docs/SESSION_FORMAT.md explains it.

    draft = Draft(MoveEvent, config_id="B100_Z450_A90", data=RigData(rig=reading.to_dict()))
    document = writer.record(draft)[0]        # stamped (seq, time, attempt), validated, written
    parse_document(json.loads(line))           # -> MoveEvent (or StartDocument, ResultDocument, ...)

The result row (:class:`ResultRow`) is defined once: the columns of ``results.csv`` and of the SQLite
store (:data:`RESULT_COLUMNS`), the report's columns (:data:`REPORT_COLUMNS`) and what a replay
compares (:data:`COMPARED_COLUMNS`) all derive from its fields. Adding a column is one line there.

Versions: :data:`SCHEMA_VERSION` is written into ``start`` and ``resume``; a reader accepts every
version in :data:`READABLE_SCHEMA_VERSIONS`. Version 2 only adds to version 1 (the ``prompt`` event,
``start.bench``, ``resume.plan_drift``, ``stop.resume_command``, typed result columns that version 1
kept as extra keys), so the same models read both. A later change that is not additive gets a new
version number and an upgrade step in :func:`parse_document`.
"""

from __future__ import annotations

import functools
import math
import operator
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Discriminator, Field, Tag, TypeAdapter, ValidationError

SCHEMA_VERSION = 2
READABLE_SCHEMA_VERSIONS = (1, 2)
EXIT_STATUSES = ("success", "aborted", "failed", "interrupted")
ExitStatus = Literal["success", "aborted", "failed", "interrupted"]
ResultStatus = Literal["measured", "failed", "infeasible", "limit"]
BenchName = Literal["simulated", "hardware", "bring-up", "replay"]


def campaign_outcome(exit_status: str, counts: Mapping[str, int]) -> tuple[str, str]:
    """The word a campaign ends with, and why: ``(word, why)``, from the stop's ``exit_status`` and the result
    statuses counted (``{"measured": 1, "infeasible": 5}``; a planned configuration with no result counts too).

    A run that ended normally is "success" only when every planned configuration was measured; "partial" when
    some were and others not (infeasible, outside the limits, failed or not run: issue 23, paper-exp2 measured
    1 of 6 under a green "success"); "failed" when none was. Other stops keep their word.
    """
    if exit_status != "success" or not counts:
        return exit_status, ""
    measured = counts.get("measured", 0)
    total = sum(counts.values())
    if measured == 0:
        return "failed", "nothing was measured"
    if measured < total:
        return "partial", f"{measured} of {total} planned configurations measured"
    return "success", ""


class DocumentError(ValueError):
    """A document that does not follow its schema; one line naming the document and the field."""


def json_safe(value: Any, where: str = "value") -> Any:
    """``value`` as strict JSON data: NaN/inf → None, numpy scalars/arrays → Python, tuples → lists.

    Dict keys must be strings (numpy strings and ints are converted); anything else that JSON cannot
    hold raises ``TypeError`` naming where it was found (e.g. ``data.rig.pose``).
    """
    if value is None or isinstance(value, bool | str):
        return value
    if isinstance(value, int):
        return int(value)
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, np.generic):
        return json_safe(value.item(), where)
    if isinstance(value, np.ndarray):
        return json_safe(value.tolist(), where)
    if isinstance(value, Path):
        return value.as_posix()
    if isinstance(value, BaseModel):
        return json_safe(value.model_dump(mode="json", exclude_unset=True), where)
    if isinstance(value, Mapping):
        out = {}
        for key, item in value.items():
            if isinstance(key, np.generic):
                key = key.item()
            if isinstance(key, bool) or not isinstance(key, str | int):
                raise TypeError(f"{where}: key {key!r} is not a string")
            out[str(key)] = json_safe(item, f"{where}.{key}")
        return out
    if isinstance(value, list | tuple):
        return [json_safe(item, f"{where}[{i}]") for i, item in enumerate(value)]
    raise TypeError(f"{where}: {type(value).__name__} cannot be stored as JSON")


_STRICT = ConfigDict(extra="forbid")
# Records that a driver describes (rig readings, frame descriptions) may carry more than listed here.
_OPEN = ConfigDict(extra="allow")


# --------------------------------------------------------------------------------------------------
# The result row


def column(description: str, *, compared: bool = False, report: bool = True, added: bool = False,
           scale: str | None = None, uncertainty: str | None = None) -> Any:
    """A scalar result column (CSV, SQLite). ``compared``: a replay must reproduce it (docs/REPLAY.md).

    ``added``: a compared column that sessions recorded before it existed lack; a replay of such a
    session does not compare it (every session recorded since has it).

    A compared number (a float column) states what its replay tolerance is made of
    (:mod:`stereo_bench.campaign.reproduce`): ``scale``, the size of the operands it is computed from
    (``"value"``: the number itself; a column name: it is a difference from, or a dispersion of, numbers that
    size; ``"image_height_px"``: of image rows), and ``uncertainty``, its own standard uncertainty u (a column
    name, ``"a|b"`` for the first the row has; ``"dispersion:RULE"``: an estimate of a spread over nu
    degrees of freedom, u = x / sqrt(2 nu), nu by ``RULE``; ``"structure:KEY"``: the structure sigma the
    recording states for the extrinsics used). A compared column without them (a status, a count, a
    mode) is compared exactly.
    """
    extra: dict[str, Any] = {"compared": compared, "report": report, "added": added}
    if scale is not None or uncertainty is not None:
        if not compared or scale is None or uncertainty is None:
            raise ValueError("scale and uncertainty come together, on a compared column")
        extra.update(scale=scale, uncertainty=uncertainty)
    return Field(None, description=description, json_schema_extra=extra)


def nested(description: str) -> Any:
    """A result field holding a dict or list (e.g. an uncertainty budget): kept in SQLite's JSON ``extra`` column
    and after the columns in the CSV, not a column of its own."""
    return Field(None, description=description, json_schema_extra={"nested": True})


class ResultRow(BaseModel):
    """One configuration's result: the row of ``results.csv`` and of the ``results`` table.

    Field order is column order. A known column that is missing or null is left out of the stored row
    (the store gives it back absent); keys not listed here are kept (SQLite: in the ``extra`` JSON
    column; CSV: after these columns, sorted).
    """

    model_config = ConfigDict(extra="allow")

    config_id: str = Field(min_length=1, description="the configuration's id, e.g. B100_Z450_A90",
                           json_schema_extra={"compared": False, "report": True})
    baseline_mm: float | None = column("baseline B, mm")
    distance_mm: float | None = column("target distance Z from the baseline, mm")
    alpha_deg: float | None = column("angle between the baseline and each optical axis, deg (90 = parallel)")
    status: ResultStatus | None = column("measured | failed | infeasible | limit (outside the rig's soft limits)",
                                         compared=True)
    square_mean_mm: float | None = column("mean measured square side over every frame, mm", compared=True,
                                          scale="value", uncertainty="u_combined_mm|sigma_mm")
    square_std_mm: float | None = column("standard deviation of the individual square sides, mm", compared=True,
                                         scale="square_mean_mm", uncertainty="dispersion:squares")
    n_squares: int | None = column("square sides measured (adjacent corner pairs, all frames)", compared=True)
    error_mm: float | None = column("square_mean_mm minus the nominal side, mm", compared=True,
                                    scale="square_mean_mm", uncertainty="u_combined_mm|sigma_mm")
    sigma_mm: float | None = column("sigma of square_mean_mm propagated from the corner noise, mm", compared=True,
                                    scale="value", uncertainty="dispersion:squares")
    rms_px: float | None = column("stereo calibration RMS reprojection error, px", compared=True,
                                  scale="value", uncertainty="dispersion:calibration_coordinates")
    epipolar_rms_px: float | None = column("rectified epipolar error of the measured corners, px", compared=True,
                                           scale="image_height_px", uncertainty="dispersion:measured_corners")
    toe_in_deg: float | None = column("toe-in of each camera, deg (90 - alpha)")
    tilt_deg: float | None = column("tilt of both cameras, deg (> 0 looks down)")
    fraction_in_both: float | None = column("predicted share of the target's corners in both views")
    depth_mm: float | None = column("mean depth of the measured corners, mm")
    reason: str | None = column("why the configuration failed or was not run")
    attempt: int | None = column("the session attempt that recorded this row", report=False)
    n_frames: int | None = column("measurement frames measured")
    calib_views_used: int | None = column("calibration views the stereo calibration used")
    calib_views_rejected: int | None = column("calibration views it rejected")
    time: str | None = column("when the row was recorded (UTC, ISO-8601)", report=False)
    frame_scatter_mm: float | None = column("standard deviation of the per-frame means, mm", report=False)
    calibration_epipolar_rms_px: float | None = column("epipolar error of the calibration views, px", report=False)
    fraction_in_both_measured: float | None = column("measured share of the target's corners in both views")
    baseline_estimated_mm: float | None = column("|T| of the stereo calibration, mm", report=False)
    extrinsics_mode: str | None = column("where the measurement's R, T came from: per-config | kinematic | nominal | "
                                         "fixed", compared=True, added=True)
    baseline_used_mm: float | None = column("optical baseline |T| of the extrinsics the measurement used, mm",
                                            compared=True, added=True, scale="value",
                                            uncertainty="structure:baseline_mm")
    alpha_left_used_deg: float | None = column("left camera's alpha in the extrinsics the measurement used, deg",
                                               compared=True, added=True, scale="value",
                                               uncertainty="structure:alpha_left_deg")
    alpha_right_used_deg: float | None = column("right camera's alpha in the extrinsics the measurement used, deg",
                                                compared=True, added=True, scale="value",
                                                uncertainty="structure:alpha_right_deg")
    baseline_true_mm: float | None = column("simulated sessions: the true optical baseline at the measurement, mm")
    alpha_left_true_deg: float | None = column("simulated sessions: the left camera's true alpha, deg")
    alpha_right_true_deg: float | None = column("simulated sessions: the right camera's true alpha, deg")
    square_true_mm: float | None = column("simulated sessions: the measured board's printed square as it really "
                                          "is, mm")
    u_combined_mm: float | None = column("combined standard uncertainty u_c of square_mean_mm (noise, calibration, "
                                         "structure, target), mm", compared=True, added=True, scale="value",
                                         uncertainty="dispersion:squares")
    U_expanded_mm: float | None = column("expanded uncertainty U = k u_c (k = 2) of square_mean_mm, mm",
                                         compared=True, added=True, scale="value", uncertainty="dispersion:squares")
    uncertainty: dict | None = nested("the uncertainty budget of square_mean_mm: noise, calibration, structure, "
                                      "target, combined, expanded, k (mm) and what they rest on")

    def stored(self) -> dict[str, Any]:
        """The row as recorded (stream, store): strict JSON values, null known columns left out."""
        data = self.model_dump(mode="json")
        declared = type(self).model_fields
        return {key: value for key, value in data.items() if value is not None or key not in declared}


def _flag(name: str, flag: str, model: type[BaseModel] = ResultRow) -> bool:
    extra = model.model_fields[name].json_schema_extra
    return bool(isinstance(extra, dict) and extra.get(flag))


def columns_of(model: type[BaseModel]) -> tuple[str, ...]:
    """The scalar columns of a result-row model, in field order (nested fields are not columns)."""
    return tuple(name for name in model.model_fields if not _flag(name, "nested", model))


#: Columns of ``results.csv`` and of the SQLite ``results`` table, in this order.
RESULT_COLUMNS: tuple[str, ...] = columns_of(ResultRow)
#: What a replay must reproduce (docs/REPLAY.md): exactly, or within the tolerance of :data:`TOLERANCES`.
COMPARED_COLUMNS: tuple[str, ...] = tuple(name for name in RESULT_COLUMNS if _flag(name, "compared"))
#: Compared numbers -> (scale, uncertainty): what their replay tolerance is made of (:func:`column`); the other
#: compared columns are compared exactly.
TOLERANCES: dict[str, tuple[str, str]] = {
    name: (extra["scale"], extra["uncertainty"]) for name in COMPARED_COLUMNS
    if isinstance(extra := ResultRow.model_fields[name].json_schema_extra, dict) and "scale" in extra}
#: Compared columns added after the first sessions were recorded: compared only when the recording has them.
ADDED_COLUMNS: frozenset[str] = frozenset(name for name in COMPARED_COLUMNS if _flag(name, "added"))
#: What a report's ``tables/results.csv`` shows of each row (in this order).
REPORT_COLUMNS: tuple[str, ...] = tuple(name for name in RESULT_COLUMNS if _flag(name, "report"))


def result_row(row: ResultRow | Mapping[str, Any]) -> ResultRow:
    """A row validated as a :class:`ResultRow` (NaN and numpy values made strict JSON first)."""
    if isinstance(row, ResultRow):
        return row
    try:
        return ResultRow.model_validate(json_safe(dict(row), "row"))
    except ValidationError as error:
        raise DocumentError(_one_line(error, f"result row {row.get('config_id')!r}")) from None


# --------------------------------------------------------------------------------------------------
# Records inside documents


class RigReadingRecord(BaseModel):
    """Where the rig was (``drivers.rig.rig.RigReading.to_dict()``): physical units, source per quantity."""

    model_config = _OPEN

    state: str
    timestamp: float | None = None
    baseline_mm: float | None = None
    toe_in_left_deg: float | None = None
    toe_in_right_deg: float | None = None
    tilt_left_deg: float | None = None
    tilt_right_deg: float | None = None
    target_distance_mm: float | None = None
    machine_position: dict[str, float] | None = None
    sources: dict[str, str] = Field(default_factory=dict)
    alpha_left_deg: float | None = None
    alpha_right_deg: float | None = None


class FrameRecord(BaseModel):
    """One camera's frame as the camera describes it (``drivers.camera.base.Frame.describe()``), no pixels."""

    model_config = _OPEN

    source: str
    sequence: int | None = None
    timestamp_s: float | None = None
    timestamp_source: str | None = None
    shape: list[int]
    dtype: str
    settings: dict[str, Any] = Field(default_factory=dict)
    meta: dict[str, Any] | None = None


class RigData(BaseModel):
    model_config = _STRICT
    rig: RigReadingRecord
    approach: dict[str, int] | None = Field(
        None, description="move: per axis the direction the rig arrived from (+1 increasing, -1 decreasing, 0 "
                          "unknown), from the positions it reported since homing; the kinematic model's backlash")


class ApproachData(BaseModel):
    """A move before a configuration's own, so that it arrives the way the uninterrupted run did
    (``campaign/approach.py``); the configuration's ``move`` event follows."""

    model_config = _STRICT
    action: Literal["approach"] = "approach"
    rig: RigReadingRecord
    target: dict[str, float] = Field(description="the physical values moved to (quantities left alone are absent)")


class ActionData(BaseModel):
    model_config = _STRICT
    action: str


class TrustData(BaseModel):
    """The rig's position taken as right without homing (``[rig] homing = false``): where it stood, and why."""

    model_config = _STRICT
    rig: RigReadingRecord
    reason: str


class ErrorData(BaseModel):
    model_config = _STRICT
    error: str


class AutoCaptureStamp(BaseModel):
    """Why a streamed pair was kept as a calibration view (stereo_bench/campaign/autocapture.py)."""

    model_config = _STRICT
    time_s: float = Field(description="the pair's time stamp, s (the cameras' clock; the bench clock when simulated)")
    offered: int = Field(ge=0, description="its place in the stream (0 = the first pair offered)")
    speed_px_s: float | None = Field(None, description="median corner speed, the larger of the two cameras, px/s")
    novelty: float | None = Field(None, description="L1 distance in (X, Y, size, skew) to the nearest kept view")


class CaptureData(BaseModel):
    """One stereo capture: ``index`` within its step, grab skew ``dt_s`` and both frames' descriptions."""

    model_config = _STRICT
    index: int = Field(ge=0)
    dt_s: float | None = None
    left: FrameRecord
    right: FrameRecord
    retry: int | None = Field(None, ge=0, description="measurement frames: re-capture number (0 = first)")
    auto: AutoCaptureStamp | None = Field(None, description="calibration views taken automatically: when and why "
                                                            "this pair of the stream was kept")


class DetectionRecord(BaseModel):
    """The corners found in one image (:class:`stereo_bench.vision.detect.Detection`), exactly: JSON keeps
    every float64 to the last bit, so a calibration from these gives the numbers the images gave."""

    model_config = _STRICT
    ids: list[int] = Field(description="corner ids (indices into the board's object points)")
    corners_px: list[tuple[float, float]] = Field(description="(x, y) full-resolution pixels, per id")
    image_size: tuple[int, int] = Field(description="(width, height) of the image, px")
    order: str = Field(description="how the ids were assigned: colour, layout, edges or ids")
    sigma_px: list[float | None] | None = Field(None, description="per-coordinate corner noise, px (null: unknown)")

    @classmethod
    def of(cls, detection) -> DetectionRecord | None:
        if detection is None:
            return None
        sigma = None if detection.sigma_px is None else [
            None if not math.isfinite(value) else float(value) for value in detection.sigma_px]
        return cls(ids=[int(i) for i in detection.ids], corners_px=[(float(x), float(y)) for x, y in
                                                                    detection.corners_px],
                   image_size=(int(detection.image_size[0]), int(detection.image_size[1])),
                   order=detection.order, sigma_px=sigma)

    def detection(self):
        """The :class:`~stereo_bench.vision.detect.Detection` recorded (ids int64, corners and sigmas float64)."""
        from stereo_bench.vision.detect import Detection

        sigma = None if self.sigma_px is None else np.array(
            [math.nan if value is None else value for value in self.sigma_px], dtype=np.float64)
        return Detection(ids=np.array(self.ids, dtype=np.int64),
                         corners_px=np.array(self.corners_px, dtype=np.float64).reshape(-1, 2),
                         image_size=tuple(self.image_size), order=self.order, sigma_px=sigma)


class CalibrationDetectionsData(BaseModel):
    """The detections of a calibration view whose frames were not kept (``[capture] keep_frames``)."""

    model_config = _STRICT
    index: int = Field(ge=0, description="the calibration view's index, as in its calibration_view event")
    left: DetectionRecord | None = Field(description="null: the board was not found in the left image")
    right: DetectionRecord | None = Field(description="null: the board was not found in the right image")


class TargetNotFoundData(BaseModel):
    model_config = _STRICT
    index: int = Field(ge=0)
    retry: int = Field(ge=0)
    missing: list[Literal["left", "right"]]
    ambiguous: bool = False


class CalibrationData(BaseModel):
    """A stereo calibration written as OpenCV YAML (``files``: intrinsics, extrinsics)."""

    model_config = _STRICT
    board: str
    mode: str
    rms_px: float | None = None
    baseline_mm: float | None = None
    image_size: list[int]
    views_used: list[int]
    views_rejected: int
    extra: dict[str, Any] = Field(default_factory=dict)


class AnalysisData(BaseModel):
    """Per-view and per-frame figures behind a result (``calibration``: RMS, per-view RMS, T; ``frames``)."""

    model_config = _STRICT
    calibration: dict[str, Any]
    frames: list[dict[str, Any]]
    frames_failed: list[dict[str, Any]] = Field(default_factory=list)


class TranscriptData(BaseModel):
    model_config = _STRICT
    name: str


class TruthData(BaseModel):
    """The simulated bench's ground truth at a configuration's measurement (``BenchSimulator.truth()``);
    never used by the measurement. Keys not listed here (the profile's values, camera poses, lenses) are kept."""

    model_config = _OPEN
    profile: str
    R: list[list[float]]
    T: list[float]
    structure: dict[str, float] | None = Field(description="optical baseline, alphas and rotation angle of R, T")
    target: dict[str, Any] | None = Field(None, description="the board in the scene: pose, print scale, bow, "
                                                            "placement, square_true_mm")
    reported: dict[str, float | None] = Field(default_factory=dict, description="the axes the rig reported")


class ControllerData(BaseModel):
    """The rig controller as read at connect (``GrblRig.controller_info()``): build, options, settings, warnings."""

    model_config = _STRICT
    port: str | None = None
    info: dict[str, Any]
    warnings: list[str] = Field(default_factory=list)


class SourceRecord(BaseModel):
    """One source of extrinsics at a configuration: its R, T, structure and the square measured with it."""

    model_config = _STRICT
    R: list[list[float]]
    T: list[float]
    structure: dict[str, float] = Field(description="baseline_mm, alpha_left_deg, alpha_right_deg, rotation_deg")
    structure_sigma: dict[str, float] | None = Field(None, description="their standard uncertainties, when known")
    square_mean_mm: float | None = Field(None, description="the configuration's frames measured with this source")
    error_mm: float | None = Field(None, description="square_mean_mm minus the nominal square, mm")
    error_true_mm: float | None = Field(None, description="square_mean_mm minus the true printed square (simulated)")
    uncertainty: dict[str, Any] | None = Field(None, description="its budget: noise, calibration, structure, "
                                                                 "target, combined, expanded, k, ... (mm)")
    note: str | None = None


class StructureData(BaseModel):
    """Per configuration: the extrinsics used and every other available source side by side, with the truth."""

    model_config = _STRICT
    mode: str = Field(description="the extrinsics mode the measurement used")
    used: str = Field(description="which entry of sources the measurement used")
    axes: dict[str, float | None] = Field(description="the axis positions the rig reported at the configuration")
    approach: dict[str, int] = Field(default_factory=dict, description="per axis the direction the move arrived "
                                                                       "from: +1 increasing, -1 decreasing, 0 unknown")
    sources: dict[str, SourceRecord] = Field(description="calibrated | kinematic | nominal | fixed -> record")
    truth: dict[str, Any] | None = Field(None, description="simulated sessions: R, T, structure, square_true_mm")


class IntrinsicsData(BaseModel):
    """The intrinsics nominal extrinsics use, read from ``[extrinsics] calib_dir`` (``files``: its intrinsics.yml)."""

    model_config = _STRICT
    source: Literal["calib_dir"]
    path: str = Field(description="the directory it was read from (copied into the session)")


class KinematicModelData(BaseModel):
    """The kinematic rig model the campaign predicts R, T with (``files.model``: the readable TOML)."""

    model_config = _STRICT
    source: Literal["design", "file"]
    path: str | None = Field(None, description="source 'file': the file it was read from (copied into the session)")
    n_views: int | None = None
    rms_px: float | None = None
    visits_used: list[str] = Field(default_factory=list, description="source 'design': the visits fitted")
    views_dropped: list[dict[str, Any]] = Field(default_factory=list)
    fit_s: float | None = None
    error: str | None = Field(None, description="the fit failed: why (no model; configurations fail with it)")
    design: Literal["presented", "fixed-board"] = Field("presented", description="how the design's views were taken")
    identifiability: list[dict[str, Any]] = Field(
        default_factory=list, description="fixed-board: per kinematic parameter whether the design identified it "
                                          "(name, unit, identified, sigma, note)")
    fixed_board: dict[str, Any] | None = Field(
        None, description="fixed-board: the board's fitted pose in the left camera's frame at B_ref and toe-in 0 "
                          "(T 4x4, mm) and the left carriage's share of a baseline change")
    lens_visit: str | None = Field(
        None, description="fixed-board without calib_dir: the intrinsics visit whose lens calibration of presented "
                          "views (its calibration event) was the fit's intrinsics prior; None: calib_dir's, or none")


PromptKind = Literal["target", "manual", "calibration_board", "calibration_view", "calibration_review",
                     "measured_target", "fixed_board", "calibration_stream", "calibration_errors"]


class PromptData(BaseModel):
    """An operator step the runner asked for and who answered it (the first operator to answer wins)."""

    model_config = _STRICT
    prompt: PromptKind
    message: str
    quantity: str | None = Field(None, description="manual prompts: the quantity set by hand, e.g. target_distance_mm")
    value: float | None = Field(None, description="the value asked for, in the quantity's units")
    index: int | None = Field(None, description="calibration views and measured frames: which one")
    answered_by: str = Field(description="the operator that answered: terminal, simulator, web, ...")
    waited_s: float = Field(ge=0, description="seconds between the question and the answer")
    action: str | None = Field(None, description="how it was answered when not plainly (Enter / Continue): "
                                                 "capture_now, discard_last_view, set_threshold, exclude_view, "
                                                 "recalibrate")
    action_value: float | None = Field(None, description="the action's number: a threshold (px), a view's index")


class ViewDiscardedData(BaseModel):
    """The operator dropped a kept calibration view; the next view of the same ``index`` replaces it."""

    model_config = _STRICT
    index: int = Field(ge=0, description="the calibration view dropped (its frames stay recorded)")
    answered_by: str = Field(description="the operator that asked for it")


class CalibrationSelectionData(BaseModel):
    """Calibration views taken automatically at one configuration: every pair of the stream offered, which were kept
    (their ``calibration_view`` events, ``data.auto``) and why the others were not, and how the collection ended."""

    model_config = _STRICT
    capture: Literal["auto"] = "auto"
    rule: dict[str, Any] = Field(description="the AutoCaptureRule's thresholds (px/s, s, 1, views)")
    offered: int = Field(ge=0, description="stereo pairs of the stream offered to the selector")
    kept: int = Field(ge=0, description="views kept (calibration_view events 0..kept-1)")
    unpaired: int = Field(0, ge=0, description="grabs skipped: no pair within [cameras] max_skew_s")
    tally: dict[str, int] = Field(description="pairs per decision: kept, not in both views, moving, settling, not new")
    ended_by: str = Field(description="why the collection ended: the coverage gate, the operator, the presenter")
    gate: str = Field(description="the coverage gate's state at the end, in words")
    started_s: float | None = Field(None, description="time stamp of the first pair offered, s")
    ended_s: float | None = Field(None, description="time stamp of the last pair offered, s")
    collect_s: float = Field(ge=0, description="seconds from the first pair to the last (the presentation time)")
    clock: Literal["bench", "cameras"] = Field(description="whose seconds: the simulated bench's clock or the cameras'")
    decisions: list[tuple[float, str, float | None, float | None]] = Field(
        default_factory=list, description="every pair offered: (time s, reason, speed px/s, novelty)")
    coverage: dict[str, Any] | None = Field(None, description="the kept views' coverage bars per camera")


class CalibrationExclusionsData(BaseModel):
    """What the operator's review of a configuration's per-view errors left out of its calibration (a replay leaves
    out the same): the views with the reason, and the per-view RMS threshold."""

    model_config = _STRICT
    excluded: list[tuple[int, str]] = Field(description="(view index, why): by the operator, by [calibration] "
                                                        "exclude_views, or over the threshold")
    max_view_rms_px: float | None = Field(None, description="views over this RMS (the worse camera's) left out, px")
    recalibrations: int = Field(0, ge=0, description="calibrations the review ran again (r)")
    answered_by: str = Field(description="the operator who accepted the calibration")


class PresentationTimeData(BaseModel):
    """How long the calibration board's presentations took at one configuration (by an operator, or the simulated
    hand): the next plan's estimate per presentation reads it (stereo_bench/campaign/presentation.py)."""

    model_config = _STRICT
    views: int = Field(ge=1, description="calibration views taken")
    seconds: float = Field(ge=0, description="from the first view asked for to the last one taken, s")
    capture: Literal["auto", "enter"] = Field(description="how the views were taken ([capture] calibration_capture)")
    clock: Literal["bench", "wall"] = Field(description="whose seconds: the simulated bench's clock, or the wall "
                                                        "clock at a real bench")


class RunControlData(BaseModel):
    """The run was paused or resumed from outside (a live page, a test)."""

    model_config = _STRICT
    action: Literal["pause", "resume"]
    feed_hold: bool = Field(False, description="pause: a move in progress was feed-held (and resumed after)")


# --------------------------------------------------------------------------------------------------
# Documents


class Document(BaseModel):
    """Every document's header: its type, order in the stream, wall and monotonic time, attempt."""

    model_config = _STRICT

    type: str
    seq: int = Field(ge=0, description="position in the stream, from 0, never reused")
    time: str = Field(description="UTC, ISO-8601 with microseconds and a Z")
    monotonic: float = Field(description="time.monotonic() of the writing process, s")
    attempt: int = Field(ge=0, description="1 for the first run, +1 per resume")


class Host(BaseModel):
    model_config = _OPEN
    hostname: str
    pid: int


class BlasLibrary(BaseModel):
    """A BLAS library loaded in the process, as threadpoolctl reports it."""

    model_config = _OPEN
    package: str | None = Field(None, description="the package that ships it: numpy; opencv_contrib_python_headless "
                                                  "(OpenCV's wheels bring an OpenBLAS for their LAPACK calls)")
    library: str | None = Field(None, description="its file name")
    internal_api: str | None = Field(None, description="openblas, mkl, blis, ...")
    version: str | None = None
    architecture: str | None = Field(None, description="the kernel family chosen at run time (OpenBLAS: "
                                                       "openblas_get_corename(), e.g. Haswell, SkylakeX, Katmai)")
    num_threads: int | None = None
    threading_layer: str | None = None


class CpuRecord(BaseModel):
    model_config = _OPEN
    model: str | None = Field(None, description="e.g. 'AMD EPYC' (/proc/cpuinfo model name; elsewhere the platform's)")
    machine: str | None = Field(None, description="e.g. x86_64, aarch64")
    vector_extensions: list[str] | None = Field(
        None, description="the SIMD extensions present (sse4_2, avx, avx2, fma, avx512f, ..., neon, sve); null: not "
                          "known on this platform")


class NumericEnvironment(BaseModel):
    """What decides the last digits of the computed numbers (``campaign.environment.numeric_environment()``):
    a replay on another environment reproduces them within the tolerance of docs/REPLAY.md, not bit for bit."""

    model_config = _OPEN
    python: str
    numpy: str
    opencv: str
    blas: list[BlasLibrary] = Field(default_factory=list, description="the BLAS libraries loaded (numpy's first)")
    variables: dict[str, str] = Field(default_factory=dict, description="the environment variables that choose "
                                      "kernels or thread counts, where set (OPENBLAS_CORETYPE, OPENBLAS_NUM_THREADS, "
                                      "OMP_NUM_THREADS, OPENCV_CPU_DISABLE, ...)")
    opencv_threads: int | None = Field(None, description="OpenCV's thread count as the process has it set "
                                                         "(vision.calibrate.opencv_threads; the calibration solvers "
                                                         "run on one thread whatever it is)")
    opencv_cpu_features: str | None = Field(None, description="cv2.getCPUFeaturesLine(): the SIMD paths OpenCV "
                                                              "dispatches to (* = built for dispatch, ? = not here)")
    cpu: CpuRecord = Field(default_factory=CpuRecord)


class StartDocument(Document):
    type: Literal["start"] = "start"
    schema_version: int
    uid: str
    config: dict[str, Any] = Field(description="the campaign config (CampaignConfig as JSON)")
    plan: list[dict[str, Any]] = Field(description="the configurations in order (Configuration.as_dict())")
    software: dict[str, Any] = Field(description="versions: stereo_bench, opencv, numpy, python")
    host: Host
    extra: dict[str, Any] = Field(default_factory=dict)
    recovery: dict[str, Any] | None = None
    bench: BenchName | None = Field(None, description="v2: what recorded it: simulated, hardware, bring-up, replay")
    design: list[dict[str, Any]] | None = Field(
        None, description="v2: the visits before the configurations (plan.Visit.as_dict()): the kinematic design "
                          "or the one-off intrinsics calibration; a resume and a replay run these")
    numeric_environment: NumericEnvironment | None = Field(
        None, description="v2: library versions, BLAS kernels and threads, CPU and vector extensions (absent: "
                          "recorded before it was kept)")

    # The recorded config and plan stay as recorded (``config``, ``plan``, ``design``: a resume compares them byte
    # for byte); readers read them typed through campaign/recorded.RecordedStart.
    @property
    def config_ids(self) -> list[str]:
        """The recorded plan's configuration ids, in order (without parsing the configurations)."""
        return [entry["config_id"] for entry in self.plan if isinstance(entry.get("config_id"), str)]


class ResumeDocument(Document):
    type: Literal["resume"] = "resume"
    schema_version: int
    uid: str
    start_uid: str | None
    previous_attempt: int
    software: dict[str, Any] = Field(description="versions: stereo_bench, opencv, numpy, python")
    host: Host
    completed: list[str] = Field(description="configurations complete before this attempt")
    recovery: dict[str, Any] = Field(default_factory=dict)
    extra: dict[str, Any] = Field(default_factory=dict)
    plan_drift: str | None = Field(None, description="v2: where today's planner differs from the recorded plan "
                                                     "(the recorded plan is what runs)")
    numeric_environment: NumericEnvironment | None = Field(None, description="v2: this attempt's (as in start)")
    # What a reader of the live stream needs to show a resumed run at once without reading the session from disk
    # (the live page): the start's bench, its config and plan (checked equal to this attempt's), and the rows of
    # the earlier attempts. Absent in resumes recorded before they were carried.
    bench: BenchName | None = Field(None, description="v2: the start's bench")
    config: dict[str, Any] | None = Field(None, description="v2: the start's campaign config (this attempt's: "
                                                            "a resume with another is refused)")
    plan: list[dict[str, Any]] | None = Field(None, description="v2: the start's plan (likewise)")
    results: list[ResultRow] | None = Field(None, description="v2: the last row of each configuration recorded "
                                                              "before this attempt, in order of first appearance")


#: The typed event kinds, kind -> model, in the order their classes are defined below. A class that derives from
#: :class:`EventDocument` and declares ``kind: Literal["..."]`` registers itself here (and so in :data:`AnyDocument`
#: and the JSON Schema): a new kind is its class and nothing else. A kind not listed is read (and may be written,
#: e.g. by other tools) as a plain EventDocument; the runner writes only these.
EVENT_MODELS: dict[str, type[EventDocument]] = {}


class EventDocument(Document):
    """An event: ``kind`` says what happened, ``data`` holds it, ``frames``/``files`` its side files."""

    @classmethod
    def __pydantic_init_subclass__(cls, **kwargs: Any) -> None:
        super().__pydantic_init_subclass__(**kwargs)
        kind = cls.model_fields["kind"].default
        if "kind" not in cls.__dict__.get("__annotations__", {}) or not isinstance(kind, str):
            return  # a subclass that does not name a kind of its own (e.g. a test's variant of a typed event)
        if kind in EVENT_MODELS:
            raise TypeError(f"event kind {kind!r} is already {EVENT_MODELS[kind].__name__}")
        EVENT_MODELS[kind] = cls

    type: Literal["event"] = "event"
    kind: str
    config_id: str | None = None
    data: dict[str, Any] = Field(default_factory=dict)
    frames: dict[str, str] = Field(default_factory=dict, description="name -> PNG path relative to the session")
    files: dict[str, str] = Field(default_factory=dict, description="name -> path relative to the session")


class HomeEvent(EventDocument):
    kind: Literal["home"] = "home"
    data: RigData


class MoveEvent(EventDocument):
    kind: Literal["move"] = "move"
    data: RigData


class ApproachEvent(EventDocument):
    kind: Literal["approach"] = "approach"
    data: ApproachData


class RigRecoveredEvent(EventDocument):
    kind: Literal["rig_recovered"] = "rig_recovered"
    data: ActionData


class RigPositionTrustedEvent(EventDocument):
    kind: Literal["rig_position_trusted"] = "rig_position_trusted"
    data: TrustData


class RigUnrecoverableEvent(EventDocument):
    kind: Literal["rig_unrecoverable"] = "rig_unrecoverable"
    data: ErrorData


class CalibrationViewEvent(EventDocument):
    kind: Literal["calibration_view"] = "calibration_view"
    data: CaptureData


class MeasurementFrameEvent(EventDocument):
    kind: Literal["measurement_frame"] = "measurement_frame"
    data: CaptureData


class TargetNotFoundEvent(EventDocument):
    kind: Literal["target_not_found"] = "target_not_found"
    data: TargetNotFoundData


class CalibrationEvent(EventDocument):
    kind: Literal["calibration"] = "calibration"
    data: CalibrationData


class AnalysisEvent(EventDocument):
    kind: Literal["analysis"] = "analysis"
    data: AnalysisData


class TranscriptEvent(EventDocument):
    kind: Literal["transcript"] = "transcript"
    data: TranscriptData


class PromptEvent(EventDocument):
    kind: Literal["prompt"] = "prompt"
    data: PromptData


class CalibrationViewDiscardedEvent(EventDocument):
    kind: Literal["calibration_view_discarded"] = "calibration_view_discarded"
    data: ViewDiscardedData


class CalibrationSelectionEvent(EventDocument):
    kind: Literal["calibration_selection"] = "calibration_selection"
    data: CalibrationSelectionData


class CalibrationExclusionsEvent(EventDocument):
    kind: Literal["calibration_exclusions"] = "calibration_exclusions"
    data: CalibrationExclusionsData


class PresentationTimeEvent(EventDocument):
    kind: Literal["presentation_time"] = "presentation_time"
    data: PresentationTimeData


class RunControlEvent(EventDocument):
    kind: Literal["run_control"] = "run_control"
    data: RunControlData


class CalibrationDetectionsEvent(EventDocument):
    kind: Literal["calibration_detections"] = "calibration_detections"
    data: CalibrationDetectionsData


class TruthEvent(EventDocument):
    kind: Literal["truth"] = "truth"
    data: TruthData


class ControllerEvent(EventDocument):
    kind: Literal["controller"] = "controller"
    data: ControllerData


class StructureEvent(EventDocument):
    kind: Literal["structure"] = "structure"
    data: StructureData


class KinematicModelEvent(EventDocument):
    kind: Literal["kinematic_model"] = "kinematic_model"
    data: KinematicModelData


class IntrinsicsEvent(EventDocument):
    kind: Literal["intrinsics"] = "intrinsics"
    data: IntrinsicsData


class ResultDocument(Document):
    type: Literal["result"] = "result"
    config_id: str
    row: ResultRow


class StopDocument(Document):
    type: Literal["stop"] = "stop"
    exit_status: ExitStatus
    reason: str | None = None
    completed: int = Field(ge=0, description="configurations with a result, all attempts")
    resume_command: str | None = Field(None, description="v2: the command that continues an interrupted or failed "
                                                         "session")


DOCUMENT_MODELS: dict[str, type[Document]] = {
    "start": StartDocument, "resume": ResumeDocument, "event": EventDocument, "result": ResultDocument,
    "stop": StopDocument,
}
DOCUMENT_TYPES = tuple(DOCUMENT_MODELS)


def _tag(value: Any) -> str:
    get = value.get if isinstance(value, dict) else (lambda key, default=None: getattr(value, key, default))
    kind = get("type")
    if kind == "event":
        return f"event:{get('kind')}" if get("kind") in EVENT_MODELS else "event"
    return str(kind)


def _document_union() -> Any:
    """Every document model tagged as :func:`_tag` names it: the documents, the plain event, then each typed kind."""
    members = [Annotated[model, Tag(name)] for name, model in DOCUMENT_MODELS.items() if model is not EventDocument]
    members.append(Annotated[EventDocument, Tag("event")])
    members += [Annotated[model, Tag(f"event:{kind}")] for kind, model in EVENT_MODELS.items()]
    return functools.reduce(operator.or_, members)


#: Any document, discriminated by ``type`` (and an event's ``kind``): derived from :data:`DOCUMENT_MODELS` and
#: :data:`EVENT_MODELS`, so a kind is listed once, by its class.
AnyDocument = Annotated[_document_union(), Discriminator(_tag)]
_ADAPTER: TypeAdapter = TypeAdapter(AnyDocument)


def _dotted(loc: tuple) -> str:
    parts = [str(part) for part in loc if not (isinstance(part, str) and (part.startswith("event:") or
                                                                          part in DOCUMENT_MODELS))]
    return ".".join(parts) or "(document)"


def _one_line(error: ValidationError, what: str) -> str:
    first = error.errors()[0]
    message = first.get("msg", "invalid").removeprefix("Value error, ")
    more = f" (and {error.error_count() - 1} more)" if error.error_count() > 1 else ""
    return f"{what}: {_dotted(tuple(first.get('loc', ())))}: {message}{more}"


def describe(doc: Mapping[str, Any]) -> str:
    """E.g. 'event document (kind move)' for messages."""
    kind = doc.get("kind")
    return f"{doc.get('type')} document" + (f" (kind {kind})" if doc.get("type") == "event" and kind else "")


def parse_document(doc: Mapping[str, Any]) -> Document:
    """The typed document of a parsed JSON line; raises :class:`DocumentError` naming the field.

    Accepts every schema version in :data:`READABLE_SCHEMA_VERSIONS` (versions 1 and 2 share these models).
    """
    if doc.get("type") not in DOCUMENT_MODELS:
        raise DocumentError(f"unknown document type {doc.get('type')!r}; known: {', '.join(DOCUMENT_TYPES)}")
    try:
        return _ADAPTER.validate_python(dict(doc))
    except ValidationError as error:
        raise DocumentError(_one_line(error, describe(doc))) from None


def document_json(document: Document) -> dict[str, Any]:
    """The document as its JSON line holds it (fields that were never given are left out)."""
    data = document.model_dump(mode="json", exclude_unset=True)
    if isinstance(document, ResultDocument):
        data["row"] = document.row.stored()
    return data


def document_json_schema() -> dict[str, Any]:
    """JSON Schema (draft 2020-12) of one line of ``documents.jsonl``."""
    schema = _ADAPTER.json_schema()
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["title"] = f"stereo-bench session document (schema version {SCHEMA_VERSION})"
    schema["description"] = ("One line of a session's documents.jsonl. Event documents of a kind not listed "
                             "here validate as the generic event.")
    return schema


# --------------------------------------------------------------------------------------------------
# Drafts: what the runner publishes, before a recorder stamps and writes it


@dataclass(frozen=True)
class CalibrationFiles:
    """The calibration a CalibrationEvent writes as OpenCV YAML (``StereoCalibration``, ``Rectification``)."""

    calib: Any
    rect: Any
    board: str
    extra: dict[str, Any] = field(default_factory=dict)

    def data(self) -> dict[str, Any]:
        """The CalibrationEvent's ``data`` (:class:`CalibrationData`)."""
        calib = self.calib
        return {"board": self.board, "mode": calib.mode, "rms_px": calib.rms_px, "baseline_mm": calib.baseline_mm,
                "image_size": list(calib.image_size), "views_used": list(calib.views_used),
                "views_rejected": len(calib.views_rejected), "extra": self.extra}


class Draft:
    """A document before it is recorded: its model and its fields (no header), and what it brings along.

    ``frames``: name -> image array, written as PNG side files; ``files``: name -> bytes;
    ``calibration``: for a :class:`CalibrationEvent`, the calibration to write as YAML.
    """

    __slots__ = ("calibration", "fields", "files", "frames", "model")

    def __init__(self, model: type[Document], *, frames: Mapping[str, np.ndarray] | None = None,
                 files: Mapping[str, bytes] | None = None, calibration: CalibrationFiles | None = None,
                 **fields: Any):
        self.model = model
        kind = model.model_fields["kind"].default if "kind" in model.model_fields else None
        if isinstance(kind, str):  # a typed event: its kind is written, not left to the default
            fields = {"kind": kind, **fields}
        self.fields = fields
        self.frames = frames
        self.files = files
        self.calibration = calibration

    def __repr__(self) -> str:
        return f"Draft({self.model.__name__}, {self.fields!r})"

    @property
    def type(self) -> str:
        return self.model.model_fields["type"].default

    def build(self, header: Mapping[str, Any], **more: Any) -> Document:
        """The complete document: header + fields + ``more``, validated (raises DocumentError)."""
        try:
            data = json_safe({**self.fields, **more}, self.type)
        except TypeError as error:
            raise DocumentError(f"cannot record {error}") from None
        try:
            return self.model.model_validate({**header, **data})
        except ValidationError as error:
            raise DocumentError(_one_line(error, describe({"type": self.type, **data}))) from None


def event_draft(kind: str, *, config_id: str | None = None, data: Any = None, **bring: Any) -> Draft:
    """A draft of an event of ``kind``: its typed model when the kind is known, else a plain event."""
    return Draft(EVENT_MODELS.get(kind, EventDocument), kind=kind, config_id=config_id,
                 data={} if data is None else data, **bring)


__all__ = [
    "ADDED_COLUMNS", "COMPARED_COLUMNS", "DOCUMENT_MODELS", "DOCUMENT_TYPES", "EVENT_MODELS", "EXIT_STATUSES",
    "READABLE_SCHEMA_VERSIONS", "REPORT_COLUMNS", "RESULT_COLUMNS", "SCHEMA_VERSION", "TOLERANCES", "AnalysisEvent",
    "ApproachEvent", "CalibrationDetectionsEvent", "CalibrationEvent", "CalibrationExclusionsEvent", "CalibrationFiles",
    "CalibrationSelectionEvent",
    "CalibrationViewDiscardedEvent", "CalibrationViewEvent", "ControllerEvent", "DetectionRecord", "Document",
    "DocumentError", "Draft", "EventDocument", "HomeEvent", "IntrinsicsEvent", "KinematicModelEvent",
    "MeasurementFrameEvent", "NumericEnvironment", "MoveEvent", "PresentationTimeEvent", "PromptEvent",
    "ResultDocument", "ResultRow",
    "ResumeDocument", "RunControlEvent", "StartDocument", "StopDocument", "StructureEvent", "TargetNotFoundEvent",
    "TranscriptEvent", "TruthEvent", "campaign_outcome", "document_json", "columns_of", "column",
    "document_json_schema", "event_draft", "json_safe", "nested", "parse_document", "result_row",
]
