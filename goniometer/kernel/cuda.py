"""The CUDA kernel (``docs/gpu.md``): one GPU thread per path, through numba-cuda.

Each thread traces one path with :func:`goniometer.kernel.onepath.trace_path` -- the per-path
transport, compiled for the device from the same Python source as the CPU's (numba-cuda compiles
the ``numba.njit`` functions a kernel calls: the optics, the walks, the free flights, the cell
lookup) -- seeded from the path's own key, so a path draws the same numbers on any device, in any
thread. The grid is two-dimensional: ``blockIdx.y`` is the chunk slot, ``blockIdx.x * blockDim.x +
threadIdx.x`` the path in the chunk.

Sums are 64-bit integers: a weight ``w`` adds ``round(w * 2^32)``
(:func:`goniometer.kernel.onepath.fixed_point`) with integer atomics, which commute, so a run's
sums do not depend on the order in which threads finish, nor on the block size: they are the same
bits on every launch on the same device and compiler. A block first sums into its shared memory
(the energies always; the histograms when the grid's two histograms fit,
:data:`SHARED_BYTES`), then adds what it holds to global memory; otherwise it adds to global
memory directly. The integers are turned into float64 at the end (``/ 2^32``).

This module imports ``numba.cuda``; :func:`goniometer.kernel.tracer.check_device` says why a run cannot
use it (no numba-cuda, no GPU) before anything imports it. Under numba-cuda's simulator
(``NUMBA_ENABLE_CUDASIM=1``, set before ``numba.cuda`` is first imported) the kernel runs as Python
threads calling the CPU's compiled functions: the tests' way to run it without a GPU.
"""

from __future__ import annotations

import numpy as np
from numba import config, cuda, int64, uint64

from goniometer.kernel.layout import (C_CAPPED, C_EVENTS, E_ABSORBED, E_CAPPED, E_MASKING, E_REFLECTED,
                                      E_REFLECTED_WITHOUT_BASE, E_ROULETTE, E_TRANSMITTED, N_COUNTS, N_ENERGY,
                                      N_ENERGY_SQ, P_TABULATE)
from goniometer.kernel.onepath import FIXED_SCALE, X_NONE, X_REFLECTED, X_TRANSMITTED, fixed_point, path_state, trace_path
from goniometer.grids.halfdiff import cell_of as halfdiff_cell
from goniometer.grids.slice_grid import cell_index_fast

#: threads per block
BLOCK = 128
#: shared memory a block's histograms may take (the energies' few hundred bytes come on top)
SHARED_BYTES = 40_960
#: a block's energy sums: N_ENERGY x 3 weights, N_ENERGY_SQ x 3 squares, N_COUNTS counters
_N_EN = N_ENERGY * 3
_N_ENSQ = N_ENERGY_SQ * 3
_N_ACC = _N_EN + _N_ENSQ + N_COUNTS


if config.ENABLE_CUDASIM:
    def _plain(a):
        """In the simulator a kernel's array argument is a wrapper that the CPU's compiled functions
        cannot take: its numpy array."""
        return a._item._ary
else:
    @cuda.jit(device=True, inline=True)
    def _plain(a):
        """On the device an array argument is what the compiled functions take."""
        return a


@cuda.jit(device=True, inline=True)
def _add(a, i, v):
    """``a[i] += v`` with an atomic add (``a``: int64)."""
    if v != 0:
        cuda.atomic.add(a, i, v)


@cuda.jit(device=True, inline=True)
def _deposit(h, base, o, max_order, w0, w1, w2):
    """One exit into the histogram ``h`` (flat, int64) at cell offset ``base``: order row ``o``,
    the squares' row ``max_order`` and, for an internal exit, ``max_order + 1``."""
    _add(h, base + o * 3, fixed_point(w0))
    _add(h, base + o * 3 + 1, fixed_point(w1))
    _add(h, base + o * 3 + 2, fixed_point(w2))
    s0 = fixed_point(w0 * w0)
    s1 = fixed_point(w1 * w1)
    s2 = fixed_point(w2 * w2)
    _add(h, base + max_order * 3, s0)
    _add(h, base + max_order * 3 + 1, s1)
    _add(h, base + max_order * 3 + 2, s2)
    if o > 0:
        _add(h, base + max_order * 3 + 3, s0)
        _add(h, base + max_order * 3 + 4, s1)
        _add(h, base + max_order * 3 + 5, s2)


