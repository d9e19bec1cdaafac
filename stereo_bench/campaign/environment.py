"""The numeric environment of this process: what decides the last digits of a computed number.

The same frames give the same numbers only on the same arithmetic: numpy's OpenBLAS picks its kernels
by CPU at run time (``OPENBLAS_CORETYPE`` forces a kernel family) and splits work by its thread count,
and OpenCV dispatches its own SIMD paths (``OPENCV_CPU_DISABLE`` turns some off). A session records this
in its start (and resume) document, and a replay says where today's differs (docs/REPLAY.md):

    numeric_environment()["blas"]      # [{'package': 'numpy', 'internal_api': 'openblas',
                                       #   'version': '0.3.31.188.0', 'architecture': 'Haswell', ...}, ...]
    environment_differences(recorded, numeric_environment())
    # [('BLAS core (numpy)', 'Haswell', 'Katmai'), ('OPENBLAS_CORETYPE', None, 'Prescott')]

OpenBLAS's core name is ``openblas_get_corename()`` (through threadpoolctl): it names kernel families
coarsely (Prescott and Core2 both report ``Katmai`` and still give other last digits), which is why the
variables that force a core type or a thread count are recorded beside it.
"""

from __future__ import annotations

import os
import platform
from collections.abc import Mapping
from functools import cache
from pathlib import Path
from typing import Any

import cv2
import numpy as np

# Variables that change which kernels run or how work is split, hence the last digits of a result.
NUMERIC_VARIABLES = ("OPENBLAS_CORETYPE", "OPENBLAS_NUM_THREADS", "OPENBLAS_VERBOSE", "GOTO_NUM_THREADS",
                     "OMP_NUM_THREADS", "MKL_NUM_THREADS", "MKL_CBWR", "MKL_ENABLE_INSTRUCTIONS",
                     "NPY_DISABLE_CPU_FEATURES", "OPENCV_CPU_DISABLE", "OPENCV_FOR_THREADS_NUM")
# The vector extensions that select different SIMD kernels (x86 /proc/cpuinfo ``flags``, Arm ``Features``).
VECTOR_EXTENSIONS = ("sse2", "sse3", "ssse3", "sse4_1", "sse4_2", "avx", "f16c", "fma", "avx2", "avx512f",
                     "avx512dq", "avx512cd", "avx512bw", "avx512vl", "avx512_vnni", "avx512_bf16", "avx512_fp16",
                     "amx_tile", "neon", "asimd", "asimddp", "sve", "sve2")
# (field, label) in the order a replay names the differences; a BLAS library's fields follow its package.
BLAS_LABELS = (("architecture", "BLAS core"), ("num_threads", "BLAS threads"), ("internal_api", "BLAS"),
               ("version", "BLAS version"), ("library", "BLAS library"), ("threading_layer", "BLAS threading"))
LABELS = (("numpy", "numpy"), ("opencv", "OpenCV"), ("python", "Python"), ("opencv_threads", "OpenCV threads"),
          ("opencv_cpu_features", "OpenCV CPU features"), ("cpu.model", "CPU"), ("cpu.machine", "machine"),
          ("cpu.vector_extensions", "vector extensions"))


def blas_libraries() -> list[dict[str, Any]]:
    """The BLAS libraries loaded in this process, as threadpoolctl reports them, by the package that ships
    each (``numpy``; OpenCV's wheels bring an OpenBLAS of their own for their LAPACK calls): ``package``,
    ``library`` (file name), ``internal_api`` (openblas, mkl, blis), ``version``, ``architecture`` (the kernel
    family chosen), ``num_threads``, ``threading_layer``. Sorted by package; the directory is left out (it
    says where a library is installed, not how it computes)."""
    from threadpoolctl import threadpool_info

    keys = ("internal_api", "version", "architecture", "num_threads", "threading_layer")
    found = []
    for info in threadpool_info():
        if info.get("user_api") != "blas":
            continue
        path = Path(str(info.get("filepath") or ""))
        package = path.parent.name.removesuffix(".libs") or None  # numpy.libs/libscipy_openblas64_-....so
        found.append({"package": package, "library": path.name or None, **{key: info.get(key) for key in keys}})
    return sorted(found, key=lambda library: (library["package"] != "numpy", str(library["package"]),
                                              str(library["library"])))


