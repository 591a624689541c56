"""ggx-kulla-conty against its own definition: the albedo tables against an independent quadrature
of goniometer.optics' single-scattering lobe, the white furnace it claims (conductor with F = 1,
dielectric R + T = 1), reciprocity of the compensation, the split's conservation from both sides,
the alpha -> 0 limit, and the Turquin option. Never against the goniometer simulation."""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import pytest

from goniometer import optics
from goniometer.stack import Interface, Lambertian, Stack
from models import registry
from models.base import ModelError
from models.production import GGXKullaConty, conductor_fresnel_term, dielectric_split
from models.tables import microfacet_albedo as ma

#: two independent quadratures, each claimed to ERROR_E
TOL = 2.0 * ma.ERROR_E
#: a conductor whose Fresnel factor is 1 to 1e-11 at every angle (the white furnace of the method)
WHITE = (1.0, 1.0e6)


def conductor(alpha: float, eta: float = WHITE[0], kappa: float = WHITE[1]) -> Stack:
    return Stack("c", (Interface(alpha, (eta,) * 3, (kappa,) * 3),), "metal")


def dielectric(alpha: float, eta: float = 1.5) -> Stack:
    return Stack("d", (Interface(alpha, (eta,) * 3),), "slab")


@lru_cache(maxsize=8)
def h_grid(alpha: float, n_u: int = 512, n_phi: int = 256):
    """Half vectors and weights with sum g(h) W = Int g(h) dw_h: GGX's own CDF in
    u = t^2 / (1 + t^2), t = tan(theta_h) / alpha (Gauss-Legendre), uniform azimuth; a
    parametrisation independent of the tables' visible-normal quadrature."""
    x, w = np.polynomial.legendre.leggauss(n_u)
    u, wu = 0.5 * (x + 1.0), 0.5 * w
    phi = (np.arange(n_phi) + 0.5) / n_phi * 2.0 * math.pi
    U, P = np.meshgrid(u, phi, indexing="ij")
    c = 1.0 / np.sqrt(1.0 + alpha * alpha * U / (1.0 - U))
    s = np.sqrt(1.0 - c * c)
    h = np.stack([s * np.cos(P), s * np.sin(P), c], -1)
    d = optics.np_ggx_d(h[..., 0], h[..., 1], h[..., 2], alpha, alpha)
    return h, (wu[:, None] / n_phi) / (d * c)


def single_scattering_albedo(mu: float, alpha: float, eta: float, kappa: float) -> tuple[float, float]:
    """(R, T) of optics' Walter 2007 lobe for light at cosine mu, integrated over half vectors
    with Walter's Jacobians (reflection 4 |v.h|, refraction (l.h + eta v.h)^2 / (eta^2 |v.h|))."""
    l = np.array([math.sqrt(1.0 - mu * mu), 0.0, mu])
    h, W = h_grid(alpha)
    lh = h @ l
    v = 2.0 * lh[..., None] * h - l
    f = optics.np_microfacet_reflection(*l, v[..., 0], v[..., 1], v[..., 2], alpha, alpha, eta, kappa, False)
    keep = (lh > 0) & (v[..., 2] > 0)
    R = float(np.sum(np.where(keep, f * v[..., 2] * 4.0 * np.abs(np.sum(v * h, -1)), 0.0) * W))
    if kappa > 0.0:
        return R, 0.0
    s2 = (1.0 - lh * lh) / eta**2
    ok = (lh > 0) & (s2 < 1.0)
    t = (lh / eta - np.sqrt(np.maximum(0.0, 1.0 - s2)))[..., None] * h - l / eta
    ft = optics.np_microfacet_transmission(*l, t[..., 0], t[..., 1], t[..., 2], alpha, alpha, eta, False)
    th = np.sum(t * h, -1)
    ok &= (t[..., 2] < 0) & (np.abs(th) > 0)
    jac = np.where(ok, (lh + eta * th) ** 2 / (eta**2 * np.where(ok, np.abs(th), 1.0)), 0.0)
    T = float(np.sum(np.where(ok, ft * np.abs(t[..., 2]) * jac, 0.0) * W))
    return R, T


