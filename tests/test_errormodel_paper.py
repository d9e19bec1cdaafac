"""The paper's model (Yang et al. 2024, Eqs. 4-5) pinned to hand-computed values and its optimum."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stereo_bench.errormodel import paper

# Hand-computed: e1 = 1/2 + K^2/8, e2 = 1/K + K/4, gamma_rel = sqrt(e1^2 + e2^2).
HAND = [
    # K,   e1,       e2,          gamma_rel
    (0.5, 0.53125, 2.125, math.sqrt(0.53125**2 + 2.125**2)),  # 2.190400
    (1.0, 0.625, 1.25, math.sqrt(1.953125)),  # 1.397542
    (1.5, 0.78125, 1.0 / 1.5 + 0.375, math.sqrt(0.78125**2 + (2 / 3 + 0.375) ** 2)),  # 1.302083
    (2.0, 1.0, 1.0, math.sqrt(2.0)),
]


@pytest.mark.parametrize(("k", "e1", "e2", "gamma_rel"), HAND)
def test_factors_match_hand_values(k, e1, e2, gamma_rel):
    assert paper.e1(k) == pytest.approx(e1, abs=1e-12)
    assert paper.e2(k) == pytest.approx(e2, abs=1e-12)
    assert paper.gamma_relative(k) == pytest.approx(gamma_rel, abs=1e-12)


def test_literal_decimal_values():
    assert paper.gamma_relative(0.5) == pytest.approx(2.1903999, abs=1e-6)
    assert paper.gamma_relative(1.0) == pytest.approx(1.3975425, abs=1e-6)
    assert paper.gamma_relative(1.5) == pytest.approx(1.3020833, abs=1e-6)


def test_gamma_in_mm():
    # sqrt(2) * (500 / 1333.33) * gamma_rel(1) * 0.1 px = 0.0741159 mm
    assert paper.gamma_mm(1.0, 500.0, 4000.0 / 3.0, 0.1) == pytest.approx(0.07411588, abs=1e-7)
    dx, dz = paper.components_mm(1.0, 500.0, 4000.0 / 3.0, 0.1)
    assert math.hypot(dx, dz) == pytest.approx(paper.gamma_mm(1.0, 500.0, 4000.0 / 3.0, 0.1), rel=1e-12)


def test_optimum_is_sqrt2_and_inside_the_papers_claim():
    k = paper.optimum_k()
    assert k == pytest.approx(math.sqrt(2.0), abs=1e-6)
    assert paper.OPTIMUM_K == math.sqrt(2.0)
    assert paper.gamma_relative(paper.OPTIMUM_K) == pytest.approx(3.0 * math.sqrt(3.0) / 4.0, abs=1e-12)
    assert 1.0 <= k <= 1.5
    grid = np.linspace(0.05, 5.0, 2000)
    assert float(paper.gamma_relative(grid).min()) >= float(paper.gamma_relative(paper.OPTIMUM_K)) - 1e-12


def test_alpha_forms_agree_with_k_forms():
    k = np.array([0.3, 1.0, np.sqrt(2.0), 2.5])
    alpha = paper.converging_alpha_deg(k)
    np.testing.assert_allclose(paper.e1_from_alpha(alpha), paper.e1(k), rtol=1e-12)
    np.testing.assert_allclose(paper.e2_from_alpha(alpha), paper.e2(k), rtol=1e-12)
    np.testing.assert_allclose(paper.k_from_converging_alpha(alpha), k, rtol=1e-12)
    # The optimum's converging angle is atan(sqrt 2) = 54.7356 deg, outside the paper's 30-40 deg.
    assert paper.converging_alpha_deg(paper.OPTIMUM_K) == pytest.approx(54.7356103, abs=1e-6)


def test_curves_shape_and_validation():
    c = paper.curves([0.5, 1.0, 2.0])
    assert set(c) == {"K", "e1", "e2", "gamma_rel", "alpha_deg"}
    assert all(v.shape == (3,) for v in c.values())
    with pytest.raises(ValueError, match="positive"):
        paper.e1(0.0)
    with pytest.raises(ValueError, match="converging"):
        paper.k_from_converging_alpha(95.0)
