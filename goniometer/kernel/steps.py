"""Steps whose number of random numbers varies from path to path (``docs/kernel.md``): free
flights in scattering media and random walks on multiple-scattering interfaces, as the per-path
transport (:func:`goniometer.kernel.onepath.trace_path`) takes them, the film events both take
(:func:`film_rt3`, :func:`film_choice`), and the lane kernel's per-lane step: the
continuation of a walk whose first bounce the vectorised event (:mod:`goniometer.kernel.event`)
made. A lane's random numbers there come from the path's own xoshiro256** stream, seeded from its
key the first time (:func:`goniometer.kernel.rng.seed_state`).

Directions as in :mod:`goniometer.kernel.event` (world frame, direction of travel).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from goniometer import optics
from goniometer.kernel.codegen import u64_as_double, u64_bits
from goniometer.kernel.event import RR_START, RR_THRESHOLD
from goniometer.kernel.layout import (A_RL, F_AB0, F_AB1, F_AB2, F_DX, F_DY, F_DZ, F_EV, F_FRAME, F_HPOS, F_KEY,
                                      F_MUELLER, F_MULTI, F_REG, F_SEEDED, F_W0, F_W1, F_W2, F_WC, F_WIN, F_WK, F_WVX,
                                      F_WVY, F_WVZ, F_X0, LANES, ST_ALIVE, ST_CAPPED, ST_DEAD, ST_REFLECTED,
                                      ST_TRANSMITTED)
from goniometer.kernel.rng import next_disk, next_float, seed_state
from goniometer.kernel import polarized
from goniometer.kernel.packing import FL_DL0, FL_K0, FL_KB0, FL_N0, FL_NA, FL_NB0, FL_ON

LN = LANES


@numba.njit(cache=True, error_model='numpy', inline="always")
def _attenuate(w0, w1, w2, ab0, ab1, ab2, a0, a1, a2):
    """The path weight times ``(a0, a1, a2)`` per channel, what it loses booked as absorbed:
    ``(w0 a0, w1 a1, w2 a2, ab0 + w0 (1 - a0), ...)``."""
    return w0 * a0, w1 * a1, w2 * a2, ab0 + w0 * (1.0 - a0), ab1 + w1 * (1.0 - a1), ab2 + w2 * (1.0 - a2)


@numba.njit(cache=True, error_model='numpy', inline="always")
def film_rt3(cos_i, fr, down):
    """A thin film's reflectance and transmittance per channel, ``(R_0, R_1, R_2, T_0, T_1, T_2)``,
    at a microfacet of cosine ``cos_i`` with the light (:func:`goniometer.optics.film_rt`): ``fr``
    the interface's packed film row (:data:`goniometer.kernel.packing.FILM_COLS`), ``down`` True
    when the light arrives from above (region above / film / medium below), False from below
    (the medium below, a dielectric's, / film / region above; ``docs/material-format.md``, thin
    films). Every per-path film event calls it: a single-scattering interface's
    (:func:`goniometer.kernel.onepath.trace_path`) and each bounce of a walk (:func:`walk_from`)."""
    n_in = fr[FL_NA] if down else fr[FL_NB0]
    r0, t0 = optics.film_rt(cos_i, n_in, fr[FL_N0], fr[FL_K0], fr[FL_NB0] if down else fr[FL_NA],
                            fr[FL_KB0] if down else 0.0, fr[FL_DL0])
    r1, t1 = optics.film_rt(cos_i, n_in, fr[FL_N0 + 1], fr[FL_K0 + 1], fr[FL_NB0 + 1] if down else fr[FL_NA],
                            fr[FL_KB0 + 1] if down else 0.0, fr[FL_DL0 + 1])
    r2, t2 = optics.film_rt(cos_i, n_in, fr[FL_N0 + 2], fr[FL_K0 + 2], fr[FL_NB0 + 2] if down else fr[FL_NA],
                            fr[FL_KB0 + 2] if down else 0.0, fr[FL_DL0 + 2])
    return r0, r1, r2, t0, t1, t2


@numba.njit(cache=True, error_model='numpy', inline="always")
def film_choice(u, r0, r1, r2, t0, t1, t2):
    """A filmed dielectric microfacet's choice (``docs/material-format.md``, thin films): with the
    uniform ``u``, reflect with probability ``P = sum R_c / sum (R_c + T_c)``, weight factors
    ``R_c / P``, else refract, factors ``T_c / (1 - P)``. Returns ``(reflected, a_0, a_1, a_2)``.
    (A filmed conductor always reflects, factors ``R_c``; the lane kernel's vectorised event makes
    the same choice as selects, :func:`goniometer.kernel.event.step`.)"""
    s_r = r0 + r1 + r2
    s_rt = s_r + t0 + t1 + t2
    if u * s_rt < s_r:
        q = s_rt / s_r
        return True, r0 * q, r1 * q, r2 * q
    q = s_rt / max(s_rt - s_r, 1e-300)
    return False, t0 * q, t1 * q, t2 * q


@numba.njit(cache=True, error_model='numpy', inline="always")
def film_p(r0, r1, r2, t0, t1, t2):
    """The probability :func:`film_choice` reflects with."""
    s_r = r0 + r1 + r2
    return s_r / max(s_r + t0 + t1 + t2, 1e-300)


@numba.njit(cache=True, error_model='numpy', inline="always")
def _walk_frame(pol, vx, vy, vz, mx, my, mz, inside, up, rc, rs):
    """Turn a polarized walk's frame to the plane of incidence of a bounce: the ray travelling along
    ``v`` onto the microfacet ``m``, both in the walk's frame (negated ``inside``; the interface's
    tangent frame of the arrival side, rotated by ``(rc, rs)``, its z the stack's if ``up``), taken to
    the stack's frame (:func:`goniometer.kernel.polarized.to_plane`)."""
    sg = -1.0 if inside else 1.0
    zs = 1.0 if up else -1.0
    kx, ky, kz = sg * vx, sg * vy, sg * vz
    nx, ny, nz = sg * mx, sg * my, sg * mz
    polarized.to_plane(pol, rc * kx - rs * ky, rs * kx + rc * ky, zs * kz,
                       rc * nx - rs * ny, rs * nx + rc * ny, zs * nz)


