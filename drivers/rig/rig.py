"""The rig in physical units: the :class:`Rig` protocol the campaign runner uses, and :class:`GrblRig`.

A campaign asks for a baseline, toe-ins (or alphas), tilts and a target distance; :class:`GrblRig`
turns that into one GRBL move through the :class:`~drivers.rig.config.RigConfig` mapping (refusing
anything outside the soft limits, or outside the machine space the controller accepts, before a byte
is sent) and returns its :class:`~drivers.rig.status.RigStatus`, which finishes once the controller has
stopped, with the reading there. The rig moves only its motors: a quantity set by hand is the operator's,
asked through the campaign's ``OperatorDesk`` (the runner's prompt steps, ``rig move``), and
:meth:`GrblRig.set_by_hand` records what the operator set.

At :meth:`GrblRig.open` the config is checked against what the controller reported (``$$``): machine
targets outside ``[-$13x, 0]`` (Grbl's machine space once homed), a tolerance finer than one step
(``$10x``), homing disabled. Each problem is one warning line in :meth:`GrblRig.controller_info`.

Angles: toe-in t = 90 deg - alpha (0 = parallel). Lengths in mm, angles in degrees, times in seconds.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import IO, Any, Protocol, runtime_checkable

import serial

from drivers.rig import codec
from drivers.rig.codec import vector_feed
from drivers.rig.config import (
    QUANTITIES,
    MachineSpaceError,
    MoveRequestError,
    RigConfig,
    RigConfigError,
    alpha_from_toe_in,
    plan_move,
    to_physical,
    toe_in_from_alpha,
)
from drivers.rig.grbl import GrblController, GrblReading
from drivers.rig.status import RigStatus
from drivers.rig.transport import Transport


@dataclass(frozen=True)
class RigReading:
    """Where the rig is, in physical units, with the controller's raw report behind it.

    A driven quantity comes from the controller's report; a fixed one from the config; a manual one
    from what the operator last confirmed (None until then). ``sources`` says which, per quantity.
    ``timestamp`` is time.time() (s) when the controller's report arrived.
    """

    state: str
    timestamp: float
    baseline_mm: float | None
    toe_in_left_deg: float | None
    toe_in_right_deg: float | None
    tilt_left_deg: float | None
    tilt_right_deg: float | None
    target_distance_mm: float | None
    machine_position: dict[str, float] | None
    sources: dict[str, str] = field(default_factory=dict)

    @property
    def alpha_left_deg(self) -> float | None:
        return None if self.toe_in_left_deg is None else alpha_from_toe_in(self.toe_in_left_deg)

    @property
    def alpha_right_deg(self) -> float | None:
        return None if self.toe_in_right_deg is None else alpha_from_toe_in(self.toe_in_right_deg)

    def to_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data["alpha_left_deg"] = self.alpha_left_deg
        data["alpha_right_deg"] = self.alpha_right_deg
        return data

    @staticmethod
    def describe() -> dict[str, dict[str, str]]:
        units = {q: ("mm" if q.endswith("_mm") else "deg") for q in QUANTITIES}
        units.update(alpha_left_deg="deg", alpha_right_deg="deg")
        described = {name: {"units": unit} for name, unit in units.items()}
        described["machine_position"] = {"units": "machine units per GRBL axis letter"}
        described["timestamp"] = {"units": "s since the epoch"}
        return described


@dataclass(frozen=True)
class RigCapabilities:
    """What a rig can do beyond moving, homing, reading, holding and resuming; each rig states it (the runner asks
    this, never ``getattr``). A rig without one still has the method (it does nothing that needs recording)."""

    #: A controller read at connect: :meth:`Rig.controller_info` and :attr:`Rig.warnings` are part of the recording.
    controller: bool = False
    #: A soft reset: the recovery after a fault resets before homing (without it, the rig is only homed).
    reset: bool = False
    #: It can be told that the position it reports is right without homing (``[rig] homing = false``).
    trust_position: bool = False


@runtime_checkable
class Rig(Protocol):
    """What the campaign runner needs from a stereo rig, whatever drives it (GRBL, a replay, a fake).

    ``move_to`` returns a :class:`~drivers.rig.status.RigStatus` at once (the request validated, the motion
    queued); the move finishes by itself, ``status.wait()`` blocks until it has and returns the reading there."""

    capabilities: RigCapabilities

    def open(self) -> Any: ...

    def close(self) -> None: ...

    def home(self, *, timeout_s: float | None = None) -> RigReading:
        """Home the motorised axes; return the reading afterwards."""

    def move_to(
        self, *, baseline_mm: float | None = None, toe_in_left_deg: float | None = None,
        toe_in_right_deg: float | None = None, tilt_left_deg: float | None = None,
        tilt_right_deg: float | None = None, target_distance_mm: float | None = None,
        timeout_s: float | None = None,
    ) -> RigStatus:
        """Move (None = leave as is): refused (raises) before anything moves, else the move's status."""

    def read(self) -> RigReading:
        """Where the rig is now."""

    def stop(self) -> None:
        """Stop motion as soon as possible (a feed hold on GRBL): the move's status then fails."""

    def resume(self, *, timeout_s: float | None = None) -> RigReading:
        """Continue after :meth:`stop`; return once the resumed motion has ended."""

    def reset(self) -> RigReading:
        """Soft reset (``capabilities.reset``): stop at once, discard queued moves, end a halt after an alarm."""

    def trust_position(self) -> RigReading:
        """The reported position is right without homing (``capabilities.trust_position``)."""

    def homing_approach(self) -> dict[str, int]:
        """Per driven quantity the direction (+1/-1) homing leaves it from; empty when not known."""

    def controller_info(self) -> dict[str, Any]:
        """The controller as read at connect, JSON-ready (``capabilities.controller``); empty without one."""

    @property
    def warnings(self) -> list[str]:
        """Every warning about the controller's setup (empty without a controller)."""


