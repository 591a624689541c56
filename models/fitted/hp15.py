"""Holzschuch & Pacanowski 2015 (eq. 24-27): their micro-facet distribution, its Smith shadowing, the
diffraction lobe, and the fitted family ``hp15`` (:class:`HP15Family`, 15 parameters)::

    f = kd/pi + G(l, v) ( ks D(theta_h) F(theta_d) / (4 l_z v_z) + kw / lambda^4 S_z(f) / E_{a,lambda} )

``l``, ``v`` point away from the surface, ``z`` is the macro normal, values without cosine in 1/sr,
RGB last; ``lambda`` per channel (:data:`WAVELENGTHS_UM`, micrometres), ``a`` in 1/um. Where we
depart from the paper (eq. 18 vs 26, the Smith integral, the diffraction normalisation):
``docs/fitted.md``.
"""

from __future__ import annotations

import math

import numpy as np

from models._jit import njit
from models.fitted.family import FD_STEP, INV_PI, Family, ParamSpec
from models.fitted.samples import Samples

#: wavelengths of the R, G, B channels in micrometres (Holzschuch & Pacanowski 2015, sec. 5.5)
WAVELENGTHS_UM = np.array([0.645, 0.526, 0.444])

_LOG_PI = math.log(math.pi)
#: Lambda table: number of points in ln(a) and its upper end (linear extrapolation beyond)
_TABLE_N = 256
_TABLE_A_MAX = 1e5
#: Lambda quadrature: Gauss-Legendre panels x nodes per panel (see hp_lambda)
_QUAD_PANELS = 8
_QUAD_NODES, _QUAD_WEIGHTS = np.polynomial.legendre.leggauss(16)
#: exponent cut-off of the integrand exp(-u^p): e^-45 is negligible
_QUAD_EXP_CUT = 45.0


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

    (The paper prints ``pi (1 + 1/(a^2 lambda^2))``; see ``docs/fitted.md``.)
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

        f = kd[None, :] * INV_PI + combine(A, B, R)
        if not jac:
            return f, None
        kw_scale = WAVELENGTHS_UM ** 4
        V = np.empty((3, 7, smp.n_cells))
        cols = np.empty((3, 7), dtype=np.int64)
        for c in range(3):
            cols[c] = (s["kd"].start + c, s["ks"].start + c, s["kw"].start + c, s["F0"].start + c,
                       s["sigma"].start, s["p"].start, s["a"].start)
            V[c, 0] = INV_PI
            V[c, 1] = A * f0[c] + B
            V[c, 2] = R[:, c] * kw_scale[c]
            V[c, 3] = ks[c] * A
        h = FD_STEP
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

