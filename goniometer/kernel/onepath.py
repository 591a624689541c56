"""One path from start to end, as a function of its own key: the transport of the CUDA kernel
(``docs/gpu.md``), where each GPU thread traces one path.

:func:`trace_path` is the per-path kernel's transport (:func:`goniometer.kernel.paths.trace_paths`,
the same events, written the same way, calling the same :mod:`goniometer.optics`,
:func:`goniometer.kernel.steps.free_flight` and :func:`goniometer.kernel.steps.microsurface_walk`)
with two differences: it returns the path's exit and its totals instead of depositing and booking
them, and it draws from a xoshiro256** stream seeded from the path's own key
(:func:`goniometer.kernel.rng.path_key` of :func:`goniometer.kernel.rng.chunk_key` ``(seed, incident, chunk)``),
so a path draws the same numbers whichever thread, block or device traces it.

It is a plain ``numba.njit`` function: numba-cuda compiles the CPU dispatchers a CUDA kernel calls
for the device (the same Python source, one formula in one place), and the CPU can run it too:
:func:`trace_keyed_chunk` is the CUDA kernel's twin on the CPU (float64 sums in path order), which
the tests check against the lane kernel with many paths, and :func:`fixed_point` is the
quantisation the CUDA kernel's integer sums use.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from goniometer import optics
from goniometer.grids.halfdiff import cell_of as halfdiff_cell
from goniometer.kernel.event import RR_START, RR_THRESHOLD
from goniometer.kernel.layout import (C_CAPPED, C_EVENTS, E_ABSORBED, E_CAPPED, E_MASKING, E_REFLECTED,
                                      E_REFLECTED_WITHOUT_BASE, E_ROULETTE, E_TRANSMITTED, P_TABULATE, TAU_SCATTER)
from goniometer.kernel.steps import _attenuate, free_flight, microsurface_walk
from goniometer.kernel.rng import chunk_key, next_disk, next_float, path_key, seed_state
from goniometer.grids.slice_grid import cell_index_fast
from goniometer.kernel.packing import FL_DL0, FL_K0, FL_KB0, FL_N0, FL_NA, FL_NB0, FL_ON

#: how a path ended (:func:`trace_path`'s first value)
X_NONE = 0
X_REFLECTED = 1
X_TRANSMITTED = 2
#: the CUDA kernel's sums are integers: a weight ``w`` adds ``round(w * FIXED_SCALE)`` (2^32), so the
#: order of the atomic additions cannot change a sum (``docs/gpu.md``, determinism)
FIXED_SCALE = 4294967296.0


@numba.njit(cache=True, error_model='numpy', inline='always')
def fixed_point(w: float) -> np.int64:
    """``w`` in the CUDA kernel's fixed point: the nearest integer to ``w * 2^32`` (ties upward)."""
    return np.int64(math.floor(w * FIXED_SCALE + 0.5))


