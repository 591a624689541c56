"""The numba-parallel path-tracing kernel of the virtual goniometer.

Transport (``docs/material-format.md``, transport): a path starts above the top interface travelling along ``-l``
with weight (1, 1, 1). At an interface a microfacet normal is sampled from the visible
normals of the side the path comes from; a dielectric reflects with probability F (exact
Fresnel) and refracts otherwise, a conductor always reflects with weight *= F (RGB).
The weight is then multiplied by the masking term (separable: ``G1(o)``; height-correlated:
``G2 / G1(i)``) and an outgoing direction on the wrong side of the macro-surface ends the path
(``masking_loss``). On a multiple-scattering interface the event is instead a random walk on the
microsurface (:func:`microsurface_walk`, Heitz et al. 2016) that always leaves it: no masking loss. Absorbing media attenuate deterministically (Beer-Lambert); in a scattering
medium the path makes free flights between collisions (:func:`_free_flight`: spectral-MIS
distance sampling, Henyey-Greenstein directions). Lambertian bases reflect with cosine sampling
and weight *= rho. A path leaving the top upward is recorded in the BRDF
slice of its bounce order (number of events at the top layer); one leaving the bottom of a
transmitting stack downward in the BTDF slice.

Energy bookkeeping per channel and per path is exact: the weight a path loses is booked as
absorbed or masking loss, the weight it leaves with as reflected or transmitted; Russian
roulette books the weight it kills and the weight it adds (negative) in ``roulette``, and paths
stopped by the event cap book their weight in ``capped``. Hence, per chunk,
reflected + transmitted + absorbed + masking + roulette + capped = number of rays (to rounding).
A reflected path that never had an event at the base (the bottom layer) also books its weight in
``E_REFLECTED_WITHOUT_BASE`` (a part of reflected; ``docs/slices-format.md``, ``/energy``).

Kernel inputs are flat arrays (see :class:`goniometer.stack.PackedStack`); outputs are
per-chunk histograms, so results do not depend on the number of threads.
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
from goniometer.halfdiff import cell_of as halfdiff_cell
from goniometer.rng import next_disk, next_float, stream_state
from goniometer.slices import cell_index_fast

# rows of the per-chunk energy array
E_REFLECTED = 0
E_TRANSMITTED = 1
E_ABSORBED = 2
E_MASKING = 3
#: reflected weight of paths that never had an event at the base (the bottom layer)
E_REFLECTED_WITHOUT_BASE = 4
E_ROULETTE = 5
E_CAPPED = 6
N_ENERGY = 7
#: rows with a per-path second moment (for standard errors)
N_ENERGY_SQ = 5
# columns of the per-chunk counters
C_CAPPED = 0
C_EVENTS = 1
N_COUNTS = 2

#: Russian roulette: from this many events on, paths whose largest channel weight is below
#: RR_THRESHOLD survive with probability max(w) / RR_THRESHOLD
RR_START = 3
RR_THRESHOLD = 0.05
#: default hard cap on the number of events of one path (reported if ever reached)
EVENT_CAP = 10_000
#: ``param`` of :func:`trace_chunk` for a tabulation (``docs/tabulated-format.md``): every path
#: draws its own incident direction (cosine-weighted), and a reflected exit is recorded per path as
#: its MERL cell (:func:`goniometer.halfdiff.cell_of`) and weight instead of in a slice histogram
P_TABULATE = 2
#: ``tau_mode`` of a scattering medium region with achromatic extinction (+ 1: chromatic)
TAU_SCATTER = 3


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


@numba.njit(cache=True, _nrt=False)
def _prefetch_exit(h, i, j, o, max_order):
    """Prefetch the rows of histogram cell ``(i, j)`` that :func:`_deposit` will update."""
    _prefetch(h, i, j, o, 0)
    _prefetch(h, i, j, o, 2)
    _prefetch(h, i, j, max_order, 0)
    _prefetch(h, i, j, max_order + 1, 2)


@numba.njit(cache=True, _nrt=False)
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


@numba.njit(cache=True, _nrt=False)
def _deposit_pending(brdf, btdf, pend, i, j, o, max_order, w0, w1, w2):
    """Deposit the exit held back for prefetching: none (``pend`` 0), BRDF (1) or BTDF (2)."""
    if pend == 1:
        _deposit(brdf, i, j, o, max_order, w0, w1, w2)
    elif pend == 2:
        _deposit(btdf, i, j, o, max_order, w0, w1, w2)


@numba.njit(cache=True, inline="always")
def _book(energy, energy_sq, row, x0, x1, x2):
    """Add a path's per-channel amount to energy row ``row`` and its square to the second moments."""
    energy[row, 0] += x0
    energy[row, 1] += x1
    energy[row, 2] += x2
    energy_sq[row, 0] += x0 * x0
    energy_sq[row, 1] += x1 * x1
    energy_sq[row, 2] += x2 * x2


