"""The effective darkening and effective base roughness (models.production.study.effective, docs/production.md
sections 2-3), against cases whose answer is known in closed form:

* an index-matched coat (ior = 1.0, any roughness) is optically absent (docs/material-format.md 5):
  the coated stack is its bare base, so the effective darkening is 1 and the effective roughness is
  the base's own alpha -- checked on independent simulations of the coated and the bare stack, with
  tolerances from their standard errors;
* synthetic internal slices made of the spec's own layered lobe at a known alpha and scaled by a
  known darkening give those values back (the estimators invert their own definition).
"""

from __future__ import annotations

import numpy as np
import pytest

import goniometer as g
from goniometer.grids.slice_grid import SliceGrid
from goniometer.stack import Interface, Lambertian, Stack
from models.production.study.effective import (ALPHA_MAX, ALPHA_MIN, ProductionError, bare_key, coat_albedo_rows,
                                               coated_base, darkening_from, effective_darkening, effective_roughness,
                                               median_angle, model_ring_energy, roughness_from)
from goniometer.testing import Z_TOL

GOLD = dict(ior=(0.17, 0.43, 1.38), extinction=(3.15, 2.45, 1.9))
SETTINGS = dict(incident_deg=(0.0, 40.0), resolution=(45, 90), parametrization="classic", seed=5)


def _metal(alpha: float) -> Interface:
    return Interface(alpha, GOLD["ior"], GOLD["extinction"])


def _sim(stack: Stack, rays: int, seed: int = 5) -> g.SimulationResult:
    return g.simulate(stack, g.SimulationSettings(rays=rays, **{**SETTINGS, "seed": seed}))


@pytest.fixture(scope="module")
def index_matched():
    """A rough index-matched coat over a rough gold base, and the bare base (independent seeds)."""
    base = _metal(0.2)
    coated = Stack("metal/matched", (Interface(0.3, (1.0,) * 3), base), "metal")
    bare = Stack("bare/gold", (base,), "other")
    return _sim(coated, 200_000, seed=5), _sim(bare, 200_000, seed=6)


def test_configuration_and_twin_key():
    coated = Stack("m", (Interface(0.1, (1.5,) * 3), _metal(0.2)), "metal")
    cfg = coated_base(coated)
    assert (cfg.base, cfg.coat_ior, cfg.coat_alpha, cfg.base_alpha) == ("conductor", 1.5, 0.1, 0.2)
    assert cfg.base_key == bare_key(Stack("b", (_metal(0.2),)))
    assert cfg.base_key != bare_key(Stack("b", (_metal(0.2 + 1e-9),)))
    # MS twins are different bases
    assert bare_key(Stack("b", (_metal(0.2),)).with_multiple_scattering()) != cfg.base_key
    plastic = Stack("p", (Interface(0.0, (1.3,) * 3), Lambertian((0.1, 0.4, 0.8))), "plastic")
    assert coated_base(plastic).base == "lambertian" and coated_base(plastic).base_alpha is None
    # not production stacks
    assert coated_base(Stack("bare", (_metal(0.2),))) is None
    assert coated_base(Stack("two coats", (Interface(0.1, (1.5,) * 3), Interface(0.1, (1.3,) * 3), _metal(0.2)))) is None
    assert bare_key(coated) is None


def test_index_matched_coat_has_no_darkening(index_matched):
    coated, bare = index_matched
    assert np.all(coat_albedo_rows(0.3, 1.0, "separable", 45) == 0.0)   # Fresnel of a matched interface
    d = effective_darkening(coated, bare)
    assert np.all(d.stderr > 0) and np.all(d.stderr < 0.01)
    z = np.abs(d.value - 1.0) / d.stderr
    assert np.all(z < Z_TOL), f"D = {d.value} +- {d.stderr}"


def test_index_matched_coat_keeps_the_base_roughness(index_matched):
    coated, _ = index_matched
    r = effective_roughness(coated)
    assert not r.clamped and 0 < r.stderr < 0.02
    assert abs(r.alpha - 0.2) < Z_TOL * r.stderr, f"alpha_eff = {r.alpha} +- {r.stderr}"


def test_index_matched_coat_over_lambertian():
    base = Lambertian((0.1, 0.5, 0.9))
    coated = _sim(Stack("p", (Interface(0.2, (1.0,) * 3), base), "plastic"), 50_000, seed=7)
    bare = _sim(Stack("b", (base,)), 50_000, seed=8)
    d = effective_darkening(coated, bare)
    assert np.all(np.abs(d.value - 1.0) < Z_TOL * d.stderr), f"D = {d.value} +- {d.stderr}"
    with pytest.raises(ProductionError, match="not a clear coat over a conductor"):
        effective_roughness(coated)