@cache
def cpu() -> dict[str, Any]:
    """``model``, ``machine`` and the ``vector_extensions`` present (None: not known on this platform)."""
    model, flags = None, None
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as handle:
            for line in handle:
                key, _, value = line.partition(":")
                key = key.strip().lower()
                if model is None and key in ("model name", "hardware", "cpu model", "uarch"):
                    model = value.strip()
                elif flags is None and key in ("flags", "features"):
                    flags = set(value.split())
                    if "pni" in flags:  # the kernel's name for SSE3 ("Prescott New Instructions")
                        flags.add("sse3")
                if model is not None and flags is not None:
                    break
    except OSError:  # not Linux: the platform's own names, extensions unknown
        pass
    return {"model": model or platform.processor() or platform.machine() or None, "machine": platform.machine(),
            "vector_extensions": None if flags is None else [name for name in VECTOR_EXTENSIONS if name in flags]}


def numeric_environment() -> dict[str, Any]:
    """The numeric environment of this process now (``documents.NumericEnvironment`` as JSON)."""
    from stereo_bench.vision.calibrate import opencv_threads
    return {
        "python": platform.python_version(), "numpy": np.__version__, "opencv": cv2.__version__,
        "blas": blas_libraries(),
        "variables": {name: os.environ[name] for name in NUMERIC_VARIABLES if name in os.environ},
        "opencv_threads": opencv_threads(),
        "opencv_cpu_features": cv2.getCPUFeaturesLine(),
        "cpu": cpu(),
    }


def _flat(environment: Mapping[str, Any]) -> dict[str, Any]:
    """label -> value: the BLAS libraries' fields as 'BLAS core (numpy)', the CPU's and the rest by
    :data:`LABELS`, in the order a replay names them, then anything else under its own name."""
    labels = dict(LABELS)
    flat: dict[str, Any] = {}
    for library in environment.get("blas") or []:
        package = library.get("package") or "?"
        for key, label in BLAS_LABELS:
            flat[f"{label} ({package})"] = library.get(key)
    rest = {key: value for key, value in environment.items() if key not in ("blas", "cpu", "variables")}
    rest.update({f"cpu.{key}": value for key, value in (environment.get("cpu") or {}).items()})
    for key in [key for key, _ in LABELS] + sorted(set(rest) - set(labels)):
        if key in rest:
            flat[labels.get(key, key)] = rest[key]
    return flat


def environment_differences(recorded: Mapping[str, Any], today: Mapping[str, Any]) -> list[tuple[str, Any, Any]]:
    """(label, recorded, today) for every field that differs: each BLAS library by the package that ships it
    ('BLAS core (numpy)'; one loaded on one side only shows as '(not set)' on the other), then
    :data:`LABELS`, then the variables (``OPENBLAS_CORETYPE`` ...; None: not set)."""
    old, new = _flat(recorded), _flat(today)
    keys = list(old) + [key for key in new if key not in old]
    found = [(key, old.get(key), new.get(key)) for key in keys if old.get(key) != new.get(key)]
    old_vars, new_vars = recorded.get("variables") or {}, today.get("variables") or {}
    found += [(name, old_vars.get(name), new_vars.get(name)) for name in sorted(set(old_vars) | set(new_vars))
              if old_vars.get(name) != new_vars.get(name)]
    return found


def describe_differences(differences: list[tuple[str, Any, Any]]) -> str:
    """E.g. 'BLAS core Haswell -> Katmai, OPENBLAS_CORETYPE (not set) -> Prescott'."""
    def shown(value: Any) -> str:
        if value is None:
            return "(not set)"
        if isinstance(value, list):
            return " ".join(str(item) for item in value) or "(none)"
        return str(value)

    parts = []
    for label, old, new in differences:
        if isinstance(old, list) and isinstance(new, list):  # vector extensions: what was added or lost
            lost, gained = [x for x in old if x not in new], [x for x in new if x not in old]
            parts.append(f"{label} " + ", ".join([f"-{x}" for x in lost] + [f"+{x}" for x in gained]))
        else:
            parts.append(f"{label} {shown(old)} -> {shown(new)}")
    return ", ".join(parts)


__all__ = ["NUMERIC_VARIABLES", "VECTOR_EXTENSIONS", "blas_libraries", "cpu", "describe_differences",
           "environment_differences", "numeric_environment"]
