"""The numbered equations of Bati 2021 (scalar and array forms), at normal incidence.

``eq1_reflectance`` ... ``eq19_sigma_r`` are the paper's equations 1 to 19 as written (see
``docs/inverse.md`` for the list and the sections they belong to); :func:`eq18_scalar` and
:func:`eq19_scalar` are their compiled scalar forms used by the kernels. Indices are absolute
(air above the stack, ``eta0 = 1`` by default); variances are Belcour's ``f(alpha)``;
``J_0n = eta_n / eta_0`` at normal incidence.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import optimize

from goniometer import optics
from models._jit import njit
from models.belcour import roughness_to_variance
from models.inverse.lobes import InverseError

#: smallest normal reflectance of a conductor with kappa >= eta (eq. 9 defined): 3 - 2 sqrt(2)
CONDUCTOR_R_MIN = 3.0 - 2.0 * math.sqrt(2.0)


# ============================================================================ compiled scalar forms (kernels)

@njit(cache=True)
def eq18_scalar(rk, t0, ti, ri) -> float:
    """Eq. 18: R'_{n,n+l} = 1 / (T_0n T_n0 / R_k + R_n0) (R'_{n,n+l} = R_k for an empty stack)."""
    if rk <= 0.0:
        return 0.0
    return 1.0 / (t0 * ti / rk + ri)


@njit(cache=True)
def eq19_scalar(sigma, rp, ri, vti, vt0, vri, j0) -> float:
    """Eq. 19: sigma^R_{n,n+l} = (1 - R_n0 R') ((sigma_k - sigma^T_n0) / J_0n - sigma^T_0n) - R_n0 R' sigma^R_n0,
    with J_0n = eta_n / eta_0 at normal incidence."""
    q = ri * rp
    return (1.0 - q) * ((sigma - vti) / j0 - vt0) - q * vri


# ============================================================================ equations (scalar forms)

def eq1_reflectance(eta0: float, eta1: float, kappa1: float = 0.0) -> float:
    """Eq. 1: Fresnel reflectance at normal incidence between media ``eta0`` and ``eta1 + i kappa1``
    (:func:`goniometer.optics.fresnel_conductor` at cos = 1)."""
    return float(optics.fresnel_conductor(1.0, eta1 / eta0, kappa1 / eta0))


def eq2_adding(R01: Any, R12p: Any) -> np.ndarray:
    """Eq. 2 at normal incidence with R10 = R01, T01 = T10 = 1 - R01: R02 = R01 + T01 R'12 T10 / (1 - R'12 R10)."""
    r01 = np.asarray(R01, dtype=float)
    r12 = np.asarray(R12p, dtype=float)
    t = 1.0 - r01
    return r01 + t * r12 * t / (1.0 - r12 * r01)


def eq7_roots(R01: float, eta0: float = 1.0) -> tuple[float, float]:
    """Eq. 7: the two indices ``eta1 = eta0 (1 -+ sqrt R01) / (1 +- sqrt R01)`` with normal
    reflectance ``R01`` in a medium ``eta0``: ``(lower, upper)``."""
    if not 0.0 <= R01 < 1.0:
        raise InverseError(f"R01: must be in [0, 1), got {R01!r}")
    s = math.sqrt(R01)
    return eta0 * (1.0 - s) / (1.0 + s), eta0 * (1.0 + s) / (1.0 - s)


def eq8_kappa(R01: float, eta1: float, eta0: float = 1.0) -> float:
    """Eq. 8: the extinction ``kappa1`` giving normal reflectance ``R01`` for real part ``eta1``
    (NaN where the radicand is negative: no conductor with that ``eta1``)."""
    x = eta1 / eta0
    rad = (R01 * (x + 1.0) ** 2 - (x - 1.0) ** 2) / (1.0 - R01)
    return eta0 * math.sqrt(rad) if rad >= 0.0 else float("nan")


def eq9_eta_max(R01: float, eta0: float = 1.0) -> float:
    """Eq. 9: the largest ``eta1`` of a conductor (kappa1 >= eta1) with reflectance ``R01``; NaN
    when ``R01 < 3 - 2 sqrt 2``."""
    rad = 6.0 * R01 - 1.0 - R01 * R01
    if rad < 0.0:
        return float("nan")
    return eta0 * (1.0 + R01 + math.sqrt(rad)) / (2.0 * (1.0 - R01))


def eq10_eta_min(R01: float, eta0: float = 1.0) -> float:
    """Eq. 10: the smallest ``eta1`` retained for a conductor (maximal edge tint, Gulbrandsen 2014)."""
    return eta0 * (1.0 - R01) / (1.0 + R01)


def conductor_eta_bounds(R01: float, eta0: float = 1.0) -> tuple[float, float] | None:
    """``[eta_c_min, eta_c_max]`` of eqs. 10 and 9 (None if ``R01 < 3 - 2 sqrt 2`` or ``R01 >= 1``).
    The lower bound is also kept above the smaller root of ``kappa = eta`` (never active in practice)."""
    if not (CONDUCTOR_R_MIN <= R01 < 1.0):
        if R01 < CONDUCTOR_R_MIN and R01 > CONDUCTOR_R_MIN - 1e-12:
            R01 = CONDUCTOR_R_MIN
        else:
            return None
    rad = max(0.0, 6.0 * R01 - 1.0 - R01 * R01)
    hi = eta0 * (1.0 + R01 + math.sqrt(rad)) / (2.0 * (1.0 - R01))
    lo_k = eta0 * (1.0 + R01 - math.sqrt(rad)) / (2.0 * (1.0 - R01))
    lo = max(eq10_eta_min(R01, eta0), lo_k)
    return lo, hi


def eq11_inverse_adding(R02: Any, R01: Any) -> np.ndarray:
    """Eq. 11: R'12 = R12 exp(-2 tau1) = (R02 - R01) / (1 + (R02 - 2) R01)."""
    r02 = np.asarray(R02, dtype=float)
    r01 = np.asarray(R01, dtype=float)
    return (r02 - r01) / (1.0 + (r02 - 2.0) * r01)


