"""The vectorised step of the lane kernel (``docs/kernel.md``, the step).

A step first books, in per-lane sums, the path each lane ended at the previous step (the
per-lane pass has deposited its exit meanwhile) and gives the lane its next path (lane ``i``
traces paths ``i, i + LANES, ...`` of the chunk). Then every lane whose next action is not the
continuation of a walk (:func:`goniometer.kernel.steps.continue_walk`) takes one event: it
traverses its region (Beer-Lambert; in a scattering region a free flight, whose collision is the
event's outcome), then meets what lies at the end -- a rough single-scattering interface
(visible-normal sample, Fresnel, reflection or refraction, masking), the first bounce of a walk on
a multiple-scattering one (and whether the ray then leaves the microsurface), an index-matched
interface (crossed unchanged), or the Lambertian base -- and plays Russian roulette. The
branches are selects, the stack's parameters are gathered per lane from a table on the loop's
own stack, and the physics is that of :mod:`goniometer.optics`, inlined: LLVM vectorises the
loop (packed square roots, divisions and gathers; 512-bit vectors where the CPU has them).

Directions are in the world frame, pointing the way the path travels (``d_z < 0``: down);
the interface's local frame has ``z`` along the normal of the side the light arrives from.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from goniometer import optics
from goniometer.kernel.codegen import prefer_wide_vectors, stack_block, u64_as_double, u64_bits
from goniometer.kernel.layout import (A_AB, A_CP, A_MK, A_NCAP, A_NEV, A_RB, A_RE, A_RL, A_TR, F_AB0, F_AB1, F_AB2,
                                      F_BASED, F_CTR, F_DX, F_DY, F_DZ, F_EV, F_FRAME, F_HPOS, F_KEY, F_LX, F_LY, F_LZ,
                                      F_EVENT, F_MK0, F_MK1, F_MK2, F_MUELLER, F_MULTI, F_ORDER, F_PATH, F_PNEW, F_Q0, F_Q1, F_Q2, F_REG, F_SEEDED, F_STATUS,
                                      F_W0, F_W1, F_W2, F_WC, F_WIN, F_WK, F_WVX, F_WVY, F_WVZ, IF_STRIDE, LANES,
                                      RG_STRIDE, ST_ALIVE, ST_CAPPED, ST_DEAD, ST_DONE, ST_REFLECTED, ST_SCALAR,
                                      ST_TRANSMITTED, T_ALB0, T_ALB1, T_ALB2, T_AX, T_AY, T_CHROM, T_ETA_DN, T_ETA_UP,
                                      T_G, T_IEXT0, T_MATCHED, T_MS, T_RC, T_RS, T_SCAT, T_TAU0, T_TAU1, T_TAU2, N_EVENT)
from goniometer.kernel import polarized
from goniometer.kernel.rng import draw, path_key, uniform_pair
from goniometer.kernel.packing import FILM_COLS, FL_DL0, FL_K0, FL_KB0, FL_N0, FL_NA, FL_NB0, FL_ON

#: Russian roulette: from this many events on, paths whose largest channel weight is below
#: RR_THRESHOLD survive with probability max(w) / RR_THRESHOLD
RR_START = 3
RR_THRESHOLD = 0.05

_U1 = np.uint64(1)
_U11 = np.uint64(11)
_U32 = np.uint64(32)
_INV_2_53 = 2.0 ** -53
#: the counter of a path's draw that picks its hero channel (spectral MIS): far from those its
#: events use (1, 2, ...) and from a tabulation's light direction (0)
HERO_DRAW = np.uint64(1 << 63)
_THIRD = 1.0 / 3.0
LN = LANES
# the rows of a polarized lane's event, from F_EVENT (goniometer.kernel.layout)
K_EVENT = 0
K_TRAVERSAL = 18
K_C2, K_S2, K_G, K_BOOST, K_GO, K_NEW = 21, 22, 23, 24, 25, 26


@numba.njit(cache=True, error_model='numpy', boundscheck=False)
def renew(S, ckey, n_rays, lx, ly, lz, tabulate, r_new, e_new, polar):
    """Stage A of :func:`step`: for every lane of ``S``, add the path it ended at the previous step
    (reflected, transmitted, absorbed by roulette or capped; the per-lane pass has deposited its
    exit) to the lane's sums, and give the lane its next path (lane ``i`` traces paths ``i, i +
    LANES, ...`` of the chunk), whose first region and event count are ``r_new``, ``e_new``.
    ``tabulate`` None: a new path starts along ``-l``; True: it draws its light direction
    (cosine-weighted, its draw 0). ``polar``: None, or a polarized run's initial path state
    (:func:`goniometer.kernel.polarized.initial_state`): a new path's frame ``F_FRAME`` .. is the
    incident beam's (a tabulation's: its own, as :func:`~goniometer.kernel.polarized.start` sets it),
    and ``F_PNEW`` marks the lane, whose Mueller matrices stage B then reads as the identity. A loop
    LLVM vectorises, as stage B's."""
    prefer_wide_vectors()
    for i in range(LN):
        st = np.int64(S[F_STATUS * LN + i])
        # (a lane without paths left keeps its last path's index, >= n_rays: nothing to book)
        p = np.int64(S[F_PATH * LN + i])
        live = p < n_rays
        refl = (st == ST_REFLECTED) & live
        trans = (st == ST_TRANSMITTED) & live
        dead = (st == ST_DEAD) & live
        capd = (st == ST_CAPPED) & live
        ended = refl | trans | dead | capd
        x = S[F_DX * LN + i]
        y = S[F_DY * LN + i]
        z = S[F_DZ * LN + i]
        v0 = S[F_W0 * LN + i]
        v1 = S[F_W1 * LN + i]
        v2 = S[F_W2 * LN + i]
        b0 = S[F_AB0 * LN + i]
        b1 = S[F_AB1 * LN + i]
        b2 = S[F_AB2 * LN + i]
        m0 = S[F_MK0 * LN + i]
        m1 = S[F_MK1 * LN + i]
        m2 = S[F_MK2 * LN + i]
        r = np.int64(S[F_REG * LN + i])
        ev = np.int64(S[F_EV * LN + i])
        order = np.int64(S[F_ORDER * LN + i])
        bo = S[F_BASED * LN + i]
        o0 = v0 if refl else 0.0
        o1 = v1 if refl else 0.0
        o2 = v2 if refl else 0.0
        S[(A_RE + 0) * LN + i] += o0
        S[(A_RE + 1) * LN + i] += o1
        S[(A_RE + 2) * LN + i] += o2
        S[(A_RE + 3) * LN + i] += o0 * o0
        S[(A_RE + 4) * LN + i] += o1 * o1
        S[(A_RE + 5) * LN + i] += o2 * o2
        nob = bo == 0.0
        o0 = o0 if nob else 0.0
        o1 = o1 if nob else 0.0
        o2 = o2 if nob else 0.0
        S[(A_RB + 0) * LN + i] += o0
        S[(A_RB + 1) * LN + i] += o1
        S[(A_RB + 2) * LN + i] += o2
        S[(A_RB + 3) * LN + i] += o0 * o0
        S[(A_RB + 4) * LN + i] += o1 * o1
        S[(A_RB + 5) * LN + i] += o2 * o2
        o0 = v0 if trans else 0.0
        o1 = v1 if trans else 0.0
        o2 = v2 if trans else 0.0
        S[(A_TR + 0) * LN + i] += o0
        S[(A_TR + 1) * LN + i] += o1
        S[(A_TR + 2) * LN + i] += o2
        S[(A_TR + 3) * LN + i] += o0 * o0
        S[(A_TR + 4) * LN + i] += o1 * o1
        S[(A_TR + 5) * LN + i] += o2 * o2
        o0 = b0 if ended else 0.0
        o1 = b1 if ended else 0.0
        o2 = b2 if ended else 0.0
        S[(A_AB + 0) * LN + i] += o0
        S[(A_AB + 1) * LN + i] += o1
        S[(A_AB + 2) * LN + i] += o2
        S[(A_AB + 3) * LN + i] += o0 * o0
        S[(A_AB + 4) * LN + i] += o1 * o1
        S[(A_AB + 5) * LN + i] += o2 * o2
        o0 = m0 if ended else 0.0
        o1 = m1 if ended else 0.0
        o2 = m2 if ended else 0.0
        S[(A_MK + 0) * LN + i] += o0
        S[(A_MK + 1) * LN + i] += o1
        S[(A_MK + 2) * LN + i] += o2
        S[(A_MK + 3) * LN + i] += o0 * o0
        S[(A_MK + 4) * LN + i] += o1 * o1
        S[(A_MK + 5) * LN + i] += o2 * o2
        S[(A_RL + 0) * LN + i] += v0 if dead else 0.0
        S[(A_RL + 1) * LN + i] += v1 if dead else 0.0
        S[(A_RL + 2) * LN + i] += v2 if dead else 0.0
        S[(A_CP + 0) * LN + i] += v0 if capd else 0.0
        S[(A_CP + 1) * LN + i] += v1 if capd else 0.0
        S[(A_CP + 2) * LN + i] += v2 if capd else 0.0
        S[A_NCAP * LN + i] += 1.0 if capd else 0.0
        S[A_NEV * LN + i] += float(ev) if ended else 0.0
        # the next path of the lane (its fields as a new path's where the lane takes it)
        p = p + LN if ended else p
        key = path_key(ckey, np.uint64(p))
        if tabulate is not None:
            t1, t2 = uniform_pair(draw(key, np.uint64(0)))
            tc, ts = optics.cos_sin_2pi(t1)
            tr = math.sqrt(max(0.0, t2))
            nlx = tr * tc
            nly = tr * ts
            nlz = math.sqrt(max(0.0, 1.0 - t2))
        else:
            nlx = lx
            nly = ly
            nlz = lz
        st = (ST_ALIVE if p < n_rays else ST_DONE) if ended else st
        x = -nlx if ended else x
        y = -nly if ended else y
        z = -nlz if ended else z
        v0 = 1.0 if ended else v0
        v1 = 1.0 if ended else v1
        v2 = 1.0 if ended else v2
        b0 = 0.0 if ended else b0
        b1 = 0.0 if ended else b1
        b2 = 0.0 if ended else b2
        m0 = 0.0 if ended else m0
        m1 = 0.0 if ended else m1
        m2 = 0.0 if ended else m2
        r = r_new if ended else r
        ev = e_new if ended else ev
        order = e_new if ended else order
        bo = 0.0 if ended else bo
        c = np.uint64(1) if ended else np.uint64(np.int64(S[F_CTR * LN + i]))
        S[F_DX * LN + i] = x
        S[F_DY * LN + i] = y
        S[F_DZ * LN + i] = z
        S[F_W0 * LN + i] = v0
        S[F_W1 * LN + i] = v1
        S[F_W2 * LN + i] = v2
        S[F_AB0 * LN + i] = b0
        S[F_AB1 * LN + i] = b1
        S[F_AB2 * LN + i] = b2
        S[F_MK0 * LN + i] = m0
        S[F_MK1 * LN + i] = m1
        S[F_MK2 * LN + i] = m2
        S[F_REG * LN + i] = float(r)
        S[F_EV * LN + i] = float(ev)
        S[F_ORDER * LN + i] = float(order)
        S[F_BASED * LN + i] = bo
        S[F_CTR * LN + i] = float(np.int64(c))
        S[F_STATUS * LN + i] = float(st)
        S[F_KEY * LN + i] = u64_as_double(key) if ended else S[F_KEY * LN + i]
        S[F_PATH * LN + i] = float(p)
        S[F_LX * LN + i] = nlx if ended else S[F_LX * LN + i]
        S[F_LY * LN + i] = nly if ended else S[F_LY * LN + i]
        S[F_LZ * LN + i] = nlz if ended else S[F_LZ * LN + i]
        # a new path's per-lane-step fields
        S[F_Q0 * LN + i] = _THIRD if ended else S[F_Q0 * LN + i]
        S[F_Q1 * LN + i] = _THIRD if ended else S[F_Q1 * LN + i]
        S[F_Q2 * LN + i] = _THIRD if ended else S[F_Q2 * LN + i]
        S[F_HPOS * LN + i] = -1.0 if ended else S[F_HPOS * LN + i]
        S[F_SEEDED * LN + i] = 0.0 if ended else S[F_SEEDED * LN + i]
        S[F_WK * LN + i] = 0.0 if ended else S[F_WK * LN + i]
        S[F_MULTI * LN + i] = 0.0 if ended else S[F_MULTI * LN + i]
        if polar is not None:
            if tabulate is None:
                qx = polar[3, 0]
                qy = polar[3, 1]
                qz = polar[3, 2]
            else:
                qx, qy, qz = polarized.beam_frame(x, y, z)
            S[F_FRAME * LN + i] = qx if ended else S[F_FRAME * LN + i]
            S[(F_FRAME + 1) * LN + i] = qy if ended else S[(F_FRAME + 1) * LN + i]
            S[(F_FRAME + 2) * LN + i] = qz if ended else S[(F_FRAME + 2) * LN + i]
            S[F_PNEW * LN + i] = 1.0 if ended else 0.0


