"""The paper's structural error model, exactly as published (Yang et al. 2024, section 3, Eqs. 4-5).

The model is for the symmetric rig of the paper's Figure 2: both cameras at the same angle α to the
baseline, their optical axes meeting at the object point P (``cot α = K / 2`` with ``K = B / Z``),
equal focal lengths f, and an image-point error δ in each camera. With these

    e1(K) = 1/2 + K²/8          (the X, along-baseline, propagation factor)
    e2(K) = 1/K + K/4           (the Z, depth, propagation factor)
    γ     = √2 · (Z / f) · √(e1² + e2²) · δ

(units: Z in mm, f and δ in the same pixel unit, γ in mm). In α, with cot α = K/2, the same factors
read e1 = cot α / sin 2α and e2 = 1 / sin 2α; they are the first-order derivatives of the two-ray
intersection (X, Z) w.r.t. each ray's angle, divided by Z, and δ / f is that angle's error:
ΔX = √2 · (Z/f) · e1 · δ and ΔZ = √2 · (Z/f) · e2 · δ for independent errors in the two cameras.

The relative error √(e1² + e2²) = (K² + 4)^(3/2) / (8 K) has its minimum where 3K² = K² + 4, i.e.
at K = √2 (γ_rel = 3√3 / 4 ≈ 1.299), which is the paper's "K between 1 and 1.5". The converging
angle there is α = atan(2 / K) = atan(√2) ≈ 54.7°, not the paper's 30-40°: see docs/ERROR_MODEL.md.

Pure functions of numpy arrays (or floats); angles in degrees at the interface.
"""

from __future__ import annotations

import math

import numpy as np

#: K at which the paper's γ is smallest (closed form, d/dK ln γ = 3K/(K²+4) - 1/K = 0).
OPTIMUM_K = math.sqrt(2.0)


def _k_array(k: np.ndarray | float) -> np.ndarray:
    k = np.asarray(k, dtype=float)
    if np.any(~(k > 0)):
        raise ValueError("K = B / Z must be positive")
    return k


def e1(k: np.ndarray | float) -> np.ndarray:
    """The paper's X (along-baseline) propagation factor e1 = 1/2 + K²/8 (dimensionless, same shape as K)."""
    k = _k_array(k)
    return 0.5 + k**2 / 8.0


def e2(k: np.ndarray | float) -> np.ndarray:
    """The paper's Z (depth) propagation factor e2 = 1/K + K/4 (dimensionless, same shape as K)."""
    k = _k_array(k)
    return 1.0 / k + k / 4.0


def gamma_relative(k: np.ndarray | float) -> np.ndarray:
    """√(e1² + e2²): the paper's total error in units of √2 · (Z/f) · δ (dimensionless)."""
    return np.hypot(e1(k), e2(k))


def gamma_mm(k: np.ndarray | float, distance_mm: float, focal_px: float, delta_px: float) -> np.ndarray:
    """The paper's total error γ = √2 · (Z/f) · √(e1² + e2²) · δ in mm, for an image-point error δ (px)."""
    return math.sqrt(2.0) * (distance_mm / focal_px) * gamma_relative(k) * delta_px


def components_mm(
    k: np.ndarray | float, distance_mm: float, focal_px: float, delta_px: float
) -> tuple[np.ndarray, np.ndarray]:
    """(ΔX, ΔZ) in mm: √2 · (Z/f) · e1 · δ and √2 · (Z/f) · e2 · δ (X along the baseline, Z the depth)."""
    scale = math.sqrt(2.0) * (distance_mm / focal_px) * delta_px
    return scale * e1(k), scale * e2(k)


def converging_alpha_deg(k: np.ndarray | float) -> np.ndarray:
    """α (deg) of the symmetric rig whose optical axes meet at the object: cot α = K / 2."""
    k = _k_array(k)
    return np.degrees(np.arctan2(2.0, k))


def k_from_converging_alpha(alpha_deg: np.ndarray | float) -> np.ndarray:
    """K = 2 cot α: the inverse of :func:`converging_alpha_deg` (α in (0, 90) deg)."""
    alpha = np.asarray(alpha_deg, dtype=float)
    if np.any(~((alpha > 0) & (alpha < 90))):
        raise ValueError("a converging rig has 0 < alpha < 90 deg")
    return 2.0 / np.tan(np.radians(alpha))


def e1_from_alpha(alpha_deg: np.ndarray | float) -> np.ndarray:
    """e1 = cot α / sin 2α: the same factor as :func:`e1` written in the converging angle."""
    a = np.radians(np.asarray(alpha_deg, dtype=float))
    return (1.0 / np.tan(a)) / np.sin(2.0 * a)


def e2_from_alpha(alpha_deg: np.ndarray | float) -> np.ndarray:
    """e2 = 1 / sin 2α: the same factor as :func:`e2` written in the converging angle."""
    a = np.radians(np.asarray(alpha_deg, dtype=float))
    return 1.0 / np.sin(2.0 * a)


def curves(k: np.ndarray | float) -> dict[str, np.ndarray]:
    """The paper's Figure 3: ``K``, ``e1``, ``e2``, ``gamma_rel`` and the converging ``alpha_deg``, each like K."""
    k = _k_array(k)
    return {"K": k, "e1": e1(k), "e2": e2(k), "gamma_rel": gamma_relative(k), "alpha_deg": converging_alpha_deg(k)}


def optimum_k(*, k_min: float = 1e-3, k_max: float = 10.0) -> float:
    """K minimising γ, found numerically (golden section on the unimodal γ_rel); equals :data:`OPTIMUM_K`."""
    inv_phi = (math.sqrt(5.0) - 1.0) / 2.0
    a, b = k_min, k_max
    c, d = b - inv_phi * (b - a), a + inv_phi * (b - a)
    while b - a > 1e-12:
        if float(gamma_relative(c)) < float(gamma_relative(d)):
            b, d = d, c
            c = b - inv_phi * (b - a)
        else:
            a, c = c, d
            d = a + inv_phi * (b - a)
    return 0.5 * (a + b)
