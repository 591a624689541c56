"""Run by tests/goniometer/kernel/test_cuda.py in a subprocess with NUMBA_ENABLE_CUDASIM=1: the
CUDA kernel (goniometer.kernel.cuda) under numba-cuda's simulator against its CPU twin
(goniometer.kernel.onepath.trace_keyed_chunk, the same paths summed in float64), on tiny grids."""

from __future__ import annotations

import os
import sys

assert os.environ.get("NUMBA_ENABLE_CUDASIM") == "1"

import numpy as np  # noqa: E402

from goniometer.run.settings import EVENT_CAP  # noqa: E402
from goniometer.kernel import tracer  # noqa: E402
from goniometer.kernel.onepath import FIXED_SCALE, trace_keyed_chunk  # noqa: E402
from goniometer.grids.slice_grid import boundary_tables, light_direction  # noqa: E402
from goniometer.kernel.packing import pack  # noqa: E402
from tests.goniometer.kernel.test_two_kernels import STACKS  # noqa: E402

RES = (4, 8)
K = 3


def outs(nb, transmits):
    bt = RES if transmits else (1, 1)
    return (np.empty((nb,) + RES + (K + 2, 3)), np.empty((nb,) + bt + (K + 2, 3)), np.empty((nb, tracer.N_ENERGY, 3)),
            np.empty((nb, tracer.N_ENERGY_SQ, 3)), np.empty((nb, tracer.N_COUNTS), dtype=np.int64))


def check(name, rays, cr, hc=False):
    stack = STACKS[name]
    p = pack(stack)
    nb = -(-rays // cr)
    l = light_direction(40.0, 10.0)
    tables = boundary_tables("classic", *RES)
    run = tracer.prepare(p, l, rays, cr, 7, 0, 0, *RES, tables, K, EVENT_CAP, height_correlated=hc,
                         device="cuda")
    got = outs(nb, stack.transmits)
    tracer.launch(run, 0, got)
    want = outs(nb, stack.transmits)
    f = run.facts
    for b in range(nb):
        for o in want:
            o[b].fill(0)
        trace_keyed_chunk(*(getattr(p, k) for k in ("if_alpha", "if_rot", "if_ms", "if_film", "region_tau",
                                                    "region_albedo", "region_g", "cond", "rho", "base_kind")),
                          f.tau_mode, f.eta_dn, f.eta_up, *l, min(cr, rays - b * cr), 7, 0, b, 0, *RES, *tables, K,
                          EVENT_CAP, False, hc, *(o[b] for o in want), np.empty(0, dtype=np.int64),
                          np.empty((0, 3)))
    # the same paths: the integer sums differ from float64 ones by the rounding of each addend
    tol = 4.0 * rays / FIXED_SCALE
    for g, w in zip(got[:4], want[:4]):
        assert np.allclose(g, w, rtol=0.0, atol=tol), (name, np.abs(g - w).max())
    assert np.array_equal(got[4], want[4]), (name, got[4], want[4])
    e = got[2].sum(0)
    total = e[:tracer.N_ENERGY].sum(0) - e[tracer.E_REFLECTED_WITHOUT_BASE]
    assert np.allclose(total, rays, rtol=0.0, atol=tol * 8), (name, total)
    assert got[0].sum() > 0.0
    print(name, "ok", e[tracer.E_REFLECTED] / rays, got[4].sum(0), flush=True)


def check_tabulation(name, rays, cr):
    """A tabulation launch (exits per path as MERL cells) against the twin's records, then a whole
    spectral tabulation through goniometer.run.tabulation with device="cuda" (energies add up)."""
    import dataclasses

    from goniometer.run.settings import TabulationSettings
    from goniometer.run.tabulation import TAB_STREAM, tabulate
    stack = STACKS[name]
    p = pack(stack)
    nb = -(-rays // cr)
    tables = boundary_tables("classic", 1, 1)
    run = tracer.prepare(p, (0.0, 0.0, 1.0), rays, cr, 5, TAB_STREAM, tracer.P_TABULATE, 1, 1, tables, 1,
                         EVENT_CAP, tabulate=True, device="cuda")
    o = (np.empty((nb, 1, 1, 3, 3)), np.empty((nb, 1, 1, 3, 3)), np.empty((nb, tracer.N_ENERGY, 3)),
         np.empty((nb, tracer.N_ENERGY_SQ, 3)), np.empty((nb, tracer.N_COUNTS), dtype=np.int64))
    cells, w = np.empty((nb, cr), dtype=np.int64), np.empty((nb, cr, 3))
    tracer.launch(run, 0, o, (cells, w))
    f = run.facts
    for b in range(nb):
        n = min(cr, rays - b * cr)
        want_c, want_w = np.full(n, -1, dtype=np.int64), np.zeros((n, 3))
        scratch = tuple(np.zeros(x.shape[1:], dtype=x.dtype) for x in o)
        trace_keyed_chunk(*(getattr(p, k) for k in ("if_alpha", "if_rot", "if_ms", "if_film", "region_tau",
                                                    "region_albedo", "region_g", "cond", "rho", "base_kind")),
                          f.tau_mode, f.eta_dn, f.eta_up, 0.0, 0.0, 1.0, n, 5, TAB_STREAM, b, tracer.P_TABULATE, 1, 1,
                          *tables, 1, EVENT_CAP, False, False, *scratch, want_c, want_w)
        assert np.array_equal(cells[b, :n], want_c), (name, b)
        assert np.allclose(w[b, :n], want_w, rtol=1e-15, atol=0.0), (name, b)
        assert np.array_equal(o[4][b], scratch[4]), (name, b)
    assert np.count_nonzero(cells >= 0) > 0
    s = TabulationSettings(rays=rays, chunk_rays=cr, threads=1, device="cuda", spectral=True, wavelength_bins=3)
    tab = tabulate(stack, s)
    total = sum(tab.energy[k] for k in ("reflected", "transmitted", "absorbed", "masking_loss"))
    assert np.allclose(total + tab.roulette + tab.capped, 1.0, atol=1e-6), (name, total)
    assert tab.hits.sum() > 0 and dataclasses.replace(s, device="cpu") != s
    print(name, "tabulation ok", tab.energy["reflected"], flush=True)


if __name__ == "__main__":
    rays = int(sys.argv[1]) if len(sys.argv) > 1 else 1500
    for name in sys.argv[2:] or ["metal", "scattering-ms-plastic", "film-slab"]:
        check(name, rays, 1024, hc=name == "metal")
    check_tabulation("film-slab", 300, 128)
    print("ALL OK")