def hemisphere(lower: bool = False, n_mu: int = 96, n_phi: int = 32):
    """Directions and cosine-weighted solid angles of a hemisphere (for the smooth compensation lobe)."""
    x, w = np.polynomial.legendre.leggauss(n_mu)
    mu, wm = 0.5 * (x + 1.0), 0.5 * w
    phi = (np.arange(n_phi) + 0.5) / n_phi * 2.0 * math.pi
    M, P = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1.0 - M * M)
    v = np.stack([s * np.cos(P), s * np.sin(P), -M if lower else M], -1)
    return v, wm[:, None] * (2.0 * math.pi / n_phi) * M


def light(mu: float) -> np.ndarray:
    return np.array([math.sqrt(1.0 - mu * mu), 0.0, mu])


#: table nodes checked: near grazing (mu = 0.0003), mid (0.22), normal incidence
NODES = (2, 30, 64)


def test_registered_with_both_sides():
    m = registry.get("ggx-kulla-conty")
    assert isinstance(m, GGXKullaConty) and m.sides == ("brdf", "btdf")
    assert "Kulla" in GGXKullaConty.__doc__ and "Turquin" in GGXKullaConty.__doc__


def test_refuses_anything_but_one_interface():
    m = GGXKullaConty()
    coated = Stack("p", (Interface(0.2, (1.5,) * 3), Lambertian((0.5,) * 3)), "plastic")
    assert "single GGX interface" in m.reason(coated)
    assert "index-matched" in m.reason(dielectric(0.3, 1.0))
    with pytest.raises(ModelError, match="single GGX interface"):
        m.evaluate(coated, light(0.5), np.array([[0.0, 0.0, 1.0]]))
    assert m.reason(conductor(0.3)) is None and m.reason(dielectric(0.3)) is None
    with pytest.raises(ValueError, match="compensation"):
        GGXKullaConty(compensation="heitz")


def test_inside_albedo_table_matches_an_independent_quadrature():
    """E from the denser side (total internal reflection included; the white-furnace tests below
    check the other tables through the furnace itself)."""
    mus = ma.mu_nodes()
    inside = ma.load_albedo_table("dielectric", 1.0, 1.0 / 1.5)
    for k in (2, 40):
        assert inside.e[k] == pytest.approx(sum(single_scattering_albedo(mus[k], 1.0, 1.0 / 1.5, 0.0)), abs=TOL)


def test_table_average_is_the_integral_of_its_interpolant():
    mus = ma.mu_nodes()
    e = 0.3 + 0.5 * mus  # linear: 2 Int (0.3 + 0.5 mu) mu = 0.3 + 1/3
    assert ma.average(mus, e) == pytest.approx(0.3 + 1.0 / 3.0, abs=1e-12)
    t = ma.load_albedo_table("white", 0.5)
    fine = np.linspace(0.0, 1.0, 200001)
    assert t.e_avg == pytest.approx(2.0 * np.trapezoid(t.at(fine) * fine, fine), abs=1e-8)


def test_fresnel_averages_obey_the_two_sided_identity():
    """1 - F_avg(1/eta) = (1 - F_avg(eta)) / eta^2 (what crosses from each side balances)."""
    for eta in (1.2, 1.5, 2.0):
        assert 1.0 - ma.fresnel_average(1.0 / eta) == pytest.approx((1.0 - ma.fresnel_average(eta)) / eta**2, abs=1e-7)
    assert ma.fresnel_average(1.5) == pytest.approx(0.0917779, abs=2e-6)  # Fresnel's hemispherical average


