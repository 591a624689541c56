"""Bati, Pacanowski, Barla 2021: an inverse method for layered material appearance.

Users describe the BRDF lobes they want at normal incidence -- energy ``R_k`` (RGB) and variance
``sigma_k`` of each lobe, top lobe first -- and get physical layer stacks that produce them under
Belcour's forward model (:mod:`models.belcour.model`), together with the equivalence classes (sets of
stacks with the same lobes at normal incidence) to explore.

Paper: ``shared/papers/bati2021-inverse-layered-appearance.txt`` (sections and equations cited
below as "eq. n", "alg. n"); summary in ``shared/spec/MODELS.md``.

API
---
* :class:`Lobe` ``(R, sigma, layers)`` and :func:`parse_lobe` (``"R=0.03,0.06,0.09 sigma=0.05 layers=2"``).
* :func:`invert` ``(lobes, base="dielectric"|"conductor", **choices) -> Stack`` (top lobe first;
  raises :class:`NotAchievable` with the reason), :func:`solve` (the same, returning an
  :class:`Inversion`: stack, per-lobe classes, chosen points, never raising for an unachievable
  request), :func:`equivalence_classes`.
* Free choices: :class:`Pick` per lobe (``picks=[...]`` or ``lobe1=Pick(...)``), :func:`parse_picks`.
* Classes (sampled sets with bounds): :func:`one_layer_dielectric_class`, :func:`conductor_class`,
  :func:`two_layer_class` (N1, N2 at a point, T0, ``eta_sigma_max``), :func:`lobe_class`; each has
  ``achievable``/``reason``, ``bounds``, ``sample()`` and ``pick()``. :class:`Context` holds the
  statistics of the layers above a lobe (alg. 3), :class:`InverseOptions` the switches.
* :func:`inherent_variance_spread`, :func:`bench_invert` (figure 17 timing).

Conventions
-----------
* Lobe variance ``sigma = f(alpha) = alpha^1.1 / (1 - alpha^1.1)`` (Belcour's mapping,
  :func:`models.belcour.model.roughness_to_variance`); ``alpha = f^-1(sigma)``.
* Everything is at normal incidence (``theta_0 = 0``), per colour channel ("Contrary to
  Belcour's optimized implementation, we do not average lobe statistics over color channels",
  footnote 1): the inverse mirrors the forward model with ``per_channel=True``.
* Indices are absolute (``eta_n`` is the real index of medium n; air above the stack);
  ``eta_max`` (default 4) bounds dielectric indices, ``[1, eta_max]``.
* A *layer* of the paper's stack ``S`` is ``{eta_{m+1}, tau_m, alpha_{m+1}}`` (alg. 4): the
  optical depth ``tau_m`` of the medium above interface ``m + 1``, its roughness and the index
  below it. :meth:`Inversion.stack` turns them into a :class:`goniometer.stack.Stack`
  (a medium layer only where ``tau > 0``).
* Lobe ``k`` of a stack is the sum of the forward model's lobes of its interfaces (one for a
  1-layer lobe, two for a 2-layer lobe); its energy is their sum and its variance their
  energy-weighted mean (eq. 4: the unnormalised variances add).

The inverse's own forward equations
-----------------------------------
Algorithm 3 needs the statistics ``R_0n, R_n0, T_0n, T_n0`` and variances of the stack already
built ("Compute ... from S [Belcour 2018]"). :class:`Context` computes them at normal incidence
with exactly the adding-doubling of ``belcour2018.md`` section 6 (the per-channel variant, no
TIR, normal-incidence transmission scales, eq. 6), and FGD at normal incidence from the *same*
angular quadrature and the same interpolation in ``alpha`` as the forward model's material
slices (:func:`fgd_normal`: ``FGD(1, alpha, eta, kappa) = sum_j W[mu=1, alpha, j] F(x_j)``,
exact Fresnel in the ``alpha = 0`` column, linear in ``sqrt(alpha)`` between the 64 alpha nodes).
So the round trip through :mod:`models.belcour.model` is limited only by root-finding tolerances
(~1e-12), except where the forward model uses a *split* FGD slice (``eta < 1`` relative index
with a reachable critical angle, :func:`models.tables.belcour.fgd_slice`): there the two quadratures
differ by up to 1.4 % relative at normal incidence (measured over eta_rel in (0.25, 1), alpha <=
0.7; the tests). Table resolution: against an exact 1-D quadrature of the microfacet albedo at
normal incidence, this FGD is within 5e-4 relative where Fresnel is smooth and within about
1.2 % near total internal reflection (interpolation in alpha across the critical angle) -- an
error of the retrieved stack's true energies that the forward model shares.

Equations implemented
---------------------
* eq. 1 (:func:`eq1_reflectance`), eq. 2 (:func:`eq2_adding`), eq. 6 (inside :class:`Context`).
* 1-layer dielectric lobes (section 5.1.1): eq. 7 (:func:`eq7_roots`), both roots, the smaller
  one valid when ``eta0 > (1 + sqrt R) / (1 - sqrt R)``; ``R`` at most eq. 1 at ``eta_max``; rough
  lobes by numerical inversion of FGD at normal incidence (one or two roots); coloured lobes
  through ``tau0 = 1/2 log(R01 / R01_rgb)`` with the channel of maximal reflectance.
* 1-layer conductor lobes (section 5.1.2): eq. 8 (:func:`eq8_kappa`) on ``[eta_c_min, eta_c_max]``
  of eqs. 10 and 9 (:func:`eq10_eta_min`, :func:`eq9_eta_max`), ``R01 > 3 - 2 sqrt 2``.
* 2-layer lobes (section 5.2, alg. 1): eq. 11 (:func:`eq11_inverse_adding`), the sets N1 (eq. 12)
  and N2 (eq. 14), eq. 13 (:func:`eq13_tau`), eq. 15 (:func:`eq15_sigma_r12`), the
  ``eta1 <= eta_sigma_max`` approximation (:func:`eta_sigma_max`) followed by the explicit
  ``sigma_R12 >= 0`` check, T0 (eq. 16), coloured media (per-channel classes intersected, 5.2.3),
  conductor base through the equivalent index (5.2.4).
* Multi-lobe stacking (section 6, algs. 2-5): eq. 17-19 (:func:`eq18_r_prime`,
  :func:`eq19_sigma_r`, :meth:`Context.base_stats`), eq. 20 (target of the second interface of a
  stacked 2-layer lobe).

Choices where the paper is vague (all documented again where they are made)
----------------------------------------------------------------------------
1. *Conductor energy with roughness.* The paper inverts Fresnel for conductors ("no significant
   impact of roughness on energy") and attributes the residual in figure 25 to its FGD table.
   We solve ``FGD(alpha~, eta, kappa) = R`` exactly instead: for a position ``u`` in the class,
   ``eta = eta_c_min(R_F) + u (eta_c_max(R_F) - eta_c_min(R_F))`` and ``kappa = eq. 8(R_F, eta)``,
   with the Fresnel reflectance ``R_F >= R`` found by root finding (``R_F = R`` when smooth).
   Eqs. 9-10 then bound ``R_F``; a rough conductor also cannot exceed the F = 1 albedo of GGX.
2. *Top interface of a stacked 2-layer lobe.* Alg. 5 sets ``alpha_{n+1} = f^-1(sigma_R_{n,n+2})``
   with eq. 19 evaluated with the whole lobe's ``R'_{n,n+2}``; the forward model then gives that
   sub-lobe a variance slightly different from ``sigma_k`` (the inter-reflection factor ``m`` of
   eq. 19 belongs to the first interface alone). By default (``top_variance="exact"``) we solve
   eq. 19 with the first interface's own ``R'_{n,n+1}`` (a fixed point, since ``R'_{n,n+1}``
   depends on ``alpha_{n+1}`` through FGD; converges in a few iterations), so both sub-lobes get
   ``sigma_k`` exactly on the chosen channel. ``top_variance="paper"`` reproduces alg. 5.
   For the top lobe (n = 0) both are identical (eq. 15 / alg. 1).
3. *Channel of the variance.* ``alpha`` is achromatic while eq. 19 holds per channel (the
   inter-reflection factor ``m = R_n0 R' / (1 - R_n0 R')`` differs between channels of a coloured
   lobe under a stack), so no achromatic roughness gives ``sigma_k`` in every channel. Section
   5.2.3 uses the channel of maximal ``R'`` (``variance_channel="max"``: exact there, the other
   channels off by up to the whole spread). By default (``"minimax"``) we pick the scalar variance
   minimising the largest error over channels -- the forward variance is affine in ``sigma_R``
   per channel with slope ``J_0n (1 + m_c)`` -- which halves the worst channel's error. At the top
   of a stack (``m = 0``) both give ``sigma_k`` exactly in every channel.
4. *eta_sigma_max* (the paper's supplemental approximation is not available): we use the
   necessary condition obtained from eq. 15 by dropping the inter-reflection terms
   ``R10 R'12`` (which only lower ``sigma_R12``):
   ``(sigma_02 - f(|1 - x| alpha1 / 2)) / x - f(|1 - 1/x| alpha1 / 2) >= 0`` with
   ``x = eta1 / eta0``; its root in ``x > 1`` gives ``eta_sigma_max`` (about 2.1 ``eta0`` for small
   ``alpha1``). It never excludes a valid ``eta1`` but is not sufficient ("not conservative"), so
   ``sigma_R12 >= 0`` is then checked explicitly.
5. *Sampling and bounds of N1.* N1 is found on a scan of ``n_scan`` (128) values of ``eta1`` in
   ``[1, min(eta_max, eta_sigma_max)]`` (the eta_sigma_max restriction only for the top lobe,
   where it is the paper's), each run of valid samples refined to 1e-10 by bisection of the
   exact predicate at both ends; intervals narrower than the scan step can be missed (a
   1024-sample scan is tried before declaring N1 empty, except inside the search of choice 6).
6. *Defaults for the free choices* (:class:`Pick`): the centre (``u = 0.5``, by length over the
   union of intervals) of N1, of N2 and of conductor classes (the paper: "we systematically pick
   the center"); no absorption above a lobe (``tau0 = 0``) unless needed; for 1-layer
   dielectric lobes the ``tau = 0`` root of the channel of maximal ``R'`` (section 5.1.1),
   upper root (``eta1 > eta_n``) if it is within ``eta_max``, else the lower one; for a conductor
   that is too dark for its own reflectance (``R' < 3 - 2 sqrt 2``) under a stack, the smallest
   ``tau`` that brings its reflectance to ``CONDUCTOR_R_FLOOR = 0.2`` (``tau1`` of a 2-layer
   conductor lobe likewise). If a default choice of an upper lobe leaves a lower lobe
   unachievable, the upper lobes' free positions are searched (:func:`solve`, ``search=True``):
   candidate positions ordered by distance from the defaults, the first that makes every lobe
   achievable wins; explicit picks are never changed.
7. *Top of the stack.* The stack starts in air with no medium above the first interface, so the
   top lobe has ``tau0 = 0``: a coloured top 1-layer dielectric lobe is not achievable (use a
   2-layer lobe); a top conductor lobe needs ``R >= 3 - 2 sqrt 2`` in every channel.
8. *T0 (eq. 16)* is reported per channel as ``1/2 log([R_min, R_max] / R)`` with ``R_min, R_max``
   the bounds of an achromatic lobe with the same variance found by bisection (R_min = 0 for
   dielectric lobes): an outer bound for coloured lobes.
"""

from __future__ import annotations

import math
import re
import time
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Any, Sequence

import numpy as np
from scipy import optimize

from goniometer import optics
from goniometer.stack import Interface, Medium, Stack
from models._jit import njit
from models.tables import belcour as tables
from models.belcour import roughness_to_variance, variance_to_roughness

RGB = tuple[float, float, float]

ETA_MAX_DEFAULT = 4.0
#: smallest normal reflectance of a conductor with kappa >= eta (eq. 9 defined): 3 - 2 sqrt(2)
CONDUCTOR_R_MIN = 3.0 - 2.0 * math.sqrt(2.0)
#: default conductor reflectance when absorption above it is needed to reach the conductor range
CONDUCTOR_R_FLOOR = 0.2
#: eta1 samples of the N1 scan (choice 5 of the module docstring), and the fallback scan
N_SCAN = 128
N_SCAN_FALLBACK = 1024
#: bisection tolerance on eta boundaries
ETA_TOL = 1e-10
#: relative tolerance for "the channels of R are equal" (achromatic lobe)
ACHROMATIC_RTOL = 1e-9

# failure codes of the 2-layer predicate
OK = 0
FAIL_TOP_VARIANCE = 1
FAIL_TOP_ENERGY = 2
FAIL_BOTTOM_ENERGY = 3
FAIL_BOTTOM_VARIANCE = 4
FAIL_NO_ETA2 = 5
FAIL_CONDUCTOR = 6
FAIL_TOP_TARGET = 7

_FAIL_TEXT = {
    FAIL_TOP_VARIANCE: "the first interface would need a negative variance (sigma_R < 0, eq. 19): the layers above "
                       "already spread the lobe more than sigma",
    FAIL_TOP_ENERGY: "the first interface alone reflects at least the lobe's energy (eq. 20 target <= 0)",
    FAIL_BOTTOM_ENERGY: "the second interface would need a reflectance >= 1 (eq. 11/18)",
    FAIL_BOTTOM_VARIANCE: "the second interface would need a negative variance (sigma_R12 < 0, eq. 15/19)",
    FAIL_NO_ETA2: "no eta2 in [1, eta_max] reflects enough (eq. 14: N2 empty)",
    FAIL_CONDUCTOR: "the conductor base would need a reflectance above what a rough conductor reaches",
    FAIL_TOP_TARGET: "the stack above transmits too little: the lobe would need a reflectance >= 1 below it (eq. 18)",
}