def test_a_real_coat_darkens_and_roughens(index_matched):
    """Sanity on the other side of the limit: a glass coat (n = 1.6) over the same base darkens it
    (internal light lost to the base's absorption on extra bounces) and widens its lobe (refraction
    out of the denser coat), both far beyond the noise."""
    _, bare = index_matched
    coated = _sim(Stack("m", (Interface(0.0, (1.6,) * 3), _metal(0.2)), "metal"), 100_000, seed=9)
    d = effective_darkening(coated, bare)
    assert np.all(d.value < 1.0 - 10 * d.stderr)
    r = effective_roughness(coated)
    assert r.alpha > 0.2 + 10 * r.stderr


def test_wrong_twin_and_half_slices_are_refused(index_matched):
    coated, bare = index_matched
    other = _sim(Stack("bare/other", (_metal(0.3),)), 2_000)
    with pytest.raises(ProductionError, match="is not the bare base"):
        effective_darkening(coated, other)
    half = g.simulate(coated.stack, g.SimulationSettings(rays=2_000, **{**SETTINGS, "parametrization": "half"}))
    with pytest.raises(ProductionError, match="classic"):
        effective_roughness(half)


def _synthetic_cells(alpha: float, cfg, masking: str, darkening: float, grid: SliceGrid):
    """Internal cells at normal incidence that are exactly the spec's layered lobe of ``alpha`` times
    ``darkening`` in ring energy (spread evenly over each ring's cells)."""
    edges = grid.theta_edges_deg()
    rows = coat_albedo_rows(cfg.coat_alpha, cfg.coat_ior, masking, grid.n_theta)
    ring = darkening * model_ring_energy(alpha, cfg, rows, edges, masking)
    t0, t1 = np.radians(edges[:-1]), np.radians(edges[1:])
    omega = np.repeat(((np.sin(t1) ** 2 - np.sin(t0) ** 2) / 2 * np.radians(360.0 / grid.n_phi))[:, None],
                      grid.n_phi, axis=1)
    value = np.repeat((ring / omega.sum(axis=1))[:, None], grid.n_phi, axis=1)
    return np.repeat(value[None], 3, axis=0), omega, edges


@pytest.mark.parametrize("alpha", [0.02, 0.15, 0.4, 0.8])
def test_roughness_estimator_inverts_its_definition(alpha):
    grid = SliceGrid("classic", 45, 90)
    cfg = coated_base(Stack("m", (Interface(0.1, (1.7,) * 3), _metal(0.3)), "metal"))
    cells, omega, edges = _synthetic_cells(alpha, cfg, "separable", 0.37, grid)
    r = roughness_from(cells, omega, cfg, "separable", edges)
    assert r.alpha == pytest.approx(alpha, rel=1e-5) and not r.clamped


def test_median_is_monotone_in_alpha():
    """Well-posedness: the median exit angle of the layered lobe grows strictly with alpha."""
    cfg = coated_base(Stack("m", (Interface(0.25, (2.0,) * 3), _metal(0.3)), "metal"))
    edges = SliceGrid("classic", 45, 90).theta_edges_deg()
    rows = coat_albedo_rows(cfg.coat_alpha, cfg.coat_ior, "separable", 45)
    alphas = np.geomspace(ALPHA_MIN, ALPHA_MAX, 40)
    med = [median_angle(edges, model_ring_energy(a, cfg, rows, edges, "separable")) for a in alphas]
    assert np.all(np.diff(med) > 0)


def test_median_angle_by_hand():
    edges = np.array([0.0, 10.0, 20.0, 30.0])
    assert median_angle(edges, np.array([1.0, 2.0, 1.0])) == pytest.approx(15.0)
    assert median_angle(edges, np.array([3.0, 1.0, 0.0])) == pytest.approx(10.0 * 2.0 / 3.0)
    with pytest.raises(ProductionError):
        median_angle(edges, np.zeros(3))


def test_darkening_ratio_of_sums():
    e = np.array([[0.2, 0.4, 0.6], [0.1, 0.2, 0.3]])
    p = np.array([[0.4, 0.5, 0.6], [0.4, 0.5, 0.6]])
    d = darkening_from(e, np.zeros_like(e), p, np.zeros_like(p))
    assert d.value == pytest.approx([0.3 / 0.8, 0.6 / 1.0, 0.9 / 1.2])
    assert d.per_incident == pytest.approx(e / p)


def test_coat_albedo_is_the_direct_fgd_quadrature():
    """The vectorised quadrature equals fgd_direct point by point, and a smooth coat's albedo is the
    Fresnel reflectance (goniometer.optics) at each row's centre."""
    from goniometer.optics import np_fresnel_dielectric
    from models.tables import fgd_direct
    rows = coat_albedo_rows(0.1, 1.7, "separable", 45)
    mu = np.cos(np.radians((np.arange(45) + 0.5) * 2.0))
    for i in (0, 20, 44):
        assert rows[i] == pytest.approx(fgd_direct(float(mu[i]), 0.1, 1.7), abs=1e-14)
    smooth = coat_albedo_rows(0.0, 1.7, "separable", 45)
    # 1e-4: the quadrature's accuracy at grazing rows (9e-6 at 89 deg), far below any darkening compared
    assert smooth == pytest.approx(np_fresnel_dielectric(mu, 1.7), abs=1e-4)
