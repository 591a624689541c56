"""The per-path kernel (``docs/kernel.md``, two kernels): each path of a chunk is traced from start
to end before the next, all from the chunk's one random stream: the transport written the plain
way, the reference the lane kernel (:func:`goniometer.kernel.tracer.trace_chunk`, which traces every
stack) is checked against, forced with ``KERNEL_PATHS``. Physics, bookkeeping and outputs as the
lane kernel's (the transport rules: :mod:`goniometer.kernel.tracer`).

A histogram exit is deposited when the next exit happens (or at the end of the chunk), its cell
being prefetched meanwhile: each cell still receives its additions in path order.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from goniometer import optics
from goniometer.grids.halfdiff import cell_of as halfdiff_cell
from goniometer.kernel.event import RR_START, RR_THRESHOLD
from goniometer.kernel.layout import (C_CAPPED, C_EVENTS, E_ABSORBED, E_CAPPED, E_MASKING, E_REFLECTED,
                                      E_REFLECTED_WITHOUT_BASE, E_ROULETTE, E_TRANSMITTED, P_TABULATE, TAU_SCATTER)
from goniometer.kernel.steps import _attenuate, free_flight, microsurface_walk
from goniometer.kernel.rng import next_disk, next_float
from goniometer.grids.slice_grid import cell_index_fast
from goniometer.kernel.packing import FL_DL0, FL_K0, FL_KB0, FL_N0, FL_NA, FL_NB0, FL_ON

@intrinsic
def _prefetch(typingctx, arr, i, j, k, c):
    """Hint the CPU to fetch the cache line of ``arr[i, j, k, c]`` for writing (``llvm.prefetch``,
    no effect on results; no bounds check)."""
    sig = types.void(arr, i, j, k, c)

    def codegen(context, builder, signature, args):
        aryty = signature.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        idx = [context.cast(builder, a, t, types.intp) for a, t in zip(args[1:], signature.args[1:])]
        ptr = cgutils.get_item_pointer2(context, builder, ary.data, cgutils.unpack_tuple(builder, ary.shape),
                                        cgutils.unpack_tuple(builder, ary.strides), aryty.layout, idx)
        i8p = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        # the name suffix follows llvmlite's pointer mangling (typed or opaque pointers)
        fnty = ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32])
        fn = builder.module.declare_intrinsic("llvm.prefetch", [i8p], fnty)
        # rw = 1 (write), locality = 3 (keep in all cache levels), data cache
        builder.call(fn, [builder.bitcast(ptr, i8p), ir.Constant(i32, 1), ir.Constant(i32, 3), ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return sig, codegen


@numba.njit(cache=True, error_model='numpy', _nrt=False)
def _prefetch_exit(h, i, j, o, max_order):
    """Prefetch the rows of histogram cell ``(i, j)`` that :func:`_deposit` will update."""
    _prefetch(h, i, j, o, 0)
    _prefetch(h, i, j, o, 2)
    _prefetch(h, i, j, max_order, 0)
    _prefetch(h, i, j, max_order + 1, 2)


@numba.njit(cache=True, error_model='numpy', _nrt=False)
def _deposit(h, i, j, o, max_order, w0, w1, w2):
    """Add one exit of bounce-order row ``o`` with weight ``w`` to histogram cell ``(i, j)``."""
    h[i, j, o, 0] += w0
    h[i, j, o, 1] += w1
    h[i, j, o, 2] += w2
    q0 = w0 * w0
    q1 = w1 * w1
    q2 = w2 * w2
    h[i, j, max_order, 0] += q0
    h[i, j, max_order, 1] += q1
    h[i, j, max_order, 2] += q2
    if o > 0:
        h[i, j, max_order + 1, 0] += q0
        h[i, j, max_order + 1, 1] += q1
        h[i, j, max_order + 1, 2] += q2


@numba.njit(cache=True, error_model='numpy', _nrt=False)
def _deposit_pending(brdf, btdf, pend, i, j, o, max_order, w0, w1, w2):
    """Deposit the exit held back for prefetching: none (``pend`` 0), BRDF (1) or BTDF (2)."""
    if pend == 1:
        _deposit(brdf, i, j, o, max_order, w0, w1, w2)
    elif pend == 2:
        _deposit(btdf, i, j, o, max_order, w0, w1, w2)


@numba.njit(cache=True, error_model='numpy', inline="always")
def _book(energy, energy_sq, row, x0, x1, x2):
    """Add a path's per-channel amount to energy row ``row`` and its square to the second moments."""
    energy[row, 0] += x0
    energy[row, 1] += x1
    energy[row, 2] += x2
    energy_sq[row, 0] += x0 * x0
    energy_sq[row, 1] += x1 * x1
    energy_sq[row, 2] += x2 * x2


