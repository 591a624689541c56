"""The numba-parallel path-tracing kernel of the virtual goniometer.

Transport (``docs/material-format.md``, transport): a path starts above the top interface travelling along ``-l``
with weight (1, 1, 1). At an interface a microfacet normal is sampled from the visible
normals of the side the path comes from; a dielectric reflects with probability F (exact
Fresnel) and refracts otherwise, a conductor always reflects with weight *= F (RGB).
The weight is then multiplied by the masking term (separable: ``G1(o)``; height-correlated:
``G2 / G1(i)``) and an outgoing direction on the wrong side of the macro-surface ends the path
(``masking_loss``). On a multiple-scattering interface the event is instead a random walk on the
microsurface (:func:`goniometer.kernel.steps.microsurface_walk`, Heitz et al. 2016) that always leaves it: no masking loss. Absorbing media attenuate deterministically (Beer-Lambert); in a scattering
medium the path makes free flights between collisions (:func:`goniometer.kernel.steps.free_flight`: spectral-MIS
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

Kernel (``docs/kernel.md``): a chunk's paths run in :data:`~goniometer.kernel.layout.LANES`
lanes advanced in lock-step; each step is one vectorised event for every lane
(:mod:`goniometer.kernel.event`), then a pass over the lanes that runs per-lane steps (free
flights, microsurface walks: :mod:`goniometer.kernel.steps`), books the paths that ended and
gives their lanes the next path of the chunk. Every path draws its own random numbers, keyed by
(seed, incident index, chunk, path) (:mod:`goniometer.rng`), so neither the lane a path runs in
nor the number of threads changes a result. Kernel inputs are flat arrays (see
:class:`goniometer.stack.PackedStack`); outputs are per-chunk histograms.
"""

from __future__ import annotations

import numba
import numpy as np

from goniometer import optics
from goniometer.halfdiff import cell_of as halfdiff_cell
from goniometer.kernel.codegen import u64_as_double
from goniometer.kernel.deposit import BUFFER, X_COLS, flush
from goniometer.kernel.event import RR_START, RR_THRESHOLD, events
from goniometer.kernel.layout import (C_CAPPED, C_EVENTS, E_ABSORBED, E_CAPPED, E_MASKING, E_REFLECTED,
                                      E_REFLECTED_WITHOUT_BASE, E_ROULETTE, E_TRANSMITTED, N_COUNTS, N_ENERGY,
                                      N_ENERGY_SQ, P_TABULATE, F_AB0, F_AB1, F_AB2, F_BASED, F_CTR, F_DX, F_DY, F_DZ, F_EV, F_HERO, F_HPOS,
                                      F_KEY, F_LX, F_LY, F_LZ, F_MK0, F_MK1, F_MK2, F_ORDER, F_PATH, F_Q0, F_Q1,
                                      F_Q2, F_REG, F_RL0, F_RL1, F_RL2, F_STATUS, F_W0, F_W1, F_W2,
                                      LANES, N_FIELDS, N_RESET, ST_ALIVE, ST_CAPPED, ST_DEAD, ST_REFLECTED,
                                      ST_SCALAR, ST_TRANSMITTED, T_MS, TAU_SCATTER, stack_table, tau_modes)
from goniometer.kernel.paths import trace_paths
from goniometer.kernel.steps import free_flight, lane_steps, microsurface_walk
from goniometer.rng import chunk_key, draw, path_key, stream_state, uniform_pair

__all__ = ["trace_batch", "trace_batch_serial", "trace_chunk", "microsurface_walk", "free_flight",
           "E_REFLECTED", "E_TRANSMITTED", "E_ABSORBED", "E_MASKING", "E_REFLECTED_WITHOUT_BASE", "E_ROULETTE",
           "E_CAPPED", "N_ENERGY", "N_ENERGY_SQ", "C_CAPPED", "C_EVENTS", "N_COUNTS", "RR_START", "RR_THRESHOLD",
           "EVENT_CAP", "P_TABULATE", "TAU_SCATTER", "KERNEL_AUTO", "KERNEL_LANES", "KERNEL_PATHS", "lane_kernel_for"]