@numba.njit(cache=True, error_model='numpy')
def trace_path(if_alpha, if_rot, if_ms, if_film, region_tau, region_albedo, region_g, cond, rho, base_kind, tau_mode,
               eta_dn, eta_up, lx, ly, lz, tabulate, height_correlated, event_cap, state):
    """Trace one path for light direction ``l`` (``tabulate``: the path first draws its own,
    cosine-weighted) drawing from ``state`` (uint64[4], seeded by the caller from the path's key).
    ``tau_mode``, ``eta_dn``, ``eta_up``: the stack's facts (:mod:`goniometer.kernel.variants`).

    Returns ``(kind, lx, ly, lz, dx, dy, dz, w0, w1, w2, order, single, based, ab0, ab1, ab2, mk0,
    mk1, mk2, rl0, rl1, rl2, cp0, cp1, cp2, capped, events)``: ``kind`` one of ``X_*`` and the exit
    direction and weight; the bounce order, whether the top's last walk had one bounce, whether the
    path had an event at the base; the weight absorbed, lost to masking, roulette's net change
    (negative for boosts, the killed weight added), the capped weight, 1 if capped, and the events.
    The bookkeeping is :func:`goniometer.kernel.paths.trace_paths`'s."""
    n_if = region_tau.shape[0] - 1
    transmit_base = base_kind == 0
    conductor_base = base_kind == 1
    g_is_r = cond[1] == cond[0] and cond[4] == cond[3]
    b_is_g = cond[2] == cond[1] and cond[5] == cond[4]
    base_k = -1 if base_kind == 2 else n_if - 1
    if tabulate:
        qx, qy = next_disk(state)
        lx, ly, lz = optics.cosine_from_disk(qx, qy)
    dx = -lx
    dy = -ly
    dz = -lz
    region = 0
    w0 = 1.0
    w1 = 1.0
    w2 = 1.0
    ab0 = 0.0
    ab1 = 0.0
    ab2 = 0.0
    mk0 = 0.0
    mk1 = 0.0
    mk2 = 0.0
    rl0 = 0.0
    rl1 = 0.0
    rl2 = 0.0
    cp0 = 0.0
    cp1 = 0.0
    cp2 = 0.0
    capped = 0
    kind = X_NONE
    order = 0
    events = 0
    based = False
    single = True
    hero = -1
    q0 = 1.0 / 3.0
    q1 = 1.0 / 3.0
    q2 = 1.0 / 3.0
    hpos = -1.0
    while True:
        if events >= event_cap:
            cp0 = w0
            cp1 = w1
            cp2 = w2
            capped = 1
            break
        # ---- traverse the current region (Beer-Lambert), or one free flight in a scattering medium
        tm = tau_mode[region]
        scattered = False
        if tm >= TAU_SCATTER:
            scattered, hpos, dx, dy, dz, w0, w1, w2, ab0, ab1, ab2, hero, q0, q1, q2 = free_flight(
                tm == TAU_SCATTER, region_tau[region, 0], region_tau[region, 1], region_tau[region, 2],
                region_albedo[region, 0], region_albedo[region, 1], region_albedo[region, 2], region_g[region],
                hpos, dx, dy, dz, w0, w1, w2, ab0, ab1, ab2, hero, q0, q1, q2, state)
        elif tm != 0:
            inv_mu = 1.0 / abs(dz)
            a0 = math.exp(-region_tau[region, 0] * inv_mu)
            if tm == 1:
                a1 = a0
                a2 = a0
            else:
                a1 = math.exp(-region_tau[region, 1] * inv_mu)
                a2 = math.exp(-region_tau[region, 2] * inv_mu)
            w0, w1, w2, ab0, ab1, ab2 = _attenuate(w0, w1, w2, ab0, ab1, ab2, a0, a1, a2)
        # ---- what lies at the end of this traversal
        at_interface = True
        k = -1
        from_above = True
        if scattered:
            at_interface = False
            events += 1
            if w0 == 0.0 and w1 == 0.0 and w2 == 0.0:
                break
        elif dz > 0.0:
            if region == 0:
                kind = X_REFLECTED
                break
            k = region - 1
            from_above = False
        elif region < n_if:
            k = region
        elif transmit_base:
            kind = X_TRANSMITTED
            break
        else:
            # Lambertian base: weight *= rho, cosine-distributed new direction upward
            at_interface = False
            events += 1
            based = True
            if n_if == 0:
                order += 1
            w0, w1, w2, ab0, ab1, ab2 = _attenuate(w0, w1, w2, ab0, ab1, ab2, rho[0], rho[1], rho[2])
            qx, qy = next_disk(state)
            dx, dy, dz = optics.cosine_from_disk(qx, qy)
        if at_interface:
            events += 1
            if k == 0:
                order += 1
            if k == base_k and from_above:
                based = True
            wx = -dx
            wy = -dy
            wz = -dz if from_above else dz
            is_cond = conductor_base and k == n_if - 1
            filmed = if_film[k, FL_ON] != 0.0
            if not is_cond and eta_dn[k] == 1.0 and not filmed:
                # index-matched dielectric: the interface is optically absent
                region = k + 1 if from_above else k
            else:
                ax = if_alpha[k, 0]
                ay = if_alpha[k, 1]
                rot = ax != ay or if_rot[k, 1] != 0.0
                c = 1.0
                s = 0.0
                if rot:
                    c = if_rot[k, 0]
                    s = if_rot[k, 1]
                    tx = c * wx + s * wy
                    wy = -s * wx + c * wy
                    wx = tx
                transmitted = False
                ox = 0.0
                oy = 0.0
                oz = 0.0
                if if_ms[k]:
                    # multiple scattering: the whole walk is this one event; each further bounce
                    # counts toward the event cap
                    eta = eta_dn[k] if from_above else eta_up[k]
                    inv_eta = eta_up[k] if from_above else eta_dn[k]
                    ox, oy, oz, f0, f1, f2, nb, transmitted = microsurface_walk(
                        wx, wy, wz, ax, ay, is_cond, cond[0], cond[1], cond[2], cond[3], cond[4], cond[5],
                        g_is_r, b_is_g, eta, inv_eta, max(1, event_cap - events + 1), state, True,
                        if_film[k], from_above)
                    if is_cond or filmed:
                        w0, w1, w2, ab0, ab1, ab2 = _attenuate(w0, w1, w2, ab0, ab1, ab2, f0, f1, f2)
                    if k == 0:
                        single = nb == 1
                    if nb == 0:
                        # still on the microsurface at the cap: booked as capped at the loop top
                        events = event_cap
                        continue
                    events += nb - 1
                else:
                    qx, qy = next_disk(state)
                    mx, my, mz = optics.sample_vndf_disk(wx, wy, wz, ax, ay, qx, qy)
                    wm = wx * mx + wy * my + wz * mz
                    if filmed:
                        n_in = if_film[k, FL_NA] if from_above else if_film[k, FL_NB0]
                        r0, t0 = optics.film_rt(wm, n_in, if_film[k, FL_N0], if_film[k, FL_K0],
                                                if_film[k, FL_NB0] if from_above else if_film[k, FL_NA],
                                                if_film[k, FL_KB0] if from_above else 0.0, if_film[k, FL_DL0])
                        r1, t1 = optics.film_rt(wm, n_in, if_film[k, FL_N0 + 1], if_film[k, FL_K0 + 1],
                                                if_film[k, FL_NB0 + 1] if from_above else if_film[k, FL_NA],
                                                if_film[k, FL_KB0 + 1] if from_above else 0.0, if_film[k, FL_DL0 + 1])
                        r2, t2 = optics.film_rt(wm, n_in, if_film[k, FL_N0 + 2], if_film[k, FL_K0 + 2],
                                                if_film[k, FL_NB0 + 2] if from_above else if_film[k, FL_NA],
                                                if_film[k, FL_KB0 + 2] if from_above else 0.0, if_film[k, FL_DL0 + 2])
                        if is_cond:
                            w0, w1, w2, ab0, ab1, ab2 = _attenuate(w0, w1, w2, ab0, ab1, ab2, r0, r1, r2)
                            ox, oy, oz = optics.reflect(wx, wy, wz, mx, my, mz)
                        else:
                            eta = eta_dn[k] if from_above else eta_up[k]
                            inv_eta = eta_up[k] if from_above else eta_dn[k]
                            _, cos_t = optics.fresnel_dielectric_cos_t_inv(wm, eta, inv_eta)
                            s_r = r0 + r1 + r2
                            s_rt = s_r + t0 + t1 + t2
                            if next_float(state) * s_rt < s_r:
                                q = s_rt / s_r
                                w0, w1, w2, ab0, ab1, ab2 = _attenuate(w0, w1, w2, ab0, ab1, ab2, r0 * q, r1 * q,
                                                                       r2 * q)
                                ox, oy, oz = optics.reflect(wx, wy, wz, mx, my, mz)
                            else:
                                q = s_rt / max(s_rt - s_r, 1e-300)
                                w0, w1, w2, ab0, ab1, ab2 = _attenuate(w0, w1, w2, ab0, ab1, ab2, t0 * q, t1 * q,
                                                                       t2 * q)
                                ox, oy, oz = optics.refract_known(wx, wy, wz, mx, my, mz, inv_eta, wm, cos_t)
                                transmitted = True
                    elif is_cond:
                        f0, f1, f2 = optics.fresnel_conductor_channels(wm, cond[0], cond[3], cond[1], cond[4],
                                                                       cond[2], cond[5], g_is_r, b_is_g)
                        w0, w1, w2, ab0, ab1, ab2 = _attenuate(w0, w1, w2, ab0, ab1, ab2, f0, f1, f2)
                        ox, oy, oz = optics.reflect(wx, wy, wz, mx, my, mz)
                    else:
                        eta = eta_dn[k] if from_above else eta_up[k]
                        inv_eta = eta_up[k] if from_above else eta_dn[k]
                        f, cos_t = optics.fresnel_dielectric_cos_t_inv(wm, eta, inv_eta)
                        if next_float(state) < f:
                            ox, oy, oz = optics.reflect(wx, wy, wz, mx, my, mz)
                        else:
                            ox, oy, oz = optics.refract_known(wx, wy, wz, mx, my, mz, inv_eta, wm, cos_t)
                            transmitted = True
                    # single-scattering microfacet model: wrong side -> lost to masking
                    if (transmitted and oz >= 0.0) or (not transmitted and oz <= 0.0):
                        mk0 += w0
                        mk1 += w1
                        mk2 += w2
                        w0 = 0.0
                        w1 = 0.0
                        w2 = 0.0
                        break
                    if height_correlated:
                        lam_o = optics.ggx_lambda(ox, oy, oz, ax, ay)
                        lam_i = optics.ggx_lambda(wx, wy, wz, ax, ay)
                        g = optics.smith_g2(lam_i, lam_o, transmitted, True) * (1.0 + lam_i)
                    else:
                        g = optics.smith_g1_dir(ox, oy, oz, ax, ay)
                    mk0 += w0 * (1.0 - g)
                    mk1 += w1 * (1.0 - g)
                    mk2 += w2 * (1.0 - g)
                    w0 *= g
                    w1 *= g
                    w2 *= g
                if rot:
                    tx = c * ox - s * oy
                    oy = s * ox + c * oy
                    ox = tx
                dx = ox
                dy = oy
                dz = oz if from_above else -oz
                if transmitted:
                    region = k + 1 if from_above else k
        # ---- Russian roulette on the largest channel weight
        if events >= RR_START:
            wmax = max(w0, max(w1, w2))
            if wmax < RR_THRESHOLD:
                if wmax <= 0.0:
                    break
                p = wmax / RR_THRESHOLD
                if next_float(state) < p:
                    boost = 1.0 / p - 1.0
                    rl0 -= w0 * boost
                    rl1 -= w1 * boost
                    rl2 -= w2 * boost
                    w0 *= 1.0 / p
                    w1 *= 1.0 / p
                    w2 *= 1.0 / p
                else:
                    rl0 += w0
                    rl1 += w1
                    rl2 += w2
                    break
    return (kind, lx, ly, lz, dx, dy, dz, w0, w1, w2, order, single, based, ab0, ab1, ab2, mk0, mk1, mk2,
            rl0, rl1, rl2, cp0, cp1, cp2, capped, events)


