"""Tests of the multilayer-lut model (models.multilayer_lut) and its tables (models.tables.multilayer).

Reference values are computed here from first principles with textbook formulas in angle form
(Snell's law on angles, Fresnel via sin/tan differences, the a/b form for conductors, GGX D and
Lambda in tan(theta); shared with other model tests in tests/models/helpers.py), independently of
goniometer.optics. The tables are built once per run into a temporary cache directory (a few
seconds on 2 cores).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from goniometer import optics
from goniometer.stack import Interface, Lambertian, Medium, Stack
from models.tables import multilayer as mt
from models.base import ModelError
from models.multilayer_lut import MultilayerLUT, MultilayerLUTArticle
from models.weidlich_wilkie import WWBati19
from tests.models.helpers import (direction, fresnel_conductor_tb, fresnel_dielectric_tb, g1_tb, ggx_brdf_tb,
                                  ggx_d_tb, polar, snell_about_n)

DEG = math.pi / 180.0


# ---------------------------------------------------------------------- textbook optics

def inner_of_cosine(w: np.ndarray, c: float) -> np.ndarray:
    """Unit direction of cosine c in the azimuth of w (the model's mean refracted direction)."""
    return direction(math.acos(min(1.0, c)), math.atan2(w[1], w[0]))


def transmittance_vndf_tb(mu: float, alpha: float, eta: float, n_theta: int = 500, n_phi: int = 720):
    """(T, C, norm) by an independent quadrature over the microfacet normal in spherical coordinates.

    T = Int D_v (1 - F) dm, C = cosine of Int D_v (1 - F) O(t) dm, with D_v = G1(v) max(0, v.m) D(m)
    / v_z, textbook D, Lambda and Fresnel and the article's refraction formula; theta_m mapped by
    tan(theta_m) = alpha tan(s pi / 2) (Gauss-Legendre in s), phi by the midpoint rule.
    ``norm`` = Int D_v dm (should be 1).
    """
    x, w = np.polynomial.legendre.leggauss(n_theta)
    s = 0.5 * (x + 1.0)
    ws = 0.5 * w
    psi = 0.5 * np.pi * s
    th = np.arctan(alpha * np.tan(psi))
    dth = alpha * 0.5 * np.pi / np.cos(psi) ** 2 / (1.0 + (alpha * np.tan(psi)) ** 2)
    phi = (np.arange(n_phi) + 0.5) / n_phi * 2.0 * np.pi
    TH, PH = np.meshgrid(th, phi, indexing="ij")
    W = (ws * dth)[:, None] * (2.0 * np.pi / n_phi) * np.sin(TH)
    m = np.stack([np.sin(TH) * np.cos(PH), np.sin(TH) * np.sin(PH), np.cos(TH)], axis=-1)
    theta_v = math.acos(mu)
    v = np.array([math.sin(theta_v), 0.0, mu])
    vm = m @ v
    dv = g1_tb(theta_v, alpha) * np.maximum(vm, 0.0) * ggx_d_tb(TH, alpha) / mu
    f = fresnel_dielectric_tb(np.arccos(np.clip(vm, -1.0, 1.0)), eta)
    wt = W * dv * (1.0 - f)
    # article: refract(v, n, eta) = -v/eta + n (n.v/eta - sqrt(1 - (1 - (n.v)^2)/eta^2))
    k = 1.0 - (1.0 - vm * vm) / (eta * eta)
    ok = (k > 0.0) & (vm > 0.0)
    t = -v / eta + m * (vm / eta - np.sqrt(np.maximum(k, 0.0)))[..., None]
    keep = ok & (t[..., 2] < 0.0)
    tbar = np.sum((wt * keep)[..., None] * t, axis=(0, 1))
    return float(np.sum(wt)), float(-tbar[2] / np.linalg.norm(tbar)), float(np.sum(W * dv))


# ---------------------------------------------------------------------- fixtures and stacks

@pytest.fixture(scope="module")
def table_dir(tmp_path_factory):
    """Tables built from scratch into a fresh cache directory (the build is part of the test)."""
    d = tmp_path_factory.mktemp("multilayer-cache")
    calls = []
    mt.build_multilayer_tables(d, progress=lambda stage, frac: calls.append((stage, frac)))
    assert calls and calls[-1][1] == 1.0
    fr = [c[1] for c in calls]
    assert all(0.0 <= a <= b <= 1.0 for a, b in zip(fr, fr[1:]))
    return d


@pytest.fixture(scope="module")
def tables(table_dir) -> mt.MultilayerTables:
    return mt.load_multilayer_tables(table_dir)


@pytest.fixture(scope="module")
def model(table_dir) -> MultilayerLUT:
    return MultilayerLUT(cache_dir=table_dir)


def coat(alpha0=0.2, tau=(0.05, 0.1, 0.4), base=None, eta0=1.5) -> Stack:
    base = base if base is not None else Lambertian((0.2, 0.5, 0.8))
    return Stack("s", (Interface(alpha0, (eta0,) * 3), Medium(tau), base))


def conductor(alpha1=0.2, eta1=1.45, kappa1=(1.0, 0.01, 0.01)) -> Interface:
    return Interface(alpha1, (eta1,) * 3, kappa1)


def database_stacks() -> list[Stack]:
    """The 48 BRDF materials of docs/database-format.md (plastics and metals)."""
    out = []
    for a0 in (0.001, 0.05, 0.2):
        for tau in ((0.2,) * 3, (0.05, 0.1, 0.4)):
            for rho in ((0.5,) * 3, (0.2, 0.5, 0.8)):
                out.append(coat(a0, tau, Lambertian(rho)))
            for eta1 in (1.9, 1.45, 1.2):
                for a1 in (0.001, 0.2):
                    out.append(coat(a0, tau, conductor(a1, eta1)))
    return out


def hemisphere(n_theta=46, n_phi=48, extra=(89.9,)) -> np.ndarray:
    th = np.concatenate([np.linspace(0.0, 89.0, n_theta), np.asarray(extra)]) * DEG
    ph = np.linspace(0.0, 2.0 * np.pi, n_phi, endpoint=False)
    T, P = np.meshgrid(th, ph, indexing="ij")
    return np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], axis=-1).reshape(-1, 3)


