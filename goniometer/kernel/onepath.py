"""The per-path transport (``docs/kernel.md``, one physics, two drivers): :func:`trace_path` traces
one path from start to end. It is the only code that does, for every driver that traces whole
paths: the per-path kernel on the CPU (:mod:`goniometer.kernel.paths`, the tests' second
implementation) and the CUDA kernel (:mod:`goniometer.kernel.cuda`, one GPU thread per path) call
it, as pbrt-v4's CPU and wavefront integrators share their BxDFs. The lane kernel
(:mod:`goniometer.kernel.event`) makes the same events in its own vectorised loop, calling the same
:mod:`goniometer.optics` formulas and the same walks (:func:`goniometer.kernel.steps.walk_from`).

Transport (``docs/material-format.md``, transport): a path starts above the top interface
travelling along ``-l`` with weight (1, 1, 1). At an interface a microfacet normal is sampled from
the visible normals of the side the path comes from; a dielectric reflects with probability F
(exact Fresnel) and refracts otherwise, a conductor always reflects with weight *= F (RGB); a thin
film's per-channel R and T replace Fresnel's (:func:`goniometer.kernel.steps.film_choice`). The
weight is then multiplied by the masking term (separable: ``G1(o)``; height-correlated: ``G2 /
G1(i)``) and an outgoing direction on the wrong side of the macro-surface ends the path (masking
loss). On a multiple-scattering interface the event is instead a random walk on the microsurface
(:func:`goniometer.kernel.steps.microsurface_walk`, Heitz et al. 2016) that always leaves it: no
masking loss. Absorbing media attenuate deterministically (Beer-Lambert); in a scattering medium
the path makes free flights between collisions (:func:`goniometer.kernel.steps.free_flight`:
spectral-MIS distance sampling, Henyey-Greenstein directions). Lambertian bases reflect with
cosine sampling and weight *= rho. A path leaving the top upward is recorded in the BRDF slice of
its bounce order (number of events at the top layer); one leaving the bottom of a transmitting
stack downward in the BTDF slice. From :data:`~goniometer.kernel.event.RR_START` events on, Russian
roulette keeps a path whose largest channel weight is below
:data:`~goniometer.kernel.event.RR_THRESHOLD` with probability ``max(w) / RR_THRESHOLD`` (its weight
divided by it); a path that reaches the event cap is stopped (capped).

Energy bookkeeping per channel and per path is exact: the weight a path loses is booked as
absorbed or masking loss, the weight it leaves with as reflected or transmitted; Russian roulette
books the weight it kills and the weight it adds (negative) as roulette, and a capped path its
weight as capped. Hence reflected + transmitted + absorbed + masking + roulette + capped = 1 per
path and channel (to rounding). A reflected path that never had an event at the base (the bottom
layer) also books its weight as reflected without base (``docs/slices-format.md``, ``/energy``).
:func:`trace_path` returns the exit and adds the rest to the path's record (``R_*``); the drivers
book both.
"""

from __future__ import annotations

import math

import numba

from goniometer import optics
from goniometer.kernel.event import RR_START, RR_THRESHOLD
from goniometer.kernel.layout import (E_ABSORBED, E_CAPPED, E_MASKING, E_REFLECTED, E_REFLECTED_WITHOUT_BASE,
                                      E_ROULETTE, E_TRANSMITTED, TAU_SCATTER)
from goniometer.kernel.packing import FL_ON
from goniometer.kernel.rng import next_disk, next_float
from goniometer.kernel import polarized
from goniometer.kernel.steps import film_choice, film_p, film_rt3, free_flight, microsurface_walk

#: how a path ended (:func:`trace_path`'s first value): inside the stack with nothing to book but
#: its books (killed by roulette, lost to masking, no weight left), out of the top (BRDF), out of
#: the bottom of a transmitting stack (BTDF), or stopped by the event cap (its weight is capped)
X_LOST = 0
X_REFLECTED = 1
X_TRANSMITTED = 2
X_CAPPED = 3
#: a path's record (float64[N_RECORD], :func:`new_record`): per channel the weight it lost to
#: absorption, to masking, and roulette's net change (killed weight, minus the weight boosts added);
#: then its state in scattering media: the spectral-MIS technique shares, the hero channel (-1
#: before its first chromatic flight) and the height in the region (< 0: at the boundary it enters
#: by). The state a path rarely touches, kept out of the registers of a GPU thread (the CUDA
#: kernel keeps records in shared memory, ``docs/gpu.md``)
R_ABSORBED = 0
R_MASKING = 3
R_ROULETTE = 6
R_Q = 9
R_HERO = 12
R_HPOS = 13
N_RECORD = 14