class GrblRig:
    """A stereo rig driven by a GRBL controller. Constructing it does no I/O.

    Args:
        port: a device path or pyserial URL, an open ``serial.SerialBase``, a :class:`Transport`, or an
            already-built :class:`GrblController`.
        config: the axis mapping and limits (default: stock Grbl machine space one pull-off inside it, X =
            baseline 1-349 mm at X -349..-1, Y/Z = left/right toe-in 0-88 deg at -1..-89, tilts fixed at 0, target
            distance manual).
        spy_log: record every byte on the link (see :class:`~drivers.rig.transport.SpyTransport`).
    """

    capabilities = RigCapabilities(controller=True, reset=True, trust_position=True)

    def __init__(
        self, port: str | serial.SerialBase | Transport | GrblController, config: RigConfig | None = None, *,
        spy_log: str | Path | IO[str] | None = None, **controller_options,
    ):
        self.config = config or RigConfig()
        settings = self.config.controller
        if isinstance(port, GrblController):
            self.controller = port
        else:
            options = dict(
                baudrate=settings.baudrate, rx_buffer_size=settings.rx_buffer_size,
                connect_timeout_s=settings.connect_timeout_s, reset_on_open=settings.reset_on_open, spy_log=spy_log,
            )
            options.update(controller_options)
            self.controller = GrblController(port, **options)
        self._manual: dict[str, float] = {}
        self._lock = threading.RLock()

    # lifecycle --------------------------------------------------------------------------------

    def open(self) -> GrblRig:
        """Connect; check that the controller has every axis the config drives, and the config against the
        controller's settings (warnings, see :meth:`controller_info`)."""
        self.controller.open()
        axes = self.controller.axes or ""
        missing = [a for a in self.config.axes if a not in axes]
        if missing:
            self.controller.close()
            raise RigConfigError(  # a setup the user fixes (the config or the firmware), not a fault
                f"the rig config drives axis {', '.join(missing)} but the controller on {self.controller.port_name} "
                f"reports only {', '.join(axes) or 'no axes'}")
        for message in config_warnings(self.config, self.controller.info, port=self.controller.port_name):
            self.controller._warn(message)
        return self

    def controller_info(self) -> dict[str, Any]:
        """What was read at connect, JSON-ready: build, options, settings (``{"$100": 250.0, ...}``),
        startup lines, receive buffer size, whether the controller booted at connect, and every warning."""
        return self.controller.info.to_dict()

    @property
    def warnings(self) -> list[str]:
        return list(self.controller.info.warnings)

    def close(self) -> None:
        self.controller.close()

    def __enter__(self) -> GrblRig:
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    # actions ----------------------------------------------------------------------------------

    def home(self, *, timeout_s: float | None = None) -> RigReading:
        """Run GRBL's homing cycle (``$H``) and return the reading afterwards."""
        with self._lock:
            timeout = self.config.controller.home_timeout_s if timeout_s is None else timeout_s
            return self._reading(self.controller.home(timeout=timeout))

    def homing_approach(self) -> dict[str, int]:
        """Per driven quantity the direction (+1 increasing, -1 decreasing, physical units) from which homing
        leaves it: the last move of the cycle pulls off its switch (limits.c ``limits_go_home``), toward -
        machine units on an axis homing toward + and toward + on a ``$23`` axis. The kinematic model's
        backlash correction needs it for the first configurations visited at the homed position. Empty when
        the settings were not read."""
        info = self.controller.info
        if not info.settings_read:
            return {}
        out = {}
        for quantity, axis in self.config.driven.items():
            homes_negative = codec.setting_bit(info.settings, codec.SETTING_HOMING_DIR_MASK,
                                               codec.AXIS_LETTERS.index(axis))
            machine = 1 if homes_negative else -1
            out[quantity] = machine if self.config.quantities[quantity].scale > 0 else -machine
        return out

    def unlock(self, *, trust_position: bool = False) -> RigReading:
        """Leave Alarm without homing (``$X``): only when the positions are known to be right. After a boot the
        position stays unknown (moves refused) unless ``trust_position`` states that it is right."""
        with self._lock:
            return self._reading(self.controller.unlock(trust_position=trust_position))

    def trust_position(self) -> RigReading:
        """The position the controller reports is right, without homing (a campaign with ``[rig] homing =
        false``): leave Alarm (``$X``) and stop refusing moves for a boot. Returns the reading then."""
        return self.unlock(trust_position=True)

    def read(self) -> RigReading:
        with self._lock:
            return self._reading(self.controller.status(timeout=2.0))

    def stop(self) -> None:
        self.controller.feed_hold()

    def resume(self, *, timeout_s: float | None = None) -> RigReading:
        """Continue after :meth:`stop` (a feed hold): wait until the hold is complete, send ``~``, confirm the
        controller left Hold, and return once the resumed motion has ended."""
        timeout = self.config.controller.move_timeout_s if timeout_s is None else timeout_s
        with self._lock:
            reading = self.controller.resume(timeout=timeout)
            if reading.state in ("Run", "Jog"):
                reading = self.controller.wait_idle(timeout)
            return self._reading(reading)

    def reset(self) -> RigReading:
        """Soft reset (0x18): stops at once and discards queued moves; ends a halt after ALARM:1/2.

        The controller keeps its position when it was standing still; a reset in motion raises ALARM:3
        (home again)."""
        with self._lock:
            reading = self.controller.soft_reset(timeout=self.config.controller.connect_timeout_s)
            return self._reading(reading)  # type: ignore[arg-type]

    def plan(self, **request: float | None) -> dict[str, float]:
        """The machine targets (axis letter -> machine units) a request would send; raises as move_to would."""
        return plan_move(self.config, request).machine_targets

    def move_to(
        self, *, baseline_mm: float | None = None, toe_in_left_deg: float | None = None,
        toe_in_right_deg: float | None = None, tilt_left_deg: float | None = None,
        tilt_right_deg: float | None = None, target_distance_mm: float | None = None,
        alpha_left_deg: float | None = None, alpha_right_deg: float | None = None,
        timeout_s: float | None = None, on_moving: Callable[[dict[str, float]], None] | None = None,
    ) -> RigStatus:
        """Move to a configuration (None = leave as is); return the move's status once it is queued.

        ``alpha_*_deg`` is an alternative to ``toe_in_*_deg`` (t = 90 - alpha); giving both for one side
        is an error. Everything is validated before anything moves, and raised here: unknown/fixed quantities
        (MoveRequestError), soft limits (LimitError), a target the controller refuses, a manual quantity other
        than what the operator last set (MoveRequestError: the operator sets it, see :meth:`manual_steps`). Then
        the motors move (``on_moving(machine_targets)`` is called once the move is queued) and the status
        finishes by itself (on a thread of its own) once the rig has stopped there; ``.wait()`` returns the
        reading then.
        """
        request = physical_request(
            baseline_mm=baseline_mm, toe_in_left_deg=toe_in_left_deg, toe_in_right_deg=toe_in_right_deg,
            tilt_left_deg=tilt_left_deg, tilt_right_deg=tilt_right_deg, target_distance_mm=target_distance_mm,
            alpha_left_deg=alpha_left_deg, alpha_right_deg=alpha_right_deg,
        )
        plan = plan_move(self.config, request)
        manual_steps = {q: v for q, v in plan.manual.items() if not _same(self._manual.get(q), v)}
        if manual_steps:
            names = ", ".join(manual_steps)
            raise MoveRequestError(f"{names} is set by hand on this rig and no operator prompt is available to "
                                   "the rig: ask the operator (the campaign's OperatorDesk), then set_by_hand()")
        timeout = self.config.controller.move_timeout_s if timeout_s is None else timeout_s
        with self._lock:
            motion = None
            if plan.machine_targets:
                refused = machine_space_violations(plan.machine_targets, self.controller.info,
                                                   homed=self.controller.homed)
                if refused:
                    raise MachineSpaceError(refused)
                feed = self._feed_for(plan.machine_targets)
                tolerance = self._tolerances(plan.driven)
                motion = self.controller.move_to(
                    plan.machine_targets, feed_per_min=feed, timeout_s=timeout, tolerance=tolerance)
                if on_moving is not None:
                    on_moving(dict(plan.machine_targets))

        def finish() -> RigReading:
            with self._lock:  # one talker at a time, as before: a read() waits for the move's end
                reading: GrblReading | None = motion.wait(timeout) if motion is not None else None
                if reading is None:
                    reading = self.controller.status(timeout=2.0)
                return self._reading(reading)

        return RigStatus.running(finish)

    def manual_steps(self, **request: float | None) -> dict[str, float]:
        """The quantities of a move request (``move_to``'s keywords) set by hand on this rig whose value differs
        from what the operator last set: what the operator has to do (then :meth:`set_by_hand`)."""
        plan = plan_move(self.config, physical_request(**request))
        return {q: v for q, v in plan.manual.items() if not _same(self._manual.get(q), v)}

    def set_by_hand(self, quantity: str, value: float) -> None:
        """The operator has set the manual ``quantity`` to ``value``: readings report it (source "operator")."""
        if self.config.quantities[quantity].axis != "manual":
            raise MoveRequestError(f"{quantity} is not set by hand on this rig")
        with self._lock:
            self._manual[quantity] = float(value)

    def move_to_pose(self, pose: Any, *, target_distance_mm: float | None = None,
                     timeout_s: float | None = None) -> RigStatus:
        """Move to a pose object with ``baseline_mm``, ``alpha_left_deg``, ``alpha_right_deg`` and optionally
        ``tilt_left_deg``/``tilt_right_deg`` (e.g. ``stereo_bench.geometry.RigPose``; duck-typed so this
        package does not import the app)."""
        return self.move_to(
            baseline_mm=pose.baseline_mm, alpha_left_deg=pose.alpha_left_deg, alpha_right_deg=pose.alpha_right_deg,
            tilt_left_deg=getattr(pose, "tilt_left_deg", None), tilt_right_deg=getattr(pose, "tilt_right_deg", None),
            target_distance_mm=target_distance_mm, timeout_s=timeout_s,
        )

    # helpers ----------------------------------------------------------------------------------

    def _tolerances(self, driven: Mapping[str, float]) -> dict[str, float]:
        """Machine-unit tolerance per axis: the config's, but never finer than one step (``$10x``)."""
        tolerance = {}
        for quantity in driven:
            mapping = self.config.quantities[quantity]
            spu = self.controller.info.steps_per_unit(mapping.axis)
            step = 1.0 / spu if spu else 0.0
            tolerance[mapping.axis] = max(mapping.tolerance * abs(mapping.scale), step)
        return tolerance

    def _feed_for(self, targets: Mapping[str, float]) -> float | None:
        feeds = self.config.axis_feeds_per_min()
        if all(feeds.get(axis) is None for axis in targets):
            return None  # rapid: no need to know where we start
        current = self.controller.last_reading
        here = current.machine_position if current is not None and current.machine_position else None
        if here is None:
            here = self.controller.status(timeout=2.0).machine_position or {}
        deltas = {axis: value - here.get(axis, value) for axis, value in targets.items()}
        return vector_feed(deltas, feeds)

    def _reading(self, grbl: GrblReading) -> RigReading:
        values: dict[str, float | None] = dict.fromkeys(QUANTITIES)
        sources: dict[str, str] = {}
        physical = to_physical(self.config, grbl.machine_position or {})
        for quantity in QUANTITIES:
            mapping = self.config.quantities[quantity]
            if mapping.driven:
                values[quantity] = physical.get(quantity)
                sources[quantity] = f"controller axis {mapping.axis}"
            elif mapping.axis == "fixed":
                values[quantity] = mapping.value
                sources[quantity] = "fixed"
            else:
                values[quantity] = self._manual.get(quantity)
                sources[quantity] = "operator" if quantity in self._manual else "unknown (manual)"
        return RigReading(
            state=grbl.full_state, timestamp=grbl.timestamp, machine_position=grbl.machine_position,
            sources=sources, **values,  # type: ignore[arg-type]
        )


