"""Bounce order 1 integrated over the cells (``first_order = "integrated"``, docs/first-order.md).

References: the traced order 1 of the same stack (its own per-cell standard errors), the Fresnel
closed form for a smooth interface, the two slice parametrizations against each other and against
an adaptive quadrature over the hemisphere, and replicate seeds for the standard errors.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy import integrate

from goniometer import optics
from goniometer.run.first_order import first_order_fractions
from goniometer.run.results import cell_geometry, run_description
from goniometer.run.loop import simulate
from goniometer.run.settings import SettingsError, SimulationSettings
from goniometer.grids.slice_grid import SliceGrid, light_direction
from goniometer.stack import Interface, Lambertian, Medium, Stack
from goniometer.run.tasks import trace_incident
from goniometer.testing import Z_TOL, assert_cells_match, assert_sparse_flux_matches, cell_chi2, chi2_limit

COAT = (Medium((0.1, 0.2, 0.4)), Lambertian((0.3, 0.5, 0.7)))
ANISO_METAL = Stack("aniso-metal", (Interface(0.1, (0.2, 0.9, 1.1), (3.0, 2.5, 2.2), roughness_y=0.3,
                                              rotation_deg=30.0),), "metal")


def _traced_order_one(stack: Stack, s: SimulationSettings, m: int = 0):
    """Traced order-1 cell values, their standard errors (squared weights of order-1 exits: all
    exits' minus internal exits'), the cells' projected solid angles and mask."""
    part = trace_incident(stack, s, m)
    n = s.rays
    omega, mask = cell_geometry(s.parametrization, *s.resolution, s.incident_deg[m], s.incident_phi_deg[m])
    inv = np.divide(1.0, n * omega, out=np.zeros_like(omega), where=omega > 0)
    s1 = part.brdf[0]
    sq1 = part.brdf_sq[0] - part.brdf_sq[1]
    var = np.maximum(sq1 - s1 * s1 / n, 0.0) / (n - 1)
    return s1 * inv, np.sqrt(var * n) * inv, omega, mask


def _integrated(stack: Stack, s: SimulationSettings, m: int = 0) -> np.ndarray:
    omega, _ = cell_geometry(s.parametrization, *s.resolution, s.incident_deg[m], s.incident_phi_deg[m])
    f = first_order_fractions(stack, s.parametrization, *s.resolution,
                              light_direction(s.incident_deg[m], s.incident_phi_deg[m]), s.masking)
    return np.divide(f, omega, out=np.zeros_like(f), where=omega > 0)


CASES = {
    "rough-coat-classic": (Stack("p", (Interface(0.2, (1.5,) * 3),) + COAT, "plastic"),
                           dict(incident_deg=(30.0,), parametrization="classic", resolution=(30, 60))),
    "sharp-coat-half-hc": (Stack("p", (Interface(0.05, (1.5,) * 3),) + COAT, "plastic"),
                           dict(incident_deg=(60.0,), parametrization="half", resolution=(30, 60),
                                masking="height-correlated")),
    "aniso-conductor-classic": (ANISO_METAL, dict(incident_deg=(45.0,), incident_phi_deg=(20.0,),
                                                  parametrization="classic", resolution=(30, 60))),
    "aniso-conductor-half": (ANISO_METAL, dict(incident_deg=(70.0,), incident_phi_deg=(110.0,),
                                               parametrization="half", resolution=(30, 60))),
}


@pytest.mark.parametrize("case", list(CASES))
def test_integrated_cells_match_the_traced_order_one(case):
    stack, kw = CASES[case]
    s = SimulationSettings(rays=400_000, seed=11, threads=2, **kw)
    value, se, omega, mask = _traced_order_one(stack, s)
    model = _integrated(stack, s)
    # per cell where >= 20 paths are expected (weights <= 1), every channel
    assert_cells_match(value, se, model, omega[None], s.rays, min_expected=20.0, where=mask[None], min_cells=60)
    # the sparse rest in aggregate: its total flux
    assert_sparse_flux_matches(value, se, model, omega[None], s.rays, min_expected=20.0, where=mask[None])


def test_the_comparison_tells_a_wrong_rotation():
    """The check above can fail: the same traced cells against the integral of an interface rotated
    by 0 instead of 30 degrees (or with its roughnesses swapped) are rejected."""
    stack, kw = CASES["aniso-conductor-classic"]
    s = SimulationSettings(rays=400_000, seed=11, threads=2, **kw)
    value, se, omega, mask = _traced_order_one(stack, s)
    top = stack.layers[0]
    for wrong in (Interface(0.1, top.ior, top.extinction, roughness_y=0.3, rotation_deg=0.0),
                  Interface(0.3, top.ior, top.extinction, roughness_y=0.1, rotation_deg=30.0)):
        model = _integrated(Stack("wrong", (wrong,), "metal"), s)
        chi2, dof = cell_chi2(value, se, model, omega[None], s.rays, 20.0, mask[None])
        assert chi2 > chi2_limit(dof), (wrong, chi2, dof)