@numba.njit(cache=True, error_model='numpy', boundscheck=False)
def step(S, table, off, n_if, transmit_base, base_k, ce0, ce1, ce2, ck0, ck1, ck2, rho0, rho1, rho2, event_cap,
         lx, ly, lz, ckey, n_rays, max_order, height_correlated, tabulate, media, lambertian, conductor, g_is_r, b_is_g,
         aniso, ms, film, polar):
    """One step for all lanes of ``S`` (see the module docstring).

    ``polar``: None (scalar light), or a polarized run's initial path state
    (:func:`goniometer.kernel.polarized.initial_state`): each lane then carries its path's Mueller
    matrices and frame in the fields ``F_MUELLER`` .. ``F_FRAME + 2`` (``S`` has
    ``N_FIELDS_POLARIZED`` rows), which the event changes as :mod:`goniometer.kernel.polarized` does
    for a path (``docs/polarization.md``); the weights are the matrices' ``[0, 0]``.

    The ten arguments before are None or True and select what is compiled (numba compiles a None
    argument's specialisation without the other branch; LLVM vectorises the loops of every
    specialisation):

    * ``height_correlated``: None, separable masking ``G1(o)``; True, height-correlated
      ``G2 / G1(i)`` (the transmission's Beta function from
      :func:`goniometer.optics.smith_g2_height_correlated`, which vectorises);
    * ``tabulate``: None, every path starts along ``-l``; True, each draws its light direction
      (cosine-weighted, its draw 0);
    * ``media``: True when some region scatters: the event of a lane in such a region begins with a
      free flight from the lane's height; a collision (Henyey-Greenstein scattering) is the event's
      outcome, a flight that reaches the region's boundary goes on to what lies there;
    * ``lambertian``, ``conductor``: True when the base is Lambertian, resp. a conductor;
    * ``g_is_r``, ``b_is_g``: True when the conductor's green channel has the red one's complex
      index, resp. blue the green one's (their Fresnel values are computed once);
    * ``aniso``: True when some interface is anisotropic (tangent-frame rotations);
    * ``ms``: True when some interface scatters multiply: the event on it is the first bounce of
      its microsurface walk (the height of the hit, the visible normal, Fresnel, and whether the
      ray then leaves the microsurface); a walk that goes on is continued by a per-lane step
      (:func:`goniometer.kernel.steps.continue_walk`), and only lanes whose next action is the
      event take it (without, every lane takes it);
    * ``film``: True when some interface carries a thin film (the table's film block): on such an
      interface the microfacet's reflectance and transmittance are the film's per channel
      (:func:`goniometer.optics.film_rt_channel`); a dielectric reflects with probability
      ``P = sum R_c / sum (R_c + T_c)`` and the weights take ``R_c / P`` or ``T_c / (1 - P)``, a
      conductor reflects with the weights times ``R_c`` (``docs/material-format.md``, thin films).

    The loop bodies are written out here, as an inlined function taking the state array would
    keep reference counting in the loop and stop LLVM."""
    prefer_wide_vectors()
    # the stack table on this function's stack (gathers that provably do not alias S)
    T = stack_block()
    # 64-bit draws per event: two, a third for a walk's first bounce, one for a free flight
    n_draws = 2 + (0 if ms is None else 1) + (0 if media is None else 1)
    # an index-matched top interface that is not the base: a new path's first event, crossing it
    # unchanged (no random number; an event at the top: bounce order 1), is made when the lane
    # takes the path, and its first step goes on below
    enter = n_if >= 1 and table[T_MATCHED] != 0.0 and base_k != 0 and event_cap > 1
    r_new = 1 if enter else 0
    e_new = 1 if enter else 0
    for q in range(table.shape[0]):
        T[q] = table[q]
    # ---------------- stage A: book the path each lane ended, give the lane its next path
    renew(S, ckey, n_rays, lx, ly, lz, tabulate, r_new, e_new, polar)
    for i in range(LN):
        # ---------------- stage B: the event of the lanes whose next action it is
        st = np.int64(S[F_STATUS * LN + i])
        x = S[F_DX * LN + i]
        y = S[F_DY * LN + i]
        z = S[F_DZ * LN + i]
        v0 = S[F_W0 * LN + i]
        v1 = S[F_W1 * LN + i]
        v2 = S[F_W2 * LN + i]
        b0 = S[F_AB0 * LN + i]
        b1 = S[F_AB1 * LN + i]
        b2 = S[F_AB2 * LN + i]
        m0 = S[F_MK0 * LN + i]
        m1 = S[F_MK1 * LN + i]
        m2 = S[F_MK2 * LN + i]
        r = np.int64(S[F_REG * LN + i])
        ev = np.int64(S[F_EV * LN + i])
        order = np.int64(S[F_ORDER * LN + i])
        bo = S[F_BASED * LN + i]
        c = np.uint64(np.int64(S[F_CTR * LN + i]))
        key = u64_bits(S[F_KEY * LN + i])
        p = np.int64(S[F_PATH * LN + i])
        # without walks to continue every lane takes the event, also a lane without paths left (its
        # values are never booked); only the roulette sum must not see it
        go = True if ms is None else st == ST_ALIVE
        booked = go and p < n_rays
        up = z > 0.0
        # what lies at the end: interface k, or the Lambertian base below the last region
        from_above = not up
        k = r - 1 if up else r
        lamb = False if lambertian is None else from_above and r == n_if
        kc = min(max(k, 0), max(n_if, 1) - 1)
        io = kc * IF_STRIDE
        ax = T[io + T_AX]
        e_dn = T[io + T_ETA_DN]
        e_up = T[io + T_ETA_UP]
        matched = T[io + T_MATCHED] != 0.0
        plain = (not lamb) & (not matched)   # a rough interface (not crossed unchanged)
        eta = e_dn if from_above else e_up
        inv_eta = e_up if from_above else e_dn
        is_cond = False if conductor is None else kc == n_if - 1
        # the arrival direction in the interface's tangent frame of the arrival side
        tx = -x
        ty = -y
        wz = -z if from_above else z
        if aniso is None:
            ay = ax
            wx = tx
            wy = ty
        else:
            ay = T[io + T_AY]
            rc = T[io + T_RC]
            rs = T[io + T_RS]
            wx = rc * tx + rs * ty
            wy = rc * ty - rs * tx
        # one division for 1 / |z| (Beer-Lambert) and the inverse stretched length of w (VNDF)
        za = max(wz, 1e-150)
        sn = math.sqrt(optics.vndf_stretch_norm2(wx, wy, wz, ax, ay))
        inv = 1.0 / (za * sn)
        inv_mu = inv * sn
        # traverse region r (Beer-Lambert; clear regions have depth 0)
        ro = off + r * RG_STRIDE
        if media is None:
            a0 = optics.exp_neg(-T[ro + T_TAU0] * inv_mu)
            a1 = optics.exp_neg(-T[ro + T_TAU1] * inv_mu)
            a2 = optics.exp_neg(-T[ro + T_TAU2] * inv_mu)
            coll = False
            q0 = q1 = q2 = nq0 = nq1 = nq2 = _THIRD
            hp = nh = -1.0
        else:
            # a scattering region (docs/material-format.md, media; as steps.free_flight): a free
            # flight from the lane's height h (1 top, 0 bottom; at the boundary: the side it
            # entered by) towards the boundary at distance `dist`, its length drawn with the hero
            # channel's extinction (the path's hero from its own draw; the optical length
            # -log(1 - u) with u on the grid 2^-53); a collision before the boundary is this
            # event (the weights times the albedo and, chromatic, the spectral-MIS factor
            # optics.spectral_mis_update of the density t_c exp(-t_c s)); otherwise the flight's
            # factor exp(-t_c dist) (chromatic MIS) and the event goes on at the boundary. In any
            # other region the path crosses it whole (dist = 1 / |z|): its Beer-Lambert factors
            # are the same exponentials
            scat = T[ro + T_SCAT] != 0.0
            chrom = scat and T[ro + T_CHROM] != 0.0
            hp = S[F_HPOS * LN + i]
            q0 = S[F_Q0 * LN + i]
            q1 = S[F_Q1 * LN + i]
            q2 = S[F_Q2 * LN + i]
            h = hp if hp >= 0.0 else (1.0 if from_above else 0.0)
            dist = (h if from_above else 1.0 - h) * inv_mu
            hero = np.int64(((draw(key, HERO_DRAW) >> _U32) * np.uint64(3)) >> _U32)
            ud = float(np.int64(draw(key, c + np.uint64(2 if ms is None else 3)) >> _U11)) * _INV_2_53
            sopt = -optics.log_pos(1.0 - ud)
            coll = scat and sopt < T[ro + T_TAU0 + hero] * dist
            d = sopt * T[ro + T_IEXT0 + hero] if coll else dist
            t0 = T[ro + T_TAU0]
            t1 = T[ro + T_TAU1]
            t2 = T[ro + T_TAU2]
            e0 = optics.exp_neg(-t0 * d)
            e1 = optics.exp_neg(-t1 * d)
            e2 = optics.exp_neg(-t2 * d)
            p0 = t0 * e0 if coll else e0
            p1 = t1 * e1 if coll else e1
            p2 = t2 * e2 if coll else e2
            mr0, mr1, mr2, mq0, mq1, mq2 = optics.spectral_mis_update(p0, p1, p2, q0, q1, q2)
            # the weight factor per channel: Beer-Lambert, or the flight's
            a0 = (T[ro + T_ALB0] * (mr0 if chrom else 1.0) if coll else (mr0 if chrom else 1.0)) if scat else e0
            a1 = (T[ro + T_ALB1] * (mr1 if chrom else 1.0) if coll else (mr1 if chrom else 1.0)) if scat else e1
            a2 = (T[ro + T_ALB2] * (mr2 if chrom else 1.0) if coll else (mr2 if chrom else 1.0)) if scat else e2
            nq0 = mq0 if chrom else q0
            nq1 = mq1 if chrom else q1
            nq2 = mq2 if chrom else q2
            nh = min(1.0, max(0.0, h + d * z)) if coll else -1.0
            # a collision meets nothing at the end
            lamb = lamb and not coll
            plain = plain and not coll
        nb0 = b0 + v0 * (1.0 - a0)
        nb1 = b1 + v1 * (1.0 - a1)
        nb2 = b2 + v2 * (1.0 - a2)
        nv0 = v0 * a0
        nv1 = v1 * a1
        nv2 = v2 * a2
        # two 64-bit draws: azimuth and radius of a disk point, Fresnel choice, roulette
        u1, u2 = uniform_pair(draw(key, c))
        u3, u4 = uniform_pair(draw(key, c + _U1))
        cp, sp = optics.cos_sin_2pi(u1)
        if media is None:
            fx = x
            fy = y
            fz = z
        else:
            # a collision's new direction: Henyey-Greenstein (u2: the scattering cosine, u1 the
            # azimuth; a collision uses no interface number)
            hx, hy, hz = optics.hg_scatter_cs(x, y, z, T[ro + T_G], u2, cp, sp)
            fx = hx if coll else x
            fy = hy if coll else y
            fz = hz if coll else z
        mx, my, mz = optics.sample_vndf_polar(wx, wy, wz, ax, ay, cp, sp, u2, inv * za)
        wm = wx * mx + wy * my + wz * mz
        # dielectric and conductor Fresnel of the same cosine, one division between them
        nd, dd, cos_t, tir = optics.fresnel_dielectric_terms(wm, eta, inv_eta)
        if conductor is None:
            f0 = f1 = f2 = 1.0
            qd = nd / dd
        elif g_is_r is None and b_is_g is None:
            f0, f1, f2, qd = optics.fresnel_conductor_rgb(wm, ce0, ck0, ce1, ck1, ce2, ck2, nd, dd)
        elif g_is_r is None:
            f0, f1, qd = optics.fresnel_conductor_pair(wm, ce0, ck0, ce1, ck1, nd, dd)
            f2 = f1
        elif b_is_g is None:
            f0, f2, qd = optics.fresnel_conductor_pair(wm, ce0, ck0, ce2, ck2, nd, dd)
            f1 = f0
        else:
            f0 = optics.fresnel_conductor(wm, ce0, ck0)
            f1 = f0
            f2 = f0
            qd = nd / dd
        fd = optics.fresnel_dielectric_select(qd, eta, tir)
        if film is None:
            refl_ = is_cond or u3 < fd
            fon = False
            j0 = j1 = j2 = 1.0
        else:
            # a thin film on the interface: per channel its R and T at the microfacet's cosine,
            # from the side the light arrives from (above: region above / film / medium below;
            # below: the medium below / film / region above)
            fo = off + (n_if + 1) * RG_STRIDE + kc * FILM_COLS
            fon = T[fo + FL_ON] != 0.0
            fna = T[fo + FL_NA]
            fn_in = fna if from_above else T[fo + FL_NB0]
            xr0 = T[fo + FL_NB0] if from_above else fna
            xr1 = T[fo + FL_NB0 + 1] if from_above else fna
            xr2 = T[fo + FL_NB0 + 2] if from_above else fna
            xi0 = T[fo + FL_KB0] if from_above else 0.0
            xi1 = T[fo + FL_KB0 + 1] if from_above else 0.0
            xi2 = T[fo + FL_KB0 + 2] if from_above else 0.0
            fr0, ft0 = optics.film_rt_channel(wm, fn_in, T[fo + FL_N0], T[fo + FL_K0], xr0, xi0, T[fo + FL_DL0])
            fr1, ft1 = optics.film_rt_channel(wm, fn_in, T[fo + FL_N0 + 1], T[fo + FL_K0 + 1], xr1, xi1,
                                              T[fo + FL_DL0 + 1])
            fr2, ft2 = optics.film_rt_channel(wm, fn_in, T[fo + FL_N0 + 2], T[fo + FL_K0 + 2], xr2, xi2,
                                              T[fo + FL_DL0 + 2])
            s_r = fr0 + fr1 + fr2
            s_t = ft0 + ft1 + ft2
            s_rt = s_r + s_t
            # reflect with probability s_r / s_rt (a conductor always: weights R_c)
            refl_ = is_cond or (u3 * s_rt < s_r if fon else u3 < fd)
            q_f = 1.0 if is_cond else (s_rt / max(s_r if refl_ else s_t, 1e-300))
            j0 = (fr0 if refl_ else ft0) * q_f
            j1 = (fr1 if refl_ else ft1) * q_f
            j2 = (fr2 if refl_ else ft2) * q_f
        rx, ry, rz = optics.reflect(wx, wy, wz, mx, my, mz)
        sx, sy, sz = optics.refract_known(wx, wy, wz, mx, my, mz, inv_eta, wm, cos_t)
        ox = rx if refl_ else sx
        oy = ry if refl_ else sy
        oz = rz if refl_ else sz
        # a multiple-scattering interface: the walk's first bounce (Heitz et al. 2016; as
        # optics.ms_sample_height draws heights): the hit's height CDF c1 = (1 - u)^(1 / (1 +
        # Lambda(w))) below the ray's start at 1; from there (reflected) or from 1 - c1 seen from
        # below (refracted) the ray leaves if it travels away from the microsurface and
        # 1 - u' <= c^Lambda(o); otherwise the same u' gives the next hit's height, where the
        # per-lane step goes on (steps.walk_from)
        if ms is None:
            walked = False
            cont = False
            c_next = 1.0
        else:
            walked = plain and T[io + T_MS] != 0.0
            u5, u6 = uniform_pair(draw(key, c + np.uint64(2)))
            log_c1 = optics.log_pos(1.0 - u5) / (1.0 + optics.ggx_lambda(wx, wy, wz, ax, ay))
            c1 = optics.exp_neg(log_c1)
            log_c = log_c1 if refl_ else optics.log_pos(max(1.0 - c1, 1e-300))
            lam_o = optics.ggx_lambda(ox, oy, oz, ax, ay)
            log_v = optics.log_pos(1.0 - u6)
            away = oz > 0.0 if refl_ else oz < 0.0
            leaves = away and log_v <= lam_o * log_c
            cont = walked and not leaves
            # the next hit: upward c / v^(1 / Lambda(o)) (<= 1), downward c v^(1 / (1 + Lambda(o)))
            log_next = log_c - log_v / max(lam_o, 1e-300) if away else log_c + log_v / (1.0 + lam_o)
            c_next = optics.exp_neg(min(log_next, 0.0))
        # single-scattering microfacet model: an exit on the wrong side is lost to masking
        wrong = plain and (not walked) and (oz <= 0.0 if refl_ else oz >= 0.0)
        if height_correlated is not None:
            lam_o = optics.ggx_lambda(ox, oy, oz, ax, ay)
            lam_i = optics.ggx_lambda(wx, wy, wz, ax, ay)
            g = optics.smith_g2_height_correlated(lam_i, lam_o, not refl_) * (1.0 + lam_i)
        else:
            # in single precision (well conditioned: a sum of positives; relative error < 1e-6,
            # docs/kernel.md, precision)
            g = float(optics.smith_g1_dir(np.float32(ox), np.float32(oy), np.float32(oz), np.float32(ax),
                                          np.float32(ay)))
        g = 0.0 if wrong else (g if (plain and not walked) else 1.0)
        # weight factors: conductor Fresnel, or the base's albedo; absorbed what they take
        if film is None:
            h0 = rho0 if lamb else (f0 if (is_cond and plain) else 1.0)
            h1 = rho1 if lamb else (f1 if (is_cond and plain) else 1.0)
            h2 = rho2 if lamb else (f2 if (is_cond and plain) else 1.0)
        else:
            fp = fon and plain
            h0 = rho0 if lamb else (j0 if fp else (f0 if (is_cond and plain) else 1.0))
            h1 = rho1 if lamb else (j1 if fp else (f1 if (is_cond and plain) else 1.0))
            h2 = rho2 if lamb else (j2 if fp else (f2 if (is_cond and plain) else 1.0))
        if polar is not None:
            # ---- polarized light (docs/polarization.md; as goniometer.kernel.polarized does for a
            # path): after the traversal's factors, the frame turns to the plane of incidence on the
            # microfacet (world frame) and the event's matrix applies per channel -- a Fresnel event
            # divided by the probability of its choice, the base's or a collision's
            # depolarization, or nothing (an index-matched interface); the weights become the
            # matrices' [0, 0], their change booked as absorbed (signed). The matrices themselves
            # are updated after this loop, with masking and roulette (mueller_pass)
            fresnel = plain
            if aniso is None:
                gmx = mx
                gmy = my
            else:
                gmx = rc * mx - rs * my
                gmy = rs * mx + rc * my
            gmz = mz if from_above else -mz
            pfx = S[F_FRAME * LN + i]
            pfy = S[(F_FRAME + 1) * LN + i]
            pfz = S[(F_FRAME + 2) * LN + i]
            pc2, ps2, psx, psy, psz = polarized.lane_plane(x, y, z, pfx, pfy, pfz, gmx, gmy, gmz)
            pc2 = pc2 if fresnel else 1.0
            ps2 = ps2 if fresnel else 0.0
            # the Fresnel event per channel: a dielectric's (every channel the same), a conductor's,
            # a film's
            dra, drb, drc, drs, dta, dtb, dtc, dts = optics.fresnel_dielectric_mueller(wm, eta)
            dF = 1.0 / fd if refl_ else 1.0 / (1.0 - fd)
            ev0 = (dra, drb, drc, drs, dF) if refl_ else (dta, dtb, dtc, dts, dF)
            ev1 = ev0
            ev2 = ev0
            if conductor is not None:
                ca0, cb0, cc0, cs0 = optics.fresnel_conductor_mueller(wm, ce0, ck0)
                cv0 = (ca0, cb0, cc0, cs0, 1.0)
                if g_is_r is None:
                    ca1, cb1, cc1, cs1 = optics.fresnel_conductor_mueller(wm, ce1, ck1)
                    cv1 = (ca1, cb1, cc1, cs1, 1.0)
                else:
                    cv1 = cv0
                if b_is_g is None:
                    ca2, cb2, cc2, cs2 = optics.fresnel_conductor_mueller(wm, ce2, ck2)
                    cv2 = (ca2, cb2, cc2, cs2, 1.0)
                else:
                    cv2 = cv1
                ev0 = cv0 if is_cond else ev0
                ev1 = cv1 if is_cond else ev1
                ev2 = cv2 if is_cond else ev2
            if film is not None:
                fv0 = polarized.lane_film(wm, fn_in, T[fo + FL_N0], T[fo + FL_K0], xr0, xi0, T[fo + FL_DL0], refl_,
                                          q_f)
                fv1 = polarized.lane_film(wm, fn_in, T[fo + FL_N0 + 1], T[fo + FL_K0 + 1], xr1, xi1,
                                          T[fo + FL_DL0 + 1], refl_, q_f)
                fv2 = polarized.lane_film(wm, fn_in, T[fo + FL_N0 + 2], T[fo + FL_K0 + 2], xr2, xi2,
                                          T[fo + FL_DL0 + 2], refl_, q_f)
                ev0 = fv0 if fon else ev0
                ev1 = fv1 if fon else ev1
                ev2 = fv2 if fon else ev2
            pk0 = polarized.lane_coefficients(lamb, coll, fresnel, rho0, ev0[0], ev0[1], ev0[2], ev0[3], ev0[4])
            pk1 = polarized.lane_coefficients(lamb, coll, fresnel, rho1, ev1[0], ev1[1], ev1[2], ev1[3], ev1[4])
            pk2 = polarized.lane_coefficients(lamb, coll, fresnel, rho2, ev2[0], ev2[1], ev2[2], ev2[3], ev2[4])
            # (a lane that took a new path at this step: its matrices are the identity)
            nw = S[F_PNEW * LN + i] != 0.0
            w0n = polarized.lane_m00((1.0 if nw else S[F_MUELLER * LN + i]) * a0,
                                     (0.0 if nw else S[(F_MUELLER + 4) * LN + i]) * a0,
                                     (0.0 if nw else S[(F_MUELLER + 8) * LN + i]) * a0, pc2, ps2, pk0)
            w1n = polarized.lane_m00((1.0 if nw else S[(F_MUELLER + 16) * LN + i]) * a1,
                                     (0.0 if nw else S[(F_MUELLER + 20) * LN + i]) * a1,
                                     (0.0 if nw else S[(F_MUELLER + 24) * LN + i]) * a1, pc2, ps2, pk1)
            w2n = polarized.lane_m00((1.0 if nw else S[(F_MUELLER + 32) * LN + i]) * a2,
                                     (0.0 if nw else S[(F_MUELLER + 36) * LN + i]) * a2,
                                     (0.0 if nw else S[(F_MUELLER + 40) * LN + i]) * a2, pc2, ps2, pk2)
            nb0 += nv0 - w0n
            nb1 += nv1 - w1n
            nb2 += nv2 - w2n
            nv0 = w0n
            nv1 = w1n
            nv2 = w2n
            h0 = h1 = h2 = 1.0
        nb0 += nv0 * (1.0 - h0)
        nb1 += nv1 * (1.0 - h1)
        nb2 += nv2 * (1.0 - h2)
        nv0 *= h0
        nv1 *= h1
        nv2 *= h2
        nm0 = m0 + nv0 * (1.0 - g)
        nm1 = m1 + nv1 * (1.0 - g)
        nm2 = m2 + nv2 * (1.0 - g)
        nv0 *= g
        nv1 *= g
        nv2 *= g
        # the new direction (world frame): the lobe's, rotated back; the disk point lifted onto the
        # hemisphere (cosine-distributed, upward) at the base; unchanged through a matched interface
        if aniso is None:
            gx = ox
            gy = oy
        else:
            gx = rc * ox - rs * oy
            gy = rs * ox + rc * oy
        gz = oz if from_above else -oz
        if lambertian is None:
            nx = gx if (plain and not cont) else fx
            ny = gy if (plain and not cont) else fy
            nz = gz if (plain and not cont) else fz
        else:
            # the disk point sqrt(u2) (cos, sin) lifted onto the hemisphere (Malley)
            rad = math.sqrt(max(0.0, u2))
            nx = rad * cp if lamb else (gx if (plain and not cont) else fx)
            ny = rad * sp if lamb else (gy if (plain and not cont) else fy)
            nz = math.sqrt(max(0.0, 1.0 - u2)) if lamb else (gz if (plain and not cont) else fz)
        # (a walk that goes on keeps the lane's region and arrival direction for its per-lane step;
        # a collision in a medium met no interface)
        crossed = (not coll) and (not lamb) and (not cont) and (not plain or not refl_)
        nr = (k + 1 if from_above else k) if crossed else r
        ne = ev + 1
        top = (not coll) and ((k == 0 and not lamb) or (lamb and n_if == 0))
        based = lamb or ((not coll) and k == base_k and from_above)
        # Russian roulette: survivors boosted by 1 / p (the added weight booked per lane); a killed
        # lane keeps its weight for booking as roulette
        wmax = max(nv0, max(nv1, nv2))
        pr = wmax * (1.0 / RR_THRESHOLD)
        rr = ne >= RR_START and wmax < RR_THRESHOLD
        # (a collision that leaves no weight in any channel ends the path)
        killed = wrong or (rr and u4 >= pr) or (coll and wmax == 0.0)
        boost = 1.0 / pr if (rr and not killed) else 1.0
        # what comes next: an exit (nothing lies beyond), the cap, a per-lane step (a walk that goes
        # on) or another event
        nst = ST_DONE if p >= n_rays else ST_DEAD if killed else (ST_REFLECTED if (nr == 0 and nz > 0.0) else (
            ST_TRANSMITTED if (transmit_base and nr == n_if and nz < 0.0) else (
                ST_CAPPED if ne >= event_cap else (ST_SCALAR if cont else ST_ALIVE))))
        if polar is not None:
            # the numbers of the pass over the matrices that follows this loop (mueller_pass)
            S[(F_EVENT + K_EVENT) * LN + i] = pk0[0]
            S[(F_EVENT + K_EVENT + 1) * LN + i] = pk0[1]
            S[(F_EVENT + K_EVENT + 2) * LN + i] = pk0[2]
            S[(F_EVENT + K_EVENT + 3) * LN + i] = pk0[3]
            S[(F_EVENT + K_EVENT + 4) * LN + i] = pk0[4]
            S[(F_EVENT + K_EVENT + 5) * LN + i] = pk0[5]
            S[(F_EVENT + K_EVENT + 6) * LN + i] = pk1[0]
            S[(F_EVENT + K_EVENT + 7) * LN + i] = pk1[1]
            S[(F_EVENT + K_EVENT + 8) * LN + i] = pk1[2]
            S[(F_EVENT + K_EVENT + 9) * LN + i] = pk1[3]
            S[(F_EVENT + K_EVENT + 10) * LN + i] = pk1[4]
            S[(F_EVENT + K_EVENT + 11) * LN + i] = pk1[5]
            S[(F_EVENT + K_EVENT + 12) * LN + i] = pk2[0]
            S[(F_EVENT + K_EVENT + 13) * LN + i] = pk2[1]
            S[(F_EVENT + K_EVENT + 14) * LN + i] = pk2[2]
            S[(F_EVENT + K_EVENT + 15) * LN + i] = pk2[3]
            S[(F_EVENT + K_EVENT + 16) * LN + i] = pk2[4]
            S[(F_EVENT + K_EVENT + 17) * LN + i] = pk2[5]
            S[(F_EVENT + K_TRAVERSAL) * LN + i] = a0
            S[(F_EVENT + K_TRAVERSAL + 1) * LN + i] = a1
            S[(F_EVENT + K_TRAVERSAL + 2) * LN + i] = a2
            S[(F_EVENT + K_C2) * LN + i] = pc2
            S[(F_EVENT + K_S2) * LN + i] = ps2
            S[(F_EVENT + K_G) * LN + i] = g
            S[(F_EVENT + K_BOOST) * LN + i] = boost
            S[(F_EVENT + K_GO) * LN + i] = 1.0 if go else 0.0
            S[(F_EVENT + K_NEW) * LN + i] = 1.0 if nw else 0.0
            # the frame: the plane of incidence's s after a Fresnel event, a new one after a
            # depolarization, else unchanged
            dpx, dpy, dpz = polarized.beam_frame(nx, ny, nz)
            dep = lamb or coll
            S[F_FRAME * LN + i] = (dpx if dep else (psx if fresnel else pfx)) if go else pfx
            S[(F_FRAME + 1) * LN + i] = (dpy if dep else (psy if fresnel else pfy)) if go else pfy
            S[(F_FRAME + 2) * LN + i] = (dpz if dep else (psz if fresnel else pfz)) if go else pfz
        S[(A_RL + 0) * LN + i] -= nv0 * (boost - 1.0) if booked else 0.0
        S[(A_RL + 1) * LN + i] -= nv1 * (boost - 1.0) if booked else 0.0
        S[(A_RL + 2) * LN + i] -= nv2 * (boost - 1.0) if booked else 0.0
        S[F_DX * LN + i] = nx if go else x
        S[F_DY * LN + i] = ny if go else y
        S[F_DZ * LN + i] = nz if go else z
        S[F_W0 * LN + i] = nv0 * boost if go else v0
        S[F_W1 * LN + i] = nv1 * boost if go else v1
        S[F_W2 * LN + i] = nv2 * boost if go else v2
        S[F_AB0 * LN + i] = nb0 if go else b0
        S[F_AB1 * LN + i] = nb1 if go else b1
        S[F_AB2 * LN + i] = nb2 if go else b2
        S[F_MK0 * LN + i] = nm0 if go else m0
        S[F_MK1 * LN + i] = nm1 if go else m1
        S[F_MK2 * LN + i] = nm2 if go else m2
        S[F_REG * LN + i] = float(nr if go else r)
        S[F_EV * LN + i] = float(ne if go else ev)
        S[F_ORDER * LN + i] = float(order + 1 if (go and top) else order)
        S[F_BASED * LN + i] = 1.0 if (go and based) else bo
        S[F_CTR * LN + i] = float(np.int64(c) + n_draws if go else np.int64(c))
        S[F_STATUS * LN + i] = float(nst if go else st)
        if media is not None:
            S[F_HPOS * LN + i] = nh if go else hp
            S[F_Q0 * LN + i] = nq0 if go else q0
            S[F_Q1 * LN + i] = nq1 if go else q1
            S[F_Q2 * LN + i] = nq2 if go else q2
        if ms is not None:
            # where the walk goes on: the ray's direction of travel, the next hit's height CDF and
            # the side (the refracted ray is seen from below: direction negated, heights 1 - c)
            pend = go and cont
            S[F_WK * LN + i] = float(kc + 1) if pend else S[F_WK * LN + i]
            S[F_WVX * LN + i] = (ox if refl_ else -ox) if pend else S[F_WVX * LN + i]
            S[F_WVY * LN + i] = (oy if refl_ else -oy) if pend else S[F_WVY * LN + i]
            S[F_WVZ * LN + i] = (oz if refl_ else -oz) if pend else S[F_WVZ * LN + i]
            S[F_WC * LN + i] = c_next if pend else S[F_WC * LN + i]
            S[F_WIN * LN + i] = (0.0 if refl_ else 1.0) if pend else S[F_WIN * LN + i]
            # a walk of one bounce on the top interface (its steps mark a longer one)
            S[F_MULTI * LN + i] = 0.0 if (go and walked and k == 0) else S[F_MULTI * LN + i]
    if polar is not None:
        mueller_pass(S)