def machine_space_violations(targets: Mapping[str, float], info: Any, *, homed: bool = True) -> list[str]:
    """One message per machine target the controller would not accept (empty when it would accept all).

    ``info`` is the controller's :class:`~drivers.rig.grbl.ControllerInfo`. Homed, Grbl's machine space is
    ``[-$13x, 0]`` (limits.c, system.c); with soft limits on (``$20=1``) a target outside it halts the
    controller with ALARM:2, and without them it drives the axis past its homing switch. grblHAL keeps one
    pull-off off each end with hard limits on (machine_limits.c ``limits_set_work_envelope``) and checks soft
    limits only on the axes it has homed (``check_travel_limits``): on an axis not homed (``homed`` False: the
    position was trusted, not homed) this check is the only one. Targets are compared as they go on the wire
    (3 decimals). Nothing is refused when homing is disabled (``$22=0``): machine coordinates then mean
    nothing fixed.
    """
    problems = []
    soft = bool(info.settings.get(codec.SETTING_SOFT_LIMITS))
    grblhal = info.dialect == "GrblHAL"
    for axis, value in targets.items():
        space = info.machine_space(axis)
        if space is None:
            continue
        sent = float(codec.format_number(value))
        low, high = space
        if not low <= sent <= high:
            number = codec.SETTING_MAX_TRAVEL + codec.AXIS_LETTERS.index(axis)
            if grblhal and soft and not homed:
                consequence = ("grblHAL checks soft limits only on homed axes and this one was not homed: it would "
                               "drive past the switch")
            elif soft:
                consequence = "soft limits would halt it with ALARM:2"
            else:
                consequence = "it would drive past the switch"
            where = "work envelope" if grblhal else "machine space"
            problems.append(f"{axis}={sent:g} is outside the controller's {where} {axis} {low:g}..{high:g} "
                            f"(${number}={info.settings[number]:g}; {consequence})")
    return problems


