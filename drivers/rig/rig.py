"""The rig in physical units: the :class:`Rig` protocol the campaign runner uses, and :class:`GrblRig`.

A campaign asks for a baseline, toe-ins (or alphas), tilts and a target distance; :class:`GrblRig`
turns that into one GRBL move through the :class:`~drivers.rig.config.RigConfig` mapping (refusing
anything outside the soft limits before a byte is sent), waits until the controller has stopped,
prompts the operator for the manual quantities, and reads back where the rig is.

Angles: toe-in t = 90 deg - alpha (0 = parallel). Lengths in mm, angles in degrees, times in seconds.
"""

from __future__ import annotations

import math
import sys
import threading
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import IO, Any, Protocol, runtime_checkable

import serial

from drivers.rig.codec import vector_feed
from drivers.rig.config import (
    QUANTITIES,
    MoveRequestError,
    RigConfig,
    RigError,
    alpha_from_toe_in,
    plan_move,
    to_physical,
    toe_in_from_alpha,
)
from drivers.rig.grbl import GrblController, GrblReading
from drivers.rig.transport import Transport

PromptCallback = Callable[[str], None]


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


@runtime_checkable
class Rig(Protocol):
    """What the campaign runner needs from a stereo rig, whatever drives it (GRBL, a replay, a fake)."""

    def open(self) -> Any: ...

    def close(self) -> None: ...

    def home(self, *, timeout_s: float | None = None) -> RigReading:
        """Home the motorised axes; return the reading afterwards."""

    def move_to(
        self, *, baseline_mm: float | None = None, toe_in_left_deg: float | None = None,
        toe_in_right_deg: float | None = None, tilt_left_deg: float | None = None,
        tilt_right_deg: float | None = None, target_distance_mm: float | None = None,
        timeout_s: float | None = None,
    ) -> RigReading:
        """Move (None = leave as is); return once stopped at the target, with the reading there."""

    def read(self) -> RigReading:
        """Where the rig is now."""

    def stop(self) -> None:
        """Stop motion as soon as possible (a feed hold on GRBL)."""


