"""The FGD and TIR tables of Belcour's model against independent quadratures.

The tables integrate over the visible-normal parameter disc (models/tables/belcour.py, docs/tables.md). The references
here integrate differently -- the FGD over half vectors (GGX-importance mapping of theta_h, Gauss-
Legendre, through ``optics.np_microfacet_reflection``) and the TIR over outgoing directions split
at the critical angle -- so they share only the optics formulas with the code under test.

Stated error bounds (absolute, tested below; see docs/tables.md):

* material slices (``fgd_slice``): <= 2e-3 for mu >= 0.05 and <= 3.5e-3 for mu >= 0.01;
* 4D table where Fresnel has no critical angle (eta >= 1.2 or kappa >= 0.5): <= 3e-3 for mu >= 0.05;
* TIR table and slices: <= tables.TIR_ERROR = 6e-3 for alpha >= 0.1 and mu >= 0.05 (mostly the indicator
  quadrature's own error; the median is far lower), exact step at alpha = 0.
"""

from __future__ import annotations

import math
import shutil

import numba
import numpy as np
import pytest

from goniometer import atomic
from goniometer import optics
from models.tables import belcour as tables

# -------------------------------------------------------------------------- references


def _gl(n: int, lo: float, hi: float) -> tuple[np.ndarray, np.ndarray]:
    x, w = np.polynomial.legendre.leggauss(n)
    return lo + (hi - lo) * (x + 1.0) / 2.0, w * (hi - lo) / 2.0


def fgd_reference(mu: float, alpha: float, eta: float, kappa: float, n: int = 320,
                  height_correlated: bool = False) -> float:
    """Directional albedo by quadrature over half vectors h: theta_h from the GGX CDF
    ``tan^2 = alpha^2 u / (1 - u)`` (u Gauss-Legendre), phi_h Gauss-Legendre on [0, pi] (the
    integrand is even in phi), value ``Int f(l, v(h)) v_z 4 (l.h) dh``."""
    u, wu = _gl(n, 0.0, 1.0)
    ph, wph = _gl(n, 0.0, math.pi)
    U, P = np.meshgrid(u, ph, indexing="ij")
    W = np.outer(wu, wph) * 2.0 / (2.0 * math.pi)   # du dphi / (2 pi) = D cos dh
    t2 = alpha * alpha * U / (1.0 - U)
    ch = 1.0 / np.sqrt(1.0 + t2)
    sh = np.sqrt(t2) * ch
    hx, hy, hz = sh * np.cos(P), sh * np.sin(P), ch
    lx, lz = math.sqrt(1.0 - mu * mu), mu
    lh = lx * hx + lz * hz
    vx, vy, vz = 2 * lh * hx - lx, 2 * lh * hy, 2 * lh * hz - lz
    f = optics.np_microfacet_reflection(lx, 0.0, lz, vx, vy, vz, alpha, alpha, eta, kappa, height_correlated)
    d = optics.np_ggx_d(hx, hy, hz, alpha, alpha)
    val = np.where(lh > 0, f * np.maximum(vz, 0.0) * 4.0 * lh / (d * hz), 0.0)
    return float(np.sum(val * W))


def tir_reference(mu: float, alpha: float, eta_up: float, n: int = 300) -> float:
    """Escaping fraction of the F = 1 single-scattering GGX lobe: the lobe integrated over
    outgoing directions with theta_o below and above asin(eta_up) separately (Gauss-Legendre in
    theta_o and phi_o), using optics.np_ggx_d and optics.np_ggx_lambda."""
    th_c = math.asin(eta_up)
    lx, lz = math.sqrt(1.0 - mu * mu), mu

    def part(lo: float, hi: float) -> float:
        th, wt = _gl(n, lo, hi)
        ph, wp = _gl(2 * n, 0.0, math.pi)
        T, P = np.meshgrid(th, ph, indexing="ij")
        ox, oy, oz = np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)
        hx, hy, hz = lx + ox, oy, lz + oz
        nn = np.sqrt(hx * hx + hy * hy + hz * hz)
        d = optics.np_ggx_d(hx / nn, hy / nn, hz / nn, alpha, alpha)
        lam_o = optics.np_ggx_lambda(ox, oy, oz, alpha, alpha)
        f = d / (1.0 + lam_o) / (4.0 * lz)
        return float(np.sum(f * np.sin(T) * np.outer(wt, wp)))

    inside = part(0.0, th_c)
    return inside / (inside + part(th_c, math.pi / 2))


