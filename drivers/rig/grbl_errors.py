"""Every failure of the GRBL controller driver, one class each, all a :class:`~drivers.rig.errors.RigError`
(the caller reports them in one line).
"""

from __future__ import annotations

from drivers.rig import codec
from drivers.rig.errors import RigError


class GrblError(RigError):
    """Base of the controller's failures."""


class GrblCommandError(GrblError):
    """A line answered with ``error:N``."""

    def __init__(self, code: int, line: str):
        self.code = code
        self.meaning = codec.error_meaning(code)
        self.line = line
        super().__init__(f"GRBL error:{code} for {line!r}: {self.meaning}")


class GrblAlarm(GrblError):
    """The controller pushed ``ALARM:N``, or is halted by one."""

    def __init__(self, code: int, context: str = ""):
        self.code = code
        self.meaning = codec.alarm_meaning(code)
        super().__init__(f"GRBL ALARM:{code}: {self.meaning}" + (f" ({context})" if context else ""))


class GrblLocked(GrblError):
    """The controller is in Alarm state and refuses motion until homed (``$H``) or unlocked (``$X``)."""


class GrblTimeout(GrblError, TimeoutError):
    """Something the controller should have said did not come in time."""


class GrblConnectionError(GrblError):
    """The port cannot be opened, or does not speak GRBL."""


class GrblConnectionLost(GrblConnectionError):
    """The port went away (unplugged, emulator stopped) after the connection was made."""


class GrblSettingsError(GrblError):
    """The controller's settings make it unsafe to drive (e.g. ``$13=1``: positions reported in inches)."""


class GrblResetError(GrblError):
    """The controller reset (a banner arrived) while lines were outstanding; they were discarded."""


class GrblMoveError(GrblError):
    """Motion ended somewhere other than the target."""


class GrblPositionUnknown(GrblLocked):
    """The controller booted (at open, late, or mid-run) or failed a homing cycle: its step counters say nothing
    about where the axes stand, so motion is refused until the rig is homed or the position is confirmed
    (:meth:`GrblController.trust_position`)."""
