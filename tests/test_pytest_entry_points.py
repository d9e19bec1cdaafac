"""``pytest`` and ``python -m pytest`` run the same suite (README's hardware tier, ``pytest --camera ...``, is bare
``pytest`` with an option that changes what is skipped, not what is collected).

``python -m pytest`` puts the working directory on ``sys.path``; the bare ``pytest`` script does not, and the test
modules import their shared helpers as ``tests.campaigns``, ``tests.real_data``, ...: without pyproject's
``pythonpath = ["."]`` bare ``pytest`` failed to collect 25 of 73 modules (``No module named 'tests'``).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _collected(command: list[str], cwd: Path) -> list[str]:
    """The test ids ``command --collect-only -q`` lists, run in ``cwd`` with no PYTHONPATH from the caller."""
    env = {key: value for key, value in os.environ.items() if key != "PYTHONPATH"}
    result = subprocess.run([*command, "--collect-only", "-q", "-n", "0", "-p", "no:cacheprovider"], cwd=cwd,
                            env=env, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return sorted(line for line in result.stdout.splitlines() if "::" in line)


@pytest.mark.slow  # two collections of the whole suite (~10 s each on 2 cores): the only way to compare them
def test_bare_pytest_collects_what_python_m_pytest_collects():
    script = shutil.which("pytest", path=str(Path(sys.executable).parent))
    assert script is not None, f"no pytest script beside {sys.executable}"
    as_module = _collected([sys.executable, "-m", "pytest"], ROOT)
    bare = _collected([script], ROOT)
    assert len(as_module) > 1000  # the whole suite, not an empty or partial collection
    assert bare == as_module
