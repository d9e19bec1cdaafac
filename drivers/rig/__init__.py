"""The rig controller: GRBL 1.1 over a serial port, in three layers, and the rig in physical units.

- :mod:`drivers.rig.transport`: bytes (pyserial port, spy recorder, scripted fake);
- :mod:`drivers.rig.codec`: pure parse/encode of GRBL's lines, error and alarm tables;
- :mod:`drivers.rig.grbl`: :class:`GrblController`, the protocol in machine units (and its :class:`MoveStatus`);
  :mod:`drivers.rig.grbl_reports`: what it reports (:class:`GrblReading`, :class:`ControllerInfo`: settings,
  dialect); :mod:`drivers.rig.grbl_errors`: its failures;
- :mod:`drivers.rig.config`: :class:`RigConfig`, the mapping of physical quantities to axes;
- :mod:`drivers.rig.rig`: the :class:`Rig` protocol and :class:`GrblRig`, in mm and degrees;
- :mod:`drivers.rig.status`: :class:`RigStatus`, what a move returns (done, wait, reading, exception).

Typical use::

    from drivers.rig import GrblRig, load_rig_config
    with GrblRig("/dev/ttyUSB0", load_rig_config("rig.toml")) as rig:
        rig.home()
        status = rig.move_to(baseline_mm=120.0, alpha_left_deg=85.0, alpha_right_deg=85.0)  # queued: returns at once
        reading = status.wait()  # once the rig has stopped there
"""

from drivers.rig.config import (
    LimitError,
    MachineSpaceError,
    MoveRequestError,
    QuantityMapping,
    RigConfig,
    RigConfigError,
    RigError,
    load_rig_config,
)
from drivers.rig.grbl import (
    ControllerInfo,
    GrblAlarm,
    GrblCommandError,
    GrblConnectionError,
    GrblConnectionLost,
    GrblController,
    GrblError,
    GrblLocked,
    GrblMoveError,
    GrblPositionUnknown,
    GrblReading,
    GrblResetError,
    GrblSettingsError,
    GrblTimeout,
    MoveStatus,
)
from drivers.rig.rig import GrblRig, Rig, RigCapabilities, RigReading, manual_instruction
from drivers.rig.status import RigStatus, StatusTimeout

__all__ = [
    "ControllerInfo", "GrblAlarm", "GrblCommandError", "GrblConnectionError", "GrblConnectionLost", "GrblController",
    "GrblError", "GrblLocked", "GrblMoveError", "GrblPositionUnknown", "GrblReading", "GrblResetError", "GrblRig",
    "GrblSettingsError", "GrblTimeout", "LimitError", "MachineSpaceError", "MoveRequestError", "MoveStatus",
    "QuantityMapping", "Rig", "RigCapabilities", "RigConfig", "RigConfigError", "RigError", "RigReading", "RigStatus",
    "StatusTimeout", "load_rig_config", "manual_instruction",
]
