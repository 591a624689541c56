"""The CUDA kernel (``docs/gpu.md``): one GPU thread per path, through numba-cuda.

Each thread traces one path with :func:`goniometer.kernel.onepath.trace_path` -- the per-path
transport, the CPU per-path kernel's too (:mod:`goniometer.kernel.paths`): numba-cuda compiles the
``numba.njit`` functions a kernel calls for the device from the same Python source (the optics,
the walks, the free flights, the cell lookup) -- seeded from the path's own key, so a path draws
the same numbers on any device, in any thread, and on the CPU's per-path kernel. The grid is
two-dimensional: ``blockIdx.y`` is the chunk slot, ``blockIdx.x * blockDim.x + threadIdx.x`` the
path in the chunk.

Sums are 64-bit integers: a weight ``w`` adds ``round(w * 2^32)`` (:func:`fixed_point`) with
integer atomics, which commute, so a run's sums do not depend on the order in which threads
finish, nor on the block size: they are the same bits on every launch on the same device and
compiler. A block first sums into its shared memory (the energies always; the histograms when the
grid's two histograms fit, :data:`SHARED_BYTES`), then adds what it holds to global memory;
otherwise it adds to global memory directly. The integers are turned into float64 at the end
(``/ 2^32``).

The kernel is compiled for :data:`BLOCK` threads per block and at least :data:`MIN_BLOCKS` blocks
per multiprocessor (its launch bounds, :data:`KERNEL_OPTIONS`): ptxas then keeps a thread's
registers within ``65536 / (BLOCK * MIN_BLOCKS)`` = 128, and
``tests/goniometer/kernel/test_cuda_compile.py`` checks, without a GPU, that it compiles for sm_80
and sm_90 without spilling (:mod:`goniometer.kernel.cuda_build`).

This module imports ``numba.cuda``; :func:`goniometer.kernel.tracer.check_device` says why a run cannot
use it (no numba-cuda, no GPU) before anything imports it. Under numba-cuda's simulator
(``NUMBA_ENABLE_CUDASIM=1``, set before ``numba.cuda`` is first imported) the kernel runs as Python
threads calling the CPU's compiled functions: the tests' way to run it without a GPU.
"""

from __future__ import annotations

import math

import numpy as np
from numba import config, cuda, float64, int64, uint64

from goniometer.grids.halfdiff import cell_of as halfdiff_cell
from goniometer.grids.slice_grid import cell_index_fast
from goniometer.kernel.layout import (C_CAPPED, C_EVENTS, E_ABSORBED, E_CAPPED, E_MASKING, E_REFLECTED,
                                      E_REFLECTED_WITHOUT_BASE, E_ROULETTE, E_TRANSMITTED, N_COUNTS, N_ENERGY,
                                      N_ENERGY_SQ, P_TABULATE)
from goniometer.kernel.onepath import (B_ABSORBED, B_MASKING, B_ROULETTE, N_BOOKS, X_CAPPED, X_REFLECTED,
                                       X_TRANSMITTED, path_light, trace_path)
from goniometer.kernel.rng import path_state

#: threads per block
BLOCK = 128
#: blocks per multiprocessor the kernel is compiled to fit (launch bounds; module docstring)
MIN_BLOCKS = 4
#: the kernel's compile options: its launch bounds (the most threads per block, the fewest blocks
#: per multiprocessor), which the compile check reads too
KERNEL_OPTIONS = {"launch_bounds": (BLOCK, MIN_BLOCKS)}
#: shared memory a block's histograms may take (the energies' few hundred bytes come on top)
SHARED_BYTES = 40_960
#: the CUDA kernel's sums are integers: a weight ``w`` adds ``round(w * FIXED_SCALE)`` (2^32), so the
#: order of the atomic additions cannot change a sum (``docs/gpu.md``, determinism)
FIXED_SCALE = 4294967296.0
#: a block's energy sums: N_ENERGY x 3 weights, N_ENERGY_SQ x 3 squares, N_COUNTS counters
_N_EN = N_ENERGY * 3
_N_ENSQ = N_ENERGY_SQ * 3
_N_ACC = _N_EN + _N_ENSQ + N_COUNTS