def random_pairs(rng, n: int, max_deg: float = 85.0) -> tuple[np.ndarray, np.ndarray]:
    th = np.arccos(rng.uniform(math.cos(max_deg * DEG), 1.0, (2, n)))
    ph = rng.uniform(0.0, 2.0 * np.pi, (2, n))
    d = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1)
    return d[0], d[1]


# ---------------------------------------------------------------------- tables

def test_tables_against_direct_quadrature_off_grid(tables):
    """Interpolated T and C against the quadrature at random off-grid points, with the stated bounds."""
    rng = np.random.default_rng(20240607)
    n = 4000
    mu = rng.uniform(0.0, 1.0, n) ** 1.5
    alpha = rng.uniform(0.0, 1.0, n) ** 2
    eta = np.where(rng.uniform(size=n) < 0.5, rng.uniform(mt.ETA_MIN, 1.0, n), rng.uniform(1.0, mt.ETA_MAX, n))
    ref = mt.direct(mu, alpha, eta)
    t, c = tables.at(mu, alpha, eta)
    e_t = np.abs(t - ref[..., 0])
    e_tc = ref[..., 0] * np.abs(c - ref[..., 1])
    mu_c = np.sqrt(np.maximum(0.0, 1.0 - eta ** 2))
    corner = (np.abs(eta - 1.0) < mt.CORNER_ETA) & (mu < mt.CORNER_MU)
    kink = (eta < 1.0) & (np.abs(mu - mu_c) < mt.KINK_BAND)
    up = ~corner & (eta >= 1.0)
    down = ~corner & (eta < 1.0) & ~kink
    assert e_t[up].max() <= mt.ERROR_T_UP
    assert e_t[down].max() <= mt.ERROR_T_DOWN
    assert e_t[kink & ~corner].max() <= mt.ERROR_T_KINK
    assert e_tc[~corner].max() <= mt.ERROR_TC
    # typical errors are far below the bounds
    assert np.median(e_t[~corner]) < 3e-4
    assert np.quantile(e_t[~corner], 0.99) < 4e-3


def test_tables_at_the_database_index(tables):
    rng = np.random.default_rng(3)
    mu = rng.uniform(0.01, 1.0, 600)
    alpha = rng.uniform(0.0, 1.0, 600) ** 2
    ref = mt.direct(mu, alpha, 1.5)
    t, c = tables.at(mu, alpha, 1.5)
    assert np.abs(t - ref[..., 0]).max() < 3e-3
    assert np.abs(c - ref[..., 1]).max() < 3e-3


@pytest.mark.parametrize("mu, alpha, eta, tol", [
    (0.7, 0.3, 1.5, 2e-5), (0.3, 0.1, 1.5, 2e-5), (0.9, 0.6, 2.2, 2e-5), (0.15, 0.5, 1.33, 2e-5),
    (0.5, 0.05, 1.1, 2e-5), (0.95, 0.3, 0.7, 6e-4), (0.8, 0.2, 0.9, 6e-4),
])
def test_quadrature_against_independent_integration(mu, alpha, eta, tol):
    """The table's quadrature (VNDF parameter square) against spherical coordinates over m.

    They agree to 1e-5 where Fresnel is smooth (eta > 1); for eta < 1 the total-internal-reflection
    edge limits the table's rule to a few 1e-4 (module docstring: <= 1.6e-3 over random points)."""
    t_ref, c_ref, norm = transmittance_vndf_tb(mu, alpha, eta, 300, 400)
    assert norm == pytest.approx(1.0, abs=1e-6)
    t, c, s = mt.direct(mu, alpha, eta)
    assert t == pytest.approx(t_ref, abs=tol)
    assert c == pytest.approx(c_ref, abs=tol)
    assert s == pytest.approx(math.sqrt(1.0 - c * c), abs=1e-9) and s >= 0.0


def test_smooth_limit_is_exact(tables):
    """alpha = 0: T = 1 - F(theta) and C = Snell's cosine (0 beyond the critical angle), exactly."""
    mu = np.linspace(0.0, 1.0, 201)
    for eta in (0.5, 0.8, 1.0, 1.2, 1.5, 2.7):
        t, c = tables.at(mu, 0.0, eta)
        theta = np.arccos(mu)
        s = np.sin(theta) / eta
        snell = np.where(s < 1.0, np.sqrt(np.maximum(0.0, 1.0 - s * s)), 0.0)
        # at the critical angle T and C go like sqrt(1 - s^2): a rounding of a few ulp in s^2 moves
        # them by ~sqrt(1e-16) -- those grid points (mu = 0.6 for eta = 0.8) get that tolerance
        critical = np.abs(s - 1.0) < 1e-12
        tol = np.where(critical, 1e-6, 1e-12)
        assert np.all(np.abs(t - (1.0 - fresnel_dielectric_tb(theta, eta))) <= tol), eta
        assert np.all(np.abs(c - snell) <= tol), eta


