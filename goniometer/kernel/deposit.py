"""Exits to histogram cells (``docs/kernel.md``, deposits).

The kernel collects the exits of a chunk in a small buffer, in the order the paths leave, and
flushes it here: a vectorised loop finds the cells (:func:`goniometer.grids.slice_grid.cell_index_lanes`),
a pass prefetches their cache lines, a last one adds the weights in buffer order. The order of additions
to a cell is thus the order of exits within the chunk, which does not depend on threads.

Histograms: (n_theta, n_phi, K + 2, 3), rows ``0 .. K - 1`` the weight sums of bounce orders
``1 .. K`` (K: "K or more"), row ``K`` the squared weights of all exits, row ``K + 1`` those of
internal exits (order >= 2).
"""

from __future__ import annotations

import numba
import numpy as np

from goniometer.kernel.codegen import STACK_BLOCK, prefer_wide_vectors, prefetch, stack_block
from goniometer.grids.warp import invert_point
from goniometer.grids.slice_grid import RGL, cell_index_fast, cell_index_lanes

#: exits a buffer holds: rows d_x, d_y, d_z, w_0, w_1, w_2, order row, 1.0 if transmitted (one
#: column per exit)
BUFFER = 512
X_COLS = 8


@numba.njit(cache=True, error_model='numpy', inline='always')
def _offsets(i, j, o, transmission, n_phi, row, nb, max_order):
    """Flat offsets of cell (i, j)'s order row ``o`` and of its squared-sum row (-1 outside the
    slice, ``i < 0``); transmitted exits offset by the BRDF's size ``nb``."""
    base = (i * n_phi + j) * row + (nb if transmission else 0)
    return (-1 if i < 0 else base + o * 3), (-1 if i < 0 else base + max_order * 3)


@numba.njit(cache=True, error_model='numpy', boundscheck=False)
def flush(xbuf, n_exit, cell, sqo, param, lx, ly, lz, n_theta, n_phi, row_cos, col_cos, col_sin, max_order,
          brdf, btdf):
    """Deposit the ``n_exit`` buffered exits of ``xbuf`` (X_COLS, BUFFER) into ``brdf``/``btdf``
    (``cell``/``sqo``: int64 scratch of the buffer's length)."""
    row = (max_order + 2) * 3
    nb = n_theta * n_phi * row
    hb = brdf.reshape(-1)
    ht = btdf.reshape(-1)
    if param == RGL:
        # the RGL grid: the node of each reflected exit through the incident direction's warp (the
        # tables' slots hold it, goniometer.grids.warp.pack_kernel_tables); transmitted exits are
        # booked in the energies only
        for e in range(n_exit):
            transmission = xbuf[7, e] != 0.0
            i, j = invert_point(lx, ly, lz, xbuf[0, e], xbuf[1, e], xbuf[2, e], n_theta, row_cos, col_cos, col_sin)
            i = -1 if transmission else i
            cell[e], sqo[e] = _offsets(i, j, np.int64(xbuf[6, e]), transmission, n_phi, row, nb, max_order)
    elif n_phi >= 8 and n_theta + 1 <= STACK_BLOCK and n_phi + 1 <= STACK_BLOCK:
        # the cells of all exits in one vectorised loop (the boundary tables on this function's
        # stack: gathers that provably do not alias the results)
        prefer_wide_vectors()
        rc = stack_block()
        cc = stack_block()
        cs = stack_block()
        for q in range(n_theta + 1):
            rc[q] = row_cos[q]
        for q in range(n_phi + 1):
            cc[q] = col_cos[q]
            cs[q] = col_sin[q]
        for e in range(n_exit):
            transmission = xbuf[7, e] != 0.0
            i, j = cell_index_lanes(param, transmission, lx, ly, lz, xbuf[0, e], xbuf[1, e], xbuf[2, e], n_theta,
                                    n_phi, rc, cc, cs)
            cell[e], sqo[e] = _offsets(i, j, np.int64(xbuf[6, e]), transmission, n_phi, row, nb, max_order)
    else:
        for e in range(n_exit):
            transmission = xbuf[7, e] != 0.0
            i, j = cell_index_fast(param, transmission, lx, ly, lz, xbuf[0, e], xbuf[1, e], xbuf[2, e], n_theta,
                                   n_phi, row_cos, col_cos, col_sin)
            cell[e], sqo[e] = _offsets(i, j, np.int64(xbuf[6, e]), transmission, n_phi, row, nb, max_order)
    # every line the additions touch fetched before the first: they find them in cache
    for e in range(n_exit):
        f = cell[e]
        if f >= 0:
            if f >= nb:
                prefetch(ht, f - nb)
                prefetch(ht, sqo[e] - nb)
            else:
                prefetch(hb, f)
                prefetch(hb, sqo[e])
    for e in range(n_exit):
        f = cell[e]
        if f < 0:
            continue
        q = sqo[e]
        h = hb
        if f >= nb:
            h = ht
            f -= nb
            q -= nb
        v0 = xbuf[3, e]
        v1 = xbuf[4, e]
        v2 = xbuf[5, e]
        h[f] += v0
        h[f + 1] += v1
        h[f + 2] += v2
        s0 = v0 * v0
        s1 = v1 * v1
        s2 = v2 * v2
        h[q] += s0
        h[q + 1] += s1
        h[q + 2] += s2
        if f != q - max_order * 3:
            # an internal exit (order row > 0): its squares also in the last row
            h[q + 3] += s0
            h[q + 4] += s1
            h[q + 5] += s2


