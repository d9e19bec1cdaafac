"""Rig configuration: which GRBL axis drives which physical quantity, and within which limits.

Physical quantities (units in the names, as everywhere at interfaces):

    baseline_mm, toe_in_left_deg, toe_in_right_deg, tilt_left_deg, tilt_right_deg, target_distance_mm

Toe-in t = 90 deg - alpha (0 = parallel rig, > 0 turns the camera toward the other one). Each quantity
is driven by a GRBL axis (X Y Z, or A B C on grblHAL), or is ``fixed`` at a value (the tilts, 0 by
default), or is ``manual``: the operator sets it when prompted (the target distance, by default).

For a driven quantity::

    machine = offset + scale * physical          (machine units: what GRBL reports, mm for G21)

Soft limits ``min``/``max`` are in physical units, and a move outside them is refused before a byte is
sent. Everything below the config classes is a pure function.

The default mapping matches a stock Grbl 1.1h, which homes each axis to its switch at the positive end
and counts machine space negative from there, ``[-$13x, 0]`` (see docs/RIG.md), and keeps every target one
pull-off (``$27`` = 1) off both ends, where a homing switch would trip with hard limits on: X = baseline
with ``offset = -350`` (B = 350 mm at the switch, X = 0), B = 1..349 mm at X -349..-1; Y/Z = left/right
toe-in with ``offset = -1``, ``scale = -1`` (the switch one pull-off beyond parallel; homing leaves the head
parallel at -1), toe-in 0..88 deg at -1..-89. A controller with other travel ($13x) needs its own file, e.g.
for ``$130=200``: baseline ``offset = -200``, ``min = 1``, ``max = 199``.

TOML layout (every table optional; what is missing keeps the default mapping)::

    [controller]
    baudrate = 115200
    rx_buffer_size = 128
    home_timeout_s = 120
    move_timeout_s = 120

    [quantities.baseline_mm]
    axis = "X"
    offset = -200.0     # machine units at B = 0
    scale = 1.0         # machine units per mm
    min = 0.0
    max = 200.0
    feed_per_min = 3000 # machine units/min; omit for GRBL's rapid rate

    [quantities.toe_in_left_deg]
    axis = "Y"
    offset = 0.0
    scale = -1.0        # toe-in grows toward negative Y
    min = 0
    max = 90

    [quantities.target_distance_mm]
    axis = "manual"
    min = 200
    max = 2000
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from drivers.files import InputFileError, read_toml
from drivers.rig.errors import RigError

QUANTITIES = (
    "baseline_mm", "toe_in_left_deg", "toe_in_right_deg", "tilt_left_deg", "tilt_right_deg", "target_distance_mm",
)
MACHINE_AXES = ("X", "Y", "Z", "A", "B", "C")
AxisName = Literal["X", "Y", "Z", "A", "B", "C", "fixed", "manual"]

PARALLEL_ALPHA_DEG = 90.0
#: The toe-in (deg, either way) at which a camera looks along the baseline: alpha 0 (or 180), the optical axis in
#: line with the other camera. The BRIEF measures alpha between the baseline and the optical axis *on the target
#: side*, so alpha lies in (0, 180) and a toe-in in (-90, 90); the default soft limits (toe-in 0..90) reach the end.
MAX_TOE_IN_DEG = 90.0

#: The fastest serial rate: Linux's highest standard termios rate (B4000000); pyserial raises OverflowError past
#: 2**31 - 1. GRBL talks at 115200, grblHAL up to 921600 (native USB ignores the rate).
MAX_BAUDRATE = 4_000_000
#: How long opening the port may take to get an answer: the banner comes ~1.1 s after the open (an Arduino's
#: bootloader, docs/RIG.md); a minute is over 50 times that.
MAX_CONNECT_TIMEOUT_S = 60.0
#: A homing cycle: ~8 s on the reference rig (``campaign plan``'s prediction), 10-15 s on real slides; an hour
#: covers the slowest seek rates many times over.
MAX_HOME_TIMEOUT_S = 3600.0
#: One move: a day, as ``rig --timeout``: a 350 mm move at Grbl's slowest feed (1 mm/min) takes ~6 h. Beyond
#: ``threading.TIMEOUT_MAX`` (~292 years) the wait itself overflowed (``home_timeout_s = inf``: OverflowError).
MAX_MOVE_TIMEOUT_S = 86_400.0
#: Grbl's slowest feed (MINIMUM_FEED_RATE in its config.h, 1 mm/min): its planner runs a slower one at that rate.
MIN_FEED_PER_MIN = 1.0
#: How far from machine zero a soft limit may put an axis (machine units, mm on GRBL): 100 m, past any bench's
#: travel. A move's duration grows with it: soft limits of 1e9 mm planned 11,111 hours of motion.
MAX_MACHINE_TRAVEL = 100_000.0


class RigConfigError(RigError):
    """A rig configuration file that cannot be used; the message names the file and the field."""


class LimitError(RigError):
    """A requested move outside the configured soft limits (nothing was sent)."""

    _prefix = "move refused, outside soft limits: "

    def __init__(self, violations: list[str]):
        super().__init__(self._prefix + "; ".join(violations))
        self.violations = violations


class MachineSpaceError(LimitError):
    """A move whose machine targets the controller would not accept (outside ``[-$13x, 0]`` once homed)."""

    _prefix = "move refused: "  # each violation names the controller's machine space itself


class MoveRequestError(RigError):
    """A move request that names an unknown quantity or changes a fixed one (nothing was sent)."""


def toe_in_from_alpha(alpha_deg: float) -> float:
    """Toe-in (deg, 0 = parallel) for a camera whose optical axis makes ``alpha_deg`` with the baseline.

    Same convention as ``stereo_bench.geometry``; repeated here because drivers/ must not import the app.
    """
    return PARALLEL_ALPHA_DEG - alpha_deg


def alpha_from_toe_in(toe_in_deg: float) -> float:
    return PARALLEL_ALPHA_DEG - toe_in_deg


def along_baseline(toe_in_deg: float) -> bool:
    """True when a camera at ``toe_in_deg`` looks along the baseline or behind it (|toe-in| >= 90 deg, alpha
    outside (0, 180)): its optical axis points at the other camera, or away from the target side, and no target
    in front of the rig is on it. ``rig move`` asks for ``--yes``; a campaign plan refuses such an angle."""
    return not abs(toe_in_deg) < MAX_TOE_IN_DEG


#: Why each bounded field is bounded, said with its refusal; keyed by the end of the field's dotted path.
BOUND_REASONS = {
    "controller.baudrate": "Linux's fastest serial rate is 4,000,000 (GRBL talks at 115200)",
    "controller.connect_timeout_s": "a controller answers ~1.1 s after its port opens",
    "controller.home_timeout_s": "a homing cycle takes 10-15 s",
    "controller.move_timeout_s": "a 350 mm move at Grbl's slowest feed (1 mm/min) takes ~6 h",
    "feed_per_min": "Grbl runs a slower feed at its MINIMUM_FEED_RATE, 1 unit/min",
}
_BOUND_ERRORS = ("greater_than", "greater_than_equal", "less_than", "less_than_equal")


def with_bound_reason(message: str, error: Mapping, where: str, reasons: Mapping[str, str]) -> str:
    """``message`` of a pydantic ``error`` at dotted ``where``, with the bound's reason from ``reasons`` when it is a
    bound that was crossed (``... less than or equal to 3600: a homing cycle takes 10-15 s``)."""
    if error.get("type") in _BOUND_ERRORS:
        for key, reason in reasons.items():
            if where == key or where.endswith("." + key):
                return f"{message}: {reason}"
    return message


class QuantityMapping(BaseModel):
    """How one physical quantity is set. ``offset``/``min``/``max``/``value`` are in the quantity's units."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    axis: AxisName
    offset: float = Field(0.0, allow_inf_nan=False, description="machine units at physical value 0")
    scale: float = Field(1.0, allow_inf_nan=False, description="machine units per physical unit; may be negative")
    min: float | None = Field(None, allow_inf_nan=False, description="soft limit, physical units")
    max: float | None = Field(None, allow_inf_nan=False, description="soft limit, physical units")
    feed_per_min: float | None = Field(None, ge=MIN_FEED_PER_MIN, allow_inf_nan=False,
                                       description="this axis' feed, machine units/min (at least Grbl's slowest, "
                                                   "1); None = rapid")
    value: float | None = Field(None, allow_inf_nan=False, description="the value of a fixed quantity")
    tolerance: float = Field(0.02, ge=0, allow_inf_nan=False,
                             description="how far (physical units) the stopped position may be from the target")

    @model_validator(mode="after")
    def _check(self) -> QuantityMapping:
        if self.scale == 0.0:
            raise ValueError("scale must not be 0")
        if self.min is not None and self.max is not None and self.min > self.max:
            raise ValueError(f"min ({self.min}) is greater than max ({self.max})")
        if self.axis in MACHINE_AXES and (self.min is None or self.max is None):
            raise ValueError(f"a quantity driven by axis {self.axis} needs soft limits: set both min and max")
        if self.axis == "fixed" and self.value is None:
            raise ValueError("a fixed quantity needs its value")
        if self.axis != "fixed" and self.value is not None:
            raise ValueError("value is only for axis = \"fixed\"")
        if self.driven:
            for end, value in (("min", self.min), ("max", self.max)):
                machine = self.offset + self.scale * value  # type: ignore[operator]
                if not abs(machine) <= MAX_MACHINE_TRAVEL:
                    raise ValueError(f"{end} = {value:g} puts axis {self.axis} at {machine:g} machine units, beyond "
                                     f"+-{MAX_MACHINE_TRAVEL:g} (100 m): no bench travels that far, and moves there "
                                     "would take days")
        return self

    @property
    def driven(self) -> bool:
        return self.axis in MACHINE_AXES


