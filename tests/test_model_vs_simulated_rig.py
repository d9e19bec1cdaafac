"""The rigorous model's square sigma against the scatter the simulated rig actually produces."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.sim.render import StereoRenderer
from stereo_bench.errormodel.rigorous import Setup, calibration_of, predict
from stereo_bench.targets import Checkerboard
from stereo_bench.vision.pipeline import measure_pair


@pytest.mark.slow
@pytest.mark.parametrize("baseline_mm, distance_mm, alpha_deg", [(100.0, 500.0, 90.0), (60.0, 400.0, 80.0)])
def test_predicted_square_sigma_matches_the_simulated_scatter_within_1_5(baseline_mm, distance_mm, alpha_deg):
    setup = Setup.make(baseline_mm, distance_mm, alpha_deg)
    renderer = StereoRenderer(Checkerboard(9, 6, 27.0), setup.left, setup.right)
    calib = calibration_of(setup)  # the true calibration: only image noise varies between frames
    means, pixel_sigmas = [], []
    for seed in range(24):
        pair = renderer.render_pair(setup.rig, setup.T_rig_board, np.random.default_rng(seed))
        result = measure_pair(pair.left.image, pair.right.image, calib, setup.board)
        means.append(result.square.mean_mm)
        pixel_sigmas.extend(result.square.pixel_sigma_px)
    # The model is fed the random corner noise the pipeline estimated from the images themselves.
    predicted = predict(setup, float(np.mean(pixel_sigmas))).sigma_square_mm
    scatter = float(np.std(means, ddof=1))
    assert 1 / 1.5 < predicted / scatter < 1.5, f"predicted {predicted:.5f} mm, scatter {scatter:.5f} mm"