class InverseError(ValueError):
    """Invalid input to the inverse method (malformed lobe, out-of-range value, bad pick name)."""


class NotAchievable(ValueError):
    """The requested lobes have no physically achievable stack.

    ``reason`` says why (with the bound that is violated when there is one), ``lobe`` is the
    1-based index of the first lobe that failed (0 if not lobe specific).
    """

    def __init__(self, reason: str, lobe: int = 0) -> None:
        super().__init__(f"not physically achievable: {reason}")
        self.reason = reason
        self.lobe = lobe


# ============================================================================ input: lobes

def _rgb(x: Any, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.ndim == 0:
        a = np.full(3, float(a))
    if a.shape != (3,):
        raise InverseError(f"{name}: expected a number or 3 numbers (R, G, B), got {x!r}")
    if not np.all(np.isfinite(a)):
        raise InverseError(f"{name}: {x!r} is not finite")
    return a


@dataclass(frozen=True)
class Lobe:
    """A requested BRDF lobe at normal incidence: energy ``R`` (scalar or RGB, each in (0, 1)),
    variance ``sigma >= 0`` (Belcour's variance, ``f(alpha)``), made of ``layers`` = 1 or 2 interfaces."""

    R: RGB | float
    sigma: float = 0.0
    layers: int = 1

    def __post_init__(self) -> None:
        r = _rgb(self.R, "R")
        if np.any(r < 0.0) or np.any(r >= 1.0):
            raise InverseError(f"R: every energy must be in [0, 1), got {_fmt_rgb(r)}")
        if np.any(r == 0.0):
            raise InverseError(f"R: every channel needs a positive energy, got {_fmt_rgb(r)} (a zero would need an "
                               "infinitely absorbing medium; use a small value such as 1e-4)")
        object.__setattr__(self, "R", tuple(float(x) for x in r))
        s = self.sigma
        if isinstance(s, bool) or not isinstance(s, (int, float, np.floating, np.integer)) or not math.isfinite(s):
            raise InverseError(f"sigma: {s!r} is not a finite number")
        if s < 0.0:
            raise InverseError(f"sigma: the variance must be >= 0, got {s:g}")
        object.__setattr__(self, "sigma", float(s))
        if isinstance(self.layers, bool) or self.layers not in (1, 2):
            raise InverseError(f"layers: a lobe has 1 or 2 layers (Bati 2021 figure 3), got {self.layers!r}")

    @property
    def rgb(self) -> np.ndarray:
        return np.asarray(self.R, dtype=float)

    @property
    def achromatic(self) -> bool:
        r = self.rgb
        return bool(np.ptp(r) <= ACHROMATIC_RTOL * np.max(r))

    def describe(self) -> str:
        return f"R={_fmt_rgb(self.rgb)} sigma={self.sigma:g} layers={self.layers}"


_LOBE_KEYS = ("R", "sigma", "layers")


def parse_lobe(text: str) -> Lobe:
    """Parse ``"R=0.03,0.06,0.09 sigma=0.05 layers=2"`` (keys in any order; ``R`` required, one or
    three numbers; ``sigma`` default 0; ``layers`` default 1). Raises :class:`InverseError`."""
    if not isinstance(text, str) or not text.strip():
        raise InverseError("empty lobe (expected e.g. \"R=0.03,0.06,0.09 sigma=0.05 layers=2\")")
    values: dict[str, str] = {}
    for token in text.replace(";", " ").split():
        if "=" not in token:
            raise InverseError(f"lobe {text!r}: {token!r} is not KEY=VALUE (keys: R, sigma, layers)")
        key, value = token.split("=", 1)
        key = key.strip()
        if key not in _LOBE_KEYS:
            raise InverseError(f"lobe {text!r}: unknown key {key!r} (keys: R, sigma, layers)")
        if key in values:
            raise InverseError(f"lobe {text!r}: {key} given twice")
        values[key] = value.strip()
    if "R" not in values:
        raise InverseError(f"lobe {text!r}: R is required (e.g. R=0.04 or R=0.03,0.06,0.09)")
    parts = [p for p in values["R"].split(",")]
    try:
        r = [float(p) for p in parts]
    except ValueError:
        raise InverseError(f"lobe {text!r}: R={values['R']!r} is not one or three numbers") from None
    if len(r) not in (1, 3):
        raise InverseError(f"lobe {text!r}: R needs one or three numbers, got {len(r)}")
    try:
        sigma = float(values.get("sigma", "0"))
    except ValueError:
        raise InverseError(f"lobe {text!r}: sigma={values['sigma']!r} is not a number") from None
    try:
        layers_f = float(values.get("layers", "1"))
    except ValueError:
        raise InverseError(f"lobe {text!r}: layers={values['layers']!r} is not 1 or 2") from None
    if layers_f != int(layers_f):
        raise InverseError(f"lobe {text!r}: layers={values['layers']!r} is not 1 or 2")
    try:
        return Lobe(tuple(r) if len(r) == 3 else r[0], sigma, int(layers_f))
    except InverseError as e:
        raise InverseError(f"lobe {text!r}: {e}") from None


@dataclass(frozen=True)
class InverseOptions:
    """Switches of the method (see the module docstring, choices 2, 3 and 5)."""

    eta_max: float = ETA_MAX_DEFAULT
    top_variance: str = "exact"
    variance_channel: str = "minimax"
    height_correlated: bool = False
    n_scan: int = N_SCAN
    cache_dir: str | None = None

    def __post_init__(self) -> None:
        if not (isinstance(self.eta_max, (int, float)) and math.isfinite(self.eta_max) and 1.0 < self.eta_max <= 16.0):
            raise InverseError(f"eta_max: must be in (1, 16], got {self.eta_max!r}")
        if self.top_variance not in ("exact", "paper"):
            raise InverseError(f"top_variance: {self.top_variance!r} is not one of exact, paper")
        if self.variance_channel not in ("max", "minimax"):
            raise InverseError(f"variance_channel: {self.variance_channel!r} is not one of max, minimax")
        if not isinstance(self.n_scan, int) or self.n_scan < 8:
            raise InverseError(f"n_scan: must be an integer >= 8, got {self.n_scan!r}")


# ============================================================================ FGD at normal incidence

@lru_cache(maxsize=4)
def _kernel(cache_dir: str | None, height_correlated: bool) -> tuple[np.ndarray, np.ndarray]:
    """The angular kernel row at mu = 1 (N_ALPHA x N_X) and its x nodes (models.tables)."""
    t = tables.load_belcour_tables(cache_dir, height_correlated)
    w1 = np.ascontiguousarray(t.kernel[-1], dtype=np.float64)
    xs = np.ascontiguousarray(tables.x_nodes(), dtype=np.float64)
    w1.setflags(write=False)
    xs.setflags(write=False)
    return w1, xs


def kernel_for(options: InverseOptions) -> tuple[np.ndarray, np.ndarray]:
    return _kernel(options.cache_dir, bool(options.height_correlated))


@njit(cache=True)
def _row_value(w1, xs, j, fx, f1) -> float:
    """Node value of the material slice at (mu = 1, alpha node j): exact Fresnel at j = 0, else
    the kernel moment clipped to [0, 1] (as models.tables.belcour._fgd_from_kernel)."""
    if j == 0:
        return f1
    acc = 0.0
    for i in range(xs.shape[0]):
        acc += w1[j, i] * fx[i]
    return min(max(acc, 0.0), 1.0)


@njit(cache=True)
def fgd_normal(w1, xs, alpha, eta, kappa) -> float:
    """FGD at normal incidence for GGX roughness ``alpha`` and relative index ``eta + i kappa``,
    identical to the forward model's (unsplit) material slice looked up at ``mu = 1``."""
    if eta == 1.0 and kappa == 0.0:
        return 0.0
    na = w1.shape[0]
    ta = math.sqrt(min(max(alpha, 0.0), 1.0)) * (na - 1)
    j = min(int(ta), na - 2)
    f = ta - j
    fx = np.empty(xs.shape[0])
    for i in range(xs.shape[0]):
        fx[i] = optics.fresnel_conductor(xs[i], eta, kappa)
    f1 = optics.fresnel_conductor(1.0, eta, kappa)
    v0 = _row_value(w1, xs, j, fx, f1)
    v1 = _row_value(w1, xs, j + 1, fx, f1)
    return v0 * (1.0 - f) + v1 * f


@njit(cache=True)
def albedo_normal(w1, alpha) -> float:
    """Directional albedo at normal incidence of a GGX interface with F = 1 (the most a rough
    conductor can reflect), interpolated as :func:`fgd_normal`."""
    na = w1.shape[0]
    ta = math.sqrt(min(max(alpha, 0.0), 1.0)) * (na - 1)
    j = min(int(ta), na - 2)
    f = ta - j
    v = np.zeros(2)
    for d in range(2):
        if j + d == 0:
            v[d] = 1.0
        else:
            acc = 0.0
            for i in range(w1.shape[1]):
                acc += w1[j + d, i]
            v[d] = min(acc, 1.0)
    return v[0] * (1.0 - f) + v[1] * f


@njit(cache=True)
def _fgd_minus(w1, xs, alpha, target, eta_n, e) -> float:
    return fgd_normal(w1, xs, alpha, e / eta_n, 0.0) - target


@njit(cache=True)
def fgd_root(w1, xs, alpha, target, eta_n, a, b, xtol) -> float:
    """Absolute index ``e`` in [a, b] with ``FGD(alpha, e / eta_n) = target`` (Brent's method; the
    caller guarantees a sign change). NaN if there is none."""
    fa = _fgd_minus(w1, xs, alpha, target, eta_n, a)
    fb = _fgd_minus(w1, xs, alpha, target, eta_n, b)
    if fa == 0.0:
        return a
    if fb == 0.0:
        return b
    if (fa > 0.0) == (fb > 0.0):
        return math.nan
    c, fc = a, fa
    d = e = b - a
    for _ in range(200):
        if (fb > 0.0) == (fc > 0.0):
            c, fc = a, fa
            d = e = b - a
        if abs(fc) < abs(fb):
            a, b, c = b, c, b
            fa, fb, fc = fb, fc, fb
        tol1 = 2.0 * 2.2e-16 * abs(b) + 0.5 * xtol
        xm = 0.5 * (c - b)
        if abs(xm) <= tol1 or fb == 0.0:
            return b
        if abs(e) >= tol1 and abs(fa) > abs(fb):
            s_ = fb / fa
            if a == c:
                p_ = 2.0 * xm * s_
                q_ = 1.0 - s_
            else:
                q_ = fa / fc
                r_ = fb / fc
                p_ = s_ * (2.0 * xm * q_ * (q_ - r_) - (b - a) * (r_ - 1.0))
                q_ = (q_ - 1.0) * (r_ - 1.0) * (s_ - 1.0)
            if p_ > 0.0:
                q_ = -q_
            p_ = abs(p_)
            if 2.0 * p_ < min(3.0 * xm * q_ - abs(tol1 * q_), abs(e * q_)):
                e = d
                d = p_ / q_
            else:
                d = xm
                e = d
        else:
            d = xm
            e = d
        a, fa = b, fb
        if abs(d) > tol1:
            b += d
        else:
            b += tol1 if xm > 0.0 else -tol1
        fb = _fgd_minus(w1, xs, alpha, target, eta_n, b)
    return b


# ============================================================================ context kernels

# rows of the context state (per channel)
_R0, _T0, _RI, _TI, _VR0, _VT0, _VRI, _VTI = range(8)
# scalars: J0n, Jn0, eta_n (absolute index of the current medium)
_J0, _JI, _ETA = range(3)


@njit(cache=True)
def _add_interface(st, sc, w1, xs, alpha, eta_abs, kappa_abs, conductor, out_e, out_v) -> None:
    """Add one interface below the context (in place): belcour2018.md section 6 at c = 1 with
    per-channel statistics, no TIR, normal-incidence transmission scales (eq. 6). ``out_e`` and
    ``out_v`` receive the energy and variance of this interface's lobe."""
    eta_cur = sc[_ETA]
    n = eta_abs[0] / eta_cur
    vr = roughness_to_variance(alpha)
    vtd = 0.0
    vtu = 0.0
    jd = 1.0
    ju = 1.0
    if not conductor:
        vtd = roughness_to_variance(alpha * 0.5 * abs(n - 1.0) / n)
        vtu = roughness_to_variance(alpha * 0.5 * abs(1.0 - n))
        jd = n
        ju = 1.0 / n
    r = np.empty(3)
    prev_at = -1.0
    for ch in range(3):
        at = variance_to_roughness(st[_VT0, ch] + vr) if st[_VT0, ch] > 0.0 else alpha
        e = eta_abs[ch] / eta_cur
        k = kappa_abs[ch] / eta_cur
        if ch > 0 and at == prev_at and eta_abs[ch] == eta_abs[ch - 1] and kappa_abs[ch] == kappa_abs[ch - 1]:
            r[ch] = r[ch - 1]
        else:
            r[ch] = fgd_normal(w1, xs, at, e, k)
        prev_at = at
    for ch in range(3):
        rdn = r[ch]
        if conductor:
            tdn = 0.0
            rup = 0.0
            tup = 0.0
        else:
            tdn = 1.0 - rdn
            rup = rdn
            tup = 1.0 - rdn
        d = 1.0 - st[_RI, ch] * rdn
        if d > 0.0:
            inv = 1.0 / d
            e_k = st[_T0, ch] * rdn * st[_TI, ch] * inv
            rup2 = tup * st[_RI, ch] * tdn * inv
            m = st[_RI, ch] * rdn * inv
        else:
            inv = 0.0
            e_k = 0.0
            rup2 = 0.0
            m = 0.0
        v_k = st[_VTI, ch] + sc[_J0] * (st[_VT0, ch] + vr + m * (vr + st[_VRI, ch]))
        out_e[ch] = e_k
        out_v[ch] = v_k
        wsum = st[_R0, ch] + e_k
        new_vr0 = (st[_R0, ch] * st[_VR0, ch] + e_k * v_k) / wsum if wsum > 0.0 else 0.0
        new_vt0 = jd * st[_VT0, ch] + vtd + jd * (vr + st[_VRI, ch]) * m
        wsum = rup + rup2
        new_vri = ((rup * vr + rup2 * (vtd + jd * (vtu + st[_VRI, ch] + m * (vr + st[_VRI, ch])))) / wsum
                   if wsum > 0.0 else 0.0)
        new_vti = sc[_JI] * vtu + st[_VTI, ch] + sc[_JI] * (vr + st[_VRI, ch]) * m
        st[_R0, ch] = st[_R0, ch] + e_k
        st[_T0, ch] = st[_T0, ch] * tdn * inv
        st[_RI, ch] = rup + rup2
        st[_TI, ch] = tup * st[_TI, ch] * inv
        st[_VR0, ch] = new_vr0
        st[_VT0, ch] = new_vt0
        st[_VRI, ch] = new_vri
        st[_VTI, ch] = new_vti
    sc[_J0] *= jd
    sc[_JI] *= ju
    if not conductor:
        sc[_ETA] = eta_abs[0]


@njit(cache=True)
def _add_medium(st, tau) -> None:
    """Add an absorbing medium of optical depth ``tau`` (RGB) below the context (in place), as the
    forward model's medium entry at c = 1 (no lobe, variances unchanged)."""
    for ch in range(3):
        t = math.exp(-tau[ch])
        r0 = st[_R0, ch]
        st[_VR0, ch] = (r0 * st[_VR0, ch]) / r0 if r0 > 0.0 else 0.0
        rup2 = t * st[_RI, ch] * t
        st[_VRI, ch] = (rup2 * st[_VRI, ch]) / rup2 if rup2 > 0.0 else 0.0
        st[_T0, ch] = st[_T0, ch] * t
        st[_RI, ch] = rup2
        st[_TI, ch] = t * st[_TI, ch]


@njit(cache=True)
def _eq18(rk, t0, ti, ri) -> float:
    """Eq. 18: R'_{n,n+l} = 1 / (T_0n T_n0 / R_k + R_n0) (R'_{n,n+l} = R_k for an empty stack)."""
    if rk <= 0.0:
        return 0.0
    return 1.0 / (t0 * ti / rk + ri)


@njit(cache=True)
def _eq19(sigma, rp, ri, vti, vt0, vri, j0) -> float:
    """Eq. 19: sigma^R_{n,n+l} = (1 - R_n0 R') ((sigma_k - sigma^T_n0) / J_0n - sigma^T_0n) - R_n0 R' sigma^R_n0,
    with J_0n = eta_n / eta_0 at normal incidence."""
    q = ri * rp
    return (1.0 - q) * ((sigma - vti) / j0 - vt0) - q * vri


@njit(cache=True)
def _combine_sigma(per, q, j0, minimax, ch, use) -> float:
    """One achromatic sigma_R from the per-channel solutions ``per`` of eq. 19 (choice 3): the
    value of channel ``ch`` (paper, 5.2.3), or -- ``minimax`` -- the value minimising the largest
    error ``max_c |v_c(s) - sigma|`` of the forward variances, which are affine in s with slopes
    ``J (1 + m_c) = J / (1 - q_c)``, ``q_c = R_n0 R'`` (channels with ``use[c]`` False ignored)."""
    if not minimax:
        return per[ch]
    best = per[ch]
    best_err = 1e300
    for a in range(3):
        if not use[a]:
            continue
        for b in range(3):
            if not use[b]:
                continue
            sa = j0 / max(1.0 - q[a], 1e-300)
            sb = j0 / max(1.0 - q[b], 1e-300)
            s = (per[a] * sa + per[b] * sb) / (sa + sb)
            err = 0.0
            for c in range(3):
                if use[c]:
                    err = max(err, abs(s - per[c]) * j0 / max(1.0 - q[c], 1e-300))
            if err < best_err:
                best_err = err
                best = s
    return best


@njit(cache=True)
def _channel_sigma_r(st, sc, rp, sigma, ch) -> float:
    return _eq19(sigma, rp[ch], st[_RI, ch], st[_VTI, ch], st[_VT0, ch], st[_VRI, ch], sc[_J0])


@njit(cache=True)
def _two_layer_eval(st, sc, w1, xs, rk, sigma, eta1, eta_max, conductor, exact, ch_top, vr_top_paper,
                    minimax, st1, sc1, sub, bot) -> int:
    """The 2-layer predicate at ``eta1`` (alg. 1 / alg. 5 up to N2).

    ``st, sc``: context at the lobe's top (medium tau0 included). Writes the context below the
    first interface into ``st1, sc1``; ``sub = (E1 rgb, v1 rgb, sigma_R1)`` the first interface's
    lobe; ``bot = (R'_b rgb, sigma_R2, alpha~2 rgb, alpha2)`` the second interface's target.
    Returns OK or a FAIL_* code.
    """
    zero = np.zeros(3)
    eta = np.full(3, eta1)
    e1 = np.empty(3)
    v1 = np.empty(3)
    vr = vr_top_paper
    if vr < 0.0:
        return FAIL_TOP_VARIANCE
    use = np.ones(3, dtype=np.bool_)
    if exact and st[_RI, ch_top] > 0.0:
        # choice 2: eq. 19 with the first interface's own R' (fixed point; R' depends on alpha via FGD)
        per = np.empty(3)
        q = np.empty(3)
        for it in range(50):
            for c in range(3):
                at = variance_to_roughness(st[_VT0, c] + vr) if st[_VT0, c] > 0.0 else variance_to_roughness(vr)
                r1 = fgd_normal(w1, xs, at, eta1 / sc[_ETA], 0.0)
                per[c] = _eq19(sigma, r1, st[_RI, c], st[_VTI, c], st[_VT0, c], st[_VRI, c], sc[_J0])
                q[c] = st[_RI, c] * r1
            vr_new = _combine_sigma(per, q, sc[_J0], minimax, ch_top, use)
            if vr_new < 0.0:
                return FAIL_TOP_VARIANCE
            done = abs(vr_new - vr) <= 1e-15 * max(1.0, vr)
            vr = vr_new
            if done:
                break
    st1[:, :] = st
    sc1[:] = sc
    _add_interface(st1, sc1, w1, xs, variance_to_roughness(vr), eta, zero, False, e1, v1)
    for ch in range(3):
        sub[ch] = e1[ch]
        sub[3 + ch] = v1[ch]
    sub[6] = vr
    # eq. 20: the second interface's target energy, then eq. 18 below the first interface
    rb = np.empty(3)
    for ch in range(3):
        rbar = rk[ch] - e1[ch]
        if rbar <= 0.0:
            return FAIL_TOP_ENERGY
        rb[ch] = _eq18(rbar, st1[_T0, ch], st1[_TI, ch], st1[_RI, ch])
        bot[ch] = rb[ch]
        if rb[ch] >= 1.0:
            return FAIL_BOTTOM_ENERGY
    cb = 0
    for ch in range(1, 3):
        if rb[ch] > rb[cb]:
            cb = ch
    per2 = np.empty(3)
    q2 = np.empty(3)
    for c in range(3):
        per2[c] = _channel_sigma_r(st1, sc1, rb, sigma, c)
        q2[c] = st1[_RI, c] * rb[c]
    s2 = _combine_sigma(per2, q2, sc1[_J0], minimax, cb, use)
    bot[3] = s2
    if s2 < 0.0:
        return FAIL_BOTTOM_VARIANCE
    a2 = variance_to_roughness(s2)
    bot[7] = a2
    for ch in range(3):
        bot[4 + ch] = variance_to_roughness(st1[_VT0, ch] + s2) if st1[_VT0, ch] > 0.0 else a2
    if conductor:
        for ch in range(3):
            if rb[ch] >= albedo_normal(w1, bot[4 + ch]):
                return FAIL_CONDUCTOR
        return OK
    # N2 non-empty: the extreme eta2 (1 or eta_max) works for every channel (FGD grows away from eta1)
    for e2 in (1.0, eta_max):
        good = True
        for ch in range(3):
            if fgd_normal(w1, xs, bot[4 + ch], e2 / eta1, 0.0) < rb[ch]:
                good = False
                break
        if good:
            return OK
    return FAIL_NO_ETA2


@njit(cache=True)
def _two_layer_scan(st, sc, w1, xs, rk, sigma, etas, eta_max, conductor, exact, ch_top, vr_top_paper, minimax,
                    status):
    """:func:`_two_layer_eval` at every ``etas[i]`` (statuses into ``status``)."""
    st1 = np.empty_like(st)
    sc1 = np.empty_like(sc)
    sub = np.empty(7)
    bot = np.empty(8)
    for i in range(etas.shape[0]):
        status[i] = _two_layer_eval(st, sc, w1, xs, rk, sigma, etas[i], eta_max, conductor, exact, ch_top,
                                    vr_top_paper, minimax, st1, sc1, sub, bot)


# ============================================================================ context (python side)

@dataclass(frozen=True)
class SubLobe:
    """The forward model's lobe of one interface, as the inverse predicts it (RGB energy, variance)."""

    energy: np.ndarray
    variance: np.ndarray


@dataclass(frozen=True)
class Context:
    """Statistics at normal incidence of the stack above the current medium (alg. 3, Belcour 2018).

    ``state`` rows: R_0n, T_0n, R_n0, T_n0 (energies) and sigma^R_0n, sigma^T_0n, sigma^R_n0,
    sigma^T_n0 (variances), per channel; ``J0``/``Ji`` the variance Jacobians (J_0n = eta_n/eta_0),
    ``eta`` the absolute index of the current medium; ``interfaces`` how many interfaces are above;
    ``absorbing``: whether a medium may be put above the next interface (False only at the top of a
    stack in air, where no layer holds it).
    """

    state: np.ndarray
    scalars: np.ndarray
    interfaces: int = 0
    absorbing: bool = False
    options: InverseOptions = field(default_factory=InverseOptions)

    @classmethod
    def ambient(cls, eta0: float = 1.0, absorbing: bool | None = None,
                options: InverseOptions | None = None) -> "Context":
        """An empty stack in a medium of index ``eta0`` (section 5: a single lobe in medium eta0).
        ``absorbing`` (default: ``eta0 != 1``) allows a coloured ``tau0`` above the lobe."""
        if not (math.isfinite(eta0) and eta0 > 0.0):
            raise InverseError(f"eta0: must be > 0, got {eta0!r}")
        st = np.zeros((8, 3))
        st[_T0] = 1.0
        st[_TI] = 1.0
        sc = np.array([1.0, 1.0, float(eta0)])
        return cls(st, sc, 0, bool(eta0 != 1.0) if absorbing is None else bool(absorbing),
                   options if options is not None else InverseOptions())

    @property
    def eta(self) -> float:
        return float(self.scalars[_ETA])

    def row(self, r: int) -> np.ndarray:
        return self.state[r].copy()

    @property
    def R0n(self) -> np.ndarray:
        return self.row(_R0)

    @property
    def T0n(self) -> np.ndarray:
        return self.row(_T0)

    @property
    def Rn0(self) -> np.ndarray:
        return self.row(_RI)

    @property
    def Tn0(self) -> np.ndarray:
        return self.row(_TI)

    @property
    def vT0n(self) -> np.ndarray:
        return self.row(_VT0)

    @property
    def vTn0(self) -> np.ndarray:
        return self.row(_VTI)

    @property
    def vRn0(self) -> np.ndarray:
        return self.row(_VRI)

    @property
    def J0n(self) -> float:
        return float(self.scalars[_J0])

    def with_medium(self, tau: Any) -> "Context":
        """The context after an absorbing medium of optical depth ``tau`` (RGB)."""
        t = tau if isinstance(tau, np.ndarray) and tau.shape == (3,) else _rgb(tau, "tau")
        if t.min() < 0.0:
            raise InverseError(f"tau: must be >= 0, got {_fmt_rgb(t)}")
        if not t.max() > 0.0:
            return self
        if not self.absorbing:
            raise InverseError("tau: no medium can lie above the top interface of a stack in air")
        st = self.state.copy()
        _add_medium(st, t)
        return replace(self, state=st)

    def with_interface(self, alpha: float, eta: Any, kappa: Any = 0.0) -> tuple["Context", SubLobe]:
        """The context below one more interface (roughness ``alpha``, absolute index ``eta + i kappa``
        of the medium below; kappa > 0 = conductor) and that interface's lobe."""
        w1, xs = kernel_for(self.options)
        e = _rgb(eta, "eta")
        k = _rgb(kappa, "kappa")
        conductor = bool(np.any(k > 0.0))
        st = self.state.copy()
        sc = self.scalars.copy()
        out_e = np.empty(3)
        out_v = np.empty(3)
        _add_interface(st, sc, w1, xs, float(alpha), e, k, conductor, out_e, out_v)
        return replace(self, state=st, scalars=sc, interfaces=self.interfaces + 1, absorbing=True), \
            SubLobe(out_e, out_v)

    def r_prime(self, R: Any) -> np.ndarray:
        """Eq. 18 per channel: the reflectance the layers below must have, as seen in the current
        medium, for a lobe of energy ``R`` outside (``R`` itself for an empty stack)."""
        r = _rgb(R, "R")
        return np.array([_eq18(r[c], self.state[_T0, c], self.state[_TI, c], self.state[_RI, c]) for c in range(3)])

    def sigma_r(self, R_prime: Any, sigma: float) -> np.ndarray:
        """Eq. 19 per channel: the variance sigma^R_{n,n+l} the layers below must have."""
        rp = _rgb(R_prime, "R'")
        return np.array([_channel_sigma_r(self.state, self.scalars, rp, float(sigma), c) for c in range(3)])

    def base_stats(self, R: Any, sigma: float) -> tuple[np.ndarray, np.ndarray]:
        """Algorithm 3: ``(R'_{n,n+l}, sigma^R_{n,n+l})`` per channel (eqs. 18 and 19)."""
        rp = self.r_prime(R)
        return rp, self.sigma_r(rp, sigma)

    def sigma_min(self, R_prime: Any) -> np.ndarray:
        """The smallest lobe variance reachable below this context (eq. 19 with sigma_R = 0), per channel."""
        rp = _rgb(R_prime, "R'")
        ri, vti, vt0, vri = self.state[_RI], self.state[_VTI], self.state[_VT0], self.state[_VRI]
        q = ri * rp
        with np.errstate(divide="ignore", invalid="ignore"):
            return vti + self.J0n * (vt0 + np.where(q < 1.0, q / (1.0 - q), np.inf) * vri)


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
    return float(_eq19(sigma_k, Rp, Rn0, vTn0, vT0n, vRn0, J0n))


def _sigma_condition(x: float, alpha1: float, sigma02: float) -> float:
    return (sigma02 - roughness_to_variance(0.5 * abs(x - 1.0) * alpha1)) / x \
        - roughness_to_variance(0.5 * abs(1.0 - 1.0 / x) * alpha1)


def eta_sigma_max(alpha1: float, eta0: float = 1.0) -> float:
    """The ``eta1 <= eta_sigma_max`` approximation of V (section 5.2.2; choice 4 of the module
    docstring): the root in ``x = eta1/eta0 > 1`` of eq. 15 without its inter-reflection terms,
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


# ============================================================================ picks

@dataclass(frozen=True)
class Pick:
    """Which point of a lobe's equivalence class to take (every field optional; None = default,
    choice 6 of the module docstring).

    * ``u1`` / ``eta1``: the first index -- position in [0, 1] along N1 (2-layer) or along the
      conductor class (1-layer conductor; scalar or RGB), or along the chosen root's branch from
      its ``tau = 0`` end (1-layer dielectric; default 0); or the absolute index itself (RGB for
      a conductor).
    * ``root``: 1-layer dielectric, ``"upper"`` (eta1 > eta_n) or ``"lower"``.
    * ``u2`` / ``eta2``: 2-layer lobes, the second index: position in N2 (dielectric) or in the
      conductor class (scalar or RGB), or the absolute index (RGB for a conductor).
    * ``tau0``: optical depth (scalar or RGB) of a medium above the lobe's first interface
      (2-layer lobes and conductors; for 1-layer dielectrics it follows from eta1).
    * ``tau1``: 2-layer conductor lobes, optical depth between the two interfaces (for a 2-layer
      dielectric it follows from eta2, eq. 13).
    """

    u1: float | RGB | None = None
    eta1: float | RGB | None = None
    root: str | None = None
    u2: float | RGB | None = None
    eta2: float | RGB | None = None
    tau0: float | RGB | None = None
    tau1: float | RGB | None = None

    def __post_init__(self) -> None:
        for name in ("u1", "u2"):
            v = getattr(self, name)
            if v is not None:
                a = _rgb(v, name)
                if np.any(a < 0.0) or np.any(a > 1.0):
                    raise InverseError(f"{name}: a position in a class is in [0, 1], got {v!r}")
        for name in ("eta1", "eta2"):
            v = getattr(self, name)
            if v is not None and np.any(_rgb(v, name) <= 0.0):
                raise InverseError(f"{name}: an index must be > 0, got {v!r}")
        for name in ("tau0", "tau1"):
            v = getattr(self, name)
            if v is not None and np.any(_rgb(v, name) < 0.0):
                raise InverseError(f"{name}: an optical depth must be >= 0, got {v!r}")
        if self.root is not None and self.root not in ("upper", "lower"):
            raise InverseError(f"root: {self.root!r} is not one of upper, lower")
        if self.u1 is not None and self.eta1 is not None:
            raise InverseError("give either u1 or eta1, not both")
        if self.u2 is not None and self.eta2 is not None:
            raise InverseError("give either u2 or eta2, not both")

    @property
    def is_default(self) -> bool:
        return all(getattr(self, f) is None for f in ("u1", "eta1", "root", "u2", "eta2", "tau0", "tau1"))

    def fields(self) -> dict[str, Any]:
        return {k: v for k, v in self.__dict__.items() if v is not None}


PICK_FIELDS = ("u1", "eta1", "root", "u2", "eta2", "tau0", "tau1")


def as_pick(p: Pick | dict | None) -> Pick:
    if p is None:
        return Pick()
    if isinstance(p, Pick):
        return p
    if isinstance(p, dict):
        unknown = sorted(set(p) - set(PICK_FIELDS))
        if unknown:
            raise InverseError(f"pick: unknown choice {unknown[0]!r} (choices: {', '.join(PICK_FIELDS)})")
        return Pick(**p)
    raise InverseError(f"pick: expected a Pick or a dict, got {type(p).__name__}")


def parse_picks(text: str, n_lobes: int) -> list[Pick]:
    """Parse ``--pick``: ``"center"`` (every default) or space-separated ``K.NAME=VALUE`` items,
    ``K`` the 1-based lobe index, ``NAME`` one of :data:`PICK_FIELDS`, ``VALUE`` a number, three
    comma-separated numbers, or upper/lower for ``root`` (e.g. ``"1.eta1=1.6 2.u2=0.2 2.tau1=0,0.3,0"``)."""
    picks: list[dict[str, Any]] = [dict() for _ in range(n_lobes)]
    text = text.strip()
    if text in ("", "center", "centre", "default"):
        return [Pick() for _ in range(n_lobes)]
    for token in text.replace(";", " ").split():
        m = re.fullmatch(r"(\d+)\.([a-z0-9_]+)=(.+)", token)
        if not m:
            raise InverseError(f"--pick: {token!r} is not K.NAME=VALUE (e.g. 1.eta1=1.6, 2.u2=0.3, 2.tau1=0,0.3,0)")
        k, name, value = int(m.group(1)), m.group(2), m.group(3)
        if not 1 <= k <= n_lobes:
            raise InverseError(f"--pick: {token!r}: lobe {k} does not exist (there are {n_lobes})")
        if name not in PICK_FIELDS:
            raise InverseError(f"--pick: {token!r}: unknown choice {name!r} (choices: {', '.join(PICK_FIELDS)})")
        if name in picks[k - 1]:
            raise InverseError(f"--pick: {k}.{name} given twice")
        if name == "root":
            picks[k - 1][name] = value
            continue
        try:
            nums = [float(x) for x in value.split(",")]
        except ValueError:
            raise InverseError(f"--pick: {token!r}: {value!r} is not a number or three numbers") from None
        if len(nums) not in (1, 3):
            raise InverseError(f"--pick: {token!r}: expected one or three numbers")
        picks[k - 1][name] = nums[0] if len(nums) == 1 else tuple(nums)
    out = []
    for k, d in enumerate(picks):
        try:
            out.append(Pick(**d))
        except InverseError as e:
            raise InverseError(f"--pick: lobe {k + 1}: {e}") from None
    return out


# ============================================================================ helpers

def _fmt_rgb(a: Any) -> str:
    a = np.atleast_1d(np.asarray(a, dtype=float))
    if a.size == 3 and np.ptp(a) == 0.0:
        return f"{a[0]:.4g}"
    return "[" + ", ".join(f"{x:.4g}" for x in a) + "]"


def _bisect(pred, good: float, bad: float, tol: float = ETA_TOL) -> float:
    """The boundary between ``good`` (pred True) and ``bad`` (pred False), returned on the good side."""
    for _ in range(200):
        if abs(bad - good) <= tol:
            break
        mid = 0.5 * (good + bad)
        if pred(mid):
            good = mid
        else:
            bad = mid
    return good


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Maximal runs [i, j] (inclusive) of True in a boolean array."""
    out = []
    i = 0
    n = mask.shape[0]
    while i < n:
        if mask[i]:
            j = i
            while j + 1 < n and mask[j + 1]:
                j += 1
            out.append((i, j))
            i = j + 1
        else:
            i += 1
    return out


