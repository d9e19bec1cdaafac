"""The kinematic rig model: R and T of the stereo pair at any configuration, from the rig's axis positions.

One room per concern, lowest first (each imports only ``model`` and the leaf modules):

- ``model``: the parameters, the kinematic chain (:func:`chain`) and the fitted model (:class:`KinematicModel`);
- ``nominal``: the ideal geometry (:func:`nominal_extrinsics`), its tolerances' covariance (:func:`nominal_covariance`);
- ``design``: the configurations the fit visits (:func:`kinematic_design`) and the approach directions;
- ``file``: the model's readable TOML file (:func:`save_model`, :func:`load_model`);
- ``prediction``: R, T and their covariance at any axis positions (:func:`predict`);
- ``fit``: the joint bundle adjustment (:func:`fit_kinematics`);
- ``fixed_board``, the one room above the others (it stands on ``fit`` and ``design``): the fit from one board that
  stays put while the rig moves, its design and identifiability table (:func:`fit_fixed_board`, issue 25).

Pure functions on numpy arrays; OpenCV for PnP and the initial intrinsics, scipy for least squares.
Units: mm and deg at the interface and in the file, radians inside.
"""

from stereo_bench.kinematics.design import DesignConfiguration, approach_directions, campaign_design, kinematic_design
from stereo_bench.kinematics.file import KinematicFileError, load_model, model_from_toml, model_toml, save_model
from stereo_bench.kinematics.fit import FIT_TOLERANCE, ConfigurationViews, KinematicFit, fit_kinematics
from stereo_bench.kinematics.model import (
    AXES,
    FILE_SCHEMA,
    N_PARAMS,
    NAMES,
    PARAMETERS,
    TILT_AXES,
    TILT_PARAMETERS,
    FitSummary,
    KinematicModel,
    ParameterSpec,
    ParameterValue,
    chain,
    model_axes,
    nominal_parameters,
    parameter_specs,
    vector_specs,
)
from stereo_bench.kinematics.nominal import TOLERANCE_NAMES, nominal_covariance, nominal_extrinsics
from stereo_bench.kinematics.prediction import STRUCTURE_KEYS, Prediction, joint_covariance, predict, structure_sigma

__all__ = [
    "AXES", "FILE_SCHEMA", "FIT_TOLERANCE", "N_PARAMS", "NAMES", "PARAMETERS", "STRUCTURE_KEYS", "TILT_AXES",
    "TILT_PARAMETERS", "TOLERANCE_NAMES", "ConfigurationViews", "DesignConfiguration", "FitSummary",
    "KinematicFileError", "KinematicFit", "KinematicModel", "ParameterSpec", "ParameterValue", "Prediction",
    "approach_directions", "campaign_design", "chain", "fit_kinematics", "joint_covariance", "kinematic_design",
    "load_model", "model_axes", "model_from_toml", "model_toml", "nominal_covariance", "nominal_extrinsics",
    "nominal_parameters", "parameter_specs", "predict", "save_model", "structure_sigma", "vector_specs",
]
