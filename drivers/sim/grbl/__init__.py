"""The GRBL 1.1h / grblHAL controller the simulated bench runs on a pseudo-terminal, one room per concern:

- :mod:`drivers.sim.grbl.emulator`: :class:`GrblEmulator`, the firmware's state machine on its pty (the byte
  protocol, the ``$`` commands, homing, alarms, the grblHAL dialect), see docs/RIG.md;
- :mod:`drivers.sim.grbl.firmware`: the build constants, the ``$$`` defaults and the axes (:class:`AxisSpec`);
- :mod:`drivers.sim.grbl.planner`: planned blocks, feed-hold stops, homing phases, :class:`MotionEvent`;
- :mod:`drivers.sim.grbl.faults`: the faults it injects and their command-line spelling.
"""
