"""Exits to histogram cells (``docs/kernel.md``, deposits).

The kernel collects the exits of a chunk in a small buffer, in the order the paths leave, and
flushes it here: one pass finds the cells (:func:`goniometer.slices.cell_index_fast`) and
prefetches their cache lines, a second adds the weights in buffer order. The order of additions
to a cell is thus the order of exits within the chunk, which does not depend on threads.

Histograms: (n_theta, n_phi, K + 2, 3), rows ``0 .. K - 1`` the weight sums of bounce orders
``1 .. K`` (K: "K or more"), row ``K`` the squared weights of all exits, row ``K + 1`` those of
internal exits (order >= 2).
"""

from __future__ import annotations

import numba

from goniometer.kernel.codegen import prefetch
from goniometer.slices import cell_index_fast

#: exits a buffer holds: columns d_x, d_y, d_z, w_0, w_1, w_2, order row, 1.0 if transmitted
BUFFER = 512
X_COLS = 8


@numba.njit(cache=True, error_model='numpy', boundscheck=False)
def flush(xbuf, n_exit, cell, sqo, param, lx, ly, lz, n_theta, n_phi, row_cos, col_cos, col_sin, max_order,
          brdf, btdf):
    """Deposit the ``n_exit`` buffered exits of ``xbuf`` into ``brdf``/``btdf`` (``cell``/``sqo``:
    int64 scratch of the buffer's length)."""
    row = (max_order + 2) * 3
    nb = n_theta * n_phi * row
    hb = brdf.reshape(-1)
    ht = btdf.reshape(-1)
    for e in range(n_exit):
        transmission = xbuf[e, 7] != 0.0
        o = int(xbuf[e, 6])
        i, j = cell_index_fast(param, transmission, lx, ly, lz, xbuf[e, 0], xbuf[e, 1], xbuf[e, 2], n_theta, n_phi,
                               row_cos, col_cos, col_sin)
        # flat offset of the cell's order row and of its squared-sum row (-1: outside the slice);
        # transmitted exits offset by the BRDF's size
        shift = nb if transmission else 0
        base = (i * n_phi + j) * row + shift
        cell[e] = -1 if i < 0 else base + o * 3
        sqo[e] = -1 if i < 0 else base + max_order * 3
        # fetched while the next cells are found: the additions below find their lines in cache
        if i >= 0:
            if transmission:
                prefetch(ht, cell[e] - nb)
                prefetch(ht, sqo[e] - nb)
            else:
                prefetch(hb, cell[e])
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
        v0 = xbuf[e, 3]
        v1 = xbuf[e, 4]
        v2 = xbuf[e, 5]
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