def test_small_roughness_tends_to_the_smooth_limit(tables):
    """T and C are continuous as alpha -> 0, both in the tables and in the quadrature itself."""
    mu = np.linspace(0.2, 1.0, 41)
    for eta in (1.5, 2.2, 0.8):
        theta = np.arccos(mu)
        s = np.sin(theta) / eta
        ok = s < 0.95  # away from the critical angle, where T has a square-root kink
        snell = np.sqrt(np.maximum(0.0, 1.0 - s * s))
        for alpha in (1e-3, 1e-4):
            t, c = tables.at(mu, alpha, eta)
            ref = mt.direct(mu, alpha, eta)
            for tt, cc in ((t, c), (ref[..., 0], ref[..., 1])):
                np.testing.assert_allclose(tt[ok], 1.0 - fresnel_dielectric_tb(theta[ok], eta), atol=20 * alpha)
                np.testing.assert_allclose(cc[ok], snell[ok], atol=20 * alpha)


def test_index_matched_interface_transmits_everything_undeviated(tables):
    rng = np.random.default_rng(5)
    mu = rng.uniform(0.0, 1.0, 300)
    alpha = rng.uniform(0.0, 1.0, 300)
    t, c = tables.at(mu, alpha, 1.0)
    np.testing.assert_allclose(t, 1.0, atol=1e-12)
    np.testing.assert_allclose(c, mu, atol=1e-9)
    ref = mt.direct(mu[:20], alpha[:20], 1.0)
    np.testing.assert_allclose(ref[..., 0], 1.0, atol=1e-12)
    np.testing.assert_allclose(ref[..., 1], np.maximum(mu[:20], mt.MU_FLOOR), atol=1e-9)


def test_mean_direction_points_forward_and_values_are_bounded(tables):
    rng = np.random.default_rng(9)
    mu = rng.uniform(0.0, 1.0, 2000)
    alpha = rng.uniform(0.0, 1.0, 2000)
    eta = rng.uniform(mt.ETA_MIN, mt.ETA_MAX, 2000)
    assert mt.direct(mu, alpha, eta)[..., 2].min() >= -1e-12
    t, c = tables.at(mu, alpha, eta)
    assert np.all((t >= 0) & (t <= 1) & (c >= 0) & (c <= 1))
    assert tables.up.shape == (mt.N_MU_UP, mt.N_ALPHA, mt.N_ETA_UP, 2)
    assert tables.down.shape == (mt.n_mu_down(), mt.N_ALPHA, mt.N_ETA_DOWN, 2)


# ---------------------------------------------------------------------- cache

def test_cache_file_is_versioned_and_written_atomically(tmp_path, tiny_multilayer_grid):
    path = mt.build_multilayer_tables(tmp_path)
    assert path == tmp_path / mt.FILE_NAME and path.exists()
    assert [p.name for p in tmp_path.iterdir()] == [mt.FILE_NAME]  # no temporary left behind
    with np.load(path) as z:
        assert int(z["version"]) == mt.TABLE_VERSION
    assert mt.read_if_current(path) is not None


def test_stale_version_is_rebuilt_not_reused(tmp_path, tiny_multilayer_grid, monkeypatch):
    path = mt.build_multilayer_tables(tmp_path)
    monkeypatch.setattr(mt, "TABLE_VERSION", mt.TABLE_VERSION + 1)
    assert mt.read_if_current(path) is None
    mt.load_multilayer_tables(tmp_path)
    with np.load(path) as z:
        assert int(z["version"]) == mt.TABLE_VERSION


def test_other_grid_or_corrupt_file_is_rebuilt(tmp_path, tiny_multilayer_grid, monkeypatch):
    path = mt.build_multilayer_tables(tmp_path)
    monkeypatch.setattr(mt, "N_ALPHA", 4)
    assert mt.read_if_current(path) is None
    assert mt.load_multilayer_tables(tmp_path).up.shape[1] == 4
    path.write_bytes(b"not a table")
    mt._load_cached.cache_clear()
    assert mt.load_multilayer_tables(tmp_path).up.shape[1] == 4
    assert mt.read_if_current(path) is not None


def test_default_cache_directory_follows_goniometer_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("GONIOMETER_CACHE", str(tmp_path))
    assert mt.table_path() == tmp_path / mt.FILE_NAME


# ---------------------------------------------------------------------- model: exact cases

def test_single_conductor_interface_is_the_microfacet_brdf(model):
    stack = Stack("m", (Interface(0.3, (1.2, 0.9, 0.4), (3.0, 2.5, 2.0)),))
    rng = np.random.default_rng(1)
    for theta_l in (0.0, 30.0, 70.0, 89.0):
        l = direction(theta_l * DEG, 0.4)
        v = hemisphere()
        r = model.evaluate(stack, l, v)
        for c, (eta, kappa) in enumerate(((1.2, 3.0), (0.9, 2.5), (0.4, 2.0))):
            ref = optics.np_microfacet_reflection(l[0], l[1], l[2], v[:, 0], v[:, 1], v[:, 2],
                                                  0.3, 0.3, eta, kappa, False)
            np.testing.assert_allclose(r.top[:, c], ref, rtol=1e-13, atol=0)
        assert np.all(r.internal == 0.0)
    # and against the textbook form
    l, v = random_pairs(rng, 20)
    for a, b in zip(l, v):
        val = model.evaluate(stack, a, b).top
        ref = ggx_brdf_tb(a, b, 0.3, lambda t: fresnel_conductor_tb(t, 1.2, 3.0))
        assert val[0] == pytest.approx(ref, rel=1e-10)


