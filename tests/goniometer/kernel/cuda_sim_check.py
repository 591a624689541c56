"""Run by tests/goniometer/kernel/test_cuda.py in a subprocess with NUMBA_ENABLE_CUDASIM=1: the
CUDA kernel (goniometer.kernel.cuda) under numba-cuda's simulator against its CPU twin, the
per-path kernel (KERNEL_PATHS: the same transport, goniometer.kernel.onepath.trace_path, and the
same paths, summed in float64), on tiny grids; scalar and polarized light (``--polarized``: the
polarized checks only)."""

from __future__ import annotations

import os
import sys

assert os.environ.get("NUMBA_ENABLE_CUDASIM") == "1"

import numpy as np  # noqa: E402

from goniometer.kernel import tracer  # noqa: E402
from goniometer.run.settings import EVENT_CAP  # noqa: E402
from goniometer.kernel.cuda import FIXED_SCALE  # noqa: E402
from goniometer.grids.slice_grid import boundary_tables, light_direction  # noqa: E402
from goniometer.kernel.packing import pack  # noqa: E402
from goniometer.stack import Interface, Medium, Stack  # noqa: E402
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
    l = light_direction(40.0, 10.0)
    tables = boundary_tables("classic", *RES)
    run = tracer.prepare(p, l, rays, cr, 7, 0, 0, *RES, tables, K, EVENT_CAP, height_correlated=hc,
                         device="cuda")
    nb = run.n_chunks
    got = outs(nb, stack.transmits)
    tracer.launch(run, 0, got)
    twin = tracer.prepare(p, l, rays, cr, 7, 0, 0, *RES, tables, K, EVENT_CAP, height_correlated=hc,
                          kernel=tracer.KERNEL_PATHS)
    want = outs(nb, stack.transmits)
    tracer.launch(twin, 0, want)
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
    tables = boundary_tables("classic", 1, 1)

    def traced(kernel, device):
        run = tracer.prepare(p, (0.0, 0.0, 1.0), rays, cr, 5, TAB_STREAM, tracer.P_TABULATE, 1, 1, tables, 1,
                             EVENT_CAP, tabulate=True, kernel=kernel, device=device)
        nb = run.n_chunks
        o = (np.empty((nb, 1, 1, 3, 3)), np.empty((nb, 1, 1, 3, 3)), np.empty((nb, tracer.N_ENERGY, 3)),
             np.empty((nb, tracer.N_ENERGY_SQ, 3)), np.empty((nb, tracer.N_COUNTS), dtype=np.int64))
        ex = np.empty((nb, cr), dtype=np.int64), np.empty((nb, cr, 3))
        tracer.launch(run, 0, o, ex)
        sizes = run.chunk_sizes(0, nb)
        return o, [(ex[0][b, :n], ex[1][b, :n]) for b, n in enumerate(sizes)]

    o, got = traced(tracer.KERNEL_AUTO, "cuda")
    o_twin, want = traced(tracer.KERNEL_PATHS, "cpu")
    for b, ((cells, w), (want_c, want_w)) in enumerate(zip(got, want)):
        assert np.array_equal(cells, want_c), (name, b)
        assert np.allclose(w[cells >= 0], want_w[want_c >= 0], rtol=1e-15, atol=0.0), (name, b)
        assert np.array_equal(o[4][b], o_twin[4][b]), (name, b)
    assert sum(np.count_nonzero(c >= 0) for c, _ in got) > 0
    s = TabulationSettings(rays=rays, chunk_rays=cr, threads=1, device="cuda", spectral=True, wavelength_bins=3)
    tab = tabulate(stack, s)
    total = sum(tab.energy[k] for k in ("reflected", "transmitted", "absorbed", "masking_loss"))
    assert np.allclose(total + tab.roulette + tab.capped, 1.0, atol=1e-6), (name, total)
    assert tab.hits.sum() > 0 and dataclasses.replace(s, device="cpu") != s
    print(name, "tabulation ok", tab.energy["reflected"], flush=True)


#: a smooth dielectric slab (the polarized checks' third stack, beside a coated conductor and a rough slab)
SMOOTH_SLAB = Stack("smooth-slab", (Interface(0.0, (1.5,) * 3), Medium((0.0, 0.5, 1.0)), Interface(0.0, (1.0,) * 3)),
                    "slab")


def mueller_outs(nb, transmits, shape=RES):
    bt = shape if transmits else (1, 1)
    return np.empty((nb,) + shape + (32, 3)), np.empty((nb,) + bt + (32, 3))