#: default hard cap on the number of events of one path (reported if ever reached)
EVENT_CAP = 10_000
#: ``kernel`` of :func:`trace_batch`: the kernel :func:`lane_kernel_for` picks for the stack, the
#: lane kernel (:func:`trace_chunk`) or the per-path kernel (:func:`goniometer.kernel.paths.trace_paths`)
KERNEL_AUTO = 0
KERNEL_LANES = 1
KERNEL_PATHS = 2

_THIRD = 1.0 / 3.0


@numba.njit(cache=True)
def lane_kernel_for(if_ms, region_tau, region_albedo) -> bool:
    """True when the lane kernel traces the stack (``KERNEL_AUTO``): no scattering medium and no
    multiple-scattering interface, so that every event is the vectorised one. Stacks with either
    go to the per-path kernel, for which their per-lane steps would cost more in moving lane
    state than the vectorised interface events save (``docs/kernel.md``, two kernels)."""
    for m in tau_modes(region_tau, region_albedo):
        if m >= TAU_SCATTER:
            return False
    for k in range(if_ms.shape[0]):
        if if_ms[k]:
            return False
    return True


@numba.njit(cache=True, inline="always")
def _acc(s0, s1, s2, q0, q1, q2, x0, x1, x2):
    """Running sums and sums of squares of three channels, plus ``x``."""
    return s0 + x0, s1 + x1, s2 + x2, q0 + x0 * x0, q1 + x1 * x1, q2 + x2 * x2


@numba.njit(cache=True, error_model='numpy', inline='always')
def _start_path(S, i, fresh, ckey, path, tabulate, first_status, exit_cell):
    """Give lane ``i`` path ``path`` of the chunk: the fresh-path fields of ``fresh``, its key and
    index; a tabulation draws its light direction with density ``cos theta_l / pi`` (draw 0)."""
    for f in range(N_RESET):
        S[f * LANES + i] = fresh[f]
    key = path_key(ckey, np.uint64(path))
    S[F_KEY * LANES + i] = u64_as_double(key)
    S[F_PATH * LANES + i] = float(path)
    S[F_STATUS * LANES + i] = float(first_status)
    if tabulate:
        u1, u2 = uniform_pair(draw(key, np.uint64(0)))
        cp, sp = optics.cos_sin_2pi(u1)
        r = np.sqrt(u2)
        lz = np.sqrt(max(0.0, 1.0 - u2))
        S[F_LX * LANES + i] = r * cp
        S[F_LY * LANES + i] = r * sp
        S[F_LZ * LANES + i] = lz
        S[F_DX * LANES + i] = -r * cp
        S[F_DY * LANES + i] = -r * sp
        S[F_DZ * LANES + i] = -lz
        exit_cell[path] = -1


@numba.njit(cache=True, error_model='numpy', inline='always')
def _move_lane(S, dst, src):
    """Copy every field of lane ``src`` into lane ``dst``."""
    for f in range(N_FIELDS):
        S[f * LANES + dst] = S[f * LANES + src]


