"""``stereo-bench model paper | predict | surface | compare`` and ``stereo-bench advise``: the error models.

Monte Carlo runs and sweeps go through an executor: ``--executor local`` (a process pool, the
default), ``serial`` (this process), or ``dask`` (``--scheduler ADDRESS`` of a running Dask cluster;
without it a LocalCluster on this machine). dask is an optional extra.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import math
import sys
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from stereo_bench import atomic
from stereo_bench.campaign.config import MAX_CALIBRATION_VIEWS
from stereo_bench.cli import CliError, json_ready, print_json
from stereo_bench.cli.args import (
    ALPHA_DEG,
    BASELINE_MM,
    DISTANCE_MM,
    FOCAL_MM,
    PIXEL_SIGMA_PX,
    PIXEL_UM,
    SEED,
    SQUARE_MM,
    TILT_DEG,
    TOE_IN_DEG,
    WORKERS,
    board_pattern,
    check_range,
    finite_float,
    image_size,
    int_in,
)
from stereo_bench.targets import Checkerboard, parse_pattern

DEFAULT_K = (0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0, 2.5, 3.0)

# Ranges of the options only these commands take (the shared ones: stereo_bench/cli/args.py), with the
# bounds on the inputs that scale the work.
K_RATIO = finite_float(min=0, max=100, inclusive=(False, True))  # K = B / Z; the paper's curves end at 3
FOCAL_PX = finite_float(min=0, max=1e6, inclusive=(False, True), unit="px")
MARGIN_PX = finite_float(min=0, max=1000, unit="px")
BOARD_ANGLE_DEG = finite_float(min=-90, max=90, inclusive=(False, False), unit="deg")  # +-90: seen edge-on
OFFSET_MM = finite_float(min=-100_000, max=100_000, unit="mm")
TARGET_ERROR_MM = finite_float(min=0, max=1000, inclusive=(False, True), unit="mm")
STRUCTURE_ERROR_MM = finite_float(min=0, max=1000, unit="mm")
STRUCTURE_ERROR_DEG = finite_float(min=0, max=90, unit="deg")
GRID_VALUE = finite_float()  # START STOP STEP of a grid; _range checks their order and the grid's size
# Monte Carlo samples: 50-190 us each on one core (load 6-16, scripts/bench_input_bounds.py) plus 32 bytes kept
# per sample. A million gives the sigmas to 1/sqrt(2N) = 0.07 % in minutes; 1e9 would need 30 GB and days.
MAX_MONTE_CARLO = 1_000_000
MONTE_CARLO = int_in(min=2, max=MAX_MONTE_CARLO)
# Planned calibration views, the campaign's bound (campaign/config.py MAX_CALIBRATION_VIEWS): the predicted calibration
# error costs 3-5 ms per view per configuration (500 views: 1.5 s for one, scripts/bench_input_bounds.py); a bench
# collects 10-50.
CALIBRATION_VIEWS = int_in(min=0, max=MAX_CALIBRATION_VIEWS)
# Configurations of one surface or advice grid: 10-20 ms each on one core (load 6-16,
# scripts/bench_input_bounds.py), so 100,000 is half an hour at most; a bigger grid is a typo in STEP.
MAX_GRID_CONFIGURATIONS = 100_000


def _print_json(obj) -> None:
    print_json(obj, indent=2)


# ----------------------------------------------------------------------------------------------
# Shared options


def _add_scene_options(parser: argparse.ArgumentParser) -> None:
    """The simulated rig's camera and board options (same names and defaults as ``stereo-bench render``)."""
    group = parser.add_argument_group("scene (defaults: the simulated rig's camera and board)")
    group.add_argument("--board", default="9x6", type=board_pattern, metavar="COLSxROWS",
                       help="checkerboard inner corners (default 9x6)")
    group.add_argument("--square", type=SQUARE_MM, default=27.0, metavar="MM", help="square size (default 27)")
    group.add_argument("--focal", type=FOCAL_MM, default=4.0, metavar="MM", help="lens focal length (default 4)")
    group.add_argument("--pixel", type=PIXEL_UM, default=3.0, metavar="UM", help="pixel pitch (default 3)")
    group.add_argument("--image-size", default="1920x1080", type=image_size, metavar="WxH",
                       help="image size in px (default 1920x1080)")
    group.add_argument("--no-distortion", action="store_true", help="ideal pinhole cameras (default: the "
                                                                    "simulator's mild barrel distortion)")
    group.add_argument("--intrinsics", metavar="CALIB_DIR_OR_FILE",
                       help="take both cameras (K, distortion, image size) from an intrinsics.yml instead, e.g. "
                            "the ground truth 'stereo-bench render' writes")
    group.add_argument("--margin", type=MARGIN_PX, default=10.0, metavar="PX",
                       help="a corner closer than this to an image border counts as not seen (default 10)")