def test_top_lobe_is_the_dielectric_microfacet_brdf(model):
    rng = np.random.default_rng(2)
    l, v = random_pairs(rng, 50)
    for stack in (coat(0.2), coat(0.05, base=conductor())):
        for a, b in zip(l[:10], v[:10]):
            top = model.evaluate(stack, a, b).top
            ref = ggx_brdf_tb(a, b, stack.layers[0].roughness, lambda t: fresnel_dielectric_tb(t, 1.5))
            np.testing.assert_allclose(top, ref, rtol=1e-10)


def test_bare_lambertian(model):
    stack = Stack("l", (Lambertian((0.2, 0.5, 0.8)),))
    r = model.evaluate(stack, direction(0.3, 0.0), hemisphere())
    np.testing.assert_allclose(r.top, np.broadcast_to(np.array([0.2, 0.5, 0.8]) / np.pi, r.top.shape))
    assert np.all(r.internal == 0.0)


@pytest.mark.parametrize("base", ["conductor", "lambertian"])
def test_smooth_coat_is_the_first_order_adding_term(model, base):
    """alpha0 = 0: internal = T01(l) T10(v) exp(-tau (1/mu_l1 + 1/mu_v1)) f1(l1, v1) / eta0^2 exactly
    (the single-bounce term of the adding equations for a smooth coat; G = 1)."""
    tau = np.array([0.05, 0.1, 0.4])
    b = conductor(0.2, 1.9) if base == "conductor" else Lambertian((0.2, 0.5, 0.8))
    stack = coat(0.0, tuple(tau), b)
    rng = np.random.default_rng(4)
    l, v = random_pairs(rng, 30)
    for a, w in zip(l, v):
        r = model.evaluate(stack, a, w)
        assert np.all(r.top == 0.0)  # a smooth coat's reflection is a Dirac: not evaluable pointwise
        l1, v1 = snell_about_n(a, 1.5), snell_about_n(w, 1.5)
        t = (1.0 - fresnel_dielectric_tb(polar(a), 1.5)) * (1.0 - fresnel_dielectric_tb(polar(w), 1.5))
        att = np.exp(-tau * (1.0 / l1[2] + 1.0 / v1[2]))
        if base == "conductor":
            f1 = np.array([ggx_brdf_tb(l1, v1, 0.2, lambda x, k=k: fresnel_conductor_tb(x, 1.9 / 1.5, k / 1.5))
                           for k in (1.0, 0.01, 0.01)])
        else:
            f1 = np.array([0.2, 0.5, 0.8]) / np.pi
        np.testing.assert_allclose(r.internal, t * att * f1 / 1.5 ** 2, rtol=1e-10)


def test_nearly_smooth_coat_tends_to_the_smooth_limit(model):
    rng = np.random.default_rng(6)
    l, v = random_pairs(rng, 200, max_deg=70.0)
    b = conductor(0.3, 1.45)
    ref = np.array([model.evaluate(coat(0.0, base=b), a, w).internal for a, w in zip(l, v)])
    val = np.array([model.evaluate(coat(1e-4, base=b), a, w).internal for a, w in zip(l, v)])
    np.testing.assert_allclose(val, ref, rtol=2e-3)


def test_plastic_closed_form_with_tables(model, tables):
    """One rough coat over a Lambertian: T(l) T(v) G1(l1) G1(v1) a rho / (pi eta^2) -- the model's G is
    the masking of the mean refracted pair, a uses the mean refracted cosines."""
    tau = np.array([0.05, 0.1, 0.4])
    rho = np.array([0.2, 0.5, 0.8])
    a0 = 0.2
    stack = coat(a0, tuple(tau), Lambertian(tuple(rho)))
    rng = np.random.default_rng(8)
    l, v = random_pairs(rng, 40)
    for a, w in zip(l, v):
        (tl, tv), (cl, cv) = tables.at(np.array([a[2], w[2]]), a0, 1.5)
        g = g1_tb(math.acos(cl), a0) * g1_tb(math.acos(cv), a0)
        expected = tl * tv * g * np.exp(-tau * (1 / cl + 1 / cv)) * rho / (np.pi * 1.5 ** 2)
        np.testing.assert_allclose(model.evaluate(stack, a, w).internal, expected, rtol=1e-9)