@numba.njit(cache=True, inline="always")
def _attenuate(w0, w1, w2, ab0, ab1, ab2, a0, a1, a2):
    """The path weight times ``(a0, a1, a2)`` per channel, what it loses booked as absorbed:
    ``(w0 a0, w1 a1, w2 a2, ab0 + w0 (1 - a0), ...)``."""
    return w0 * a0, w1 * a1, w2 * a2, ab0 + w0 * (1.0 - a0), ab1 + w1 * (1.0 - a1), ab2 + w2 * (1.0 - a2)


@numba.njit(cache=True, error_model='numpy')
def _free_flight(achromatic, t0, t1, t2, a0, a1, a2, g, hpos, dx, dy, dz, w0, w1, w2, ab0, ab1, ab2,
                 hero, q0, q1, q2, state):
    """One free flight of a path in a scattering medium region (``docs/material-format.md``, media).

    The region is a slab of unit thickness whose extinction coefficients are the optical depths
    ``t_c``; ``hpos`` is the height of the path in it (1 top, 0 bottom; < 0: entering, at the
    boundary the direction leaves). The flight length is drawn from ``t0`` (achromatic
    extinction: weights change only by the albedo at a collision) or, with chromatic extinction,
    from the path's hero channel ``hero`` (picked uniformly at the path's first chromatic flight;
    -1 before) with path-level spectral MIS weights (:func:`goniometer.optics.spectral_mis_update`;
    ``q`` the path's technique shares, bounded weights). A collision scatters with the albedo
    weights and a Henyey-Greenstein direction; the weight each channel loses (or gains) is booked
    as absorbed, which keeps the per-path bookkeeping exact.

    Returns ``(scattered, hpos, d, w, absorbed, hero, q)``: ``scattered`` False when the path
    reached the boundary of the region (``hpos`` reset to -1); a path moving exactly horizontally
    that draws no collision is lost (booked as absorbed, weights 0; measure zero).
    """
    h = hpos if hpos >= 0.0 else (1.0 if dz < 0.0 else 0.0)
    if dz < 0.0:
        smax = h / -dz
    elif dz > 0.0:
        smax = (1.0 - h) / dz
    else:
        smax = math.inf
    if achromatic:
        s = -math.log1p(-next_float(state)) / t0
    else:
        if hero < 0:
            hero = min(int(next_float(state) * 3.0), 2)
        s = optics.hero_free_flight(next_float(state), t0 if hero == 0 else (t1 if hero == 1 else t2))
    if s >= smax:
        if smax == math.inf:
            return True, h, dx, dy, dz, 0.0, 0.0, 0.0, ab0 + w0, ab1 + w1, ab2 + w2, hero, q0, q1, q2
        if achromatic:
            return False, -1.0, dx, dy, dz, w0, w1, w2, ab0, ab1, ab2, hero, q0, q1, q2
        r0, r1, r2, q0, q1, q2 = optics.spectral_mis_update(math.exp(-t0 * smax), math.exp(-t1 * smax),
                                                            math.exp(-t2 * smax), q0, q1, q2)
        return (False, -1.0, dx, dy, dz, w0 * r0, w1 * r1, w2 * r2,
                ab0 + w0 * (1.0 - r0), ab1 + w1 * (1.0 - r1), ab2 + w2 * (1.0 - r2), hero, q0, q1, q2)
    if achromatic:
        r0 = a0
        r1 = a1
        r2 = a2
    else:
        c0, c1, c2, q0, q1, q2 = optics.spectral_mis_update(t0 * math.exp(-t0 * s), t1 * math.exp(-t1 * s),
                                                            t2 * math.exp(-t2 * s), q0, q1, q2)
        r0 = a0 * c0
        r1 = a1 * c1
        r2 = a2 * c2
    w0, w1, w2, ab0, ab1, ab2 = _attenuate(w0, w1, w2, ab0, ab1, ab2, r0, r1, r2)
    h = min(1.0, max(0.0, h + s * dz))
    u1 = next_float(state)
    ox, oy, oz = optics.hg_scatter(dx, dy, dz, g, u1, next_float(state))
    return True, h, ox, oy, oz, w0, w1, w2, ab0, ab1, ab2, hero, q0, q1, q2