def config_warnings(config: RigConfig, info: Any, *, port: str = "controller") -> list[str]:
    """One warning line per conflict between a rig config and the controller's settings (``info``, a
    :class:`~drivers.rig.grbl.ControllerInfo`): machine targets outside the machine space, targets that reach a
    homing switch with hard limits on, a tolerance finer than one step, homing disabled. Empty when the settings
    were not read."""
    if not info.settings_read:
        return []
    warnings = []
    if not info.homing_enabled:
        warnings.append(f"{port}: homing is disabled ($22=0): machine positions count from wherever the axes "
                        "stood when the controller booted, so the rig config's mapping holds only if they stood "
                        "at machine 0 then; enable homing ($22=1) and soft limits ($20=1)")
    elif not info.settings.get(codec.SETTING_SOFT_LIMITS):
        warnings.append(f"{port}: soft limits are off ($20=0): the controller would not stop a move past its "
                        "travel; this driver refuses targets outside the machine space, other programs will not")
    at_switch = []
    for quantity, axis in config.driven.items():
        mapping = config.quantities[quantity]
        low, high = sorted((mapping.offset + mapping.scale * mapping.min,  # type: ignore[operator]
                            mapping.offset + mapping.scale * mapping.max))  # type: ignore[operator]
        space = info.machine_space(axis)
        number = codec.AXIS_LETTERS.index(axis)
        if space is not None:
            a, b = space
            where = (f"{quantity} = {mapping.min:g}..{mapping.max:g} maps to {axis} {low:g}..{high:g}, but the "
                     f"controller's machine space is {axis} {a:g}..{b:g} ($13{number}="
                     f"{info.settings.get(codec.SETTING_MAX_TRAVEL + number, 0):g}")
            if min(high, b) - max(low, a) <= 0.0:  # no overlap (or a single point)
                warnings.append(f"{where}; Grbl homes to 0 and counts negative): moves of {quantity} will be "
                                "refused; set offset/scale in the rig config (docs/RIG.md)")
            elif low < a or high > b:
                warnings.append(f"{where}): moves of {quantity} beyond it will be refused")
        if info.hard_limits:
            reached = _switch_reached(config, quantity, info)
            if reached is not None:
                at_switch.append(reached)
        spu = info.steps_per_unit(axis)
        if spu:
            step = 1.0 / spu / abs(mapping.scale)
            if mapping.tolerance < step:
                unit = "mm" if quantity.endswith("_mm") else "deg"
                warnings.append(f"{quantity}: tolerance {mapping.tolerance:g} {unit} is finer than one step of axis "
                                f"{axis} ({step:g} {unit} at $10{number}={spu:g}): using one step")
    if at_switch:
        pulloff = info.settings.get(codec.SETTING_HOMING_PULLOFF, 0.0)
        warnings.append(f"{port}: hard limits are on ($21=1) and {'; '.join(at_switch)}: a move there trips the "
                        f"switch and halts the controller with ALARM:1; keep every target at least the pull-off "
                        f"($27={pulloff:g}) inside it (docs/RIG.md section 3)")
    return warnings