@dataclass(frozen=True)
class Interval:
    lo: float
    hi: float

    @property
    def length(self) -> float:
        return self.hi - self.lo

    def contains(self, x: float, tol: float = 1e-9) -> bool:
        return self.lo - tol <= x <= self.hi + tol

    def to_list(self) -> list[float]:
        return [self.lo, self.hi]


def _position(intervals: Sequence[Interval], u: float) -> float:
    """The point at fraction ``u`` of the total length of a union of disjoint sorted intervals."""
    total = sum(iv.length for iv in intervals)
    if total <= 0.0:
        return intervals[0].lo
    target = u * total
    for iv in intervals:
        if target <= iv.length or iv is intervals[-1]:
            return min(iv.lo + target, iv.hi)
        target -= iv.length
    return intervals[-1].hi  # pragma: no cover


def _fraction(intervals: Sequence[Interval], x: float) -> float:
    """Inverse of :func:`_position` (the position of ``x``; NaN if outside)."""
    total = sum(iv.length for iv in intervals)
    acc = 0.0
    for iv in intervals:
        if iv.contains(x):
            return (acc + min(max(x - iv.lo, 0.0), iv.length)) / total if total > 0 else 0.0
        acc += iv.length
    return float("nan")


def _fgd(options: InverseOptions, alpha: float, eta_rel: float, kappa_rel: float = 0.0) -> float:
    w1, xs = kernel_for(options)
    return float(fgd_normal(w1, xs, float(alpha), float(eta_rel), float(kappa_rel)))