@numba.njit(cache=True, error_model='numpy')
def microsurface_walk(wx, wy, wz, ax, ay, conductor, ce0, ce1, ce2, ck0, ck1, ck2, g_is_r, b_is_g,
                      eta, inv_eta, max_bounces, state):
    """One event on a multiple-scattering interface: the random walk of Heitz et al. 2016 on the
    GGX microsurface with Smith's height-correlated statistics (``docs/material-format.md`` 2.1).

    ``w`` is the direction the light arrives from, in the interface's tangent frame of the
    arrival side (``w_z > 0``); ``(ax, ay)`` its roughness. The ray starts above the microsurface
    (height CDF 1); each step draws the next hit height (:func:`goniometer.optics.ms_sample_height`),
    a visible normal of the reversed ray direction (:func:`goniometer.optics.sample_vndf_disk`, valid
    for directions below the horizon too) and reflects there -- a conductor with its Fresnel
    weight per channel (complex index ``ce + i ck`` relative to the arrival side), a dielectric
    reflecting with probability F and otherwise refracting (relative index ``eta``; on the far
    side the microsurface is seen from below: heights ``1 - c``, directions negated, index
    ``inv_eta``), until the ray leaves the microsurface. ``g_is_r`` / ``b_is_g``: channels that
    share their complex index (one Fresnel evaluation).

    Returns ``(ox, oy, oz, f0, f1, f2, n, transmitted)``: the exit direction (``o_z > 0``
    reflected, ``< 0`` transmitted), the product of the conductor's Fresnel factors per channel
    (1 for a dielectric) and the number ``n >= 1`` of microfacet bounces; ``n = 0`` when the ray
    is still on the microsurface after ``max_bounces`` bounces (the caller books it as capped).
    """
    vx = -wx
    vy = -wy
    vz = -wz
    c = 1.0
    inside = False
    f0 = 1.0
    f1 = 1.0
    f2 = 1.0
    n = 0
    while n < max_bounces:
        cn = optics.ms_sample_height(vx, vy, vz, c, ax, ay, next_float(state))
        if cn < 0.0:
            if inside:
                return -vx, -vy, -vz, f0, f1, f2, n, True
            return vx, vy, vz, f0, f1, f2, n, False
        n += 1
        c = cn
        ix = -vx
        iy = -vy
        iz = -vz
        qx, qy = next_disk(state)
        mx, my, mz = optics.sample_vndf_disk(ix, iy, iz, ax, ay, qx, qy)
        im = ix * mx + iy * my + iz * mz
        if conductor:
            r0 = optics.fresnel_conductor(im, ce0, ck0)
            r1 = r0 if g_is_r else optics.fresnel_conductor(im, ce1, ck1)
            r2 = r1 if b_is_g else optics.fresnel_conductor(im, ce2, ck2)
            f0 *= r0
            f1 *= r1
            f2 *= r2
            vx, vy, vz = optics.reflect(ix, iy, iz, mx, my, mz)
        else:
            e = inv_eta if inside else eta
            ie = eta if inside else inv_eta
            f, cos_t = optics.fresnel_dielectric_cos_t_inv(im, e, ie)
            if next_float(state) < f:
                vx, vy, vz = optics.reflect(ix, iy, iz, mx, my, mz)
            else:
                tx, ty, tz = optics.refract_known(ix, iy, iz, mx, my, mz, ie, im, cos_t)
                vx = -tx
                vy = -ty
                vz = -tz
                inside = not inside
                c = 1.0 - c
    return vx, vy, vz, f0, f1, f2, 0, inside