def _switch_reached(config: RigConfig, quantity: str, info: Any) -> str | None:
    """Where ``quantity``'s range comes closer to its axis' homing switch than the pull-off (``$27``, the point
    homing proved clear of it), as text; None when it stays clear or the switch is not known."""
    mapping = config.quantities[quantity]
    axis = mapping.axis
    switch = info.switch_position(axis)
    if switch is None:
        return None
    pulloff = float(info.settings.get(codec.SETTING_HOMING_PULLOFF, 0.0))
    ends = {value: mapping.offset + mapping.scale * value for value in (mapping.min, mapping.max)}  # type: ignore
    homes_negative = codec.setting_bit(info.settings, codec.SETTING_HOMING_DIR_MASK, codec.AXIS_LETTERS.index(axis))
    # The switch closes the side the axis homes to; clear of it means at least one pull-off short of it.
    reaching = {value: target for value, target in ends.items()
                if (target < switch + pulloff - 1e-9 if homes_negative else target > switch - pulloff + 1e-9)}
    if not reaching:
        return None
    value, target = min(reaching.items(), key=lambda item: abs(item[1] - switch))  # the end nearest the switch
    unit = "mm" if quantity.endswith("_mm") else "deg"
    return (f"{quantity} = {value:g} {unit} maps to {axis}{target:g}, within {abs(target - switch):g} of the {axis} "
            f"switch at {axis}{switch:g}")