def test_the_option_replaces_order_one_and_nothing_else(metal):
    s = SimulationSettings(incident_deg=(0.0, 75.0), rays=200_000, resolution=(18, 36), seed=5, threads=2)
    a = simulate(metal, s)
    b = simulate(metal, s.with_overrides(first_order="integrated"))
    assert np.array_equal(a.brdf.orders[:, 1:], b.brdf.orders[:, 1:])
    assert np.array_equal(a.brdf.stderr_internal, b.brdf.stderr_internal)
    for k in a.energy:
        assert np.array_equal(a.energy[k], b.energy[k])
    # no variance from order 1: the total's standard error is the internal paths'
    assert np.array_equal(b.brdf.stderr, b.brdf.stderr_internal)
    assert np.allclose(b.brdf.value, b.brdf.orders.sum(axis=1), rtol=1e-12, atol=0.0)
    for m in range(2):
        assert np.allclose(b.brdf.orders[m, 0], _integrated(metal, s, m), rtol=1e-12, atol=0.0)
    # and the total noise floor is far lower (the coat's specular peak carried most of it)
    om = a.brdf.proj_solid_angle[:, None]
    assert np.sum(b.brdf.stderr ** 2 * om) < 0.5 * np.sum(a.brdf.stderr ** 2 * om)


def test_standard_errors_agree_with_replicate_seeds(plastic):
    """Scatter of cell values over independent seeds against the standard errors the runs report
    (integrated order 1: the total's standard error must not count order 1)."""
    R = 12
    n = 100_000
    runs = [simulate(plastic, SimulationSettings(incident_deg=(30.0,), rays=n, resolution=(15, 30), seed=100 + r,
                                                 threads=2, first_order="integrated"))
            for r in range(R)]
    x = np.array([r.brdf.value[0] for r in runs])
    se2 = np.mean([r.brdf.stderr[0] ** 2 for r in runs], axis=0)
    omega = runs[0].brdf.proj_solid_angle[0]
    internal = x - np.array([r.brdf.orders[0, 0] for r in runs])
    sel = (n * internal.mean(axis=0) * omega[None] >= 20.0) & (se2 > 0)
    t = (((x - x.mean(axis=0)) ** 2).sum(axis=0)[sel] / se2[sel]).sum()
    dof = int(np.count_nonzero(sel)) * (R - 1)
    assert dof > 1000
    assert abs(t / dof - 1.0) < Z_TOL * math.sqrt(2.0 / dof) + 0.02, (t / dof, dof)


@pytest.mark.parametrize("param", ["classic", "half"])
def test_smooth_interface_puts_fresnel_in_the_mirror_cell(param):
    stack = Stack("smooth", (Interface(0.0, (1.5,) * 3),) + COAT, "plastic")
    theta = 40.0
    l = light_direction(theta, 0.0)
    f = first_order_fractions(stack, param, 30, 60, l, "separable")
    c = math.cos(math.radians(theta))
    st = math.sqrt(1.0 - (1.0 - c * c) / 1.5 ** 2)
    rs = (c - 1.5 * st) / (c + 1.5 * st)
    rp = (1.5 * c - st) / (1.5 * c + st)
    assert np.count_nonzero(f[0]) == 1
    assert f[0].sum() == pytest.approx(0.5 * (rs * rs + rp * rp), rel=1e-12)
    i, j = SliceGrid(param, 30, 60).cell_of(l, np.array([-l[0], -l[1], l[2]]))
    assert f[0, i, j] > 0.0
    # the traced smooth reflection lands in the same cell, with the same mean
    s = SimulationSettings(incident_deg=(theta,), rays=200_000, parametrization=param, resolution=(30, 60), seed=2,
                           threads=2)
    value, se, omega, _ = _traced_order_one(stack, s)
    assert np.count_nonzero(value[0]) == 1 and value[0, i, j] > 0.0
    assert abs(value[0, i, j] * omega[i, j] - f[0, i, j]) < Z_TOL * se[0, i, j] * omega[i, j]