@numba.njit(cache=True, error_model='numpy', _nrt=False)
def deposit_mueller(mh, i, j, pol):
    """Add a polarized exit's Mueller matrices (``pol``, :mod:`goniometer.kernel.polarized`: rows 0-2
    per channel, in its exit frames) to cell ``(i, j)`` of ``mh`` (n_theta, n_phi, 32, 3): rows 0-15
    the elements, rows 16-31 their squares, per channel."""
    for e in range(16):
        for c in range(3):
            v = pol[c, e]
            mh[i, j, e, c] += v
            mh[i, j, 16 + e, c] += v * v



@numba.njit(cache=True, error_model='numpy', boundscheck=False)
def flush_mueller(mbuf, xbuf, n_exit, cell, max_order, n_theta, n_phi, mbrdf, mbtdf):
    """Add the Mueller matrices ``mbuf`` (BUFFER, 48: element ``e`` of channel ``c`` at column ``3 e
    + c``, in the exits' frames) of the ``n_exit`` buffered exits of a polarized chunk to the cells
    :func:`flush` found for them (``cell``, after its call on the same buffer; ``xbuf`` for their
    order rows and sides): per channel the 16 elements' sums (rows 0-15 of a cell of ``mbrdf`` /
    ``mbtdf``, (n_theta, n_phi, 32, 3)) and their squares' (rows 16-31), in buffer order. The cells'
    cache lines are fetched a block of exits ahead of the additions."""
    row = (max_order + 2) * 3
    nb = n_theta * n_phi * row
    hb = mbrdf.reshape(-1)
    ht = mbtdf.reshape(-1)
    for e0 in range(0, n_exit, 64):
        e1 = min(n_exit, e0 + 64)
        for e in range(e0, e1):
            f = cell[e]
            if f >= 0:
                base = ((f - (nb if f >= nb else 0) - np.int64(xbuf[6, e]) * 3) // row) * 96
                for q in range(0, 96, 8):
                    prefetch(ht if f >= nb else hb, base + q)
        for e in range(e0, e1):
            f = cell[e]
            if f < 0:
                continue
            h = ht if f >= nb else hb
            base = ((f - (nb if f >= nb else 0) - np.int64(xbuf[6, e]) * 3) // row) * 96
            for q in range(48):
                v = mbuf[e, q]
                h[base + q] += v
                h[base + 48 + q] += v * v