@numba.njit(cache=True, error_model='numpy')
def trace_chunk(if_alpha, if_rot, if_ms, region_eta, region_tau, region_albedo, region_g, cond, rho, base_kind,
                lx, ly, lz, n_rays, state, param, n_theta, n_phi, row_cos, col_cos, col_sin, max_order,
                height_correlated, event_cap, brdf, btdf, energy, energy_sq, counts, exit_cell, exit_w):
    """Trace ``n_rays`` paths for light direction ``l`` and accumulate into the given arrays.

    ``param`` is the slice parametrization (:data:`goniometer.slices.CLASSIC`, ``HALF``) or
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
    (N_COUNTS,) int64. ``state`` is the chunk's RNG state (advanced).

    A histogram exit is deposited when the next exit happens (or at the end of the chunk), its
    cell being prefetched meanwhile: each cell still receives its additions in path order, so the
    sums are the same, bit for bit, as with immediate deposits.
    """
    n_if = region_eta.shape[0] - 1
    transmit_base = base_kind == 0
    conductor_base = base_kind == 1
    # per region: 0 no absorption, 1 achromatic (one exp), 2 chromatic; a scattering medium
    # (albedo > 0 where tau > 0): TAU_SCATTER achromatic extinction, TAU_SCATTER + 1 chromatic
    tau_mode = np.zeros(n_if + 1, dtype=np.int64)
    for r in range(n_if + 1):
        t0 = region_tau[r, 0]
        if t0 > 0.0 or region_tau[r, 1] > 0.0 or region_tau[r, 2] > 0.0:
            achromatic = region_tau[r, 1] == t0 and region_tau[r, 2] == t0
            tau_mode[r] = 1 if achromatic else 2
            for c in range(3):
                if region_albedo[r, c] > 0.0 and region_tau[r, c] > 0.0:
                    tau_mode[r] = TAU_SCATTER if achromatic else TAU_SCATTER + 1
    # per interface: relative indices going down / up, tangent-frame rotation needed
    n_k = max(n_if, 1)
    eta_dn = np.ones(n_k)
    eta_up = np.ones(n_k)
    aniso = np.zeros(n_k, dtype=np.bool_)
    for k in range(n_if):
        eta_dn[k] = region_eta[k + 1] / region_eta[k]
        eta_up[k] = 1.0 / eta_dn[k]
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
                scattered, hpos, dx, dy, dz, w0, w1, w2, ab0, ab1, ab2, hero, q0, q1, q2 = _free_flight(
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
                    else:
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
                if not is_cond and eta_dn[k] == 1.0:
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
                            cond_g_is_r, cond_b_is_g, eta, inv_eta, max(1, event_cap - events + 1), state)
                        if is_cond:
                            w0, w1, w2, ab0, ab1, ab2 = _attenuate(w0, w1, w2, ab0, ab1, ab2, f0, f1, f2)
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
                        if is_cond:
                            f0 = optics.fresnel_conductor(wm, cond[0], cond[3])
                            f1 = f0 if cond_g_is_r else optics.fresnel_conductor(wm, cond[1], cond[4])
                            f2 = f1 if cond_b_is_g else optics.fresnel_conductor(wm, cond[2], cond[5])
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