def check_polarized(stack, rays, cr, hc=False):
    """A polarized run's launch against the twin's: every histogram, the Mueller histograms
    included, to the fixed point's rounding (each addend within 2^-33 of its value: a cell's sum of
    at most ``rays`` addends within rays * 2^-33; checked at twice that), counters exactly."""
    p = pack(stack)
    l = light_direction(40.0, 10.0)
    tables = boundary_tables("classic", *RES)

    def traced(**kw):
        run = tracer.prepare(p, l, rays, cr, 7, 0, 0, *RES, tables, K, EVENT_CAP, height_correlated=hc,
                             polarized=True, phi_deg=10.0, **kw)
        o, m = outs(run.n_chunks, stack.transmits), mueller_outs(run.n_chunks, stack.transmits)
        tracer.launch(run, 0, o, mueller=m)
        return o, m

    got, got_m = traced(device="cuda")
    want, want_m = traced(kernel=tracer.KERNEL_PATHS)
    tol = 2.0 * rays / FIXED_SCALE
    for g, w in zip(got[:4] + got_m, want[:4] + want_m):
        assert np.allclose(g, w, rtol=0.0, atol=tol), (stack.name, np.abs(g - w).max())
    assert np.array_equal(got[4], want[4]), (stack.name, got[4], want[4])
    m = got_m[0].sum(0)
    # polarization that the check sees: some element off the diagonal, some negative sum
    assert m[..., 0, :].sum() > 0.0 and np.abs(m[..., 1:16, :]).max() > 1e-3 and m[..., :16, :].min() < 0.0, \
        stack.name
    if stack.transmits:
        assert got_m[1].sum(0)[..., 0, :].sum() > 0.0, stack.name
    print(stack.name, "polarized ok", m[..., 0, :].sum(axis=(0, 1)) / rays, flush=True)


def check_polarized_tabulation(stack, rays, cr):
    """A polarized tabulation launch: each reflected exit's Mueller matrices in the plane frames of
    its MERL cell (goniometer.kernel.polarized.tabulated_exit) equal the twin's, as its cell and
    weights do."""
    p = pack(stack)
    tables = boundary_tables("classic", 1, 1)

    def traced(**kw):
        run = tracer.prepare(p, (0.0, 0.0, 1.0), rays, cr, 5, 9, tracer.P_TABULATE, 1, 1, tables, 1, EVENT_CAP,
                             tabulate=True, polarized=True, **kw)
        nb = run.n_chunks
        o = (np.empty((nb, 1, 1, 3, 3)), np.empty((nb, 1, 1, 3, 3)), np.empty((nb, tracer.N_ENERGY, 3)),
             np.empty((nb, tracer.N_ENERGY_SQ, 3)), np.empty((nb, tracer.N_COUNTS), dtype=np.int64))
        ex = np.empty((nb, cr), dtype=np.int64), np.empty((nb, cr, 3))
        m = np.empty((nb, cr, 1, 16, 3)), np.empty((nb, 0, 0, 0, 3))
        tracer.launch(run, 0, o, ex, mueller=m)
        return run.chunk_sizes(0, nb), ex, m[0]

    sizes, (cells, w), m = traced(device="cuda")
    _, (want_c, want_w), want_m = traced(kernel=tracer.KERNEL_PATHS)
    for b, n in enumerate(sizes):
        assert np.array_equal(cells[b, :n], want_c[b, :n]), (stack.name, b)
        hit = cells[b, :n] >= 0
        assert np.allclose(w[b, :n][hit], want_w[b, :n][hit], rtol=1e-15, atol=0.0), (stack.name, b)
        assert np.allclose(m[b, :n][hit], want_m[b, :n][hit], rtol=0.0, atol=1e-15), (stack.name, b)
        assert not m[b, :n][~hit].any(), (stack.name, b)
    assert np.count_nonzero(cells >= 0) > 0 and np.abs(m[..., 1:16, :]).max() > 1e-3
    print(stack.name, "polarized tabulation ok", flush=True)


if __name__ == "__main__":
    args = sys.argv[1:]
    polarized_only = "--polarized" in args
    args = [a for a in args if a != "--polarized"]
    rays = int(args[0]) if args else 1500
    if not polarized_only:
        for name in args[1:] or ["metal", "scattering-ms-plastic", "film-slab"]:
            check(name, rays, 1024, hc=name == "metal")
        check_tabulation("film-slab", 300, 128)
    else:
        for stack in (STACKS["metal"], STACKS["slab-matched"], SMOOTH_SLAB):
            check_polarized(stack, rays, 128)
        check_polarized_tabulation(STACKS["metal"], 200, 128)
    print("ALL OK")