class GrblRig:
    """A stereo rig driven by a GRBL controller. Constructing it does no I/O.

    Args:
        port: a device path or pyserial URL, an open ``serial.SerialBase``, a :class:`Transport`, or an
            already-built :class:`GrblController`.
        config: the axis mapping and limits (default: X = baseline 0-350 mm, Y/Z = left/right toe-in 0-90
            deg, tilts fixed at 0, target distance manual).
        prompt: ``prompt(message) -> None`` shows the operator what to do for a manual quantity and
            returns once it is done (e.g. after Enter). Without it, a move that needs a manual step is
            refused before anything moves.
        spy_log: record every byte on the link (see :class:`~drivers.rig.transport.SpyTransport`).
    """

    def __init__(
        self, port: str | serial.SerialBase | Transport | GrblController, config: RigConfig | None = None, *,
        prompt: PromptCallback | None = None, spy_log: str | Path | IO[str] | None = None, **controller_options,
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
        self.prompt = prompt
        self._manual: dict[str, float] = {}
        self._lock = threading.RLock()

    # lifecycle --------------------------------------------------------------------------------

    def open(self) -> GrblRig:
        """Connect; check that the controller has every axis the config drives."""
        self.controller.open()
        axes = self.controller.axes or ""
        missing = [a for a in self.config.axes if a not in axes]
        if missing:
            self.controller.close()
            raise RigError(
                f"the rig config drives axis {', '.join(missing)} but the controller on {self.controller.port_name} "
                f"reports only {', '.join(axes) or 'no axes'}")
        return self

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

    def unlock(self) -> RigReading:
        """Leave Alarm without homing (``$X``): only when the positions are known to be right."""
        with self._lock:
            return self._reading(self.controller.unlock())

    def read(self) -> RigReading:
        with self._lock:
            return self._reading(self.controller.status(timeout=2.0))

    def stop(self) -> None:
        self.controller.feed_hold()

    def plan(self, **request: float | None) -> dict[str, float]:
        """The machine targets (axis letter -> machine units) a request would send; raises as move_to would."""
        return plan_move(self.config, request).machine_targets

    def move_to(
        self, *, baseline_mm: float | None = None, toe_in_left_deg: float | None = None,
        toe_in_right_deg: float | None = None, tilt_left_deg: float | None = None,
        tilt_right_deg: float | None = None, target_distance_mm: float | None = None,
        alpha_left_deg: float | None = None, alpha_right_deg: float | None = None,
        timeout_s: float | None = None, on_moving: Callable[[dict[str, float]], None] | None = None,
    ) -> RigReading:
        """Move to a configuration (None = leave as is) and return once the rig has stopped there.

        ``alpha_*_deg`` is an alternative to ``toe_in_*_deg`` (t = 90 - alpha); giving both for one side
        is an error. Everything is validated before anything moves: unknown/fixed quantities
        (MoveRequestError), soft limits (LimitError), a needed operator prompt that is missing. Then
        the motors move (``on_moving(machine_targets)`` is called once the move is queued), then the
        operator is prompted for the manual quantities.
        """
        request = physical_request(
            baseline_mm=baseline_mm, toe_in_left_deg=toe_in_left_deg, toe_in_right_deg=toe_in_right_deg,
            tilt_left_deg=tilt_left_deg, tilt_right_deg=tilt_right_deg, target_distance_mm=target_distance_mm,
            alpha_left_deg=alpha_left_deg, alpha_right_deg=alpha_right_deg,
        )
        plan = plan_move(self.config, request)
        manual_steps = {q: v for q, v in plan.manual.items() if not _same(self._manual.get(q), v)}
        if manual_steps and self.prompt is None:
            names = ", ".join(manual_steps)
            raise MoveRequestError(f"{names} is set by hand on this rig and no operator prompt is available")
        timeout = self.config.controller.move_timeout_s if timeout_s is None else timeout_s
        with self._lock:
            reading: GrblReading | None = None
            if plan.machine_targets:
                feed = self._feed_for(plan.machine_targets)
                tolerance = {self.config.quantities[q].axis: self.config.quantities[q].tolerance
                             * abs(self.config.quantities[q].scale) for q in plan.driven}
                status = self.controller.move_to(
                    plan.machine_targets, feed_per_min=feed, timeout_s=timeout, tolerance=tolerance)
                if on_moving is not None:
                    on_moving(dict(plan.machine_targets))
                reading = status.wait(timeout)
            for quantity, value in manual_steps.items():
                self.prompt(manual_instruction(quantity, value))  # type: ignore[misc]
                self._manual[quantity] = value
            if reading is None:
                reading = self.controller.status(timeout=2.0)
            return self._reading(reading)

    def move_to_pose(self, pose: Any, *, target_distance_mm: float | None = None,
                     timeout_s: float | None = None) -> RigReading:
        """Move to a pose object with ``baseline_mm``, ``alpha_left_deg``, ``alpha_right_deg`` and optionally
        ``tilt_left_deg``/``tilt_right_deg`` (e.g. ``stereo_bench.geometry.RigPose``; duck-typed so this
        package does not import the app)."""
        return self.move_to(
            baseline_mm=pose.baseline_mm, alpha_left_deg=pose.alpha_left_deg, alpha_right_deg=pose.alpha_right_deg,
            tilt_left_deg=getattr(pose, "tilt_left_deg", None), tilt_right_deg=getattr(pose, "tilt_right_deg", None),
            target_distance_mm=target_distance_mm, timeout_s=timeout_s,
        )

    # helpers ----------------------------------------------------------------------------------

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


def wait_for_enter(message: str, *, stream_in=None, stream_out=None) -> None:
    """A terminal prompt for :class:`GrblRig`: print the instruction and wait for Enter."""
    out = stream_out or sys.stderr
    out.write(message + " ")
    out.flush()
    line = (stream_in or sys.stdin).readline()
    if line == "":
        raise RigError(f"no operator answer (end of input) to: {message}")


__all__ = [
    "GrblRig", "PromptCallback", "Rig", "RigReading", "manual_instruction", "physical_request", "wait_for_enter",
]
