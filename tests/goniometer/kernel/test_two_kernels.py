"""The lane kernel (``goniometer.kernel.tracer._trace_chunk``) and the per-path kernel
(``goniometer.kernel.paths.trace_paths``, the driver of the per-path transport
``goniometer.kernel.onepath.trace_path`` that the CUDA kernel runs too) are two implementations of
the same transport (``docs/kernel.md``): forced onto the same stacks, with independent random
numbers, they agree
cell by cell and in every energy term within their standard errors. Stacks cover every kind of
event: rough dielectric and conductor interfaces, anisotropy, absorbing and scattering media
(chromatic: spectral MIS; achromatic; with walks, a Lambertian base, a transmitting base),
multiple-scattering walks, an index-matched interface, height-correlated masking, thin films (on
a dielectric met from above and below, on a conductor; single scattering and walks)."""

from __future__ import annotations

import numpy as np
import pytest

from goniometer.kernel import tracer
from goniometer.run.settings import EVENT_CAP
from goniometer.grids.slice_grid import boundary_tables, light_direction
from goniometer.stack import Film, Interface, Lambertian, Medium, Stack
from goniometer.kernel.packing import pack
from goniometer.testing import Z_TOL, chi2_limit

RAYS = 240_000
RES = (9, 36)
K = 5

STACKS = {
    "metal": Stack("m", (Interface(0.1, (1.5,) * 3), Medium((0.1, 0.2, 0.5)),
                         Interface(0.3, (1.1, 1.2, 1.3), (1.0, 0.5, 2.0))), "metal"),
    "aniso-plastic": Stack("p", (Interface(0.3, (1.5,) * 3, roughness_y=0.1, rotation_deg=30.0), Medium((0.1, 0.2, 0.3)),
                                 Lambertian((0.2, 0.5, 0.8))), "plastic"),
    "slab-matched": Stack("s", (Interface(0.2, (1.5,) * 3), Medium((0.05, 0.1, 0.2)), Interface(0.4, (1.5,) * 3),
                                Interface(0.3, (1.0,) * 3)), "slab"),
    # (an index-matched top: the lane kernel crosses it when a lane takes a path)
    "scattering": Stack("e", (Interface(0.0, (1.0,) * 3), Medium((0.5, 1.0, 2.0), (0.9, 0.6, 0.3), 0.7),
                              Interface(0.2, (1.1,) * 3, (2.0,) * 3)), "metal"),
    # an achromatic medium (no spectral MIS), back-scattering, under an anisotropic multiple-scattering
    # top, over a Lambertian base
    "scattering-ms-plastic": Stack("q", (Interface(0.4, (1.5,) * 3, roughness_y=0.2, rotation_deg=20.0,
                                                   multiple_scattering=True),
                                         Medium((0.8,) * 3, (0.9, 0.7, 0.5), -0.3), Lambertian((0.6, 0.4, 0.2))),
                                   "plastic"),
    # a chromatic scattering medium and an absorbing one in one transmitting slab
    "scattering-slab": Stack("t", (Interface(0.2, (1.5,) * 3), Medium((0.3, 0.6, 1.2), (0.95, 0.8, 0.6), 0.5),
                                   Interface(0.3, (1.4,) * 3), Medium((0.1, 0.2, 0.3)), Interface(0.25, (1.0,) * 3)),
                             "slab"),
    "ms-slab": Stack("w", (Interface(0.5, (1.5,) * 3, multiple_scattering=True), Medium((0.1, 0.1, 0.1)),
                           Interface(0.6, (1.0,) * 3, multiple_scattering=True)), "slab"),
    "ms-aniso-metal": Stack("x", (Interface(0.4, (1.5,) * 3, roughness_y=0.1, rotation_deg=30.0,
                                            multiple_scattering=True), Medium((0.1, 0.2, 0.4)),
                                  Interface(0.5, (1.1, 1.2, 1.3), (1.0, 0.5, 2.0), multiple_scattering=True)), "metal"),
    # thin films: an absorbing one on a rough coat (met from above and below), a clear one on a
    # multiple-scattering conductor
    "film-metal": Stack("fm", (Interface(0.3, (1.5,) * 3, film=Film(400.0, (1.33, 1.38, 1.45), (0.0, 0.01, 0.03))),
                               Medium((0.1, 0.2, 0.3)),
                               Interface(0.4, (0.2, 0.9, 1.3), (3.5, 2.5, 2.0), film=Film(90.0, (1.46,) * 3),
                                         multiple_scattering=True)), "metal", wavelengths_nm=(450.0, 550.0, 650.0)),
    # a clear film on a walk (from above and below) over a soap-film-like index-matched bottom
    "film-slab": Stack("fs", (Interface(0.4, (1.5,) * 3, film=Film(250.0, (1.9,) * 3), multiple_scattering=True),
                              Medium((0.05, 0.1, 0.2)),
                              Interface(0.3, (1.0,) * 3, film=Film(600.0, (1.33, 1.34, 1.35), (0.0, 0.0, 0.02)))),
                       "slab", wavelengths_nm=(450.0, 550.0, 650.0)),
}