def _albedo(options: InverseOptions, alpha: float) -> float:
    w1, _ = kernel_for(options)
    return float(albedo_normal(w1, float(alpha)))


def _dielectric_roots(options: InverseOptions, alpha: float, target: float, eta_n: float,
                      lo_bound: float, hi_bound: float) -> tuple[float | None, float | None]:
    """Absolute ``eta`` with ``FGD(alpha, eta / eta_n) = target`` below and above ``eta_n`` within
    [lo_bound, hi_bound] (None where FGD never reaches the target there). FGD grows monotonically
    away from ``eta = eta_n`` on both sides (verified over the alpha nodes in the tests)."""
    if target <= 0.0:
        return eta_n, eta_n
    if alpha <= 0.0:
        lo_r, hi_r = eq7_roots(target, eta_n)
        lo = lo_r if lo_r >= lo_bound else None
        hi = hi_r if hi_r <= hi_bound else None
        return lo, hi
    w1, xs = kernel_for(options)
    lo = hi = None
    if hi_bound > eta_n and _fgd_minus(w1, xs, alpha, target, eta_n, hi_bound) >= 0.0:
        hi = float(fgd_root(w1, xs, alpha, target, eta_n, eta_n, hi_bound, 1e-13))
    if lo_bound < eta_n and _fgd_minus(w1, xs, alpha, target, eta_n, lo_bound) >= 0.0:
        lo = float(fgd_root(w1, xs, alpha, target, eta_n, lo_bound, eta_n, 1e-13))
    return lo, hi


def _variance_channel(rp: np.ndarray) -> int:
    return int(np.argmax(rp))


def _scalar_sigma_r(ctx: Context, rp: np.ndarray, sigma: float, options: InverseOptions) -> tuple[float, int]:
    """The achromatic sigma_R of an interface below ``ctx`` (choice 3): eq. 19 on the channel of
    maximal R' ("max"), or the value minimising the largest relative error ("minimax")."""
    ch = _variance_channel(rp)
    per = ctx.sigma_r(rp, sigma)
    q = ctx.state[_RI] * rp
    s = _combine_sigma(per, q, ctx.J0n, options.variance_channel == "minimax", ch, np.ones(3, dtype=np.bool_))
    return float(s), ch


# ============================================================================ classes and solutions

@dataclass(frozen=True)
class Layer:
    """One layer of the paper's stack S (alg. 4): optical depth ``tau`` (RGB) of the medium above
    the interface, its GGX roughness ``alpha``, and the absolute index ``eta + i kappa`` (RGB) of
    the medium below it."""

    tau: np.ndarray
    alpha: float
    eta: np.ndarray
    kappa: np.ndarray

    @property
    def conductor(self) -> bool:
        return bool(np.any(self.kappa > 0.0))

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"tau": self.tau.tolist(), "alpha": self.alpha}
        if self.conductor:
            d["eta"] = self.eta.tolist()
            d["kappa"] = self.kappa.tolist()
        else:
            d["eta"] = float(self.eta[0])
        return d