@cuda.jit(device=True, inline=True)
def _book(acc, row, x0, x1, x2, squares):
    """A path's amounts into a block's energy sums (and their squares where the row has them)."""
    _add(acc, row * 3, fixed_point(x0))
    _add(acc, row * 3 + 1, fixed_point(x1))
    _add(acc, row * 3 + 2, fixed_point(x2))
    if squares:
        _add(acc, _N_EN + row * 3, fixed_point(x0 * x0))
        _add(acc, _N_EN + row * 3 + 1, fixed_point(x1 * x1))
        _add(acc, _N_EN + row * 3 + 2, fixed_point(x2 * x2))


@cuda.jit
def _trace_kernel(if_alpha, if_rot, if_ms, if_film, region_tau, region_albedo, region_g, cond, rho, base_kind, tau_mode,
                  eta_dn, eta_up, lx, ly, lz, n_rays_total, chunk_rays, first_chunk, seed, stream, param, n_theta, n_phi,
                  row_cos, col_cos, col_sin, max_order, event_cap, skip_first, height_correlated, shared_hist, hist,
                  acc_g, exit_cell, exit_w):
    """Trace the paths of a batch of chunks (module docstring). ``hist``: (B, 2 * cells * row)
    int64, the BRDF then the BTDF of each slot, flat; ``acc_g``: (B, _N_ACC) int64 energy sums;
    ``exit_cell`` / ``exit_w``: per path of a tabulation ((B, 0) otherwise). ``shared_hist``: the
    block sums its histograms in dynamic shared memory before adding them to ``hist``."""
    b = cuda.blockIdx.y
    tid = cuda.threadIdx.x
    r = cuda.blockIdx.x * cuda.blockDim.x + tid
    c = first_chunk + b
    n = min(chunk_rays, n_rays_total - c * chunk_rays)
    n_hist = hist.shape[1]
    sh = cuda.shared.array(0, dtype=int64)        # shared_hist: the block's histograms
    acc = cuda.shared.array(_N_ACC, dtype=int64)  # the block's energy sums
    for q in range(tid, _N_ACC, cuda.blockDim.x):
        acc[q] = int64(0)
    if shared_hist:
        for q in range(tid, n_hist, cuda.blockDim.x):
            sh[q] = int64(0)
    cuda.syncthreads()
    if r < n:
        if_alpha = _plain(if_alpha)
        if_rot = _plain(if_rot)
        if_ms = _plain(if_ms)
        if_film = _plain(if_film)
        region_tau = _plain(region_tau)
        region_albedo = _plain(region_albedo)
        region_g = _plain(region_g)
        cond = _plain(cond)
        rho = _plain(rho)
        tau_mode = _plain(tau_mode)
        eta_dn = _plain(eta_dn)
        eta_up = _plain(eta_up)
        row_cos = _plain(row_cos)
        col_cos = _plain(col_cos)
        col_sin = _plain(col_sin)
        state = cuda.local.array(4, dtype=uint64)
        path_state(state, seed, stream, c, r)
        tabulate = param == P_TABULATE
        (kind, plx, ply, plz, dx, dy, dz, w0, w1, w2, order, single, based, ab0, ab1, ab2, mk0, mk1, mk2,
         rl0, rl1, rl2, cp0, cp1, cp2, capped, events) = trace_path(
            if_alpha, if_rot, if_ms, if_film, region_tau, region_albedo, region_g, cond, rho, base_kind, tau_mode,
            eta_dn, eta_up, lx, ly, lz, tabulate, height_correlated, event_cap, state)
        if tabulate:
            exit_cell[b, r] = -1
            if kind == X_REFLECTED:
                exit_cell[b, r] = halfdiff_cell(plx, ply, plz, dx, dy, dz)
                exit_w[b, r, 0] = w0
                exit_w[b, r, 1] = w1
                exit_w[b, r, 2] = w2
        elif kind != X_NONE and not (skip_first and kind == X_REFLECTED and order == 1 and single):
            trans = kind == X_TRANSMITTED
            i, j = cell_index_fast(param, trans, lx, ly, lz, dx, dy, dz, n_theta, n_phi, row_cos, col_cos, col_sin)
            if i >= 0:
                row = (max_order + 2) * 3
                base = (i * n_phi + j) * row + (n_hist // 2 if trans else 0)
                o = min(order, max_order) - 1
                if shared_hist:
                    _deposit(sh, base, o, max_order, w0, w1, w2)
                else:
                    _deposit(hist[b], base, o, max_order, w0, w1, w2)
        refl = kind == X_REFLECTED
        if refl:
            _book(acc, E_REFLECTED, w0, w1, w2, True)
            if not based:
                _book(acc, E_REFLECTED_WITHOUT_BASE, w0, w1, w2, True)
        if kind == X_TRANSMITTED:
            _book(acc, E_TRANSMITTED, w0, w1, w2, True)
        _book(acc, E_ABSORBED, ab0, ab1, ab2, True)
        _book(acc, E_MASKING, mk0, mk1, mk2, True)
        _book(acc, E_ROULETTE, rl0, rl1, rl2, False)
        _book(acc, E_CAPPED, cp0, cp1, cp2, False)
        _add(acc, _N_EN + _N_ENSQ + C_CAPPED, capped)
        _add(acc, _N_EN + _N_ENSQ + C_EVENTS, events)
    cuda.syncthreads()
    # the block's sums into the slot's (integer additions: in any order the same)
    for q in range(tid, _N_ACC, cuda.blockDim.x):
        if acc[q] != 0:
            cuda.atomic.add(acc_g, (b, q), acc[q])
    if shared_hist:
        for q in range(tid, n_hist, cuda.blockDim.x):
            if sh[q] != 0:
                cuda.atomic.add(hist, (b, q), sh[q])


def trace_batch(run, first_chunk: int, outs: tuple, exits: tuple) -> None:
    """Trace chunks ``first_chunk .. first_chunk + B - 1`` of ``run`` (a
    :class:`goniometer.kernel.tracer.Launch`) on the GPU into the CPU arrays ``outs`` / ``exits``, as
    :func:`goniometer.kernel.tracer.launch` documents (each slot's sums are the integers' values)."""
    brdf, btdf, energy, energy_sq, counts = outs
    exit_cell, exit_w = exits
    B = brdf.shape[0]
    if B == 0:
        return
    f = run.facts
    p = f.packed
    nb = brdf[0].size
    transmits = btdf.shape[1:] == brdf.shape[1:]
    n_hist = 2 * nb
    shared_hist = n_hist * 8 <= SHARED_BYTES
    d = cuda.to_device
    hist = cuda.to_device(np.zeros((B, n_hist), dtype=np.int64))
    acc = cuda.to_device(np.zeros((B, _N_ACC), dtype=np.int64))
    tabulate = run.param == P_TABULATE
    ec = d(np.full(exit_cell.shape, -1, dtype=np.int64) if tabulate else np.zeros((B, 0), dtype=np.int64))
    ew = d(np.zeros(exit_w.shape) if tabulate else np.zeros((B, 0, 3)))
    row_cos, col_cos, col_sin = (np.ascontiguousarray(t, dtype=np.float64) for t in run.tables)
    blocks = (max(1, -(-run.chunk_rays // BLOCK)), B)
    dyn = n_hist * 8 if shared_hist else 0
    _trace_kernel[blocks, BLOCK, 0, dyn](
        d(p.if_alpha), d(p.if_rot), d(p.if_ms), d(p.if_film), d(p.region_tau), d(p.region_albedo), d(p.region_g),
        d(p.cond), d(p.rho), int(p.base_kind), d(f.tau_mode), d(f.eta_dn), d(f.eta_up), *run.light, run.n_rays,
        run.chunk_rays, first_chunk, run.seed, run.stream, run.param, run.n_theta, run.n_phi, d(row_cos), d(col_cos),
        d(col_sin), run.max_order, run.event_cap, run.skip_first, run.flags[1] is not None, shared_hist, hist, acc,
        ec, ew)
    h = hist.copy_to_host().astype(np.float64) / FIXED_SCALE
    a = acc.copy_to_host()
    brdf[...] = h[:, :nb].reshape(brdf.shape)
    if transmits:
        btdf[...] = h[:, nb:].reshape(btdf.shape)
    else:
        btdf[...] = 0.0
    energy[...] = (a[:, :_N_EN].astype(np.float64) / FIXED_SCALE).reshape(energy.shape)
    energy_sq[...] = (a[:, _N_EN:_N_EN + _N_ENSQ].astype(np.float64) / FIXED_SCALE).reshape(energy_sq.shape)
    counts[...] = a[:, _N_EN + _N_ENSQ:]
    if tabulate:
        exit_cell[...] = ec.copy_to_host()
        exit_w[...] = ew.copy_to_host()
