"""Closed-form replacements for OpenPBR's coat darkening and roughening, fitted on measurements.

The formulas (``docs/production.md`` section 5), in OpenPBR's own inputs so a renderer can use
them as they are: ``coat_ior`` n, the base albedo estimate ``E_base`` (``base_color *
specular_weight`` for a metal, ``base_color`` for a diffuse base), ``base_metalness`` m (0 or 1),
and GGX alphas (``alpha = r**2`` of OpenPBR's perceptual roughness r) of the coat and the base.
Domain: ``n >= 1`` (a coat denser than air), ``E_base`` in [0, 1], alphas in [0, 1].

* :data:`DARKENING` keeps the specification's form ``(1 - K) / (1 - E K)``. Diffuse base:
  ``K = 1 - (1 - F0(n)) / n**(2 q)`` (``q = 1`` is the spec). Metal base: the metal's reflectance
  re-referenced to the coat, ``E'`` (:func:`metal_in_coat`), ``K = k0 (1 - 1/n**2)**k1 (1 + ka
  alpha_base + kc alpha_coat)`` and ``D = (E'/E)**w (1 - K) / (1 - E' K)``.
* :data:`ROUGHENING`: ``t = n**(2 p) alpha_base**2 + c (n - 1)**d alpha_coat**2`` and
  ``alpha_eff = sqrt(t / (1 + s t))``: the base lobe widened by refraction out of the coat (the
  angular spread of light leaving a denser medium grows ~n), the coat's own roughness entering
  only through its index contrast (an index-matched rough coat is absent), saturating as the
  lobe fills the hemisphere.

The split (:func:`heldout_iors`) holds out whole coat indices, drawn with a fixed seed among the
interior ones (so held-out configurations are interpolation, not extrapolation, in n).
Fitting: :func:`scipy.optimize.least_squares` from fixed starting values, unweighted residuals in
the quantity's own units.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

#: seed of the held-out draw
SPLIT_SEED = 13
#: fraction of the coat indices held out
HELDOUT_FRACTION = 0.25


def heldout_iors(iors: Sequence[float], seed: int = SPLIT_SEED, fraction: float = HELDOUT_FRACTION
                 ) -> tuple[float, ...]:
    """The coat indices held out: ``max(1, round(fraction * n))`` of the distinct indices, drawn with
    ``seed`` among the interior ones (the smallest and largest always train). Needs >= 3 indices."""
    values = sorted({round(float(x), 9) for x in iors})
    if len(values) < 3:
        raise ValueError(f"coat indices: need at least 3 distinct values to hold one out, got {values}")
    if not 0.0 < fraction < 1.0:
        raise ValueError(f"fraction: must be in (0, 1), got {fraction}")
    interior = values[1:-1]
    k = min(len(interior), max(1, int(round(fraction * len(values)))))
    picked = np.random.default_rng(seed).choice(len(interior), size=k, replace=False)
    return tuple(sorted(interior[i] for i in picked))


def is_heldout(ior: float, held: Sequence[float]) -> bool:
    return any(abs(float(ior) - h) < 1e-9 for h in held)


def fresnel_f0(n: np.ndarray) -> np.ndarray:
    """Normal-incidence Fresnel reflectance of a dielectric of relative index n."""
    return ((n - 1.0) / (n + 1.0)) ** 2


@dataclass(frozen=True)
class Formula:
    """A closed form ``predict(coef, X)`` with named coefficients, starting values and bounds.

    ``X`` is a dict of 1-D arrays (the formula's ``inputs``); ``expression(coef)`` writes it out."""

    name: str
    inputs: tuple[str, ...]
    coefficients: tuple[str, ...]
    initial: tuple[float, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    predict: Callable[[np.ndarray, dict[str, np.ndarray]], np.ndarray]
    expression: Callable[[np.ndarray], str]


def metal_in_coat(e_base: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Normal-incidence reflectance of a metal of reflectance ``e_base`` in air once it lies under a
    medium of index n, with the metal treated as a dielectric of the same F0 (``n_e = (1 + sqrt(E)) /
    (1 - sqrt(E))``, ``E' = ((n_e - n) / (n_e + n))**2``); 0 where ``n_e <= n`` (a "metal" no brighter
    than the coat's own Fresnel, outside the domain). ``e_base`` in [0, 1)."""
    r = np.sqrt(np.clip(e_base, 0.0, 1.0 - 1e-12))
    ne = (1.0 + r) / (1.0 - r)
    return np.where(ne > n, ((ne - n) / (ne + n)) ** 2, 0.0)


def _darkening(coef: np.ndarray, X: dict[str, np.ndarray]) -> np.ndarray:
    q_d, k0, k1, ka, kc, w = coef
    n, e, m = X["coat_ior"], X["base_albedo"], X["base_metalness"]
    ab, ac = X["base_alpha"], X["coat_alpha"]
    # diffuse base: the specification's K with a fitted exponent of n
    k_d = 1.0 - (1.0 - fresnel_f0(n)) / n ** (2.0 * q_d)
    d_diffuse = (1.0 - k_d) / (1.0 - e * k_d)
    # metal base: the metal's reflectance re-referenced to the coat, and a K rising with both roughnesses
    e_in = metal_in_coat(e, n)
    k_m = k0 * (1.0 - 1.0 / n ** 2) ** k1 * (1.0 + ka * ab + kc * ac)
    ratio = np.divide(e_in, e, out=np.zeros_like(e_in), where=e > 0.0) ** w
    d_metal = ratio * (1.0 - k_m) / (1.0 - e_in * k_m)
    return (1.0 - m) * d_diffuse + m * d_metal


def _darkening_text(c: np.ndarray) -> str:
    return ("diffuse base (metalness 0): D = (1 - K) / (1 - E_base K),  K = 1 - (1 - F0(n)) / n^"
            f"{2 * c[0]:.4f},  F0(n) = ((n - 1) / (n + 1))^2\n"
            "metal base (metalness 1):   D = (E' / E_base)^"
            f"{c[5]:.4f} (1 - K) / (1 - E' K),  K = {c[1]:.4f} (1 - 1/n^2)^{c[2]:.4f} "
            f"(1 + {c[3]:.4f} alpha_base + {c[4]:.4f} alpha_coat),\n"
            "                            E' = ((n_e - n) / (n_e + n))^2,  n_e = (1 + sqrt(E_base)) / (1 - sqrt(E_base))\n"
            "metalness m in (0, 1): D = (1 - m) D_diffuse + m D_metal")


def _roughening(coef: np.ndarray, X: dict[str, np.ndarray]) -> np.ndarray:
    p, c, d, s = coef
    n, ab, ac = X["coat_ior"], X["base_alpha"], X["coat_alpha"]
    t = n ** (2.0 * p) * ab ** 2 + c * np.abs(n - 1.0) ** d * ac ** 2
    return np.sqrt(t / (1.0 + s * t))


def _roughening_text(c: np.ndarray) -> str:
    return (f"alpha_eff = sqrt(t / (1 + {c[3]:.4f} t)),  "
            f"t = n^{2 * c[0]:.4f} alpha_base^2 + {c[1]:.4f} (n - 1)^{c[2]:.4f} alpha_coat^2")


DARKENING = Formula(
    name="darkening", inputs=("coat_ior", "base_albedo", "base_metalness", "base_alpha", "coat_alpha"),
    coefficients=("q_diffuse", "k0_metal", "k1_metal", "k_base_alpha", "k_coat_alpha", "w_metal"),
    initial=(1.0, 0.6, 1.0, 0.0, 0.0, 1.0), lower=(0.0, 0.0, 0.0, -1.0, -1.0, 0.0),
    upper=(5.0, 1.0, 5.0, 10.0, 10.0, 5.0), predict=_darkening, expression=_darkening_text)

ROUGHENING = Formula(
    name="roughening", inputs=("coat_ior", "base_alpha", "coat_alpha"),
    coefficients=("p", "c", "d", "s"), initial=(1.0, 2.0, 1.0, 0.5),
    lower=(0.0, 0.0, 0.0, 0.0), upper=(3.0, 50.0, 6.0, 10.0), predict=_roughening, expression=_roughening_text)


@dataclass(frozen=True)
class Fit:
    """A fitted formula: coefficients (named), training RMSE, and whether the solver converged."""

    formula: Formula
    coef: np.ndarray
    rmse_train: float
    converged: bool
    message: str

    def predict(self, X: dict[str, np.ndarray]) -> np.ndarray:
        return self.formula.predict(self.coef, X)

    def coefficients(self) -> dict[str, float]:
        return {k: float(v) for k, v in zip(self.formula.coefficients, self.coef)}

    def expression(self) -> str:
        return self.formula.expression(self.coef)


def fit_formula(formula: Formula, X: dict[str, np.ndarray], y: np.ndarray) -> Fit:
    """Least-squares fit of ``formula`` to ``y`` (residuals in y's own units), from its fixed start."""
    y = np.asarray(y, dtype=np.float64)
    missing = [k for k in formula.inputs if k not in X]
    if missing:
        raise ValueError(f"{formula.name}: inputs {missing} are missing")
    if len(y) < len(formula.coefficients):
        raise ValueError(f"{formula.name}: {len(y)} samples cannot fit {len(formula.coefficients)} coefficients")
    Xf = {k: np.asarray(X[k], dtype=np.float64) for k in formula.inputs}

    def residual(c: np.ndarray) -> np.ndarray:
        return formula.predict(c, Xf) - y

    r = least_squares(residual, np.array(formula.initial), bounds=(np.array(formula.lower), np.array(formula.upper)),
                      x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=5000)
    return Fit(formula, r.x, float(np.sqrt(np.mean(r.fun ** 2))), bool(r.success), str(r.message))


def rmse(predicted: np.ndarray, measured: np.ndarray) -> float:
    """Root mean square of ``predicted - measured`` (NaN for no samples)."""
    d = np.asarray(predicted, dtype=np.float64) - np.asarray(measured, dtype=np.float64)
    return float(np.sqrt(np.mean(d ** 2))) if d.size else float("nan")
