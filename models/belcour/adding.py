"""The adding-doubling of per-lobe statistics through a packed stack (Belcour 2018 §6; Bati 2021
eqs. 2, 4, 5): :func:`adding_doubling` (the numba kernel) and :func:`run_adding_doubling`.

Per interface ``R = FGD(c, a~)``, ``T = 1 - R`` (0 for a conductor or total internal reflection at
the mean cosine, after which the loop stops); per medium ``T = exp(-tau / c)``, ``R = 0``, and for a
scattering medium Belcour's forward-scattering operator ``T = (1 + tau_s / c) exp(-tau / c)``,
``R = 0``, with ``sigma_HG(g)`` added to the variance transmitted down and up (``J = 1``). Lobe
energy ``E_k = T0i R Ti0 / (1 - Ri0 R)``, lobe (co)variance
``v_k = vTi0 + J0i (vT0i + vr + m (vr + vRi0))``, ``m = Ri0 R / (1 - Ri0 R)``. Cosines are in the
medium of each entry, clamped to ``>= COS_MIN``. Equations, choices and the covariance form:
``docs/belcour.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from models._jit import njit
from models.belcour.covariance import (blended_alpha, lobe_covariance, lookup_alpha, same_as_previous_channel,
                                       transmission_roughness, variance_to_roughness)
from models.belcour.options import BelcourOptions
from models.belcour.packing import KIND_CONDUCTOR, KIND_MEDIUM, BelcourPackedStack, kernel_n_cov
from models.tables import belcour as tables

COS_MIN = 1e-4

#: rows of the energy state of the adding-doubling kernel: R0N, T0N, RN0, TN0 (per channel),
#: then (J0N, JN0, c_N)
_S_R0, _S_T0, _S_RI, _S_TI, _S_MISC = range(5)
#: rows of the (co)variance state: vR0N, vT0N, vRN0, vTN0 (Bati 2021 notation), nq entries each
_C_R0, _C_T0, _C_RI, _C_TI = range(4)
#: rows of the per-entry scratch array: R and T of the entry down and up, inter-reflection factor
#: m, lobe energy, second upward reflection term, 1 / (1 - Ri0 R)
_W_RDN, _W_TDN, _W_RUP, _W_TUP, _W_M, _W_E, _W_RUP2, _W_DINV = range(8)


@njit(cache=True, inline="always")
def _mean_row(a, row) -> float:
    return (a[row, 0] + a[row, 1] + a[row, 2]) / 3.0


@njit(cache=True, inline="always")
def _pick(q: int, x0: float, x1: float, x2: float) -> float:
    """Entry ``q`` of ``(x0, x1, x2)`` (a constant ``q`` folds away)."""
    if q == 0:
        return x0
    if q == 1:
        return x1
    return x2


@njit(cache=True, inline="always")
def _lookup_roughness(nq, cs, ch, r0, r1, r2, a, ay, rc, rs, iso, c, dx, dy) -> float:
    """FGD/TIR lookup roughness of an interface (§4): ``a~ = f^-1(vT0i + f(alpha))`` -- for
    covariances :func:`lookup_alpha` of ``Sigma_T0i + Sigma_r`` -- and the interface's own roughness
    (:func:`blended_alpha` if anisotropic) when nothing is accumulated above; ``(r0, r1, r2)``: the
    interface's reflection (co)variance."""
    if nq == 1:
        v = cs[_C_T0, ch, 0]
        return variance_to_roughness(v + r0) if v > 0.0 else a
    if cs[_C_T0, ch, 0] > 0.0 or cs[_C_T0, ch, 2] > 0.0:
        return lookup_alpha(cs[_C_T0, ch, 0] + r0, cs[_C_T0, ch, 1] + r1, cs[_C_T0, ch, 2] + r2, c, dx, dy)
    if iso:
        return a
    return blended_alpha(a, ay, rc, rs, c, dx, dy)


@njit(cache=True)
def workspace(n_lobes: int, nq: int) -> tuple:
    """The output and scratch arrays of :func:`adding_doubling` for ``n_lobes`` lobes and ``nq``
    entries per (co)variance: ``(E, C, st, cs, wk, wc)``."""
    return (np.zeros((n_lobes, 3)), np.zeros((n_lobes, 3, nq)), np.zeros((5, 3)), np.zeros((4, 3, nq)),
            np.zeros((8, 3)), np.zeros((3, nq)))