def test_three_interfaces_step_by_step(model, tables):
    """Two rough dielectric interfaces (1 -> 1.5 -> 1.2, the second with eta < 1) over a rough
    conductor, with coloured media: the article's steps 1-8 written out by hand."""
    tau1 = np.array([0.05, 0.1, 0.4])
    tau2 = np.array([0.3, 0.2, 0.1])
    kappa = (1.0, 0.01, 0.01)
    stack = Stack("three", (Interface(0.3, (1.5,) * 3), Medium(tuple(tau1)), Interface(0.1, (1.2,) * 3),
                            Medium(tuple(tau2)), Interface(0.25, (1.9,) * 3, kappa)))
    layers = ((0.3, 1.5, tau1), (0.1, 1.2 / 1.5, tau2))
    rng = np.random.default_rng(10)
    l, v = random_pairs(rng, 25, max_deg=80.0)
    for a, w in zip(l, v):
        top = ggx_brdf_tb(a, w, 0.3, lambda t: fresnel_dielectric_tb(t, 1.5))
        internal = np.zeros(3)
        q = np.ones(3)
        lk, vk = a, w
        for k, (alpha, eta, tau) in enumerate(layers):
            if k > 0:
                internal += q * ggx_brdf_tb(lk, vk, alpha, lambda t, e=eta: fresnel_dielectric_tb(t, e))
            (tl, tv), (cl, cv) = tables.at(np.array([lk[2], vk[2]]), alpha, eta)
            lk, vk = inner_of_cosine(lk, cl), inner_of_cosine(vk, cv)
            g = g1_tb(polar(lk), alpha) * g1_tb(polar(vk), alpha)
            q = q * tl * tv * g / eta ** 2 * np.exp(-tau * (1 / lk[2] + 1 / vk[2]))
        base = np.array([ggx_brdf_tb(lk, vk, 0.25, lambda t, c=c: fresnel_conductor_tb(t, 1.9 / 1.2, c / 1.2))
                         for c in kappa])
        internal += q * base
        r = model.evaluate(stack, a, w)
        np.testing.assert_allclose(r.top, top, rtol=1e-10)
        np.testing.assert_allclose(r.internal, internal, rtol=1e-9)


def test_large_optical_depth_leaves_only_the_top_lobe(model):
    v = hemisphere()
    l = direction(40 * DEG, 0.0)
    for b in (Lambertian((0.5,) * 3), conductor(0.2)):
        thick = model.evaluate(coat(0.2, (200.0,) * 3, b), l, v)
        clear = model.evaluate(coat(0.2, (0.0,) * 3, b), l, v)
        assert np.all(thick.internal == 0.0) or thick.internal.max() < 1e-80
        np.testing.assert_array_equal(thick.top, clear.top)
        assert clear.internal.max() > 0.01


def test_reciprocity(model):
    stack = Stack("r", (Interface(0.2, (1.5,) * 3), Medium((0.05, 0.1, 0.4)), Interface(0.4, (1.3,) * 3),
                        Interface(0.15, (1.45,) * 3, (1.0, 0.01, 0.01))))
    rng = np.random.default_rng(12)
    l, v = random_pairs(rng, 40)
    for s in (stack, coat(0.05)):
        for a, w in zip(l, v):
            f = model.evaluate(s, a, w).total
            g = model.evaluate(s, w, a).total
            np.testing.assert_allclose(f, g, rtol=1e-12)


def test_index_matched_interface_is_invisible(model):
    """An interface with the same index on both sides changes nothing (as in the simulator)."""
    with_if = Stack("a", (Interface(0.2, (1.5,) * 3), Medium((0.05, 0.1, 0.2)), Interface(0.5, (1.5,) * 3),
                          Medium((0.1, 0.1, 0.1)), Lambertian((0.5, 0.6, 0.7))))
    without = Stack("b", (Interface(0.2, (1.5,) * 3), Medium((0.15, 0.2, 0.3)), Lambertian((0.5, 0.6, 0.7))))
    v = hemisphere()
    for theta_l in (0.0, 45.0, 80.0):
        l = direction(theta_l * DEG, 1.0)
        a = model.evaluate(with_if, l, v)
        b = model.evaluate(without, l, v)
        np.testing.assert_allclose(a.total, b.total, rtol=1e-12, atol=1e-300)


def test_jacobian_choice(model, table_dir):
    """The article's form (no radiance Jacobian) is eta0^2 times larger inside a single coat."""
    article = MultilayerLUTArticle(cache_dir=table_dir)
    v = hemisphere()
    l = direction(30 * DEG, 0.0)
    for b in (Lambertian((0.5,) * 3), conductor(0.2)):
        s = coat(0.2, base=b)
        np.testing.assert_allclose(article.evaluate(s, l, v).internal,
                                   1.5 ** 2 * model.evaluate(s, l, v).internal, rtol=1e-12)
        np.testing.assert_array_equal(article.evaluate(s, l, v).top, model.evaluate(s, l, v).top)


def test_directional_albedo_at_most_one(model):
    """No energy is created: Int f cos dv <= 1 (the model ignores inter-reflections, so < 1)."""
    n_t, n_p = 180, 180
    th = (np.arange(n_t) + 0.5) / n_t * np.pi / 2
    ph = (np.arange(n_p) + 0.5) / n_p * 2 * np.pi
    T, P = np.meshgrid(th, ph, indexing="ij")
    v = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1)
    w = (np.cos(T) * np.sin(T) * (np.pi / 2 / n_t) * (2 * np.pi / n_p))[..., None]
    for s in (coat(0.3, (0.0,) * 3, Lambertian((1.0,) * 3)), coat(0.3, (0.0,) * 3, conductor(0.3, 0.2, (8.0,) * 3))):
        for theta_l in (0.0, 60.0):
            a = np.sum(model.evaluate(s, direction(theta_l * DEG, 0.0), v).total * w, axis=(0, 1))
            assert np.all(a <= 1.0) and np.all(a > 0.3)


# ---------------------------------------------------------------------- model: robustness