# -------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="session")
def built(tmp_path_factory):
    """Tables built from scratch into a fresh directory (exercises build_belcour_tables)."""
    d = tmp_path_factory.mktemp("belcour-tables")
    stages = []
    paths = tables.build_belcour_tables(d, progress=lambda stage, frac: stages.append((stage, frac)))
    return d, paths, stages


@pytest.fixture(scope="session")
def cdir(built) -> str:
    return str(built[0])


@pytest.fixture(scope="session")
def tabs(cdir) -> tables.BelcourTables:
    return tables.load_belcour_tables(cdir)


# -------------------------------------------------------------------------- cache and files


def test_build_writes_versioned_atomic_files(built, tabs):
    d, paths, stages = built
    assert set(paths) == {"fgd", "tir"}
    assert stages and stages[-1] == ("done", 1.0)
    for p in paths.values():
        assert p.exists() and p.parent == d
        with np.load(p) as z:
            assert int(z["version"]) == tables.TABLE_VERSION
            np.testing.assert_array_equal(z["mu"], tables.mu_nodes())
            np.testing.assert_array_equal(z["alpha"], tables.alpha_nodes())
    assert not list(d.glob(atomic.TEMP_GLOB))
    assert tabs.fgd.shape == (tables.N_MU, tables.N_ALPHA, tables.N_ETA, tables.N_KAPPA)
    assert tabs.tir.shape == (tables.N_MU, tables.N_ALPHA, tables.N_ETA_UP)
    assert tabs.kernel.shape == (tables.N_MU, tables.N_ALPHA, tables.N_X)
    # the loader is memoised per directory
    assert tables.load_belcour_tables(d) is tabs


def test_stale_version_is_rebuilt_not_reused(built, tmp_path, monkeypatch):
    d, paths, _ = built
    for p in paths.values():
        shutil.copy(p, tmp_path / p.name)
    # rewrite the FGD file with an older version stamp
    stale = tmp_path / paths["fgd"].name
    with np.load(stale) as z:
        content = {k: z[k] for k in z.files}
    content["version"] = np.int64(tables.TABLE_VERSION - 1)
    np.savez(stale, **content)
    assert tables.read_if_current(stale, False, ("fgd",)) is None
    calls = []

    def fake_build(cache_dir=None, progress=None, height_correlated=False):
        calls.append(cache_dir)
        for p in paths.values():
            shutil.copy(p, tmp_path / p.name)
        return tables.table_paths(cache_dir, height_correlated)

    monkeypatch.setattr(tables, "build_belcour_tables", fake_build)
    tables._load_cached.cache_clear()
    t = tables.load_belcour_tables(tmp_path)
    assert len(calls) == 1
    assert t.fgd.shape[0] == tables.N_MU
    tables._load_cached.cache_clear()


def test_default_cache_dir_follows_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("GONIOMETER_CACHE", str(tmp_path))
    assert tables.default_cache_dir() == tmp_path
    assert tables.table_paths()["fgd"].parent == tmp_path
    monkeypatch.delenv("GONIOMETER_CACHE")
    assert tables.default_cache_dir().name == "goniometer"


# -------------------------------------------------------------------------- FGD


def test_fgd_energy_is_in_unit_interval(tabs, cdir):
    assert np.all(np.isfinite(tabs.fgd)) and tabs.fgd.min() >= 0.0 and tabs.fgd.max() <= 1.0
    # the angular kernel's total weight is the F = 1 albedo: at most 1 (to rounding)
    assert tabs.kernel.min() >= 0.0 and tabs.kernel.sum(axis=-1).max() <= 1.0 + 1e-12
    for eta, kappa in [(1.5, 0.0), (1 / 1.5, 0.0), (1.45 / 1.5, 0.01 / 1.5), (0.3, 3.0)]:
        s = tables.fgd_slice(eta, kappa, cache_dir=cdir)
        for a in (s.upper, s.lower):
            assert np.all(np.isfinite(a)) and a.min() >= 0.0 and a.max() <= 1.0


def test_fgd_alpha_zero_is_fresnel(tabs):
    """At alpha = 0 the table holds the exact Fresnel reflectance at its mu nodes."""
    mus = np.maximum(tables.mu_nodes(), tables.MU_FLOOR)
    for k in (0, 10, 16, 24, 40, 64):
        for m in (0, 1, 8, 40):
            eta, kappa = tables.eta_nodes()[k], tables.kappa_nodes()[m]
            expect = tables.fresnel_on(mus, eta, kappa)
            np.testing.assert_allclose(tabs.fgd[:, 0, k, m], expect, atol=1e-7)