@numba.njit(cache=True, error_model='numpy', inline='always')
def path_light(state, tabulate, lx, ly, lz):
    """The light direction of a path whose stream is ``state``: ``l``, or for a tabulation
    (``tabulate`` True) the path's own, cosine-weighted, from its first disk point
    (:func:`goniometer.optics.cosine_from_disk`)."""
    if tabulate:
        qx, qy = next_disk(state)
        return optics.cosine_from_disk(qx, qy)
    return lx, ly, lz


@numba.njit(cache=True, error_model='numpy', inline='always')
def new_record(rec) -> None:
    """A new path's record: nothing lost, equal technique shares, no hero, not in a medium."""
    for c in range(R_Q):
        rec[c] = 0.0
    for c in range(3):
        rec[R_Q + c] = 1.0 / 3.0
    rec[R_HERO] = -1.0
    rec[R_HPOS] = -1.0


@numba.njit(cache=True, error_model='numpy', inline='always')
def path_energy(kind, based, w0, w1, w2, rec, row):
    """A traced path's energy term ``row`` (``E_*`` of :mod:`goniometer.kernel.layout`) per channel,
    from how it ended (:func:`trace_path`'s ``kind``, ``based`` and weight) and its record: what every
    driver books per path (rows below ``N_ENERGY_SQ`` with their squares)."""
    if row == E_ABSORBED or row == E_MASKING or row == E_ROULETTE:
        r = R_ABSORBED if row == E_ABSORBED else (R_MASKING if row == E_MASKING else R_ROULETTE)
        return rec[r], rec[r + 1], rec[r + 2]
    if row == E_REFLECTED:
        on = kind == X_REFLECTED
    elif row == E_REFLECTED_WITHOUT_BASE:
        on = kind == X_REFLECTED and not based
    elif row == E_TRANSMITTED:
        on = kind == X_TRANSMITTED
    else:
        on = row == E_CAPPED and kind == X_CAPPED
    return (w0, w1, w2) if on else (0.0, 0.0, 0.0)


@numba.njit(cache=True, error_model='numpy', inline='always')
def _absorb(rec, w0, w1, w2, a0, a1, a2):
    """The path weight times ``(a0, a1, a2)`` per channel; what it loses booked as absorbed."""
    rec[R_ABSORBED] += w0 * (1.0 - a0)
    rec[R_ABSORBED + 1] += w1 * (1.0 - a1)
    rec[R_ABSORBED + 2] += w2 * (1.0 - a2)
    return w0 * a0, w1 * a1, w2 * a2


@numba.njit(cache=True, error_model='numpy', inline='always')
def _fresnel_books(rec, pol, w0, w1, w2):
    """A polarized path's weights after a Fresnel event (its Mueller matrices' ``[0, 0]``), what
    they changed by booked as absorbed (signed: a conductor's or a film's absorption, and the
    difference between the state's own reflectance and the unpolarized one that chose the event)."""
    v0, v1, v2 = polarized.weights(pol)
    rec[R_ABSORBED] += w0 - v0
    rec[R_ABSORBED + 1] += w1 - v1
    rec[R_ABSORBED + 2] += w2 - v2
    return v0, v1, v2