@pytest.mark.parametrize("alpha", [0.05, 0.5, 1.0])
def test_white_furnace_conductor(alpha):
    """F = 1: directional albedo of the compensated BRDF = 1 at every angle (the method's claim):
    E by the independent quadrature + the compensation lobe integrated over the hemisphere."""
    m = GGXKullaConty()
    st = conductor(alpha)
    v, w = hemisphere()
    for k in NODES:
        mu = ma.mu_nodes()[k]
        _, comp = m.parts(st, light(mu), v)
        ms = float(np.sum(comp[..., 0] * w))
        assert sum(single_scattering_albedo(mu, alpha, *WHITE)) + ms == pytest.approx(1.0, abs=TOL)
    assert conductor_fresnel_term(1.0, 0.4) == 1.0


@pytest.mark.parametrize("alpha", [0.05, 1.0])
def test_white_furnace_dielectric(alpha):
    """No absorption: R + T = 1 at every angle (single scattering by quadrature + both compensation lobes)."""
    m = GGXKullaConty()
    st = dielectric(alpha)
    vu, wu = hemisphere()
    vd, wd = hemisphere(lower=True)
    for k in NODES:
        mu = ma.mu_nodes()[k]
        R, T = single_scattering_albedo(mu, alpha, 1.5, 0.0)
        _, comp_r = m.parts(st, light(mu), vu)
        _, comp_t = m.parts(st, light(mu), vd, "btdf")
        ms = float(np.sum(comp_r[..., 0] * wu) + np.sum(comp_t[..., 0] * wd))
        assert R + T + ms == pytest.approx(1.0, abs=TOL)


def test_split_conserves_from_both_sides_and_transmission_is_reciprocal():
    """k_r (1 - E_avg_same) + k_t (1 - E_avg_other) = 1 from each side, and the transmitted lobes obey
    f_t(out -> in) = eta^2 f_t(in -> out) (flux-based reciprocity, n_out = 1)."""
    for alpha, eta in ((0.05, 1.5), (1.0, 1.33)):
        out = ma.load_albedo_table("dielectric", alpha, eta)
        inside = ma.load_albedo_table("dielectric", alpha, 1.0 / eta)
        s = dielectric_split(eta, out.e_avg, inside.e_avg, ma.fresnel_average(eta), ma.fresnel_average(1.0 / eta))
        assert 0.0 < s.x < 1.0
        assert s.r_out * (1 - out.e_avg) + s.t_out * (1 - inside.e_avg) == pytest.approx(1.0, abs=1e-12)
        assert s.r_in * (1 - inside.e_avg) + s.t_in * (1 - out.e_avg) == pytest.approx(1.0, abs=1e-12)
        assert s.t_out == pytest.approx(eta**2 * s.t_in, rel=1e-12)
        # the model's BTDF compensation is the t_out lobe; swapping light and viewer uses t_in
        m = GGXKullaConty()
        l, v = light(0.8), np.array([0.3, 0.2, -math.sqrt(1 - 0.13)])
        got = m.parts(dielectric(alpha, eta), l, v[None], "btdf")[1][0, 0]
        back = s.t_in * (1 - inside.at(-v[2])) * (1 - out.at(l[2])) / math.pi
        assert got == pytest.approx(eta**2 * back, rel=1e-12)


@pytest.mark.parametrize("st", [conductor(0.5, 0.2, 3.0), dielectric(1.0)])
def test_compensation_lobe_is_reciprocal(st):
    rng = np.random.default_rng(5)
    m = GGXKullaConty()
    for _ in range(20):
        a, b = rng.normal(size=(2, 3))
        a[2], b[2] = abs(a[2]), abs(b[2])
        a /= np.linalg.norm(a)
        b /= np.linalg.norm(b)
        ab = m.parts(st, a, b[None])
        ba = m.parts(st, b, a[None])
        assert ab[1][0] == pytest.approx(ba[1][0], rel=1e-12)
        assert ab[0][0] == pytest.approx(ba[0][0], rel=1e-12)


