"""Polarized light in the two CPU kernels (``docs/polarization.md``, ``docs/kernel.md`` section 2):
the lane kernel's Mueller matrices against the per-path kernel's, with independent random numbers,
element by element within their standard errors (the scalar check is ``test_two_kernels.py``)."""

from __future__ import annotations

import numpy as np
import pytest

from goniometer.kernel import tracer
from goniometer.kernel.packing import pack
from goniometer.grids.slice_grid import boundary_tables, light_direction
from goniometer.run.settings import EVENT_CAP
from goniometer.stack import Interface, Stack
from goniometer.testing import Z_TOL, chi2_limit
from tests.goniometer.kernel.test_two_kernels import K, RES, STACKS


def _trace_polarized(stack: Stack, kernel: int, seed: int, rays: int):
    """A polarized run's slices, energies and Mueller histograms (sums, then squares)."""
    p = pack(stack)
    run = tracer.prepare(p, light_direction(40.0, 10.0), rays, 1 << 14, seed, 0, 0, *RES,
                         boundary_tables("classic", *RES), K, EVENT_CAP, kernel=kernel, polarized=True)
    nb = run.n_chunks
    bt = RES if stack.transmits else (1, 1)
    outs = (np.empty((nb,) + RES + (K + 2, 3)), np.empty((nb,) + bt + (K + 2, 3)), np.empty((nb, tracer.N_ENERGY, 3)),
            np.empty((nb, tracer.N_ENERGY_SQ, 3)), np.empty((nb, tracer.N_COUNTS), dtype=np.int64))
    mueller = (np.empty((nb,) + RES + (32, 3)), np.empty((nb,) + bt + (32, 3)))
    tracer.launch(run, 0, outs, mueller=mueller)
    return tuple(o.sum(0) for o in outs + mueller)


def _mueller_chi2(a, b, rays):
    """Chi-square of two independent samples' Mueller element sums ((.., 32, 3): sums then squares)
    over the elements of the cells where each sample's M00 has at least 25 effective hits."""
    sa, qa, sb, qb = a[..., :16, :], a[..., 16:, :], b[..., :16, :], b[..., 16:, :]
    var = (qa - sa ** 2 / rays) + (qb - sb ** 2 / rays)
    hits = np.minimum(sa[..., :1, :] ** 2 / np.maximum(qa[..., :1, :], 1e-300),
                      sb[..., :1, :] ** 2 / np.maximum(qb[..., :1, :], 1e-300))
    sel = np.broadcast_to(hits >= 25.0, var.shape) & (var > 0.0)
    return float(np.sum((sa - sb)[sel] ** 2 / var[sel])), int(sel.sum())


@pytest.mark.parametrize("name", ["scattering-ms-plastic", "slab-matched"])
def test_polarized_lane_and_path_kernels_agree(name):
    """Polarized light (``docs/polarization.md``): the lane kernel's Mueller matrices against the
    per-path kernel's, every element cell by cell (reflected and transmitted), and the energies,
    within their standard errors. The stacks' events: walks (dielectric), anisotropy, a scattering
    medium, a Lambertian base, rough dielectric interfaces from both sides, an index-matched interface,
    absorption. (The lane kernel's films and conductors are checked against their Fresnel matrices
    and Mitsuba's roughconductor in tests/goniometer/test_polarized.py.)"""
    rays = 80_000
    lanes = _trace_polarized(STACKS[name], tracer.KERNEL_LANES, 1, rays)
    paths = _trace_polarized(STACKS[name], tracer.KERNEL_PATHS, 2, rays)
    for part in (5, 6) if STACKS[name].transmits else (5,):
        chi2, dof = _mueller_chi2(lanes[part], paths[part], rays)
        assert dof >= 200, f"only {dof} elements hit well enough"
        assert chi2 < chi2_limit(dof), f"{name} part {part}: chi2 {chi2:.1f} over {dof} elements"
    for row in range(tracer.N_ENERGY_SQ):
        var = (lanes[3][row] - lanes[2][row] ** 2 / rays) + (paths[3][row] - paths[2][row] ** 2 / rays)
        assert np.all(np.abs(lanes[2][row] - paths[2][row]) <= Z_TOL * np.sqrt(var) + 1e-12 * rays), row
    # the books close path by path (a Fresnel event's change of the weight is booked as absorbed)
    total = lanes[2][:tracer.N_ENERGY].sum(0) - lanes[2][tracer.E_REFLECTED_WITHOUT_BASE]
    np.testing.assert_allclose(total, rays, rtol=1e-12)
    # every cell's intensity is its M00, order by order summed
    np.testing.assert_allclose(lanes[0][..., :K, :].sum(-2), lanes[5][..., 0, :], rtol=1e-12, atol=1e-12)


def test_a_polarized_check_between_kernels_can_fail():
    """The same element-wise comparison tells a coat of index 1.5 from one of 1.6."""
    s = STACKS["slab-matched"]
    other = Stack("s2", (Interface(0.2, (1.6,) * 3),) + s.layers[1:], "slab")
    chi2, dof = _mueller_chi2(_trace_polarized(s, tracer.KERNEL_LANES, 1, 80_000)[5],
                              _trace_polarized(other, tracer.KERNEL_PATHS, 2, 80_000)[5], 80_000)
    assert chi2 > chi2_limit(dof)