@cuda.jit(device=True, inline=True)
def fixed_point(w):
    """``w`` in the CUDA kernel's fixed point: the nearest integer to ``w * 2^32`` (ties upward)."""
    return int64(math.floor(w * FIXED_SCALE + 0.5))


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


def _kernel(stack, run, tables, sizes, height_correlated, shared_hist, hist, acc_g, exit_cell, exit_w):
    """Trace the paths of a batch of chunks (module docstring). ``stack``, ``run``, ``tables``,
    ``sizes``: the CPU kernels' arguments (:func:`goniometer.kernel.tracer.launch`);
    ``height_correlated``, ``shared_hist``: bools; ``hist``: (B, 2 * cells * row) int64, the BRDF
    then the BTDF of each slot, flat; ``acc_g``: (B, _N_ACC) int64 energy sums; ``exit_cell`` /
    ``exit_w``: per path of a tabulation ((B, 0) otherwise). With ``shared_hist`` the block sums
    its histograms in dynamic shared memory before adding them to ``hist``."""
    b = cuda.blockIdx.y
    tid = cuda.threadIdx.x
    r = cuda.blockIdx.x * cuda.blockDim.x + tid
    lx, ly, lz, first_chunk, seed, stream, param, n_theta, n_phi, max_order, event_cap, skip_first = run
    n_hist = hist.shape[1]
    sh = cuda.shared.array(0, dtype=int64)        # shared_hist: the block's histograms
    acc = cuda.shared.array(_N_ACC, dtype=int64)  # the block's energy sums
    for q in range(tid, _N_ACC, cuda.blockDim.x):
        acc[q] = int64(0)
    if shared_hist:
        for q in range(tid, n_hist, cuda.blockDim.x):
            sh[q] = int64(0)
    cuda.syncthreads()
    if r < sizes[b]:
        state = cuda.local.array(4, dtype=uint64)
        books = cuda.local.array(N_BOOKS, dtype=float64)
        for q in range(N_BOOKS):
            books[q] = 0.0
        path_state(state, seed, stream, first_chunk + b, r)
        tabulate = param == P_TABULATE
        plx, ply, plz = path_light(state, tabulate, lx, ly, lz)
        kind, dx, dy, dz, w0, w1, w2, order, single, based, events = trace_path(
            stack, -plx, -ply, -plz, height_correlated, event_cap, state, books)
        refl = kind == X_REFLECTED
        trans = kind == X_TRANSMITTED
        if tabulate:
            cell = -1
            if refl:
                # the path's light again, from its key (not kept through the path: registers)
                path_state(state, seed, stream, first_chunk + b, r)
                plx, ply, plz = path_light(state, True, lx, ly, lz)
                cell = halfdiff_cell(plx, ply, plz, dx, dy, dz)
                exit_w[b, r, 0] = w0
                exit_w[b, r, 1] = w1
                exit_w[b, r, 2] = w2
            exit_cell[b, r] = cell
        elif (refl and not (skip_first and order == 1 and single)) or trans:
            row_cos, col_cos, col_sin = tables
            i, j = cell_index_fast(param, trans, lx, ly, lz, dx, dy, dz, n_theta, n_phi, row_cos, col_cos, col_sin)
            if i >= 0:
                base = (i * n_phi + j) * (max_order + 2) * 3 + (n_hist // 2 if trans else 0)
                o = min(order, max_order) - 1
                if shared_hist:
                    _deposit(sh, base, o, max_order, w0, w1, w2)
                else:
                    _deposit(hist[b], base, o, max_order, w0, w1, w2)
        if refl:
            _book(acc, E_REFLECTED, w0, w1, w2, True)
            if not based:
                _book(acc, E_REFLECTED_WITHOUT_BASE, w0, w1, w2, True)
        elif trans:
            _book(acc, E_TRANSMITTED, w0, w1, w2, True)
        elif kind == X_CAPPED:
            _book(acc, E_CAPPED, w0, w1, w2, False)
            _add(acc, _N_EN + _N_ENSQ + C_CAPPED, int64(1))
        _book(acc, E_ABSORBED, books[B_ABSORBED], books[B_ABSORBED + 1], books[B_ABSORBED + 2], True)
        _book(acc, E_MASKING, books[B_MASKING], books[B_MASKING + 1], books[B_MASKING + 2], True)
        _book(acc, E_ROULETTE, books[B_ROULETTE], books[B_ROULETTE + 1], books[B_ROULETTE + 2], False)
        _add(acc, _N_EN + _N_ENSQ + C_EVENTS, int64(events))
    cuda.syncthreads()
    # the block's sums into the slot's (integer additions: in any order the same)
    for q in range(tid, _N_ACC, cuda.blockDim.x):
        if acc[q] != 0:
            cuda.atomic.add(acc_g, (b, q), acc[q])
    if shared_hist:
        for q in range(tid, n_hist, cuda.blockDim.x):
            if sh[q] != 0:
                cuda.atomic.add(hist, (b, q), sh[q])


#: the kernel as launched (its Python function is :func:`_kernel`, which the compile check compiles
#: with the same :data:`KERNEL_OPTIONS`)
_trace_kernel = cuda.jit(_kernel) if config.ENABLE_CUDASIM else cuda.jit(**KERNEL_OPTIONS)(_kernel)
# (the simulator runs Python threads: it has no registers, and takes no launch bounds)


def kernel_args(run, first_chunk: int, sizes: np.ndarray, B: int, hist_cells: int, exit_shape: tuple,
                to_device=None) -> tuple:
    """The CUDA kernel's arguments for a batch of ``B`` chunks of ``run`` (a
    :class:`goniometer.kernel.tracer.Launch`) starting at ``first_chunk``: ``hist_cells`` numbers per
    slot's two histograms, ``exit_shape`` the per-path records' ``(B, n)`` (``n`` 0 but for a
    tabulation). ``to_device`` (None: the arrays stay on the host, as the compile check types them)
    moves an array to the GPU. Returns ``(args, shared_hist, dynamic_shared_bytes)``."""
    dev = to_device if to_device is not None else (lambda a: a)
    keep = dev if not config.ENABLE_CUDASIM else (lambda a: a)   # the simulator's CPU functions read host arrays
    stack = type(run.stack_args)(*(keep(np.ascontiguousarray(x)) if isinstance(x, np.ndarray) else x
                                   for x in run.stack_args))
    tables = tuple(keep(np.ascontiguousarray(t, dtype=np.float64)) for t in run.tables)
    shared_hist = hist_cells * 8 <= SHARED_BYTES
    tabulate = run.param == P_TABULATE
    args = (stack, run.scalars(first_chunk), tables, dev(np.ascontiguousarray(sizes, dtype=np.int64)),
            run.variant.height_correlated is not None, shared_hist, dev(np.zeros((B, hist_cells), dtype=np.int64)),
            dev(np.zeros((B, _N_ACC), dtype=np.int64)),
            dev(np.full(exit_shape, -1, dtype=np.int64) if tabulate else np.zeros((B, 0), dtype=np.int64)),
            dev(np.zeros(exit_shape + (3,)) if tabulate else np.zeros((B, 0, 3))))
    return args, shared_hist, hist_cells * 8 if shared_hist else 0


def trace_batch(run, first_chunk: int, sizes: np.ndarray, outs: tuple, exits: tuple) -> None:
    """Trace chunks ``first_chunk .. first_chunk + B - 1`` of ``run`` (a
    :class:`goniometer.kernel.tracer.Launch`; ``sizes`` their rays, :meth:`Launch.chunk_sizes`) on the
    GPU into the CPU arrays ``outs`` / ``exits``, as :func:`goniometer.kernel.tracer.launch`
    documents (each slot's sums are the integers' values)."""
    brdf, btdf, energy, energy_sq, counts = outs
    exit_cell, exit_w = exits
    B = brdf.shape[0]
    if B == 0:
        return
    nb = brdf[0].size
    transmits = btdf.shape[1:] == brdf.shape[1:]
    args, _, dyn = kernel_args(run, first_chunk, sizes, B, 2 * nb, exit_cell.shape, cuda.to_device)
    blocks = (max(1, -(-run.chunk_rays // BLOCK)), B)
    _trace_kernel[blocks, BLOCK, 0, dyn](*args)
    hist, acc, ec, ew = args[6:]
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
    if run.param == P_TABULATE:
        exit_cell[...] = ec.copy_to_host()
        exit_w[...] = ew.copy_to_host()