def _trace(stack: Stack, kernel: int, seed: int, height_correlated: bool = False):
    p = pack(stack)
    l = light_direction(40.0, 10.0)
    run = tracer.prepare(p, l, RAYS, 1 << 14, seed, 0, 0, *RES, boundary_tables("classic", *RES), K,
                         EVENT_CAP, height_correlated=height_correlated, kernel=kernel)
    nb = run.n_chunks
    bt = RES if stack.transmits else (1, 1)
    brdf = np.empty((nb,) + RES + (K + 2, 3))
    btdf = np.empty((nb,) + bt + (K + 2, 3))
    energy = np.empty((nb, tracer.N_ENERGY, 3))
    energy_sq = np.empty((nb, tracer.N_ENERGY_SQ, 3))
    counts = np.empty((nb, tracer.N_COUNTS), dtype=np.int64)
    tracer.launch(run, 0, (brdf, btdf, energy, energy_sq, counts))
    return brdf.sum(0), btdf.sum(0), energy.sum(0), energy_sq.sum(0), counts.sum(0)


def _cells_chi2(a, b):
    """Chi-square of two independent samples' cell sums (all orders, per channel) over the cells
    with at least 25 effective hits in each; each cell's variance from both samples' squares."""
    sa, qa = a[..., :K, :].sum(-2), a[..., K, :]
    sb, qb = b[..., :K, :].sum(-2), b[..., K, :]
    var = (qa - sa ** 2 / RAYS) + (qb - sb ** 2 / RAYS)
    hits_a = sa ** 2 / np.maximum(qa, 1e-300)
    hits_b = sb ** 2 / np.maximum(qb, 1e-300)
    sel = (hits_a >= 25.0) & (hits_b >= 25.0)
    return float(np.sum((sa - sb)[sel] ** 2 / var[sel])), int(sel.sum())


@pytest.mark.parametrize("name", sorted(STACKS))
def test_lane_and_path_kernels_agree(name):
    stack = STACKS[name]
    hc = name == "metal"
    lanes = _trace(stack, tracer.KERNEL_LANES, 1, hc)
    paths = _trace(stack, tracer.KERNEL_PATHS, 2, hc)
    for part in (0, 1) if stack.transmits else (0,):
        chi2, dof = _cells_chi2(lanes[part], paths[part])
        assert dof >= 40, f"only {dof} cells hit well enough"
        assert chi2 < chi2_limit(dof), f"{name} part {part}: chi2 {chi2:.1f} over {dof} cells"
    e_a, q_a, e_b, q_b = lanes[2], lanes[3], paths[2], paths[3]
    for row in range(tracer.N_ENERGY_SQ):
        var = (q_a[row] - e_a[row] ** 2 / RAYS) + (q_b[row] - e_b[row] ** 2 / RAYS)
        d = e_a[row] - e_b[row]
        ok = np.abs(d) <= Z_TOL * np.sqrt(var) + 1e-12 * RAYS
        assert ok.all(), f"{name} energy row {row}: {e_a[row] / RAYS} vs {e_b[row] / RAYS}"
    # each kernel's books close per channel: every ray's unit weight is accounted for
    for e in (e_a, e_b):
        total = e[:tracer.N_ENERGY].sum(0) - e[tracer.E_REFLECTED_WITHOUT_BASE]
        np.testing.assert_allclose(total, RAYS, rtol=1e-12)
    # same events per ray within noise (a path's event count has a standard deviation of a few)
    assert abs(lanes[4][1] - paths[4][1]) / RAYS < 0.05 * max(1.0, paths[4][1] / RAYS)