@numba.njit(cache=True, error_model='numpy')
def trace_chunk(if_alpha, if_rot, if_ms, region_eta, region_tau, region_albedo, region_g, cond, rho, base_kind,
                lx, ly, lz, n_rays, ckey, param, n_theta, n_phi, row_cos, col_cos, col_sin, max_order,
                height_correlated, event_cap, brdf, btdf, energy, energy_sq, counts, exit_cell, exit_w):
    """Trace the ``n_rays`` paths of the chunk keyed ``ckey`` (:func:`goniometer.rng.chunk_key`)
    for light direction ``l`` and accumulate into the given arrays.

    ``param`` is the slice parametrization (:data:`goniometer.slices.CLASSIC`, ``HALF``) or
    :data:`P_TABULATE`: then path ``r`` first draws its own light direction ``l`` with density
    ``cos theta_l / pi``, and its reflected exit, if any, is written to ``exit_cell[r]`` (MERL
    cell, -1 if none) and ``exit_w[r]`` (weight) instead of to ``brdf``; transmitted exits are
    booked in ``energy`` only. Otherwise ``exit_cell``/``exit_w`` are not touched (they may be empty).

    ``brdf``/``btdf``: (n_theta, n_phi, K + 2, 3) (:mod:`goniometer.kernel.deposit`); ``energy``:
    (N_ENERGY, 3) weight sums; ``energy_sq``: (N_ENERGY_SQ, 3) sums of squared per-path totals;
    ``counts``: (N_COUNTS,) int64.
    """
    n_if = region_eta.shape[0] - 1
    transmit_base = base_kind == 0
    conductor_base = base_kind == 1
    lambertian = base_kind == 2
    tabulate = param == P_TABULATE
    tau_mode = tau_modes(region_tau, region_albedo)
    n_k = max(n_if, 1)
    eta_dn = np.ones(n_k)
    eta_up = np.ones(n_k)
    for k in range(n_if):
        eta_dn[k] = region_eta[k + 1] / region_eta[k]
        eta_up[k] = 1.0 / eta_dn[k]
    table, off = stack_table(if_alpha, if_rot, if_ms, eta_dn, eta_up, region_tau, tau_mode, n_if, conductor_base)
    # conductor channels that share their complex index share their Fresnel value (walks)
    g_is_r = cond[1] == cond[0] and cond[4] == cond[3]
    b_is_g = cond[2] == cond[1] and cond[5] == cond[4]
    # the interface that is the base (the bottom layer), -1 when the base is Lambertian
    base_k = -1 if lambertian else n_if - 1
    # a new path's first action: the top interface from above (a walk if it scatters multiply)
    first_status = ST_SCALAR if (n_if > 0 and table[T_MS] != 0.0) else ST_ALIVE
    fresh = np.zeros(N_RESET)
    fresh[F_DX] = -lx
    fresh[F_DY] = -ly
    fresh[F_DZ] = -lz
    fresh[F_W0] = 1.0
    fresh[F_W1] = 1.0
    fresh[F_W2] = 1.0
    fresh[F_CTR] = 1.0
    fresh[F_HERO] = -1.0
    fresh[F_Q0] = _THIRD
    fresh[F_Q1] = _THIRD
    fresh[F_Q2] = _THIRD
    fresh[F_HPOS] = -1.0
    S = np.zeros(N_FIELDS * LANES)
    xs = np.zeros(4, dtype=np.uint64)
    xbuf = np.empty((BUFFER, X_COLS))
    cell = np.empty(BUFFER, dtype=np.int64)
    sqo = np.empty(BUFFER, dtype=np.int64)
    ce0, ce1, ce2, ck0, ck1, ck2 = cond[0], cond[1], cond[2], cond[3], cond[4], cond[5]
    rho0, rho1, rho2 = rho[0], rho[1], rho[2]
    # the chunk's energy sums (locals: array elements would be reloaded after every store)
    re0 = re1 = re2 = req0 = req1 = req2 = 0.0
    rb0 = rb1 = rb2 = rbq0 = rbq1 = rbq2 = 0.0
    tr0 = tr1 = tr2 = trq0 = trq1 = trq2 = 0.0
    ab0 = ab1 = ab2 = abq0 = abq1 = abq2 = 0.0
    mk0 = mk1 = mk2 = mkq0 = mkq1 = mkq2 = 0.0
    rl0 = rl1 = rl2 = 0.0
    cp0 = cp1 = cp2 = 0.0
    n_capped = 0
    n_events = 0
    n_exit = 0
    next_path = 0
    n = min(LANES, n_rays)
    for i in range(n):
        _start_path(S, i, fresh, ckey, next_path, tabulate, first_status, exit_cell)
        next_path += 1
    while True:
        # ---- per-lane pass: steps, then ended paths booked and replaced (or their lanes compacted);
        # afterwards every lane's next action is the vectorised event
        i = 0
        while i < n:
            st = int(S[F_STATUS * LANES + i])
            if st == ST_SCALAR:
                st = lane_steps(S, i, xs, if_alpha, if_rot, eta_dn, eta_up, region_tau, region_albedo, region_g,
                                tau_mode, table, cond, g_is_r, b_is_g, n_if, transmit_base, conductor_base, base_k,
                                event_cap)
                S[F_STATUS * LANES + i] = float(st)
            if st == ST_ALIVE:
                i += 1
                continue
            w0 = S[F_W0 * LANES + i]
            w1 = S[F_W1 * LANES + i]
            w2 = S[F_W2 * LANES + i]
            rl0 += S[F_RL0 * LANES + i]
            rl1 += S[F_RL1 * LANES + i]
            rl2 += S[F_RL2 * LANES + i]
            if st == ST_DEAD:
                rl0 += w0
                rl1 += w1
                rl2 += w2
            elif st == ST_CAPPED:
                cp0 += w0
                cp1 += w1
                cp2 += w2
                n_capped += 1
            else:
                order_row = min(int(S[F_ORDER * LANES + i]), max_order) - 1
                if st == ST_REFLECTED:
                    re0, re1, re2, req0, req1, req2 = _acc(re0, re1, re2, req0, req1, req2, w0, w1, w2)
                    if S[F_BASED * LANES + i] == 0.0:
                        rb0, rb1, rb2, rbq0, rbq1, rbq2 = _acc(rb0, rb1, rb2, rbq0, rbq1, rbq2, w0, w1, w2)
                else:
                    tr0, tr1, tr2, trq0, trq1, trq2 = _acc(tr0, tr1, tr2, trq0, trq1, trq2, w0, w1, w2)
                if tabulate:
                    if st == ST_REFLECTED:
                        path = int(S[F_PATH * LANES + i])
                        exit_cell[path] = halfdiff_cell(S[F_LX * LANES + i], S[F_LY * LANES + i],
                                                        S[F_LZ * LANES + i], S[F_DX * LANES + i],
                                                        S[F_DY * LANES + i], S[F_DZ * LANES + i])
                        exit_w[path, 0] = w0
                        exit_w[path, 1] = w1
                        exit_w[path, 2] = w2
                else:
                    xbuf[n_exit, 0] = S[F_DX * LANES + i]
                    xbuf[n_exit, 1] = S[F_DY * LANES + i]
                    xbuf[n_exit, 2] = S[F_DZ * LANES + i]
                    xbuf[n_exit, 3] = w0
                    xbuf[n_exit, 4] = w1
                    xbuf[n_exit, 5] = w2
                    xbuf[n_exit, 6] = float(order_row)
                    xbuf[n_exit, 7] = 1.0 if st == ST_TRANSMITTED else 0.0
                    n_exit += 1
                    if n_exit == BUFFER:
                        flush(xbuf, n_exit, cell, sqo, param, lx, ly, lz, n_theta, n_phi, row_cos, col_cos, col_sin,
                              max_order, brdf, btdf)
                        n_exit = 0
            a0 = S[F_AB0 * LANES + i]
            a1 = S[F_AB1 * LANES + i]
            a2 = S[F_AB2 * LANES + i]
            ab0, ab1, ab2, abq0, abq1, abq2 = _acc(ab0, ab1, ab2, abq0, abq1, abq2, a0, a1, a2)
            m0 = S[F_MK0 * LANES + i]
            m1 = S[F_MK1 * LANES + i]
            m2 = S[F_MK2 * LANES + i]
            mk0, mk1, mk2, mkq0, mkq1, mkq2 = _acc(mk0, mk1, mk2, mkq0, mkq1, mkq2, m0, m1, m2)
            n_events += int(S[F_EV * LANES + i])
            if next_path < n_rays:
                _start_path(S, i, fresh, ckey, next_path, tabulate, first_status, exit_cell)
                next_path += 1
                # not advanced when the new path starts with per-lane steps: they run next
                if first_status == ST_ALIVE:
                    i += 1
            else:
                # stream compaction: the last active lane moves into this one (and is looked at next)
                n -= 1
                if i < n:
                    _move_lane(S, i, n)
        if n == 0:
            break
        # ---- one vectorised event for every lane
        if height_correlated:
            events(n, S, table, off, n_if, lambertian, transmit_base, conductor_base, base_k, ce0, ce1, ce2, ck0,
                   ck1, ck2, rho0, rho1, rho2, event_cap, True)
        else:
            events(n, S, table, off, n_if, lambertian, transmit_base, conductor_base, base_k, ce0, ce1, ce2, ck0,
                   ck1, ck2, rho0, rho1, rho2, event_cap, None)
    if n_exit > 0:
        flush(xbuf, n_exit, cell, sqo, param, lx, ly, lz, n_theta, n_phi, row_cos, col_cos, col_sin, max_order,
              brdf, btdf)
    energy[E_REFLECTED, 0] += re0
    energy[E_REFLECTED, 1] += re1
    energy[E_REFLECTED, 2] += re2
    energy_sq[E_REFLECTED, 0] += req0
    energy_sq[E_REFLECTED, 1] += req1
    energy_sq[E_REFLECTED, 2] += req2
    energy[E_REFLECTED_WITHOUT_BASE, 0] += rb0
    energy[E_REFLECTED_WITHOUT_BASE, 1] += rb1
    energy[E_REFLECTED_WITHOUT_BASE, 2] += rb2
    energy_sq[E_REFLECTED_WITHOUT_BASE, 0] += rbq0
    energy_sq[E_REFLECTED_WITHOUT_BASE, 1] += rbq1
    energy_sq[E_REFLECTED_WITHOUT_BASE, 2] += rbq2
    energy[E_TRANSMITTED, 0] += tr0
    energy[E_TRANSMITTED, 1] += tr1
    energy[E_TRANSMITTED, 2] += tr2
    energy_sq[E_TRANSMITTED, 0] += trq0
    energy_sq[E_TRANSMITTED, 1] += trq1
    energy_sq[E_TRANSMITTED, 2] += trq2
    energy[E_ABSORBED, 0] += ab0
    energy[E_ABSORBED, 1] += ab1
    energy[E_ABSORBED, 2] += ab2
    energy_sq[E_ABSORBED, 0] += abq0
    energy_sq[E_ABSORBED, 1] += abq1
    energy_sq[E_ABSORBED, 2] += abq2
    energy[E_MASKING, 0] += mk0
    energy[E_MASKING, 1] += mk1
    energy[E_MASKING, 2] += mk2
    energy_sq[E_MASKING, 0] += mkq0
    energy_sq[E_MASKING, 1] += mkq1
    energy_sq[E_MASKING, 2] += mkq2
    energy[E_ROULETTE, 0] += rl0
    energy[E_ROULETTE, 1] += rl1
    energy[E_ROULETTE, 2] += rl2
    energy[E_CAPPED, 0] += cp0
    energy[E_CAPPED, 1] += cp1
    energy[E_CAPPED, 2] += cp2
    counts[C_CAPPED] += n_capped
    counts[C_EVENTS] += n_events