@numba.njit(cache=True, error_model='numpy', boundscheck=False)
def mueller_pass(S):
    """The lanes' Mueller matrices after stage B of a polarized step (:func:`step`), per element with
    the lanes innermost (it vectorises): the traversal, the frame's rotation, the event's matrix (the
    same arithmetic as stage B's for their ``[0, 0]``, the weights), masking and roulette, from the
    numbers stage B left at ``F_EVENT`` (copied to this function's stack: reads that provably do
    not alias the matrices); a lane that took a new path at this step starts from the identity."""
    prefer_wide_vectors()
    K = stack_block()
    for q in range(N_EVENT * LN):
        K[q] = S[F_EVENT * LN + q]
    for ch in range(3):
        for j in range(4):
            for i in range(LN):
                q = (F_MUELLER + 16 * ch + j) * LN + i
                kb = (K_EVENT + 6 * ch) * LN + i
                pa = K[(K_TRAVERSAL + ch) * LN + i]
                c2 = K[K_C2 * LN + i]
                s2 = K[K_S2 * LN + i]
                kA0 = K[kb]
                kA1 = K[kb + LN]
                kB = K[kb + 2 * LN]
                kC = K[kb + 3 * LN]
                kS = K[kb + 4 * LN]
                kF = K[kb + 5 * LN]
                g = K[K_G * LN + i]
                boost = K[K_BOOST * LN + i]
                go = K[K_GO * LN + i] != 0.0
                nw = K[K_NEW * LN + i] != 0.0
                r0 = ((1.0 if j == 0 else 0.0) if nw else S[q]) * pa
                r1 = ((1.0 if j == 1 else 0.0) if nw else S[q + 4 * LN]) * pa
                r2 = ((1.0 if j == 2 else 0.0) if nw else S[q + 8 * LN]) * pa
                r3 = ((1.0 if j == 3 else 0.0) if nw else S[q + 12 * LN]) * pa
                t1 = c2 * r1 + s2 * r2
                t2 = c2 * r2 - s2 * r1
                m0 = kF * (kA0 * r0 + kB * t1)
                m1 = kF * (kB * r0 + kA1 * t1)
                m2 = kF * (kC * t2 + kS * r3)
                m3 = kF * (kC * r3 - kS * t2)
                m0 *= g
                m1 *= g
                m2 *= g
                m3 *= g
                S[q] = m0 * boost if go else S[q]
                S[q + 4 * LN] = m1 * boost if go else S[q + 4 * LN]
                S[q + 8 * LN] = m2 * boost if go else S[q + 8 * LN]
                S[q + 12 * LN] = m3 * boost if go else S[q + 12 * LN]
