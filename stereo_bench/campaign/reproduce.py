"""The replay's comparison rule (docs/REPLAY.md): identical, reproduced within tolerance, or differs.

A replay computes every recorded number again from the recorded frames. On the machine and libraries
that recorded it the result is bit-identical; on another CPU numpy's BLAS (and OpenCV's SIMD paths)
take other kernels and the last digits move. A compared number is

- ``identical`` when it is bit-equal (NaN to NaN, absent to absent included);
- ``reproduced`` when |Δ| <= a · s **and** |Δ| <= b · u, s the magnitude of the operands it is computed
  from and u its own standard uncertainty; a = :data:`SCALE_TOLERANCE` (1e-9) and b =
  :data:`UNCERTAINTY_TOLERANCE` (1e-6) for what is computed in closed form or by OpenCV's solvers, and
  a = b = r = 2 sqrt(τ ν) (:func:`fit_resolution`) for the kinematic model a replay fits again and what is
  measured with it: that fit stops when a step lowers its cost by less than τ of it, which leaves it up to
  sqrt(τ χ²) of a sigma from the minimum, wherever the arithmetic takes it;
- ``differs`` otherwise, and whenever one side has a value the other lacks. A status, a count or a mode
  (a compared column without a tolerance) is identical or differs.

What s and u are for each column is declared where the column is defined (``ResultRow``'s
``column(..., scale=, uncertainty=)``, :data:`documents.TOLERANCES`); the kinematic model is compared
parameter by parameter with its fitted sigma as u (:func:`compare_models`).

    context = RecordedContext.of(config, reader)
    deviations = compare_rows(recorded_row, replayed_row, context)
    verdict(deviations)          # 'identical' | 'reproduced' | 'differs'
    largest(deviations).text()   # 'epipolar_rms_px of B100_Z450_A90, |Δ| = 2.6e-11 px = 4.8e-14 of its scale, ...'
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

from stereo_bench.campaign.documents import ADDED_COLUMNS, COMPARED_COLUMNS, TOLERANCES
from stereo_bench.kinematics import FIT_TOLERANCE

#: |Δ| <= 1e-9 s: 4.5 million float64 roundings (2.2e-16) of the operands, 50 times the largest relative
#: deviation measured between BLAS core types in closed-form numbers (1.8e-11, sigma_mm; docs/REPLAY.md).
SCALE_TOLERANCE = 1e-9
#: |Δ| <= 1e-6 u: a millionth of the number's own standard uncertainty, nothing a measurement could see.
UNCERTAINTY_TOLERANCE = 1e-6

Verdict = Literal["identical", "reproduced", "differs"]
_ORDER = {"identical": 0, "reproduced": 1, "differs": 2}


@dataclass(frozen=True)
class RecordedContext:
    """What the tolerance of a row's numbers needs beyond the row: from the recording's config and events.

    ``image_height_px``: per configuration, the height of its measurement frames (else the config's
    optics); ``target_corners`` / ``calibration_corners``: corners of the measured target and of the
    calibration board; ``structure_sigma``: per configuration, the structure sigmas the recording states for
    the extrinsics the measurement used (``structure`` event; none for a per-config calibration or a file).
    """

    image_height_px: Mapping[str, float] = field(default_factory=dict)
    default_image_height_px: float | None = None
    target_corners: int | None = None
    calibration_corners: int | None = None
    structure_sigma: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    # r of the kinematic model the replay fitted again (None: it fitted none): the tolerance of every number
    # of a row measured with it (extrinsics_mode "kinematic").
    fit_resolution: float | None = None

    @classmethod
    def of(cls, config: Any, reader: Any, *, refitted_model: Any = None) -> RecordedContext:
        """From a :class:`~stereo_bench.campaign.config.CampaignConfig` and the recording's
        :class:`~stereo_bench.campaign.session.SessionReader`; ``refitted_model``: the recorded kinematic
        model when the replay fitted it again (its rows then take the fit's resolution)."""
        heights: dict[str, float] = {}
        from stereo_bench.campaign.documents import MeasurementFrameEvent, StructureEvent

        for event in reader.events(kind=MeasurementFrameEvent):
            rows = [float(frame.shape[0]) for frame in (event.data.left, event.data.right) if frame.shape]
            if rows and event.config_id:
                heights[event.config_id] = max(rows + [heights.get(event.config_id, 0.0)])
        sigmas: dict[str, Mapping[str, float]] = {}
        for event in reader.events(kind=StructureEvent):
            used = event.data.sources.get(event.data.used)
            if used is not None and used.structure_sigma is not None and event.config_id:
                sigmas[event.config_id] = used.structure_sigma
        return cls(image_height_px=heights, default_image_height_px=float(config.cameras.optics.height_px),
                   target_corners=config.target.build().n_corners,
                   calibration_corners=config.calibration_board.build().n_corners, structure_sigma=sigmas,
                   fit_resolution=None if refitted_model is None else fit_resolution(refitted_model))


def fit_resolution(model: Any) -> float | None:
    """r = 2 sqrt(τ ν) of a kinematic model (``kinematics.KinematicModel``; None when it records no dof).

    The fit stops when a step lowers the cost χ² by less than τ = ``kinematics.FIT_TOLERANCE`` of it; near
    the minimum χ² rises by (δ/σ)² for a step δ along a parameter, so the remaining δ is at most
    sqrt(τ χ²) σ, χ² ≈ ν (the pixel weight is re-estimated until it is). Two fits on other arithmetic: 2x.
    """
    dof = _number(getattr(getattr(model, "fit", None), "dof", None))
    return 2 * math.sqrt(FIT_TOLERANCE * dof) if dof and dof > 0 else None


@dataclass(frozen=True)
class Deviation:
    """One compared number: where, the two values, the verdict and what it rests on."""

    where: str  # a config_id, or "the kinematic model"
    name: str  # the column (or the model's dotted field)
    recorded: Any
    replayed: Any
    verdict: Verdict
    delta: float | None = None  # |Δ|
    scale: float | None = None  # s
    u: float | None = None  # the number's standard uncertainty (None: not known: the scale alone decides)
    why: str | None = None  # differs: why
    scale_tolerance: float = SCALE_TOLERANCE  # a: |Δ| <= a s
    u_tolerance: float = UNCERTAINTY_TOLERANCE  # b: |Δ| <= b u

    @property
    def relative_to_scale(self) -> float | None:
        return _ratio(self.delta, self.scale)

    @property
    def relative_to_u(self) -> float | None:
        return _ratio(self.delta, self.u)

    @property
    def share_of_tolerance(self) -> float:
        """max(|Δ| / (1e-9 s), |Δ| / (1e-6 u)): 0 when identical, <= 1 when reproduced."""
        if self.verdict == "identical":
            return 0.0
        if self.delta is None:
            return math.inf
        shares = [_ratio(self.delta, self.scale_tolerance * self.scale) if self.scale is not None else math.inf]
        if self.u is not None:
            shares.append(_ratio(self.delta, self.u_tolerance * self.u))
        return max(math.inf if share is None else share for share in shares)

    @property
    def unit(self) -> str:
        """mm, px or deg from the name (a model's 'left_axis_x_mm.sigma' too); '' when it names none."""
        for part in reversed(self.name.split(".")):
            part = part.split("[")[0]
            unit = next((unit for unit in ("mm", "px", "deg") if part.endswith(f"_{unit}")), None)
            if unit:
                return unit
        return ""

    def size(self) -> str:
        """E.g. '|Δ| = 2.6e-11 px = 4.8e-14 of its scale, 1.5e-08 u' ('' for an exact column)."""
        if self.delta is None:
            return ""
        unit = f" {self.unit}" if self.unit else ""
        text = f"|Δ| = {self.delta:.2g}{unit}"
        if self.relative_to_scale is not None:
            text += f" = {self.relative_to_scale:.2g} of its scale"
        return text + (f", {self.relative_to_u:.2g} u" if self.relative_to_u is not None else ", u unknown")

    def text(self) -> str:
        """E.g. 'epipolar_rms_px of B100_Z450_A90, |Δ| = 2.6e-11 px = 4.8e-14 of its scale, 1.5e-08 u'."""
        size = self.size()
        return f"{self.name} of {self.where}" + (f", {size}" if size else "")

    def difference(self) -> str:
        """How a replay lists a number that differs: 'square_mean_mm 27.0049 -> 27.0051 (|Δ| = ...: beyond
        the tolerance)'; an exact column: 'status 'measured' -> 'failed''."""
        why = self.why or (f"{self.size()}: beyond the tolerance" if self.delta is not None else None)
        return f"{self.name} {self.recorded!r} -> {self.replayed!r}" + (f" ({why})" if why else "")

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready (``largest_deviation`` of ``replay --json``)."""
        return {"where": self.where, "column": self.name, "config_id": None if self.where.startswith("the ")
                else self.where, "recorded": self.recorded, "replayed": self.replayed, "verdict": self.verdict,
                "abs": self.delta, "scale": self.scale, "relative_to_scale": self.relative_to_scale, "u": self.u,
                "relative_to_u": self.relative_to_u, "unit": self.unit or None, "why": self.why,
                "tolerance": {"relative_to_scale": self.scale_tolerance, "relative_to_u": self.u_tolerance}}


def _ratio(a: float | None, b: float | None) -> float | None:
    if a is None or b is None or not math.isfinite(b):
        return None
    if b == 0:
        return 0.0 if a == 0 else math.inf
    return a / b


def _number(value: Any) -> float | None:
    """A finite or non-finite float of a JSON number (None: not a number)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value)