@numba.njit(cache=True, error_model='numpy', inline='always')
def trace_path(stack, dx, dy, dz, height_correlated, film, event_cap, state, rec, pol=None):
    """Trace one path (the module docstring's transport) entering the stack from above along
    ``d`` (``-l``; unit, ``d_z < 0``), drawing from the xoshiro256** stream ``state``
    (uint64[4], seeded by the driver from the path's key, :mod:`goniometer.kernel.rng`).

    ``stack``: the kernels' stack argument (:data:`goniometer.kernel.variants.KernelStack`: the
    packed arrays and the facts the run derived once); ``height_correlated``, ``film``: the variant
    (None or True each, :class:`goniometer.kernel.variants.Variant`: height-correlated masking, and
    the thin films' code, compiled only for a stack with a film); ``event_cap``: the most events of
    a path; ``rec``: the path's record (``R_*``, set by :func:`new_record`), to which it adds its
    absorbed, masking and roulette weights; ``pol``: None (scalar light), or a polarized path's
    state (:mod:`goniometer.kernel.polarized`, set up by the driver), which every event then changes
    too: the path's weights are its Mueller matrices' ``[0, 0]``, a Fresnel event's change of them
    booked as absorbed (signed per path: the reflection's and refraction's choice is the unpolarized
    one, ``docs/polarization.md``), and at the exit the frames are the exit beam's s/p frame.

    Returns ``(kind, dx, dy, dz, w0, w1, w2, order, single, based, events)``: how the path ended
    (``X_*``), its exit direction and weight (the capped weight for ``X_CAPPED``), its bounce order
    (events at the top interface), whether the top's last walk had one bounce (always True without
    walks: an order-1 exit then has the closed form of :mod:`goniometer.run.first_order`), whether
    it had an event at the base, and its events. Inlined into its drivers (a call per path would
    pass the stack's arrays each time: 10 % of the per-path kernel's time)."""
    n_if = stack.n_if
    transmit_base = stack.transmit_base
    conductor_base = stack.conductor_base
    base_k = stack.base_k
    region = 0
    w0 = 1.0
    w1 = 1.0
    w2 = 1.0
    kind = X_LOST
    order = 0
    events = 0
    based = False  # the path has had an event at the base
    single = True  # the top interface's last walk had one microfacet bounce
    while True:
        if events >= event_cap:
            kind = X_CAPPED
            break
        # ---- traverse the current region (Beer-Lambert), or one free flight in a scattering medium
        tm = stack.tau_mode[region]
        scattered = False
        if tm >= TAU_SCATTER:
            tau = stack.region_tau
            alb = stack.region_albedo
            # (path-level spectral MIS: the hero channel and the technique shares, and the height in
            # the region, from the path's record)
            v0, v1, v2 = w0, w1, w2
            scattered, hpos, dx, dy, dz, w0, w1, w2, ab0, ab1, ab2, hero, q0, q1, q2 = free_flight(
                tm == TAU_SCATTER, tau[region, 0], tau[region, 1], tau[region, 2], alb[region, 0], alb[region, 1],
                alb[region, 2], stack.region_g[region], rec[R_HPOS], dx, dy, dz, w0, w1, w2, rec[R_ABSORBED],
                rec[R_ABSORBED + 1], rec[R_ABSORBED + 2], int(rec[R_HERO]), rec[R_Q], rec[R_Q + 1], rec[R_Q + 2],
                state)
            rec[R_HPOS] = hpos
            rec[R_ABSORBED] = ab0
            rec[R_ABSORBED + 1] = ab1
            rec[R_ABSORBED + 2] = ab2
            rec[R_HERO] = float(hero)
            rec[R_Q] = q0
            rec[R_Q + 1] = q1
            rec[R_Q + 2] = q2
            if pol is not None:
                polarized.rescale(pol, v0, v1, v2, w0, w1, w2)
                if scattered:
                    polarized.depolarize(pol, 1.0, 1.0, 1.0, dx, dy, dz)
        elif tm != 0:
            inv_mu = 1.0 / abs(dz)
            a0 = math.exp(-stack.region_tau[region, 0] * inv_mu)
            if tm == 1:
                a1 = a0
                a2 = a0
            else:
                a1 = math.exp(-stack.region_tau[region, 1] * inv_mu)
                a2 = math.exp(-stack.region_tau[region, 2] * inv_mu)
            w0, w1, w2 = _absorb(rec, w0, w1, w2, a0, a1, a2)
            if pol is not None:
                polarized.scale(pol, a0, a1, a2)
        # ---- what lies at the end of this traversal
        at_interface = True
        k = -1
        from_above = True
        if scattered:
            # a scattering event inside the medium (an event, not at the top layer)
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
            w0, w1, w2 = _absorb(rec, w0, w1, w2, stack.rho[0], stack.rho[1], stack.rho[2])
            qx, qy = next_disk(state)
            dx, dy, dz = optics.cosine_from_disk(qx, qy)
            if pol is not None:
                polarized.depolarize(pol, stack.rho[0], stack.rho[1], stack.rho[2], dx, dy, dz)
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
            filmed = False if film is None else stack.if_film[k, FL_ON] != 0.0
            if not is_cond and stack.eta_dn[k] == 1.0 and not filmed:
                # index-matched dielectric: the interface is optically absent
                region = k + 1 if from_above else k
            else:
                eta = stack.eta_dn[k] if from_above else stack.eta_up[k]
                inv_eta = stack.eta_up[k] if from_above else stack.eta_dn[k]
                ax = stack.if_alpha[k, 0]
                ay = stack.if_alpha[k, 1]
                rot = stack.if_aniso[k]
                c = 1.0
                s = 0.0
                if rot:
                    c = stack.if_rot[k, 0]
                    s = stack.if_rot[k, 1]
                    tx = c * wx + s * wy
                    wy = -s * wx + c * wy
                    wx = tx
                cond = stack.cond
                if stack.any_ms and stack.if_ms[k]:
                    # multiple scattering: the whole walk on the microsurface is this one event (no
                    # masking loss); each further microfacet bounce counts toward the event cap
                    ox, oy, oz, f0, f1, f2, nb, transmitted = microsurface_walk(
                        wx, wy, wz, ax, ay, is_cond, cond, stack.g_is_r, stack.b_is_g, eta, inv_eta,
                        max(1, event_cap - events + 1), state, film, stack.if_film[k], from_above, pol, c, s)
                    if pol is not None:
                        w0, w1, w2 = _fresnel_books(rec, pol, w0, w1, w2)
                    elif is_cond or filmed:
                        w0, w1, w2 = _absorb(rec, w0, w1, w2, f0, f1, f2)
                    if k == 0:
                        single = nb == 1
                    if nb == 0:
                        # still on the microsurface at the cap: capped at the loop's top
                        events = event_cap
                        continue
                    events += nb - 1
                else:
                    qx, qy = next_disk(state)
                    mx, my, mz = optics.sample_vndf_disk(wx, wy, wz, ax, ay, qx, qy)
                    wm = wx * mx + wy * my + wz * mz
                    transmitted = False
                    cos_t = 0.0
                    if pol is not None:
                        # the plane of incidence on the microfacet, in the stack's frame
                        polarized.to_plane(pol, dx, dy, dz, c * mx - s * my, s * mx + c * my,
                                           mz if from_above else -mz)
                    if filmed:
                        # the thin film, from the side the light arrives from
                        r0, r1, r2, t0, t1, t2 = film_rt3(wm, stack.if_film[k], from_above)
                        if is_cond:
                            if pol is None:
                                w0, w1, w2 = _absorb(rec, w0, w1, w2, r0, r1, r2)
                            else:
                                polarized.film(pol, wm, stack.if_film[k], from_above, True, 1.0)
                        else:
                            _, cos_t = optics.fresnel_dielectric_cos_t_inv(wm, eta, inv_eta)
                            refl, a0, a1, a2 = film_choice(next_float(state), r0, r1, r2, t0, t1, t2)
                            if pol is None:
                                w0, w1, w2 = _absorb(rec, w0, w1, w2, a0, a1, a2)
                            else:
                                polarized.film(pol, wm, stack.if_film[k], from_above, refl,
                                               film_p(r0, r1, r2, t0, t1, t2))
                            transmitted = not refl
                    elif is_cond:
                        if pol is None:
                            f0, f1, f2 = optics.fresnel_conductor_channels(wm, cond[0], cond[3], cond[1], cond[4],
                                                                           cond[2], cond[5], stack.g_is_r,
                                                                           stack.b_is_g)
                            w0, w1, w2 = _absorb(rec, w0, w1, w2, f0, f1, f2)
                        else:
                            polarized.conductor(pol, wm, cond)
                    else:
                        f, cos_t = optics.fresnel_dielectric_cos_t_inv(wm, eta, inv_eta)
                        transmitted = next_float(state) >= f
                        if pol is not None:
                            polarized.dielectric(pol, wm, eta, not transmitted, f)
                    if pol is not None:
                        w0, w1, w2 = _fresnel_books(rec, pol, w0, w1, w2)
                    if transmitted:
                        ox, oy, oz = optics.refract_known(wx, wy, wz, mx, my, mz, inv_eta, wm, cos_t)
                    else:
                        ox, oy, oz = optics.reflect(wx, wy, wz, mx, my, mz)
                    # single-scattering microfacet model: wrong side -> lost to masking
                    if (transmitted and oz >= 0.0) or (not transmitted and oz <= 0.0):
                        rec[R_MASKING] += w0
                        rec[R_MASKING + 1] += w1
                        rec[R_MASKING + 2] += w2
                        break
                    if height_correlated is not None:
                        lam_o = optics.ggx_lambda(ox, oy, oz, ax, ay)
                        lam_i = optics.ggx_lambda(wx, wy, wz, ax, ay)
                        g = optics.smith_g2(lam_i, lam_o, transmitted, True) * (1.0 + lam_i)
                    else:
                        g = optics.smith_g1_dir(ox, oy, oz, ax, ay)
                    rec[R_MASKING] += w0 * (1.0 - g)
                    rec[R_MASKING + 1] += w1 * (1.0 - g)
                    rec[R_MASKING + 2] += w2 * (1.0 - g)
                    w0 *= g
                    w1 *= g
                    w2 *= g
                    if pol is not None:
                        polarized.scale(pol, g, g, g)
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
                    rec[R_ROULETTE] -= w0 * boost
                    rec[R_ROULETTE + 1] -= w1 * boost
                    rec[R_ROULETTE + 2] -= w2 * boost
                    w0 *= 1.0 / p
                    w1 *= 1.0 / p
                    w2 *= 1.0 / p
                    if pol is not None:
                        polarized.scale(pol, 1.0 / p, 1.0 / p, 1.0 / p)
                else:
                    rec[R_ROULETTE] += w0
                    rec[R_ROULETTE + 1] += w1
                    rec[R_ROULETTE + 2] += w2
                    break
    if pol is not None and (kind == X_REFLECTED or kind == X_TRANSMITTED):
        polarized.to_exit(pol, dx, dy, dz)
    return kind, dx, dy, dz, w0, w1, w2, order, single, based, events