class ControllerSettings(BaseModel):
    """Link and timing settings for the controller (seconds, bits per second, bytes); each bound's reason is with
    its constant above."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    baudrate: int = Field(115200, gt=0, le=MAX_BAUDRATE)
    rx_buffer_size: int = Field(128, ge=16, description="GRBL's serial receive buffer; 1024 on most grblHAL")
    connect_timeout_s: float = Field(5.0, gt=0, le=MAX_CONNECT_TIMEOUT_S, allow_inf_nan=False)
    home_timeout_s: float = Field(120.0, gt=0, le=MAX_HOME_TIMEOUT_S, allow_inf_nan=False)
    move_timeout_s: float = Field(120.0, gt=0, le=MAX_MOVE_TIMEOUT_S, allow_inf_nan=False)
    reset_on_open: bool = True


DEFAULT_BASELINE_TRAVEL_MM = 350.0
DEFAULT_HEAD_TRAVEL_DEG = 90.0
#: Grbl's default pull-off ($27): the default mapping keeps every target this far inside the travel.
DEFAULT_PULLOFF = 1.0


def _default_quantities() -> dict[str, QuantityMapping]:
    # Stock Grbl machine space [-$13x, 0] after homing (limits.c), with $130=350, $131=$132=90 and $27=1. The
    # baseline switch marks B = 350 mm (X = 0); each pan switch sits one pull-off beyond parallel (toe-in -1 deg at
    # machine 0), so that homing (-$27) leaves the heads parallel. Every target stays one pull-off inside the
    # travel, [-$13x + $27, -$27]: none reaches a switch, where hard limits ($21=1) would halt with ALARM:1, and
    # grblHAL's work envelope with hard limits (machine_limits.c) is exactly that range.
    head_max = DEFAULT_HEAD_TRAVEL_DEG - 2.0 * DEFAULT_PULLOFF
    return {
        "baseline_mm": QuantityMapping(axis="X", offset=-DEFAULT_BASELINE_TRAVEL_MM, min=DEFAULT_PULLOFF,
                                       max=DEFAULT_BASELINE_TRAVEL_MM - DEFAULT_PULLOFF),
        "toe_in_left_deg": QuantityMapping(axis="Y", offset=-DEFAULT_PULLOFF, scale=-1.0, min=0.0, max=head_max),
        "toe_in_right_deg": QuantityMapping(axis="Z", offset=-DEFAULT_PULLOFF, scale=-1.0, min=0.0, max=head_max),
        "tilt_left_deg": QuantityMapping(axis="fixed", value=0.0),
        "tilt_right_deg": QuantityMapping(axis="fixed", value=0.0),
        "target_distance_mm": QuantityMapping(axis="manual"),
    }


class RigConfig(BaseModel):
    """The whole rig: controller settings and the mapping of every physical quantity.

    Quantities missing from a file keep their default mapping (X = baseline 1-349 mm at X -349..-1, Y/Z =
    left/right toe-in 0-88 deg at -1..-89, tilts fixed at 0, target distance manual): stock Grbl's negative
    machine space with $130=350, $131=$132=90, one pull-off inside it.
    """

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    controller: ControllerSettings = Field(default_factory=ControllerSettings)
    quantities: dict[str, QuantityMapping] = Field(default_factory=_default_quantities)

    @model_validator(mode="before")
    @classmethod
    def _fill_defaults(cls, data):
        if isinstance(data, Mapping) and "quantities" in data and isinstance(data["quantities"], Mapping):
            merged: dict = dict(_default_quantities())
            merged.update(data["quantities"])
            data = {**data, "quantities": merged}
        return data

    @field_validator("quantities")
    @classmethod
    def _check_quantities(cls, quantities: dict[str, QuantityMapping]) -> dict[str, QuantityMapping]:
        unknown = sorted(set(quantities) - set(QUANTITIES))
        if unknown:
            raise ValueError(f"unknown quantity {unknown[0]!r}; known: {', '.join(QUANTITIES)}")
        used: dict[str, str] = {}
        for name in QUANTITIES:
            mapping = quantities[name]
            if mapping.driven:
                if mapping.axis in used:
                    raise ValueError(f"axis {mapping.axis} drives both {used[mapping.axis]} and {name}")
                used[mapping.axis] = name
        return quantities

    def mapping(self, quantity: str) -> QuantityMapping:
        return self.quantities[quantity]

    @property
    def driven(self) -> dict[str, str]:
        """Quantity -> GRBL axis letter, for the quantities a motor sets."""
        return {q: m.axis for q, m in self.quantities.items() if m.driven}

    @property
    def axes(self) -> str:
        """The GRBL axis letters this rig uses, in GRBL order."""
        used = set(self.driven.values())
        return "".join(a for a in MACHINE_AXES if a in used)

    def machine_travel(self) -> dict[str, tuple[float, float]]:
        """Axis letter -> (min, max) machine units covered by the soft limits (for sizing an emulator)."""
        travel = {}
        for quantity, axis in self.driven.items():
            m = self.quantities[quantity]
            ends = sorted((m.offset + m.scale * m.min, m.offset + m.scale * m.max))  # type: ignore[operator]
            travel[axis] = (ends[0], ends[1])
        return travel

    def axis_feeds_per_min(self) -> dict[str, float | None]:
        return {self.quantities[q].axis: self.quantities[q].feed_per_min for q in self.driven}


def _field_path(loc: tuple) -> str:
    return ".".join(str(part) for part in loc) or "(top level)"


def load_rig_config(path: str | Path) -> RigConfig:
    """Read and validate a rig configuration TOML file. Errors name the file and the field.

    Read as every input file is (:func:`drivers.files.read_toml`: a regular file, bounded in size and nesting).
    """
    try:
        data = read_toml(path, what="rig configuration file")
    except InputFileError as error:
        raise RigConfigError(str(error)) from None
    return rig_config_from_dict(data, source=str(path))


def rig_config_from_dict(data: Mapping, *, source: str = "rig config") -> RigConfig:
    try:
        return RigConfig.model_validate(data)
    except ValidationError as error:
        first = error.errors()[0]
        where = _field_path(tuple(first.get("loc", ())))
        message = with_bound_reason(first.get("msg", "invalid").removeprefix("Value error, "), first, where,
                                    BOUND_REASONS)
        more = f" (and {error.error_count() - 1} more)" if error.error_count() > 1 else ""
        raise RigConfigError(f"{source}: {where}: {message}{more}") from None


# --------------------------------------------------------------------------------------------------
# Pure conversions


def to_machine(config: RigConfig, physical: Mapping[str, float]) -> dict[str, float]:
    """Machine targets (axis letter -> machine units) for the driven quantities among ``physical``."""
    targets = {}
    for quantity, value in physical.items():
        mapping = config.quantities[quantity]
        if mapping.driven:
            targets[mapping.axis] = mapping.offset + mapping.scale * float(value)
    return targets


def to_physical(config: RigConfig, machine: Mapping[str, float]) -> dict[str, float]:
    """Physical values of the driven quantities whose axis appears in ``machine`` (axis letter -> units)."""
    values = {}
    for quantity, axis in config.driven.items():
        if axis in machine:
            mapping = config.quantities[quantity]
            values[quantity] = (float(machine[axis]) - mapping.offset) / mapping.scale + 0.0  # no -0.0
    return values


def limit_violations(config: RigConfig, physical: Mapping[str, float]) -> list[str]:
    """One message per requested value outside its quantity's soft limits (empty if all are inside)."""
    problems = []
    for quantity, value in physical.items():
        mapping = config.quantities[quantity]
        if not math.isfinite(value):
            problems.append(f"{quantity} = {value} is not a number")
            continue
        low = -math.inf if mapping.min is None else mapping.min
        high = math.inf if mapping.max is None else mapping.max
        if not low <= value <= high:
            problems.append(f"{quantity} = {value:g} outside [{_fmt(mapping.min)}, {_fmt(mapping.max)}]")
    return problems