def _add_calibration_options(parser: argparse.ArgumentParser) -> None:
    """The planned stereo calibration whose own error is predicted (same names as the campaign's)."""
    group = parser.add_argument_group("calibration (its predicted error is included; defaults: the campaign's)")
    group.add_argument("--calibration-views", type=CALIBRATION_VIEWS, default=12, metavar="N",
                       help=f"calibration views planned per configuration, 5-{MAX_CALIBRATION_VIEWS} (default 12; 0 "
                            "leaves the calibration's error out: image noise only)")
    group.add_argument("--calibration-board", default="11x8", type=board_pattern, metavar="COLSxROWS",
                       help="calibration checkerboard inner corners (default 11x8)")
    group.add_argument("--calibration-square", type=SQUARE_MM, default=25.0, metavar="MM",
                       help="its square size (default 25)")
    group.add_argument("--calibration-distance", type=DISTANCE_MM, nargs=2, metavar=("NEAR", "FAR"),
                       help="board distances of the views, mm (default: max(250, 0.6 Z) to 1.3 Z)")
    group.add_argument("--calibration-mode", choices=("joint", "fixed"), default="joint",
                       help="joint: intrinsics refined with R, T (default); fixed: from mono calibrations")


def _calibration_plan(args):
    from stereo_bench.errormodel.rigorous import CalibrationPlan

    check_range(args.calibration_distance, "--calibration-distance")
    if args.calibration_views == 0:
        return None
    if args.calibration_views < 5:
        raise CliError(f"--calibration-views must be 0 (left out) or at least 5, not {args.calibration_views}")
    try:
        cols, rows = parse_pattern(args.calibration_board)
        board = Checkerboard(cols, rows, args.calibration_square)
        return CalibrationPlan(n_views=args.calibration_views, board=board, mode=args.calibration_mode,
                               distance_mm=None if args.calibration_distance is None
                               else tuple(args.calibration_distance))
    except ValueError as error:
        raise CliError(f"--calibration-board/--calibration-square/--calibration-distance: {error}") from None


def _add_rig_options(parser: argparse.ArgumentParser) -> None:
    """Where R, T come from and what the rig and boards state: the structure and target terms of the budget."""
    from stereo_bench.campaign.config import EXTRINSICS_MODES, PRESETS

    modes = [m for m in EXTRINSICS_MODES if m != "fixed"]
    group = parser.add_argument_group(
        "rig and boards (the structure and target terms of the campaign's budget; defaults: a campaign's defaults, "
        "a hobby-grade rig's stated tolerances and a printed target)")
    group.add_argument("--config", metavar="CAMPAIGN", help="take the extrinsics mode, [extrinsics.tolerances], the "
                       "repeatability, kinematic_file and the boards' scale uncertainties from a campaign file or "
                       f"a shipped preset ({', '.join(PRESETS)})")
    group.add_argument("--extrinsics", choices=modes, metavar="MODE",
                       help=f"where R, T come from: {', '.join(modes)} (default: the config's mode, else per-config)")
    group.add_argument("--kinematic-file", metavar="FILE", help="with --extrinsics kinematic: a fitted rig model "
                       "(rig calibrate-kinematics); without one, only the axes' landing repeatability is counted")
    group.add_argument("--target-scale-u", type=finite_float(min=0, max=0.1), metavar="REL",
                       help="the measured board's relative scale uncertainty (default: the config's, else 5.8e-4: "
                            "an office print)")
    group.add_argument("--no-rig", action="store_true",
                       help="leave the structure and target terms out (image noise and the calibration only)")


def _rig_errors(args: argparse.Namespace):
    """The :class:`~stereo_bench.errormodel.rig.RigErrors` the options describe; None with --no-rig."""
    from stereo_bench.campaign.config import PRESETS, CampaignConfig, load_campaign, load_preset
    from stereo_bench.errormodel.rig import rig_errors_of
    from stereo_bench.kinematics import KinematicFileError, load_model

    if args.no_rig:
        if args.config or args.extrinsics or args.kinematic_file or args.target_scale_u is not None:
            raise CliError("--no-rig leaves the rig and boards out: drop --config, --extrinsics, --kinematic-file "
                           "and --target-scale-u")
        return None
    if args.config is None:
        # A campaign's sections as a file that states none of them has them.
        sections = tuple(CampaignConfig.model_fields[name].default_factory()
                         for name in ("extrinsics", "target", "calibration_board"))
        source = "the campaign's default tolerances (a hobby-grade rig, not measured) and a printed target"
    else:
        if Path(args.config).exists() or args.config not in PRESETS:
            config, source = load_campaign(args.config), f"from {args.config}"
        else:
            config, source = load_preset(args.config), f"from preset {args.config}"
        sections = config.extrinsics, config.target, config.calibration_board
    extrinsics = sections[0]
    mode = args.extrinsics or extrinsics.mode
    if mode == "fixed":
        raise CliError(f"--config {args.config}: extrinsics.mode \"fixed\" (R, T of one calibration at every "
                       "configuration) has no predicted structure term; choose --extrinsics per-config, nominal or "
                       "kinematic")
    model_path = args.kinematic_file or (extrinsics.kinematic_file if mode == "kinematic" else None)
    if model_path is not None and mode != "kinematic":
        raise CliError("--kinematic-file needs --extrinsics kinematic")
    model = None
    if model_path is not None:
        try:
            model = load_model(model_path)
        except (KinematicFileError, OSError) as error:
            raise CliError(f"--kinematic-file: {error}") from None
        source += f", the kinematic model {model_path}"
    design = None
    if mode == "kinematic" and model is None and args.config is not None:
        # The design the campaign's plan would visit: the prediction fits its planned views (docs/ERROR_MODEL.md §5).
        from stereo_bench.campaign.plan.configurations import expand_plan
        from stereo_bench.kinematics import campaign_design

        design = campaign_design(expand_plan(config))
        if design is not None:
            source += f", the kinematic design over its plan ({len(design[0])} visits)"
    try:
        return rig_errors_of(*sections, mode=mode, kinematic_model=model, target_scale_u_rel=args.target_scale_u,
                             design=None if design is None else design[0],
                             design_distance_mm=None if design is None else design[1], source=source)
    except ValueError as error:
        raise CliError(str(error)) from None


