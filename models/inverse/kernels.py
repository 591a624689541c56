"""Compiled kernels of the inverse method: FGD at normal incidence and the adding of Belcour 2018.

:func:`fgd_normal` is the forward model's FGD at ``mu = 1`` from the *same* angular kernel and
the same interpolation in ``alpha`` as the material slices (:mod:`models.tables.belcour`), so the
inverse's round trip through the forward model is exact up to root-finding tolerances where the
forward slice is unsplit (``docs/inverse.md``, "The inverse's own forward equations").
:func:`add_interface` and :func:`add_medium` update a context *state* (rows ``ROW_*`` per channel,
scalars ``SCALAR_*``) with Belcour 2018 section 6 at ``c = 1`` (per-channel statistics, no TIR,
normal-incidence transmission scales: ``docs/models.md``). Also the failure codes of the 2-layer
predicate (``OK``, ``FAIL_*``, :data:`FAIL_TEXT`) and Python wrappers (:func:`fgd_for`,
:func:`albedo_for`, :func:`dielectric_roots`) that take :class:`~models.inverse.lobes.InverseOptions`.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from goniometer import optics
from models._jit import njit
from models.tables import belcour as tables
from models.belcour import roughness_to_variance, variance_to_roughness
from models.inverse.equations import eq7_roots, eq19_scalar
from models.inverse.lobes import InverseOptions

#: failure codes of the 2-layer predicate (models.inverse.two_layer)
OK = 0
FAIL_TOP_VARIANCE = 1
FAIL_TOP_ENERGY = 2
FAIL_BOTTOM_ENERGY = 3
FAIL_BOTTOM_VARIANCE = 4
FAIL_NO_ETA2 = 5
FAIL_CONDUCTOR = 6
FAIL_TOP_TARGET = 7

#: why the 2-layer predicate failed, per failure code (messages of the classes)
FAIL_TEXT = {
    FAIL_TOP_VARIANCE: "the first interface would need a negative variance (sigma_R < 0, eq. 19): the layers above "
                       "already spread the lobe more than sigma",
    FAIL_TOP_ENERGY: "the first interface alone reflects at least the lobe's energy (eq. 20 target <= 0)",
    FAIL_BOTTOM_ENERGY: "the second interface would need a reflectance >= 1 (eq. 11/18)",
    FAIL_BOTTOM_VARIANCE: "the second interface would need a negative variance (sigma_R12 < 0, eq. 15/19)",
    FAIL_NO_ETA2: "no eta2 in [1, eta_max] reflects enough (eq. 14: N2 empty)",
    FAIL_CONDUCTOR: "the conductor base would need a reflectance above what a rough conductor reaches",
    FAIL_TOP_TARGET: "the stack above transmits too little: the lobe would need a reflectance >= 1 below it (eq. 18)",
}


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

#: rows of the context state (per channel; models.inverse.context)
ROW_R0, ROW_T0, ROW_RI, ROW_TI, ROW_VR0, ROW_VT0, ROW_VRI, ROW_VTI = range(8)
#: scalars: J0n, Jn0, eta_n (absolute index of the current medium)
SCALAR_J0, SCALAR_JI, SCALAR_ETA = range(3)


@njit(cache=True)
def add_interface(st, sc, w1, xs, alpha, eta_abs, kappa_abs, conductor, out_e, out_v) -> None:
    """Add one interface below the context (in place): Belcour 2018 section 6 (docs/models.md) at c = 1 with
    per-channel statistics, no TIR, normal-incidence transmission scales (eq. 6). ``out_e`` and
    ``out_v`` receive the energy and variance of this interface's lobe."""
    eta_cur = sc[SCALAR_ETA]
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
        at = variance_to_roughness(st[ROW_VT0, ch] + vr) if st[ROW_VT0, ch] > 0.0 else alpha
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
        d = 1.0 - st[ROW_RI, ch] * rdn
        if d > 0.0:
            inv = 1.0 / d
            e_k = st[ROW_T0, ch] * rdn * st[ROW_TI, ch] * inv
            rup2 = tup * st[ROW_RI, ch] * tdn * inv
            m = st[ROW_RI, ch] * rdn * inv
        else:
            inv = 0.0
            e_k = 0.0
            rup2 = 0.0
            m = 0.0
        v_k = st[ROW_VTI, ch] + sc[SCALAR_J0] * (st[ROW_VT0, ch] + vr + m * (vr + st[ROW_VRI, ch]))
        out_e[ch] = e_k
        out_v[ch] = v_k
        wsum = st[ROW_R0, ch] + e_k
        new_vr0 = (st[ROW_R0, ch] * st[ROW_VR0, ch] + e_k * v_k) / wsum if wsum > 0.0 else 0.0
        new_vt0 = jd * st[ROW_VT0, ch] + vtd + jd * (vr + st[ROW_VRI, ch]) * m
        wsum = rup + rup2
        new_vri = ((rup * vr + rup2 * (vtd + jd * (vtu + st[ROW_VRI, ch] + m * (vr + st[ROW_VRI, ch])))) / wsum
                   if wsum > 0.0 else 0.0)
        new_vti = sc[SCALAR_JI] * vtu + st[ROW_VTI, ch] + sc[SCALAR_JI] * (vr + st[ROW_VRI, ch]) * m
        st[ROW_R0, ch] = st[ROW_R0, ch] + e_k
        st[ROW_T0, ch] = st[ROW_T0, ch] * tdn * inv
        st[ROW_RI, ch] = rup + rup2
        st[ROW_TI, ch] = tup * st[ROW_TI, ch] * inv
        st[ROW_VR0, ch] = new_vr0
        st[ROW_VT0, ch] = new_vt0
        st[ROW_VRI, ch] = new_vri
        st[ROW_VTI, ch] = new_vti
    sc[SCALAR_J0] *= jd
    sc[SCALAR_JI] *= ju
    if not conductor:
        sc[SCALAR_ETA] = eta_abs[0]