def test_database_stacks_finite_and_non_negative(model):
    v = hemisphere(n_theta=90, n_phi=72, extra=(89.5, 89.9, 89.99))
    for stack in database_stacks():
        for theta_l in (0.0, 45.0, 80.0, 89.0, 89.9):
            r = model.evaluate(stack, direction(theta_l * DEG, 0.0), v)
            for part in (r.top, r.internal):
                assert part.shape == v.shape
                assert np.all(np.isfinite(part)) and np.all(part >= 0.0), (stack, theta_l)


def test_extreme_and_degenerate_inputs(model):
    stacks = [coat(0.0, base=conductor(0.0)), coat(1.0, base=conductor(1.0)), coat(0.001, base=conductor(0.001)),
              Stack("low", (Interface(0.001, (1.5,) * 3), Interface(0.001, (0.5,) * 3), Lambertian((1.0,) * 3)))]
    v = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 0.6, -0.8], [np.nan, 0.0, 1.0],
                  [math.sin(89.99 * DEG), 0.0, math.cos(89.99 * DEG)]])
    for s in stacks:
        for l in (direction(89.99 * DEG, 0.0), direction(0.0, 0.0), np.array([1.0, 0.0, 0.0])):
            r = model.evaluate(s, l, v)
            assert np.all(np.isfinite(r.total)) and np.all(r.total >= 0.0)
            assert np.all(r.total[1:4] == 0.0)  # grazing, below the horizon, NaN
        assert np.all(model.evaluate(s, np.array([1.0, 0.0, 0.0]), v).total == 0.0)
    # a smooth conductor under a smooth coat is all Dirac: nothing evaluable pointwise
    assert np.all(model.evaluate(stacks[0], direction(0.3, 0.0), hemisphere()).total == 0.0)


def test_output_shape_follows_v(model):
    v = hemisphere().reshape(47, 48, 3)
    r = model.evaluate(coat(0.2), direction(0.3, 0.0), v)
    assert r.top.shape == r.internal.shape == (47, 48, 3)


# ---------------------------------------------------------------------- refusals

@pytest.mark.parametrize("stack, words", [
    (Stack("slab", (Interface(0.05, (1.5,) * 3), Medium((0.05, 0.1, 0.4)), Interface(0.2, (1.0,) * 3)), "slab"),
             "slab"),
    (Stack("glass", (Interface(0.1, (1.5,) * 3),)), "transmits"),
    (coat(0.2, eta0=3.5), "range"),
    (Stack("drop", (Interface(0.1, (3.5,) * 3), Interface(0.1, (1.0,) * 3), Lambertian((0.5,) * 3))), "range"),
])
def test_refusals(model, stack, words):
    reason = model.support_reason(stack)
    assert reason is not None and words in reason and "\n" not in reason
    with pytest.raises(ModelError, match="multilayer-lut"):
        model.evaluate(stack, direction(0.3, 0.0), hemisphere())


def test_supported_stacks(model):
    for s in database_stacks()[:3] + [Stack("m", (conductor(),)), Stack("l", (Lambertian((0.5,) * 3),))]:
        assert model.support_reason(s) is None


def test_btdf_side_is_refused(model):
    with pytest.raises(ModelError, match="BTDF"):
        model.evaluate(coat(0.2), direction(0.3, 0.0), -hemisphere(), side="btdf")


# ---------------------------------------------------------------------- pinned values (issue 11)
#
# Source: S. Steinberg 2016, "Light Transport in a Multi-Layered Microfacet Model"
# (/work/shared/papers/multilayer-microfacet-realtime-blog.txt), section "Evaluating a
# multi-layered BRDF", steps 1-8, for one coat (roughness alpha0, eta = 1.5) over a base:
#   step 5     r  = f_0(l, v)                       Cook-Torrance lobe of the coat (our `top`)
#   steps 1-2  t_i = t(l), t_o = t(v); u, o = mean refracted directions of l and v
#   steps 3-4  k  = exp(-tau (1/n.u + 1/n.o))     (the article's exp(+a l) is a sign typo)
#   step 7     q  = k t_i t_o G
#   base       r += q f_1(u, o)                     rho / pi, or the GGX conductor lobe
# and our documented choices (docs/multilayer-lut.md) where the article is silent or differs:
# G = G1(u) G1(o) of the coat's alpha0 (the article does not say which G); t_o = t(v) from the
# outside (reciprocity); q also carries 1 / eta^2 (Bati 2019 appendix C; the article has none);
# t and the mean direction are averaged over the visible normals D_v, the mean direction weighted
# by the transmitted energy (docs/tables.md; the article weights D cos(theta_m) -- pinned as a
# difference in test_tables_use_vndf_weights_not_the_articles). A conductor base takes its index
# relative to the coat, (1.45 + i kappa) / 1.5.
#
# Materials: P1 = configs/bati2019.toml plastic P1 (tau C = (0.05, 0.1, 0.4), rho C = (0.2, 0.5,
# 0.8)); M2 = metal M2 (tau C, conductor 1.45 + i (1.0, 0.01, 0.01), alpha1 = 0.2); the coat is
# alpha0 = 0 (smooth: t = 1 - F and Snell's direction exactly, G = 1) or alpha0 = 0.2.
# Numbers computed outside the project (scratch script, `math`/`cmath` only: Walter 2007 eq. 22
# Fresnel, complex-amplitude conductor Fresnel, GGX D and Lambda in cosine form), then checked
# against the derivation below (angle forms of tests/models/helpers.py) to 1e-12.

