"""What a campaign is checked for before anything moves, in one place: ``campaign plan`` and ``campaign run`` both
call :func:`check_campaign`, so a plan that passes cannot fail ``run`` on what is checked here (issue 9 item 5).

Checked, each failure one :class:`~stereo_bench.campaign.config.ConfigError` line ``SOURCE: field: what``:

- the cameras' names (V4L2): no ``/dev/videoN``, and not one camera as both sides (``run`` refuses both);
- the bench: the rig and camera kinds make a bench (``CampaignConfig``'s own validator); with simulated cameras
  (the simulated bench and bring-up) every quantity the cameras render from (baseline, toe-ins, tilts) is driven
  by an axis or fixed: the renderer places the cameras where the controller reports the axes, so a ``manual``
  one has no value there (the target distance is set "by hand" by the simulator, and a manual tilt renders as 0,
  right only for a plan at ``tilt_deg = 0``);
- the files the config names, read the way ``run`` reads them: ``extrinsics.calib_dir`` (``fixed``: the whole
  stereo calibration; otherwise the intrinsics and their covariance) and its image size against
  ``cameras.optics``; ``extrinsics.kinematic_file``; ``rig.config_file``.

Per configuration (not an error: the configuration is planned as infeasible and skipped by ``run``), the
feasibility rule of :func:`stereo_bench.campaign.plan.expand_plan`, which ``run`` uses too: enough target corners
in both views, each view's target squares large enough for the corner detector
(:func:`stereo_bench.vision.detect.min_detectable_square_px`), the calibration board placeable, the soft limits.

:func:`preflight` runs these checks once and keeps what it read and resolved (:class:`Preflight`: the rig config,
the kinematic model, what ``calib_dir`` gives the runner, the copies of the input files the session records), so
that ``campaign run`` reads each input file once before the first move: the CLI runs it and hands it to
:func:`~stereo_bench.campaign.execute.run_campaign`, which runs it itself only when not given one.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from drivers.files import read_once
from drivers.rig.config import RigConfig, RigConfigError
from stereo_bench.campaign.config import CampaignConfig, ConfigError
from stereo_bench.campaign.documents import Draft

#: The quantities simulated cameras render from: each must be driven by an axis or fixed.
RENDERED_QUANTITIES = ("baseline_mm", "toe_in_left_deg", "toe_in_right_deg", "tilt_left_deg", "tilt_right_deg")


@dataclass(frozen=True)
class Preflight:
    """A campaign config checked as ``run`` checks it before moving, and the inputs it names, read once: the rig
    config (``rig.config_file``), the kinematic model (``extrinsics.kinematic_file``), what ``extrinsics.calib_dir``
    sets in the runner's options (``calib_dir_options``: the intrinsics and their covariance, the fixed calibration,
    nominal's intrinsics) and the documents that record the input files' copies in the session (``sources``)."""

    config: CampaignConfig
    rig_config: RigConfig
    kinematic_model: Any = None
    calib_dir_options: MappingProxyType = field(default_factory=lambda: MappingProxyType({}))
    sources: tuple[Draft, ...] = ()


def preflight(config: CampaignConfig, *, source: str = "campaign config") -> Preflight:
    """Everything ``run`` checks before moving (:func:`check_campaign`), and what it read; raises ``ConfigError``."""
    from stereo_bench.campaign.extrinsics_run import session_sources

    with read_once():  # each input file read once, whichever checks and parsers read it
        rig_config = check_bench(config, source=source)
        kinematic_model, calib_dir_options = _read_files(config, source=source)
        sources = tuple(session_sources(config))
    return Preflight(config=config, rig_config=rig_config, kinematic_model=kinematic_model,
                     calib_dir_options=MappingProxyType(calib_dir_options), sources=sources)


def check_campaign(config: CampaignConfig, *, source: str = "campaign config") -> None:
    """Everything ``run`` checks before moving, without moving or opening anything; raises ``ConfigError``."""
    preflight(config, source=source)


def check_bench(config: CampaignConfig, *, source: str = "campaign config") -> RigConfig:
    """The rig mapping fits the bench: simulated cameras cannot render a quantity set by hand; V4L2 cameras are
    named stably and are two cameras. Returns the rig config."""
    try:
        rig_config = config.rig.rig_config()
    except RigConfigError as error:
        raise ConfigError(f"{source}: rig.config_file: {error}") from None
    if config.cameras.kind == "v4l2":
        check_camera_names(config, source=source)
        return rig_config
    if config.cameras.kind != "simulated":
        return rig_config
    where = (f"rig.config_file ({config.rig.config_file}): quantities" if config.rig.config_file is not None
             else "rig.quantities")
    for quantity in RENDERED_QUANTITIES:
        if quantity.startswith("tilt_") and not any(config.plan.tilts()):
            continue  # the renderer takes a tilt without a value as 0, which is what the operator is asked to set
        if rig_config.quantities[quantity].axis == "manual":
            bench = "bring-up" if config.rig.kind == "grbl" else "the simulated bench"
            raise ConfigError(
                f"{source}: {where}.{quantity}: axis = \"manual\" cannot run on {bench}: the simulated cameras "
                f"render from the axis positions the controller reports, and a manual {quantity} has none; drive "
                f"it by an axis, or set axis = \"fixed\" with its value (only target_distance_mm can be manual)")
    return rig_config


def check_camera_names(config: CampaignConfig, *, source: str = "campaign config") -> None:
    """The names ``run`` resolves the cameras by, checked without looking at a device: no ``/dev/videoN`` (its
    number changes across reboots, :func:`drivers.camera.usb_identity.is_unstable_name`, which ``run`` refuses
    too) and not one camera as both left and right (the pair would have no baseline)."""
    from drivers.camera.usb_identity import UNSTABLE_NAME_REASON, is_unstable_name, spec_key

    left, right = config.cameras.left or "", config.cameras.right or ""
    for side, spec in (("left", left), ("right", right)):
        if is_unstable_name(spec):
            raise ConfigError(f"{source}: cameras.{side}: {spec.strip()}: {UNSTABLE_NAME_REASON}")
    if spec_key(left) == spec_key(right):
        raise ConfigError(f"{source}: cameras.right: {right.strip()} is also cameras.left: one camera cannot be both "
                          "sides of a stereo pair; name the other camera (`stereo-bench devices` lists them)")


def _image_size(config: CampaignConfig) -> tuple[tuple[int, int], str] | None:
    """(width, height) of the frames the cameras will give and the keys that say so; None when not known offline."""
    if config.cameras.kind == "simulated":
        optics = config.cameras.optics
        return (optics.width_px, optics.height_px), "cameras.optics width_px, height_px"
    settings = config.cameras.camera_settings()
    if settings.width_px is not None and settings.height_px is not None:
        return (settings.width_px, settings.height_px), "cameras.settings width_px, height_px"
    return None


class _CalibDirOptions:
    """What a source's ``load_calibration`` sets from ``calib_dir`` (the runner's options take these attributes)."""


def _read_files(config: CampaignConfig, *, source: str) -> tuple[Any, dict[str, Any]]:
    """Read the calibration and model files the config names, as ``run`` will (a corrupt YAML fails here), and
    keep what the run takes from them: the kinematic model, the options ``calib_dir`` sets."""
    from stereo_bench.kinematics import KinematicFileError, load_model
    from stereo_bench.vision.calibio import CalibrationFileError

    extrinsics = config.extrinsics
    optics = config.cameras.optics
    image_size = (optics.width_px, optics.height_px)
    calib_dir = extrinsics.calib_dir
    if calib_dir is not None:
        if not calib_dir.is_dir():
            raise ConfigError(f"{source}: extrinsics.calib_dir: no such directory: {calib_dir}")
        try:
            size = extrinsics.source().read_calib_dir(calib_dir, image_size)
        except CalibrationFileError as error:
            raise ConfigError(f"{source}: extrinsics.calib_dir: {error}") from None
        given = _image_size(config)
        if size is not None and given is not None and tuple(size) != given[0]:
            raise ConfigError(
                f"{source}: extrinsics.calib_dir: {calib_dir} is a calibration of {size[0]}x{size[1]} images, the "
                f"cameras give {given[0][0]}x{given[0][1]} ({given[1]})")
    calib_dir_options: dict[str, Any] = {}
    if calib_dir is not None:
        read = _CalibDirOptions()
        try:
            extrinsics.source().load_calibration(read, extrinsics, reader=None, intrinsics_copy=None,
                                                 image_size=image_size)
        except CalibrationFileError as error:
            raise ConfigError(f"{source}: extrinsics.calib_dir: {error}") from None
        calib_dir_options = vars(read)
    model = None
    if extrinsics.kinematic_file is not None:
        try:
            model = load_model(extrinsics.kinematic_file)
        except KinematicFileError as error:
            raise ConfigError(f"{source}: extrinsics.kinematic_file: {error}") from None
        _check_model_axes(config, model, source=source)
    return model, calib_dir_options


def _check_model_axes(config: CampaignConfig, model, *, source: str) -> None:
    """A model with tilt joints predicts from the reported tilts: a rig that does not drive one reports none, and
    every configuration would fail to predict (``axes: missing tilt_left_deg``). Said once, before any motion."""
    from stereo_bench.kinematics.model import TILT_AXES

    driven = config.rig.rig_config().driven
    missing = [axis for axis in model.axes if axis in TILT_AXES and axis not in driven]
    if missing:
        raise ConfigError(
            f"{source}: extrinsics.kinematic_file: {config.extrinsics.kinematic_file}: the model has a tilt joint "
            f"for {', '.join(missing)}, which this rig does not drive (map it in the rig config's [quantities], "
            f"or use a model fitted on a rig without tilt axes)")


__all__ = [
    "RENDERED_QUANTITIES", "Preflight", "check_bench", "check_camera_names", "check_campaign", "preflight",
]