@njit(cache=True)
def add_medium(st, tau) -> None:
    """Add an absorbing medium of optical depth ``tau`` (RGB) below the context (in place), as the
    forward model's medium entry at c = 1 (no lobe, variances unchanged)."""
    for ch in range(3):
        t = math.exp(-tau[ch])
        r0 = st[ROW_R0, ch]
        st[ROW_VR0, ch] = (r0 * st[ROW_VR0, ch]) / r0 if r0 > 0.0 else 0.0
        rup2 = t * st[ROW_RI, ch] * t
        st[ROW_VRI, ch] = (rup2 * st[ROW_VRI, ch]) / rup2 if rup2 > 0.0 else 0.0
        st[ROW_T0, ch] = st[ROW_T0, ch] * t
        st[ROW_RI, ch] = rup2
        st[ROW_TI, ch] = t * st[ROW_TI, ch]


@njit(cache=True)
def combine_sigma(per, q, j0, minimax, ch, use) -> float:
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
def channel_sigma_r(st, sc, rp, sigma, ch) -> float:
    """Eq. 19 on channel ``ch`` of a context state: the variance sigma^R the layers below must have."""
    return eq19_scalar(sigma, rp[ch], st[ROW_RI, ch], st[ROW_VTI, ch], st[ROW_VT0, ch], st[ROW_VRI, ch], sc[SCALAR_J0])


# ============================================================================ python wrappers

def fgd_for(options: InverseOptions, alpha: float, eta_rel: float, kappa_rel: float = 0.0) -> float:
    """:func:`fgd_normal` with the kernel of ``options`` (relative index ``eta_rel + i kappa_rel``)."""
    w1, xs = kernel_for(options)
    return float(fgd_normal(w1, xs, float(alpha), float(eta_rel), float(kappa_rel)))


def albedo_for(options: InverseOptions, alpha: float) -> float:
    """:func:`albedo_normal` with the kernel of ``options``."""
    w1, _ = kernel_for(options)
    return float(albedo_normal(w1, float(alpha)))


def dielectric_roots(options: InverseOptions, alpha: float, target: float, eta_n: float,
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