ML_POINTS = {
    "N0": ((0.0, 0.0), (0.0, 0.0)),        # normal incidence, specular view
    "N1": ((0.0, 0.0), (30.0, 90.0)),      # normal incidence, off-specular view
    "O1": ((60.0, 0.0), (40.0, 135.0)),    # oblique, off-specular, out of the plane of incidence
}

#: T(mu, 0.2, 1.5) and C(mu, 0.2, 1.5) by an independent nested Gauss-Legendre quadrature over
#: the facet normal (exact azimuth limits of the visible facets; converged to 1e-13), our D_v
#: definition (docs/tables.md); mu = cos theta of 0, 30, 40 and 60 degrees
ML_T_C = {
    0: (0.956958077454524, 1.0),
    30: (0.953536036631906, 0.937575637218568),
    40: (0.947500793418623, 0.892826515065662),
    60: (0.905970736048403, 0.778097738725952),
}

#: (alpha0, material, point) -> internal RGB
PINNED_ML = {
    (0.0, "P1", "N0"): (0.0235944915394446, 0.053372947011056, 0.0468667109956758),
    (0.0, "P1", "N1"): (0.0234857285045023, 0.052966024576847, 0.0456706673709714),
    (0.0, "P1", "O1"): (0.0218860994171913, 0.0486945289262943, 0.038710689442781),
    (0.0, "M2", "N0"): (0.0761835795165332, 0.000199322131071095, 0.000109390304862876),
    (0.0, "M2", "N1"): (0.0282671988984588, 7.37571228269562e-05, 3.97487947436766e-05),
    (0.0, "M2", "O1"): (0.0190451576385968, 5.0966735481984e-05, 2.53231409238729e-05),
    (0.2, "P1", "N0"): (0.0234452021562777, 0.0530352404610435, 0.0465701713409046),
    (0.2, "P1", "N1"): (0.0232517725422089, 0.0524228764019362, 0.0451221164524199),
    (0.2, "P1", "O1"): (0.0213431504299913, 0.0473118312650409, 0.0367889240592484),
    (0.2, "M2", "N0"): (0.0757015432931857, 0.000198060960515698, 0.000108698159786974),
    (0.2, "M2", "N1"): (0.0261570052317384, 6.82354413444019e-05, 3.67078237337365e-05),
    (0.2, "M2", "O1"): (0.0156183916926204, 4.24695157965758e-05, 2.06397605749061e-05),
}

ML_TAU = np.array([0.05, 0.1, 0.4])
ML_RHO = np.array([0.2, 0.5, 0.8])
ML_KAPPA = (1.0, 0.01, 0.01)


def _pin_stack(alpha0: float, kind: str) -> Stack:
    base = Lambertian(tuple(ML_RHO)) if kind == "P1" else conductor(0.2, 1.45, ML_KAPPA)
    return coat(alpha0, tuple(ML_TAU), base)


def _pin_directions(point: str) -> tuple[np.ndarray, np.ndarray]:
    (tl, pl), (tv, pv) = ML_POINTS[point]
    return direction(tl * DEG, pl * DEG), direction(tv * DEG, pv * DEG)


def _steinberg_by_hand(kind: str, l, v, alpha0: float, tl: float, cl: float, tv: float, cv: float):
    """Internal RGB of one coat (eta 1.5) over P1 or M2 from the article's steps (block comment),
    given t and the mean refracted cosine C of l (tl, cl) and of v (tv, cv)."""
    u, o = inner_of_cosine(l, cl), inner_of_cosine(v, cv)                 # step 2 (azimuth kept)
    k = np.exp(-ML_TAU * (1.0 / cl + 1.0 / cv))                            # steps 3-4
    g = g1_tb(polar(u), alpha0) * g1_tb(polar(o), alpha0) if alpha0 > 0 else 1.0
    q = k * tl * tv * g / 1.5 ** 2                                         # step 7 and 1/eta^2
    if kind == "P1":
        f1 = ML_RHO / math.pi
    else:
        f1 = np.array([ggx_brdf_tb(u, o, 0.2, lambda t, c=c: fresnel_conductor_tb(t, 1.45 / 1.5, c / 1.5))
                       for c in ML_KAPPA])
    return q * f1


@pytest.mark.parametrize("kind", ["P1", "M2"])
@pytest.mark.parametrize("point", list(ML_POINTS))
def test_pinned_smooth_coat_values(model, kind, point):
    """alpha0 = 0: t = 1 - F(theta, 1.5) and Snell's cosine exactly (the tables' smooth limit),
    G = 1 -- exact to 1e-10. These are also Bati 2019 eq. 5 (ww-bati19) for a smooth coat."""
    stack = _pin_stack(0.0, kind)
    l, v = _pin_directions(point)
    want = np.array(PINNED_ML[(0.0, kind, point)])
    tl, tv = 1.0 - fresnel_dielectric_tb(polar(l), 1.5), 1.0 - fresnel_dielectric_tb(polar(v), 1.5)
    cl, cv = snell_about_n(l, 1.5)[2], snell_about_n(v, 1.5)[2]
    np.testing.assert_allclose(_steinberg_by_hand(kind, l, v, 0.0, tl, cl, tv, cv), want, rtol=1e-12)
    got = model.evaluate(stack, l, v[None])
    assert np.all(got.top == 0.0)  # the smooth coat's reflection is a Dirac
    np.testing.assert_allclose(got.internal[0], want, rtol=1e-10, atol=0)
    np.testing.assert_allclose(WWBati19().evaluate(stack, l, v[None]).internal[0], want, rtol=1e-10, atol=0)


