"""Fitted compact BRDF models: Holzschuch & Pacanowski 2015 and one-/two-lobe GGX baselines.

A fitted model is not a layered model: it is a parametric BRDF whose parameters are found by
least squares against the BRDF slices of one simulated file, so that its error (Bati 2019, eq. 4)
can sit in the same tables as the physical models (``hp15-fit``, ``ggx1-fit``, ``ggx2-fit``).

Conventions (as :mod:`models.base`, :mod:`goniometer.optics` and SLICES.md): ``z`` is the macro
normal; ``l`` (= the paper's ``i``) and ``v`` (= ``o``) are unit vectors pointing away from the
surface, ``h = normalize(l + v)``; values are BRDF values without the cosine factor, in 1/sr,
RGB on the last axis. Every value is 0 when ``l_z <= 0`` or ``v_z <= 0`` (or ``v`` is not finite).

Families
--------
``ggx1`` (8 parameters: ``kd`` RGB, ``ks`` RGB, ``F0``, ``alpha``)::

    f = kd/pi + ks F_S(F0, l.h) / F0  D(h) G2(l, v) / (4 l_z v_z)
    F_S(F0, c) = F0 + (1 - F0) (1 - c)^5          (Schlick; HP15 eq. 8/27)

  ``D`` is GGX and ``G2`` the height-correlated Smith term ``1 / (1 + Lambda(l) + Lambda(v))``,
  both from :mod:`goniometer.optics`. ``ks`` (RGB) is the lobe's Fresnel factor at normal
  incidence; the scalar ``F0`` only shapes the grazing rise ``F_S / F0 = (1 - m) + m / F0``
  (``m = (1 - l.h)^5``; ``F0 = 1``: none). Putting the colour in ``ks`` rather than in an RGB
  Schlick ``F0`` lets ``ks = 0`` switch a lobe off, so one lobe nests in two.
``ggx2`` (13 parameters): diffuse + two such lobes (``ks_j, F0_j, alpha_j``). After the fit the
  lobes are sorted so that lobe 1 is the sharper (smaller ``alpha``). The two-lobe fit always
  includes a start at the best one-lobe fit plus a second lobe of ``ks_2 = 0`` (its colours then
  re-solved linearly, which can only lower the cost), so its objective is never above the
  one-lobe fit's.
``hp15`` (15 parameters, Holzschuch & Pacanowski 2015 eq. 24-27)::

    f = kd/pi + G(l, v) ( ks D(theta_h) F(theta_d) / (4 l_z v_z) + kw / lambda^4 S_z(f) / E_{a,lambda} )
    S_z(f) = 1 / (1 + f^2 / a^2)^2                                          (eq. 25)
    D(theta) = chi(theta) / cos^4 theta  p / (pi sigma^2 Gamma(1/p))  exp(-(tan^2 theta / sigma^2)^p)   (eq. 26)
    F(theta_d) = F0 + (1 - F0) (1 - cos theta_d)^5,  cos theta_d = l.h     (eq. 27)
    f = |(l + v) x n| / lambda   (eq. 10: the tangential part of the deviation from the mirror direction)

  with ``kd, ks, kw, F0`` RGB and ``sigma, p, a`` shared; ``lambda`` = 0.645, 0.526, 0.444 um for
  R, G, B (section 5.5) and ``a`` in 1/um.

Choices where the paper is vague or inconsistent
------------------------------------------------
* **Distribution (eq. 18 vs 26).** Eq. 18 writes ``exp(-(x/sigma)^p)`` but the normalisation
  (eq. 19) and eq. 26 use ``x / sigma^2``; we follow eq. 26 (then ``p = 1`` is Beckmann with
  ``alpha = sigma``, which the tests use), and ``Int D cos dw = 1`` holds exactly (tested).
* **Shadowing (eq. 20-21).** Smith's ``Lambda`` for this distribution: ``Lambda(theta) =
  Lambda_1(sigma tan theta)`` (it depends on ``sigma tan theta`` and ``p`` only). Eq. 20 has
  ``Int_0^inf`` where the marginal slope density needs ``Int_-inf^inf`` (a factor 2); we use the
  correct marginal. Writing the double integral in polar slope coordinates reduces it to one
  integral (derivation in :func:`hp_lambda`), evaluated by Gauss-Legendre quadrature after the
  substitution ``u = cosh^2(w) / a^2`` that removes the square-root endpoint singularity
  (tested against the closed-form Beckmann Lambda at ``p = 1``, against eq. 20-21 integrated
  numerically, and against ``Lambda = Int <v.m> D(m) dm / cos theta_v - 1`` over D itself). For
  speed ``Lambda_1`` is tabulated for the current ``p`` on 256 points in ``ln a`` (Catmull-Rom
  interpolation; ``G1`` within ~1e-5 of the direct quadrature, tested) -- in place of the
  paper's 2D table over ``(5/p, exp(-(sigma tan theta)^(-1/20)))``. ``G = G1(l) G1(v)``, the
  separable form the paper uses (eq. 6-7).
* **Diffraction normalisation.** The paper prints ``E_{a,lambda} = pi (1 + 1/(a^2 lambda^2))``
  as "the maximum energy of the lobe", but ``Int S_z cos dw_o`` over the hemisphere at normal
  incidence (the maximum over incidence, since ``S_z`` decreases away from the mirror direction)
  is ``pi / (1 + 1/(a^2 lambda^2))``. We use the latter, so that ``kw / lambda^4`` is the
  diffraction lobe's albedo at normal incidence before shadowing (tested by quadrature).
* **Fresnel.** Only on the reflection lobe (section 5.3); ``F0`` bounded to ``[0.02, 1.2]`` as
  the paper does; all other parameters non-negative, ``p`` in ``[0.1, 5]``. Upper bounds that
  keep the search finite: ``kd <= 1``, ``ks <= 50``, ``kw / lambda^4 <= 2``,
  ``sigma in [1e-6, 4]``, ``a in [1e-3, 1e3]`` 1/um; GGX ``ks <= 5``, ``F0 in [0.02, 1]``,
  ``alpha in [1e-3, 1.5]``.

Fitting
-------
* **Objective (the paper's eq. 29, section 5.8).** Residual per valid cell and channel
  ``r = sqrt(W) (f_model - f_ref)`` with ``W = cos^2(theta_i) dw_o / M``: the squared error
  integrated over outgoing *solid angle* (not projected: the paper's ``d omega_o``; the cell's
  solid angle is ``Omega(cell)`` times the average of ``1/cos theta_v`` over its sub-cells),
  weighted by ``cos^2 theta_i``. Directions too close to the horizon are left out as the paper
  does: incident directions with ``theta_i >= 1.4`` rad and cells whose centre has
  ``theta_o >= 1.4`` rad. If that leaves nothing (grazing-only data) every valid cell is used and
  the message says so. ``weighting="eq4"`` minimises the project's eq. 4 instead
  (``W = Omega / M``, no exclusion); when the optimiser's sub-cells are 5 x 5 everywhere (the
  automatic choice for 30 x 60 grids) ``2 cost = sum_c E_c^2`` of the reported errors exactly.
  The paper-weighted fit can report a slightly larger eq. 4 error than a simpler family (the
  objectives differ); the eq4-weighted one cannot.
* **Model cell values inside the optimiser.** The candidate is averaged over ``s x s`` sub-cells
  of every cell (``grid.subcells``, weights = projected solid angles), ``fbar = sum f w / sum w``
  -- the same cell value the simulator estimates. Automatic ``s``: sub-cells of about 1 degree
  (``s = 1``, i.e. cell centres, on the default 90 x 360 grids; 5 on a 30 x 60 grid) and, for
  classic grids, about 0.25 degree (``s = 4`` on 90 x 360) in cells within 8 degrees of the
  mirror direction, where every lobe of these families peaks: with cell centres only there, the
  optimiser learnt to place a spike narrower than a cell on a cell centre (a ggx2 lobe of
  ``alpha = 0.016`` on 1-degree cells) that lowered its objective and raised the error of the
  properly integrated model. Half grids already have small cells around the mirror direction.
  The reported errors always integrate the fitted model with ``s = 5``
  (:func:`models.compare.integrate.integrate`).
* **Optimiser.** ``scipy.optimize.least_squares`` (trf, bounded) in internal coordinates
  (``ln`` for ``alpha, F0`` (GGX), ``sigma, a``; ``kw / lambda^4`` for ``kw``), with an exact
  Jacobian for the colour parameters (the model is affine in them) and central differences
  (step 1e-4) for the shape parameters. It is handed an equivalent compressed problem of
  ``n + 1`` residuals with the same cost, gradient and Gauss-Newton matrix (see
  :class:`_Problem`), which keeps its per-iteration SVD small. Several starts: start 0 at typical
  values, the others random (seeded by ``seed``; as in the paper every colour starts equal over
  the channels; shape parameters drawn log-uniformly over typical ranges). Before each start the
  colour parameters (``kd, ks`` for GGX; ``kd, ks, kw`` for HP15) are set by a bounded *linear*
  least-squares solve given the others, which makes random starts far more robust than random
  colours. The start with the lowest cost wins (a converged start within 1e-6 of it is
  preferred to a non-converged one); its ``least_squares`` status decides ``converged``
  (status 0 = evaluation budget exhausted: the message starts with "did not converge").
* **No NaN reaches the optimiser.** Reference cells with non-finite values are dropped (as if
  masked; also from the reported errors). Model kernels return 0 instead of dividing by zero;
  should a model cell value still be non-finite it is replaced by ``1e12`` 1/sr -- a huge but
  finite residual that the trust-region step rejects -- and non-finite Jacobian entries by 0.
* **Parameter uncertainty.** ``FitResult.param_stderr`` propagates the reference's Monte Carlo
  standard errors through the weighted least squares (sandwich estimate at the solution).

Results put the whole fitted BRDF in ``ModelValue.internal`` (``top`` is 0): a fit has no
top-lobe/internal split, and :func:`fit` reports the errors of the total
(``models.compare.errors.compare(..., drop_first_order=False)``, so ``"internal"`` and ``"total"`` are
the same comparison). Fitted models accept any stack (``support_reason`` is None).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Callable, Sequence

import numpy as np
from scipy.optimize import least_squares, lsq_linear

from goniometer.optics import ggx_d, ggx_lambda, half_vector, smith_g2
from goniometer.results import SimulationResult, SliceData
from goniometer.slices import light_direction
from goniometer.stack import Stack
from models._jit import njit
from models.base import Model, ModelError, ModelValue
from models.compare.errors import compare
from models.compare.integrate import integrate

#: wavelengths of the R, G, B channels in micrometres (Holzschuch & Pacanowski 2015, sec. 5.5)
WAVELENGTHS_UM = np.array([0.645, 0.526, 0.444])
#: the paper's grazing cut-off (sec. 5.8): theta_i, theta_o >= 1.4 rad are left out of the fit
GRAZING_RAD = 1.4
#: value that replaces a non-finite model cell value inside the optimiser (1/sr)
NONFINITE_VALUE = 1e12

_INV_PI = 1.0 / math.pi
_LOG_PI = math.log(math.pi)
#: Lambda table: number of points in ln(a) and its upper end (linear extrapolation beyond)
_TABLE_N = 256
_TABLE_A_MAX = 1e5
#: Lambda quadrature: Gauss-Legendre panels x nodes per panel (see hp_lambda)
_QUAD_PANELS = 8
_QUAD_NODES, _QUAD_WEIGHTS = np.polynomial.legendre.leggauss(16)
#: exponent cut-off of the integrand exp(-u^p): e^-45 is negligible
_QUAD_EXP_CUT = 45.0


# =========================================================================== HP15 physics

@njit(cache=True)
def hp_d(cos_h: float, sigma: float, p: float) -> float:
    """Holzschuch-Pacanowski micro-facet distribution D(theta_h) in 1/sr (eq. 26).

    ``D = 1/cos^4 * p / (pi sigma^2 Gamma(1/p)) * exp(-(tan^2 / sigma^2)^p)``, 0 for
    ``cos_h <= 0``; normalised so that ``Int D cos dw = 1`` (eq. 19). Evaluated in log space so
    that grazing half vectors give 0, never ``0 * inf``.
    """
    if not cos_h > 0.0:
        return 0.0
    c2 = min(cos_h * cos_h, 1.0)
    x = (1.0 - c2) / (c2 * sigma * sigma)
    e = 0.0 if x <= 0.0 else math.exp(p * math.log(x))
    log_d = math.log(p) - _LOG_PI - 2.0 * math.log(sigma) - math.lgamma(1.0 / p) - 2.0 * math.log(c2) - e
    return math.exp(log_d)


@njit(cache=True)
def hp_lambda(a: float, p: float, nodes: np.ndarray, weights: np.ndarray, panels: int) -> float:
    """Smith ``Lambda_1(a)`` of the HP15 distribution with ``sigma = 1`` (eq. 20-21).

    ``Lambda(theta) = Lambda_1(sigma tan theta)``. With the slope density
    ``P22(x^2 + y^2)``, ``P22_1(u) = p / (pi Gamma(1/p)) exp(-u^p)``, Smith's
    ``Lambda(a) = Int Int_{x > 1/a} (a x - 1) P22(x^2 + y^2) dx dy`` (eq. 4-5 with the full
    marginal); in polar slope coordinates the angular integral is analytic,
    ``2 (sqrt(a^2 r^2 - 1) - arccos(1 / (a r)))``, leaving
    ``Lambda(a) = Int_{1/a^2}^inf P22(u) (sqrt(a^2 u - 1) - arccos(1/(a sqrt u))) du``. The
    substitution ``u = cosh^2(w) / a^2`` makes the bracket ``sinh w - atan(sinh w)`` (smooth,
    ``~w^3/3`` at 0) and the integral runs over ``w in [0, W]`` with ``u(W)^p = 45``.
    ``nodes``/``weights``: Gauss-Legendre on [-1, 1], used on ``panels`` equal panels.
    """
    if not a > 0.0:
        return 0.0
    if not math.isfinite(a):
        return math.inf
    # upper end: u^p = cut  <=>  cosh W = a cut^(1 / (2p))
    ch = a * math.exp(math.log(_QUAD_EXP_CUT) / (2.0 * p))
    if ch <= 1.0:
        return 0.0
    w_max = math.log(ch + math.sqrt(ch * ch - 1.0))
    c = p / (math.pi * math.exp(math.lgamma(1.0 / p)))
    a2 = a * a
    h = w_max / panels
    total = 0.0
    for k in range(panels):
        mid = (k + 0.5) * h
        for j in range(nodes.shape[0]):
            w = mid + 0.5 * h * nodes[j]
            sh = math.sinh(w)
            chw = math.cosh(w)
            u = chw * chw / a2
            g = sh - math.atan(sh)
            total += weights[j] * c * math.exp(-math.exp(p * math.log(u))) * g * 2.0 * chw * sh / a2
    return total * 0.5 * h


@njit(cache=True)
def hp_lambda_table(p: float, n: int, nodes: np.ndarray, weights: np.ndarray, panels: int):
    """Tabulate ``Lambda_1`` for one ``p`` on ``n`` points uniform in ``ln a``.

    The range starts where ``Lambda_1`` is negligible (``a_lo = 45^(-1/(2p))``: no slope of the
    integrand's support reaches ``1/a``) and ends at ``a = 1e5``. Returns ``(x0, dx, values)``
    with ``x0 = ln a_lo``.
    """
    x0 = -math.log(_QUAD_EXP_CUT) / (2.0 * p)
    x1 = math.log(_TABLE_A_MAX)
    dx = (x1 - x0) / (n - 1)
    vals = np.empty(n)
    for k in range(n):
        vals[k] = hp_lambda(math.exp(x0 + k * dx), p, nodes, weights, panels)
    return x0, dx, vals


@njit(cache=True)
def hp_lambda_lookup(ln_a: float, x0: float, dx: float, vals: np.ndarray) -> float:
    """``Lambda_1(a)`` from a table of :func:`hp_lambda_table`, given ``ln a``.

    Catmull-Rom cubic interpolation in ``ln a`` (G1 within ~1e-5 of the direct quadrature,
    tested). Below the table 0; above it ``Lambda_1`` grows linearly in ``a`` (its asymptote),
    so the last value is scaled by ``a / a_max``; ``ln a = inf`` gives inf.
    """
    if math.isnan(ln_a):
        return 0.0
    t = (ln_a - x0) / dx
    n = vals.shape[0]
    if t <= 0.0:
        return 0.0
    if t >= n - 1:
        if math.isinf(ln_a):
            return math.inf
        return vals[n - 1] * math.exp(ln_a - x0 - (n - 1) * dx)
    k = int(t)
    f = t - k
    p1 = vals[k]
    p2 = vals[k + 1]
    p0 = vals[k - 1] if k >= 1 else 2.0 * p1 - p2
    p3 = vals[k + 2] if k + 2 < n else 2.0 * p2 - p1
    return p1 + 0.5 * f * (p2 - p0 + f * (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3 + f * (3.0 * (p1 - p2) + p3 - p0)))


@njit(cache=True)
def _tan_from_cos(c: float) -> float:
    if c <= 0.0:
        return math.inf
    c = min(c, 1.0)
    return math.sqrt(max(0.0, 1.0 - c * c)) / c


def hp_g1(cos_theta: float, sigma: float, p: float) -> float:
    """Smith masking ``G1 = 1 / (1 + Lambda_1(sigma tan theta))`` of the HP15 distribution (direct)."""
    lam = hp_lambda(sigma * _tan_from_cos(cos_theta), p, _QUAD_NODES, _QUAD_WEIGHTS, _QUAD_PANELS)
    return 1.0 / (1.0 + lam)


def diffraction_norm(a: float, lam: float) -> float:
    """``E_{a,lambda} = pi / (1 + 1/(a lambda)^2)``: ``Int S_z cos dw_o`` at normal incidence.

    (The paper prints ``pi (1 + 1/(a^2 lambda^2))``; see the module docstring.)
    """
    x = (a * lam) ** 2
    return math.pi * x / (1.0 + x)


@njit(cache=True)
def _hp_pieces(lz, vz, ln_tan_l, ln_tan_v, ln_tan2_h, ln_cos2_h, schlick, ft2, w, start,
               sigma, p, a, x0, dx, table, lam, A, B, R) -> None:
    """Cell averages of the HP15 pieces (eq. 24) over the samples of every cell.

    Per sample: ``q = G D / (4 l_z v_z)`` and ``r_c = G S_z(f_c) / (lambda_c^4 E_c)`` with
    ``G = G1(l) G1(v)`` from the Lambda table, ``D`` eq. 26, ``S_z`` eq. 25 at
    ``f_c^2 = ft2 / lambda_c^2``. Output, with ``<.>`` the ``w``-weighted sum over a cell's
    samples ``start[i]:start[i + 1]`` (weights normalised per cell): ``A = <q (1 - m)>``,
    ``B = <q m>`` (``m`` the Schlick weight) and ``R[:, c] = <r_c>``.
    """
    ln_sigma = math.log(sigma)
    log_beta = math.log(p) - _LOG_PI - 2.0 * ln_sigma - math.lgamma(1.0 / p)
    k2 = np.empty(3)
    rc = np.empty(3)
    for c in range(3):
        al2 = (a * lam[c]) ** 2
        k2[c] = 1.0 / al2
        rc[c] = (1.0 + al2) / (math.pi * al2 * lam[c] ** 4)   # 1 / (lambda^4 E)
    n_cells = start.shape[0] - 1
    for i in range(n_cells):
        sa = 0.0
        sb = 0.0
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        for k in range(start[i], start[i + 1]):
            wk = w[k]
            if wk == 0.0 or not (lz[k] > 0.0 and vz[k] > 0.0):
                continue
            g = 1.0 / ((1.0 + hp_lambda_lookup(ln_sigma + ln_tan_l[k], x0, dx, table))
                       * (1.0 + hp_lambda_lookup(ln_sigma + ln_tan_v[k], x0, dx, table)))
            if g <= 0.0:
                continue
            e = math.exp(p * (ln_tan2_h[k] - 2.0 * ln_sigma))
            q = g * math.exp(log_beta - 2.0 * ln_cos2_h[k] - e) / (4.0 * lz[k] * vz[k])
            sa += wk * q * (1.0 - schlick[k])
            sb += wk * q * schlick[k]
            gw = g * wk
            t = 1.0 + ft2[k] * k2[0]
            s0 += gw * rc[0] / (t * t)
            t = 1.0 + ft2[k] * k2[1]
            s1 += gw * rc[1] / (t * t)
            t = 1.0 + ft2[k] * k2[2]
            s2 += gw * rc[2] / (t * t)
        A[i] = sa
        B[i] = sb
        R[i, 0] = s0
        R[i, 1] = s1
        R[i, 2] = s2


# =========================================================================== GGX lobe

@njit(cache=True)
def _ggx_lobe(l: np.ndarray, v: np.ndarray, schlick: np.ndarray, w: np.ndarray, start: np.ndarray,
              alpha: float, A: np.ndarray, B: np.ndarray) -> None:
    """Cell averages of an isotropic GGX lobe ``q = D(h) G2(l, v) / (4 l_z v_z)``.

    ``D``, ``Lambda`` and the height-correlated ``G2`` come from :mod:`goniometer.optics`.
    ``A = <q (1 - m)>``, ``B = <q m>`` with ``<.>`` the ``w``-weighted sum over a cell's samples
    ``start[i]:start[i + 1]`` (weights normalised per cell) and ``m`` the Schlick weight.
    Samples with ``l_z <= 0`` or ``v_z <= 0`` contribute 0.
    """
    n_cells = start.shape[0] - 1
    for i in range(n_cells):
        sa = 0.0
        sb = 0.0
        for k in range(start[i], start[i + 1]):
            lx, ly, lz = l[k, 0], l[k, 1], l[k, 2]
            vx, vy, vz = v[k, 0], v[k, 1], v[k, 2]
            if w[k] == 0.0 or not (lz > 0.0 and vz > 0.0):
                continue
            hx, hy, hz = half_vector(lx, ly, lz, vx, vy, vz)
            d = ggx_d(hx, hy, hz, alpha, alpha)
            g = smith_g2(ggx_lambda(lx, ly, lz, alpha, alpha), ggx_lambda(vx, vy, vz, alpha, alpha), False, True)
            q = w[k] * d * g / (4.0 * lz * vz)
            sa += q * (1.0 - schlick[k])
            sb += q * schlick[k]
        A[i] = sa
        B[i] = sb


# =========================================================================== samples

@dataclass
class Samples:
    """Direction samples grouped by cell: cell ``i`` owns samples ``start[i]:start[i + 1]``.

    ``l``/``v`` (N, 3) unit light and view directions, ``w`` (N,) sub-cell weights normalised to
    sum 1 over each cell, ``start`` (n_cells + 1,) int64 offsets. Derived per-sample geometry is
    computed once here; invalid samples (``l_z <= 0``, ``v_z <= 0``, non-finite ``v``) get weight 0.
    """

    l: np.ndarray
    v: np.ndarray
    w: np.ndarray
    start: np.ndarray

    def __post_init__(self) -> None:
        l, v = self.l, self.v
        ok = (l[:, 2] > 0.0) & (v[:, 2] > 0.0) & np.all(np.isfinite(v), axis=1)
        self.valid = ok
        v = np.where(ok[:, None], v, np.array([0.0, 0.0, 1.0]))
        self.v = v
        h = l + v
        h /= np.linalg.norm(h, axis=1, keepdims=True)
        self.lz = np.where(ok, l[:, 2], 0.0)
        self.vz = np.where(ok, v[:, 2], 0.0)
        self.cos_h = h[:, 2]
        lh = np.clip(np.sum(l * h, axis=1), 0.0, 1.0)
        self.schlick = (1.0 - lh) ** 5  # Schlick weight m: F = F0 (1 - m) + m
        with np.errstate(divide="ignore", invalid="ignore"):
            self.tan_l = np.where(l[:, 2] > 0, np.sqrt(np.maximum(0.0, 1.0 - l[:, 2] ** 2)) / l[:, 2], np.inf)
            self.tan_v = np.where(self.vz > 0, np.sqrt(np.maximum(0.0, 1.0 - self.vz ** 2)) / self.vz, np.inf)
        self.ft2 = (l[:, 0] + v[:, 0]) ** 2 + (l[:, 1] + v[:, 1]) ** 2
        with np.errstate(divide="ignore"):
            self.ln_tan_l = np.log(self.tan_l)
            self.ln_tan_v = np.log(self.tan_v)
            self.ln_tan2_h = np.log(np.maximum(0.0, 1.0 - self.cos_h ** 2)) - np.log(self.cos_h ** 2)
            self.ln_cos2_h = np.log(self.cos_h ** 2)
        self.ln_tan2_h = np.where(ok, self.ln_tan2_h, -np.inf)
        self.ln_cos2_h = np.where(ok, self.ln_cos2_h, 0.0)
        self.w = np.ascontiguousarray(np.where(ok, self.w, 0.0))
        self.start = np.ascontiguousarray(self.start, dtype=np.int64)

    @property
    def n_cells(self) -> int:
        return self.start.shape[0] - 1

    @classmethod
    def directions(cls, l: np.ndarray, v: np.ndarray) -> "Samples":
        """One sample per direction (model evaluation): ``l`` (3,), ``v`` (N, 3)."""
        v = np.ascontiguousarray(v, dtype=np.float64).reshape(-1, 3)
        ll = np.ascontiguousarray(np.broadcast_to(np.asarray(l, dtype=np.float64), v.shape))
        return cls(ll, v, np.ones(v.shape[0]), np.arange(v.shape[0] + 1))


# =========================================================================== families

@dataclass(frozen=True)
class ParamSpec:
    """One named parameter (scalar or RGB) with its bounds and internal coordinate.

    Internal coordinate: ``ln x`` if ``log`` else ``x / scale`` (``scale`` per channel; for a
    scaled parameter ``lower``, ``upper``, ``typical`` and ``start`` are given in units of
    ``scale``). ``typical`` is the (lower, upper) range random starts draw from (log-uniform if
    ``log``); ``start`` the value of start 0.
    """

    name: str
    size: int
    lower: float
    upper: float
    log: bool = False
    scale: tuple[float, ...] | None = None
    typical: tuple[float, float] | None = None
    linear: bool = False  # the model is affine in it: solved linearly before each start
    positive: bool = False  # must be > 0 for the model to be defined (implied by log)
    start: float = 0.0


class Family:
    """A parametric BRDF family: parameter layout, evaluation and Jacobian on :class:`Samples`."""

    kind: str = ""
    specs: tuple[ParamSpec, ...] = ()

    # ------------------------------------------------------------- layout
    @property
    def size(self) -> int:
        return sum(s.size for s in self.specs)

    def slices(self) -> dict[str, slice]:
        out, k = {}, 0
        for s in self.specs:
            out[s.name] = slice(k, k + s.size)
            k += s.size
        return out

    def _scale(self, s: ParamSpec) -> np.ndarray:
        return np.ones(s.size) if s.scale is None else np.asarray(s.scale, dtype=float)

    def to_internal(self, x: np.ndarray) -> np.ndarray:
        z = np.empty(self.size)
        for s, sl in zip(self.specs, self.slices().values()):
            z[sl] = np.log(x[sl]) if s.log else x[sl] / self._scale(s)
        return z

    def to_natural(self, z: np.ndarray) -> np.ndarray:
        x = np.empty(self.size)
        for s, sl in zip(self.specs, self.slices().values()):
            x[sl] = np.exp(z[sl]) if s.log else z[sl] * self._scale(s)
        return x

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounds in natural coordinates."""
        lo, hi = np.empty(self.size), np.empty(self.size)
        for s, sl in zip(self.specs, self.slices().values()):
            lo[sl], hi[sl] = s.lower * self._scale(s), s.upper * self._scale(s)
        return lo, hi

    def internal_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = self.bounds()
        return self.to_internal(lo), self.to_internal(hi)

    def linear_mask(self) -> np.ndarray:
        m = np.zeros(self.size, dtype=bool)
        for s, sl in zip(self.specs, self.slices().values()):
            m[sl] = s.linear
        return m

    def to_dict(self, x: np.ndarray) -> dict[str, float | list[float]]:
        out: dict[str, float | list[float]] = {}
        for s, sl in zip(self.specs, self.slices().values()):
            val = [float(t) for t in x[sl]]
            out[s.name] = val[0] if s.size == 1 else val
        return out

    def from_dict(self, params: dict) -> np.ndarray:
        x = np.empty(self.size)
        for s, sl in zip(self.specs, self.slices().values()):
            if s.name not in params:
                raise ModelError(f"{self.kind}-fit: parameter {s.name!r} is missing")
            x[sl] = np.broadcast_to(np.asarray(params[s.name], dtype=float), (s.size,))
        return x

    def check(self, x: np.ndarray) -> str | None:
        """Why ``x`` is not a valid parameter vector (None if it is)."""
        if x.shape != (self.size,):
            return f"needs {self.size} parameters ({', '.join(s.name for s in self.specs)}), got {x.size}"
        if not np.all(np.isfinite(x)):
            return "parameters must be finite"
        for s, sl in zip(self.specs, self.slices().values()):
            if (s.log or s.positive) and np.any(x[sl] <= 0):
                return f"{s.name} must be > 0"
            if not s.log and np.any(x[sl] < 0) and s.lower >= 0:
                return f"{s.name} must be >= 0"
        return None

    def start_point(self) -> np.ndarray:
        x = np.empty(self.size)
        for s, sl in zip(self.specs, self.slices().values()):
            x[sl] = s.start * self._scale(s)
        return x

    def random_point(self, rng: np.random.Generator) -> np.ndarray:
        """A random start: every colour equal over the channels (as the paper), shapes log-uniform."""
        x = np.empty(self.size)
        for s, sl in zip(self.specs, self.slices().values()):
            lo, hi = s.typical if s.typical is not None else (s.lower, s.upper)
            u = rng.uniform()
            x[sl] = math.exp(math.log(lo) + u * (math.log(hi) - math.log(lo))) if s.log else lo + u * (hi - lo)
            x[sl] *= self._scale(s)
        return x

    # ------------------------------------------------------------- evaluation
    def evaluate(self, x: np.ndarray, smp: Samples) -> np.ndarray:
        """Cell values (n_cells, 3) for natural parameters ``x``."""
        return self.cells_and_jac(self.to_internal(x), smp, jac=False)[0]

    def cells_and_jac(self, z: np.ndarray, smp: Samples, jac: bool) -> tuple[np.ndarray, "SparseJac | None"]:
        """Cell values (n_cells, 3) and, if asked, their Jacobian in internal coordinates."""
        raise NotImplementedError

    def dense_jac(self, jac: "SparseJac") -> np.ndarray:
        """The Jacobian as a dense (n_cells, 3, P) array (tests and diagnostics)."""
        V, cols = jac
        out = np.zeros((V.shape[2], 3, self.size))
        for c in range(3):
            for k in range(cols.shape[1]):
                out[:, c, cols[c, k]] += V[c, k]
        return out


#: A Jacobian with a fixed sparsity pattern per colour channel: ``(V, cols)``; row (cell ``i``,
#: channel ``c``) has the values ``V[c, :, i]`` in the columns ``cols[c, :]`` (others are 0).
#: Colour parameters of one channel only touch that channel's rows.
SparseJac = tuple[np.ndarray, np.ndarray]


_FD_STEP = 1e-4  # central-difference step in internal (mostly log) coordinates


class GGXFamily(Family):
    """Diffuse + ``n_lobes`` GGX lobes with a Schlick Fresnel shape (see the module docstring).

    Lobe ``j``: ``ks_j F_S(F0_j, l.h) / F0_j * D G2 / (4 l_z v_z)`` -- ``ks`` (RGB) is the lobe's
    Fresnel factor at normal incidence, the scalar ``F0`` only shapes the grazing rise
    ``(1 - m) + m / F0`` (``m = (1 - l.h)^5``). ``ks = 0`` switches a lobe off, so one lobe nests
    in two.
    """

    def __init__(self, n_lobes: int) -> None:
        self.n_lobes = n_lobes
        self.kind = f"ggx{n_lobes}"
        specs = [ParamSpec("kd", 3, 0.0, 1.0, typical=(0.0, 1.0), linear=True, start=0.5)]
        starts = (0.1,) if n_lobes == 1 else (0.05, 0.3)
        for j in range(n_lobes):
            sfx = "" if n_lobes == 1 else f"_{j + 1}"
            specs.append(ParamSpec(f"ks{sfx}", 3, 0.0, 5.0, typical=(0.0, 1.0), linear=True, start=0.05))
            specs.append(ParamSpec(f"F0{sfx}", 1, 0.02, 1.0, log=True, typical=(0.02, 1.0), start=0.04))
            specs.append(ParamSpec(f"alpha{sfx}", 1, 1e-3, 1.5, log=True, typical=(0.01, 1.0), start=starts[j]))
        self.specs = tuple(specs)

    def lobe(self, alpha: float, smp: Samples) -> tuple[np.ndarray, np.ndarray]:
        """Cell averages ``(<q (1 - m)>, <q m>)`` of the lobe shape ``q`` (see :func:`_ggx_lobe`)."""
        A = np.empty(smp.n_cells)
        B = np.empty(smp.n_cells)
        _ggx_lobe(smp.l, smp.v, smp.schlick, smp.w, smp.start, float(alpha), A, B)
        return A, B

    def cells_and_jac(self, z, smp, jac):
        s = self.slices()
        x = self.to_natural(z)
        n = smp.n_cells
        f = np.broadcast_to(x[s["kd"]] * _INV_PI, (n, 3)).copy()
        K = 1 + 3 * self.n_lobes
        V = np.empty((3, K, n)) if jac else None
        cols = np.empty((3, K), dtype=np.int64)
        for c in range(3):
            cols[c, 0] = s["kd"].start + c
            if jac:
                V[c, 0] = _INV_PI
        for j in range(self.n_lobes):
            sfx = "" if self.n_lobes == 1 else f"_{j + 1}"
            s_ks, s_f0, s_a = s["ks" + sfx], s["F0" + sfx], s["alpha" + sfx]
            ks, f0 = x[s_ks], x[s_f0][0]
            A, B = self.lobe(x[s_a][0], smp)
            shape = A + B / f0
            f += shape[:, None] * ks[None, :]
            if not jac:
                continue
            za = z[s_a][0]
            Ap, Bp = self.lobe(math.exp(za + _FD_STEP), smp)
            Am, Bm = self.lobe(math.exp(za - _FD_STEP), smp)
            dshape = ((Ap - Am) + (Bp - Bm) / f0) / (2.0 * _FD_STEP)
            for c in range(3):
                cols[c, 1 + 3 * j: 4 + 3 * j] = (s_ks.start + c, s_f0.start, s_a.start)
                V[c, 1 + 3 * j] = shape
                V[c, 2 + 3 * j] = -(B / f0) * ks[c]   # d/d(ln F0) of B / F0 is -B / F0
                V[c, 3 + 3 * j] = dshape * ks[c]
        return f, ((V, cols) if jac else None)


class HP15Family(Family):
    """Holzschuch & Pacanowski 2015, eq. 24-27 (see the module docstring)."""

    kind = "hp15"
    specs = (
        ParamSpec("kd", 3, 0.0, 1.0, typical=(0.0, 1.0), linear=True, start=0.5),
        ParamSpec("ks", 3, 0.0, 50.0, typical=(0.0, 1.0), linear=True, start=1.0),
        # in units of lambda^4: kw / lambda^4 is the diffraction albedo at normal incidence
        ParamSpec("kw", 3, 0.0, 2.0, scale=tuple(WAVELENGTHS_UM ** 4), typical=(0.0, 1.0), linear=True, start=0.1),
        ParamSpec("F0", 3, 0.02, 1.2, typical=(0.02, 1.0), start=0.04),
        ParamSpec("sigma", 1, 1e-6, 4.0, log=True, typical=(1e-3, 1.0), start=0.1),
        ParamSpec("p", 1, 0.1, 5.0, typical=(0.2, 1.5), start=0.6, positive=True),
        ParamSpec("a", 1, 1e-3, 1e3, log=True, typical=(0.1, 10.0), start=1.0),
    )

    @staticmethod
    def table(p: float) -> tuple[float, float, np.ndarray]:
        return hp_lambda_table(float(p), _TABLE_N, _QUAD_NODES, _QUAD_WEIGHTS, _QUAD_PANELS)

    def pieces(self, sigma: float, p: float, a: float, smp: Samples,
               table=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cell averages ``A = <q (1 - m)>``, ``B = <q m>`` (n_cells,) and ``R = <r>`` (n_cells, 3)."""
        x0, dx, vals = self.table(p) if table is None else table
        A = np.empty(smp.n_cells)
        B = np.empty(smp.n_cells)
        R = np.empty((smp.n_cells, 3))
        _hp_pieces(smp.lz, smp.vz, smp.ln_tan_l, smp.ln_tan_v, smp.ln_tan2_h, smp.ln_cos2_h, smp.schlick, smp.ft2,
                   smp.w, smp.start, float(sigma), float(p), float(a), x0, dx, vals, WAVELENGTHS_UM, A, B, R)
        return A, B, R

    def cells_and_jac(self, z, smp, jac):
        s = self.slices()
        x = self.to_natural(z)
        kd, ks, kw, f0 = x[s["kd"]], x[s["ks"]], x[s["kw"]], x[s["F0"]]
        sigma, p, a = x[s["sigma"]][0], x[s["p"]][0], x[s["a"]][0]
        table = self.table(p)
        A, B, R = self.pieces(sigma, p, a, smp, table)

        def combine(A, B, R):
            return ks[None, :] * (A[:, None] * f0[None, :] + B[:, None]) + R * kw[None, :]

        f = kd[None, :] * _INV_PI + combine(A, B, R)
        if not jac:
            return f, None
        kw_scale = WAVELENGTHS_UM ** 4
        V = np.empty((3, 7, smp.n_cells))
        cols = np.empty((3, 7), dtype=np.int64)
        for c in range(3):
            cols[c] = (s["kd"].start + c, s["ks"].start + c, s["kw"].start + c, s["F0"].start + c,
                       s["sigma"].start, s["p"].start, s["a"].start)
            V[c, 0] = _INV_PI
            V[c, 1] = A * f0[c] + B
            V[c, 2] = R[:, c] * kw_scale[c]
            V[c, 3] = ks[c] * A
        h = _FD_STEP
        zs, za = z[s["sigma"]][0], z[s["a"]][0]
        hp = h * max(p, 0.1)
        # sigma and a (log coordinates) share the table; p needs its own
        steps = ((4, h, (math.exp(zs + h), p, a, table), (math.exp(zs - h), p, a, table)),
                 (6, h, (sigma, p, math.exp(za + h), table), (sigma, p, math.exp(za - h), table)),
                 (5, hp, (sigma, p + hp, a, None), (sigma, p - hp, a, None)))
        for k, step, plus, minus in steps:
            fp = combine(*self.pieces(plus[0], plus[1], plus[2], smp, plus[3]))
            fm = combine(*self.pieces(minus[0], minus[1], minus[2], smp, minus[3]))
            V[:, k] = ((fp - fm) / (2 * step)).T
        return f, (V, cols)


FAMILIES: dict[str, Callable[[], Family]] = {
    "hp15": HP15Family,
    "ggx1": lambda: GGXFamily(1),
    "ggx2": lambda: GGXFamily(2),
}


# =========================================================================== Model classes

class FittedModel(Model):
    """A fitted BRDF, constructed from its natural parameter vector (order of ``param_names``).

    Stack-agnostic (``support_reason`` is always None): the parameters came from one file.
    The whole BRDF is returned in ``ModelValue.internal``; ``top`` is 0 (no split in a fit).
    """

    sides = ("brdf",)
    kind: str = ""
    #: a fit describes the file, whatever the stack: anisotropic materials are fitted like others
    anisotropic = True

    def __init__(self, x: Sequence[float] | np.ndarray) -> None:
        self.family = FAMILIES[self.kind]()
        x = np.array(x, dtype=np.float64).reshape(-1)
        reason = self.family.check(x)
        if reason is not None:
            raise ModelError(f"{self.name}: {reason}")
        self.x = x
        self._table = self.family.table(x[self.family.slices()["p"]][0]) if self.kind == "hp15" else None

    @classmethod
    def from_params(cls, params: dict) -> "FittedModel":
        """Build from a ``{name: value or RGB list}`` dict (as :attr:`params` / ``FitResult.params``)."""
        return cls(FAMILIES[cls.kind]().from_dict(params))

    @classmethod
    def param_names(cls) -> list[str]:
        return [s.name for s in FAMILIES[cls.kind]().specs]

    @property
    def params(self) -> dict[str, float | list[float]]:
        return self.family.to_dict(self.x)

    def support_reason(self, stack: Stack) -> str | None:
        return None

    def _evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> ModelValue:
        smp = Samples.directions(l, v)
        if self.kind == "hp15":
            f = self._hp_evaluate(smp)
        else:
            f = self.family.evaluate(self.x, smp)
        f = np.where(smp.valid[:, None], f, 0.0).reshape(v.shape[:-1] + (3,))
        return ModelValue(np.zeros_like(f), f)

    def _hp_evaluate(self, smp: Samples) -> np.ndarray:
        s = self.family.slices()
        x = self.x
        A, B, R = self.family.pieces(x[s["sigma"]][0], x[s["p"]][0], x[s["a"]][0], smp, self._table)
        ks, f0, kw = x[s["ks"]], x[s["F0"]], x[s["kw"]]
        return x[s["kd"]][None, :] * _INV_PI + ks * (A[:, None] * f0 + B[:, None]) + R * kw


class HP15Fit(FittedModel):
    """Holzschuch & Pacanowski 2015 (eq. 24-27): diffuse + Cook-Torrance with their distribution + diffraction."""

    name = "hp15-fit"
    kind = "hp15"
    description = "Holzschuch-Pacanowski 2015 fitted: diffuse + exponential-power Cook-Torrance + diffraction (15 parameters)"


class GGX1Fit(FittedModel):
    """Lambertian + one GGX lobe with a Schlick Fresnel shape, fitted (8 parameters)."""

    name = "ggx1-fit"
    kind = "ggx1"
    description = "fitted Lambertian + one GGX lobe (RGB ks, Schlick F0), 8 parameters"


class GGX2Fit(FittedModel):
    """Lambertian + two GGX lobes with Schlick Fresnel shapes, fitted (13 parameters)."""

    name = "ggx2-fit"
    kind = "ggx2"
    description = "fitted Lambertian + two GGX lobes (RGB ks, Schlick F0), 13 parameters"


MODELS: dict[str, type[FittedModel]] = {"hp15": HP15Fit, "ggx1": GGX1Fit, "ggx2": GGX2Fit}


def model_class(kind: str) -> type[FittedModel]:
    """The model class of ``kind`` ("hp15", "ggx1", "ggx2" or their "-fit" names)."""
    k = kind[:-4] if kind.endswith("-fit") else kind
    if k not in MODELS:
        raise ModelError(f"unknown fitted model {kind!r} (known: {', '.join(MODELS)})")
    return MODELS[k]


# =========================================================================== fitting

@dataclass
class FitResult:
    """The outcome of :func:`fit`. Every number is finite.

    ``params``: natural parameters by name (scalars or RGB lists); ``param_stderr``: their
    standard errors propagated from the reference's Monte Carlo standard errors through the
    weighted least-squares problem (sandwich estimate at the solution; ``None`` where the data do
    not constrain a parameter at all; meaningless for a parameter sitting on a bound).
    ``cost``: ``0.5 sum r^2`` of the best start (see the module docstring for the weighting);
    ``converged``/``message``: from ``least_squares`` for the best start; ``errors``:
    ``{"internal": E, "total": E}`` (eq. 4, the same comparison twice) of the fitted model
    integrated onto the reference cells with ``s = 5``.
    """

    kind: str
    params: dict[str, float | list[float]]
    cost: float
    converged: bool
    message: str
    model: FittedModel
    errors: dict | None = None
    param_stderr: dict[str, float | list[float | None] | None] = field(default_factory=dict)
    starts: int = 0
    nfev: int = 0
    n_cells: int = 0
    subcells: int = 1
    peak_subcells: int = 1
    weighting: str = "paper"
    elapsed_s: float = 0.0
    costs: list[float] = field(default_factory=list)

    @property
    def name(self) -> str:
        return self.model.name

    def to_json(self) -> dict:
        """A JSON-ready summary (what ``gonio fit --json`` may print)."""
        return {
            "model": self.model.name, "kind": self.kind, "params": self.params,
            "param_stderr": self.param_stderr, "cost": self.cost, "converged": self.converged,
            "message": self.message, "errors": self.errors, "starts": self.starts, "nfev": self.nfev,
            "n_cells": self.n_cells, "subcells": self.subcells, "peak_subcells": self.peak_subcells,
            "weighting": self.weighting,
            "elapsed_s": self.elapsed_s,
        }


@dataclass
class FitData:
    """The fitting problem of one reference: samples, reference values and residual weights."""

    samples: Samples
    ref: np.ndarray        # (n_cells, 3)
    stderr: np.ndarray     # (n_cells, 3)
    weight: np.ndarray     # (n_cells,) residual weight W (r = sqrt(W) (f - ref))
    subcells: int
    peak_subcells: int
    n_peak: int = 0
    note: str = ""


#: sub-cell sizes the automatic rules aim at (degrees): everywhere, and near the mirror direction
AUTO_SUBCELL_DEG = 1.0
AUTO_PEAK_SUBCELL_DEG = 0.25
#: cells whose centre lies within this angle of the mirror direction get ``peak_subcells``
PEAK_DEG = 8.0


def _cell_extent_deg(sd: SliceData) -> float:
    g = sd.grid
    return max(90.0 / g.n_theta, 360.0 / g.n_phi)


def auto_subcells(sd: SliceData) -> int:
    """Sub-cells per axis so that sub-cells are at most ~1 degree (1 to 5)."""
    return int(min(5, max(1, math.ceil(_cell_extent_deg(sd) / AUTO_SUBCELL_DEG - 1e-9))))


def auto_peak_subcells(sd: SliceData, subcells: int) -> int:
    """Sub-cells per axis near the mirror direction: ~0.25 degree for classic grids (at most 5).

    Half grids already concentrate small cells around the mirror direction; they keep ``subcells``.
    """
    if sd.grid.parametrization != "classic":
        return subcells
    return int(max(subcells, min(5, math.ceil(_cell_extent_deg(sd) / AUTO_PEAK_SUBCELL_DEG - 1e-9))))


def fit_data(reference: SimulationResult, subcells: int | None = None, weighting: str = "paper",
             grazing: float = GRAZING_RAD, peak_subcells: int | None = None,
             peak_deg: float = PEAK_DEG) -> FitData:
    """Select the cells to fit and build their samples and weights (see the module docstring).

    A cell is used if it is valid in the reference mask, its value is finite and (paper
    weighting) neither the incident direction nor the cell centre is beyond ``grazing`` rad.
    Cells whose centre is within ``peak_deg`` of the mirror direction get ``peak_subcells`` sub-cells
    per axis, the others ``subcells`` (None: automatic).
    """
    if weighting not in ("paper", "eq4"):
        raise ModelError(f"fit: weighting {weighting!r} is not one of paper, eq4")
    sd = reference.brdf
    s = auto_subcells(sd) if subcells is None else int(subcells)
    sp = auto_peak_subcells(sd, s) if peak_subcells is None else int(peak_subcells)
    if s < 1 or sp < 1:
        raise ModelError(f"fit: sub-cells ({s}, {sp}) must be >= 1")
    M = len(reference.theta_deg)
    cos_cut = math.cos(grazing)
    cos_peak = math.cos(math.radians(peak_deg))
    parts: dict[str, list] = {k: [] for k in ("l", "v", "w", "n", "ref", "se", "W", "keep")}
    n_peak = 0
    for m in range(M):
        light = light_direction(reference.theta_deg[m], reference.phi_deg[m])
        vb, wb = sd.grid.subcells(light, s)
        ref = sd.value[m].transpose(1, 2, 0)
        se = sd.stderr[m].transpose(1, 2, 0)
        ok = (sd.mask[m] & (wb.sum(axis=(2, 3)) > 0) & np.all(np.isfinite(ref), axis=-1)
              & (sd.proj_solid_angle[m] > 0))
        centre = np.einsum("ijab,ijabk->ijk", wb, vb)
        centre /= np.maximum(np.linalg.norm(centre, axis=-1, keepdims=True), 1e-300)
        mirror = np.array([-light[0], -light[1], light[2]])
        peak = ok & (centre @ mirror > cos_peak) if sp != s else np.zeros_like(ok)
        groups = [(ok & ~peak, vb, wb, s)]
        if peak.any():
            vp, wp = sd.grid.subcells(light, sp)
            peak &= wp.sum(axis=(2, 3)) > 0
            groups.append((peak, vp, wp, sp))
            n_peak += int(peak.sum())
        for sel, v, w, ss in groups:
            idx = np.nonzero(sel)
            if idx[0].size == 0:
                continue
            vv = v[idx].reshape(-1, ss * ss, 3)
            ww = w[idx].reshape(-1, ss * ss)
            ww = ww / ww.sum(axis=1, keepdims=True)
            vz = vv[..., 2]
            inv_cos = np.divide(1.0, vz, out=np.zeros_like(vz), where=vz > 0)
            omega = sd.proj_solid_angle[m][idx]
            if weighting == "paper":
                W = light[2] ** 2 * omega * np.sum(ww * inv_cos, axis=1) / M
                keep = (centre[idx][:, 2] > cos_cut) & (light[2] > cos_cut)
            else:
                W = omega / M
                keep = np.ones(W.shape, dtype=bool)
            parts["l"].append(np.broadcast_to(light, (vv.shape[0] * ss * ss, 3)))
            parts["v"].append(vv.reshape(-1, 3))
            parts["w"].append(ww.ravel())
            parts["n"].append(np.full(vv.shape[0], ss * ss))
            parts["ref"].append(ref[idx])
            parts["se"].append(np.where(np.isfinite(se[idx]), se[idx], 0.0))
            parts["W"].append(W)
            parts["keep"].append(keep)
    if not parts["W"]:
        raise ModelError("fit: the reference has no valid BRDF cells to fit")
    keep = np.concatenate(parts["keep"])
    note = ""
    if not keep.any():
        keep[:] = True
        note = f"no data left after excluding directions beyond {grazing:g} rad from the normal; fitted all valid cells"
    counts = np.concatenate(parts["n"])
    keep_s = np.repeat(keep, counts)
    start = np.concatenate([[0], np.cumsum(counts[keep])])
    smp = Samples(np.ascontiguousarray(np.concatenate(parts["l"])[keep_s]),
                  np.ascontiguousarray(np.concatenate(parts["v"])[keep_s]),
                  np.ascontiguousarray(np.concatenate(parts["w"])[keep_s]), start)
    return FitData(smp, np.ascontiguousarray(np.concatenate(parts["ref"])[keep]),
                   np.concatenate(parts["se"])[keep], np.concatenate(parts["W"])[keep], s, sp, n_peak, note)


@njit(cache=True, fastmath={"reassoc", "contract"})
def _gram(f: np.ndarray, V: np.ndarray, cols: np.ndarray, ref: np.ndarray, sw: np.ndarray, d: np.ndarray,
          big: float, n: int):
    """Normal equations of the weighted residuals (no (m x n) temporaries, no BLAS threads).

    Residual of cell ``i``, channel ``c``: ``r = sw_i (f_ic - ref_ic)``; its Jacobian row has
    ``sw_i V[c, k, i]`` in column ``cols[c, k]`` (see :data:`SparseJac`). Returns
    ``(J^T diag(d) J, J^T r, r^T r)`` with ``n`` columns. Non-finite model values count as
    ``big`` and non-finite Jacobian entries as 0 (the NaN guard of the module docstring).
    """
    n_cells = f.shape[0]
    K = cols.shape[1]
    G = np.zeros((n, n))
    g = np.zeros(n)
    rr = 0.0
    r = np.empty(n_cells)
    rows = np.empty((K, n_cells))
    rows_d = np.empty(n_cells)
    for c in range(3):
        for i in range(n_cells):
            fv = f[i, c]
            if not math.isfinite(fv):
                fv = big
            r[i] = sw[i] * (fv - ref[i, c])
            rr += r[i] * r[i]
        for a in range(K):
            for i in range(n_cells):
                x = V[c, a, i]
                rows[a, i] = sw[i] * x if math.isfinite(x) else 0.0
        for a in range(K):
            ca = cols[c, a]
            ra = rows[a]
            acc = 0.0
            for i in range(n_cells):
                acc += ra[i] * r[i]
            g[ca] += acc
            for i in range(n_cells):
                rows_d[i] = ra[i] * d[i, c]
            for b in range(a, K):
                cb = cols[c, b]
                rb = rows[b]
                acc = 0.0
                for i in range(n_cells):
                    acc += rows_d[i] * rb[i]
                G[ca, cb] += acc
                if b != a:
                    G[cb, ca] += acc
    return G, g, rr


def _square_root(G: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(R, t)`` (n, n) and (n,) with ``R^T R = G`` and ``R^T t = g`` (for ``g`` in the range of ``G``).

    Eigen-decomposition of the column-scaled ``G`` (robust to rank deficiency: eigenvalues below
    1e-14 of the largest are dropped, their rows of ``R`` are 0).
    """
    n = G.shape[0]
    d = np.sqrt(np.maximum(np.diag(G), 0.0))
    d = np.where(d > 0, d, 1.0)
    lam, V = np.linalg.eigh(G / np.outer(d, d))
    keep = lam > max(lam.max(), 0.0) * 1e-14
    R = np.zeros((n, n))
    t = np.zeros(n)
    if keep.any():
        sq = np.sqrt(lam[keep])
        R[: keep.sum()] = (sq[:, None] * V[:, keep].T) * d[None, :]
        t[: keep.sum()] = (V[:, keep].T @ (g / d)) / sq
    return R, t


class _Problem:
    """The weighted residuals ``r = sqrt(W) (f - ref)`` (n_cells * 3) of one family on one data set.

    ``least_squares`` is given an equivalent **compressed** problem of n + 1 residuals: with
    ``R^T R = J^T J`` and ``R^T t = J^T r`` (:func:`_square_root`), the residual vector
    ``[t, sqrt(|r|^2 - |t|^2)]`` and Jacobian ``[R; 0]`` have exactly the cost, gradient and
    Gauss-Newton matrix of the full problem, so every trust-region step, the cost and the
    termination tests are the same; but the optimiser's dense linear algebra (an SVD per
    iteration) runs on an (n+1) x n matrix instead of a (3 n_cells) x n one. (On a shared machine
    a multithreaded BLAS on the tall matrix was 5-30x slower than the whole model evaluation.)
    Because the compressed residual needs ``J``, each new point evaluates the Jacobian too; the
    last point is cached, so the usual call ``fun(z)`` then ``jac(z)`` costs one evaluation.
    """

    def __init__(self, family: Family, data: FitData) -> None:
        self.family = family
        self.data = data
        self.sw = np.ascontiguousarray(np.sqrt(data.weight))
        self._ones = np.ones(data.ref.shape)
        self._z: np.ndarray | None = None
        self._cache: tuple | None = None

    def _point(self, z: np.ndarray) -> tuple:
        """Evaluate (cached) at internal point ``z``: ``(G, g, rr, comp_r, comp_J)``."""
        if self._z is not None and np.array_equal(z, self._z):
            return self._cache
        f, (V, cols) = self.family.cells_and_jac(z, self.data.samples, True)
        G, g, rr = _gram(f, V, cols, self.data.ref, self.sw, self._ones, NONFINITE_VALUE, self.family.size)
        R, t = _square_root(G, g)
        extra = math.sqrt(max(0.0, rr - float(t @ t)))
        comp_r = np.concatenate([t, [extra]])
        comp_J = np.vstack([R, np.zeros((1, R.shape[1]))])
        self._z = z.copy()
        self._cache = (G, g, rr, comp_r, comp_J, f, V, cols)
        return self._cache

    def gram(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(J^T J, J^T r)`` of the full weighted problem at ``z``."""
        c = self._point(z)
        return c[0], c[1]

    def cost(self, z: np.ndarray) -> float:
        """``0.5 |r|^2`` of the full weighted problem at ``z``."""
        return 0.5 * self._point(z)[2]

    def residuals(self, z: np.ndarray) -> np.ndarray:
        """Compressed residuals (n + 1,)."""
        return self._point(z)[3]

    def jacobian(self, z: np.ndarray) -> np.ndarray:
        """Compressed Jacobian (n + 1, n)."""
        return self._point(z)[4]

    def sandwich(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(J^T J, J^T diag(W se^2) J)`` at ``z`` (for parameter standard errors)."""
        G, _, _, _, _, f, V, cols = self._point(z)
        var_r = np.ascontiguousarray((self.data.stderr * self.sw[:, None]) ** 2)  # variance of each residual
        B, _, _ = _gram(f, V, cols, self.data.ref, self.sw, var_r, NONFINITE_VALUE, self.family.size)
        return G, B

    def linear_init(self, z: np.ndarray) -> np.ndarray:
        """Solve the affine (colour) parameters by bounded linear least squares, others fixed.

        The residual is affine in them: ``r(z_lin) = r0 + J_lin (z_lin - z_lin0)``; the bounded
        problem is solved in its compressed (Gram square-root) form.
        """
        lin = self.family.linear_mask()
        if not lin.any():
            return z
        lo, hi = self.family.internal_bounds()
        G, g = self.gram(z)
        Gl = G[np.ix_(lin, lin)]
        # min |J_l x + (r0 - J_l x0)|^2  <=>  min x^T Gl x - 2 x^T gl
        gl = Gl @ z[lin] - g[lin]
        R, t = _square_root(Gl, gl)
        if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
            return z
        try:
            sol = lsq_linear(R, t, bounds=(lo[lin], hi[lin]), method="bvls")
        except (ValueError, np.linalg.LinAlgError):  # pragma: no cover - degenerate data
            return z
        out = z.copy()
        out[lin] = np.clip(sol.x, lo[lin], hi[lin])
        return out


def _stderr(problem: _Problem, z: np.ndarray) -> np.ndarray:
    """Sandwich standard errors of the natural parameters at ``z`` (NaN where unconstrained).

    ``Cov = (J^T J)^+ J^T diag(W se^2) J (J^T J)^+`` with ``se`` the reference's standard errors,
    computed on column-scaled matrices; converted from internal to natural coordinates.
    """
    G, Bm = problem.sandwich(z)
    norms = np.sqrt(np.maximum(np.diag(G), 0.0))
    ok = norms > 0
    out = np.full(G.shape[0], np.nan)
    if ok.any():
        dn = np.outer(norms[ok], norms[ok])
        A = np.linalg.pinv(G[np.ix_(ok, ok)] / dn, rcond=1e-12, hermitian=True)
        cov = A @ (Bm[np.ix_(ok, ok)] / dn) @ A
        out[ok] = np.sqrt(np.maximum(np.diag(cov), 0.0)) / norms[ok]
    fam = problem.family
    x = fam.to_natural(z)
    for s, sl in zip(fam.specs, fam.slices().values()):
        out[sl] = out[sl] * (x[sl] if s.log else fam._scale(s))
    return out


def _stderr_dict(family: Family, se: np.ndarray) -> dict:
    out: dict = {}
    for s, sl in zip(family.specs, family.slices().values()):
        vals = [float(t) if np.isfinite(t) else None for t in se[sl]]
        out[s.name] = vals[0] if s.size == 1 else vals
    return out


def _run_starts(problem: _Problem, starts: list[np.ndarray], max_nfev: int,
                progress: Callable[[int, float], None] | None):
    """Run ``least_squares`` from every start (natural coordinates); return all results."""
    fam = problem.family
    lo, hi = fam.internal_bounds()
    results = []
    for k, x0 in enumerate(starts):
        z0 = np.clip(fam.to_internal(np.clip(x0, *fam.bounds())), lo, hi)
        z0 = problem.linear_init(z0)
        res = least_squares(problem.residuals, z0, jac=problem.jacobian, bounds=(lo, hi), method="trf",
                            max_nfev=max_nfev, x_scale=1.0)
        results.append(res)
        if progress is not None:
            progress(k, float(res.cost))
    return results


def _best(results: list) -> object:
    """The start with the lowest cost; a converged start within 1e-6 (relative) of it is preferred.

    (A flat valley -- e.g. two GGX lobes fitting data that have one -- can leave a start crawling
    to a cost lower by 1e-9 when its budget runs out while another has converged.)
    """
    best = min(results, key=lambda r: r.cost)
    if best.status > 0:
        return best
    ok = [r for r in results if r.status > 0 and r.cost <= best.cost * (1.0 + 1e-6) + 1e-300]
    return min(ok, key=lambda r: r.cost) if ok else best


def _finite_slices(sd: SliceData) -> SliceData:
    """``sd`` with cells holding non-finite reference values masked out (and zeroed) for the errors.

    Simulated files never hold such values; this keeps a hand-made reference from turning the
    reported errors into NaN. Returns ``sd`` itself when everything is finite.
    """
    bad = ~np.all(np.isfinite(sd.value), axis=1) | ~np.all(np.isfinite(sd.stderr), axis=1)
    if not bad.any():
        return sd
    keep = ~bad[:, None]
    return replace(sd, value=np.where(keep, sd.value, 0.0), stderr=np.where(keep, sd.stderr, 0.0),
                   mask=sd.mask & ~bad)


def _sort_lobes(family: Family, x: np.ndarray) -> np.ndarray:
    """GGX2: put the sharper lobe (smaller alpha) first."""
    if not isinstance(family, GGXFamily) or family.n_lobes != 2:
        return x
    s = family.slices()
    if x[s["alpha_1"]][0] <= x[s["alpha_2"]][0]:
        return x
    y = x.copy()
    for a, b in (("ks_1", "ks_2"), ("F0_1", "F0_2"), ("alpha_1", "alpha_2")):
        y[s[a]], y[s[b]] = x[s[b]], x[s[a]]
    return y


def fit(reference: SimulationResult, kind: str, *, side: str = "brdf", starts: int = 4, seed: int = 0,
        subcells: int | None = None, peak_subcells: int | None = None, weighting: str = "paper",
        max_nfev: int = 200, errors: bool = True,
        progress: Callable[[int, float], None] | None = None) -> FitResult:
    """Fit ``kind`` ("hp15", "ggx1", "ggx2") to every incident direction of ``reference``'s BRDF.

    ``starts``: number of optimiser starts (start 0 typical values, the others random from
    ``seed``); ggx2 adds one start at the best of a ggx1 fit with ``max(1, starts // 2)`` starts.
    ``subcells``/``peak_subcells``: sub-cells per axis inside the optimiser, away from / within
    8 degrees of the mirror direction (None: automatic, see the module docstring).
    ``weighting``: "paper" (eq. 29, grazing directions left out) or "eq4". ``max_nfev``:
    evaluation budget per start. ``errors``: also integrate the fitted model (s = 5) and compute
    eq. 4 errors. ``progress(start, cost)`` is called after each start. Raises
    :class:`ModelError` for a BTDF request or a reference without BRDF slices.
    """
    cls = model_class(kind)
    if side != "brdf":
        raise ModelError(f"{cls.name}: fitted models are BRDF models; cannot fit the {side.upper()}")
    if reference.brdf is None:
        raise ModelError(f"{cls.name}: the file has no BRDF slices to fit (fitted models are BRDF-only)")
    if starts < 1:
        raise ModelError(f"{cls.name}: starts = {starts} must be >= 1")
    t0 = time.perf_counter()
    data = fit_data(reference, subcells, weighting, peak_subcells=peak_subcells)
    family = FAMILIES[cls.kind]()
    problem = _Problem(family, data)
    rng = np.random.default_rng(seed)
    points = [family.start_point()] + [family.random_point(rng) for _ in range(starts - 1)]
    nfev = 0
    if cls.kind == "ggx2":
        g1 = FAMILIES["ggx1"]()
        n1 = max(1, starts // 2)
        sub = _run_starts(_Problem(g1, data), [g1.start_point()] + [g1.random_point(rng) for _ in range(n1 - 1)],
                          max_nfev, None)
        nfev += sum(r.nfev for r in sub)
        best1 = g1.to_natural(min(sub, key=lambda r: r.cost).x)
        s1, s2 = g1.slices(), family.slices()
        nested = family.start_point()
        for name in ("kd",):
            nested[s2[name]] = best1[s1[name]]
        for name in ("ks", "F0", "alpha"):
            nested[s2[name + "_1"]] = best1[s1[name]]
        nested[s2["ks_2"]] = 0.0
        nested[s2["alpha_2"]] = min(1.0, 4.0 * best1[s1["alpha"]][0])
        points.append(nested)
    results = _run_starts(problem, points, max_nfev, progress)
    best = _best(results)
    nfev += sum(r.nfev for r in results)
    z = best.x
    x = _sort_lobes(family, family.to_natural(z))
    z_sorted = family.to_internal(x)
    model = cls(x)
    se = _stderr(problem, z_sorted)
    converged = bool(best.status > 0)
    msg = str(best.message)
    if not converged:
        msg = f"did not converge: {msg}"
    if data.note:
        msg = f"{msg} ({data.note})"
    result = FitResult(
        kind=cls.kind, params=model.params, cost=problem.cost(z_sorted), converged=converged, message=msg,
        model=model, param_stderr=_stderr_dict(family, se), starts=len(points), nfev=int(nfev),
        n_cells=data.samples.n_cells, subcells=data.subcells, peak_subcells=data.peak_subcells, weighting=weighting,
        costs=[float(r.cost) for r in results],
    )
    if errors:
        ms = integrate(model, reference, "brdf", s=5)
        result.errors = compare(_finite_slices(reference.brdf), ms, drop_first_order=False)
    result.elapsed_s = time.perf_counter() - t0
    return result