def inherent_variance_spread(sublobes: Sequence["SubLobe"], sigma: float) -> float:
    """The smallest worst-channel relative variance error any achromatic roughness could give these
    sub-lobes (choice 3): each sub-lobe's forward variance is ``v_c(s) = sigma + slope_c (s - s_c)``
    with slopes ``J (1 + m_c)`` that differ by the small m_c only, so its minimax error is half the
    spread of its channel variances (to a relative O(m)); the lobe's (energy-weighted) error is at
    most the largest over its sub-lobes. 0 for a smooth lobe."""
    if sigma <= 0.0:
        return 0.0
    return max(float(np.ptp(s.variance)) / (2.0 * sigma) for s in sublobes)


@dataclass
class LobeSolution:
    """One chosen point of a lobe's class: its layers, the context below them, the inverse's
    prediction of its sub-lobes (one per interface), and the resolved choices."""

    layers: list[Layer]
    context: Context
    sublobes: list[SubLobe]
    choices: dict[str, Any]
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def energy(self) -> np.ndarray:
        return np.sum([s.energy for s in self.sublobes], axis=0)

    def variance_spread(self, sigma: float) -> float:
        """:func:`inherent_variance_spread` of this lobe's sub-lobes."""
        return inherent_variance_spread(self.sublobes, sigma)

    @property
    def variance(self) -> np.ndarray:
        e = np.array([s.energy for s in self.sublobes])
        v = np.array([s.variance for s in self.sublobes])
        tot = e.sum(axis=0)
        return np.where(tot > 0, (e * v).sum(axis=0) / np.where(tot > 0, tot, 1.0), 0.0)


class PickError(InverseError):
    """An explicit pick lies outside its class."""


@dataclass
class LobeClass:
    """Equivalence class of one lobe in a context (base class).

    ``achievable`` and ``reason``; ``bounds`` (name -> intervals or values, JSON-friendly);
    :meth:`sample` returns the sampled class as arrays; :meth:`pick` a :class:`LobeSolution`.
    """

    kind: str
    lobe: Lobe
    context: Context
    achievable: bool
    reason: str | None
    bounds: dict[str, Any]

    def pick(self, pick: Pick | dict | None = None) -> LobeSolution:  # pragma: no cover - abstract
        raise NotImplementedError

    def sample(self, n: int = 64) -> dict[str, np.ndarray]:  # pragma: no cover - abstract
        raise NotImplementedError

    def _require(self) -> None:
        if not self.achievable:
            raise NotAchievable(self.reason or "empty class")

    def summary(self) -> dict[str, Any]:
        return {"kind": self.kind, "achievable": self.achievable, "reason": self.reason,
                "bounds": _jsonable(self.bounds)}


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, Interval):
        return x.to_list()
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if math.isfinite(v) else (None if math.isnan(v) else ("inf" if v > 0 else "-inf"))
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.bool_,)):
        return bool(x)
    return x


# ---------------------------------------------------------------------------- 1-layer dielectric

@dataclass
class OneLayerDielectricClass(LobeClass):
    """Section 5.1.1 / alg. 4: ``eta1`` on the upper (``eta1 > eta_n``) and/or lower branch; on each
    branch ``tau0`` grows from 0 (max channel) at the root to the branch's far end."""

    alpha: float = 0.0
    alpha_lookup: np.ndarray = field(default_factory=lambda: np.zeros(3))
    r_prime: np.ndarray = field(default_factory=lambda: np.zeros(3))
    sigma_r: float = 0.0
    branches: dict[str, Interval] = field(default_factory=dict)

    def tau_at(self, eta1: float) -> np.ndarray:
        r = np.array([_fgd(self.context.options, a, eta1 / self.context.eta) for a in self.alpha_lookup])
        with np.errstate(divide="ignore"):
            t = 0.5 * np.log(r / self.r_prime)
        return np.where(np.abs(t) < 1e-12, 0.0, t)

    def _branch_eta(self, name: str, u: float) -> float:
        iv = self.branches[name]
        # u = 0 is the tau = 0 root end of the branch
        return iv.lo + u * iv.length if name == "upper" else iv.hi - u * iv.length

    def pick(self, pick: Pick | dict | None = None) -> LobeSolution:
        self._require()
        p = as_pick(pick)
        for bad in ("u2", "eta2", "tau1", "tau0"):
            if getattr(p, bad) is not None:
                what = "follows from eta1 (alg. 4)" if bad == "tau0" else "is for 2-layer lobes"
                raise PickError(f"{bad}: not a choice of a 1-layer dielectric lobe ({what})")
        if p.eta1 is not None:
            e = _rgb(p.eta1, "eta1")
            if np.ptp(e) != 0.0:
                raise PickError("eta1: a dielectric index is achromatic")
            eta1 = float(e[0])
            name = next((k for k, iv in self.branches.items() if iv.contains(eta1)), None)
            if name is None:
                raise PickError(f"eta1={eta1:g} is outside the class ({self._branch_text()})")
        else:
            name = p.root or ("upper" if "upper" in self.branches else "lower")
            if name not in self.branches:
                raise PickError(f"root={name}: that branch is empty ({self._branch_text()})")
            u = 0.0 if p.u1 is None else float(_rgb(p.u1, "u1")[0])
            if not self.context.absorbing and u > 0.0:
                raise PickError("u1 > 0 needs a medium above the interface, and the top of the stack has none")
            eta1 = self._branch_eta(name, u)
        tau = np.maximum(self.tau_at(eta1), 0.0) if self.context.absorbing else np.zeros(3)
        ctx = self.context.with_medium(tau) if np.any(tau > 0) else self.context
        ctx2, sub = ctx.with_interface(self.alpha, eta1)
        layer = Layer(tau, self.alpha, np.full(3, eta1), np.zeros(3))
        u_res = (eta1 - self.branches[name].lo) / self.branches[name].length if self.branches[name].length > 0 else 0.0
        if name == "lower":
            u_res = 1.0 - u_res
        return LobeSolution([layer], ctx2, [sub], {"root": name, "u1": u_res, "eta1": eta1, "tau0": tau.tolist()},
                            {"alpha": self.alpha, "r_prime": self.r_prime.tolist(), "sigma_r": self.sigma_r})

    def _branch_text(self) -> str:
        return ", ".join(f"{k}: [{iv.lo:.6g}, {iv.hi:.6g}]" for k, iv in self.branches.items()) or "empty"

    def sample(self, n: int = 64) -> dict[str, np.ndarray]:
        """``eta1`` samples on each branch (a single point per branch at the top of a stack in air)
        with their ``tau0`` (RGB)."""
        if not self.achievable:
            return {"eta1": np.zeros(0), "tau0": np.zeros((0, 3)), "branch": np.zeros(0, dtype=int)}
        etas, taus, br = [], [], []
        for b, (name, iv) in enumerate(self.branches.items()):
            us = np.linspace(0.0, 1.0, n) if self.context.absorbing else np.zeros(1)
            for u in us:
                e = self._branch_eta(name, float(u))
                etas.append(e)
                taus.append(np.maximum(self.tau_at(e), 0.0))
                br.append(b)
        return {"eta1": np.array(etas), "tau0": np.array(taus), "branch": np.array(br)}


def one_layer_dielectric_class(lobe: Lobe, context: Context | None = None) -> OneLayerDielectricClass:
    """The class of a 1-layer dielectric lobe below ``context`` (section 5.1.1, alg. 3-4)."""
    ctx = context if context is not None else Context.ambient()
    o = ctx.options
    R = lobe.rgb
    bounds: dict[str, Any] = {}
    mk = lambda ok, reason, **kw: OneLayerDielectricClass("dielectric-1", lobe, ctx, ok, reason, bounds, **kw)  # noqa: E731
    if not ctx.absorbing and not lobe.achromatic:
        return mk(False, f"a coloured 1-layer dielectric lobe (R={_fmt_rgb(R)}) needs an absorbing medium above its "
                         "interface (tau0, section 5.1.1), and the top of a stack in air has none: use layers=2")
    rp = ctx.r_prime(R)
    if np.any(rp >= 1.0) or np.any(rp < 0.0):
        return mk(False, _FAIL_TEXT[FAIL_TOP_TARGET] + f" (R'={_fmt_rgb(rp)})")
    sigma_r, ch = _scalar_sigma_r(ctx, rp, lobe.sigma, o)
    bounds["r_prime"] = rp
    bounds["sigma_r"] = sigma_r
    if sigma_r < 0.0:
        smin = ctx.sigma_min(rp)
        return mk(False, f"sigma={lobe.sigma:g} is below the variance the layers above already add "
                         f"(sigma_min={smin[ch]:.4g}, eq. 19 with sigma_R = 0)")
    alpha = variance_to_roughness(sigma_r)
    vt0 = ctx.vT0n
    at = np.array([variance_to_roughness(v + sigma_r) if v > 0 else alpha for v in vt0])
    bounds["alpha"] = alpha
    # roots per channel; the branch is valid where tau >= 0 in every channel (R >= R' in all channels)
    los, his = [], []
    for c in range(3):
        lo, hi = _dielectric_roots(o, at[c], rp[c], ctx.eta, 1.0, o.eta_max)
        los.append(lo)
        his.append(hi)
    branches: dict[str, Interval] = {}
    if all(h is not None for h in his):
        h = max(his)
        if h <= o.eta_max:
            branches["upper"] = Interval(h, o.eta_max if ctx.absorbing else h)
    if all(lv is not None for lv in los) and ctx.eta > 1.0:
        lv = min(los)
        if lv >= 1.0:
            branches["lower"] = Interval(1.0 if ctx.absorbing else lv, lv)
    bounds["eta1"] = {k: v for k, v in branches.items()}
    # the largest energy per channel: eq. 17 with the largest FGD reachable (eta1 = eta_max or 1)
    r_max = np.array([_eq17_scalar(max(_fgd(o, at[c], o.eta_max / ctx.eta), _fgd(o, at[c], 1.0 / ctx.eta)), ctx, c)
                      for c in range(3)])
    bounds["R_max"] = r_max
    if ctx.absorbing:
        bounds["T0"] = [Interval(0.0, 0.5 * math.log(r_max[c] / R[c])) if r_max[c] > R[c] else None
                        for c in range(3)]
    if not branches:
        over = [c for c in range(3) if R[c] > r_max[c] * (1 - 1e-12)]
        which = "" if len(over) in (0, 3) else " in channel(s) " + "".join("RGB"[c] for c in over)
        where = " here (below the layers chosen above)" if ctx.interfaces else ""
        return mk(False, f"R={_fmt_rgb(R)} is above the maximum energy of a 1-layer dielectric lobe with "
                         f"eta <= eta_max={o.eta_max:g}{where}{which} (R_max={_fmt_rgb(r_max)}; eq. 1/7 at eta_max)",
                  alpha=alpha, alpha_lookup=at, r_prime=rp, sigma_r=sigma_r)
    return mk(True, None, alpha=alpha, alpha_lookup=at, r_prime=rp, sigma_r=sigma_r, branches=branches)


def _eq17_scalar(rp: float, ctx: Context, ch: int) -> float:
    st = ctx.state
    return st[_T0, ch] * rp * st[_TI, ch] / (1.0 - rp * st[_RI, ch])


# ---------------------------------------------------------------------------- conductors

def _conductor_point(o: InverseOptions, alpha_lookup: float, target: float, eta_n: float,
                     u: float | None = None, eta: float | None = None) -> tuple[float, float, float] | str:
    """``(eta, kappa, R_F)`` of a conductor below a medium ``eta_n`` with ``FGD(alpha~, .) = target``,
    at position ``u`` of its class (eqs. 8-10 on the Fresnel reflectance ``R_F``; choice 1), or with
    real part ``eta``. Returns a reason string when impossible."""

    def at_rf(rf: float) -> tuple[float, float]:
        b = conductor_eta_bounds(rf, eta_n)
        assert b is not None
        e = b[0] + u * (b[1] - b[0]) if eta is None else eta
        k = eq8_kappa(rf, e, eta_n)
        return e, k

    def g(rf: float) -> float:
        e, k = at_rf(rf)
        if not math.isfinite(k):
            return -1.0
        return _fgd(o, alpha_lookup, e / eta_n, k / eta_n) - target

    if target >= _albedo(o, alpha_lookup):
        return (f"the conductor would need a reflectance {target:.4g} at or above the albedo "
                f"{_albedo(o, alpha_lookup):.4g} of a perfectly reflecting GGX interface of alpha={alpha_lookup:.4g}")
    lo_rf = CONDUCTOR_R_MIN
    if eta is not None:
        # the smallest R_F whose class contains eta: eta <= eta_c_max(R_F) (eq. 9 grows with R_F)
        lo_rf = max(lo_rf, _rf_for_eta_max(eta / eta_n))
    if g(lo_rf) > 0.0:
        return (f"reflectance {target:.4g} is below the darkest conductor (kappa >= eta) "
                f"{'with this eta ' if eta is not None else ''}(R >= 3 - 2 sqrt 2 = {CONDUCTOR_R_MIN:.4f}, eq. 9)")
    hi_rf = 1.0 - 1e-15
    if g(hi_rf) < 0.0:
        return f"reflectance {target:.4g} is not reachable by a rough conductor with alpha={alpha_lookup:.4g}"
    rf = target if alpha_lookup <= 0.0 and lo_rf <= target else optimize.brentq(g, lo_rf, hi_rf, xtol=1e-15, rtol=1e-14)
    e, k = at_rf(rf)
    if eta is not None:
        b = conductor_eta_bounds(rf, eta_n)
        if b is None or not (b[0] - 1e-9 <= eta <= b[1] + 1e-9):
            return (f"eta={eta:g} is outside the conductor class [{b[0]:.6g}, {b[1]:.6g}] for this reflectance "
                    "(eqs. 9-10)" if b else "no conductor")
    return e, k, rf