def _bit_equal(a: Any, b: Any) -> bool:
    x, y = _number(a), _number(b)
    if x is not None and y is not None:
        return (math.isnan(x) and math.isnan(y)) or (x == y and math.copysign(1, x) == math.copysign(1, y))
    return a == b and type(a) is type(b) or (a is None and b is None)


def _absent(value: Any) -> bool:
    """A number a row does not have: absent, null or NaN (a row stores NaN as absent)."""
    return value is None or (isinstance(value, float) and math.isnan(value))


def compare_number(where: str, name: str, recorded: Any, replayed: Any, *, scale: float | None,
                   u: float | None, scale_tolerance: float = SCALE_TOLERANCE,
                   u_tolerance: float = UNCERTAINTY_TOLERANCE) -> Deviation:
    """One number against its tolerance: |Δ| <= ``scale_tolerance`` ``scale`` and <= ``u_tolerance`` ``u``
    (u None: not known, the scale alone decides; scale None: only bit-equality reproduces it)."""
    tolerances = {"scale_tolerance": scale_tolerance, "u_tolerance": u_tolerance}
    if _bit_equal(recorded, replayed) or (_absent(recorded) and _absent(replayed)):
        return Deviation(where, name, recorded, replayed, "identical", **tolerances)
    if _absent(recorded) or _absent(replayed):
        side = "the replay" if _absent(replayed) else "the recording"
        return Deviation(where, name, recorded, replayed, "differs", why=f"{side} has no value", **tolerances)
    x, y = _number(recorded), _number(replayed)
    if x is None or y is None:
        return Deviation(where, name, recorded, replayed, "differs", why="not a number", **tolerances)
    if not (math.isfinite(x) and math.isfinite(y)):
        return Deviation(where, name, recorded, replayed, "differs", why="not finite", **tolerances)
    delta = abs(y - x)
    scale = None if scale is None or not math.isfinite(scale) else abs(scale)
    u = None if u is None or not math.isfinite(u) or u < 0 else u
    if scale is None:
        return Deviation(where, name, recorded, replayed, "differs", delta, None, u,
                         why=f"|Δ| = {delta:.2g}: no scale to hold it to", **tolerances)
    within = delta <= scale_tolerance * scale and (u is None or delta <= u_tolerance * u)
    return Deviation(where, name, recorded, replayed, "reproduced" if within else "differs", delta, scale, u,
                     **tolerances)