def test_single_scattering_lobe_is_optics():
    st = conductor(0.3, 0.2, 3.0)
    l, v = light(0.6), np.array([[0.1, -0.4, math.sqrt(0.83)]])
    m = GGXKullaConty()
    single, comp = m.parts(st, l, v)
    assert single[0, 0] == optics.microfacet_reflection(*l, *v[0], 0.3, 0.3, 0.2, 3.0, False)
    # the simulator counts a walk on the microsurface as one event: the whole BRDF is bounce order 1
    r = m.evaluate(st, l, v)
    assert np.array_equal(r.top, single + comp) and np.all(r.internal == 0.0) and np.all(comp > 0.0)
    d = dielectric(0.3)
    vd = -v
    t = m.evaluate(d, l, vd, "btdf")
    assert np.all(t.top == 0.0) and np.array_equal(t.internal, sum(m.parts(d, l, vd, "btdf")))


def test_conductor_colour_term():
    """F_ms = F_avg^2 E_avg / (1 - F_avg (1 - E_avg)): light that scatters again keeps F_avg per
    bounce and leaves with E_avg or is lost again (hand-summed series over the extra bounces)."""
    f, e = 0.7, 0.8
    series = sum(f * f * e * (f * (1.0 - e)) ** j for j in range(200))
    assert conductor_fresnel_term(f, e) == pytest.approx(series, rel=1e-12)


def test_alpha_to_zero_limit():
    """alpha -> 0: the lost energy 1 - E vanishes away from grazing and so does the compensation;
    the compensated albedo tends to the smooth Fresnel factor; alpha = 0 (a Dirac) is 0."""
    losses = []
    mus = ma.mu_nodes()
    for alpha in (0.1, 0.03, 0.01):
        t = ma.load_albedo_table("white", alpha)
        losses.append(1.0 - t.e_avg)
        # second order in alpha: below alpha^2 (1 + tan^2 theta) = alpha^2 / mu^2 at mu >= 0.3
        assert np.max(1.0 - t.e[mus >= 0.3]) < alpha**2 / 0.09
        assert losses[-1] < alpha**2 / 0.09
    assert losses[0] > losses[1] > losses[2] > 0.0
    st = conductor(0.01, 0.2, 3.0)
    v, w = hemisphere()
    mu = 0.7
    ms = float(np.sum(GGXKullaConty().parts(st, light(mu), v)[1][..., 0] * w))
    total = single_scattering_albedo(mu, 0.01, 0.2, 3.0)[0] + ms
    assert ms < 1e-3
    assert total == pytest.approx(optics.fresnel_conductor(mu, 0.2, 3.0), abs=1e-3)
    smooth = GGXKullaConty().evaluate(conductor(0.0), light(mu), v)
    assert np.all(smooth.total == 0.0)


def test_turquin_light_white_furnace_and_dielectric():
    """turquin-light: f_ss (1 + F0 (1 - E) / E) with E at the light's cosine: albedo 1 for F = 1;
    dielectric f_ss / E_out: R + T = 1."""
    m = GGXKullaConty(compensation="turquin-light")
    v, w = hemisphere()
    vd, wd = hemisphere(lower=True)
    for k in (30, 64):
        mu = ma.mu_nodes()[k]
        l = light(mu)
        e = ma.load_albedo_table("white", 0.5).e[k]
        single, comp = m.parts(conductor(0.5), l, v[:1, :1])
        assert (single + comp)[0, 0, 0] == pytest.approx(single[0, 0, 0] / e, rel=1e-9)
        ed = ma.load_albedo_table("dielectric", 1.0, 1.5).e[k]
        R, T = single_scattering_albedo(mu, 1.0, 1.5, 0.0)
        assert (R + T) / ed == pytest.approx(1.0, abs=TOL)
        rb = m.evaluate(dielectric(1.0), l, vd[:2, :2], "btdf")
        ss = optics.np_microfacet_transmission(*l, vd[:2, :2, 0], vd[:2, :2, 1], vd[:2, :2, 2], 1.0, 1.0, 1.5, False)
        assert rb.internal[..., 1] == pytest.approx(ss / ed, rel=1e-9)