@numba.njit(cache=True, error_model='numpy')
def trace_slot(b, if_alpha, if_rot, if_ms, region_eta, region_tau, region_albedo, region_g, cond, rho, base_kind,
               lx, ly, lz, n_rays_total, chunk_rays, first_chunk, seed, incident_index,
               param, n_theta, n_phi, row_cos, col_cos, col_sin, max_order, height_correlated, event_cap,
               brdf, btdf, energy, energy_sq, counts, exit_cell, exit_w):
    """Zero histogram slot ``b`` and trace chunk ``first_chunk + b`` into it (``exit_cell[b]``,
    ``exit_w[b]``: see :func:`trace_chunk`).

    Chunk ``c`` covers rays ``[c * chunk_rays, min((c + 1) * chunk_rays, n_rays_total))`` and
    draws from the stream ``(seed, incident_index, c)``.
    """
    c = first_chunk + b
    n = min(chunk_rays, n_rays_total - c * chunk_rays)
    brdf[b].fill(0.0)
    btdf[b].fill(0.0)
    energy[b].fill(0.0)
    energy_sq[b].fill(0.0)
    counts[b].fill(0)
    exit_cell[b].fill(-1)
    if n <= 0:
        return
    state = stream_state(np.uint64(seed), np.uint64(incident_index), np.uint64(c))
    trace_chunk(if_alpha, if_rot, if_ms, region_eta, region_tau, region_albedo, region_g, cond, rho, base_kind,
                lx, ly, lz, n, state, param, n_theta, n_phi, row_cos, col_cos, col_sin, max_order,
                height_correlated, event_cap, brdf[b], btdf[b], energy[b], energy_sq[b], counts[b], exit_cell[b],
                exit_w[b])


@numba.njit(parallel=True, cache=True, error_model='numpy')
def trace_batch(if_alpha, if_rot, if_ms, region_eta, region_tau, region_albedo, region_g, cond, rho, base_kind,
                lx, ly, lz, n_rays_total, chunk_rays, first_chunk, seed, incident_index,
                param, n_theta, n_phi, row_cos, col_cos, col_sin, max_order, height_correlated, event_cap,
                brdf, btdf, energy, energy_sq, counts, exit_cell, exit_w):
    """Trace chunks ``first_chunk .. first_chunk + B - 1`` in parallel, one histogram slot each
    (:func:`trace_slot`). Output arrays carry a leading dimension B (the batch)."""
    for b in numba.prange(brdf.shape[0]):
        trace_slot(b, if_alpha, if_rot, if_ms, region_eta, region_tau, region_albedo, region_g, cond, rho, base_kind,
                   lx, ly, lz, n_rays_total, chunk_rays, first_chunk, seed, incident_index,
                   param, n_theta, n_phi, row_cos, col_cos, col_sin, max_order, height_correlated, event_cap,
                   brdf, btdf, energy, energy_sq, counts, exit_cell, exit_w)


@numba.njit(cache=True, error_model='numpy')
def trace_batch_serial(if_alpha, if_rot, if_ms, region_eta, region_tau, region_albedo, region_g, cond, rho, base_kind,
                       lx, ly, lz, n_rays_total, chunk_rays, first_chunk, seed, incident_index,
                       param, n_theta, n_phi, row_cos, col_cos, col_sin, max_order, height_correlated, event_cap,
                       brdf, btdf, energy, energy_sq, counts, exit_cell, exit_w):
    """:func:`trace_batch` without threads (same per-chunk results, bit for bit).

    For callers that are themselves run concurrently, e.g. the threads of a Dask worker: numba's
    default threading layer must not be entered by several threads at once.
    """
    for b in range(brdf.shape[0]):
        trace_slot(b, if_alpha, if_rot, if_ms, region_eta, region_tau, region_albedo, region_g, cond, rho, base_kind,
                   lx, ly, lz, n_rays_total, chunk_rays, first_chunk, seed, incident_index,
                   param, n_theta, n_phi, row_cos, col_cos, col_sin, max_order, height_correlated, event_cap,
                   brdf, btdf, energy, energy_sq, counts, exit_cell, exit_w)