# ----------------------------------------------------------------------------------------------------
# Result rows


def _degrees_of_freedom(rule: str, row: Mapping[str, Any], context: RecordedContext) -> float | None:
    """nu of a dispersion estimate (docs/REPLAY.md), by the rule its column names; None when not known.

    ``squares``: n_squares - 1 (the sides the spread is computed over). ``measured_corners``: target corners x
    frames measured (one rectified row difference per corner and frame; an upper bound with partial views).
    ``calibration_coordinates``: 4 x calibration-board corners x views used (two coordinates in two images
    per corner; an upper bound: the fitted parameters and partial views lower it). An upper bound makes u
    smaller, so the tolerance never leans on an overstated uncertainty.
    """
    def count(key: str) -> float | None:
        value = _number(row.get(key))
        return value if value is not None and math.isfinite(value) else None

    if rule == "squares":
        n = count("n_squares")
        return n - 1 if n is not None and n > 1 else None
    if rule == "measured_corners":
        frames = count("n_frames")
        return frames * context.target_corners if frames and context.target_corners else None
    if rule == "calibration_coordinates":
        views = count("calib_views_used")
        return 4 * views * context.calibration_corners if views and context.calibration_corners else None
    raise ValueError(f"unknown degrees-of-freedom rule {rule!r}")