def _fmt(value: float | None) -> str:
    return "-inf" if value is None else f"{value:g}"


def check_limits(config: RigConfig, physical: Mapping[str, float]) -> None:
    """Raise :class:`LimitError` naming every requested value outside its soft limits."""
    problems = limit_violations(config, physical)
    if problems:
        raise LimitError(problems)


@dataclass(frozen=True)
class MovePlan:
    """What a physical move request turns into, decided before anything is sent.

    ``machine_targets``: axis letter -> machine units. ``manual``: quantity -> value the operator must set.
    ``driven``: quantity -> requested physical value for the motorised quantities.
    """

    machine_targets: dict[str, float]
    driven: dict[str, float]
    manual: dict[str, float]


def plan_move(config: RigConfig, request: Mapping[str, float | None]) -> MovePlan:
    """Validate a request (quantity -> physical value; None = leave as is) and split it by how it is set.

    Raises :class:`MoveRequestError` for an unknown quantity or a change to a fixed one, and
    :class:`LimitError` for anything outside the soft limits. Pure: nothing is sent.
    """
    wanted = {q: float(v) for q, v in request.items() if v is not None}
    unknown = sorted(set(wanted) - set(QUANTITIES))
    if unknown:
        raise MoveRequestError(f"unknown quantity {unknown[0]!r}; known: {', '.join(QUANTITIES)}")
    for quantity, value in wanted.items():
        mapping = config.quantities[quantity]
        if mapping.axis == "fixed" and not math.isclose(value, mapping.value, abs_tol=1e-9):  # type: ignore[arg-type]
            raise MoveRequestError(
                f"{quantity} is fixed at {mapping.value:g} on this rig (no axis drives it); cannot set {value:g}")
    check_limits(config, wanted)
    driven = {q: v for q, v in wanted.items() if config.quantities[q].driven}
    manual = {q: v for q, v in wanted.items() if config.quantities[q].axis == "manual"}
    return MovePlan(machine_targets=to_machine(config, driven), driven=driven, manual=manual)