@numba.njit(cache=True, error_model='numpy')
def free_flight(achromatic, t0, t1, t2, a0, a1, a2, g, hpos, dx, dy, dz, w0, w1, w2, ab0, ab1, ab2,
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
def microsurface_walk(wx, wy, wz, ax, ay, conductor, cond, g_is_r, b_is_g, eta, inv_eta, max_bounces, state, film,
                      fr, from_above, pol=None, rc=1.0, rs=0.0):
    """One event on a multiple-scattering interface: the random walk of Heitz et al. 2016 on the
    GGX microsurface with Smith's height-correlated statistics (``docs/material-format.md`` 2.1).

    ``w`` is the direction the light arrives from, in the interface's tangent frame of the
    arrival side (``w_z > 0``); ``(ax, ay)`` its roughness. The ray starts above the microsurface
    (height CDF 1); each step draws the next hit height (:func:`goniometer.optics.ms_sample_height`),
    a visible normal of the reversed ray direction (:func:`goniometer.optics.sample_vndf_disk`, valid
    for directions below the horizon too) and reflects there -- a conductor with its Fresnel
    weight per channel (complex index ``cond[c] + i cond[3 + c]`` relative to the arrival side: the
    packed :attr:`goniometer.kernel.packing.PackedStack.cond`), a dielectric
    reflecting with probability F and otherwise refracting (relative index ``eta``; on the far
    side the microsurface is seen from below: heights ``1 - c``, directions negated, index
    ``inv_eta``), until the ray leaves the microsurface. ``g_is_r`` / ``b_is_g``: channels that
    share their complex index (one Fresnel evaluation).

    With ``film`` True and ``fr`` a packed film row (:data:`goniometer.kernel.packing.FILM_COLS`, ``FL_ON``
    set), every bounce reflects and transmits with the thin film's per-channel ``R_c``, ``T_c``
    (:func:`goniometer.optics.film_rt`, from the side the bounce's light arrives from;
    ``from_above``: the walk began on the interface's upper side): a conductor reflects with the
    factors ``R_c``, a dielectric reflects with probability ``P = sum R_c / sum (R_c + T_c)``,
    factors ``R_c / P``, and otherwise refracts (the film-free direction), factors
    ``T_c / (1 - P)`` (``docs/material-format.md``, thin films). ``film`` None compiles the walk
    without films (``fr``, an array all the same, is then not read).

    With ``pol`` a polarized path's state (:mod:`goniometer.kernel.polarized`), every bounce also
    applies its Fresnel event's Mueller matrix to it (divided by the probability of the choice it
    made), in the stack's frame: ``(rc, rs)`` the cosine and sine of the interface's tangent-frame
    rotation, ``from_above`` whether the local frame's z is the stack's; the returned factors are then
    1 (``pol`` carries them).

    Returns ``(ox, oy, oz, f0, f1, f2, n, transmitted)``: the exit direction (``o_z > 0``
    reflected, ``< 0`` transmitted), the product of the conductor's Fresnel factors per channel
    (1 for a dielectric; the film's factors with a film) and the number ``n >= 1`` of microfacet
    bounces; ``n = 0`` when the ray is still on the microsurface after ``max_bounces`` bounces
    (the caller books it as capped).
    """
    return walk_from(-wx, -wy, -wz, 1.0, False, 0, False, ax, ay, conductor, cond, g_is_r, b_is_g, eta, inv_eta,
                     max_bounces, state, film, fr, from_above, pol, rc, rs)


@numba.njit(cache=True, error_model='numpy')
def walk_from(vx, vy, vz, c, inside, n, hit, ax, ay, conductor, cond, g_is_r, b_is_g, eta, inv_eta, max_bounces,
              state, film, fr, from_above, pol=None, rc=1.0, rs=0.0):
    """:func:`microsurface_walk` from a given point of the walk: the ray travels along ``v`` at
    height CDF ``c`` after ``n`` bounces, on the far side of the microsurface if ``inside`` (there
    ``v`` and ``c`` are in the flipped frame); with ``hit`` its next hit is already drawn, at ``c``.
    ``film`` None (compiled without films) or True, ``fr`` the interface's packed film row (read
    only where ``film`` is True), ``from_above`` as :func:`microsurface_walk`'s.
    Returns as :func:`microsurface_walk` (``n`` counts the bounces before this call too; the
    Fresnel factors are those of the bounces from here)."""
    f0 = 1.0
    f1 = 1.0
    f2 = 1.0
    fon = False if film is None else fr[FL_ON] != 0.0
    while n < max_bounces:
        cn = c if hit else optics.ms_sample_height(vx, vy, vz, c, ax, ay, next_float(state))
        hit = False
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
        if pol is not None:
            _walk_frame(pol, vx, vy, vz, mx, my, mz, inside, from_above, rc, rs)
        if fon:
            # the film, seen from the side this bounce's light arrives from
            r0, r1, r2, t0, t1, t2 = film_rt3(im, fr, from_above != inside)
            if conductor:
                if pol is None:
                    f0 *= r0
                    f1 *= r1
                    f2 *= r2
                else:
                    polarized.film(pol, im, fr, from_above != inside, True, 1.0)
                vx, vy, vz = optics.reflect(ix, iy, iz, mx, my, mz)
            else:
                e = inv_eta if inside else eta
                ie = eta if inside else inv_eta
                _, cos_t = optics.fresnel_dielectric_cos_t_inv(im, e, ie)
                refl, a0, a1, a2 = film_choice(next_float(state), r0, r1, r2, t0, t1, t2)
                if pol is None:
                    f0 *= a0
                    f1 *= a1
                    f2 *= a2
                else:
                    polarized.film(pol, im, fr, from_above != inside, refl, film_p(r0, r1, r2, t0, t1, t2))
                if refl:
                    vx, vy, vz = optics.reflect(ix, iy, iz, mx, my, mz)
                else:
                    tx, ty, tz = optics.refract_known(ix, iy, iz, mx, my, mz, ie, im, cos_t)
                    vx = -tx
                    vy = -ty
                    vz = -tz
                    inside = not inside
                    c = 1.0 - c
        elif conductor:
            # (the complex index read where it is used: on a GPU it then takes no registers through
            # the walk's other branches)
            if pol is None:
                r0, r1, r2 = optics.fresnel_conductor_channels(im, cond[0], cond[3], cond[1], cond[4], cond[2],
                                                               cond[5], g_is_r, b_is_g)
                f0 *= r0
                f1 *= r1
                f2 *= r2
            else:
                polarized.conductor(pol, im, cond)
            vx, vy, vz = optics.reflect(ix, iy, iz, mx, my, mz)
        else:
            e = inv_eta if inside else eta
            ie = eta if inside else inv_eta
            f, cos_t = optics.fresnel_dielectric_cos_t_inv(im, e, ie)
            refl = next_float(state) < f
            if pol is not None:
                polarized.dielectric(pol, im, e, refl, f)
            if refl:
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
def continue_walk(S, i, xs, if_alpha, if_rot, eta_dn, eta_up, cond, g_is_r, b_is_g, n_if, transmit_base,
                  conductor_base, event_cap, film, if_film, pol=None):
    """Continue, in lane ``i`` of the state ``S``, the microsurface walk whose first bounce the
    vectorised event made (fields ``F_WK`` .. ``F_WIN``: the walk's interface, the ray's direction
    of travel and next hit, the side) until the ray leaves the microsurface, then play Russian
    roulette as the event does; returns the lane's new status (``ST_*``: its next action is the
    vectorised event, or its path ended and is booked at the next step). The event counted the
    walk, traversed the region and did its bookkeeping; each further bounce counts toward the cap.
    ``xs`` is scratch ``uint64[4]``; roulette's boosts go straight to the lane's sum ``A_RL``.
    ``film`` None or True (the kernel's film variant); ``if_film`` the packed films
    (:attr:`goniometer.kernel.packing.PackedStack.if_film`). ``pol``: None (scalar light), or
    scratch (4, 16) for a polarized lane: its state (fields ``F_MUELLER`` ..) goes through the walk's
    bounces there and back, the weights becoming the matrices' ``[0, 0]`` (their change booked as
    absorbed, signed, as the event books it)."""
    dx = S[F_DX * LN + i]
    dy = S[F_DY * LN + i]
    dz = S[F_DZ * LN + i]
    w0 = S[F_W0 * LN + i]
    w1 = S[F_W1 * LN + i]
    w2 = S[F_W2 * LN + i]
    ab0 = S[F_AB0 * LN + i]
    ab1 = S[F_AB1 * LN + i]
    ab2 = S[F_AB2 * LN + i]
    region = np.int64(S[F_REG * LN + i])
    events = np.int64(S[F_EV * LN + i])
    if S[F_SEEDED * LN + i] == 0.0:
        seed_state(xs, u64_bits(S[F_KEY * LN + i]))
    else:
        for j in range(4):
            xs[j] = u64_bits(S[(F_X0 + j) * LN + i])
    k = np.int64(S[F_WK * LN + i]) - 1
    from_above = dz < 0.0
    if pol is not None:
        polarized.lane_load(S, i, LN, F_MUELLER, F_FRAME, pol)
    is_cond = conductor_base and k == n_if - 1
    eta = eta_dn[k] if from_above else eta_up[k]
    inv_eta = eta_up[k] if from_above else eta_dn[k]
    ox, oy, oz, f0, f1, f2, nb, transmitted = walk_from(
        S[F_WVX * LN + i], S[F_WVY * LN + i], S[F_WVZ * LN + i], S[F_WC * LN + i], S[F_WIN * LN + i] != 0.0, 1, True,
        if_alpha[k, 0], if_alpha[k, 1], is_cond, cond, g_is_r, b_is_g, eta, inv_eta, max(1, event_cap - events + 1), xs,
        film, if_film[k], from_above, pol, if_rot[k, 0], if_rot[k, 1])
    st = ST_ALIVE
    if pol is not None:
        v0, v1, v2 = polarized.weights(pol)
        ab0 += w0 - v0
        ab1 += w1 - v1
        ab2 += w2 - v2
        w0, w1, w2 = v0, v1, v2
    elif is_cond or (False if film is None else if_film[k, FL_ON] != 0.0):
        w0, w1, w2, ab0, ab1, ab2 = _attenuate(w0, w1, w2, ab0, ab1, ab2, f0, f1, f2)
    if nb == 0:
        # still on the microsurface at the cap
        events = event_cap
        st = ST_CAPPED
    else:
        events += nb - 1
        if k == 0:
            S[F_MULTI * LN + i] = 1.0 if nb > 1 else 0.0
        # back to the world frame (the walk ran in the interface's tangent frame of the arrival side)
        rc = if_rot[k, 0]
        rs = if_rot[k, 1]
        dx = rc * ox - rs * oy
        dy = rs * ox + rc * oy
        dz = oz if from_above else -oz
        if transmitted:
            region = k + 1 if from_above else k
        # ---- Russian roulette on the largest channel weight (as the vectorised event's)
        if events >= RR_START:
            wmax = max(w0, max(w1, w2))
            if wmax < RR_THRESHOLD:
                p = wmax * (1.0 / RR_THRESHOLD)
                if next_float(xs) >= p:
                    st = ST_DEAD
                else:
                    boost = 1.0 / p
                    S[(A_RL + 0) * LN + i] -= w0 * (boost - 1.0)
                    S[(A_RL + 1) * LN + i] -= w1 * (boost - 1.0)
                    S[(A_RL + 2) * LN + i] -= w2 * (boost - 1.0)
                    w0 *= boost
                    w1 *= boost
                    w2 *= boost
                    if pol is not None:
                        polarized.scale(pol, boost, boost, boost)
        if st == ST_ALIVE:
            if region == 0 and dz > 0.0:
                st = ST_REFLECTED
            elif transmit_base and region == n_if and dz < 0.0:
                st = ST_TRANSMITTED
            elif events >= event_cap:
                st = ST_CAPPED
    S[F_DX * LN + i] = dx
    S[F_DY * LN + i] = dy
    S[F_DZ * LN + i] = dz
    S[F_W0 * LN + i] = w0
    S[F_W1 * LN + i] = w1
    S[F_W2 * LN + i] = w2
    S[F_AB0 * LN + i] = ab0
    S[F_AB1 * LN + i] = ab1
    S[F_AB2 * LN + i] = ab2
    S[F_REG * LN + i] = float(region)
    S[F_EV * LN + i] = float(events)
    S[F_HPOS * LN + i] = -1.0
    S[F_SEEDED * LN + i] = 1.0
    S[F_WK * LN + i] = 0.0
    for j in range(4):
        S[(F_X0 + j) * LN + i] = u64_as_double(xs[j])
    if pol is not None:
        polarized.lane_store(S, i, LN, F_MUELLER, F_FRAME, pol)
    return st
