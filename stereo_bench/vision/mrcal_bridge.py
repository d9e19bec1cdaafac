"""mrcal, out of process: where it is, and the cross-check fit of the same corners (docs/FORMATS.md).

mrcal has no wheel for the Python the project runs on (BRIEF section 8); Debian's ``python3-mrcal`` installs it for
the system Python. So it runs in a child process: :func:`mrcal_python` finds an interpreter that imports it
(``STEREO_BENCH_MRCAL_PYTHON``, else ``/usr/bin/python3``, else ``python3`` on PATH), and the solve's inputs and
results cross as JSON.
"""

from __future__ import annotations

import functools
import os
import shutil
import subprocess

#: The interpreter to run mrcal with, when it is not the system Python (a venv of Python >= 3.12 with mrcal 2.5).
MRCAL_PYTHON_ENV = "STEREO_BENCH_MRCAL_PYTHON"
PROBE_TIMEOUT_S = 60


class MrcalUnavailable(RuntimeError):
    """No Python with mrcal was found (the message says where it looked and how to install it)."""


def _candidates() -> list[str]:
    given = os.environ.get(MRCAL_PYTHON_ENV)
    if given:
        return [given]
    found = ["/usr/bin/python3"]
    on_path = shutil.which("python3")
    if on_path and on_path not in found:
        found.append(on_path)
    return found


@functools.cache
def _probe(python: str) -> str | None:
    """mrcal's version as ``python`` imports it, or None."""
    try:
        done = subprocess.run([python, "-c", "import mrcal, numpy; print(getattr(mrcal, '__version__', '2'))"],
                              capture_output=True, text=True, timeout=PROBE_TIMEOUT_S)
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout.strip() or "unknown" if done.returncode == 0 else None


def mrcal_python() -> str | None:
    """The first interpreter that imports mrcal: ``$STEREO_BENCH_MRCAL_PYTHON`` (only it, when set), else
    ``/usr/bin/python3`` (Debian's python3-mrcal), else ``python3`` on PATH; None when none does."""
    for python in _candidates():
        if _probe(python) is not None:
            return python
    return None


def unavailable_reason() -> str:
    where = ", ".join(_candidates())
    return (f"mrcal is not importable by {where} (install Debian's packages: apt-get install mrcal python3-mrcal; "
            f"or set {MRCAL_PYTHON_ENV} to a Python that imports mrcal)")
