"""The GGX lobes of the Belcour models and the parallel kernels that evaluate them over many view
directions: statistics fixed for all directions (:func:`eval_fixed`), recomputed per direction
(:func:`eval_dynamic`) or interpolated from a per-stack table (:func:`stats_grid`, :func:`eval_grid`).

Lobes (§7): ``f = sum_k E_k D(h; a_k) G(l, v; a_k) / (4 l_z v_z)``, ``h = normalize(l + v)``, D and G
about the macro normal, no Fresnel factor (it is in ``E_k``); ``l`` towards the light, ``v`` towards
the viewer, values without cosine in 1/sr, RGB last; lobe 0 is ``top``, the others ``internal``.
Lobe roughness is clamped to ``>= ALPHA_EVAL_MIN`` for evaluation only. ``docs/belcour.md``.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from goniometer import optics
from models._jit import njit
from models.belcour.adding import adding_doubling, workspace
from models.belcour.covariance import (interface_covariance, principal, same_as_previous_channel, unit_azimuth,
                                       variance_to_roughness)
from models.belcour.packing import kernel_n_cov

ALPHA_EVAL_MIN = 1e-4

#: the cosine the statistics are computed for: ``l_z`` (fixed for all views), ``v_z``, ``|l.h|``
MODE_LIGHT = 0
MODE_VIEW = 1
MODE_HALF = 2

#: columns of the lobe parameters: a_1, a_2, principal axis (e_x, e_y), Smith Lambda of l
_P_A1, _P_A2, _P_EX, _P_EY, _P_LAM = range(5)


@njit(cache=True)
def lobe_params(E, C, P, lx, ly, lz, k_lambda) -> None:
    """Evaluation GGX of every lobe with energy: ``P[k, ch, :4] = (a1, a2, ex, ey)`` from the
    (co)variance ``C[k, ch]``: ``a1 = a2 = max(f^-1(v), ALPHA_EVAL_MIN)`` for a scalar variance or an
    isotropic covariance, else ``a_i = max(f^-1(eigenvalue), ALPHA_EVAL_MIN)`` along the principal
    axes (:func:`principal`; ``(ex, ey)`` is the axis of ``a1 >= a2``); and, for the lobes
    ``k >= k_lambda``, ``P[k, ch, 4] = Lambda(l)`` in the lobe's frame."""
    nq = C.shape[2]
    for k in range(E.shape[0]):
        if E[k, 0] == 0.0 and E[k, 1] == 0.0 and E[k, 2] == 0.0:
            continue
        for ch in range(3):
            if ch > 0 and same_as_previous_channel(C, k, ch, nq):
                for q in range(5):
                    P[k, ch, q] = P[k, ch - 1, q]
                continue
            xx = C[k, ch, 0]
            if nq == 1 or (C[k, ch, 1] == 0.0 and xx == C[k, ch, 2]):
                a = max(variance_to_roughness(xx), ALPHA_EVAL_MIN)
                P[k, ch, _P_A1] = a
                P[k, ch, _P_A2] = a
                P[k, ch, _P_EX] = 1.0
                P[k, ch, _P_EY] = 0.0
            else:
                l1, l2, ex, ey = principal(xx, C[k, ch, 1], C[k, ch, 2])
                P[k, ch, _P_A1] = max(variance_to_roughness(l1), ALPHA_EVAL_MIN)
                P[k, ch, _P_A2] = max(variance_to_roughness(l2), ALPHA_EVAL_MIN)
                P[k, ch, _P_EX] = ex
                P[k, ch, _P_EY] = ey
            if k >= k_lambda:
                P[k, ch, _P_LAM] = _lambda_in_frame(lx, ly, lz, P[k, ch, _P_A1], P[k, ch, _P_A2], P[k, ch, _P_EX],
                                                    P[k, ch, _P_EY])


@njit(cache=True, inline="always")
def _lambda_in_frame(wx, wy, wz, a1, a2, ex, ey) -> float:
    """Smith Lambda of ``w`` for the GGX ``(a1 along (ex, ey), a2 across)``."""
    if a1 == a2:
        return optics.ggx_lambda(wx, wy, wz, a1, a2)
    return optics.ggx_lambda(ex * wx + ey * wy, ex * wy - ey * wx, wz, a1, a2)


@njit(cache=True, inline="always")
def _same_params(P, k, ch) -> bool:
    """Lobe ``k`` has the same GGX in channels ``ch`` and ``ch - 1``."""
    return (P[k, ch, _P_A1] == P[k, ch - 1, _P_A1] and P[k, ch, _P_A2] == P[k, ch - 1, _P_A2]
            and P[k, ch, _P_EX] == P[k, ch - 1, _P_EX] and P[k, ch, _P_EY] == P[k, ch - 1, _P_EY])