@njit(cache=True)
def adding_doubling(c_in, dx, dy, stack, per_channel, use_tir, angular_s, consistent_j, E, C, st, cs, wk, wc):
    """The statistics of §6 for incidence cosine ``c_in`` (in the top medium) and unit incidence
    azimuth ``(dx, dy)`` (seen by anisotropic covariances only) through ``stack`` (the arrays of
    :meth:`BelcourPackedStack.kernel_args`), with ``nq`` = 1 or 3 entries per (co)variance.

    Writes lobe energies ``E[k, ch]`` and (co)variances ``C[k, ch, :nq]`` (k = interface index;
    zeros for interfaces below a conductor or below total internal reflection at the mean), the
    energy state ``st`` (5, 3): rows R0N, T0N, RN0, TN0 (per channel) and ``st[4] = (J0N, JN0,
    c_N)`` with ``c_N`` the mean cosine in the last medium reached (below a transmitting stack,
    above a conductor; -1 after total internal reflection at the mean), and the (co)variance state
    ``cs[(R0N, T0N, RN0, TN0), ch, :nq]``. ``wk`` (8, 3) and ``wc`` (3, nq) are scratch
    (:func:`workspace` makes them all). No allocation.
    """
    # one body, inlined with a constant nq each (the entry loops unroll)
    if kernel_n_cov(stack) == 1:
        _adding_doubling(1, c_in, dx, dy, stack, per_channel, use_tir, angular_s, consistent_j, E, C, st, cs, wk, wc)
    else:
        _adding_doubling(3, c_in, dx, dy, stack, per_channel, use_tir, angular_s, consistent_j, E, C, st, cs, wk, wc)