def test_fgd_is_zero_for_index_matched_interface(cdir):
    s = tables.fgd_slice(1.0, 0.0, cache_dir=cdir)
    assert np.all(s.upper == 0.0)


def test_fgd_table_against_independent_quadrature(tabs):
    """4D quadrilinear lookups at random off-grid points where Fresnel has no critical angle:
    |error| <= 3e-3 for mu >= 0.05 (stated bound)."""
    rng = np.random.default_rng(20240611)
    worst = 0.0
    for _ in range(24):
        if rng.uniform() < 0.5:
            eta, kappa = rng.uniform(1.2, 4.0), rng.uniform(0.0, 8.0)
        else:
            eta, kappa = rng.uniform(0.05, 4.0), rng.uniform(0.5, 8.0)
        mu, alpha = rng.uniform(0.05, 1.0), rng.uniform(0.0, 1.0) ** 2
        ref = fgd_reference(mu, alpha, eta, kappa)
        err = abs(float(tabs.fgd_at(mu, alpha, eta, kappa)) - ref)
        worst = max(worst, err)
        assert err <= 3e-3, (mu, alpha, eta, kappa, ref)
    assert worst > 0.0


@pytest.mark.parametrize("eta,kappa", [(1.5, 0.0), (1.9 / 1.5, 0.01 / 1.5), (1.45 / 1.5, 0.01 / 1.5),
                                       (1.2 / 1.5, 1.0 / 1.5), (1.0 / 1.5, 0.0), (0.3, 3.0)])
def test_material_slices_against_independent_quadrature(eta, kappa, cdir):
    """Slices (exact in eta, kappa; split at the critical angle) at random off-grid (mu, alpha):
    |error| <= 2e-3 (mu >= 0.05), 3.5e-3 (mu >= 0.01); within 1e-3 of the critical cosine, where
    a slightly rough FGD changes by ~0.1 over 0.002 in mu, 5e-3."""
    s = tables.fgd_slice(eta, kappa, cache_dir=cdir)
    rng = np.random.default_rng(int(eta * 1000) + int(kappa * 100))
    points = [(mu, 2e-3 if mu >= 0.05 else 3.5e-3) for mu in rng.uniform(0.01, 1.0, 6)]
    if s.mu_split > 0.0:
        points += [(s.mu_split * (1 - 1e-3), 5e-3), (s.mu_split * (1 + 1e-3), 5e-3),
                   (min(1.0, s.mu_split + 0.01), 2e-3)]
    for mu, bound in points:
        alpha = float(rng.uniform(0.0, 1.0) ** 2)
        ref = fgd_reference(mu, alpha, eta, kappa)
        assert abs(float(s(mu, alpha)) - ref) <= bound, (mu, alpha, ref)


def test_fgd_direct_quadrature_accuracy():
    """The table's own quadrature at a point (no interpolation): <= 2e-4 where Fresnel is smooth,
    <= 1.5e-3 at the total-internal-reflection kink (eta < 1, kappa = 0)."""
    for mu, alpha, eta, kappa, bound in [(0.3, 0.4, 1.5, 0.0, 2e-4), (0.8, 0.07, 0.3, 3.0, 2e-4),
                                         (0.17, 0.9, 1 / 1.5, 0.0, 1.5e-3), (0.6, 0.3, 0.9, 0.0, 1.5e-3),
                                         (0.9, 0.6, 1 / 1.5, 0.0, 1.5e-3)]:
        ref = fgd_reference(mu, alpha, eta, kappa)
        assert abs(tables.fgd_direct(mu, alpha, eta, kappa) - ref) <= bound


def test_lookups_work_inside_njit_kernels(tabs, cdir):
    @numba.njit
    def kernel(fgd, tir, split, lower, upper):
        return (tables.fgd_lookup(fgd, 0.5, 0.2, 1.5, 0.0, tables.ETA_MAX, tables.KAPPA_MAX)
                + tables.tir_lookup(tir, 0.5, 0.2, 0.7) + tables.slice_lookup(split, lower, upper, 0.5, 0.2))

    s = tables.fgd_slice(1.5, cache_dir=cdir)
    got = kernel(tabs.fgd, tabs.tir, s.mu_split, s.lower, s.upper)
    expect = float(tabs.fgd_at(0.5, 0.2, 1.5, 0.0)) + float(tabs.tir_at(0.5, 0.2, 0.7)) + float(s(0.5, 0.2))
    assert got == pytest.approx(expect, rel=1e-12)