def test_the_lane_kernel_is_picked_where_every_event_is_vectorised():
    """Every stack takes the lane kernel (scattering media, walks and height-correlated masking
    included); the height-correlated variant only where some interface scatters singly (a walk
    ignores the setting)."""
    for name, stack in STACKS.items():
        p = pack(stack)
        assert tracer.kernel_flags(p, False, False).lanes is True, name
        only_walks = all(layer.multiple_scattering for layer in stack.layers if isinstance(layer, Interface))
        variant = tracer.kernel_flags(p, True, False)
        assert variant.lanes is True and variant.height_correlated is (None if only_walks else True), name
        # a scattering medium is the media variant's, whose event makes the free flights
        assert (tracer.kernel_flags(p, False, False).media is True) == name.startswith("scattering"), name
        # the per-path kernel's variants are the masking's and the films'
        paths = tracer.kernel_flags(p, True, True, tracer.KERNEL_PATHS)
        assert paths.film is (True if name.startswith("film") else None), name
        none = tracer.Variant(*(None,) * len(tracer.Variant._fields))
        assert paths._replace(height_correlated=None, film=None) == none


def test_a_check_between_kernels_can_fail():
    """The same comparison tells a conductor of roughness 0.3 from one of 0.35."""
    s = STACKS["metal"]
    other = Stack("m2", s.layers[:2] + (Interface(0.35, (1.1, 1.2, 1.3), (1.0, 0.5, 2.0)),), "metal")
    chi2, dof = _cells_chi2(_trace(s, tracer.KERNEL_LANES, 1)[0], _trace(other, tracer.KERNEL_PATHS, 2)[0])
    assert chi2 > chi2_limit(dof)


def _tabulate_energy(stack: Stack, kernel: int, seed: int, rays: int = 200_000):
    """Energy sums of a tabulation's paths (each draws its own light direction, cosine-weighted)."""
    p = pack(stack)
    cr = 1 << 14
    run = tracer.prepare(p, (0.0, 0.0, 1.0), rays, cr, seed, 9, tracer.P_TABULATE, 1, 1,
                         boundary_tables("classic", 1, 1), 1, EVENT_CAP, tabulate=True, kernel=kernel)
    nb = run.n_chunks
    energy = np.empty((nb, tracer.N_ENERGY, 3))
    energy_sq = np.empty((nb, tracer.N_ENERGY_SQ, 3))
    exit_w = np.empty((nb, cr, 3))
    tracer.launch(run, 0, (np.empty((nb, 1, 1, 3, 3)), np.empty((nb, 1, 1, 3, 3)), energy, energy_sq,
                           np.empty((nb, tracer.N_COUNTS), dtype=np.int64)),
                  (np.empty((nb, cr), dtype=np.int64), exit_w))
    return energy.sum(0), energy_sq.sum(0), rays


@pytest.mark.parametrize("name", ["scattering-ms-plastic"])
def test_tabulations_agree_between_kernels(name):
    """A tabulation (per-path light directions) of a stack with walks and a scattering medium: the
    lane kernel's energies against the per-path kernel's, within their standard errors."""
    e_a, q_a, n = _tabulate_energy(STACKS[name], tracer.KERNEL_LANES, 1)
    e_b, q_b, _ = _tabulate_energy(STACKS[name], tracer.KERNEL_PATHS, 2)
    for row in (tracer.E_REFLECTED, tracer.E_TRANSMITTED, tracer.E_ABSORBED):
        var = (q_a[row] - e_a[row] ** 2 / n) + (q_b[row] - e_b[row] ** 2 / n)
        assert np.all(np.abs(e_a[row] - e_b[row]) <= Z_TOL * np.sqrt(var) + 1e-12 * n), (row, e_a[row], e_b[row])