def eq13_tau(R12: Any, R12p: Any) -> np.ndarray:
    """Eq. 13: tau1 = 1/2 log(R12 / R'12)."""
    return 0.5 * np.log(np.asarray(R12, dtype=float) / np.asarray(R12p, dtype=float))


def eq15_sigma_r12(sigma02: float, eta0: float, eta1: float, alpha1: float, R10: float, R12p: float) -> float:
    """Eq. 15: sigma^R_12 = (1 - R10 R'12) (eta0/eta1 (sigma02 - sigma^T_10) - sigma^T_01) - R10 R'12 sigma^R_10,
    with eq. 6: sigma^R_10 = f(alpha1), sigma^T_01 = f(|1 - eta0/eta1| alpha1 / 2), sigma^T_10 = f(|1 - eta1/eta0| alpha1 / 2)."""
    n = eta1 / eta0
    vt01 = roughness_to_variance(alpha1 * 0.5 * abs(n - 1.0) / n)
    vt10 = roughness_to_variance(alpha1 * 0.5 * abs(1.0 - n))
    q = R10 * R12p
    return (1.0 - q) * ((sigma02 - vt10) / n - vt01) - q * roughness_to_variance(alpha1)


def eq18_r_prime(Rk: Any, T0n: Any, Tn0: Any, Rn0: Any) -> np.ndarray:
    """Eq. 18: R'_{n,n+1} = 1 / (T_0n T_n0 / R_k + R_n0)."""
    rk = np.asarray(Rk, dtype=float)
    return 1.0 / (np.asarray(T0n) * np.asarray(Tn0) / rk + np.asarray(Rn0))


def eq17_energy(Rp: Any, T0n: Any, Tn0: Any, Rn0: Any) -> np.ndarray:
    """Eq. 17: R_k = T_0n R'_{n,n+1} T_n0 / (1 - R'_{n,n+1} R_n0)."""
    rp = np.asarray(Rp, dtype=float)
    return np.asarray(T0n) * rp * np.asarray(Tn0) / (1.0 - rp * np.asarray(Rn0))


def eq19_sigma_r(sigma_k: float, Rp: float, Rn0: float, vTn0: float, vT0n: float, vRn0: float, J0n: float) -> float:
    """Eq. 19 (scalar form; J_0n = eta_n / eta_0 at normal incidence)."""
    return float(eq19_scalar(sigma_k, Rp, Rn0, vTn0, vT0n, vRn0, J0n))


def _sigma_condition(x: float, alpha1: float, sigma02: float) -> float:
    return (sigma02 - roughness_to_variance(0.5 * abs(x - 1.0) * alpha1)) / x \
        - roughness_to_variance(0.5 * abs(1.0 - 1.0 / x) * alpha1)


def eta_sigma_max(alpha1: float, eta0: float = 1.0) -> float:
    """The ``eta1 <= eta_sigma_max`` approximation of V (section 5.2.2; choice 4 of
    docs/inverse.md): the root in ``x = eta1/eta0 > 1`` of eq. 15 without its inter-reflection terms,
    ``(f(alpha1) - f(|x - 1| alpha1 / 2)) / x - f(|1 - 1/x| alpha1 / 2) = 0``. ``inf`` for a smooth lobe."""
    if alpha1 <= 0.0:
        return math.inf
    s02 = roughness_to_variance(alpha1)
    g = lambda x: _sigma_condition(x, alpha1, s02)  # noqa: E731
    hi = 2.0
    while g(hi) > 0.0:
        hi *= 2.0
        if hi > 1e6:
            return math.inf
    return eta0 * optimize.brentq(g, 1.0, hi, xtol=1e-13, rtol=1e-13)