@numba.njit(cache=True, error_model='numpy')
def trace_paths(stack, lx, ly, lz, n_rays, state, param, n_theta, n_phi, tables, max_order, height_correlated,
                event_cap, skip_first, outs):
    """Trace ``n_rays`` paths one after the other for light direction ``l``, drawing from the
    chunk's xoshiro256** stream ``state``, and accumulate into the given arrays (arguments as
    :func:`goniometer.kernel.tracer.trace_chunk`'s: ``stack``, ``tables`` and ``outs`` tuples).

    ``param`` is the slice parametrization (:data:`goniometer.grids.slice_grid.CLASSIC`, ``HALF``) or
    :data:`P_TABULATE`: then path ``r`` first draws its own light direction ``l`` with density
    ``cos theta_l / pi`` (a disk point of the stream, :func:`goniometer.optics.cosine_from_disk`), and
    its reflected exit, if any, is written to ``exit_cell[r]`` (MERL cell, -1 if none) and
    ``exit_w[r]`` (weight) instead of to ``brdf``; transmitted exits are booked in ``energy`` only.
    Otherwise ``exit_cell``/``exit_w`` are not touched (they may be empty).

    ``brdf``/``btdf``: (n_theta, n_phi, K + 2, 3), cell-major so that one exit touches one or
    two cache lines: rows ``0 .. K-1`` sum the exit weights of bounce orders ``1 .. K`` (K
    meaning "K or more"), row ``K`` sums the squared weights of all exits and row ``K + 1``
    those of internal exits (order >= 2), for the standard errors. ``energy``: (N_ENERGY, 3) weight
    sums; ``energy_sq``: (N_ENERGY_SQ, 3) sums of squared per-path totals; ``counts``:
    (N_COUNTS,) int64. ``state`` is the chunk's RNG state (advanced). ``skip_first``: reflected
    exits of bounce order 1 whose top event was one microfacet reflection (on a multiple-scattering
    top, a walk of one bounce) are booked in ``energy`` but not deposited (``first_order =
    "integrated"``, :mod:`goniometer.run.first_order`).

    A histogram exit is deposited when the next exit happens (or at the end of the chunk), its
    cell being prefetched meanwhile: each cell still receives its additions in path order, so the
    sums are the same, bit for bit, as with immediate deposits.

    ``if_film``: the packed thin films (:attr:`goniometer.kernel.packing.PackedStack.if_film`): on an
    interface with one, each microfacet reflects and transmits with the film's per-channel
    ``R_c``, ``T_c`` (a dielectric reflects with probability ``P = sum R_c / sum (R_c + T_c)``,
    weights ``R_c / P``, else refracts, weights ``T_c / (1 - P)``; a conductor reflects, weights
    ``R_c``), in walks at every bounce (``docs/material-format.md``, thin films).
    """
    (if_alpha, if_rot, if_ms, if_film, region_eta, region_tau, region_albedo, region_g, cond, rho, base_kind, tau_mode,
     eta_dn, eta_up, _table, _off) = stack
    row_cos, col_cos, col_sin = tables
    brdf, btdf, energy, energy_sq, counts, exit_cell, exit_w = outs
    n_if = region_eta.shape[0] - 1
    transmit_base = base_kind == 0
    conductor_base = base_kind == 1
    # per region: clear, absorbing (achromatic / chromatic) or scattering (layout.tau_modes), and per
    # interface the relative indices going down / up: the run's (stack); the tangent-frame rotation needed
    aniso = np.zeros(max(n_if, 1), dtype=np.bool_)
    for k in range(n_if):
        aniso[k] = if_alpha[k, 0] != if_alpha[k, 1] or if_rot[k, 1] != 0.0
    # any multiple-scattering interface (checked first, so single scattering pays one branch)
    any_ms = False
    for k in range(n_if):
        if if_ms[k]:
            any_ms = True
    # conductor channels that share their complex index share their Fresnel value
    cond_g_is_r = cond[1] == cond[0] and cond[4] == cond[3]
    cond_b_is_g = cond[2] == cond[1] and cond[5] == cond[4]
    # the interface that is the base (the bottom layer), -1 when the base is Lambertian
    base_k = -1 if base_kind == 2 else n_if - 1
    n_events_total = 0
    # the exit not yet deposited: none (0), in brdf (1) or in btdf (2); cell, order row, weight
    pend = 0
    pi = 0
    pj = 0
    po = 0
    pw0 = 0.0
    pw1 = 0.0
    pw2 = 0.0
    tabulate = param == P_TABULATE

    for ray in range(n_rays):
        if tabulate:
            qx, qy = next_disk(state)
            lx, ly, lz = optics.cosine_from_disk(qx, qy)
            exit_cell[ray] = -1
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
        order = 0
        events = 0
        based = False  # the path has had an event at the base
        # the top interface's last walk had one microfacet bounce (always True without walks):
        # an order-1 exit then has the closed form of goniometer.run.first_order
        single = True
        # path-level spectral MIS in chromatic scattering media: hero channel, technique shares
        hero = -1
        q0 = 1.0 / 3.0
        q1 = 1.0 / 3.0
        q2 = 1.0 / 3.0
        # height in the current scattering region (0 bottom .. 1 top); < 0: at the boundary the
        # direction leaves (entering a region)
        hpos = -1.0
        while True:
            if events >= event_cap:
                energy[E_CAPPED, 0] += w0
                energy[E_CAPPED, 1] += w1
                energy[E_CAPPED, 2] += w2
                counts[C_CAPPED] += 1
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
            if scattered:
                # a scattering event inside the medium (an event, not at the top layer)
                at_interface = False
                k = -1
                from_above = True
                events += 1
                if w0 == 0.0 and w1 == 0.0 and w2 == 0.0:
                    break
            elif dz > 0.0:
                if region == 0:
                    # leaves the stack upward: BRDF
                    if tabulate:
                        exit_cell[ray] = halfdiff_cell(lx, ly, lz, dx, dy, dz)
                        exit_w[ray, 0] = w0
                        exit_w[ray, 1] = w1
                        exit_w[ray, 2] = w2
                    elif not (skip_first and order == 1 and single):
                        i, j = cell_index_fast(param, False, lx, ly, lz, dx, dy, dz, n_theta, n_phi,
                                               row_cos, col_cos, col_sin)
                        o = min(order, max_order) - 1
                        _prefetch_exit(brdf, i, j, o, max_order)
                        _deposit_pending(brdf, btdf, pend, pi, pj, po, max_order, pw0, pw1, pw2)
                        pend, pi, pj, po, pw0, pw1, pw2 = 1, i, j, o, w0, w1, w2
                    _book(energy, energy_sq, E_REFLECTED, w0, w1, w2)
                    if not based:
                        _book(energy, energy_sq, E_REFLECTED_WITHOUT_BASE, w0, w1, w2)
                    break
                k = region - 1
                from_above = False
            elif region < n_if:
                k = region
                from_above = True
            elif transmit_base:
                # leaves the stack downward: BTDF
                if not tabulate:
                    i, j = cell_index_fast(param, True, lx, ly, lz, dx, dy, dz, n_theta, n_phi,
                                           row_cos, col_cos, col_sin)
                    o = min(order, max_order) - 1
                    _prefetch_exit(btdf, i, j, o, max_order)
                    _deposit_pending(brdf, btdf, pend, pi, pj, po, max_order, pw0, pw1, pw2)
                    pend, pi, pj, po, pw0, pw1, pw2 = 2, i, j, o, w0, w1, w2
                _book(energy, energy_sq, E_TRANSMITTED, w0, w1, w2)
                break
            else:
                # Lambertian base: weight *= rho, cosine-distributed new direction upward
                at_interface = False
                k = -1
                from_above = True
                events += 1
                based = True
                if n_if == 0:
                    order += 1
                w0, w1, w2, ab0, ab1, ab2 = _attenuate(w0, w1, w2, ab0, ab1, ab2, rho[0], rho[1], rho[2])
                qx, qy = next_disk(state)
                dx, dy, dz = optics.cosine_from_disk(qx, qy)
            # ---- interface event
            if at_interface:
                events += 1
                if k == 0:
                    order += 1
                if k == base_k and from_above:
                    based = True
                # incoming direction in the local frame of the arrival side (z > 0)
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
                    rot = aniso[k]
                    c = 1.0
                    s = 0.0
                    if rot:
                        c = if_rot[k, 0]
                        s = if_rot[k, 1]
                        tx = c * wx + s * wy
                        wy = -s * wx + c * wy
                        wx = tx
                    if any_ms and if_ms[k]:
                        # multiple scattering: the whole walk on the microsurface is this one
                        # event (no masking loss); each further microfacet bounce counts toward
                        # the event cap
                        eta = eta_dn[k] if from_above else eta_up[k]
                        inv_eta = eta_up[k] if from_above else eta_dn[k]
                        ox, oy, oz, f0, f1, f2, nb, transmitted = microsurface_walk(
                            wx, wy, wz, ax, ay, is_cond, cond[0], cond[1], cond[2], cond[3], cond[4], cond[5],
                            cond_g_is_r, cond_b_is_g, eta, inv_eta, max(1, event_cap - events + 1), state, True,
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
                        transmitted = False
                        if filmed:
                            # the thin film, from the side the light arrives from
                            fr = if_film[k]
                            n_in = fr[FL_NA] if from_above else fr[FL_NB0]
                            r0, t0 = optics.film_rt(wm, n_in, fr[FL_N0], fr[FL_K0], fr[FL_NB0] if from_above else fr[FL_NA],
                                                    fr[FL_KB0] if from_above else 0.0, fr[FL_DL0])
                            r1, t1 = optics.film_rt(wm, n_in, fr[FL_N0 + 1], fr[FL_K0 + 1],
                                                    fr[FL_NB0 + 1] if from_above else fr[FL_NA],
                                                    fr[FL_KB0 + 1] if from_above else 0.0, fr[FL_DL0 + 1])
                            r2, t2 = optics.film_rt(wm, n_in, fr[FL_N0 + 2], fr[FL_K0 + 2],
                                                    fr[FL_NB0 + 2] if from_above else fr[FL_NA],
                                                    fr[FL_KB0 + 2] if from_above else 0.0, fr[FL_DL0 + 2])
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
                            f0, f1, f2 = optics.fresnel_conductor_channels(wm, cond[0], cond[3], cond[1], cond[4], cond[2],
                                                                           cond[5], cond_g_is_r, cond_b_is_g)
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
                        energy[E_ROULETTE, 0] -= w0 * boost
                        energy[E_ROULETTE, 1] -= w1 * boost
                        energy[E_ROULETTE, 2] -= w2 * boost
                        w0 *= 1.0 / p
                        w1 *= 1.0 / p
                        w2 *= 1.0 / p
                    else:
                        energy[E_ROULETTE, 0] += w0
                        energy[E_ROULETTE, 1] += w1
                        energy[E_ROULETTE, 2] += w2
                        break
        n_events_total += events
        _book(energy, energy_sq, E_ABSORBED, ab0, ab1, ab2)
        _book(energy, energy_sq, E_MASKING, mk0, mk1, mk2)
    _deposit_pending(brdf, btdf, pend, pi, pj, po, max_order, pw0, pw1, pw2)
    counts[C_EVENTS] += n_events_total