@pytest.mark.parametrize("alpha,theta,masking", [(0.3, 30.0, "separable"), (0.1, 75.0, "height-correlated")])
def test_cell_sums_are_the_directional_albedo(alpha, theta, masking):
    """Both parametrizations sum to the hemisphere's integral of f_1 cos, found by scipy's adaptive
    quadrature in (cos theta_v, phi_v)."""
    stack = Stack("c", (Interface(alpha, (1.5,) * 3),) + COAT, "plastic")
    l = light_direction(theta, 0.0)
    hc = masking == "height-correlated"

    def f(phi, mu):
        s = math.sqrt(max(0.0, 1.0 - mu * mu))
        return optics.microfacet_reflection(l[0], l[1], l[2], s * math.cos(phi), s * math.sin(phi), mu, alpha,
                                            alpha, 1.5, 0.0, hc) * mu

    # the lobe is symmetric about phi = 0: twice the half space, split where it peaks
    mu_l = math.cos(math.radians(theta))
    ref = 2.0 * sum(integrate.dblquad(f, a, b, 0.0, math.pi, epsabs=1e-12, epsrel=1e-10)[0]
                    for a, b in ((0.0, 0.5), (0.5, mu_l), (mu_l, 1.0)))
    for param in ("classic", "half"):
        got = first_order_fractions(stack, param, 90, 360, l, masking)[0].sum()
        assert got == pytest.approx(ref, rel=1e-6), param


MS_TOPS = {
    # the lane kernel (its vectorised event begins the walks); anisotropic
    "gold": Stack("gold-ms", (Interface(0.5, (0.18, 0.42, 1.37), (3.42, 2.35, 1.77), roughness_y=0.4,
                                        rotation_deg=-20.0, multiple_scattering=True),), "metal"),
    # the per-path kernel (a scattering medium)
    "coat-over-cloud": Stack("cloud", (Interface(0.5, (1.5,) * 3, multiple_scattering=True),
                                       Medium((1.0,) * 3, (0.8,) * 3, 0.3), Lambertian((0.5,) * 3)), "plastic"),
}


@pytest.mark.parametrize("name", list(MS_TOPS))
def test_multiple_scattering_top_integrates_its_one_bounce_walks(name):
    """On a multiple-scattering top, order 1 is a walk; its walks of one bounce have the
    height-correlated closed form (Heitz et al. 2016) and are integrated, longer ones stay traced.
    Against the traced order 1 of the same paths: cell by cell (the traced order 1's standard error
    bounds that of the difference, which only the one-bounce walks make), and in total, where for
    the gold the separable masking's closed form is told apart."""
    stack = MS_TOPS[name]
    s = SimulationSettings(incident_deg=(70.0,), incident_phi_deg=(30.0,), rays=1_000_000, resolution=(30, 60),
                           seed=7, threads=2)
    value, se, omega, mask = _traced_order_one(stack, s)
    b = simulate(stack, s.with_overrides(first_order="integrated"))
    a = simulate(stack, s)
    assert np.array_equal(a.brdf.orders[:, 1:], b.brdf.orders[:, 1:])
    assert np.array_equal(a.brdf.stderr_internal, b.brdf.stderr_internal)
    assert np.array_equal(a.brdf.orders[0, 0], value)
    # the walks of several bounces are still traced: the total's standard error is not 0
    assert np.all((b.brdf.stderr[0] - b.brdf.stderr_internal[0]).max(axis=(1, 2)) > 0)
    assert_cells_match(value, se, b.brdf.orders[0, 0], omega[None], s.rays, min_expected=20.0, where=mask[None],
                       min_cells=500)
    total_se = math.sqrt(((se * omega[None]) ** 2).sum(axis=(1, 2)).max())
    got = (b.brdf.orders[0, 0] * omega[None]).sum(axis=(1, 2))
    want = (value * omega[None]).sum(axis=(1, 2))
    assert np.all(np.abs(got - want) < Z_TOL * total_se), (got, want, total_se)
    if name != "gold":
        return
    # can fail: the separable closed form instead of the height-correlated one
    l = light_direction(70.0, 30.0)
    single = Stack("gold", (dataclasses.replace(stack.layers[0], multiple_scattering=False),), "metal")
    sep = first_order_fractions(single, "classic", 30, 60, l, "separable").sum(axis=(1, 2))
    hc = first_order_fractions(single, "classic", 30, 60, l, "height-correlated").sum(axis=(1, 2))
    assert np.allclose(first_order_fractions(stack, "classic", 30, 60, l, "separable").sum(axis=(1, 2)), hc)
    assert np.all(np.abs(got - hc + sep - want) > Z_TOL * total_se), (got - hc + sep, want)


def test_unsupported_stacks_and_values_are_refused():
    with pytest.raises(SettingsError, match="first_order"):
        SimulationSettings(first_order="integrate")
    s = SimulationSettings(incident_deg=(30.0,), rays=100, resolution=(4, 8), first_order="integrated")
    with pytest.raises(SettingsError, match="first_order: integrated needs an interface on top"):
        simulate(Stack("l", (Lambertian((0.5,) * 3),), "plastic"), s)


def test_run_description_names_the_option_only_when_used(plastic):
    s = SimulationSettings()
    assert "first_order" not in run_description(plastic, s)["settings"]
    d = run_description(plastic, s.with_overrides(first_order="integrated"))
    assert d["settings"]["first_order"] == "integrated"
    assert SimulationSettings.from_mapping({"first_order": "integrated"}).first_order == "integrated"