def physical_request(
    *, baseline_mm: float | None = None, toe_in_left_deg: float | None = None, toe_in_right_deg: float | None = None,
    tilt_left_deg: float | None = None, tilt_right_deg: float | None = None, target_distance_mm: float | None = None,
    alpha_left_deg: float | None = None, alpha_right_deg: float | None = None,
) -> dict[str, float | None]:
    """A move request keyed by quantity name (None = leave as is), alphas turned into toe-ins (t = 90 - alpha).

    Raises MoveRequestError if one side is given both a toe-in and an alpha. Pure; feed the result to
    :func:`drivers.rig.config.plan_move` to validate it against a config without touching the rig.
    """
    return {
        "baseline_mm": baseline_mm,
        "toe_in_left_deg": _merge_angle("left", toe_in_left_deg, alpha_left_deg),
        "toe_in_right_deg": _merge_angle("right", toe_in_right_deg, alpha_right_deg),
        "tilt_left_deg": tilt_left_deg, "tilt_right_deg": tilt_right_deg, "target_distance_mm": target_distance_mm,
    }


def _merge_angle(side: str, toe_in_deg: float | None, alpha_deg: float | None) -> float | None:
    if alpha_deg is None:
        return toe_in_deg
    if toe_in_deg is not None:
        raise MoveRequestError(f"give the {side} camera's toe-in or its alpha, not both")
    return toe_in_from_alpha(alpha_deg)


def _same(a: float | None, b: float) -> bool:
    return a is not None and math.isclose(a, b, abs_tol=1e-9)


_MANUAL_TEXT = {
    "baseline_mm": "set the baseline to B = {v:g} mm",
    "toe_in_left_deg": "turn the left camera to toe-in {v:g} deg (alpha {a:g} deg)",
    "toe_in_right_deg": "turn the right camera to toe-in {v:g} deg (alpha {a:g} deg)",
    "tilt_left_deg": "tilt the left camera to {v:g} deg",
    "tilt_right_deg": "tilt the right camera to {v:g} deg",
    "target_distance_mm": "move the target to Z = {v:g} mm",
}


def manual_instruction(quantity: str, value: float) -> str:
    """What to tell the operator for a manual quantity, e.g. 'move the target to Z = 400 mm, then press Enter'."""
    text = _MANUAL_TEXT[quantity].format(v=value, a=alpha_from_toe_in(value))
    return f"{text}, then press Enter"


__all__ = [
    "GrblRig", "Rig", "RigCapabilities", "RigReading", "RigStatus", "config_warnings",
    "machine_space_violations", "manual_instruction", "physical_request",
]