@njit(cache=True, inline="always")
def _lobe(lz, vx, vy, vz, hx, hy, hz, a1, a2, ex, ey, lam_l, height_correlated) -> float:
    """GGX lobe without Fresnel: D(h'; a1, a2) G(l', v') / (4 l_z v_z), in 1/sr; primes in the lobe's
    principal frame (no rotation when ``a1 == a2``); ``lam_l`` = Lambda(l') precomputed."""
    if a1 == a2:
        d = optics.ggx_d(hx, hy, hz, a1, a2)
        if d == 0.0:
            return 0.0
        lo = optics.ggx_lambda(vx, vy, vz, a1, a2)
    else:
        d = optics.ggx_d(ex * hx + ey * hy, ex * hy - ey * hx, hz, a1, a2)
        if d == 0.0:
            return 0.0
        lo = optics.ggx_lambda(ex * vx + ey * vy, ex * vy - ey * vx, vz, a1, a2)
    return d * optics.smith_g2(lam_l, lo, False, height_correlated) / (4.0 * lz * vz)


@njit(cache=True)
def _sum_lobes(lx, ly, lz, vx, vy, vz, E, P, k0, height_correlated, out_top, out_int, n) -> None:
    """Set ``out_top[n]`` to lobe 0 and ``out_int[n]`` to the sum of the others, lobes ``k >= k0`` only."""
    hx, hy, hz = optics.half_vector(lx, ly, lz, vx, vy, vz)
    for ch in range(3):
        out_top[n, ch] = 0.0
        out_int[n, ch] = 0.0
    for k in range(k0, E.shape[0]):
        if E[k, 0] == 0.0 and E[k, 1] == 0.0 and E[k, 2] == 0.0:
            continue
        r = 0.0
        for ch in range(3):
            if ch == 0 or not _same_params(P, k, ch):
                r = _lobe(lz, vx, vy, vz, hx, hy, hz, P[k, ch, _P_A1], P[k, ch, _P_A2], P[k, ch, _P_EX],
                          P[k, ch, _P_EY], P[k, ch, _P_LAM], height_correlated)
            if k == 0:
                out_top[n, ch] += E[k, ch] * r
            else:
                out_int[n, ch] += E[k, ch] * r


@njit(cache=True)
def _exact_top(lx, ly, lz, vx, vy, vz, E, top_alpha, top_eta, top_kappa, height_correlated, out_top, n) -> None:
    """``out_top[n]`` = the exact microfacet BRDF of the top interface (Bati 2019 eq. 6) in place of
    lobe 0 (if lobe 0 has energy). Kept out of :func:`_sum_lobes`, which it would slow down."""
    if E[0, 0] == 0.0 and E[0, 1] == 0.0 and E[0, 2] == 0.0:
        return
    for ch in range(3):
        if ch > 0 and top_eta[ch] == top_eta[ch - 1] and top_kappa[ch] == top_kappa[ch - 1]:
            out_top[n, ch] = out_top[n, ch - 1]
        else:
            out_top[n, ch] = optics.microfacet_reflection(lx, ly, lz, vx, vy, vz, top_alpha, top_alpha,
                                                          top_eta[ch], top_kappa[ch], height_correlated)