@njit(cache=True, inline="always")
def _adding_doubling(nq, c_in, dx, dy, stack, per_channel, use_tir, angular_s, consistent_j, E, C, st, cs, wk, wc):
    """:func:`adding_doubling` for ``nq`` (a constant where inlined). Every update of a (co)variance is
    the scalar one of §6 applied to each entry, in the same floating-point order."""
    (kind, alpha, alpha_y, rot, iso, cov_r, cov_t_down, cov_t_up, n_mean, tau, eta_up, achromatic, fgd_split,
     fgd_lower, fgd_upper, tir_split, tir_lower, tir_upper, tau_s, var_s) = stack
    n_e = kind.shape[0]
    for k in range(E.shape[0]):
        for ch in range(3):
            E[k, ch] = 0.0
            for q in range(nq):
                C[k, ch, q] = 0.0
    for ch in range(3):
        st[_S_R0, ch] = 0.0
        st[_S_RI, ch] = 0.0
        st[_S_T0, ch] = 1.0
        st[_S_TI, ch] = 1.0
        for r in range(4):
            for q in range(nq):
                cs[r, ch, q] = 0.0
    J0 = 1.0
    Ji = 1.0
    c = min(max(c_in, COS_MIN), 1.0)
    lobe = 0
    for e in range(n_e):
        # the entry's (co)variances: reflection r, transmission down d and up u (zero for media)
        r0 = r1 = r2 = 0.0
        d0 = d1 = d2 = 0.0
        u0 = u1 = u2 = 0.0
        jd = 1.0
        ju = 1.0
        is_cond = kind[e] == KIND_CONDUCTOR
        is_med = kind[e] == KIND_MEDIUM
        if is_med:
            c2 = c
            for ch in range(3):
                t = math.exp(-tau[e, ch] / c)
                if tau_s[e, ch] > 0.0:
                    # Belcour's forward scattering: unscattered + once-scattered energy, all forward
                    t = (1.0 + tau_s[e, ch] / c) * t
                wk[_W_RDN, ch] = 0.0
                wk[_W_RUP, ch] = 0.0
                wk[_W_TDN, ch] = t
                wk[_W_TUP, ch] = t
        else:
            n = n_mean[e]
            s2 = (1.0 - c * c) / (n * n)
            c2 = math.sqrt(1.0 - s2) if s2 <= 1.0 else -1.0
            passes = c2 > 0.0 and not is_cond
            r0 = cov_r[e, 0]
            if nq == 3:
                r1 = cov_r[e, 1]
                r2 = cov_r[e, 2]
            if passes:
                c2 = max(c2, COS_MIN)
                if angular_s:
                    x_down, x_up = transmission_roughness(alpha[e], n, c, c2, True)
                    y_down, y_up = transmission_roughness(alpha_y[e], n, c, c2, True)
                    d0, d1, d2 = lobe_covariance(x_down, y_down, rot[e, 0], rot[e, 1], iso[e])
                    u0, u1, u2 = lobe_covariance(x_up, y_up, rot[e, 0], rot[e, 1], iso[e])
                else:
                    d0 = cov_t_down[e, 0]
                    u0 = cov_t_up[e, 0]
                    if nq == 3:
                        d1 = cov_t_down[e, 1]
                        d2 = cov_t_down[e, 2]
                        u1 = cov_t_up[e, 1]
                        u2 = cov_t_up[e, 2]
                jd = (c2 / c) * n
                ju = 1.0 / jd
            do_tir = use_tir and e > 0 and eta_up[e] < 1.0
            a = alpha[e]
            at = a
            for ch in range(3):
                same = ch > 0 and same_as_previous_channel(cs, _C_T0, ch, nq)
                if not same:
                    # a~ = f^-1(vT0i + f(alpha)); exactly alpha when nothing is accumulated above
                    at = _lookup_roughness(nq, cs, ch, r0, r1, r2, a, alpha_y[e], rot[e, 0], rot[e, 1], iso[e], c, dx,
                                           dy)
                if same and achromatic[e]:
                    r = wk[_W_RDN, ch - 1]
                else:
                    r = tables.stacked_slice_lookup(fgd_split, fgd_lower, fgd_upper, e, ch, c, at)
                wk[_W_RDN, ch] = r
                if passes:
                    wk[_W_TDN, ch] = 1.0 - r
                    wk[_W_RUP, ch] = r
                    wk[_W_TUP, ch] = 1.0 - r
                else:
                    wk[_W_TDN, ch] = 0.0
                    wk[_W_RUP, ch] = 0.0
                    wk[_W_TUP, ch] = 0.0
                if do_tir:
                    esc = tables.stacked_slice_lookup(tir_split, tir_lower, tir_upper, e, 0, c, at)
                    st[_S_RI, ch] = min(max(st[_S_RI, ch] + (1.0 - esc) * st[_S_TI, ch], 0.0), 1.0)
                    st[_S_TI, ch] = esc * st[_S_TI, ch]
        # adding step (per channel), every right-hand side from the old state
        for ch in range(3):
            d = 1.0 - st[_S_RI, ch] * wk[_W_RDN, ch]
            if d > 0.0:
                inv = 1.0 / d
                wk[_W_DINV, ch] = inv
                wk[_W_E, ch] = st[_S_T0, ch] * wk[_W_RDN, ch] * st[_S_TI, ch] * inv
                wk[_W_RUP2, ch] = wk[_W_TUP, ch] * st[_S_RI, ch] * wk[_W_TDN, ch] * inv
                wk[_W_M, ch] = st[_S_RI, ch] * wk[_W_RDN, ch] * inv
            else:
                wk[_W_DINV, ch] = 0.0
                wk[_W_E, ch] = 0.0
                wk[_W_RUP2, ch] = 0.0
                wk[_W_M, ch] = 0.0
        # lobe (co)variance v_k = vTi0 + J0i (vT0i + vr + m (vr + vRi0)), entrywise
        m_avg = _mean_row(wk, _W_M)
        for ch in range(3):
            m = wk[_W_M, ch] if per_channel else m_avg
            for q in range(nq):
                vr = _pick(q, r0, r1, r2)
                wc[ch, q] = cs[_C_TI, ch, q] + J0 * (cs[_C_T0, ch, q] + vr + m * (vr + cs[_C_RI, ch, q]))
        if kind[e] != KIND_MEDIUM:
            for ch in range(3):
                E[lobe, ch] = wk[_W_E, ch]
                for q in range(nq):
                    C[lobe, ch, q] = wc[ch, q]
            lobe += 1
        wR0_avg = _mean_row(st, _S_R0)
        wE_avg = _mean_row(wk, _W_E)
        wRup_avg = _mean_row(wk, _W_RUP)
        wRup2_avg = _mean_row(wk, _W_RUP2)
        for ch in range(3):
            if per_channel:
                m = wk[_W_M, ch]
                wR0 = st[_S_R0, ch]
                wE = wk[_W_E, ch]
                wRup = wk[_W_RUP, ch]
                wRup2 = wk[_W_RUP2, ch]
            else:
                m = m_avg
                wR0 = wR0_avg
                wE = wE_avg
                wRup = wRup_avg
                wRup2 = wRup2_avg
            wsum_r = wR0 + wE
            wsum_u = wRup + wRup2
            for q in range(nq):
                vr = _pick(q, r0, r1, r2)
                vtd = _pick(q, d0, d1, d2)
                vtu = _pick(q, u0, u1, u2)
                if is_med and q != 1:
                    # sigma_HG(g) on the transmitted variance, an isotropic (co)variance (xy = 0)
                    vtd = var_s[e, ch]
                    vtu = var_s[e, ch]
                vri = cs[_C_RI, ch, q]
                new_vR0 = (wR0 * cs[_C_R0, ch, q] + wE * wc[ch, q]) / wsum_r if wsum_r > 0.0 else 0.0
                if consistent_j:
                    # variances carried down into the next medium shrink by 1 / j (the inverse of
                    # the J0i that brings them back up): docs/belcour.md, "Jacobian bookkeeping"
                    new_vT0 = (cs[_C_T0, ch, q] + (vr + vri) * m) / jd + vtd
                else:
                    new_vT0 = jd * cs[_C_T0, ch, q] + vtd + jd * (vr + vri) * m
                new_vRi = ((wRup * vr + wRup2 * (vtd + jd * (vtu + vri + m * (vr + vri)))) / wsum_u
                           if wsum_u > 0.0 else 0.0)
                new_vTi = Ji * vtu + cs[_C_TI, ch, q] + Ji * (vr + vri) * m
                cs[_C_R0, ch, q] = new_vR0
                cs[_C_T0, ch, q] = new_vT0
                cs[_C_RI, ch, q] = new_vRi
                cs[_C_TI, ch, q] = new_vTi
            st[_S_R0, ch] = st[_S_R0, ch] + wk[_W_E, ch]
            st[_S_T0, ch] = st[_S_T0, ch] * wk[_W_TDN, ch] * wk[_W_DINV, ch]
            st[_S_RI, ch] = wk[_W_RUP, ch] + wk[_W_RUP2, ch]
            st[_S_TI, ch] = wk[_W_TUP, ch] * st[_S_TI, ch] * wk[_W_DINV, ch]
        J0 *= jd
        Ji *= ju
        if is_cond:
            break
        c = c2
        if c <= 0.0:
            for ch in range(3):
                st[_S_T0, ch] = 0.0
                st[_S_TI, ch] = 0.0
            break
    st[_S_MISC, 0] = J0
    st[_S_MISC, 1] = Ji
    st[_S_MISC, 2] = c