def test_tables_cached_on_disk(tmp_path):
    a = ma.load_albedo_table("white", 0.37, cache_dir=tmp_path)
    files = list((tmp_path / ma.DIRECTORY).glob("*.npz"))
    assert len(files) == 1
    ma._load_cached.cache_clear()
    b = ma.load_albedo_table("white", 0.37, cache_dir=tmp_path)
    assert np.array_equal(a.e, b.e)
    assert ma.table_path("white", 0.37, 1.0, False, tmp_path) != ma.table_path("white", 0.37, 1.0, True, tmp_path)


def test_turquin_scales_by_the_albedo_at_the_view():
    """Turquin 2019 as renderers evaluate it: the factor is 1 / E(mu_v) for F = 1 (E at the viewer's
    cosine, whatever the light), so the albedo seen from the viewer, Int f(l, v) cos(theta_l) dl =
    R_ss(mu_v) / E(mu_v) by reciprocity of the single-scattering lobe, is 1 (R_ss from this file's own
    half-vector quadrature); the BTDF is scaled by the albedo of the inside (the viewer's side)."""
    m = GGXKullaConty(compensation="turquin")
    table = ma.load_albedo_table("white", 0.5)
    mus = ma.mu_nodes()
    l = light(mus[40])
    for k in (12, 30, 64):
        v = light(mus[k])[None, :] * np.array([-1.0, 1.0, 1.0])   # the other side of the plane: off-specular
        single, comp = m.parts(conductor(0.5), l, v)
        assert ((single + comp) / single)[0, 0] == pytest.approx(1.0 / table.e[k], rel=1e-9)
        R, _ = single_scattering_albedo(mus[k], 0.5, *WHITE)
        assert R / table.e[k] == pytest.approx(1.0, abs=TOL)
    inside = ma.load_albedo_table("dielectric", 1.0, 1.0 / 1.5)
    vd = np.array([[0.3, 0.0, -math.sqrt(1.0 - 0.09)]])
    rb = m.evaluate(dielectric(1.0), l, vd, "btdf")
    ss = optics.np_microfacet_transmission(*l, vd[:, 0], vd[:, 1], vd[:, 2], 1.0, 1.0, 1.5, False)
    assert rb.internal[0, 1] == pytest.approx(ss[0] / inside.at(vd[0, 2]), rel=1e-9)
    # the option is not the light-side form
    light_side = GGXKullaConty(compensation="turquin-light").evaluate(conductor(0.5), l, v)
    assert not np.allclose(light_side.total, m.evaluate(conductor(0.5), l, v).total, rtol=1e-3)


@pytest.mark.parametrize("compensation", ["kulla-conty", "turquin-light"])
def test_white_furnace_through_the_harness_quadrature(compensation):
    """The same claim with models.compare.albedo (gonio furnace's hemispherical rule, graded about
    the lobes), on the model's evaluate as the harness calls it: white conductor E_brdf = 1,
    dielectric E_brdf + E_btdf = 1."""
    from models.compare.albedo import directional_albedo
    m = GGXKullaConty(compensation=compensation)
    metal = Stack("m", (Interface(0.3, (1e-9,) * 3, (1.0,) * 3),), "metal")
    glass = dielectric(0.3)
    for k in (20, 45, 64):
        l = light(ma.mu_nodes()[k])
        assert directional_albedo(m, metal, l, "brdf") == pytest.approx(np.ones(3), abs=TOL)
        e = directional_albedo(m, glass, l, "brdf") + directional_albedo(m, glass, l, "btdf")
        assert e == pytest.approx(np.ones(3), abs=TOL)
