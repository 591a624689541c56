"""Research prototype (issue 15, "batched tracing"): a structure-of-arrays kernel that advances
``L`` paths in lock-step, one interface event per step for every lane, with the event's branches
turned into selects so that LLVM vectorises the per-lane loop. Not used by the simulator; see
``benchmarks/README.md``, section "Batched prototype (research)".

Physics: that of :func:`goniometer.tracer.trace_chunk` restricted to what the yardstick
(``benchmarks/reference_kernel.py``) traces and the issue's metal needs: isotropic
single-scattering GGX interfaces (separable masking ``G1(o)``), absorbing (non-scattering) media
(Beer-Lambert), a conductor or transmitting base; Russian roulette from the third event on below
weight 0.05. Bookkeeping as the real kernel's: histograms (n_theta, n_phi, K + 2, 3) with bounce
orders (events at the top interface) and squared sums, energy sums and per-path squared sums of
reflected, transmitted, absorbed and masking weight, roulette, events.

Random numbers: counter-based, ``u = hash(key(path), draw)`` with ``key(path)`` a SplitMix64-style
mix of the chunk key and the path index and the SplitMix64 finaliser as hash, two 32-bit uniforms per hash; every
event consumes exactly two hashes (draw counter += 2), so a path's numbers do not depend on the
lane it runs in, the lane count, or the thread count.

Structure of one chunk (``batched_chunk`` of :func:`make_chunk`): lanes hold paths in one flat
state array; a step runs the vectorised event loop over the active lanes (:func:`make_event`), then a scalar pass over the lanes collects finished
paths (exit direction, weight, order into a per-chunk exit buffer, losses into the energy sums)
and refills them with the next path index; when no path is left, the finished lane is removed by
moving the last active lane into it (stream compaction), so the tail shrinks the loop. The exit
buffer is deposited into the histograms in buffer order (deterministic): one pass computes the
cells, a second adds the weights, prefetching ahead.

``python benchmarks/prototypes/batched_kernel.py --rays N [--lanes L] [--variant V]`` times it on
issue 15's metal like ``reference_kernel.py`` does (one thread, compile excluded, CPU time);
``--check`` compares it with the simulator instead. Variants: ``plain`` (no fast-math),
``arcp-contract`` (numba ``fastmath={'arcp', 'contract'}``) and their ``f32-`` forms
(:func:`make_event32`).
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from goniometer.slices import boundary_tables, cell_index_fast
from goniometer.stack import Stack, pack

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_U30 = np.uint64(30)
_U27 = np.uint64(27)
_U31 = np.uint64(31)
_U32 = np.uint64(32)
_U1 = np.uint64(1)
_U2 = np.uint64(2)
_LOW32 = np.uint64(0xFFFFFFFF)
_INV_2_32 = 1.0 / 4294967296.0
_LOG2E = 1.4426950408889634
_LN2_HI = 0.693147180369123816490
_LN2_LO = 1.90821492927058770002e-10
_TWO_PI = 2.0 * math.pi

RR_START = 3
RR_THRESHOLD = 0.05
#: lane status after a step: still travelling, left upward (BRDF), left downward (BTDF), ended
#: (masking loss or roulette)
ST_ALIVE, ST_REFLECTED, ST_TRANSMITTED, ST_DEAD = 0, 1, 2, 3


#: rows of the lane state (one flat float64 array, row f of lane i at f * lanes + i; integers
#: stored exactly as doubles, the path key as the bits of a double)
F_DX = 0
F_DY = 1
F_DZ = 2
F_W0 = 3
F_W1 = 4
F_W2 = 5
F_AB0 = 6
F_AB1 = 7
F_AB2 = 8
F_MK0 = 9
F_MK1 = 10
F_MK2 = 11
F_RL0 = 12
F_RL1 = 13
F_RL2 = 14
F_REG = 15
F_EV = 16
F_ORDER = 17
F_CTR = 18
F_KEY = 19
F_STATUS = 20
N_FIELDS = 21


@intrinsic
def _bits_to_double(typingctx, x):
    """Reinterpret the bits of an int64 as a float64 (vectorisable, unlike a libm ``ldexp``)."""
    sig = types.float64(types.int64)

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.DoubleType())

    return sig, codegen


@intrinsic
def _u64_bits(typingctx, x):
    """The bits of a float64 as a uint64 (inverse of :func:`_u64_as_double`)."""
    sig = types.uint64(types.float64)

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.IntType(64))

    return sig, codegen


@intrinsic
def _u64_as_double(typingctx, x):
    """A uint64 stored in the bits of a float64 (moved, never computed with)."""
    sig = types.float64(types.uint64)

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.DoubleType())

    return sig, codegen


@intrinsic
def _prefetch_flat(typingctx, arr, idx):
    """Hint the CPU to fetch the cache line of the 1-D ``arr[idx]`` for writing (``llvm.prefetch``;
    no effect on results, no bounds check)."""
    sig = types.void(arr, idx)

    def codegen(context, builder, signature, args):
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        ptr = builder.gep(ary.data, [context.cast(builder, args[1], signature.args[1], types.intp)])
        i8p = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        fn = builder.module.declare_intrinsic("llvm.prefetch", [i8p], ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]))
        builder.call(fn, [builder.bitcast(ptr, i8p), ir.Constant(i32, 1), ir.Constant(i32, 3), ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return sig, codegen


@numba.njit(inline="always", error_model="numpy")
def _hash(key, n):
    """SplitMix64 finaliser of ``key + n * golden``: the ``n``-th 64-bit draw of a path."""
    z = key + n * _GOLDEN
    z = (z ^ (z >> _U30)) * _M1
    z = (z ^ (z >> _U27)) * _M2
    return z ^ (z >> _U31)


@numba.njit(inline="always", error_model="numpy")
def _uniforms(h):
    """Two uniforms in [0, 1) from the two 32-bit halves of ``h`` (grid 2^-32)."""
    a = np.int64(h >> _U32)
    b = np.int64(h & _LOW32)
    return float(a) * _INV_2_32, float(b) * _INV_2_32


@numba.njit(inline="always", error_model="numpy")
def _exp_neg(x):
    """``exp(x)`` for ``x <= 0`` without a libm call (vectorisable): ``2^k p(r)``, ``|r| <= ln2/2``,
    Taylor to degree 13 (relative error ~1e-16); ``x < -708`` gives ``exp(-708)``."""
    x = max(x, -708.0)
    kf = math.floor(x * _LOG2E + 0.5)
    r = (x - kf * _LN2_HI) - kf * _LN2_LO
    p = 1.0 / 6227020800.0
    p = p * r + 1.0 / 479001600.0
    p = p * r + 1.0 / 39916800.0
    p = p * r + 1.0 / 3628800.0
    p = p * r + 1.0 / 362880.0
    p = p * r + 1.0 / 40320.0
    p = p * r + 1.0 / 5040.0
    p = p * r + 1.0 / 720.0
    p = p * r + 1.0 / 120.0
    p = p * r + 1.0 / 24.0
    p = p * r + 1.0 / 6.0
    p = p * r + 0.5
    p = p * r + 1.0
    p = p * r + 1.0
    return p * _bits_to_double((np.int64(kf) + 1023) << 52)


@numba.njit(inline="always", error_model="numpy")
def _cos_sin_2pi(u):
    """``cos, sin`` of ``2 pi u``, ``u`` in [0, 1): quarter-turn split and Taylor (degree 15/16),
    selects only (the formula of ``goniometer.optics.cos_sin_2pi``, written branch-free here)."""
    kf = math.floor(u * 4.0 + 0.5)
    x = (u - 0.25 * kf) * _TWO_PI
    x2 = x * x
    s = x + x * x2 * (-1.0 / 6.0 + x2 * (1.0 / 120.0 + x2 * (-1.0 / 5040.0 + x2 * (1.0 / 362880.0 + x2 * (
        -1.0 / 39916800.0 + x2 * (1.0 / 6227020800.0 + x2 * (-1.0 / 1307674368000.0)))))))
    c = 1.0 + x2 * (-0.5 + x2 * (1.0 / 24.0 + x2 * (-1.0 / 720.0 + x2 * (1.0 / 40320.0 + x2 * (
        -1.0 / 3628800.0 + x2 * (1.0 / 479001600.0 + x2 * (-1.0 / 87178291200.0 + x2 * (1.0 / 20922789888000.0))))))))
    q = np.int64(kf) & 3
    odd = (q & 1) != 0
    a = s if odd else c
    b = c if odd else s
    cv = -a if (q == 1 or q == 2) else a
    sv = -b if q >= 2 else b
    return cv, sv


@numba.njit(inline="always", error_model="numpy")
def _fresnel_conductor(c, eta, k):
    """Unpolarised conductor reflectance (the formula of ``goniometer.optics.fresnel_conductor``),
    ``c`` in (0, 1], without branches, one division."""
    c2 = c * c
    s2 = 1.0 - c2
    t = eta * eta - k * k - s2
    a2b2 = math.sqrt(max(0.0, t * t + 4.0 * eta * eta * k * k))
    a = math.sqrt(max(0.0, 0.5 * (a2b2 + t)))
    t1 = a2b2 + c2
    t2 = 2.0 * a * c
    t3 = a2b2 * c2 + s2 * s2
    t4 = t2 * s2
    # rs = (t1 - t2) / (t1 + t2), rp = rs (t3 - t4) / (t3 + t4): one division for both
    return 0.5 * (t1 - t2) * ((t3 + t4) + (t3 - t4)) / ((t1 + t2) * (t3 + t4))


def make_event(fastmath, lanes):
    """The vectorised event over lanes ``0 .. n - 1`` (``n <= lanes``) of the flat state ``S``
    (row ``f`` of lane ``i`` at ``f * lanes + i``), compiled with numba's ``fastmath`` flags (False,
    or a set such as ``{'arcp', 'contract'}``). ``lanes`` is a compile-time constant: the rows are
    then a constant distance apart, which lets LLVM prove the lanes independent (separate arrays
    need one runtime alias check per pair: "too many memory checks needed", no vectorisation)."""
    LN = lanes

    @numba.njit(fastmath=fastmath, error_model="numpy", boundscheck=False)
    def _event(n, S, k_alpha, k_eta_dn, k_eta_up, r_tau0, r_tau1, r_tau2, n_if, transmit_base, conductor_base,
               ce0, ce1, ce2, ck0, ck1, ck2):
        last = n_if - 1
        # the stack's tables as scalars (at most two interfaces): indexed loads inside the loop
        # would defeat LLVM's runtime alias checks ("cannot identify array bounds")
        al0 = k_alpha[0]
        al1 = k_alpha[min(1, last)]
        ed0 = k_eta_dn[0]
        ed1 = k_eta_dn[min(1, last)]
        eu0 = k_eta_up[0]
        eu1 = k_eta_up[min(1, last)]
        t00 = r_tau0[0]
        t01 = r_tau0[1]
        t02 = r_tau0[min(2, n_if)]
        t10 = r_tau1[0]
        t11 = r_tau1[1]
        t12 = r_tau1[min(2, n_if)]
        t20 = r_tau2[0]
        t21 = r_tau2[1]
        t22 = r_tau2[min(2, n_if)]
        for i in range(n):
            x = S[F_DX * LN + i]
            y = S[F_DY * LN + i]
            z = S[F_DZ * LN + i]
            v0 = S[F_W0 * LN + i]
            v1 = S[F_W1 * LN + i]
            v2 = S[F_W2 * LN + i]
            r = np.int64(S[F_REG * LN + i])
            # ---- traverse the region (Beer-Lambert; tau 0 gives a factor 1)
            inv_mu = 1.0 / abs(z)
            a0 = _exp_neg(-(t00 if r == 0 else (t01 if r == 1 else t02)) * inv_mu)
            a1 = _exp_neg(-(t10 if r == 0 else (t11 if r == 1 else t12)) * inv_mu)
            a2 = _exp_neg(-(t20 if r == 0 else (t21 if r == 1 else t22)) * inv_mu)
            va0 = v0 * a0
            va1 = v1 * a1
            va2 = v2 * a2
            ba0 = S[F_AB0 * LN + i] + v0 * (1.0 - a0)
            ba1 = S[F_AB1 * LN + i] + v1 * (1.0 - a1)
            ba2 = S[F_AB2 * LN + i] + v2 * (1.0 - a2)
            up = z > 0.0
            # ---- the interface event (every lane has one: exits are detected at its end)
            k = r - 1 if up else r
            k = min(max(k, 0), last)
            from_above = not up
            alpha = al0 if k == 0 else al1
            e_dn = ed0 if k == 0 else ed1
            e_up = eu0 if k == 0 else eu1
            eta = e_dn if from_above else e_up
            inv_eta = e_up if from_above else e_dn
            is_cond = conductor_base and k == last
            wx = -x
            wy = -y
            wz = -z if from_above else z
            c = np.uint64(np.int64(S[F_CTR * LN + i]))
            kk = _u64_bits(S[F_KEY * LN + i])
            u1, u2 = _uniforms(_hash(kk, c))
            u3, u4 = _uniforms(_hash(kk, c + _U1))
            # visible normal: spherical cap, azimuth by polynomial sincos
            sx = alpha * wx
            sy = alpha * wy
            inv = 1.0 / math.sqrt(max(1e-300, sx * sx + sy * sy + wz * wz))
            sx *= inv
            sy *= inv
            b = 1.0 + wz * inv
            cp, sp = _cos_sin_2pi(u1)
            rad = math.sqrt(max(0.0, u2))
            kq = math.sqrt(max(0.0, b * (2.0 - u2 * b))) * rad
            mx = alpha * (kq * cp + sx)
            my = alpha * (kq * sp + sy)
            mz = max(1e-300, b * (1.0 - u2))
            inv = 1.0 / math.sqrt(max(1e-300, mx * mx + my * my + mz * mz))
            mx *= inv
            my *= inv
            mz *= inv
            wm = wx * mx + wy * my + wz * mz
            cw = min(abs(wm), 1.0)
            # dielectric Fresnel and refracted cosine, one division:
            # F = (rs^2 + rp^2) / 2 with rs = A / B, rp = C / D
            sin2_t = (1.0 - cw * cw) * (inv_eta * inv_eta)
            tir = sin2_t >= 1.0
            cos_t = math.sqrt(max(0.0, 1.0 - sin2_t))
            fa = cw - eta * cos_t
            fb = cw + eta * cos_t
            fc = eta * cw - cos_t
            fdd = eta * cw + cos_t
            fd = 1.0 if tir else 0.5 * (fa * fa * fdd * fdd + fc * fc * fb * fb) / (fb * fb * fdd * fdd)
            # conductor Fresnel per channel (1 where the interface is a dielectric)
            cwc = max(cw, 1e-300)
            f0 = _fresnel_conductor(cwc, ce0, ck0) if is_cond else 1.0
            f1 = _fresnel_conductor(cwc, ce1, ck1) if is_cond else 1.0
            f2 = _fresnel_conductor(cwc, ce2, ck2) if is_cond else 1.0
            refl = is_cond or u3 < fd
            q = wm * inv_eta - cos_t
            ox = 2.0 * wm * mx - wx if refl else q * mx - wx * inv_eta
            oy = 2.0 * wm * my - wy if refl else q * my - wy * inv_eta
            oz = 2.0 * wm * mz - wz if refl else q * mz - wz * inv_eta
            wrong = oz <= 0.0 if refl else oz >= 0.0
            # separable masking G1(o) = 2 |oz| / (|oz| + sqrt(oz^2 + alpha^2 (ox^2 + oy^2)))
            az = abs(oz)
            g = 2.0 * az / (az + math.sqrt(max(0.0, az * az + alpha * alpha * (ox * ox + oy * oy))))
            g = 0.0 if wrong else g
            # conductor loss to absorbed, masking loss to masking (the whole weight if wrong side)
            b0 = ba0 + va0 * (1.0 - f0)
            b1 = ba1 + va1 * (1.0 - f1)
            b2 = ba2 + va2 * (1.0 - f2)
            v0 = va0 * f0
            v1 = va1 * f1
            v2 = va2 * f2
            m0 = S[F_MK0 * LN + i] + v0 * (1.0 - g)
            m1 = S[F_MK1 * LN + i] + v1 * (1.0 - g)
            m2 = S[F_MK2 * LN + i] + v2 * (1.0 - g)
            v0 *= g
            v1 *= g
            v2 *= g
            e = np.int64(S[F_EV * LN + i]) + 1
            # Russian roulette: survivors boosted by 1 / p (the added weight booked per lane), a
            # killed lane keeps its weight for the finishing pass to book as roulette
            wmax = max(v0, max(v1, v2))
            p = wmax * (1.0 / RR_THRESHOLD)
            rr = e >= RR_START and wmax < RR_THRESHOLD
            killed = wrong or (rr and u4 >= p)
            boost = 1.0 / p if (rr and not killed) else 1.0
            nz = oz if from_above else -oz
            nr = r if refl else (k + 1 if from_above else k)
            # the path leaves the stack if it is now above the top going up (BRDF) or below a
            # transmitting bottom going down (BTDF): no medium there, so nothing happens before
            st = ST_DEAD if killed else (ST_REFLECTED if (nr == 0 and nz > 0.0) else (
                ST_TRANSMITTED if (transmit_base and nr == n_if and nz < 0.0) else ST_ALIVE))
            S[F_DX * LN + i] = ox
            S[F_DY * LN + i] = oy
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
            S[F_ORDER * LN + i] = S[F_ORDER * LN + i] + (1.0 if k == 0 else 0.0)
            S[F_CTR * LN + i] = float(np.int64(c + _U2))
            S[F_STATUS * LN + i] = float(st)

    return _event

# rows of the energy sums (as goniometer.tracer's)
E_REFLECTED, E_TRANSMITTED, E_ABSORBED, E_MASKING, E_ROULETTE = 0, 1, 2, 3, 5
N_ENERGY = 7
N_ENERGY_SQ = 5


@numba.njit(cache=True, error_model="numpy")
def path_key(chunk_key, path):
    """The counter key of path ``path`` of a chunk: its draws are ``_hash(key, 0, 1, ...)``."""
    z = chunk_key ^ (np.uint64(path) * _M2)
    z = (z ^ (z >> _U30)) * _M1
    z = (z ^ (z >> _U27)) * _M2
    return z ^ (z >> _U31)


@numba.njit(cache=True, error_model="numpy")
def chunk_key(seed, incident, chunk):
    """The key of chunk ``chunk`` of incident direction ``incident``: a function of the three only."""
    return path_key(path_key(path_key(np.uint64(0x5EED), seed), incident), chunk)


def make_chunk(event, lanes):
    """A chunk driver around the vectorised ``event`` (see :func:`make_event`) of ``lanes`` lanes."""
    LN = lanes

    @numba.njit(error_model="numpy", boundscheck=False)
    def batched_chunk(n_rays, ckey, lx, ly, lz, k_alpha, k_eta_dn, k_eta_up, r_tau, n_if, transmit_base,
                      conductor_base, cond, param, n_theta, n_phi, row_cos, col_cos, col_sin, max_order,
                      brdf, btdf, energy, energy_sq, counts, xbuf, cell, sqo):
        L = LN
        S = np.zeros(N_FIELDS * L)
        dx = S[F_DX * L:(F_DX + 1) * L]
        dy = S[F_DY * L:(F_DY + 1) * L]
        dz = S[F_DZ * L:(F_DZ + 1) * L]
        w0 = S[F_W0 * L:(F_W0 + 1) * L]
        w1 = S[F_W1 * L:(F_W1 + 1) * L]
        w2 = S[F_W2 * L:(F_W2 + 1) * L]
        ab0 = S[F_AB0 * L:(F_AB0 + 1) * L]
        ab1 = S[F_AB1 * L:(F_AB1 + 1) * L]
        ab2 = S[F_AB2 * L:(F_AB2 + 1) * L]
        mk0 = S[F_MK0 * L:(F_MK0 + 1) * L]
        mk1 = S[F_MK1 * L:(F_MK1 + 1) * L]
        mk2 = S[F_MK2 * L:(F_MK2 + 1) * L]
        rl0 = S[F_RL0 * L:(F_RL0 + 1) * L]
        rl1 = S[F_RL1 * L:(F_RL1 + 1) * L]
        rl2 = S[F_RL2 * L:(F_RL2 + 1) * L]
        reg = S[F_REG * L:(F_REG + 1) * L]
        ev = S[F_EV * L:(F_EV + 1) * L]
        order = S[F_ORDER * L:(F_ORDER + 1) * L]
        ctr = S[F_CTR * L:(F_CTR + 1) * L]
        key = S[F_KEY * L:(F_KEY + 1) * L]
        status = S[F_STATUS * L:(F_STATUS + 1) * L]
        r_tau0 = r_tau[:, 0].copy()
        r_tau1 = r_tau[:, 1].copy()
        r_tau2 = r_tau[:, 2].copy()
        next_path = 0
        n = min(L, n_rays)
        for i in range(n):
            dx[i] = -lx
            dy[i] = -ly
            dz[i] = -lz
            w0[i] = 1.0
            w1[i] = 1.0
            w2[i] = 1.0
            ab0[i] = 0.0
            ab1[i] = 0.0
            ab2[i] = 0.0
            mk0[i] = 0.0
            mk1[i] = 0.0
            mk2[i] = 0.0
            rl0[i] = 0.0
            rl1[i] = 0.0
            rl2[i] = 0.0
            reg[i] = 0.0
            ev[i] = 0.0
            order[i] = 0.0
            ctr[i] = 0.0
            key[i] = _u64_as_double(path_key(ckey, next_path))
            next_path += 1
        # energy sums of the chunk in locals (array elements would be reloaded after every store)
        rl_0 = 0.0
        rl_1 = 0.0
        rl_2 = 0.0
        re_0 = 0.0
        re_1 = 0.0
        re_2 = 0.0
        req_0 = 0.0
        req_1 = 0.0
        req_2 = 0.0
        tr_0 = 0.0
        tr_1 = 0.0
        tr_2 = 0.0
        trq_0 = 0.0
        trq_1 = 0.0
        trq_2 = 0.0
        ab_0 = 0.0
        ab_1 = 0.0
        ab_2 = 0.0
        abq_0 = 0.0
        abq_1 = 0.0
        abq_2 = 0.0
        mk_0 = 0.0
        mk_1 = 0.0
        mk_2 = 0.0
        mkq_0 = 0.0
        mkq_1 = 0.0
        mkq_2 = 0.0
        n_exit = 0
        n_events = 0
        while n > 0:
            event(n, S, k_alpha, k_eta_dn, k_eta_up, r_tau0, r_tau1, r_tau2, n_if, transmit_base,
                  conductor_base, cond[0], cond[1], cond[2], cond[3], cond[4], cond[5])
            # ---- scalar pass: finished lanes booked, refilled or compacted away
            i = 0
            while i < n:
                st = int(status[i])
                if st == ST_ALIVE:
                    i += 1
                    continue
                if st == ST_DEAD:
                    rl_0 += rl0[i] + w0[i]
                    rl_1 += rl1[i] + w1[i]
                    rl_2 += rl2[i] + w2[i]
                else:
                    rl_0 += rl0[i]
                    rl_1 += rl1[i]
                    rl_2 += rl2[i]
                    if st == ST_REFLECTED:
                        re_0 += w0[i]
                        re_1 += w1[i]
                        re_2 += w2[i]
                        req_0 += w0[i] * w0[i]
                        req_1 += w1[i] * w1[i]
                        req_2 += w2[i] * w2[i]
                    else:
                        tr_0 += w0[i]
                        tr_1 += w1[i]
                        tr_2 += w2[i]
                        trq_0 += w0[i] * w0[i]
                        trq_1 += w1[i] * w1[i]
                        trq_2 += w2[i] * w2[i]
                    xbuf[n_exit, 0] = dx[i]
                    xbuf[n_exit, 1] = dy[i]
                    xbuf[n_exit, 2] = dz[i]
                    xbuf[n_exit, 3] = w0[i]
                    xbuf[n_exit, 4] = w1[i]
                    xbuf[n_exit, 5] = w2[i]
                    xbuf[n_exit, 6] = float(min(int(order[i]), max_order) - 1 + (0 if st == ST_REFLECTED else 1000))
                    n_exit += 1
                ab_0 += ab0[i]
                ab_1 += ab1[i]
                ab_2 += ab2[i]
                abq_0 += ab0[i] * ab0[i]
                abq_1 += ab1[i] * ab1[i]
                abq_2 += ab2[i] * ab2[i]
                mk_0 += mk0[i]
                mk_1 += mk1[i]
                mk_2 += mk2[i]
                mkq_0 += mk0[i] * mk0[i]
                mkq_1 += mk1[i] * mk1[i]
                mkq_2 += mk2[i] * mk2[i]
                n_events += int(ev[i])
                if next_path < n_rays:
                    dx[i] = -lx
                    dy[i] = -ly
                    dz[i] = -lz
                    w0[i] = 1.0
                    w1[i] = 1.0
                    w2[i] = 1.0
                    ab0[i] = 0.0
                    ab1[i] = 0.0
                    ab2[i] = 0.0
                    mk0[i] = 0.0
                    mk1[i] = 0.0
                    mk2[i] = 0.0
                    rl0[i] = 0.0
                    rl1[i] = 0.0
                    rl2[i] = 0.0
                    reg[i] = 0.0
                    ev[i] = 0.0
                    order[i] = 0.0
                    ctr[i] = 0.0
                    key[i] = _u64_as_double(path_key(ckey, next_path))
                    next_path += 1
                    i += 1
                else:
                    # stream compaction: the last active lane moves into this one
                    n -= 1
                    if i < n:
                        dx[i] = dx[n]
                        dy[i] = dy[n]
                        dz[i] = dz[n]
                        w0[i] = w0[n]
                        w1[i] = w1[n]
                        w2[i] = w2[n]
                        ab0[i] = ab0[n]
                        ab1[i] = ab1[n]
                        ab2[i] = ab2[n]
                        mk0[i] = mk0[n]
                        mk1[i] = mk1[n]
                        mk2[i] = mk2[n]
                        rl0[i] = rl0[n]
                        rl1[i] = rl1[n]
                        rl2[i] = rl2[n]
                        reg[i] = reg[n]
                        ev[i] = ev[n]
                        order[i] = order[n]
                        ctr[i] = ctr[n]
                        key[i] = key[n]
                        status[i] = status[n]
        energy[E_ROULETTE, 0] += rl_0
        energy[E_ROULETTE, 1] += rl_1
        energy[E_ROULETTE, 2] += rl_2
        energy[E_REFLECTED, 0] += re_0
        energy[E_REFLECTED, 1] += re_1
        energy[E_REFLECTED, 2] += re_2
        energy_sq[E_REFLECTED, 0] += req_0
        energy_sq[E_REFLECTED, 1] += req_1
        energy_sq[E_REFLECTED, 2] += req_2
        energy[E_TRANSMITTED, 0] += tr_0
        energy[E_TRANSMITTED, 1] += tr_1
        energy[E_TRANSMITTED, 2] += tr_2
        energy_sq[E_TRANSMITTED, 0] += trq_0
        energy_sq[E_TRANSMITTED, 1] += trq_1
        energy_sq[E_TRANSMITTED, 2] += trq_2
        energy[E_ABSORBED, 0] += ab_0
        energy[E_ABSORBED, 1] += ab_1
        energy[E_ABSORBED, 2] += ab_2
        energy_sq[E_ABSORBED, 0] += abq_0
        energy_sq[E_ABSORBED, 1] += abq_1
        energy_sq[E_ABSORBED, 2] += abq_2
        energy[E_MASKING, 0] += mk_0
        energy[E_MASKING, 1] += mk_1
        energy[E_MASKING, 2] += mk_2
        energy_sq[E_MASKING, 0] += mkq_0
        energy_sq[E_MASKING, 1] += mkq_1
        energy_sq[E_MASKING, 2] += mkq_2
        # ---- exits deposited into the histograms in buffer order (scalar passes): cells first,
        # then the additions, the cell PF exits ahead prefetched
        PF = 16
        row = (max_order + 2) * 3
        for e in range(n_exit):
            code = int(xbuf[e, 6])
            transmission = code >= 1000
            o = code - 1000 if transmission else code
            i, j = cell_index_fast(param, transmission, lx, ly, lz, xbuf[e, 0], xbuf[e, 1], xbuf[e, 2], n_theta, n_phi,
                                   row_cos, col_cos, col_sin)
            # flat offset of the cell's order row (-1: outside the slice); BTDF cells offset by the BRDF size
            cell[e] = -1 if i < 0 else (i * n_phi + j) * row + o * 3 + (n_theta * n_phi * row if transmission else 0)
            sqo[e] = 0 if i < 0 else (i * n_phi + j) * row + max_order * 3 + (n_theta * n_phi * row if transmission else 0)
        hb = brdf.reshape(-1)
        ht = btdf.reshape(-1)
        nb = n_theta * n_phi * row
        for e in range(n_exit):
            if e + PF < n_exit:
                f = cell[e + PF]
                if f >= 0:
                    if f < nb:
                        _prefetch_flat(hb, f)
                        _prefetch_flat(hb, sqo[e + PF])
                    else:
                        _prefetch_flat(ht, f - nb)
                        _prefetch_flat(ht, sqo[e + PF] - nb)
            f = cell[e]
            if f < 0:
                continue
            q = sqo[e]
            h = hb
            if f >= nb:
                h = ht
                f -= nb
                q -= nb
            v0 = xbuf[e, 3]
            v1 = xbuf[e, 4]
            v2 = xbuf[e, 5]
            h[f] += v0
            h[f + 1] += v1
            h[f + 2] += v2
            h[q] += v0 * v0
            h[q + 1] += v1 * v1
            h[q + 2] += v2 * v2
            if f != q - max_order * 3:
                # an internal exit (order row > 0): also its squares
                h[q + 3] += v0 * v0
                h[q + 4] += v1 * v1
                h[q + 5] += v2 * v2
        counts[1] += n_events

    return batched_chunk


def supported(stack: Stack) -> bool:
    """What the prototype traces: one or two isotropic single-scattering rough interfaces, no
    index-matched interface, absorbing (non-scattering) media, a conductor or transmitting base."""
    p = pack(stack)
    n_if = p.region_eta.shape[0] - 1
    matched = any(p.region_eta[k] == p.region_eta[k + 1] and not (p.base_kind == 1 and k == n_if - 1)
                  for k in range(n_if))
    return (p.base_kind in (0, 1) and 1 <= n_if <= 2 and not matched and not np.any(p.if_ms)
            and bool(np.all(p.if_alpha[:, 0] == p.if_alpha[:, 1])) and bool(np.all(p.if_rot[:, 1] == 0.0))
            and bool(np.all(p.region_albedo == 0.0)) and bool(np.all(p.if_alpha[:, 0] > 0.0)))


def make_event32(fastmath, lanes):
    """:func:`make_event` with the event's direction and microfacet arithmetic in float32 (the
    VNDF's square roots and divisions, dielectric Fresnel, reflection / refraction, masking): the
    source of :func:`make_event` with the directions, roughness and indices loaded as float32 and
    its float literals made float32 (1e-300 becomes 1e-30); weights, energy sums, the Beer-Lambert exponentials, the
    sin/cos polynomial, the conductor Fresnel and the random numbers stay float64 (the uniforms
    are rounded to float32). Research only: an exit direction then carries float32 rounding."""
    import inspect
    import re
    src = inspect.getsource(make_event)
    head, body = src.split("        for i in range(n):\n", 1)
    body = body.replace("1e-300", "1e-30")
    body = re.sub(r"(?<![\w.])(\d+\.\d*(?:e-?\d+)?|\d+e-?\d+)", r"_F32(\1)", body)
    for v in ("x", "y", "z"):
        load = f"S[F_D{v.upper()} * LN + i]"
        body = body.replace(f"            {v} = {load}", f"            {v} = _F32({load})")
    for v in ("alpha", "e_dn", "e_up"):
        body = re.sub(rf"            {v} = (.*)\n", rf"            {v} = _F32(\1)\n", body, count=1)
    body = body.replace("= _uniforms(", "= _uniforms32(")
    body = body.replace("cp, sp = _cos_sin_2pi(u1)",
                        "cp64, sp64 = _cos_sin_2pi(np.float64(u1))\n            cp = _F32(cp64)\n            sp = _F32(sp64)")
    src = (head + "        for i in range(n):\n" + body).replace("def make_event(", "def _make_event32(")
    ns = dict(globals())
    exec(compile(src, __file__ + ":make_event32", "exec"), ns)
    return ns["_make_event32"](fastmath, lanes)


_F32 = np.float32


@numba.njit(inline="always", error_model="numpy")
def _uniforms32(h):
    """:func:`_uniforms` rounded to float32 (a value that rounds up to 1 is clamped below 1)."""
    a, b = _uniforms(h)
    one_minus = np.float32(0.99999994)
    return min(np.float32(a), one_minus), min(np.float32(b), one_minus)


VARIANTS = {
    "plain": False,
    "arcp-contract": {"arcp", "contract"},
}
_compiled: dict = {}


def kernel(variant: str = "plain", lanes: int = 64):
    """The compiled chunk driver of a fastmath ``variant`` (a key of :data:`VARIANTS`) over ``lanes``."""
    if (variant, lanes) not in _compiled:
        if variant.startswith("f32-"):
            event = make_event32(VARIANTS[variant[4:]], lanes)
        else:
            event = make_event(VARIANTS[variant], lanes)
        _compiled[variant, lanes] = make_chunk(event, lanes)
    return _compiled[variant, lanes]


def trace_batched(stack: Stack, l, rays: int, param: int, n_theta: int, n_phi: int, seed: int = 1,
                  incident_index: int = 0, chunk_rays: int = 1 << 17, lanes: int = 64, max_order: int = 5,
                  variant: str = "plain"):
    """Trace ``rays`` paths for light direction ``l`` (unit, towards the light), chunk by chunk
    (chunk ``c`` keyed by ``(seed, incident_index, c)``), and return ``(brdf, btdf, energy,
    energy_sq, events)``: histograms (n_theta, n_phi, max_order + 2, 3) as the simulator's, energy
    sums (7, 3) and per-path squared sums (5, 3) in its rows, the number of events."""
    if not supported(stack):
        raise ValueError(f"batched prototype: stack {stack.name!r} has a feature the prototype does not trace")
    p = pack(stack)
    n_if = p.region_eta.shape[0] - 1
    eta_dn = p.region_eta[1:] / p.region_eta[:-1]
    eta_up = 1.0 / eta_dn
    pname = "classic" if param == 0 else "half"
    row_cos, col_cos, col_sin = boundary_tables(pname, n_theta, n_phi)
    run = kernel(variant, lanes)
    brdf = np.zeros((n_theta, n_phi, max_order + 2, 3))
    btdf = np.zeros_like(brdf)
    energy = np.zeros((N_ENERGY, 3))
    energy_sq = np.zeros((N_ENERGY_SQ, 3))
    counts = np.zeros(2, dtype=np.int64)
    xbuf = np.empty((min(chunk_rays, rays), 7))
    cell = np.empty(min(chunk_rays, rays), dtype=np.int64)
    sqo = np.empty(min(chunk_rays, rays), dtype=np.int64)
    n_chunks = (rays + chunk_rays - 1) // chunk_rays
    for c in range(n_chunks):
        n = min(chunk_rays, rays - c * chunk_rays)
        ckey = np.uint64(chunk_key(np.uint64(seed), np.uint64(incident_index), np.uint64(c)))
        run(n, ckey, float(l[0]), float(l[1]), float(l[2]), np.ascontiguousarray(p.if_alpha[:, 0]),
            eta_dn, eta_up, p.region_tau, n_if, p.base_kind == 0, p.base_kind == 1, p.cond, param, n_theta, n_phi,
            row_cos, col_cos, col_sin, max_order, brdf, btdf, energy, energy_sq, counts, xbuf, cell, sqo)
    return brdf, btdf, energy, energy_sq, int(counts[1])


def _chi2(h_a, h_b, rays: int, K: int) -> tuple[float, int]:
    """Chi-square of two independent samples' BRDF cell sums (all orders, per channel, cells
    with >= 100 effective exits in the two together), each cell's variance from both samples'
    squared sums; and its degrees of freedom."""
    a, qa = h_a[:, :, :K, :].sum(axis=2), h_a[:, :, K, :]
    b, qb = h_b[:, :, :K, :].sum(axis=2), h_b[:, :, K, :]
    var = (qa / rays - (a / rays) ** 2 + qb / rays - (b / rays) ** 2) / rays
    hits = (a + b) ** 2 / np.maximum(qa + qb, 1e-300)
    sel = hits >= 100.0
    return float(np.sum(((a - b)[sel] / rays) ** 2 / var[sel])), int(sel.sum())


def check(stack: Stack, l, rays: int, lanes: int, variant: str, res: tuple[int, int] = (90, 360)) -> int:
    """Print the chi-square of the prototype's BRDF cell sums against the simulator's (seeds 2 and
    1: independent samples of the same estimator), the same statistic for the simulator against
    itself (seeds 2 and 1: what the statistic gives for identical physics, heavy-tailed cell
    weights making it not exactly 1 per degree of freedom), the z-scores of the reflected energy
    per channel and the prototype's energy closure."""
    from goniometer.settings import SimulationSettings
    from goniometer.tasks import n_tasks, trace_tasks
    sims = []
    for seed in (1, 2):
        s = SimulationSettings(incident_deg=(30.0,), rays=rays, resolution=res, parametrization="classic", threads=1,
                               seed=seed)
        parts = trace_tasks(stack, s, 0, 0, n_tasks(s))
        acc = parts[0]
        for p in parts[1:]:
            acc.add(p)
        sims.append(acc)
    acc = sims[0]
    K = s.max_order
    h, _, e, q, events = trace_batched(stack, l, rays, 0, *res, seed=2, lanes=lanes, max_order=K, variant=variant)
    chi2, dof = _chi2(acc.brdf, h, rays, K)
    chi2_s, dof_s = _chi2(acc.brdf, sims[1].brdf, rays, K)
    e_var = (acc.energy_sq[0] / rays - (acc.energy[0] / rays) ** 2 + q[0] / rays - (e[0] / rays) ** 2) / rays
    z = (acc.energy[0] - e[0]) / rays / np.sqrt(e_var)
    closure = (e[E_REFLECTED] + e[E_TRANSMITTED] + e[E_ABSORBED] + e[E_MASKING] + e[E_ROULETTE]) / rays - 1.0
    print(f"batched[{variant}, L={lanes}] vs simulator, {rays} rays each, {res[0]} x {res[1]}: chi2/dof "
          f"{chi2 / dof:.3f} over {dof} cell-channels (simulator vs itself: {chi2_s / dof_s:.3f} over {dof_s}; "
          f"sd {math.sqrt(2.0 / dof):.3f}); reflected energy {np.round(e[0] / rays, 5)} vs "
          f"{np.round(acc.energy[0] / rays, 5)}, z {np.round(z, 2)}; energy closure {np.abs(closure).max():.1e}; "
          f"events/ray {events / rays:.3f} vs {acc.counts[1] / rays:.3f}")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description="time the batched prototype on issue 15's metal (one thread)")
    ap.add_argument("--rays", type=int, default=4_000_000)
    ap.add_argument("--lanes", type=int, default=64)
    ap.add_argument("--variant", choices=sorted(VARIANTS) + ["f32-" + v for v in sorted(VARIANTS)], default="plain")
    ap.add_argument("--check", action="store_true",
                    help="instead of timing, compare with the simulator (independent seeds) at the timed configuration")
    args = ap.parse_args()
    sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[1]))
    from reference_kernel import issue15_metal

    from goniometer.slices import light_direction
    stack = issue15_metal()
    numba.set_num_threads(1)
    l = light_direction(30.0, 0.0)
    if args.check:
        return check(stack, l, args.rays, args.lanes, args.variant)
    trace_batched(stack, l, 1000, 0, 90, 360, lanes=args.lanes, variant=args.variant)
    c0 = time.process_time()
    *_, events = trace_batched(stack, l, args.rays, 0, 90, 360, lanes=args.lanes, variant=args.variant)
    cpu = time.process_time() - c0
    print(f"batched[{args.variant}, L={args.lanes}] {args.rays / cpu / 1e6:.3f} M rays/CPU-s, "
          f"{events / args.rays:.3f} events/ray")
    return 0


if __name__ == "__main__":
    sys.exit(main())