def _rf_for_eta_max(x: float) -> float:
    """Smallest R with eq9(R) >= x (relative index), i.e. the conductor class reaches eta = x eta_n."""
    if x <= eq9_eta_max(CONDUCTOR_R_MIN):
        return CONDUCTOR_R_MIN
    return optimize.brentq(lambda r: eq9_eta_max(r) - x, CONDUCTOR_R_MIN, 1.0 - 1e-15, xtol=1e-15)


def _default_tau(rp: np.ndarray, absorbing: bool) -> np.ndarray:
    """Choice 6: no absorption unless the conductor would be darker than 3 - 2 sqrt 2; then the
    smallest tau bringing it to CONDUCTOR_R_FLOOR."""
    if not absorbing:
        return np.zeros(3)
    with np.errstate(divide="ignore"):
        return np.where(rp < CONDUCTOR_R_MIN, 0.5 * np.log(CONDUCTOR_R_FLOOR / np.maximum(rp, 1e-300)), 0.0)


@dataclass
class ConductorClass(LobeClass):
    """Section 5.1.2: per channel, ``eta1`` in ``[eta_c_min, eta_c_max]`` (eqs. 9-10) and ``kappa1``
    from eq. 8 (on the Fresnel reflectance giving the FGD target, choice 1), below a medium of
    optical depth ``tau0``."""

    alpha: float = 0.0
    alpha_lookup: np.ndarray = field(default_factory=lambda: np.zeros(3))
    r_prime: np.ndarray = field(default_factory=lambda: np.zeros(3))
    sigma_r: float = 0.0
    tau0: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def targets(self) -> np.ndarray:
        return self.r_prime * np.exp(2.0 * self.tau0)

    def pick(self, pick: Pick | dict | None = None) -> LobeSolution:
        self._require()
        p = as_pick(pick)
        for bad in ("u2", "eta2", "tau1", "root"):
            if getattr(p, bad) is not None:
                raise PickError(f"{bad}: not a choice of a 1-layer conductor lobe")
        if p.tau0 is not None and not np.allclose(_rgb(p.tau0, "tau0"), self.tau0):
            raise PickError("tau0: the class was built for another tau0 (pass it to the class function)")
        u = _rgb(0.5 if p.u1 is None else p.u1, "u1")
        etas = None if p.eta1 is None else _rgb(p.eta1, "eta1")
        eta, kap, rfs = np.empty(3), np.empty(3), np.empty(3)
        tgt = self.targets()
        for c in range(3):
            r = _conductor_point(self.context.options, self.alpha_lookup[c], tgt[c], self.context.eta,
                                 u=float(u[c]), eta=None if etas is None else float(etas[c]))
            if isinstance(r, str):
                raise PickError(f"channel {'RGB'[c]}: {r}")
            eta[c], kap[c], rfs[c] = r
        ctx = self.context.with_medium(self.tau0)
        ctx2, sub = ctx.with_interface(self.alpha, eta, kap)
        layer = Layer(self.tau0.copy(), self.alpha, eta, kap)
        us = []
        for c in range(3):
            b = conductor_eta_bounds(rfs[c], self.context.eta)
            us.append((eta[c] - b[0]) / (b[1] - b[0]) if b and b[1] > b[0] else 0.0)
        return LobeSolution([layer], ctx2, [sub], {"u1": us, "eta1": eta.tolist(), "tau0": self.tau0.tolist()},
                            {"alpha": self.alpha, "kappa1": kap.tolist(), "R_fresnel": rfs.tolist(),
                             "r_prime": self.r_prime.tolist(), "sigma_r": self.sigma_r})

    def sample(self, n: int = 64) -> dict[str, np.ndarray]:
        """Per channel: ``eta1``, ``kappa1`` (n, 3) along the class (u from 0 to 1)."""
        if not self.achievable:
            return {"u": np.zeros(0), "eta1": np.zeros((0, 3)), "kappa1": np.zeros((0, 3))}
        us = np.linspace(0.0, 1.0, n)
        eta = np.full((n, 3), np.nan)
        kap = np.full((n, 3), np.nan)
        tgt = self.targets()
        for c in range(3):
            for i, u in enumerate(us):
                r = _conductor_point(self.context.options, self.alpha_lookup[c], tgt[c], self.context.eta, u=float(u))
                if not isinstance(r, str):
                    eta[i, c], kap[i, c] = r[0], r[1]
        return {"u": us, "eta1": eta, "kappa1": kap}


def conductor_class(lobe: Lobe, context: Context | None = None, tau0: Any = None) -> ConductorClass:
    """The class of a 1-layer conductor lobe below ``context`` (section 5.1.2, alg. 3-4), under a
    medium of optical depth ``tau0`` (default: choice 6)."""
    ctx = context if context is not None else Context.ambient()
    o = ctx.options
    R = lobe.rgb
    bounds: dict[str, Any] = {}
    mk = lambda ok, reason, **kw: ConductorClass("conductor-1", lobe, ctx, ok, reason, bounds, **kw)  # noqa: E731
    rp = ctx.r_prime(R)
    bounds["r_prime"] = rp
    if np.any(rp >= 1.0) or np.any(rp <= 0.0):
        return mk(False, _FAIL_TEXT[FAIL_TOP_TARGET] + f" (R'={_fmt_rgb(rp)})" if np.any(rp >= 1.0)
                  else "a conductor reflects in every channel (R > 0)")
    if tau0 is None:
        t0 = _default_tau(rp, ctx.absorbing)
    else:
        t0 = _rgb(tau0, "tau0")
        if np.any(t0 < 0):
            raise InverseError("tau0: must be >= 0")
        if np.any(t0 > 0) and not ctx.absorbing:
            return mk(False, "tau0 > 0 needs a medium above the interface, and the top of a stack in air has none")
    bounds["tau0"] = t0
    sigma_r, ch = _scalar_sigma_r(ctx, rp, lobe.sigma, o)
    bounds["sigma_r"] = sigma_r
    if sigma_r < 0.0:
        smin = ctx.sigma_min(rp)
        return mk(False, f"sigma={lobe.sigma:g} is below the variance the layers above already add "
                         f"(sigma_min={smin[ch]:.4g}, eq. 19 with sigma_R = 0)")
    alpha = variance_to_roughness(sigma_r)
    at = np.array([variance_to_roughness(v + sigma_r) if v > 0 else alpha for v in ctx.vT0n])
    bounds["alpha"] = alpha
    tgt = rp * np.exp(2.0 * t0)
    bounds["R_conductor"] = tgt
    classes = []
    for c in range(3):
        r = _conductor_point(o, at[c], tgt[c], ctx.eta, u=0.5)
        if isinstance(r, str):
            extra = ""
            if not ctx.absorbing and tgt[c] < CONDUCTOR_R_MIN * 1.05:
                extra = " at the top of a stack in air (no medium above to absorb)"
            return mk(False, f"channel {'RGB'[c]} (R={R[c]:.4g}): {r}{extra}", alpha=alpha, alpha_lookup=at,
                      r_prime=rp, sigma_r=sigma_r, tau0=t0)
        b = conductor_eta_bounds(r[2], ctx.eta)
        classes.append(Interval(*b))
    bounds["eta1"] = classes
    return mk(True, None, alpha=alpha, alpha_lookup=at, r_prime=rp, sigma_r=sigma_r, tau0=t0)


# ---------------------------------------------------------------------------- 2-layer lobes

@dataclass
class TwoLayerPoint:
    """The second-interface problem at one ``eta1`` (alg. 1 inner loop / alg. 5)."""

    status: int
    eta1: float
    alpha1: float
    context1: Context | None
    sub1: SubLobe | None
    r_prime: np.ndarray          # R'_b per channel (eq. 11 / 18)
    sigma_r: float               # sigma_R12 (eq. 15 / 19)
    alpha2: float
    alpha_lookup: np.ndarray     # alpha'_2 per channel
    n2: list[Interval] = field(default_factory=list)


