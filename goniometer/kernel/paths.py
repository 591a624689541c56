"""The per-path kernel (``docs/kernel.md``, one physics, two drivers): the CPU's driver of the
per-path transport. Each path of a chunk is traced from start to end by
:func:`goniometer.kernel.onepath.trace_path` -- the CUDA kernel's transport too
(:mod:`goniometer.kernel.cuda`) -- then its exit is deposited and its totals booked. It is the
reference the lane kernel (:func:`goniometer.kernel.tracer._trace_chunk`, which traces every stack)
is checked against, forced with ``KERNEL_PATHS``, and the CUDA kernel's twin on the CPU: path ``r``
of a chunk draws from the xoshiro256** stream seeded from its own key (:func:`path_key` of the
chunk's key, :mod:`goniometer.kernel.rng`), as on the GPU, so the two trace the same paths (the
CUDA kernel's sums are fixed point, these float64 in path order).

A histogram exit is deposited when the next exit happens (or at the end of the chunk), its cell
being prefetched meanwhile: each cell still receives its additions in path order.
"""

from __future__ import annotations

import numba
import numpy as np

from goniometer.grids.halfdiff import cell_of as halfdiff_cell
from goniometer.grids.halfdiff import halfdiff_angles
from goniometer.grids.slice_grid import cell_index_fast
from goniometer.kernel import polarized
from goniometer.kernel.codegen import prefetch
from goniometer.kernel.deposit import deposit_mueller
from goniometer.kernel.layout import C_CAPPED, C_EVENTS, N_ENERGY, N_ENERGY_SQ, P_TABULATE
from goniometer.kernel.onepath import (N_RECORD, X_CAPPED, X_REFLECTED, X_TRANSMITTED, new_record, path_energy,
                                       path_light, trace_path)
from goniometer.kernel.rng import path_key, seed_state


@numba.njit(cache=True, error_model='numpy', _nrt=False)
def _prefetch_exit(h, base, o, max_order):
    """Prefetch the rows of the histogram cell at flat offset ``base`` that :func:`_deposit` will
    update (order row ``o``, the squares' rows)."""
    prefetch(h, base + o * 3)
    prefetch(h, base + o * 3 + 2)
    prefetch(h, base + max_order * 3)
    prefetch(h, base + max_order * 3 + 5)


@numba.njit(cache=True, error_model='numpy', _nrt=False)
def _deposit(h, base, o, max_order, w0, w1, w2):
    """Add one exit of bounce-order row ``o`` with weight ``w`` to the histogram cell at flat offset
    ``base`` of ``h`` (a histogram's flat view): the order row, the squared weights' row
    ``max_order`` and, for an internal exit (``o > 0``), row ``max_order + 1``."""
    h[base + o * 3] += w0
    h[base + o * 3 + 1] += w1
    h[base + o * 3 + 2] += w2
    q0 = w0 * w0
    q1 = w1 * w1
    q2 = w2 * w2
    s = base + max_order * 3
    h[s] += q0
    h[s + 1] += q1
    h[s + 2] += q2
    if o > 0:
        h[s + 3] += q0
        h[s + 4] += q1
        h[s + 5] += q2