def row_scale(name: str, row: Mapping[str, Any], context: RecordedContext) -> float | None:
    """s of column ``name`` of a recorded ``row`` (:data:`documents.TOLERANCES`)."""
    spec = TOLERANCES[name][0]
    if spec == "value":
        value = _number(row.get(name))
    elif spec == "image_height_px":
        value = context.image_height_px.get(row.get("config_id"), context.default_image_height_px)
    else:
        value = _number(row.get(spec))
    return None if value is None or not math.isfinite(value) else abs(value)


def row_uncertainty(name: str, row: Mapping[str, Any], context: RecordedContext) -> float | None:
    """u of column ``name`` of a recorded ``row`` (None: the recording states none)."""
    spec = TOLERANCES[name][1]
    kind, _, argument = spec.partition(":")
    if kind == "dispersion":
        value, nu = _number(row.get(name)), _degrees_of_freedom(argument, row, context)
        return abs(value) / math.sqrt(2 * nu) if value is not None and math.isfinite(value) and nu else None
    if kind == "structure":
        sigma = _number((context.structure_sigma.get(row.get("config_id")) or {}).get(argument))
        return sigma if sigma is not None and math.isfinite(sigma) and sigma > 0 else None
    for column in spec.split("|"):
        value = _number(row.get(column))
        if value is not None and math.isfinite(value) and value > 0:
            return value
    return None


def compare_rows(recorded: Mapping[str, Any], replayed: Mapping[str, Any], context: RecordedContext,
                 columns: Sequence[str] = COMPARED_COLUMNS) -> list[Deviation]:
    """Every compared column of one configuration's recorded and replayed rows. A column added after the
    recording was made (:data:`documents.ADDED_COLUMNS`) that it lacks is not compared."""
    where = str(recorded.get("config_id"))
    fitted = context.fit_resolution is not None and recorded.get("extrinsics_mode") == "kinematic"
    tolerances = ({"scale_tolerance": context.fit_resolution, "u_tolerance": context.fit_resolution} if fitted
                  else {})
    out = []
    for name in columns:
        if name in ADDED_COLUMNS and name not in recorded:
            continue
        old, new = recorded.get(name), replayed.get(name)
        if name not in TOLERANCES:  # a status, a count, a mode: exact
            verdict = "identical" if _bit_equal(old, new) or (old is None and new is None) else "differs"
            out.append(Deviation(where, name, old, new, verdict))
            continue
        out.append(compare_number(where, name, old, new, scale=row_scale(name, recorded, context),
                                  u=row_uncertainty(name, recorded, context), **tolerances))
    return out


def verdict(deviations: Iterable[Deviation]) -> Verdict:
    """The worst verdict of ``deviations`` ('identical' when there are none)."""
    return max((d.verdict for d in deviations), key=_ORDER.__getitem__, default="identical")


def largest(deviations: Iterable[Deviation]) -> Deviation | None:
    """The deviation nearest its tolerance (None when every number is identical)."""
    moved = [d for d in deviations if d.verdict != "identical"]
    return max(moved, key=lambda d: d.share_of_tolerance) if moved else None


# ----------------------------------------------------------------------------------------------------
# The kinematic model fitted again

MODEL = "the kinematic model"
_COVARIANCES = ("covariance", "intrinsics_covariance")


def _leaves(value: Any, name: str) -> Iterable[tuple[str, Any]]:
    """(dotted name, value) of every scalar in a JSON structure: 'K1[0][2]', 'fit.rms_px'."""
    if isinstance(value, Mapping):
        for key, item in value.items():
            yield from _leaves(item, f"{name}.{key}" if name else str(key))
    elif isinstance(value, list):
        for i, item in enumerate(value):
            yield from _leaves(item, f"{name}[{i}]")
    else:
        yield name, value