@dataclass
class TwoLayerClass(LobeClass):
    """Section 5.2 / alg. 1 (top lobe) and alg. 5 (stacked): ``eta1 in N1`` (eq. 12), then
    ``eta2 in N2(eta1)`` (eq. 14, dielectric base) with ``tau1`` from eq. 13, or a conductor base of
    equivalent index (5.2.4) with ``tau1`` free and the complex index on its class."""

    conductor: bool = False
    tau0: np.ndarray = field(default_factory=lambda: np.zeros(3))
    n1: list[Interval] = field(default_factory=list)
    eta_sigma_max: float = math.inf
    ch_top: int = 0
    vr_top_paper: float = 0.0
    top_context: Context | None = None
    scan_status: dict[int, int] = field(default_factory=dict)

    # ---- the inner problem at one eta1
    def at(self, eta1: float) -> TwoLayerPoint:
        ctx = self.top_context
        assert ctx is not None
        o = ctx.options
        w1, xs = kernel_for(o)
        st1 = np.empty_like(ctx.state)
        sc1 = np.empty_like(ctx.scalars)
        sub = np.empty(7)
        bot = np.full(8, np.nan)
        status = _two_layer_eval(ctx.state, ctx.scalars, w1, xs, self.lobe.rgb, self.lobe.sigma, float(eta1),
                                 o.eta_max, self.conductor, o.top_variance == "exact", self.ch_top,
                                 self.vr_top_paper, o.variance_channel == "minimax", st1, sc1, sub, bot)
        if status in (FAIL_TOP_VARIANCE,):
            return TwoLayerPoint(status, eta1, float("nan"), None, None, bot[:3], bot[3], bot[7], bot[4:7])
        c1 = replace(ctx, state=st1, scalars=sc1, interfaces=ctx.interfaces + 1, absorbing=True)
        s1 = SubLobe(sub[:3].copy(), sub[3:6].copy())
        alpha1 = variance_to_roughness(sub[6])
        pt = TwoLayerPoint(status, eta1, alpha1, c1, s1, bot[:3].copy(), float(bot[3]), float(bot[7]), bot[4:7].copy())
        if status != OK:
            return pt
        if not self.conductor:
            los, his = [], []
            for c in range(3):
                lo, hi = _dielectric_roots(o, pt.alpha_lookup[c], pt.r_prime[c], eta1, 1.0, o.eta_max)
                los.append(lo)
                his.append(hi)
            n2 = []
            if all(v is not None for v in los) and min(los) >= 1.0 and eta1 > 1.0:
                n2.append(Interval(1.0, min(los)))
            if all(v is not None for v in his) and max(his) <= o.eta_max:
                n2.append(Interval(max(his), o.eta_max))
            if not n2:
                pt.status = FAIL_NO_ETA2
            pt.n2 = n2
        return pt

    def tau1_at(self, pt: TwoLayerPoint, eta2: float) -> np.ndarray:
        o = self.context.options
        r = np.array([_fgd(o, a, eta2 / pt.eta1) for a in pt.alpha_lookup])
        with np.errstate(divide="ignore"):
            t = 0.5 * np.log(r / pt.r_prime)
        return np.where(np.abs(t) < 1e-12, 0.0, t)

    # ---- choices
    def _eta1(self, p: Pick) -> float:
        if p.eta1 is not None:
            e = _rgb(p.eta1, "eta1")
            if np.ptp(e) != 0.0:
                raise PickError("eta1: a dielectric index is achromatic")
            eta1 = float(e[0])
            if not any(iv.contains(eta1) for iv in self.n1):
                raise PickError(f"eta1={eta1:g} is outside N1 = {_intervals_text(self.n1)}")
            return eta1
        u = 0.5 if p.u1 is None else (float(p.u1) if isinstance(p.u1, (int, float)) else float(_rgb(p.u1, "u1")[0]))
        return _position(self.n1, u)

    def pick(self, pick: Pick | dict | None = None) -> LobeSolution:
        self._require()
        p = as_pick(pick)
        if p.root is not None:
            raise PickError("root: not a choice of a 2-layer lobe")
        if p.tau0 is not None and not np.allclose(_rgb(p.tau0, "tau0"), self.tau0):
            raise PickError("tau0: the class was built for another tau0 (pass it to the class function)")
        eta1 = self._eta1(p)
        pt = self.at(eta1)
        if pt.status != OK:
            # a boundary point can fail by rounding: step inside N1
            iv = next(iv for iv in self.n1 if iv.contains(eta1))
            for frac in (1e-9, 1e-7, 1e-5):
                e2 = min(max(eta1, iv.lo + frac * iv.length), iv.hi - frac * iv.length)
                pt = self.at(e2)
                if pt.status == OK:
                    eta1 = e2
                    break
            else:
                raise PickError(f"eta1={eta1:g}: {_FAIL_TEXT.get(pt.status, 'invalid')}")
        o = self.context.options
        top = Layer(self.tau0.copy(), pt.alpha1, np.full(3, eta1), np.zeros(3))
        choices: dict[str, Any] = {"tau0": self.tau0.tolist(), "eta1": eta1, "u1": _fraction(self.n1, eta1)}
        info: dict[str, Any] = {"alpha1": pt.alpha1, "alpha2": pt.alpha2, "r_prime_2": pt.r_prime.tolist(),
                                "sigma_r_2": pt.sigma_r, "N1": [iv.to_list() for iv in self.n1],
                                "eta_sigma_max": self.eta_sigma_max}
        if not self.conductor:
            if p.tau1 is not None:
                raise PickError("tau1: for a 2-layer dielectric lobe tau1 follows from eta2 (eq. 13)")
            if p.eta2 is not None:
                e = _rgb(p.eta2, "eta2")
                if np.ptp(e) != 0.0:
                    raise PickError("eta2: a dielectric index is achromatic")
                eta2 = float(e[0])
                if not any(iv.contains(eta2) for iv in pt.n2):
                    raise PickError(f"eta2={eta2:g} is outside N2 = {_intervals_text(pt.n2)} (at eta1={eta1:.6g})")
            else:
                u2 = 0.5 if p.u2 is None else (float(p.u2) if isinstance(p.u2, (int, float)) else
                                               float(_rgb(p.u2, "u2")[0]))
                eta2 = _position(pt.n2, u2)
            tau1 = np.maximum(self.tau1_at(pt, eta2), 0.0)
            bottom = Layer(tau1, pt.alpha2, np.full(3, eta2), np.zeros(3))
            choices.update({"eta2": eta2, "u2": _fraction(pt.n2, eta2), "tau1": tau1.tolist()})
            info["N2"] = [iv.to_list() for iv in pt.n2]
        else:
            tau1 = _default_tau(pt.r_prime, True) if p.tau1 is None else _rgb(p.tau1, "tau1")
            tgt = pt.r_prime * np.exp(2.0 * tau1)
            u2 = _rgb(0.5 if p.u2 is None else p.u2, "u2")
            etas = None if p.eta2 is None else _rgb(p.eta2, "eta2")
            eta2, kap2, rfs = np.empty(3), np.empty(3), np.empty(3)
            for c in range(3):
                r = _conductor_point(o, pt.alpha_lookup[c], tgt[c], eta1, u=float(u2[c]),
                                     eta=None if etas is None else float(etas[c]))
                if isinstance(r, str):
                    raise PickError(f"conductor base, channel {'RGB'[c]}: {r} (choose tau1 to change its reflectance)")
                eta2[c], kap2[c], rfs[c] = r
            bottom = Layer(tau1.copy(), pt.alpha2, eta2, kap2)
            us = []
            for c in range(3):
                b = conductor_eta_bounds(rfs[c], eta1)
                us.append((eta2[c] - b[0]) / (b[1] - b[0]) if b and b[1] > b[0] else 0.0)
            eq_eta = eta1 * (1.0 + np.sqrt(rfs)) / (1.0 - np.sqrt(rfs))
            choices.update({"tau1": tau1.tolist(), "eta2": eta2.tolist(), "u2": us})
            info.update({"kappa2": kap2.tolist(), "R_fresnel_2": rfs.tolist(), "eta2_equivalent": eq_eta.tolist()})
        c1 = pt.context1.with_medium(bottom.tau) if np.any(bottom.tau > 0) else pt.context1
        c2, sub2 = c1.with_interface(bottom.alpha, bottom.eta, bottom.kappa)
        return LobeSolution([top, bottom], c2, [pt.sub1, sub2], choices, info)

    def T0(self) -> list[Interval | None]:
        """Eq. 16 per channel: the optical depths ``tau0`` above the lobe for which its class is not
        empty, ``1/2 log([R_min, R_max] / R)`` (choice 8: ``R_max`` of an achromatic lobe of the same
        variance found by bisection, ``R_min = 0``; None where even ``tau0 = 0`` is too dark). At
        the top of a stack in air only ``tau0 = 0`` exists. Costs a few dozen class evaluations."""
        R = self.lobe.rgb
        if not self.context.absorbing:
            return [Interval(0.0, 0.0) if self.achievable else None for _ in range(3)]
        r_max = two_layer_energy_max(self.lobe.sigma, self.context, self.conductor)
        if r_max is None:
            return [None, None, None]
        return [Interval(0.0, 0.5 * math.log(r_max / R[c])) if r_max >= R[c] else None for c in range(3)]

    # ---- sampling
    def sample(self, n1: int = 48, n2: int = 48) -> dict[str, np.ndarray]:
        """The sampled class: ``n1`` values of eta1 over N1 (interval ends included) and, for each,
        ``n2`` values of eta2 over N2 (dielectric; with ``tau1`` RGB from eq. 13 and the per-channel
        ``tau1 = 0`` isolines ``eta2_root_lower/upper``), or the ``tau1 >= 0`` range per channel
        (conductor: ``tau1_min``, the equivalent index of the conductor at ``tau1_min``)."""
        if not self.achievable:
            return {"eta1": np.zeros(0)}
        total = sum(iv.length for iv in self.n1)
        e1s: list[float] = []
        for iv in self.n1:
            k = max(2, int(round(n1 * iv.length / total))) if total > 0 else 1
            e1s.extend(np.linspace(iv.lo, iv.hi, k).tolist())
        o = self.context.options
        out: dict[str, list] = {"eta1": [], "alpha1": [], "alpha2": [], "eta2": [], "tau1": [], "root_lower": [],
                                "root_upper": [], "eta1_of_sample": [], "R_prime": []}
        for e1 in e1s:
            pt = self.at(e1)
            if pt.status != OK and not (pt.status == FAIL_NO_ETA2 and not self.conductor):
                continue
            out["eta1"].append(e1)
            out["alpha1"].append(pt.alpha1)
            out["alpha2"].append(pt.alpha2)
            out["R_prime"].append(pt.r_prime)
            lo_c, hi_c = [], []
            for c in range(3):
                lo, hi = _dielectric_roots(o, pt.alpha_lookup[c], pt.r_prime[c], e1, 1.0 / 16.0, 16.0)
                lo_c.append(np.nan if lo is None else lo)
                hi_c.append(np.nan if hi is None else hi)
            out["root_lower"].append(lo_c)
            out["root_upper"].append(hi_c)
            if self.conductor or pt.status != OK:
                continue
            tot2 = sum(iv.length for iv in pt.n2)
            for iv in pt.n2:
                k = max(2, int(round(n2 * iv.length / tot2))) if tot2 > 0 else 1
                for e2 in np.linspace(iv.lo, iv.hi, k):
                    out["eta2"].append(e2)
                    out["tau1"].append(np.maximum(self.tau1_at(pt, float(e2)), 0.0))
                    out["eta1_of_sample"].append(e1)
        res = {k: np.array(v) for k, v in out.items()}
        return res


def _intervals_text(ivs: Sequence[Interval]) -> str:
    return " U ".join(f"[{iv.lo:.6g}, {iv.hi:.6g}]" for iv in ivs) if ivs else "{}"


def two_layer_class(lobe: Lobe, context: Context | None = None, conductor: bool = False,
                    tau0: Any = None, diagnose: bool = True, fine: bool | None = None) -> TwoLayerClass:
    """The class of a 2-layer lobe below ``context`` (alg. 1 for the top lobe, alg. 5 when stacked)
    with a medium of optical depth ``tau0`` (default 0) above its first interface; ``conductor``:
    the second interface is a conductor base (5.2.4). ``fine`` (default: ``diagnose``): rescan with
    N_SCAN_FALLBACK samples when the quick scan finds N1 empty; ``diagnose``: when empty, also
    bound the energy in the reason (bisection, slower)."""
    ctx = context if context is not None else Context.ambient()
    o = ctx.options
    R = lobe.rgb
    bounds: dict[str, Any] = {}
    kind = "conductor-2" if conductor else "dielectric-2"
    t0 = np.zeros(3) if tau0 is None else _rgb(tau0, "tau0")
    if np.any(t0 < 0):
        raise InverseError("tau0: must be >= 0")
    mk = lambda ok, reason, **kw: TwoLayerClass(kind, lobe, ctx, ok, reason, bounds, conductor=conductor,  # noqa: E731
                                                tau0=t0, **kw)
    if np.any(t0 > 0) and not ctx.absorbing:
        return mk(False, "tau0 > 0 needs a medium above the lobe, and the top of a stack in air has none")
    bounds["tau0"] = t0
    top = ctx.with_medium(t0) if np.any(t0 > 0) else ctx
    rp = top.r_prime(R)
    bounds["r_prime"] = rp
    if np.any(rp >= 1.0):
        return mk(False, _FAIL_TEXT[FAIL_TOP_TARGET] + f" (R'={_fmt_rgb(rp)})")
    vr_paper, ch_top = _scalar_sigma_r(top, rp, lobe.sigma, o)
    esm = math.inf
    hi = o.eta_max
    if top.interfaces == 0:
        esm = eta_sigma_max(variance_to_roughness(max(vr_paper, 0.0)), top.eta)
        hi = min(hi, esm)
    bounds["eta_sigma_max"] = esm
    cls = mk(True, None, top_context=top, ch_top=ch_top, vr_top_paper=vr_paper, eta_sigma_max=esm)
    if vr_paper < 0.0:
        cls.achievable = False
        bound = f"sigma_min={top.sigma_min(rp)[ch_top]:.4g}, " if diagnose else ""
        cls.reason = (f"sigma={lobe.sigma:g} is below the variance the layers above already add "
                      f"({bound}eq. 19 with sigma_R = 0)")
        return cls
    n1, counts = _scan_n1(cls, 1.0, hi, o.n_scan)
    if not n1 and (diagnose if fine is None else fine):
        n1, counts = _scan_n1(cls, 1.0, hi, N_SCAN_FALLBACK)
    cls.scan_status = counts
    cls.n1 = n1
    bounds["N1"] = n1
    if not n1:
        cls.achievable = False
        cls.reason = _two_layer_reason(cls, counts, diagnose)
    return cls


def _scan_n1(cls: TwoLayerClass, lo: float, hi: float, n: int) -> tuple[list[Interval], dict[int, int]]:
    """N1 (eq. 12) on [lo, hi]: scan, then bisection of each run's ends (choice 5)."""
    ctx = cls.top_context
    o = ctx.options
    w1, xs = kernel_for(o)
    if hi < lo:
        return [], {}
    etas = np.linspace(lo, hi, n)
    status = np.empty(n, dtype=np.int64)
    exact = o.top_variance == "exact"
    minimax = o.variance_channel == "minimax"
    _two_layer_scan(ctx.state, ctx.scalars, w1, xs, cls.lobe.rgb, cls.lobe.sigma, etas, o.eta_max, cls.conductor,
                    exact, cls.ch_top, cls.vr_top_paper, minimax, status)
    counts = {int(k): int(v) for k, v in zip(*np.unique(status, return_counts=True))}
    st1 = np.empty_like(ctx.state)
    sc1 = np.empty_like(ctx.scalars)
    sub = np.empty(7)
    bot = np.empty(8)

    def ok(e: float) -> bool:
        return _two_layer_eval(ctx.state, ctx.scalars, w1, xs, cls.lobe.rgb, cls.lobe.sigma, e, o.eta_max,
                               cls.conductor, exact, cls.ch_top, cls.vr_top_paper, minimax, st1, sc1, sub, bot) == OK

    out = []
    for i, j in _runs(status == OK):
        a = etas[i] if i == 0 else _bisect(ok, etas[i], etas[i - 1])
        b = etas[j] if j == n - 1 else _bisect(ok, etas[j], etas[j + 1])
        out.append(Interval(float(a), float(b)))
    return out, counts


def _two_layer_reason(cls: TwoLayerClass, counts: dict[int, int], diagnose: bool) -> str:
    """Why N1 is empty: the failure most samples share, and the energy bound when the lobe is too bright."""
    fails = {k: v for k, v in counts.items() if k != OK}
    if not fails:
        return "N1 is empty"
    main = max(fails, key=lambda k: fails[k])
    text = _FAIL_TEXT.get(main, "invalid")
    where = " (top lobe: eta1 <= eta_sigma_max = %.4g, section 5.2.2)" % cls.eta_sigma_max \
        if math.isfinite(cls.eta_sigma_max) else ""
    msg = f"N1 (eq. 12) is empty for R={_fmt_rgb(cls.lobe.rgb)}, sigma={cls.lobe.sigma:g}: for most eta1 {text}{where}"
    if diagnose and main in (FAIL_NO_ETA2, FAIL_BOTTOM_ENERGY, FAIL_TOP_ENERGY, FAIL_CONDUCTOR):
        r_max = two_layer_energy_max(cls.lobe.sigma, cls.context, cls.conductor, cls.tau0)
        if r_max is not None:
            where_ = " here (below the layers chosen above)" if cls.context.interfaces else ""
            msg += f"; the largest achromatic energy reachable with eta <= eta_max={cls.context.options.eta_max:g}" \
                   f"{where_} is R_max={r_max:.4g}"
    return msg


def two_layer_energy_max(sigma: float, context: Context, conductor: bool = False, tau0: Any = None,
                         tol: float = 1e-5) -> float | None:
    """The largest achromatic energy of a 2-layer lobe of variance ``sigma`` with a non-empty class
    in ``context`` (bisection on R; used for T0, eq. 16, and for messages). None if none is."""
    def ok(r: float) -> bool:
        c = two_layer_class(Lobe(r, sigma, 2), context, conductor, tau0, diagnose=False, fine=True)
        return c.achievable

    lo, hi = 0.0, 1.0 - 1e-9
    probe = [1e-4, 1e-3, 0.01, 0.05]
    start = next((p for p in probe if ok(p)), None)
    if start is None:
        return None
    lo = start
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        if ok(mid):
            lo = mid
        else:
            hi = mid
    return lo


# ---------------------------------------------------------------------------- dispatch