def _add_executor_options(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("execution")
    group.add_argument("--executor", choices=("local", "serial", "dask"), default="local",
                       help="where Monte Carlo runs and sweeps run: a local process pool (default), this process, "
                            "or a Dask cluster")
    group.add_argument("--scheduler", metavar="ADDRESS",
                       help="Dask scheduler address, e.g. tcp://10.0.0.5:8786 (with --executor dask; without it "
                            "a LocalCluster starts on this machine)")
    group.add_argument("--workers", type=WORKERS, metavar="N",
                       help="local processes, at most 4 per CPU (default: the CPU count)")


def _board(args) -> Checkerboard:
    try:
        cols, rows = parse_pattern(args.board)
        return Checkerboard(cols, rows, args.square)
    except ValueError as error:
        raise CliError(f"--board/--square: {error}") from None


def _cameras(args):
    from stereo_bench.geometry import CameraModel

    if args.intrinsics:
        from stereo_bench.vision.calibio import CalibrationFileError, read_intrinsics

        try:
            K1, D1, K2, D2, size = read_intrinsics(args.intrinsics)
        except (CalibrationFileError, OSError) as error:
            raise CliError(str(error)) from None
        if size is None:
            size = args.image_size
        if args.no_distortion:
            D1, D2 = np.zeros_like(D1), np.zeros_like(D2)
        return (CameraModel(K=K1, dist=D1.ravel(), image_size=tuple(size), name="left"),
                CameraModel(K=K2, dist=D2.ravel(), image_size=tuple(size), name="right"))
    dist = (0.0,) * 5 if args.no_distortion else (-0.05, 0.02, 0.0, 0.0, 0.0)
    size = args.image_size
    return tuple(CameraModel.from_sensor(focal_mm=args.focal, pixel_um=args.pixel, image_size=size, dist=dist,
                                         name=name) for name in ("left", "right"))


def _scene(args) -> dict:
    left, right = _cameras(args)
    return {"board": _board(args), "left": left, "right": right, "margin_px": args.margin}


@contextmanager
def _executor(args):
    from stereo_bench.executors import ExecutorUnavailable, make_executor

    if args.scheduler and args.executor != "dask":
        raise CliError("--scheduler is for the dask executor: add --executor dask")
    try:
        executor = make_executor(args.executor, scheduler=args.scheduler, max_workers=args.workers)
    except (ExecutorUnavailable, ValueError) as error:
        raise CliError(str(error)) from None
    try:
        yield executor
    finally:
        executor.close()


def _check_sigma(value: float) -> float:
    if not (math.isfinite(value) and value >= 0):
        raise CliError(f"--pixel-sigma must be a finite number >= 0, not {value}")
    return value


def _range(values: list[float], option: str, *, positive: bool = True) -> np.ndarray:
    """START STOP STEP -> inclusive grid (at most MAX_GRID_CONFIGURATIONS values)."""
    start, stop, step = values
    if not step > 0 or stop < start:
        raise CliError(f"{option} START STOP STEP needs STEP > 0 and STOP >= START")
    if positive and not start > 0:
        raise CliError(f"{option}: START must be positive")
    count = math.floor((stop - start) / step * (1 + 1e-12)) + 1  # before allocating anything
    if count > MAX_GRID_CONFIGURATIONS:
        raise CliError(f"{option}: {count} grid values is too many (at most {MAX_GRID_CONFIGURATIONS}): check STEP")
    grid = np.arange(start, stop + step * 1e-9, step)
    return np.round(grid, 9)


def _check_grid(*axes: np.ndarray, options: str) -> None:
    """A grid over several axes is bounded in its number of configurations (MAX_GRID_CONFIGURATIONS)."""
    total = math.prod(len(a) for a in axes)
    if total > MAX_GRID_CONFIGURATIONS:
        raise CliError(f"{options}: {' x '.join(str(len(a)) for a in axes)} = {total} configurations is too many "
                       f"(at most {MAX_GRID_CONFIGURATIONS}, 10-20 ms each): use coarser steps")


# ----------------------------------------------------------------------------------------------
# model paper


def cmd_paper(args: argparse.Namespace) -> int:
    from stereo_bench.errormodel import paper

    k = np.asarray(args.k if args.k else DEFAULT_K, float)
    if np.any(~(k > 0)):
        raise CliError("--k values must be positive (K = B / Z)")
    if args.distance is not None and not (args.distance > 0 and args.focal_px > 0):
        raise CliError("--distance and --focal-px must be positive")
    _check_sigma(args.pixel_sigma)
    curves = paper.curves(k)
    rows = []
    for i in range(len(k)):
        row = {name: float(values[i]) for name, values in curves.items()}
        if args.distance is not None:
            dx, dz = paper.components_mm(k[i], args.distance, args.focal_px, args.pixel_sigma)
            row.update(baseline_mm=float(k[i] * args.distance), gamma_mm=float(
                paper.gamma_mm(k[i], args.distance, args.focal_px, args.pixel_sigma)), dx_mm=float(dx), dz_mm=float(dz))
        rows.append(row)
    k_opt = paper.optimum_k()  # numerical check of the closed form
    result = {
        "model": "Yang et al. 2024, Eqs. 4-5: e1 = 1/2 + K^2/8, e2 = 1/K + K/4, "
                 "gamma = sqrt(2) (Z/f) sqrt(e1^2 + e2^2) delta; converging symmetric rig, cot(alpha) = K/2",
        "rows": rows, "optimum_K": paper.OPTIMUM_K, "optimum_K_numeric": k_opt,
        "optimum_gamma_rel": float(paper.gamma_relative(paper.OPTIMUM_K)),
        "optimum_alpha_deg": float(paper.converging_alpha_deg(paper.OPTIMUM_K)),
    }
    if args.distance is not None:
        result.update(distance_mm=args.distance, focal_px=args.focal_px, pixel_sigma_px=args.pixel_sigma)
    if args.json:
        _print_json(result)
        return 0
    extra = args.distance is not None
    header = f"{'K':>6} {'alpha':>7} {'e1':>8} {'e2':>8} {'gamma_rel':>9}" + (
        f" {'B mm':>7} {'gamma mm':>9}" if extra else "")
    print(header)
    for row in rows:
        line = f"{row['K']:6.3f} {row['alpha_deg']:7.2f} {row['e1']:8.4f} {row['e2']:8.4f} {row['gamma_rel']:9.4f}"
        if extra:
            line += f" {row['baseline_mm']:7.1f} {row['gamma_mm']:9.4f}"
        print(line)
    print(f"optimum K = {k_opt:.4f} (sqrt 2), gamma_rel = {result['optimum_gamma_rel']:.4f}, "
          f"converging alpha = {result['optimum_alpha_deg']:.2f} deg")
    return 0


# ----------------------------------------------------------------------------------------------
# model predict


def _alphas(args) -> tuple[float, float]:
    if args.alpha is not None and args.toe_in is not None:
        raise CliError("give --alpha or --toe-in, not both")
    alpha = args.alpha if args.alpha is not None else 90.0 - (args.toe_in or 0.0)
    alpha_right = args.alpha_right if args.alpha_right is not None else alpha
    for name, value in (("--alpha", alpha), ("--alpha-right", alpha_right)):
        if not 0.0 < value < 180.0:
            raise CliError(f"{name} must lie strictly between 0 and 180 degrees, not {value:g}")
    return alpha, alpha_right


def cmd_predict(args: argparse.Namespace) -> int:
    from stereo_bench.errormodel import paper
    from stereo_bench.errormodel.rig import combined, dominant_term
    from stereo_bench.errormodel.rigorous import Setup, parallel_depth_sigma_mm, predict, sensitivities

    if not (args.baseline > 0 and args.distance > 0):
        raise CliError("--baseline and --distance must be positive (mm)")
    sigma = _check_sigma(args.pixel_sigma)
    alpha, alpha_right = _alphas(args)
    if args.monte_carlo is not None and args.monte_carlo < 2:
        raise CliError("--monte-carlo needs at least 2 samples")
    scene = _scene(args)
    try:
        setup = Setup.make(args.baseline, args.distance, alpha, alpha_right_deg=alpha_right, tilt_deg=args.tilt,
                           board=scene["board"], left=scene["left"], right=scene["right"],
                           board_yaw_deg=args.board_yaw, board_pitch_deg=args.board_pitch,
                           board_offset_mm=tuple(args.board_offset))
    except ValueError as error:
        raise CliError(str(error)) from None
    rig = _rig_errors(args)
    prediction = predict(setup, sigma, margin_px=scene["margin_px"], calibration=_calibration_plan(args), rig=rig)
    result = prediction.model_dump()
    terms = {"noise": result["sigma_square_mm"], "bias": result["bias_square_mm"]}
    if prediction.calibration_views:
        terms["calibration"] = result["sigma_calibration_mm"]
    if rig is not None:
        terms |= {"structure": result["sigma_structure_mm"], "target": result["sigma_target_mm"]}
    # Image noise, its bias, the calibration's error (when planned), the rig's and the boards' (unless --no-rig),
    # in quadrature: the square's 1-sigma error against its nominal size.
    result["terms_mm"] = terms
    result["sigma_square_total_mm"] = combined(terms)
    result["dominant_term"] = dominant_term(terms)
    k = args.baseline / args.distance
    f_px = setup.left.fx
    dx, dz = paper.components_mm(k, args.distance, f_px, sigma)
    result["paper"] = {
        "gamma_mm": float(paper.gamma_mm(k, args.distance, f_px, sigma)), "sigma_x_mm": float(dx),
        "sigma_z_mm": float(dz), "converging_alpha_deg": float(paper.converging_alpha_deg(k)),
        "note": "the paper's model assumes the optical axes meet at the board centre",
    }
    if alpha == 90.0 and alpha_right == 90.0:
        result["textbook_parallel_sigma_z_mm"] = parallel_depth_sigma_mm(args.distance, args.baseline, f_px, sigma)
    if not args.no_sensitivities:
        result["sensitivities"] = {name: s.model_dump(exclude={"parameter"})
                                   for name, s in sensitivities(setup, margin_px=scene["margin_px"]).items()}
    if args.monte_carlo:
        from stereo_bench.errormodel.montecarlo import monte_carlo

        with _executor(args) as executor:
            mc = monte_carlo(setup, sigma, args.monte_carlo, seed=args.seed, executor=executor,
                             margin_px=scene["margin_px"])
            result["monte_carlo"] = mc.model_dump() | {"executor": executor.describe()}
    if args.json:
        _print_json(result)
        return 0
    _print_prediction(result)
    return 0


def _fmt(value, spec: str = ".4f") -> str:
    return "n/a" if value is None else format(value, spec)


def _print_prediction(r: dict) -> None:
    print(f"B {r['baseline_mm']:g} mm, Z {r['distance_mm']:g} mm (K {r['K']:.3f}), alpha {r['alpha_left_deg']:g}/"
          f"{r['alpha_right_deg']:g} deg, image noise {r['pixel_sigma_px']:g} px per coordinate")
    state = "feasible: whole board in both views" if r["feasible"] else f"not feasible: {r['reason']}"
    print(f"{state} ({r['n_in_both']} corners, {r['n_pairs']} pairs)")
    print(f"square:       sigma {_fmt(r['sigma_square_mm'])} mm (mean of pairs), one pair {_fmt(r['sigma_length_mm'])}"
          f" mm, noise bias {_fmt(r['bias_square_mm'], '+.4f')} mm")
    if r["calibration_views"]:
        print(f"calibration:  square sigma {_fmt(r['sigma_calibration_mm'])} mm, centre depth sigma "
              f"{_fmt(r['sigma_calibration_depth_mm'])} mm ({r['calibration_note']}; shared by every frame)")
    else:
        print("calibration:  not included (--calibration-views 0): image noise only")
    if r["extrinsics_mode"] is not None:
        print(f"rig:          square sigma {_fmt(r['sigma_structure_mm'])} mm from the structure "
              f"({r['rig_note']}); boards' scale {_fmt(r['sigma_target_mm'])} mm")
    else:
        print("rig:          not included (--no-rig): no structure or target term")
    print(f"square total: sigma {_fmt(r['sigma_square_total_mm'])} mm ({', '.join(r['terms_mm'])} in quadrature; "
          f"the largest: {r['dominant_term']})")
    print(f"board centre: sigma x {_fmt(r['sigma_x_mm'])}  y {_fmt(r['sigma_y_mm'])}  z {_fmt(r['sigma_z_mm'])} mm "
          f"(rig frame); gamma_xz {_fmt(r['gamma_xz_mm'])} mm, paper's gamma {r['paper']['gamma_mm']:.4f} mm")
    if "textbook_parallel_sigma_z_mm" in r:
        print(f"              textbook parallel-rig depth sigma Z^2 sqrt(2) sigma / (f B) = "
              f"{r['textbook_parallel_sigma_z_mm']:.4f} mm")
    for name, s in r.get("sensitivities", {}).items():
        print(f"  d/d {name:17s} square {_fmt(s['square_mm_per_unit'], '+.5f')} mm/{s['unit']}, "
              f"depth {_fmt(s['depth_mm_per_unit'], '+.4f')} mm/{s['unit']}")
    mc = r.get("monte_carlo")
    if mc:
        print(f"Monte Carlo ({mc['n_samples']} samples, seed {mc['seed']}, {mc['executor']['executor']}): square "
              f"sigma {_fmt(mc['sigma_square_mm'])} bias {_fmt(mc['bias_square_mm'], '+.4f')} mm; centre sigma x "
              f"{mc['sigma_x_mm']:.4f} y {mc['sigma_y_mm']:.4f} z {mc['sigma_z_mm']:.4f} mm")


# ----------------------------------------------------------------------------------------------
# model surface


def cmd_surface(args: argparse.Namespace) -> int:
    from stereo_bench.errormodel.surfaces import surface_alpha, surface_bz

    sigma = _check_sigma(args.pixel_sigma)
    out = Path(args.out)
    if out.suffix.lower() not in (".csv", ".json"):
        raise CliError(f"--out {out}: the file name must end in .csv or .json")
    if out.exists() and not args.force:
        raise CliError(f"{out} exists: choose another --out or pass --force to replace it")
    scene = _scene(args)
    common = {"pixel_sigma_px": sigma, "with_sensitivities": not args.no_sensitivities, **scene}
    with _executor(args) as executor:
        if args.over == "bz":
            if args.baselines is None or args.distances is None:
                raise CliError("model surface --over bz needs --baselines and --distances")
            policy = args.alpha
            if policy not in ("converge", "parallel"):
                try:
                    policy = float(policy)
                except ValueError:
                    raise CliError(f"--alpha must be converge, parallel or degrees, not {args.alpha!r}") from None
                if not 0 < policy < 180:
                    raise CliError("--alpha must lie strictly between 0 and 180 degrees")
            baselines, distances = _range(args.baselines, "--baselines"), _range(args.distances, "--distances")
            _check_grid(baselines, distances, options="--baselines x --distances")
            rows = surface_bz(baselines, distances, alpha=policy, executor=executor, **common)
            meta = {"over": "bz", "alpha": args.alpha}
        else:
            if args.alphas is None or args.baseline is None or args.distance is None:
                raise CliError("model surface --over alpha needs --alphas, --baseline and --distance")
            alphas = _range(args.alphas, "--alphas")
            if alphas[-1] >= 180:
                raise CliError("--alphas must stay below 180 degrees")
            if not (args.baseline > 0 and args.distance > 0):
                raise CliError("--baseline and --distance must be positive (mm)")
            rows = surface_alpha(alphas, baseline_mm=args.baseline, distance_mm=args.distance,
                                 one_camera=args.one_camera, executor=executor, **common)
            meta = {"over": "alpha", "baseline_mm": args.baseline, "distance_mm": args.distance,
                    "one_camera": args.one_camera}
    records = [r.model_dump() for r in rows]
    if out.suffix.lower() == ".json":
        clean, reasons = json_ready({**meta, "pixel_sigma_px": sigma, "rows": records})
        text = json.dumps({**clean, **({"null_reasons": reasons} if reasons else {})}, indent=1, allow_nan=False)
    else:
        buffer = io.StringIO(newline="")
        writer = csv.DictWriter(buffer, fieldnames=list(records[0]))
        writer.writeheader()
        writer.writerows({k: ("" if v is None else v) for k, v in rec.items()} for rec in records)
        text = buffer.getvalue()
    atomic.write_text(out, text.rstrip("\n") + "\n")  # names the file if the disk is full
    n_feasible = sum(r.feasible for r in rows)
    print(f"wrote {len(rows)} configurations ({n_feasible} with the whole board in both views) to {out}",
          file=sys.stderr if args.quiet else sys.stdout)
    return 0


# ----------------------------------------------------------------------------------------------
# model compare


def cmd_compare(args: argparse.Namespace) -> int:
    from stereo_bench.errormodel.surfaces import compare_with_paper

    if not args.distance > 0:
        raise CliError("--distance must be positive (mm)")
    sigma = _check_sigma(args.pixel_sigma)
    scene = _scene(args)
    grids = {}
    if args.coarse:
        grids = {"k_values": np.round(np.arange(0.2, 4.0001, 0.2), 6), "alphas_deg": np.arange(5.0, 90.001, 5.0),
                 "bench_steps": (50.0, 5.0)}
    with _executor(args) as executor:
        comparison = compare_with_paper(distance_mm=args.distance, pixel_sigma_px=sigma, executor=executor,
                                        **grids, **scene)
    result = comparison.model_dump()
    if args.json:
        _print_json(result)
        return 0
    c = comparison
    print(f"paper: optimum K = {c.paper_optimum_K:.4f}, converging alpha there "
          f"{c.paper_optimum_converging_alpha_deg:.2f} deg; claimed K 1-1.5 means alpha "
          f"{c.converging_alpha_for_claimed_K_deg[0]:.1f}-{c.converging_alpha_for_claimed_K_deg[1]:.1f} deg, "
          "claimed alpha 30-40 deg means K "
          f"{c.converging_K_for_claimed_alpha[0]:.2f}-{c.converging_K_for_claimed_alpha[1]:.2f}")
    for title, optima in (("converging rig", c.converge), ("parallel rig", c.parallel),
                          (f"B = {c.experiment2_baseline_mm:g} mm over alpha", c.experiment2)):
        print(f"{title} (Z = {c.distance_mm:g} mm, {c.pixel_sigma_px:g} px):")
        for o in optima:
            alpha = f", alpha {o.point.alpha_deg:.1f} deg" if o.variable == "K" else ""
            print(f"  min |{o.metric}| = {o.value:.4g} at {o.variable} = {o.x:.4f}{alpha} ({o.limit}; within 10 %: "
                  f"{o.near_optimal[0]:.3g}-{o.near_optimal[1]:.3g})")
    print(f"B = {c.experiment2_baseline_mm:g} mm: whole board in view for alpha {c.experiment2_feasible_alpha_deg}, "
          f"measurable for {c.experiment2_measurable_alpha_deg}; anything measurable at 30-40 deg: "
          f"{c.experiment2_claimed_alpha_measurable}")
    if c.bench_optimum:
        b = c.bench_optimum
        print(f"bench range B {c.bench_baseline_range_mm[0]:g}-{c.bench_baseline_range_mm[1]:g} mm: smallest square "
              f"sigma {b.sigma_square_mm:.4g} mm at B {b.baseline_mm:g} mm, alpha {b.alpha_deg:g} deg")
    return 0


# ----------------------------------------------------------------------------------------------
# advise


def cmd_advise(args: argparse.Namespace) -> int:
    from stereo_bench.errormodel.advisor import advise

    if not (args.distance > 0 and args.target_error_mm > 0):
        raise CliError("--distance and --target-error-mm must be positive")
    sigma = _check_sigma(args.pixel_sigma)
    if not (args.baseline_error_mm >= 0 and args.alpha_error_deg >= 0):
        raise CliError("--baseline-error-mm and --alpha-error-deg must be >= 0")
    baselines = _range(args.baselines, "--baselines")
    alphas = _range(args.alphas, "--alphas")
    _check_grid(baselines, alphas, options="--baselines x --alphas")
    if alphas[-1] >= 180:
        raise CliError("--alphas must stay below 180 degrees")
    scene = _scene(args)
    with _executor(args) as executor:
        advice = advise(args.distance, args.target_error_mm, pixel_sigma_px=sigma, metric=args.metric,
                        baseline_error_mm=args.baseline_error_mm, alpha_error_deg=args.alpha_error_deg,
                        baselines_mm=baselines, alphas_deg=alphas, executor=executor,
                        calibration=_calibration_plan(args), rig=_rig_errors(args), **scene)
    if args.json:
        _print_json(advice.model_dump())
        return 0 if advice.meets_target else 1
    print(advice.message)
    if advice.best is not None:
        terms = ", ".join(f"{name} {_fmt(value, '.2g')}" for name, value in advice.best.terms_mm.items())
        print(f"at the best configuration: {terms} mm")
    print(f"{'B mm':>6}  {'alpha range (deg) meeting the target':38s} {'best alpha':>10} {'error mm':>9}")
    for row in advice.rows:
        span = (f"{row.alpha_min_deg:g}-{row.alpha_max_deg:g}" + ("" if row.contiguous else " (with gaps)")
                if row.alpha_min_deg is not None else "none")
        best_alpha, best_error = _fmt(row.best_alpha_deg, "g"), _fmt(row.best_error_mm, ".4g")
        print(f"{row.baseline_mm:6g}  {span:38s} {best_alpha:>10} {best_error:>9}")
    return 0 if advice.meets_target else 1


# ----------------------------------------------------------------------------------------------


def register(subparsers) -> None:
    model = subparsers.add_parser(
        "model", help="error models: the paper's, and the rigorous one for any rig",
        description="The paper's structural error model and a rigorous first-order model with Monte Carlo.",
    )
    actions = model.add_subparsers(dest="model_action", metavar="ACTION", required=True)

    paper = actions.add_parser("paper", help="the paper's e1, e2 and gamma over K, and the optimum K (Figure 3)")
    paper.add_argument("--k", type=K_RATIO, nargs="+", metavar="K", help=f"K = B/Z values (default {DEFAULT_K})")
    paper.add_argument("--distance", type=DISTANCE_MM, metavar="MM", help="Z: also give gamma in mm at this distance")
    paper.add_argument("--focal-px", type=FOCAL_PX, default=4000.0 / 3.0, metavar="PX",
                       help="focal length for gamma in mm (default 1333.3: 4 mm lens, 3 um pixels)")
    paper.add_argument("--pixel-sigma", type=PIXEL_SIGMA_PX, default=0.1, metavar="PX", help="image-point error delta "
                                                                                    "(default 0.1)")
    paper.add_argument("--json", action="store_true", help="print one JSON object")
    paper.set_defaults(func=cmd_paper)

    predict = actions.add_parser("predict", help="first-order errors of one configuration (+ Monte Carlo check)")
    predict.add_argument("--baseline", type=BASELINE_MM, required=True, metavar="MM",
                         help="B: optical-centre distance")
    predict.add_argument("--distance", type=DISTANCE_MM, required=True, metavar="MM",
                         help="Z: rig origin to board plane")
    predict.add_argument("--alpha", type=ALPHA_DEG, metavar="DEG", help="angle between baseline and optical axes "
                                                                    "(default 90 = parallel)")
    predict.add_argument("--alpha-right", type=ALPHA_DEG, metavar="DEG", help="right camera's alpha (default: --alpha)")
    predict.add_argument("--toe-in", type=TOE_IN_DEG, metavar="DEG", help="pan from parallel instead of --alpha")
    predict.add_argument("--tilt", type=TILT_DEG, default=0.0, metavar="DEG", help="heads' tilt, positive down")
    predict.add_argument("--board-yaw", type=BOARD_ANGLE_DEG, default=0.0, metavar="DEG",
                         help="board yaw about rig y")
    predict.add_argument("--board-pitch", type=BOARD_ANGLE_DEG, default=0.0, metavar="DEG",
                         help="board pitch about its x")
    predict.add_argument("--board-offset", type=OFFSET_MM, nargs=2, default=(0.0, 0.0), metavar=("X", "Y"),
                         help="board centre's rig x, y (mm)")
    predict.add_argument("--pixel-sigma", type=PIXEL_SIGMA_PX, default=0.1, metavar="PX",
                         help="image noise per coordinate, both cameras (default 0.1)")
    predict.add_argument("--monte-carlo", type=MONTE_CARLO, metavar="N",
                         help=f"also estimate the sigmas from N samples, 2-{MAX_MONTE_CARLO}")
    predict.add_argument("--seed", type=SEED, default=0, help="Monte Carlo seed (default 0)")
    predict.add_argument("--no-sensitivities", action="store_true", help="skip the structural sensitivities")
    predict.add_argument("--json", action="store_true", help="print one JSON object")
    _add_scene_options(predict)
    _add_calibration_options(predict)
    _add_rig_options(predict)
    _add_executor_options(predict)
    predict.set_defaults(func=cmd_predict)

    surface = actions.add_parser("surface", help="error surfaces over (B, Z) or over alpha, as CSV or JSON")
    surface.add_argument("--over", choices=("bz", "alpha"), required=True)
    surface.add_argument("--baselines", type=GRID_VALUE, nargs=3, metavar=("START", "STOP", "STEP"), help="B grid, mm")
    surface.add_argument("--distances", type=GRID_VALUE, nargs=3, metavar=("START", "STOP", "STEP"), help="Z grid, mm")
    surface.add_argument("--alpha", default="converge", metavar="POLICY",
                         help="with --over bz: converge (axes meet at the board, default), parallel, or degrees")
    surface.add_argument("--alphas", type=GRID_VALUE, nargs=3, metavar=("START", "STOP", "STEP"),
                         help="alpha grid, deg")
    surface.add_argument("--baseline", type=BASELINE_MM, metavar="MM", help="with --over alpha")
    surface.add_argument("--distance", type=DISTANCE_MM, metavar="MM", help="with --over alpha")
    surface.add_argument("--one-camera", action="store_true", help="with --over alpha: turn only the right camera")
    surface.add_argument("--pixel-sigma", type=PIXEL_SIGMA_PX, default=0.1, metavar="PX")
    surface.add_argument("--no-sensitivities", action="store_true", help="skip the structural sensitivities")
    surface.add_argument("--out", required=True, metavar="FILE", help="output .csv or .json")
    surface.add_argument("--force", action="store_true", help="replace --out if it exists")
    surface.add_argument("--quiet", action="store_true", help="report on stderr only")
    _add_scene_options(surface)
    _add_executor_options(surface)
    surface.set_defaults(func=cmd_surface)

    compare = actions.add_parser("compare", help="where the rigorous optima lie against the paper's claims")
    compare.add_argument("--distance", type=DISTANCE_MM, default=500.0, metavar="MM", help="Z (default 500)")
    compare.add_argument("--pixel-sigma", type=PIXEL_SIGMA_PX, default=0.1, metavar="PX")
    compare.add_argument("--coarse", action="store_true", help="coarser grids (K step 0.2, alpha step 5 deg): "
                                                               "~10x faster, optima still refined")
    compare.add_argument("--json", action="store_true", help="print one JSON object")
    _add_scene_options(compare)
    _add_executor_options(compare)
    compare.set_defaults(func=cmd_compare)

    adv = subparsers.add_parser(
        "advise", help="recommend baseline and angle ranges that meet an error target",
        description="Recommend B and alpha ranges (symmetric rig) that meet an error target with the whole board "
                    "in both views. Exit status 1 when no configuration meets the target.",
    )
    adv.add_argument("--distance", type=DISTANCE_MM, required=True, metavar="MM", help="Z: rig origin to board plane")
    adv.add_argument("--target-error-mm", type=TARGET_ERROR_MM, required=True, metavar="MM",
                     help="largest acceptable 1-sigma error")
    adv.add_argument("--pixel-sigma", type=PIXEL_SIGMA_PX, default=0.1, metavar="PX", help="image noise (default 0.1)")
    adv.add_argument("--metric", choices=("square", "length", "depth"), default="square",
                     help="square: the measured square, mean of all pairs (default); length: one pair; depth: "
                          "board-centre depth")
    adv.add_argument("--baseline-error-mm", type=STRUCTURE_ERROR_MM, default=0.0, metavar="MM",
                     help="1-sigma error of the calibrated baseline (default 0)")
    adv.add_argument("--alpha-error-deg", type=STRUCTURE_ERROR_DEG, default=0.0, metavar="DEG",
                     help="1-sigma error of each camera's calibrated angle (default 0)")
    adv.add_argument("--baselines", type=GRID_VALUE, nargs=3, default=(20.0, 350.0, 10.0),
                     metavar=("START", "STOP", "STEP"),
                     help="B grid, mm (default 20 350 10: the bench's slide)")
    adv.add_argument("--alphas", type=GRID_VALUE, nargs=3, default=(30.0, 90.0, 2.0), metavar=("START", "STOP", "STEP"),
                     help="alpha grid, deg (default 30 90 2)")
    adv.add_argument("--json", action="store_true", help="print one JSON object")
    _add_scene_options(adv)
    _add_calibration_options(adv)
    _add_rig_options(adv)
    _add_executor_options(adv)
    adv.set_defaults(func=cmd_advise)
