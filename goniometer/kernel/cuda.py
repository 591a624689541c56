"""The CUDA kernel (``docs/gpu.md``): the GPU's driver of the per-path transport, one thread per path,
through numba-cuda.

Each thread traces one path with :func:`goniometer.kernel.onepath.trace_path` -- the per-path
transport, the CPU per-path kernel's too (:mod:`goniometer.kernel.paths`): numba-cuda compiles the
``numba.njit`` functions a kernel calls for the device from the same Python source (the optics,
the walks, the free flights, the cell lookup) -- seeded from the path's own key, so a path draws
the same numbers on any device, in any thread, and in the CPU's per-path kernel. The grid is
two-dimensional: ``blockIdx.y`` is the chunk slot, ``blockIdx.x * blockDim.x + threadIdx.x`` the
path in the chunk.

Registers: a thread keeps in shared memory what its path touches rarely or in bursts -- the path's
record (its absorbed, masking and roulette weights, its state in scattering media,
:data:`goniometer.kernel.onepath.N_RECORD` numbers), its random stream's state, a tabulation's
light direction -- a column per thread, so that a warp reads consecutive words. The kernel has the
per-path transport's variants, ``(height_correlated, film)`` (:func:`kernel_source`), each compiled
on first use without the other's code, with launch bounds (:func:`kernel_options`): 128 threads and
at least 4 blocks per multiprocessor, so ptxas keeps a thread within 128 registers (25 %
occupancy), 3 blocks for a stack with a thin film (168 registers). ``tests/goniometer/kernel/test_cuda_compile.py``
checks without a GPU that every variant compiles for sm_80 and sm_90 without spilling
(:mod:`goniometer.kernel.cuda_build`). Polarized light (``docs/polarization.md``) is a third flag:
its variants keep each thread's Mueller state in a local (4, 16) array and deposit each exit's
matrices into Mueller histograms (launch bounds: 2 blocks, 255 registers).

Sums are 64-bit integers: a weight ``w`` adds ``round(w * 2^32)`` (:func:`fixed_point`) with
integer atomics, which commute, so a run's sums do not depend on the order in which threads
finish, nor on the block size: they are the same bits on every launch on the same device and
compiler. A block first sums into its shared memory (the energies always; the histograms when the
grid's two histograms fit, :data:`SHARED_BYTES`), then adds what it holds to global memory;
otherwise it adds to global memory directly (always, for the Mueller histograms; their elements
are signed, in the same fixed point, ``docs/gpu.md``). The integers are turned into float64 at the
end (``/ 2^32``).

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
from goniometer.grids.halfdiff import halfdiff_angles
from goniometer.grids.slice_grid import cell_index_fast
from goniometer.kernel.layout import C_CAPPED, C_EVENTS, N_COUNTS, N_ENERGY, N_ENERGY_SQ, P_TABULATE
from goniometer.kernel.onepath import (N_RECORD, X_CAPPED, X_REFLECTED, X_TRANSMITTED, new_record, path_energy,
                                       path_light, trace_path)
from goniometer.kernel.polarized import start, tabulated_exit
from goniometer.kernel.rng import path_state

#: threads per block
BLOCK = 128
#: blocks per multiprocessor a variant is compiled to fit (its launch bounds, :func:`kernel_options`):
#: 4, so 128 registers a thread (25 % occupancy); 3 for a stack with a thin film (168 registers,
#: 18.75 %), whose Airy sums of three channels on top of a walk do not fit 128 registers (ptxas
#: spills 470-850 bytes a thread there; ``benchmarks/README.md``)
MIN_BLOCKS = 4
MIN_BLOCKS_FILM = 3
#: 2 for polarized light (255 registers, 12.5 %): a path's Mueller state, 64 numbers, and the
#: rotations and products of its events spill 1-5.5 KB a thread at 3 or 4 blocks; at 2 ptxas keeps
#: the state of a stack without a film in registers (``docs/gpu.md``)
MIN_BLOCKS_POLARIZED = 2
#: shared memory a block's histograms may take: with the block's own (about 22 KB: the paths'
#: records, streams and lights, the energy sums) four blocks fit in an A100's 164 KB
SHARED_BYTES = 16_384
#: the CUDA kernel's sums are integers: a weight ``w`` adds ``round(w * FIXED_SCALE)`` (2^32), so the
#: order of the atomic additions cannot change a sum (``docs/gpu.md``, determinism)
FIXED_SCALE = 4294967296.0
#: a block's energy sums: N_ENERGY x 3 weights, N_ENERGY_SQ x 3 squares, N_COUNTS counters
_N_EN = N_ENERGY * 3
_N_ENSQ = N_ENERGY_SQ * 3
_N_ACC = _N_EN + _N_ENSQ + N_COUNTS
#: a Mueller histogram's numbers per cell: 16 elements and their squares, 3 channels
_MUELLER_ROW = 2 * 16 * 3


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
def _deposit_mueller(h, base, pol):
    """A polarized exit's Mueller matrices into the Mueller histogram ``h`` (flat, int64) at cell
    offset ``base``: rows 0-15 the elements, rows 16-31 their squares, per channel (the per-path
    kernel's layout, :func:`goniometer.kernel.paths.trace_paths`); signed, in the same fixed point."""
    for e in range(16):
        for c in range(3):
            v = pol[c, e]
            _add(h, base + e * 3 + c, fixed_point(v))
            _add(h, base + (16 + e) * 3 + c, fixed_point(v * v))


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


def kernel_source(height_correlated, film, polarized=None):
    """The CUDA kernel's Python function for the variant ``(height_correlated, film, polarized)``
    (None or True each: :class:`goniometer.kernel.variants.Variant`'s two flags of the per-path
    transport, and polarized light, ``docs/polarization.md``): numba freezes the closure's values
    as constants, so each variant compiles without the others' code (as the CPU kernels' variant
    arguments do); :func:`kernel_for` compiles it. A scalar variant's kernel takes the scalar
    arguments only; a polarized one's three more (:func:`kernel_args`)."""

    @cuda.jit(device=True, inline=True)
    def _trace(stack, run, tables, sizes, shared_hist, hist, acc_g, exit_cell, exit_w, polar, pol, mhist, exit_m):
        """Trace the paths of a batch of chunks (module docstring). ``stack``, ``run``, ``tables``,
        ``sizes``: the CPU kernels' arguments (:func:`goniometer.kernel.tracer.launch`);
        ``shared_hist``: bool; ``hist``: (B, 2 * cells * row) int64, the BRDF then the BTDF of each
        slot, flat; ``acc_g``: (B, _N_ACC) int64 energy sums; ``exit_cell`` / ``exit_w``: per path
        of a tabulation ((B, 0) otherwise). With ``shared_hist`` the block sums its histograms in
        dynamic shared memory before adding them to ``hist``. ``polar``, ``pol``, ``mhist``,
        ``exit_m``: None for scalar light; for polarized light the launch's initial path state
        (:func:`goniometer.kernel.polarized.initial_state`), the thread's path state (a local
        (4, 16) array), the Mueller histograms ((B, 2 * cells * 96) int64, the BRDF's then the
        BTDF's, each cell's 16 elements then their squares per channel, flat: the per-path
        kernel's ``mbrdf``/``mbtdf`` layout) and a tabulation's exits' Mueller matrices ((B, n,
        1, 16, 3) float64, :func:`goniometer.kernel.polarized.tabulated_exit`)."""
        b = cuda.blockIdx.y
        tid = cuda.threadIdx.x
        r = cuda.blockIdx.x * cuda.blockDim.x + tid
        lx, ly, lz, first_chunk, seed, stream, param, n_theta, n_phi, max_order, event_cap, skip_first = run
        n_hist = hist.shape[1]
        sh = cuda.shared.array(0, dtype=int64)        # shared_hist: the block's histograms
        acc = cuda.shared.array(_N_ACC, dtype=int64)  # the block's energy sums
        # what a thread keeps of its path in shared memory rather than in registers (module
        # docstring; a column per thread: consecutive threads read consecutive words): the path's
        # record (onepath.N_RECORD numbers), its random stream's state, a tabulation's light
        records = cuda.shared.array((N_RECORD, BLOCK), dtype=float64)
        states = cuda.shared.array((4, BLOCK), dtype=uint64)
        lights = cuda.shared.array((3, BLOCK), dtype=float64)
        for q in range(tid, _N_ACC, cuda.blockDim.x):
            acc[q] = int64(0)
        if shared_hist:
            for q in range(tid, n_hist, cuda.blockDim.x):
                sh[q] = int64(0)
        cuda.syncthreads()
        if r < sizes[b]:
            state = states[:, tid]
            rec = records[:, tid]
            new_record(rec)
            path_state(state, seed, stream, first_chunk + b, r)
            tabulate = param == P_TABULATE
            plx, ply, plz = path_light(state, tabulate, lx, ly, lz)
            lights[0, tid] = plx
            lights[1, tid] = ply
            lights[2, tid] = plz
            if pol is not None:
                start(pol, polar, -plx, -ply, -plz)
            kind, dx, dy, dz, w0, w1, w2, order, single, based, events = trace_path(
                stack, -plx, -ply, -plz, height_correlated, film, event_cap, state, rec, pol)
            refl = kind == X_REFLECTED
            trans = kind == X_TRANSMITTED
            if tabulate:
                cell = -1
                if refl:
                    cell = halfdiff_cell(lights[0, tid], lights[1, tid], lights[2, tid], dx, dy, dz)
                    exit_w[b, r, 0] = w0
                    exit_w[b, r, 1] = w1
                    exit_w[b, r, 2] = w2
                    if pol is not None:
                        tx, ty, tz = lights[0, tid], lights[1, tid], lights[2, tid]
                        tabulated_exit(pol, tx, ty, tz, dx, dy, dz, halfdiff_angles(tx, ty, tz, dx, dy, dz)[2] < 0.0,
                                       exit_m[b, r, 0])
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
                    if pol is not None:
                        _deposit_mueller(mhist[b], (i * n_phi + j) * _MUELLER_ROW + (mhist.shape[1] // 2 if trans
                                                                                      else 0), pol)
            for row in range(N_ENERGY):
                x0, x1, x2 = path_energy(kind, based, w0, w1, w2, rec, row)
                _book(acc, row, x0, x1, x2, row < N_ENERGY_SQ)
            if kind == X_CAPPED:
                _add(acc, _N_EN + _N_ENSQ + C_CAPPED, int64(1))
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

    if polarized is None:
        def _kernel(stack, run, tables, sizes, shared_hist, hist, acc_g, exit_cell, exit_w):
            """The scalar kernel (:func:`kernel_source`'s ``_trace`` gives the arguments)."""
            _trace(stack, run, tables, sizes, shared_hist, hist, acc_g, exit_cell, exit_w, None, None, None, None)
    else:
        def _kernel(stack, run, tables, sizes, shared_hist, hist, acc_g, exit_cell, exit_w, mueller):
            """The polarized kernel: ``mueller`` = ``(polar, mhist, exit_m)``, each thread's path state
            in a local (4, 16) array."""
            polar, mhist, exit_m = mueller
            pol = cuda.local.array((4, 16), float64)
            _trace(stack, run, tables, sizes, shared_hist, hist, acc_g, exit_cell, exit_w, polar, pol, mhist, exit_m)
    return _kernel


#: the compiled kernel of each variant, compiled on first use (:func:`kernel_for`)
_KERNELS: dict = {}


def kernel_options(film, polarized=None) -> dict:
    """The compile options of a variant: its launch bounds, the most threads per block
    (:data:`BLOCK`) and the fewest blocks per multiprocessor (:data:`MIN_BLOCKS`, or
    :data:`MIN_BLOCKS_FILM` for ``film`` True, or :data:`MIN_BLOCKS_POLARIZED` for ``polarized``
    True), which keep ptxas within ``65536 / (threads x blocks)`` registers a thread (at most 255).
    The compile check (:mod:`goniometer.kernel.cuda_build`) reads them too."""
    blocks = MIN_BLOCKS_POLARIZED if polarized is not None else MIN_BLOCKS if film is None else MIN_BLOCKS_FILM
    return {"launch_bounds": (BLOCK, blocks)}


def kernel_for(height_correlated, film, polarized=None):
    """The kernel of a variant (:func:`kernel_source`), compiled with :func:`kernel_options` (the
    simulator runs Python threads: it has no registers and takes no launch bounds)."""
    key = (height_correlated, film, polarized)
    if key not in _KERNELS:
        jit = cuda.jit if config.ENABLE_CUDASIM else cuda.jit(**kernel_options(film, polarized))
        _KERNELS[key] = jit(kernel_source(*key))
    return _KERNELS[key]


def kernel_args(run, first_chunk: int, sizes: np.ndarray, B: int, hist_cells: int, exit_shape: tuple,
                to_device=None) -> tuple:
    """The CUDA kernel's arguments for a batch of ``B`` chunks of ``run`` (a
    :class:`goniometer.kernel.tracer.Launch`) starting at ``first_chunk``: ``hist_cells`` numbers per
    slot's two histograms, ``exit_shape`` the per-path records' ``(B, n)`` (``n`` 0 but for a
    tabulation). A polarized run (``run.polar`` not None) adds one argument, the tuple of its
    initial path state, its Mueller histograms (``hist_cells // (max_order + 2) * 32`` numbers per
    slot) and a tabulation's exits' Mueller matrices ``exit_shape + (1, 16, 3)``
    (:func:`kernel_source`). ``to_device`` (None: the arrays stay on the host, as the compile check
    types them) moves an array to the GPU. Returns ``(args, shared_hist, dynamic_shared_bytes)``."""
    dev = to_device if to_device is not None else (lambda a: a)
    keep = dev if not config.ENABLE_CUDASIM else (lambda a: a)   # the simulator's CPU functions read host arrays
    stack = type(run.stack_args)(*(keep(np.ascontiguousarray(x)) if isinstance(x, np.ndarray) else x
                                   for x in run.stack_args))
    tables = tuple(keep(np.ascontiguousarray(t, dtype=np.float64)) for t in run.tables)
    shared_hist = hist_cells * 8 <= SHARED_BYTES
    tabulate = run.param == P_TABULATE
    args = (stack, run.scalars(first_chunk), tables, dev(np.ascontiguousarray(sizes, dtype=np.int64)), shared_hist,
            dev(np.zeros((B, hist_cells), dtype=np.int64)),
            dev(np.zeros((B, _N_ACC), dtype=np.int64)),
            dev(np.full(exit_shape, -1, dtype=np.int64) if tabulate else np.zeros((B, 0), dtype=np.int64)),
            dev(np.zeros(exit_shape + (3,)) if tabulate else np.zeros((B, 0, 3))))
    if run.polar is not None:
        # (a tuple: the simulator hands the CPU functions these arrays as they are)
        m_cells = hist_cells // ((run.max_order + 2) * 3) * _MUELLER_ROW
        args += ((keep(np.ascontiguousarray(run.polar, dtype=np.float64)),
                  keep(np.zeros((B, 0 if tabulate else m_cells), dtype=np.int64)),
                  keep(np.zeros((exit_shape if tabulate else (B, 0)) + (1, 16, 3)))),)
    return args, shared_hist, hist_cells * 8 if shared_hist else 0


def trace_batch(run, first_chunk: int, sizes: np.ndarray, outs: tuple, exits: tuple, mueller: tuple | None = None
                ) -> None:
    """Trace chunks ``first_chunk .. first_chunk + B - 1`` of ``run`` (a
    :class:`goniometer.kernel.tracer.Launch`; ``sizes`` their rays, :meth:`Launch.chunk_sizes`) on the
    GPU into the CPU arrays ``outs`` / ``exits`` (and a polarized run's ``mueller``), as
    :func:`goniometer.kernel.tracer.launch` documents (each slot's sums are the integers' values)."""
    brdf, btdf, energy, energy_sq, counts = outs
    exit_cell, exit_w = exits
    B = brdf.shape[0]
    if B == 0:
        return
    nb = brdf[0].size
    transmits = btdf.shape[1:] == brdf.shape[1:]
    args, _, dyn = kernel_args(run, first_chunk, sizes, B, 2 * nb, exit_cell.shape, cuda.to_device)
    blocks = (max(1, -(-run.chunk_rays // BLOCK)), B)
    polarized = None if run.polar is None else True
    kernel_for(run.variant.height_correlated, run.variant.film, polarized)[blocks, BLOCK, 0, dyn](*args)
    hist, acc, ec, ew = args[5:9]
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
    if polarized:
        _mueller_to_host(*args[9][1:], run.param == P_TABULATE, transmits, mueller)


def _host(a) -> np.ndarray:
    """A device array's copy on the host (the simulator's arrays are there already)."""
    return a if isinstance(a, np.ndarray) else a.copy_to_host()


def _mueller_to_host(mhist, exit_m, tabulate: bool, transmits: bool, mueller: tuple) -> None:
    """A polarized batch's device Mueller sums into the launch's ``mueller`` = (mbrdf, mbtdf)
    (:func:`goniometer.kernel.tracer.launch`): the histograms' integers as their values, or a
    tabulation's per-path matrices into ``mbrdf`` (its ``mbtdf`` is empty)."""
    mbrdf, mbtdf = mueller
    if tabulate:
        mbrdf[...] = _host(exit_m)
        return
    m = _host(mhist).astype(np.float64) / FIXED_SCALE
    n = mbrdf[0].size
    mbrdf[...] = m[:, :n].reshape(mbrdf.shape)
    mbtdf[...] = m[:, n:].reshape(mbtdf.shape) if transmits else 0.0