@njit(cache=True, inline="always")
def _chunks(n: int) -> int:
    """Number of parallel chunks for ``n`` directions."""
    return max(1, min(n // 2048, 512))


@njit(cache=True, inline="always")
def _below_horizon(lz, vz, out_top, out_int, n) -> bool:
    """If ``l`` or ``v`` is below the horizon, zero both outputs of direction ``n`` and say so."""
    if vz <= 0.0 or lz <= 0.0:
        for ch in range(3):
            out_top[n, ch] = 0.0
            out_int[n, ch] = 0.0
        return True
    return False


@njit(cache=True, inline="always")
def _statistics_cosine(mode, lx, ly, lz, vx, vy, vz) -> float:
    """The cosine the statistics are computed for: ``v_z`` (MODE_VIEW) or ``|l.h|`` (MODE_HALF)."""
    if mode == MODE_VIEW:
        return vz
    hx = lx + vx
    hy = ly + vy
    hz = lz + vz
    return abs(lx * hx + ly * hy + lz * hz) / math.sqrt(hx * hx + hy * hy + hz * hz)


@njit(parallel=True, cache=True)
def eval_fixed(l, v, z_sign, E, P, height_correlated, top_exact, top_alpha, top_eta, top_kappa, out_top, out_int):
    """Lobes fixed for all directions (forward model with omega_i = l; ``P`` from :func:`lobe_params`)
    at the views ``(v_x, v_y, z_sign v_z)`` (``z_sign = -1``: the mirror
    trick of the BTDF)."""
    lx, ly, lz = l[0], l[1], l[2]
    n_dir = v.shape[0]
    nc = _chunks(n_dir)
    k0 = 1 if top_exact else 0
    for chunk in numba.prange(nc):
        for n in range(chunk * n_dir // nc, (chunk + 1) * n_dir // nc):
            vx, vy, vz = v[n, 0], v[n, 1], z_sign * v[n, 2]
            if _below_horizon(lz, vz, out_top, out_int, n):
                continue
            _sum_lobes(lx, ly, lz, vx, vy, vz, E, P, k0, height_correlated, out_top, out_int, n)
            if top_exact:
                _exact_top(lx, ly, lz, vx, vy, vz, E, top_alpha, top_eta, top_kappa, height_correlated, out_top, n)


@njit(parallel=True, cache=True)
def eval_dynamic(l, v, mode, n_lobes, stack, per_channel, use_tir, angular_s, consistent_j, height_correlated, top_exact,
                 top_alpha,
                 top_eta, top_kappa, out_top, out_int):
    """Statistics recomputed per direction: ``mode`` MODE_VIEW (c = v_z) or MODE_HALF (c = |l.h|);
    the incidence azimuth is that of ``v``."""
    lx, ly, lz = l[0], l[1], l[2]
    n_dir = v.shape[0]
    nc = _chunks(n_dir)
    k0 = 1 if top_exact else 0
    nq = kernel_n_cov(stack)
    for chunk in numba.prange(nc):
        E, C, st, cs, wk, wc = workspace(n_lobes, nq)
        P = np.zeros((n_lobes, 3, 5))
        for n in range(chunk * n_dir // nc, (chunk + 1) * n_dir // nc):
            vx, vy, vz = v[n, 0], v[n, 1], v[n, 2]
            if _below_horizon(lz, vz, out_top, out_int, n):
                continue
            c = _statistics_cosine(mode, lx, ly, lz, vx, vy, vz)
            dx, dy = unit_azimuth(vx, vy) if nq == 3 else (1.0, 0.0)
            adding_doubling(c, dx, dy, stack, per_channel, use_tir, angular_s, consistent_j, E, C, st, cs, wk, wc)
            lobe_params(E, C, P, lx, ly, lz, k0)
            _sum_lobes(lx, ly, lz, vx, vy, vz, E, P, k0, height_correlated, out_top, out_int, n)
            if top_exact:
                _exact_top(lx, ly, lz, vx, vy, vz, E, top_alpha, top_eta, top_kappa, height_correlated, out_top, n)


@njit(parallel=True, cache=True)
def stats_grid(n_nodes, n_phi, n_lobes, stack, per_channel, use_tir, angular_s, consistent_j):
    """Statistics table ``G[i, j, k, ch, :]`` = (lobe energy, clamped roughness ``a`` (scalar
    variances) or roughness matrix ``a_1 e_1 e_1^T + a_2 e_2 e_2^T`` as ``(xx, xy, yy)`` (covariances))
    at the azimuths ``phi_i = i pi / n_phi`` and cosines ``c_j = (j / (n_nodes - 1))^2``.
    Azimuth-major, so that the two cosine neighbours of a direction are adjacent in memory."""
    nq = kernel_n_cov(stack)
    G = np.zeros((n_phi, n_nodes, n_lobes, 3, 1 + nq))
    nc = max(1, min(n_nodes // 16, 512))
    for chunk in numba.prange(nc):
        E, C, st, cs, wk, wc = workspace(n_lobes, nq)
        P = np.zeros((n_lobes, 3, 5))
        for j in range(chunk * n_nodes // nc, (chunk + 1) * n_nodes // nc):
            t = j / (n_nodes - 1)
            for i in range(n_phi):
                phi = i * math.pi / n_phi
                adding_doubling(t * t, math.cos(phi), math.sin(phi), stack, per_channel, use_tir, angular_s, consistent_j,
                                E, C, st, cs, wk, wc)
                for k in range(n_lobes):
                    for ch in range(3):
                        P[k, ch, _P_A1] = ALPHA_EVAL_MIN
                        P[k, ch, _P_A2] = ALPHA_EVAL_MIN
                        P[k, ch, _P_EX] = 1.0
                        P[k, ch, _P_EY] = 0.0
                lobe_params(E, C, P, 0.0, 0.0, 1.0, n_lobes)
                for k in range(n_lobes):
                    for ch in range(3):
                        G[i, j, k, ch, 0] = E[k, ch]
                        a1, a2, ex, ey = P[k, ch, _P_A1], P[k, ch, _P_A2], P[k, ch, _P_EX], P[k, ch, _P_EY]
                        if nq == 1:
                            G[i, j, k, ch, 1] = a1
                        elif a1 == a2:
                            G[i, j, k, ch, 1] = a1
                            G[i, j, k, ch, 2] = 0.0
                            G[i, j, k, ch, 3] = a1
                        else:
                            xx, xy, yy = interface_covariance(a1, a2, ex, ey)
                            G[i, j, k, ch, 1] = xx
                            G[i, j, k, ch, 2] = xy
                            G[i, j, k, ch, 3] = yy
    return G


@njit(cache=True, inline="always")
def _lerp_nodes(G, i, j, k, ch, q, f) -> float:
    """``G[i, j, k, ch, q]`` interpolated linearly towards cosine node ``j + 1`` by ``f``."""
    return G[i, j, k, ch, q] * (1.0 - f) + G[i, j + 1, k, ch, q] * f


@njit(parallel=True, cache=True)
def eval_grid(l, v, mode, G, height_correlated, top_exact, top_alpha, top_eta, top_kappa, out_top, out_int):
    """Direction-dependent statistics interpolated from :func:`stats_grid`: linearly in ``sqrt(c)``
    and, with more than one azimuth node, periodically in the azimuth of ``v`` modulo pi; an
    interpolated roughness matrix is eigen-decomposed into the lobe's GGX."""
    lx, ly, lz = l[0], l[1], l[2]
    n_dir = v.shape[0]
    n_phi = G.shape[0]
    n_nodes = G.shape[1]
    n_lobes = G.shape[2]
    nq = G.shape[4] - 1
    k0 = 1 if top_exact else 0
    nc = _chunks(n_dir)
    for chunk in numba.prange(nc):
        E = np.zeros((n_lobes, 3))
        P = np.zeros((n_lobes, 3, 5))
        for n in range(chunk * n_dir // nc, (chunk + 1) * n_dir // nc):
            vx, vy, vz = v[n, 0], v[n, 1], v[n, 2]
            if _below_horizon(lz, vz, out_top, out_int, n):
                continue
            c = _statistics_cosine(mode, lx, ly, lz, vx, vy, vz)
            s = math.sqrt(min(max(c, 0.0), 1.0)) * (n_nodes - 1)
            j = min(int(s), n_nodes - 2)
            f = s - j
            i0 = 0
            i1 = 0
            g = 0.0
            if n_phi > 1:
                phi = math.atan2(vy, vx)
                u = (phi - math.pi * math.floor(phi / math.pi)) / math.pi * n_phi
                i0 = min(int(u), n_phi - 1)
                g = u - i0
                i1 = (i0 + 1) % n_phi
            pxx = 0.0
            pxy = 0.0
            pyy = 0.0
            for k in range(n_lobes):
                for ch in range(3):
                    e = _lerp_nodes(G, i0, j, k, ch, 0, f)
                    xx = _lerp_nodes(G, i0, j, k, ch, 1, f)
                    xy = _lerp_nodes(G, i0, j, k, ch, 2, f) if nq == 3 else 0.0
                    yy = _lerp_nodes(G, i0, j, k, ch, 3, f) if nq == 3 else 0.0
                    if n_phi > 1:
                        e = e * (1.0 - g) + _lerp_nodes(G, i1, j, k, ch, 0, f) * g
                        xx = xx * (1.0 - g) + _lerp_nodes(G, i1, j, k, ch, 1, f) * g
                        if nq == 3:
                            xy = xy * (1.0 - g) + _lerp_nodes(G, i1, j, k, ch, 2, f) * g
                            yy = yy * (1.0 - g) + _lerp_nodes(G, i1, j, k, ch, 3, f) * g
                    if nq == 1:
                        yy = xx
                    E[k, ch] = e
                    if ch > 0 and xx == pxx and xy == pxy and yy == pyy:
                        for q in range(5):
                            P[k, ch, q] = P[k, ch - 1, q]
                        continue
                    if nq == 1 or (xy == 0.0 and xx == yy):
                        P[k, ch, _P_A1] = xx
                        P[k, ch, _P_A2] = xx
                        P[k, ch, _P_EX] = 1.0
                        P[k, ch, _P_EY] = 0.0
                    else:
                        a_1, a_2, ex, ey = principal(xx, xy, yy)
                        P[k, ch, _P_A1] = max(a_1, ALPHA_EVAL_MIN)
                        P[k, ch, _P_A2] = max(a_2, ALPHA_EVAL_MIN)
                        P[k, ch, _P_EX] = ex
                        P[k, ch, _P_EY] = ey
                    if k >= k0:
                        P[k, ch, _P_LAM] = _lambda_in_frame(lx, ly, lz, P[k, ch, _P_A1], P[k, ch, _P_A2],
                                                            P[k, ch, _P_EX], P[k, ch, _P_EY])
                    pxx = xx
                    pxy = xy
                    pyy = yy
            _sum_lobes(lx, ly, lz, vx, vy, vz, E, P, k0, height_correlated, out_top, out_int, n)
            if top_exact:
                _exact_top(lx, ly, lz, vx, vy, vz, E, top_alpha, top_eta, top_kappa, height_correlated, out_top, n)