def test_slice_from_table_equals_4d_lookups(tabs):
    s = tables.fgd_slice_from_table(tabs, 1.37, 0.61)
    mu, alpha = np.meshgrid(np.linspace(0, 1, 13), np.linspace(0, 1, 11), indexing="ij")
    np.testing.assert_allclose(s(mu, alpha), tabs.fgd_at(mu, alpha, 1.37, 0.61), atol=1e-12)


# -------------------------------------------------------------------------- TIR


def test_tir_in_unit_interval_and_trivial_above_one(tabs):
    assert np.all(np.isfinite(tabs.tir)) and tabs.tir.min() >= 0.0 and tabs.tir.max() <= 1.0
    np.testing.assert_array_equal(tabs.tir[:, :, -1], 1.0)   # eta_up = 1: everything escapes
    assert float(tabs.tir_at(0.3, 0.5, 1.2)) == 1.0
    assert float(tables.tir_slice(1.0)(0.3, 0.5)) == 1.0


def test_tir_alpha_zero_is_the_step_function(tabs):
    """alpha -> 0: the lobe is the mirror direction, which escapes iff sin(theta) <= eta_up."""
    mus = np.maximum(tables.mu_nodes(), tables.MU_FLOOR)
    sin = np.sqrt(1.0 - mus * mus)
    step = (sin[:, None] <= tables.eta_up_nodes()[None, :]).astype(float)
    np.testing.assert_array_equal(tabs.tir[:, 0, :], step)
    # slices: one-sided limits at the split, exact step away from it
    for eta_up in (1 / 1.5,):
        s = tables.tir_slice(eta_up)
        mu_c = math.sqrt(1 - eta_up ** 2)
        assert s.mu_split == pytest.approx(mu_c)
        assert float(s(mu_c * (1 - 1e-6), 0.0)) == 0.0 and float(s(mu_c * (1 + 1e-6), 0.0)) == 1.0
        # small roughness: still a (slightly smoothed) step away from the critical cosine
        assert float(s(mu_c - 0.1, 1e-3)) <= 1e-3 and float(s(mu_c + 0.05, 1e-3)) >= 1 - 1e-3


def test_tir_table_against_independent_quadrature(tabs):
    """3D table against a direct integration over outgoing directions at random points of the
    stated region (alpha >= 0.1, mu >= 0.05): every error <= TIR_ERROR, the median below 1e-3."""
    rng = np.random.default_rng(7)
    errs = []
    for _ in range(40):
        mu, alpha, eta_up = rng.uniform(0.05, 1.0), rng.uniform(0.1, 1.0), rng.uniform(0.0, 1.0)
        ref = tir_reference(mu, alpha, eta_up)
        errs.append(abs(float(tabs.tir_at(mu, alpha, eta_up)) - ref))
        assert errs[-1] <= tables.TIR_ERROR, (mu, alpha, eta_up, ref)
    assert np.median(errs) <= 1e-3


def test_tir_slice_against_independent_quadrature():
    """A split slice (eta_up = 1/1.5: a coat of index 1.5 seen from inside) likewise."""
    eta_up = 1 / 1.5
    s = tables.tir_slice(eta_up)
    rng = np.random.default_rng(8)
    mu_c = s.mu_split
    for mu in [*rng.uniform(0.05, 1.0, 6), mu_c - 0.01, mu_c + 0.01]:
        alpha = rng.uniform(0.1, 0.8)
        ref = tir_reference(mu, alpha, eta_up)
        assert abs(float(s(mu, alpha)) - ref) <= tables.TIR_ERROR, (mu, alpha, ref)


@pytest.mark.parametrize("eta,kappa", [(1.5, 0.0), (1.0, 3.0)])
def test_height_correlated_slices_against_independent_quadrature(eta, kappa):
    """The height-correlated masking option (own kernel, own tables) against the half-vector
    quadrature with height-correlated G2, within the slices' bound (2e-3 for mu >= 0.05); at grazing
    incidence the two masking models differ by more than twice that bound, so a slice that ignored
    the option would fail."""
    s_hc = tables.fgd_slice(eta, kappa, height_correlated=True)
    s_sep = tables.fgd_slice(eta, kappa)
    gap = 0.0
    for mu in (1.0, 0.6, 0.2, 0.08):
        for alpha in (0.1, 0.5, 0.9):
            ref = fgd_reference(mu, alpha, eta, kappa, height_correlated=True)
            assert abs(float(s_hc(mu, alpha)) - ref) <= 2e-3, (mu, alpha, ref)
            gap = max(gap, abs(float(s_sep(mu, alpha)) - ref))
    assert gap > 4e-3
