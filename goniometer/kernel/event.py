"""The vectorised event of the lane kernel (``docs/kernel.md``, the event).

Every active lane whose next action is not a per-lane step (:mod:`goniometer.kernel.steps`)
takes one event per step: it traverses its region (Beer-Lambert; clear and scattering regions
give a factor 1), then meets what lies at the end -- a rough single-scattering interface
(visible-normal sample, Fresnel, reflection or refraction, masking), an index-matched
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
from goniometer.kernel.codegen import prefer_wide_vectors, stack_block, u64_bits
from goniometer.kernel.layout import (F_AB0, F_AB1, F_AB2, F_BASED, F_CTR, F_DX, F_DY, F_DZ, F_EV, F_MK0, F_MK1,
                                      F_MK2, F_KEY, F_ORDER, F_REG, F_RL0, F_RL1, F_RL2, F_STATUS, F_W0, F_W1, F_W2,
                                      IF_STRIDE, LANES, RG_STRIDE, ST_ALIVE, ST_CAPPED, ST_DEAD, ST_REFLECTED,
                                      ST_SCALAR, ST_TRANSMITTED, T_AX, T_AY, T_ETA_DN, T_ETA_UP, T_MATCHED, T_MS,
                                      T_RC, T_RS, T_SCAT, T_TAU0, T_TAU1, T_TAU2)
from goniometer.rng import draw, uniform_pair

#: Russian roulette: from this many events on, paths whose largest channel weight is below
#: RR_THRESHOLD survive with probability max(w) / RR_THRESHOLD
RR_START = 3
RR_THRESHOLD = 0.05

_U1 = np.uint64(1)
LN = LANES


@numba.njit(cache=True, error_model='numpy', boundscheck=False)
def events(n, S, table, off, n_if, lambertian, transmit_base, conductor_base, base_k, ce0, ce1, ce2, ck0, ck1, ck2,
           rho0, rho1, rho2, event_cap, height_correlated):
    """One event for lanes ``0 .. n - 1`` of ``S`` (all ``ST_ALIVE``).

    ``height_correlated`` None: separable masking ``G1(o)``; True: height-correlated ``G2 / G1(i)``
    (its Beta function has no vector form: that specialisation runs lane by lane). The None
    specialisation is compiled without the other branch (numba prunes ``is None`` tests on a
    None argument), and its loop is vectorised; the loop body is written out here, as an inlined
    function taking the state array would keep reference counting in the loop and stop LLVM."""
    prefer_wide_vectors()
    # the stack table on this function's stack (gathers that provably do not alias S)
    T = stack_block()
    for q in range(table.shape[0]):
        T[q] = table[q]
    for i in range(n):
        x = S[F_DX * LN + i]
        y = S[F_DY * LN + i]
        z = S[F_DZ * LN + i]
        r = np.int64(S[F_REG * LN + i])
        up = z > 0.0
        # ---- traverse region r (Beer-Lambert; clear and scattering regions have depth 0)
        ro = off + r * RG_STRIDE
        inv_mu = 1.0 / max(abs(z), 1e-300)
        a0 = optics.exp_neg(-T[ro + T_TAU0] * inv_mu)
        a1 = optics.exp_neg(-T[ro + T_TAU1] * inv_mu)
        a2 = optics.exp_neg(-T[ro + T_TAU2] * inv_mu)
        v0 = S[F_W0 * LN + i]
        v1 = S[F_W1 * LN + i]
        v2 = S[F_W2 * LN + i]
        b0 = S[F_AB0 * LN + i] + v0 * (1.0 - a0)
        b1 = S[F_AB1 * LN + i] + v1 * (1.0 - a1)
        b2 = S[F_AB2 * LN + i] + v2 * (1.0 - a2)
        v0 *= a0
        v1 *= a1
        v2 *= a2
        # ---- what lies at the end: interface k, or the Lambertian base below the last region
        from_above = not up
        k = r - 1 if up else r
        lamb = lambertian and from_above and r == n_if
        kc = min(max(k, 0), max(n_if, 1) - 1)
        io = kc * IF_STRIDE
        ax = T[io + T_AX]
        ay = T[io + T_AY]
        rc = T[io + T_RC]
        rs = T[io + T_RS]
        e_dn = T[io + T_ETA_DN]
        e_up = T[io + T_ETA_UP]
        matched = T[io + T_MATCHED] != 0.0
        plain = (not lamb) & (not matched)   # a rough interface (not crossed unchanged); & keeps the loads unconditional
        eta = e_dn if from_above else e_up
        inv_eta = e_up if from_above else e_dn
        is_cond = conductor_base and kc == n_if - 1
        # the arrival direction in the interface's tangent frame of the arrival side
        tx = -x
        ty = -y
        wz = -z if from_above else z
        wx = rc * tx + rs * ty
        wy = rc * ty - rs * tx
        # two 64-bit draws: azimuth and radius of a disk point, Fresnel choice, roulette
        key = u64_bits(S[F_KEY * LN + i])
        c = np.uint64(np.int64(S[F_CTR * LN + i]))
        u1, u2 = uniform_pair(draw(key, c))
        u3, u4 = uniform_pair(draw(key, c + _U1))
        cp, sp = optics.cos_sin_2pi(u1)
        rad = math.sqrt(max(0.0, u2))
        qx = rad * cp
        qy = rad * sp
        mx, my, mz = optics.sample_vndf_disk(wx, wy, wz, ax, ay, qx, qy)
        wm = wx * mx + wy * my + wz * mz
        fd, cos_t = optics.fresnel_dielectric_cos_t_inv(wm, eta, inv_eta)
        f0 = optics.fresnel_conductor(wm, ce0, ck0)
        f1 = optics.fresnel_conductor(wm, ce1, ck1)
        f2 = optics.fresnel_conductor(wm, ce2, ck2)
        refl = is_cond or u3 < fd
        rx, ry, rz = optics.reflect(wx, wy, wz, mx, my, mz)
        sx, sy, sz = optics.refract_known(wx, wy, wz, mx, my, mz, inv_eta, wm, cos_t)
        ox = rx if refl else sx
        oy = ry if refl else sy
        oz = rz if refl else sz
        # single-scattering microfacet model: an exit on the wrong side is lost to masking
        wrong = plain and (oz <= 0.0 if refl else oz >= 0.0)
        if height_correlated is not None:
            lam_o = optics.ggx_lambda(ox, oy, oz, ax, ay)
            lam_i = optics.ggx_lambda(wx, wy, wz, ax, ay)
            g = optics.smith_g2(lam_i, lam_o, not refl, True) * (1.0 + lam_i)
        else:
            g = optics.smith_g1_dir(ox, oy, oz, ax, ay)
        g = 0.0 if wrong else (g if plain else 1.0)
        # weight factors: conductor Fresnel, or the base's albedo; absorbed what they take
        h0 = rho0 if lamb else (f0 if (is_cond and plain) else 1.0)
        h1 = rho1 if lamb else (f1 if (is_cond and plain) else 1.0)
        h2 = rho2 if lamb else (f2 if (is_cond and plain) else 1.0)
        b0 += v0 * (1.0 - h0)
        b1 += v1 * (1.0 - h1)
        b2 += v2 * (1.0 - h2)
        v0 *= h0
        v1 *= h1
        v2 *= h2
        m0 = S[F_MK0 * LN + i] + v0 * (1.0 - g)
        m1 = S[F_MK1 * LN + i] + v1 * (1.0 - g)
        m2 = S[F_MK2 * LN + i] + v2 * (1.0 - g)
        v0 *= g
        v1 *= g
        v2 *= g
        # the new direction (world frame): the lobe's, rotated back; the disk point lifted onto the
        # hemisphere (cosine-distributed, upward) at the base; unchanged through a matched interface
        gx = rc * ox - rs * oy
        gy = rs * ox + rc * oy
        gz = oz if from_above else -oz
        nx = qx if lamb else (gx if plain else x)
        ny = qy if lamb else (gy if plain else y)
        nz = math.sqrt(max(0.0, 1.0 - u2)) if lamb else (gz if plain else z)
        crossed = (not lamb) and (not plain or not refl)
        nr = (k + 1 if from_above else k) if crossed else r
        e = np.int64(S[F_EV * LN + i]) + 1
        bo = S[F_BASED * LN + i]
        top = (k == 0 and not lamb) or (lamb and n_if == 0)
        based = lamb or (k == base_k and from_above)
        # ---- Russian roulette: survivors boosted by 1 / p (the added weight booked per lane); a killed
        # lane keeps its weight for booking as roulette
        wmax = max(v0, max(v1, v2))
        p = wmax * (1.0 / RR_THRESHOLD)
        rr = e >= RR_START and wmax < RR_THRESHOLD
        killed = wrong or (rr and u4 >= p)
        boost = 1.0 / p if (rr and not killed) else 1.0
        # ---- what comes next: an exit (nothing lies beyond), the cap, a per-lane step (a scattering
        # region, or a multiple-scattering interface next) or another event
        k2 = nr - 1 if nz > 0.0 else nr
        k2c = min(max(k2, 0), max(n_if, 1) - 1)
        scat_next = T[off + nr * RG_STRIDE + T_SCAT] != 0.0
        ms_next = T[k2c * IF_STRIDE + T_MS] != 0.0
        step = scat_next | ((k2 >= 0) & (k2 < n_if) & ms_next)
        st = ST_DEAD if killed else (ST_REFLECTED if (nr == 0 and nz > 0.0) else (
            ST_TRANSMITTED if (transmit_base and nr == n_if and nz < 0.0) else (
                ST_CAPPED if e >= event_cap else (ST_SCALAR if step else ST_ALIVE))))
        S[F_DX * LN + i] = nx
        S[F_DY * LN + i] = ny
        S[F_DZ * LN + i] = nz
        S[F_W0 * LN + i] = v0 * boost
        S[F_W1 * LN + i] = v1 * boost
        S[F_W2 * LN + i] = v2 * boost
        S[F_RL0 * LN + i] = S[F_RL0 * LN + i] - v0 * (boost - 1.0)
        S[F_RL1 * LN + i] = S[F_RL1 * LN + i] - v1 * (boost - 1.0)
        S[F_RL2 * LN + i] = S[F_RL2 * LN + i] - v2 * (boost - 1.0)
        S[F_AB0 * LN + i] = b0
        S[F_AB1 * LN + i] = b1
        S[F_AB2 * LN + i] = b2
        S[F_MK0 * LN + i] = m0
        S[F_MK1 * LN + i] = m1
        S[F_MK2 * LN + i] = m2
        S[F_REG * LN + i] = float(nr)
        S[F_EV * LN + i] = float(e)
        S[F_ORDER * LN + i] = S[F_ORDER * LN + i] + (1.0 if top else 0.0)
        S[F_BASED * LN + i] = max(bo, 1.0 if based else 0.0)
        S[F_CTR * LN + i] = float(np.int64(c) + 2)
        S[F_STATUS * LN + i] = float(st)
