"""The runner's options from a campaign config (:func:`runner_options`); a replay's from its recording."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from stereo_bench.campaign.config import CampaignConfig
from stereo_bench.campaign.plan import Visit
from stereo_bench.campaign.preflight import Preflight
from stereo_bench.campaign.runner import RunnerOptions
from stereo_bench.campaign.session import SessionError, SessionReader


def _recorded_copy(reader: SessionReader, kind: str, name: str) -> Path | None:
    """The recording's last copy of an outside file: side file ``name`` of a ``kind`` event (``rig_config``: the
    ``[rig] config_file``; ``intrinsics``: calib_dir's intrinsics.yml), if it holds one."""
    for event in reversed(reader.events(kind=kind, attempt=None)):
        relative = event.files.get(name)
        if relative:
            return reader.path(relative)
    return None


def runner_options(config: CampaignConfig, *, reader: SessionReader | None = None,
                   visits: Sequence[Visit] = (), preflight: Preflight | None = None) -> RunnerOptions:
    """The runner's options from the config; ``reader``: a replay takes a fixed calibration, a model file's copy
    and nominal's ``calib_dir`` intrinsics from the recording, never from outside the session; ``preflight``: a
    run takes what ``calib_dir`` and ``kinematic_file`` hold from what its preflight read, without reading them
    again."""
    from stereo_bench.campaign.extrinsics_run import recorded_sources
    from stereo_bench.kinematics import KinematicFileError, load_model
    from stereo_bench.vision.calibio import INTRINSICS_FILE, CalibrationFileError
    from stereo_bench.vision.uncertainty import BoardScale

    extrinsics = config.extrinsics
    board = config.calibration_board
    optics = config.cameras.optics
    image_size = (optics.width_px, optics.height_px)
    options = RunnerOptions(board_retries=config.capture.board_retries,
                            # the stereo calibration's mode (vision.calibrate: "joint" | "fixed")
                            intrinsics_mode="fixed" if extrinsics.intrinsics_held else "joint",
                            calibration_board=f"{board.kind} {board.cols}x{board.rows} square {board.square_mm:g} mm",
                            extrinsics_mode=extrinsics.mode, visits=list(visits),
                            board_scale=BoardScale(target_u_rel=config.target.scale_u("target"),
                                                   calibration_board_u_rel=board.scale_u("calibration_board")),
                            tolerances=extrinsics.tolerances.sigmas(),
                            repeatability=(extrinsics.repeatability_mm, extrinsics.repeatability_deg))
    if preflight is not None and reader is None:
        for name, value in preflight.calib_dir_options.items():
            setattr(options, name, value)
        options.kinematic_model = preflight.kinematic_model
        return options
    try:
        # a replay reads the recording's copy of calib_dir's intrinsics
        copy = (_recorded_copy(reader, "intrinsics", INTRINSICS_FILE)
                if reader is not None and extrinsics.calib_dir is not None else None)
        extrinsics.source().load_calibration(options, extrinsics, reader=reader, intrinsics_copy=copy,
                                             image_size=image_size)
    except CalibrationFileError as error:
        raise SessionError(f"extrinsics.calib_dir: {error}") from None
    if reader is not None:
        recorded = recorded_sources(reader, sources=("file",), image_size=image_size)
        options.kinematic_model = recorded.kinematic_model
        options.nominal_intrinsics = recorded.nominal_intrinsics or options.nominal_intrinsics
    elif extrinsics.kinematic_file is not None:
        try:
            options.kinematic_model = load_model(extrinsics.kinematic_file)
        except KinematicFileError as error:
            raise SessionError(f"extrinsics.kinematic_file: {error}") from None
    return options
