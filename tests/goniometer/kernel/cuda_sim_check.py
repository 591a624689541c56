"""Run by tests/goniometer/kernel/test_cuda.py in a subprocess with NUMBA_ENABLE_CUDASIM=1: the
CUDA kernel (goniometer.kernel.cuda) under numba-cuda's simulator against its CPU twin
(goniometer.kernel.onepath.trace_keyed_chunk, the same paths summed in float64), on tiny grids."""

from __future__ import annotations

import os
import sys

assert os.environ.get("NUMBA_ENABLE_CUDASIM") == "1"

import numpy as np  # noqa: E402

from goniometer import tracer  # noqa: E402
from goniometer.kernel.onepath import FIXED_SCALE, trace_keyed_chunk  # noqa: E402
from goniometer.slices import boundary_tables, light_direction  # noqa: E402
from goniometer.stack import pack  # noqa: E402
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
    run = tracer.prepare(p, l, rays, cr, 7, 0, 0, *RES, tables, K, tracer.EVENT_CAP, height_correlated=hc,
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
                          tracer.EVENT_CAP, False, hc, *(o[b] for o in want), np.empty(0, dtype=np.int64),
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


if __name__ == "__main__":
    rays = int(sys.argv[1]) if len(sys.argv) > 1 else 1500
    for name in sys.argv[2:] or ["metal", "scattering-ms-plastic", "film-slab"]:
        check(name, rays, 1024, hc=name == "metal")
    print("ALL OK")