@numba.njit(cache=True, error_model='numpy', inline='always')
def path_state(state, seed, stream, chunk, path) -> None:
    """Seed ``state`` (uint64[4]) from the key of path ``path`` of chunk ``chunk`` of incident
    ``stream`` of a run seeded ``seed`` (:mod:`goniometer.kernel.rng`)."""
    seed_state(state, path_key(chunk_key(np.uint64(seed), np.uint64(stream), np.uint64(chunk)), np.uint64(path)))


@numba.njit(cache=True, error_model='numpy')
def trace_keyed_chunk(if_alpha, if_rot, if_ms, if_film, region_tau, region_albedo, region_g, cond, rho, base_kind,
                      tau_mode, eta_dn, eta_up, lx, ly, lz, n_rays, seed, stream, chunk, param, n_theta, n_phi,
                      row_cos, col_cos, col_sin, max_order, event_cap, skip_first, height_correlated, brdf, btdf,
                      energy, energy_sq, counts, exit_cell, exit_w):
    """The CUDA kernel's chunk on the CPU: the same paths (:func:`trace_path`, the same keys), their
    exits and totals summed in float64 in path order into the layouts of
    :func:`goniometer.kernel.tracer.trace_chunk` (which the caller zeroes). For tests: the CUDA kernel's
    transport checked against the lane kernel with as many paths as the CPU affords."""
    state = np.zeros(4, dtype=np.uint64)
    tabulate = param == P_TABULATE
    for r in range(n_rays):
        path_state(state, seed, stream, chunk, r)
        (kind, plx, ply, plz, dx, dy, dz, w0, w1, w2, order, single, based, ab0, ab1, ab2, mk0, mk1, mk2,
         rl0, rl1, rl2, cp0, cp1, cp2, capped, events) = trace_path(
            if_alpha, if_rot, if_ms, if_film, region_tau, region_albedo, region_g, cond, rho, base_kind, tau_mode,
            eta_dn, eta_up, lx, ly, lz, tabulate, height_correlated, event_cap, state)
        if tabulate:
            exit_cell[r] = -1
            if kind == X_REFLECTED:
                exit_cell[r] = halfdiff_cell(plx, ply, plz, dx, dy, dz)
                exit_w[r, 0] = w0
                exit_w[r, 1] = w1
                exit_w[r, 2] = w2
        elif kind != X_NONE and not (skip_first and kind == X_REFLECTED and order == 1 and single):
            trans = kind == X_TRANSMITTED
            i, j = cell_index_fast(param, trans, lx, ly, lz, dx, dy, dz, n_theta, n_phi, row_cos, col_cos, col_sin)
            if i >= 0:
                h = btdf if trans else brdf
                o = min(order, max_order) - 1
                h[i, j, o, 0] += w0
                h[i, j, o, 1] += w1
                h[i, j, o, 2] += w2
                h[i, j, max_order, 0] += w0 * w0
                h[i, j, max_order, 1] += w1 * w1
                h[i, j, max_order, 2] += w2 * w2
                if o > 0:
                    h[i, j, max_order + 1, 0] += w0 * w0
                    h[i, j, max_order + 1, 1] += w1 * w1
                    h[i, j, max_order + 1, 2] += w2 * w2
        ww = (w0, w1, w2)
        refl = kind == X_REFLECTED
        for ch in range(3):
            x = ww[ch] if refl else 0.0
            energy[E_REFLECTED, ch] += x
            energy_sq[E_REFLECTED, ch] += x * x
            x = x if not based else 0.0
            energy[E_REFLECTED_WITHOUT_BASE, ch] += x
            energy_sq[E_REFLECTED_WITHOUT_BASE, ch] += x * x
            x = ww[ch] if kind == X_TRANSMITTED else 0.0
            energy[E_TRANSMITTED, ch] += x
            energy_sq[E_TRANSMITTED, ch] += x * x
        for ch, (a, m, rl, cp) in enumerate(((ab0, mk0, rl0, cp0), (ab1, mk1, rl1, cp1), (ab2, mk2, rl2, cp2))):
            energy[E_ABSORBED, ch] += a
            energy_sq[E_ABSORBED, ch] += a * a
            energy[E_MASKING, ch] += m
            energy_sq[E_MASKING, ch] += m * m
            energy[E_ROULETTE, ch] += rl
            energy[E_CAPPED, ch] += cp
        counts[C_CAPPED] += capped
        counts[C_EVENTS] += events