def _magnitude(value: Any) -> float | None:
    """The largest |number| in a JSON structure (the scale an array's entries are computed at)."""
    numbers = [abs(x) for _, leaf in _leaves(value, "") if (x := _number(leaf)) is not None and math.isfinite(x)]
    return max(numbers) if numbers else None


def _variances(matrix: Any) -> list[float]:
    if not isinstance(matrix, list):
        return []
    return [abs(_number(row[i]) or 0.0) if isinstance(row, list) and i < len(row) else 0.0
            for i, row in enumerate(matrix)]


def compare_models(recorded: Any, fitted: Any) -> list[Deviation]:
    """Every number of a recorded kinematic model (``kinematics.KinematicModel``) against the one fitted again,
    each with a = b = r (:func:`fit_resolution`; a model without a dof: the closed-form a and b).

    A parameter's value: s and u its recorded sigma (the fit resolves a parameter in sigmas, whatever its
    value); a sigma: s itself, u = sigma / sqrt(2 dof) (an estimate over the fit's dof degrees of freedom); a
    covariance entry C_ij: s = sqrt(C_ii C_jj) (the scale of its row and column); any other number: s the
    largest |entry| of its field (K1, D1, span, fit.rms_px), u not stated. Text and integers (names, units,
    counts, the design) are compared exactly.
    """
    old = recorded.model_dump(mode="json", by_alias=True)
    new = fitted.model_dump(mode="json", by_alias=True)
    dof = _number((old.get("fit") or {}).get("dof"))
    r = fit_resolution(recorded)
    tolerances = {"scale_tolerance": r, "u_tolerance": r} if r is not None else {}
    out: list[Deviation] = []
    variances = {key: _variances(old.get(key)) for key in _COVARIANCES}
    for key in sorted(set(old) | set(new), key=lambda k: (k != "parameters", k)):
        if key == "parameters":
            for name in sorted(set(old[key]) | set(new.get(key) or {})):
                a, b = old[key].get(name) or {}, (new.get(key) or {}).get(name) or {}
                sigma = _number(a.get("sigma"))
                for field_name in sorted(set(a) | set(b)):
                    x, y = a.get(field_name), b.get(field_name)
                    label = name if field_name == "value" else f"{name}.{field_name}"
                    if field_name == "value":
                        out.append(compare_number(MODEL, label, x, y, scale=sigma, u=sigma, **tolerances))
                    elif field_name == "sigma" and sigma is not None:
                        u = sigma / math.sqrt(2 * dof) if dof and dof > 0 else None
                        out.append(compare_number(MODEL, label, x, y, scale=sigma, u=u, **tolerances))
                    else:
                        out.append(Deviation(MODEL, label, x, y, "identical" if _bit_equal(x, y) else "differs"))
            continue
        old_leaves = dict(_leaves(old.get(key), key))
        new_leaves = dict(_leaves(new.get(key), key))
        magnitude = _magnitude(old.get(key))
        for name in sorted(set(old_leaves) | set(new_leaves)):
            x, y = old_leaves.get(name), new_leaves.get(name)
            if _number(x) is None or isinstance(x, int) and isinstance(y, int):  # text, counts: exact
                out.append(Deviation(MODEL, name, x, y, "identical" if _bit_equal(x, y) else "differs"))
                continue
            scale = magnitude
            if key in _COVARIANCES or key == "cross_covariance":
                i, j = (int(part.rstrip("]")) for part in name[len(key) + 1:].split("]["))
                rows = variances["intrinsics_covariance" if key == "cross_covariance" else key]
                columns = variances["covariance" if key == "cross_covariance" else key]
                scale = math.sqrt(rows[i] * columns[j]) if i < len(rows) and j < len(columns) else None
            out.append(compare_number(MODEL, name, x, y, scale=scale, u=None, **tolerances))
    return out


__all__ = ["MODEL", "SCALE_TOLERANCE", "UNCERTAINTY_TOLERANCE", "Deviation", "RecordedContext", "compare_models",
           "compare_number", "compare_rows", "fit_resolution", "largest", "row_scale", "row_uncertainty", "verdict"]