@numba.njit(cache=True, error_model='numpy')
def trace_slot(b, if_alpha, if_rot, if_ms, region_eta, region_tau, region_albedo, region_g, cond, rho, base_kind,
               lx, ly, lz, n_rays_total, chunk_rays, first_chunk, seed, incident_index,
               param, n_theta, n_phi, row_cos, col_cos, col_sin, max_order, height_correlated, event_cap,
               kernel, brdf, btdf, energy, energy_sq, counts, exit_cell, exit_w):
    """Zero histogram slot ``b`` and trace chunk ``first_chunk + b`` into it (``exit_cell[b]``,
    ``exit_w[b]``: see :func:`trace_chunk`).

    Chunk ``c`` covers rays ``[c * chunk_rays, min((c + 1) * chunk_rays, n_rays_total))`` and
    is keyed by ``(seed, incident_index, c)``: its paths' keys (:func:`goniometer.rng.chunk_key`)
    for the lane kernel, its random stream (:func:`goniometer.rng.stream_state`) for the per-path
    kernel; ``kernel`` one of ``KERNEL_*``.
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
    lanes = kernel == KERNEL_LANES or (kernel == KERNEL_AUTO and lane_kernel_for(if_ms, region_tau, region_albedo))
    if not lanes:
        state = stream_state(np.uint64(seed), np.uint64(incident_index), np.uint64(c))
        trace_paths(if_alpha, if_rot, if_ms, region_eta, region_tau, region_albedo, region_g, cond, rho, base_kind,
                    lx, ly, lz, n, state, param, n_theta, n_phi, row_cos, col_cos, col_sin, max_order,
                    height_correlated, event_cap, brdf[b], btdf[b], energy[b], energy_sq[b], counts[b], exit_cell[b],
                    exit_w[b])
        return
    ckey = chunk_key(np.uint64(seed), np.uint64(incident_index), np.uint64(c))
    trace_chunk(if_alpha, if_rot, if_ms, region_eta, region_tau, region_albedo, region_g, cond, rho, base_kind,
                lx, ly, lz, n, ckey, param, n_theta, n_phi, row_cos, col_cos, col_sin, max_order,
                height_correlated, event_cap, brdf[b], btdf[b], energy[b], energy_sq[b], counts[b], exit_cell[b],
                exit_w[b])


@numba.njit(parallel=True, cache=True, error_model='numpy')
def trace_batch(if_alpha, if_rot, if_ms, region_eta, region_tau, region_albedo, region_g, cond, rho, base_kind,
                lx, ly, lz, n_rays_total, chunk_rays, first_chunk, seed, incident_index,
                param, n_theta, n_phi, row_cos, col_cos, col_sin, max_order, height_correlated, event_cap,
                kernel, brdf, btdf, energy, energy_sq, counts, exit_cell, exit_w):
    """Trace chunks ``first_chunk .. first_chunk + B - 1`` in parallel, one histogram slot each
    (:func:`trace_slot`). Output arrays carry a leading dimension B (the batch)."""
    for b in numba.prange(brdf.shape[0]):
        trace_slot(b, if_alpha, if_rot, if_ms, region_eta, region_tau, region_albedo, region_g, cond, rho, base_kind,
                   lx, ly, lz, n_rays_total, chunk_rays, first_chunk, seed, incident_index,
                   param, n_theta, n_phi, row_cos, col_cos, col_sin, max_order, height_correlated, event_cap,
                   kernel, brdf, btdf, energy, energy_sq, counts, exit_cell, exit_w)


@numba.njit(cache=True, error_model='numpy')
def trace_batch_serial(if_alpha, if_rot, if_ms, region_eta, region_tau, region_albedo, region_g, cond, rho, base_kind,
                       lx, ly, lz, n_rays_total, chunk_rays, first_chunk, seed, incident_index,
                       param, n_theta, n_phi, row_cos, col_cos, col_sin, max_order, height_correlated, event_cap,
                       kernel, brdf, btdf, energy, energy_sq, counts, exit_cell, exit_w):
    """:func:`trace_batch` without threads (same per-chunk results, bit for bit).

    For callers that are themselves run concurrently, e.g. the threads of a Dask worker: numba's
    default threading layer must not be entered by several threads at once.
    """
    for b in range(brdf.shape[0]):
        trace_slot(b, if_alpha, if_rot, if_ms, region_eta, region_tau, region_albedo, region_g, cond, rho, base_kind,
                   lx, ly, lz, n_rays_total, chunk_rays, first_chunk, seed, incident_index,
                   param, n_theta, n_phi, row_cos, col_cos, col_sin, max_order, height_correlated, event_cap,
                   kernel, brdf, btdf, energy, energy_sq, counts, exit_cell, exit_w)