@numba.njit(cache=True, error_model='numpy')
def trace_paths(stack, lx, ly, lz, n_rays, ckey, param, n_theta, n_phi, tables, max_order, height_correlated, film,
                event_cap, skip_first, outs, polar=None):
    """Trace the ``n_rays`` paths of the chunk keyed ``ckey`` (:func:`goniometer.kernel.rng.chunk_key`)
    one after the other for light direction ``l`` and accumulate into the given arrays (arguments
    as :func:`goniometer.kernel.tracer._trace_chunk`'s: ``stack``, ``tables`` and ``outs`` tuples;
    ``height_correlated``, ``film``: the per-path kernel's variant, None or True each,
    :class:`goniometer.kernel.variants.Variant`).

    ``param`` is the slice parametrization (:data:`goniometer.grids.slice_grid.CLASSIC`, ``HALF``,
    ``RGL``) or :data:`P_TABULATE`: then path ``r`` first draws its own light direction
    (:func:`goniometer.kernel.onepath.path_light`), and its reflected exit, if any, is written to
    ``exit_cell[r]`` (MERL cell, -1 if none) and ``exit_w[r]`` (weight) instead of to ``brdf``;
    transmitted exits are booked in ``energy`` only. Otherwise ``exit_cell``/``exit_w`` are not
    touched (they may be empty).

    ``brdf``/``btdf``: (n_theta, n_phi, K + 2, 3), cell-major so that one exit touches one or two
    cache lines: rows ``0 .. K-1`` sum the exit weights of bounce orders ``1 .. K`` (K meaning "K
    or more"), row ``K`` sums the squared weights of all exits and row ``K + 1`` those of internal
    exits (order >= 2), for the standard errors. ``energy``: (N_ENERGY, 3) weight sums;
    ``energy_sq``: (N_ENERGY_SQ, 3) sums of squared per-path totals; ``counts``: (N_COUNTS,)
    int64. ``skip_first``: reflected exits of bounce order 1 whose top event was one microfacet
    reflection (on a multiple-scattering top, a walk of one bounce) are booked in ``energy`` but
    not deposited (``first_order = "integrated"``, :mod:`goniometer.run.first_order`).
    ``polar``: None (scalar light), or the initial state of a polarized path
    (:func:`goniometer.kernel.polarized.initial_state`); each exit's Mueller matrices then go to
    ``mbrdf``/``mbtdf`` (the last two of ``outs``: (n_theta, n_phi, 2 * 16, 3), the 16 elements'
    sums then their squares' per channel; ``docs/polarization.md``); a polarized tabulation's
    reflected exit writes its Mueller matrices instead to ``mbrdf[r, 0]`` ((16, 3), the "plane"
    frames of its MERL cell, :func:`goniometer.kernel.polarized.tabulated_exit`).
    """
    row_cos, col_cos, col_sin = tables
    brdf, btdf, energy, energy_sq, counts, exit_cell, exit_w, mbrdf, mbtdf = outs
    hr = brdf.reshape(-1)
    ht = btdf.reshape(-1)
    cell_size = (max_order + 2) * 3
    state = np.empty(4, dtype=np.uint64)
    rec = np.empty(N_RECORD)
    pol = np.empty((4, 16)) if polar is not None else None
    tabulate = param == P_TABULATE
    n_events = 0
    n_capped = 0
    # the exit not yet deposited: none (0), in brdf (1) or in btdf (2); cell offset, order row, weight
    pend = 0
    pbase = 0
    po = 0
    pw0 = 0.0
    pw1 = 0.0
    pw2 = 0.0
    for r in range(n_rays):
        seed_state(state, path_key(ckey, np.uint64(r)))
        plx, ply, plz = path_light(state, tabulate, lx, ly, lz)
        new_record(rec)
        if polar is not None:
            polarized.start(pol, polar, -plx, -ply, -plz)
        kind, dx, dy, dz, w0, w1, w2, order, single, based, events = trace_path(
            stack, -plx, -ply, -plz, height_correlated, film, event_cap, state, rec, pol)
        n_events += events
        refl = kind == X_REFLECTED
        trans = kind == X_TRANSMITTED
        if tabulate:
            exit_cell[r] = halfdiff_cell(plx, ply, plz, dx, dy, dz) if refl else -1
            if refl:
                exit_w[r, 0] = w0
                exit_w[r, 1] = w1
                exit_w[r, 2] = w2
                if polar is not None:
                    polarized.tabulated_exit(pol, plx, ply, plz, dx, dy, dz,
                                             halfdiff_angles(plx, ply, plz, dx, dy, dz)[2] < 0.0, mbrdf[r, 0])
        elif (refl and not (skip_first and order == 1 and single)) or trans:
            i, j = cell_index_fast(param, trans, lx, ly, lz, dx, dy, dz, n_theta, n_phi, row_cos, col_cos, col_sin)
            if i >= 0:
                base = (i * n_phi + j) * cell_size
                o = min(order, max_order) - 1
                _prefetch_exit(ht if trans else hr, base, o, max_order)
                if pend == 1:
                    _deposit(hr, pbase, po, max_order, pw0, pw1, pw2)
                elif pend == 2:
                    _deposit(ht, pbase, po, max_order, pw0, pw1, pw2)
                pend, pbase, po, pw0, pw1, pw2 = 2 if trans else 1, base, o, w0, w1, w2
                if polar is not None:
                    deposit_mueller(mbtdf if trans else mbrdf, i, j, pol)
        for e in range(N_ENERGY):
            x0, x1, x2 = path_energy(kind, based, w0, w1, w2, rec, e)
            energy[e, 0] += x0
            energy[e, 1] += x1
            energy[e, 2] += x2
            if e < N_ENERGY_SQ:
                energy_sq[e, 0] += x0 * x0
                energy_sq[e, 1] += x1 * x1
                energy_sq[e, 2] += x2 * x2
        n_capped += kind == X_CAPPED
    if pend == 1:
        _deposit(hr, pbase, po, max_order, pw0, pw1, pw2)
    elif pend == 2:
        _deposit(ht, pbase, po, max_order, pw0, pw1, pw2)
    counts[C_CAPPED] += n_capped
    counts[C_EVENTS] += n_events
