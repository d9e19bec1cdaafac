"""The kinematic model's file: readable TOML (every parameter with value, sigma, unit; the covariance), read back
checked, one line naming the file and the field when it cannot be used.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from drivers.files import MAX_TOML_BYTES, InputFileError, decode_utf8, parse_toml, read_regular_file
from stereo_bench import atomic
from stereo_bench.kinematics.model import KinematicModel


class KinematicFileError(ValueError):
    """A kinematic model file that cannot be used; one line naming the file and the field."""


def save_model(model: KinematicModel, path: str | Path) -> Path:
    """Write ``model`` as a readable TOML file (every parameter with value, sigma, unit; the covariance).

    Atomically, and never over an existing file (FileExistsError): a file that appeared since the caller checked
    the path is not replaced.
    """
    return atomic.write_text(Path(path), model_toml(model), overwrite=False)


def model_toml(model: KinematicModel) -> str:
    """The readable TOML text :func:`save_model` writes (checked to read back)."""
    data = model.model_dump(mode="json", by_alias=True)
    lines = ["# stereo-bench kinematic rig model: T_right_left at any (B, toe-ins) from the rig's axis positions.",
             "# Parameters in mm, deg and 1; covariance over the identifiable ones, same units and order.", ""]
    keys = ["schema", "reference_baseline_mm", "repeatability_mm", "repeatability_left_deg",
            "repeatability_right_deg", "image_size", "covariance_names"]
    if model.tilts:  # a rig with tilt joints; a file without these keys is a model of one without (every older file)
        keys[1:1] = ["axes"]
        keys[5:5] = [f"repeatability_{axis.removesuffix('_deg')}_deg" for axis in model.tilts]
    for key in keys:
        lines.append(f"{key} = {_toml_value(data[key])}")
    lines.append("covariance = [")
    lines.extend(f"  {_toml_value(row)}," for row in data["covariance"])
    lines.append("]")
    for key in ("K1", "K2"):
        lines.append(f"{key} = {_toml_value(data[key])}")
    for key in ("D1", "D2"):
        lines.append(f"{key} = {_toml_value(data[key])}")
    if data.get("pixel_locking_px") is not None:
        lines.append("# the corner detector's pixel locking (a_sin, a_cos) px, from the fit's residuals")
        lines.append(f"pixel_locking_px = {_toml_value(data['pixel_locking_px'])}")
    if data["intrinsics_covariance_names"]:
        lines.append("# covariance of the intrinsics the fit refined (px and 1), marginal over everything else")
        lines.append(f"intrinsics_covariance_names = {_toml_value(data['intrinsics_covariance_names'])}")
        lines.append("intrinsics_covariance = [")
        lines.extend(f"  {_toml_value(row)}," for row in data["intrinsics_covariance"])
        lines.append("]")
    if data["cross_covariance"]:
        lines.append("# Cov(intrinsics, parameters): rows intrinsics_covariance_names, columns covariance_names")
        lines.append("cross_covariance = [")
        lines.extend(f"  {_toml_value(row)}," for row in data["cross_covariance"])
        lines.append("]")
    lines += ["", "[span]"]
    lines.extend(f"{axis} = {_toml_value(values)}" for axis, values in data["span"].items())
    for spec in model.specs:
        name = spec.name
        lines += ["", f"[parameters.{name}]  # {spec.description}"]
        lines.extend(f"{key} = {_toml_value(value)}" for key, value in data["parameters"][name].items()
                     if value is not None)
    if data.get("fit") is not None:
        lines += ["", "[fit]"]
        lines.extend(f"{key} = {_toml_value(value)}" for key, value in data["fit"].items() if value is not None)
    for side, record in (data.get("residual_maps") or {}).items():
        lines += ["", f"[residual_maps.{side}]  # the fit's residuals binned over the image (projected - observed)"]
        lines.extend(f"{key} = {_toml_value(value)}" for key, value in record.items())
    text = "\n".join(lines) + "\n"
    tomllib.loads(text)  # never write a file that does not read back
    return text


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f"cannot write {value} to TOML")
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + "}"
    raise TypeError(f"cannot write {type(value).__name__} to TOML")


def load_model(path: str | Path) -> KinematicModel:
    """Read and validate a kinematic model file; :class:`KinematicFileError` names the file and field.

    Read as every input file is (:func:`drivers.files.read_regular_file`: a regular file of bounded size).
    """
    try:
        text = decode_utf8(read_regular_file(path, what="kinematic model file", max_bytes=MAX_TOML_BYTES), path)
    except InputFileError as error:
        raise KinematicFileError(str(error)) from None
    return model_from_toml(text, str(path))


def model_from_toml(text: str, source: str = "kinematic model") -> KinematicModel:
    """Parse and validate the TOML text of a model; :class:`KinematicFileError` names ``source`` and the field."""
    path = source
    try:
        data = parse_toml(text, path)
    except InputFileError as error:
        raise KinematicFileError(str(error)) from None
    try:
        return KinematicModel.model_validate(data)
    except ValidationError as error:
        first = error.errors()[0]
        where = ".".join(str(p) for p in first.get("loc", ())) or "(top level)"
        message = first.get("msg", "invalid").removeprefix("Value error, ")
        raise KinematicFileError(f"{path}: {where}: {message}") from None