def lobe_class(lobe: Lobe, context: Context | None = None, conductor: bool = False, tau0: Any = None,
               diagnose: bool = True) -> LobeClass:
    """The equivalence class of ``lobe`` below ``context`` (air by default): 1-layer dielectric or
    conductor (section 5.1), 2-layer dielectric or over a conductor base (section 5.2)."""
    if lobe.layers == 1:
        if conductor:
            return conductor_class(lobe, context, tau0)
        if tau0 is not None:
            raise InverseError("tau0: for a 1-layer dielectric lobe tau0 follows from eta1 (choose eta1 or u1)")
        return one_layer_dielectric_class(lobe, context)
    return two_layer_class(lobe, context, conductor, tau0, diagnose)


# ============================================================================ stacking (alg. 2)

@dataclass
class Inversion:
    """Result of :func:`solve`: the stack (if achievable), per-lobe classes and solutions."""

    lobes: list[Lobe]
    base: str
    options: InverseOptions
    achievable: bool
    reason: str | None
    failed_lobe: int
    classes: list[LobeClass]
    solutions: list[LobeSolution]
    searched: bool = False
    elapsed_s: float = 0.0
    name: str = "inverse"

    @property
    def layers(self) -> list[Layer]:
        return [layer for s in self.solutions for layer in s.layers]

    @property
    def lobe_interfaces(self) -> list[list[int]]:
        """Interface indices (top = 0) belonging to each lobe."""
        out, k = [], 0
        for s in self.solutions:
            out.append(list(range(k, k + len(s.layers))))
            k += len(s.layers)
        return out

    def stack(self, name: str | None = None) -> Stack:
        if not self.achievable:
            raise NotAchievable(self.reason or "not achievable", self.failed_lobe)
        return layers_to_stack(self.layers, name or self.name)

    def predicted(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """The inverse's own prediction of each lobe: (energy RGB, variance RGB)."""
        return [(s.energy, s.variance) for s in self.solutions]

    def to_json(self) -> dict[str, Any]:
        d: dict[str, Any] = {"base": self.base, "achievable": self.achievable, "eta_max": self.options.eta_max,
                             "lobes": []}
        if not self.achievable:
            d["reason"] = self.reason
            d["failed_lobe"] = self.failed_lobe
        for k, lobe in enumerate(self.lobes):
            e: dict[str, Any] = {"R": list(lobe.R), "sigma": lobe.sigma, "layers": lobe.layers}
            if k < len(self.classes):
                e["class"] = self.classes[k].summary()
            if k < len(self.solutions):
                s = self.solutions[k]
                e["choices"] = _jsonable(s.choices)
                e["layers_retrieved"] = [layer.to_dict() for layer in s.layers]
                e["info"] = _jsonable(s.info)
            d["lobes"].append(e)
        return d


def layers_to_stack(layers: Sequence[Layer], name: str = "inverse") -> Stack:
    """The material (goniometer Stack) of the paper's layer list: a medium wherever ``tau > 0``
    (never above the first interface), then the interface. Category: metal (conductor base), slab
    (dielectric ending in air, eta = 1), other."""
    out: list[Any] = []
    for i, layer in enumerate(layers):
        if i > 0 and np.any(layer.tau > 0.0):
            out.append(Medium(tuple(float(x) for x in layer.tau)))
        if layer.conductor:
            out.append(Interface(float(layer.alpha), tuple(float(x) for x in layer.eta),
                                 tuple(float(x) for x in layer.kappa)))
        else:
            out.append(Interface(float(layer.alpha), (float(layer.eta[0]),) * 3))
    last = layers[-1]
    category = "metal" if last.conductor else ("slab" if float(last.eta[0]) == 1.0 else "other")
    return Stack(name, tuple(out), category)


def _check_lobes(lobes: Sequence[Lobe], base: str) -> list[Lobe]:
    if base not in ("dielectric", "conductor"):
        raise InverseError(f"base: {base!r} is not one of dielectric, conductor")
    out = []
    for k, lobe in enumerate(lobes):
        if not isinstance(lobe, Lobe):
            raise InverseError(f"lobe {k + 1}: expected a models.inverse.solver.Lobe, got {type(lobe).__name__}")
        out.append(lobe)
    if not out:
        raise InverseError("at least one lobe is required")
    return out


#: candidate positions tried when a default choice of an upper lobe leaves a lower lobe unachievable
SEARCH_POSITIONS = (0.5, 0.25, 0.75, 0.1, 0.9, 0.02, 0.98, 0.0, 1.0)


@lru_cache(maxsize=None)
def _candidate_table(kind: str, absorbing: bool) -> tuple[Pick, ...]:
    if kind == "conductor-1":
        return tuple(Pick(u1=u) for u in SEARCH_POSITIONS)
    if kind == "dielectric-1":
        cands = [Pick()]
        for root in ("upper", "lower"):
            for u in (0.0, 0.1, 0.3, 0.6, 1.0) if absorbing else (0.0,):
                cands.append(Pick(root=root, u1=u))
        return tuple(cands)
    cands = [Pick(u1=u1, u2=u2) for u1 in SEARCH_POSITIONS for u2 in SEARCH_POSITIONS]
    cands.sort(key=lambda p: (abs(p.u1 - 0.5) + abs(p.u2 - 0.5)))
    return tuple(cands)


def _candidates(lobe: Lobe, conductor: bool, pick: Pick, absorbing: bool) -> tuple[Pick, ...]:
    """Picks to try for a lobe whose pick is the default (choice 6 search), default first."""
    if not pick.is_default:
        return (pick,)
    kind = ("conductor-" if conductor else "dielectric-") + str(lobe.layers)
    return _candidate_table(kind, absorbing)


def solve(lobes: Sequence[Lobe], base: str = "dielectric", picks: Sequence[Pick | dict | None] | None = None,
          options: InverseOptions | None = None, search: bool = True, name: str = "inverse",
          max_search: int = 2000) -> Inversion:
    """Algorithm 2: invert the lobes top-down (the top lobe first) and return an :class:`Inversion`.

    ``base``: ``"dielectric"`` (the last interface transmits into a semi-infinite dielectric) or
    ``"conductor"`` (the last lobe's last interface is a conductor). ``picks``: one
    :class:`Pick` (or dict, or None) per lobe. With ``search`` (default), default picks of upper
    lobes are moved when they leave a lower lobe unachievable (choice 6). Never raises for an
    unachievable request: ``achievable`` is False and ``reason`` says why (raises
    :class:`InverseError` only for malformed input).
    """
    t_start = time.perf_counter()
    lobes = _check_lobes(lobes, base)
    o = options if options is not None else InverseOptions()
    K = len(lobes)
    if picks is None:
        picks = [None] * K
    if len(picks) != K:
        raise InverseError(f"picks: expected {K} (one per lobe), got {len(picks)}")
    pk = [as_pick(p) for p in picks]
    # a quick pass (N1 scans of n_scan samples); if it fails, one pass with the fine fallback scans
    for fine in (False, True):
        result, failures = _solve_pass(lobes, base, pk, o, search, max_search, fine)
        if result is not None:
            classes, sols = result
            return Inversion(list(lobes), base, o, True, None, 0, classes, sols, searched=_was_searched(sols, pk),
                             elapsed_s=time.perf_counter() - t_start, name=name)
    # report the failure along the default path (the first recorded), with its diagnosis
    k, reason, classes, sols = failures[0] if failures else (0, "no solution", [], [])
    if classes and not classes[-1].achievable and classes[-1].lobe.layers == 2 and not reason.startswith("pick"):
        c = classes[-1]
        c = two_layer_class(c.lobe, c.context, c.conductor, c.tau0, diagnose=True)
        classes = classes[:-1] + [c]
        reason = c.reason or reason
    deeper = max(failures, key=lambda f: f[0]) if failures else None
    if deeper is not None and deeper[0] > k:
        reason += (f" (searching the classes of the lobes above, the furthest reached was lobe {deeper[0] + 1}: "
                   f"{deeper[1]})")
    return Inversion(list(lobes), base, o, False, f"lobe {k + 1} ({lobes[k].describe()}): {reason}", k + 1,
                     classes, sols, elapsed_s=time.perf_counter() - t_start, name=name)


def _solve_pass(lobes: list[Lobe], base: str, pk: list[Pick], o: InverseOptions, search: bool, max_search: int,
                fine: bool):
    """One depth-first pass of alg. 2 with the choice-6 search; returns ((classes, solutions) or None,
    failures as (lobe index, reason, classes, solutions))."""
    K = len(lobes)
    budget = [max_search]
    failures: list[tuple[int, str, list[LobeClass], list[LobeSolution]]] = []

    def rec(k: int, ctx: Context, classes: list[LobeClass], sols: list[LobeSolution]):
        if k == K:
            return classes, sols
        conductor = base == "conductor" and k == K - 1
        lobe = lobes[k]
        p = pk[k]
        tau0 = p.tau0 if (lobe.layers == 2 or conductor) else None
        try:
            if lobe.layers == 2:
                cls = two_layer_class(lobe, ctx, conductor, tau0, diagnose=False, fine=fine)
            else:
                cls = lobe_class(lobe, ctx, conductor, tau0)
        except InverseError as e:
            raise InverseError(f"lobe {k + 1}: {e}") from None
        if not cls.achievable:
            failures.append((k, cls.reason or "", classes + [cls], sols))
            return None
        cands = _candidates(lobe, conductor, p, ctx.absorbing) if (search and k < K - 1) else (p,)
        for cand in cands:
            if budget[0] <= 0:
                break
            budget[0] -= 1
            try:
                sol = cls.pick(cand)
            except PickError as e:
                if cand is p:
                    failures.append((k, f"pick: {e}", classes + [cls], sols))
                    if not p.is_default:
                        return None
                continue
            r = rec(k + 1, sol.context, classes + [cls], sols + [sol])
            if r is not None:
                return r
        return None

    root_ctx = Context.ambient(1.0, absorbing=False, options=o)
    return rec(0, root_ctx, [], []), failures


def _was_searched(sols: list[LobeSolution], picks: list[Pick]) -> bool:
    """True if some default pick was moved away from its default by the search."""
    for s, p in zip(sols, picks):
        if not p.is_default:
            continue
        u1 = s.choices.get("u1")
        u2 = s.choices.get("u2")
        if "root" in s.choices:  # 1-layer dielectric: default u1 = 0
            if u1 is not None and abs(float(u1)) > 1e-9:
                return True
            continue
        for u in (u1, u2):
            if u is None:
                continue
            if np.any(np.abs(np.atleast_1d(np.asarray(u, dtype=float)) - 0.5) > 1e-6):
                return True
    return False


def _choices_to_picks(lobes: Sequence[Lobe], picks: Any, choices: dict[str, Any]) -> list[Pick | dict | None]:
    K = len(lobes)
    out: list[Any] = list(picks) if picks is not None else [None] * K
    if len(out) != K:
        raise InverseError(f"picks: expected {K} (one per lobe), got {len(out)}")
    for key, value in choices.items():
        m = re.fullmatch(r"lobe(\d+)", key)
        if not m:
            raise InverseError(f"unknown choice {key!r}: use lobe1=Pick(...) (or a dict), lobe2=..., or picks=[...]")
        k = int(m.group(1))
        if not 1 <= k <= K:
            raise InverseError(f"{key}: there are {K} lobes")
        if out[k - 1] is not None:
            raise InverseError(f"{key}: given twice")
        out[k - 1] = value
    return out


def invert(lobes: Sequence[Lobe], base: str = "dielectric", *, picks: Sequence[Pick | dict | None] | None = None,
           eta_max: float = ETA_MAX_DEFAULT, options: InverseOptions | None = None, name: str = "inverse",
           search: bool = True, **choices: Any) -> Stack:
    """Lobes (top first) -> a physical :class:`goniometer.stack.Stack` (algorithm 2).

    Free choices: ``picks=[Pick|dict|None, ...]`` or ``lobe1=Pick(...)``, ``lobe2={"u1": 0.3}``, ...
    (defaults: class centres, choice 6). Raises :class:`NotAchievable` (with the reason and the
    violated bound) when no physical stack exists, :class:`InverseError` on malformed input.
    """
    o = options if options is not None else InverseOptions(eta_max=eta_max)
    inv = solve(lobes, base, _choices_to_picks(lobes, picks, choices), o, search=search, name=name)
    return inv.stack()


def equivalence_classes(lobes: Sequence[Lobe], base: str = "dielectric",
                        picks: Sequence[Pick | dict | None] | None = None,
                        options: InverseOptions | None = None) -> list[LobeClass]:
    """The class of every lobe, each in the context of the lobes chosen above it (alg. 2); the
    list stops at the first unachievable lobe (whose class says why)."""
    return solve(lobes, base, picks, options).classes


# ============================================================================ benchmark

#: figure 17 (read from the caption): a blue and a red rough 2-layer lobe, blue on top
FIG17_LOBES = (Lobe((0.025, 0.045, 0.05), 0.028, 2), Lobe((0.052, 0.025, 0.025), 0.014, 2))


def bench_invert(repeat: int = 20, lobes: Sequence[Lobe] = FIG17_LOBES, base: str = "dielectric") -> float:
    """Median seconds of one :func:`solve` of ``lobes`` (figure 17 by default) after a warm-up
    call (numba compilation and the FGD kernel load excluded). Single-threaded by construction
    (the inverse runs no parallel kernels)."""
    solve(lobes, base)
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        solve(lobes, base)
        times.append(time.perf_counter() - t0)
    return float(np.median(times))