def test_pinned_T_and_C_by_an_independent_quadrature():
    """The literal T, C of ML_T_C are reproduced by this file's spherical-coordinate quadrature
    (transmittance_vndf_tb, 500 x 720 nodes) to 1e-8 -- two independent rules agree."""
    for deg, (t, c) in ML_T_C.items():
        t_ref, c_ref, norm = transmittance_vndf_tb(math.cos(deg * DEG), 0.2, 1.5)
        assert norm == pytest.approx(1.0, abs=1e-7)
        assert t_ref == pytest.approx(t, abs=1e-8)
        assert c_ref == pytest.approx(c, abs=1e-8)
    # normal incidence by hand: mean direction = n by symmetry (C = 1, G1(n) = 1) and
    # T(1) = Int 2 pi D(theta) cos(theta) (1 - F(theta, 1.5)) sin(theta) dtheta = 0.956958077,
    # 3.0e-3 below the smooth 0.96 (tilted facets see larger incidence angles)


@pytest.mark.parametrize("kind", ["P1", "M2"])
@pytest.mark.parametrize("point", list(ML_POINTS))
def test_pinned_rough_coat_values(model, kind, point):
    """alpha0 = 0.2: the model against the article's steps with the quadrature's T and C, within
    the tables' stated bounds (docs/tables.md: |dT| <= 6e-3, T |dC| <= 3e-3 for eta >= 1). At
    N0 by hand: internal = T(1)^2 exp(-2 tau) f_1(n, n) / 1.5^2, f_1 = rho / pi (P1) or
    F_c(0) / (4 pi 0.2^2) (M2); red P1: 0.956958^2 e^-0.1 0.2 / (2.25 pi) = 0.0234452."""
    stack = _pin_stack(0.2, kind)
    l, v = _pin_directions(point)
    want = np.array(PINNED_ML[(0.2, kind, point)])
    (tl, cl), (tv, cv) = ML_T_C[round(ML_POINTS[point][0][0])], ML_T_C[round(ML_POINTS[point][1][0])]
    np.testing.assert_allclose(_steinberg_by_hand(kind, l, v, 0.2, tl, cl, tv, cv), want, rtol=1e-12)
    got = model.evaluate(stack, l, v[None])
    # the top lobe involves no table: exact
    top = ggx_brdf_tb(l, v, 0.2, lambda t: fresnel_dielectric_tb(t, 1.5))
    np.testing.assert_allclose(got.top[0], [top] * 3, rtol=1e-10)
    # internal: bracket the hand value over the stated table errors (T: corners; C: 5 points each)
    e_t = 6e-3
    vals = []
    for sl in (-1.0, 1.0):
        for sv in (-1.0, 1.0):
            for dl in np.linspace(-1.0, 1.0, 5):
                for dv in np.linspace(-1.0, 1.0, 5):
                    c_l = min(1.0, cl + dl * 3e-3 / tl)
                    c_v = min(1.0, cv + dv * 3e-3 / tv)
                    vals.append(_steinberg_by_hand(kind, l, v, 0.2, tl + sl * e_t, c_l, tv + sv * e_t, c_v))
    vals = np.array(vals)
    assert np.all(got.internal[0] >= vals.min(axis=0)) and np.all(got.internal[0] <= vals.max(axis=0)), \
        (got.internal[0], want)
    # regression pin, tighter than the stated bounds: at these points the tables err by <= 7e-5 in
    # T and <= 1.1e-4 in C (measured), the model by <= 6e-4 relative -- enough to tell the
    # article's G of the outer pair (-2.6 % at O1) or a missing 1/eta^2 (x 2.25) apart
    np.testing.assert_allclose(got.internal[0], want, rtol=2e-3, atol=0)


def test_tables_use_vndf_weights_not_the_articles(tables):
    """A known difference from the source, pinned with numbers (alpha = 0.2, eta = 1.5).

    The article's t(v) = Int D cos(theta_m) (1 - F(v.m)) V dm / Int D cos(theta_m) V dm and
    r(v) = Int D cos(theta_m) O(refract(v, m)) dm; ours (docs/tables.md) weights by the visible
    normals D_v = G1(v) (v.m)+ D / v_z, the direction also by (1 - F). Both agree at normal
    incidence (D_v = D cos(theta_m) there): T(1) = 0.956958077. At 60 degrees they do not:
    article t = 0.874393201, cosine of its mean direction 0.813774417 (35.5 deg; front-facing
    facets, normalised; 0.822 or 34.7 deg without V), ours T = 0.905970736, C = 0.778097739 (38.9 deg), Snell 35.26 deg.
    (Independent nested Gauss-Legendre quadrature, converged to 1e-9.)"""
    t, c = tables.at(np.array([1.0, 0.5]), 0.2, 1.5)
    assert abs(t[0] - 0.956958077) <= 6e-3 and c[0] == pytest.approx(1.0, abs=1e-12)
    assert abs(t[1] - 0.905970736) <= 6e-3            # ours, within the stated table bound
    assert abs(t[1] - 0.874393201) > 0.025            # not the article's t
    assert abs(c[1] - 0.778097739) <= 3e-3 / t[1]     # ours
    assert abs(c[1] - 0.813774417) > 0.03             # not the article's mean direction