@dataclass(frozen=True)
class AddingDoubling:
    """Output of :func:`adding_doubling` for one incidence (:func:`run_adding_doubling`).

    ``energy`` (n_lobes, 3) and ``covariance`` (n_lobes, 3, nq) of the lobes (one per interface, top
    first); the stack's energies ``R0N``, ``T0N``, ``RN0``, ``TN0`` (3,) and (co)variances ``cov_R0N``,
    ``cov_T0N``, ``cov_RN0``, ``cov_TN0`` (3, nq) (Bati 2021 notation); the Jacobian products ``J0N``,
    ``JN0`` and the mean cosine in the last medium reached ``cos_bottom`` (as :class:`StackStatistics`).
    """

    energy: np.ndarray
    covariance: np.ndarray
    R0N: np.ndarray
    T0N: np.ndarray
    RN0: np.ndarray
    TN0: np.ndarray
    cov_R0N: np.ndarray
    cov_T0N: np.ndarray
    cov_RN0: np.ndarray
    cov_TN0: np.ndarray
    J0N: float
    JN0: float
    cos_bottom: float


def run_adding_doubling(packed: BelcourPackedStack, cos_theta: float, options: BelcourOptions,
                        azimuth: tuple[float, float] = (1.0, 0.0)) -> AddingDoubling:
    """:func:`adding_doubling` of a packed stack at incidence ``cos_theta`` and unit azimuth
    ``azimuth`` (which only anisotropic covariances see), with the switches of ``options``."""
    E, C, st, cs, wk, wc = workspace(packed.n_lobes, packed.n_cov)
    adding_doubling(float(cos_theta), float(azimuth[0]), float(azimuth[1]), packed.kernel_args(), options.per_channel,
                    options.use_tir, options.transmission_scale == "angular",
                    options.transmitted_jacobian == "consistent", E, C, st, cs, wk, wc)
    return AddingDoubling(E, C, st[_S_R0].copy(), st[_S_T0].copy(), st[_S_RI].copy(), st[_S_TI].copy(),
                          cs[_C_R0].copy(), cs[_C_T0].copy(), cs[_C_RI].copy(), cs[_C_TI].copy(),
                          float(st[_S_MISC, 0]), float(st[_S_MISC, 1]), float(st[_S_MISC, 2]))

