"""Tests of the Weidlich & Wilkie family (models.weidlich_wilkie): ww09, elek10, ww-bati19.

Reference values are computed here from first principles, with textbook formulas written in
angle form (Snell's law on angles, Fresnel via sin/tan differences and the a/b form for
conductors, GGX D and Lambda in tan(theta); shared with other model tests in
tests/models/helpers.py), independently of goniometer.optics.
"""

from __future__ import annotations

import cmath
import math
from dataclasses import replace

import numpy as np
import pytest
from scipy import integrate

from goniometer.stack import Interface, Lambertian, Medium, Stack
from models.base import ModelError, coated_base
from models.weidlich_wilkie import WW09, WW09_VARIANT, Elek10, WWBati19, evaluate_variant
from tests.models.helpers import (angle, direction, fresnel_conductor_tb, fresnel_dielectric_tb, g1_tb,
                                  ggx_brdf_tb, half, polar, snell_about_n)

DEG = math.pi / 180.0
MODELS = {"ww09": WW09(), "elek10": Elek10(), "ww-bati19": WWBati19()}


# ---------------------------------------------------------------------- textbook optics

def snell_about(w: np.ndarray, m: np.ndarray, eta: float) -> np.ndarray:
    """Inner direction (pointing up) of w refracted through a facet m, built from angles.

    It lies in the plane of m and w, on w's side, at sin(t) = sin(i) / eta from m.
    """
    ti = angle(w, m)
    tt = math.asin(math.sin(ti) / eta)
    u = w - math.cos(ti) * m
    u = u / np.linalg.norm(u)
    return math.cos(tt) * m + math.sin(tt) * u


# ---------------------------------------------------------------------- stacks

def plastic_stack(alpha0=0.2, tau=(0.05, 0.1, 0.4), rho=(0.2, 0.5, 0.8), eta0=1.5) -> Stack:
    return Stack("plastic", (Interface(alpha0, (eta0,) * 3), Medium(tau), Lambertian(rho)), "plastic")


def metal_stack(alpha0=0.2, tau=(0.2, 0.2, 0.2), eta1=1.45, kappa1=(1.0, 0.01, 0.01), alpha1=0.05,
                eta0=1.5) -> Stack:
    return Stack("metal", (Interface(alpha0, (eta0,) * 3), Medium(tau), Interface(alpha1, (eta1,) * 3, kappa1)),
                 "metal")


# ---------------------------------------------------------------------- hand-computed references

def top_tb(l, v, alpha0, eta0) -> float:
    return ggx_brdf_tb(l, v, alpha0, lambda t: fresnel_dielectric_tb(t, eta0))


def base_tb(stack: Stack, lb, vb, alpha1: float) -> np.ndarray:
    """f_r1 at (lb, vb) inside the coat: rho/pi or the GGX conductor with index relative to the coat."""
    cb = coated_base(stack)
    if cb.base == "lambertian":
        return cb.rho / math.pi
    return np.array([ggx_brdf_tb(lb, vb, alpha1,
                                 lambda t, c=c: fresnel_conductor_tb(t, cb.eta1[c] / cb.eta0, cb.kappa1[c] / cb.eta0))
                     for c in range(3)])


def expected_internal(name: str, stack: Stack, l: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The internal term of each variant, step by step from Bati 2019 eq. 2 / table 2 / eq. 5."""
    cb = coated_base(stack)
    eta, a0 = cb.eta0, cb.alpha0
    h0 = half(l, v)
    theta_d = angle(l, h0)  # = angle(v, h0)
    if name == "ww09":
        t01 = 1.0 - fresnel_dielectric_tb(theta_d, eta)
        t10 = 1.0 - fresnel_dielectric_tb(angle(v, h0), eta)  # leaves through the facet h0
        l1, v1 = snell_about(l, h0, eta), snell_about(v, h0, eta)
        g = g1_tb(polar(l1), a0) * g1_tb(polar(v1), a0)
        x = (1.0 - g) + t10 * g
        fr1 = base_tb(stack, l, v, cb.alpha1 if cb.alpha1 is not None else 0.0)  # the bug: (l0, v0)
    elif name == "elek10":
        t01 = 1.0 - fresnel_dielectric_tb(theta_d, eta)
        t10 = 1.0 - fresnel_dielectric_tb(angle(v, h0), eta)
        l1, v1 = snell_about_n(l, eta), snell_about_n(v, eta)
        g = g1_tb(polar(l), a0) * g1_tb(polar(v), a0)
        x = (1.0 - g) + t10 * g
        fr1 = base_tb(stack, l1, v1, max(a0, cb.alpha1) if cb.alpha1 is not None else 0.0)
    else:  # ww-bati19, eq. 5
        t01 = 1.0 - fresnel_dielectric_tb(polar(l), eta)
        t10 = 1.0 - fresnel_dielectric_tb(polar(v), eta)
        l1, v1 = snell_about_n(l, eta), snell_about_n(v, eta)
        x = t10 / eta**2
        fr1 = base_tb(stack, l1, v1, max(a0, cb.alpha1) if cb.alpha1 is not None else 0.0)
    a = np.exp(-cb.tau * (1.0 / math.cos(polar(l1)) + 1.0 / math.cos(polar(v1))))
    return t01 * fr1 * a * x


LIGHTS = [(30.0, 20.0), (65.0, 0.0)]
VIEWS = [(40.0, 160.0), (60.0, 90.0), (75.0, 250.0), (10.0, 0.0)]


@pytest.mark.parametrize("name", list(MODELS))
@pytest.mark.parametrize("kind", ["plastic", "metal"])
@pytest.mark.parametrize("light", LIGHTS)
def test_hand_computed_values(name, kind, light):
    stack = plastic_stack() if kind == "plastic" else metal_stack()
    l = direction(light[0] * DEG, light[1] * DEG)
    views = [direction(t * DEG, p * DEG) for t, p in VIEWS]
    got = MODELS[name].evaluate(stack, l, np.array(views))
    for i, v in enumerate(views):
        want_top = top_tb(l, v, 0.2, 1.5)
        np.testing.assert_allclose(got.top[i], [want_top] * 3, rtol=1e-9, atol=0)
        np.testing.assert_allclose(got.internal[i], expected_internal(name, stack, l, v), rtol=1e-9, atol=0)


@pytest.mark.parametrize("name", list(MODELS))
def test_hand_values_metallic_paint_smooth_coat(name):
    """A smooth coat (alpha0 = 0.001) over a rough base (alpha1 = 0.2), eta1 = 1.9, coloured tau."""
    stack = metal_stack(alpha0=0.001, tau=(0.05, 0.1, 0.4), eta1=1.9, alpha1=0.2)
    l = direction(45.0 * DEG, 0.0)
    views = [direction(30.0 * DEG, 200.0 * DEG), direction(80.0 * DEG, 45.0 * DEG)]
    got = MODELS[name].evaluate(stack, l, np.array(views))
    for i, v in enumerate(views):
        np.testing.assert_allclose(got.internal[i], expected_internal(name, stack, l, v), rtol=1e-9, atol=0)


def test_top_lobe_at_mirror_for_nearly_smooth_coat():
    """alpha0 = 0.001 works normally: at the mirror direction D(h = n) = 1 / (pi alpha^2)."""
    alpha, tl = 0.001, 45.0 * DEG
    l, v = direction(tl, 0.0), direction(tl, math.pi)
    g1 = g1_tb(tl, alpha)
    want = fresnel_dielectric_tb(tl, 1.5) / (math.pi * alpha**2) * g1 * g1 / (4.0 * math.cos(tl) ** 2)
    for m in MODELS.values():
        got = m.evaluate(plastic_stack(alpha0=alpha), l, v[None])
        np.testing.assert_allclose(got.top[0], [want] * 3, rtol=1e-9)


# ---------------------------------------------------------------------- shared limits

def hemisphere(n_theta: int = 46, n_phi: int = 37, grazing: float = 89.9) -> np.ndarray:
    """Grid of view directions (n_theta, n_phi, 3) from the pole to ``grazing`` degrees."""
    th = np.linspace(0.0, grazing, n_theta) * DEG
    ph = np.linspace(0.0, 360.0, n_phi) * DEG
    t, p = np.meshgrid(th, ph, indexing="ij")
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


@pytest.mark.parametrize("name", list(MODELS))
@pytest.mark.parametrize("kind", ["plastic", "metal"])
def test_opaque_coat_leaves_only_the_top_lobe(name, kind):
    make = plastic_stack if kind == "plastic" else metal_stack
    thick, clear = make(tau=(1e3,) * 3), make(tau=(0.0,) * 3)
    v = hemisphere()
    for tl in (0.0, 45.0, 80.0):
        l = direction(tl * DEG, 0.0)
        a, b = MODELS[name].evaluate(thick, l, v), MODELS[name].evaluate(clear, l, v)
        assert np.all(a.internal == 0.0)
        assert np.array_equal(a.top, b.top)
        assert b.internal.max() > 0.0


@pytest.mark.parametrize("eta0", [1.5, 1.2])
def test_bati19_jacobian_lambertian(eta0):
    """tau = 0, Lambertian: internal = rho/pi T01(n.l) T10(n.v) / eta0^2, the 1/eta^2 shown explicitly."""
    rho = np.array([0.2, 0.5, 0.8])
    stack = plastic_stack(alpha0=0.001, tau=(0.0,) * 3, rho=tuple(rho), eta0=eta0)
    l = direction(35.0 * DEG, 0.0)
    views = [(0.0, 0.0), (20.0, 180.0), (50.0, 90.0), (85.0, 300.0)]
    v = np.array([direction(t * DEG, p * DEG) for t, p in views])
    got = WWBati19().evaluate(stack, l, v).internal
    for i, (tv, _) in enumerate(views):
        no_jacobian = rho / math.pi * (1.0 - fresnel_dielectric_tb(35.0 * DEG, eta0)) \
            * (1.0 - fresnel_dielectric_tb(tv * DEG, eta0))
        np.testing.assert_allclose(got[i] / no_jacobian, 1.0 / eta0**2, rtol=1e-9)


def test_bati19_jacobian_conserves_the_escaping_flux():
    """With the 1/eta^2 Jacobian, the albedo of the internal term of a clear coat over a white
    Lambertian base equals T01(l) (1 - r_i): what enters, then the part of the Lambertian
    radiance inside the coat that is not Fresnel-reflected back (r_i = internal hemispherical
    reflectance, TIR included), integrated here over the *inner* hemisphere."""
    eta = 1.5
    stack = plastic_stack(alpha0=0.05, tau=(0.0,) * 3, rho=(1.0, 1.0, 1.0), eta0=eta)
    tl = 40.0 * DEG
    l = direction(tl, 0.0)
    # model albedo: the internal term does not depend on phi_v; Gauss-Legendre in mu = cos(theta_v)
    x, w = np.polynomial.legendre.leggauss(200)
    mu, w = 0.5 * (x + 1.0), 0.5 * w
    v = np.stack([np.sqrt(1.0 - mu**2) * np.cos(1.0), np.sqrt(1.0 - mu**2) * np.sin(1.0), mu], axis=-1)
    f = WWBati19().evaluate(stack, l, v).internal[:, 0]
    albedo = 2.0 * math.pi * float(np.sum(w * f * mu))
    # inner hemispherical reflectance: 2 Int F(mu1, 1/eta) mu1 dmu1, TIR below the critical cosine
    mu_c = math.sqrt(1.0 - 1.0 / eta**2)
    r_i = mu_c**2 + 2.0 * integrate.quad(lambda m: fresnel_dielectric_tb(math.acos(m), 1.0 / eta) * m,
                                         mu_c, 1.0, epsabs=1e-13, epsrel=1e-12, limit=200)[0]
    want = (1.0 - fresnel_dielectric_tb(tl, eta)) * (1.0 - r_i)
    # both quadratures converge to ~1e-15 (smooth integrand in mu; quad handles the sqrt kink at mu_c)
    assert albedo == pytest.approx(want, rel=1e-10)


@pytest.mark.parametrize("name", ["elek10", "ww-bati19"])
def test_elek_roughness_rule(name):
    """alpha1 <- max(alpha0, alpha1): frosted metal (0.2 / 0.001) == metallic patina (0.2 / 0.2)."""
    v = hemisphere()
    for tl in (0.0, 45.0, 80.0):
        l = direction(tl * DEG, 0.0)
        frosted = MODELS[name].evaluate(metal_stack(alpha0=0.2, alpha1=0.001), l, v)
        patina = MODELS[name].evaluate(metal_stack(alpha0=0.2, alpha1=0.2), l, v)
        assert np.array_equal(frosted.internal, patina.internal)
        assert np.array_equal(frosted.top, patina.top)
    # ww09 has no such rule
    l = direction(45.0 * DEG, 0.0)
    a = MODELS["ww09"].evaluate(metal_stack(alpha0=0.2, alpha1=0.001), l, v).internal
    b = MODELS["ww09"].evaluate(metal_stack(alpha0=0.2, alpha1=0.2), l, v).internal
    assert not np.allclose(a, b)


def test_ww09_bug_has_no_impact_on_plastics_only():
    """Bati 2019 footnote 3: evaluating f_r1 at (l0, v0) instead of (l1, v1) does not matter for a
    Lambertian base (f_r1 is constant) but does for a conductor."""
    fixed = replace(WW09_VARIANT, base_at_refracted=True)
    v = hemisphere()
    l = direction(45.0 * DEG, 0.0)
    plastic, metal = coated_base(plastic_stack()), coated_base(metal_stack(alpha1=0.2))
    assert np.array_equal(evaluate_variant(WW09_VARIANT, plastic, l, v).internal,
                          evaluate_variant(fixed, plastic, l, v).internal)
    a = evaluate_variant(WW09_VARIANT, metal, l, v).internal
    b = evaluate_variant(fixed, metal, l, v).internal
    assert np.max(np.abs(a - b) / np.maximum(b, 1e-300)) > 0.5


def test_ww09_versus_elek10():
    """What actually holds between ww09 and elek10.

    * Plastics: the bug is invisible, but the absorption (pair refracted about h0 vs n) and the TIR
      term (G(l1, v1) vs G(l0, v0)) differ, so the two differ off the normal when tau > 0.
    * Plastics, tau = 0 and a nearly smooth coat: only G differs, and G ~ 1: equal to 1e-5.
    * At l = v = n (h0 = n, alpha1 >= alpha0) both plastics and metals agree exactly.
    * Metals away from the normal: large differences (f_r1 at unrefracted directions).
    """
    ww, el = MODELS["ww09"], MODELS["elek10"]
    v = hemisphere(n_theta=40, grazing=85.0)
    l = direction(45.0 * DEG, 0.0)
    p = plastic_stack()
    rel = np.abs(ww.evaluate(p, l, v).internal / el.evaluate(p, l, v).internal - 1.0)
    assert rel.max() > 0.05
    p0 = plastic_stack(alpha0=0.001, tau=(0.0,) * 3)
    np.testing.assert_allclose(ww.evaluate(p0, l, v).internal, el.evaluate(p0, l, v).internal, rtol=1e-5)
    n = np.array([0.0, 0.0, 1.0])
    for stack in (plastic_stack(), metal_stack(alpha0=0.05, alpha1=0.2)):
        np.testing.assert_allclose(ww.evaluate(stack, n, n[None]).internal, el.evaluate(stack, n, n[None]).internal,
                                   rtol=1e-12)
    m = metal_stack(alpha0=0.001, tau=(0.0,) * 3, alpha1=0.2)
    a, b = ww.evaluate(m, l, v).internal, el.evaluate(m, l, v).internal
    assert np.max(np.abs(a - b) / np.maximum(b, 1e-300)) > 0.5


@pytest.mark.parametrize("name", list(MODELS))
def test_transmittances_use_the_documented_normals(name):
    """T10 choice: ww09 and elek10 take T10 about h0, so at a smooth, clear coat over a Lambertian
    base (G ~ 1, a = 1) internal = rho/pi T01(h0)^2; ww-bati19 takes both about n."""
    stack = plastic_stack(alpha0=1e-6, tau=(0.0,) * 3)
    rho = np.array([0.2, 0.5, 0.8])
    l, v = direction(20.0 * DEG, 0.0), direction(70.0 * DEG, 130.0 * DEG)
    got = MODELS[name].evaluate(stack, l, v[None]).internal[0]
    if name == "ww-bati19":
        want = rho / math.pi * (1 - fresnel_dielectric_tb(20 * DEG, 1.5)) * (1 - fresnel_dielectric_tb(70 * DEG, 1.5)) / 2.25
    else:
        t = 1.0 - fresnel_dielectric_tb(angle(l, half(l, v)), 1.5)
        want = rho / math.pi * t * t
    np.testing.assert_allclose(got, want, rtol=1e-9)  # G differs from 1 by ~1e-12 at alpha0 = 1e-6


# ---------------------------------------------------------------------- degenerate inputs

@pytest.mark.parametrize("name", list(MODELS))
def test_smooth_interfaces_and_lower_hemisphere_give_zeros(name):
    m = MODELS[name]
    l = direction(30.0 * DEG, 0.0)
    v = hemisphere()
    smooth_top = m.evaluate(plastic_stack(alpha0=0.0), l, v)
    assert np.all(smooth_top.top == 0.0) and smooth_top.internal.max() > 0.0
    smooth_all = m.evaluate(metal_stack(alpha0=0.0, alpha1=0.0), l, v)
    assert np.all(smooth_all.top == 0.0) and np.all(smooth_all.internal == 0.0)
    below = np.array([[0.3, 0.0, -math.sqrt(1 - 0.09)], [1.0, 0.0, 0.0], [np.nan, 0.0, 1.0]])
    out = m.evaluate(metal_stack(), l, below)
    assert np.all(out.top == 0.0) and np.all(out.internal == 0.0)
    assert m.evaluate(plastic_stack(), l, v).total.shape == v.shape


# ---------------------------------------------------------------------- refusals

def _unsupported() -> dict[str, Stack]:
    coat = Interface(0.2, (1.5,) * 3)
    return {
        "slab": Stack("slab", (coat, Medium((0.1,) * 3), Interface(0.2, (1.0,) * 3)), "slab"),
        "conductor-only": Stack("c", (Interface(0.2, (1.45,) * 3, (1.0, 0.01, 0.01)),)),
        "lambertian-only": Stack("l", (Lambertian((0.5,) * 3),)),
        "dielectric-only": Stack("d", (coat,)),
        "three-interfaces": Stack("3", (coat, Medium((0.1,) * 3), Interface(0.1, (1.3,) * 3), Medium((0.1,) * 3),
                                        Interface(0.2, (1.45,) * 3, (1.0, 0.01, 0.01)))),
    }


@pytest.mark.parametrize("name", list(MODELS))
@pytest.mark.parametrize("which", list(_unsupported()))
def test_refusals(name, which):
    m, stack = MODELS[name], _unsupported()[which]
    assert not m.supports(stack)
    reason = m.support_reason(stack)
    assert reason and "\n" not in reason
    with pytest.raises(ModelError, match=name):
        m.evaluate(stack, np.array([0.0, 0.0, 1.0]), np.array([[0.0, 0.0, 1.0]]))


@pytest.mark.parametrize("name", list(MODELS))
def test_brdf_only(name):
    m = MODELS[name]
    assert m.sides == ("brdf",)
    assert m.supports(plastic_stack()) and m.supports(metal_stack())
    with pytest.raises(ModelError):
        m.evaluate(plastic_stack(), np.array([0.0, 0.0, 1.0]), np.array([[0.0, 0.0, -1.0]]), side="btdf")


# ---------------------------------------------------------------------- database sweep

def _database() -> list[Stack]:
    out = []
    for alpha0 in (0.001, 0.05, 0.2):
        for tau in ((0.2, 0.2, 0.2), (0.05, 0.1, 0.4)):
            for rho in ((0.5,) * 3, (0.2, 0.5, 0.8)):
                out.append(plastic_stack(alpha0=alpha0, tau=tau, rho=rho))
            for eta1 in (1.9, 1.45, 1.2):
                for alpha1 in (0.001, 0.2):
                    out.append(metal_stack(alpha0=alpha0, tau=tau, eta1=eta1, alpha1=alpha1))
    return out


@pytest.mark.parametrize("name", list(MODELS))
def test_finite_and_non_negative_on_the_database(name):
    m = MODELS[name]
    v = hemisphere(n_theta=91, n_phi=73)
    for stack in _database():
        for tl in (0.0, 45.0, 80.0, 89.0):
            out = m.evaluate(stack, direction(tl * DEG, 0.0), v)
            for part in (out.top, out.internal):
                assert np.all(np.isfinite(part)), (stack, tl)
                assert np.all(part >= 0.0), (stack, tl)


def test_elek_frosted_metal_at_normal_incidence_by_hand():
    # Bati 2019 metal M4 (alpha0 = 0.2 coat over a smooth conductor, alpha1 = 0.001): Elek's rule
    # alpha1 <- max(alpha0, alpha1) (Bati 2019 table 2) makes the base an alpha = 0.2 lobe, so at
    # l = v = n the internal BRDF is T01 T10 exp(-2 tau) F_base D(alpha = 0.2) / 4 with G = 1, by hand:
    # T = 1 - ((1.5 - 1) / (1.5 + 1))^2, D = 1 / (pi alpha^2), F the normal-incidence conductor
    # reflectance of the relative index (1.45 + i kappa) / 1.5. Red: 0.96^2 e^-0.4 0.1033 7.958 / 4 = 0.12699.
    st = Stack("M4", (Interface(0.2, (1.5,) * 3), Medium((0.2,) * 3),
                      Interface(0.001, (1.45,) * 3, (1.0, 0.01, 0.01))), "metal")
    r = Elek10().evaluate(st, np.array([0.0, 0.0, 1.0]), np.array([[0.0, 0.0, 1.0]]))
    n, k = 1.45 / 1.5, np.array([1.0, 0.01, 0.01]) / 1.5
    F = ((n - 1) ** 2 + k ** 2) / ((n + 1) ** 2 + k ** 2)
    T = 1.0 - (0.5 / 2.5) ** 2
    expect = T * T * np.exp(-0.4) * F / (np.pi * 0.2 ** 2) / 4.0
    assert r.internal[0] == pytest.approx(expect, rel=1e-12)
    assert expect[0] == pytest.approx(0.12699, abs=1e-5)


# ---------------------------------------------------------------------- pinned values (issue 11)
#
# Source: Bati, Pacanowski, Barla 2019, "Numerical Analysis of Layered Materials Models"
# (/work/shared/papers/bati2019-numerical-analysis-layered-models.txt):
#   eq. 1   f_r(l, v) = D(h) G(l, v) F(l.h) / (4 |l.n| |v.n|)          (every microfacet lobe)
#   eq. 2   f = f_r0(l0, v0) + T01 f_r1(l1, v1) a t,  a = exp(-tau (1/|n.l1| + 1/|n.v1|)),
#           t = (1 - G) + T10 G                                          (ww09, elek10)
#   table 2 ww09:   T01 about h0, (l1, v1) refracted about h0, f_r1 at (l0, v0), G = G(l1, v1)
#           elek10: T01 about h0, (l1, v1) refracted about n,  f_r1 at (l1, v1), G = G(l0, v0)
#   sec 3.1 Elek's rule alpha1 <- max(alpha0, alpha1)                    (elek10, ww-bati19)
#   eq. 5   f = f_r0(l0, v0) + T01 f_r1(l1, v1) a T10 / eta^2,  T01, T10 and Snell about n,
#           no t; appendix C: eta is the coat's index (J = eta_air^2 / eta_coat^2)  (ww-bati19)
# Not fixed by the paper, our documented choices (models/weidlich_wilkie.py): T10 of ww09 and
# elek10 about h0 (equal to T01); G separable Smith G1 G1 of the coat's alpha0; a conductor base
# takes its index relative to the coat, (eta1 + i kappa1) / eta0.
#
# The numbers below were computed outside the project (a scratch script using only `math` and
# `cmath`: Fresnel in Walter 2007's g-form (eq. 22) for the coat, the complex-amplitude form
# r_s = (c - w)/(c + w), r_p = (N^2 c - w)/(N^2 c + w), w = sqrt(N^2 - sin^2) for the conductor,
# GGX D = alpha^2 / (pi (1 + (alpha^2 - 1) cos^2)^2), Lambda = (sqrt(1 + alpha^2 tan^2) - 1) / 2,
# refraction by Walter 2007 eq. 40), then checked against `expected_internal` above (angle forms)
# to 1e-12. `_bati2019_by_hand` repeats that derivation here.

def _fresnel_g(c: float, eta: float) -> float:
    """Unpolarised dielectric Fresnel, Walter 2007 eq. 22 (g-form); 1 under total reflection."""
    g2 = eta * eta - 1.0 + c * c
    if g2 <= 0.0:
        return 1.0
    g = math.sqrt(g2)
    return 0.5 * ((g - c) / (g + c)) ** 2 * (1.0 + ((c * (g + c) - 1.0) / (c * (g - c) + 1.0)) ** 2)


def _fresnel_complex(c: float, n: float, k: float) -> float:
    """Unpolarised conductor Fresnel from the complex amplitudes r_s, r_p of N = n + i k."""
    big_n = complex(n, k)
    w = cmath.sqrt(big_n * big_n - (1.0 - c * c))
    rs = (c - w) / (c + w)
    rp = (big_n * big_n * c - w) / (big_n * big_n * c + w)
    return 0.5 * (abs(rs) ** 2 + abs(rp) ** 2)


def _g1_cos(c: float, alpha: float) -> float:
    """Smith G1 = 1 / (1 + Lambda), Lambda = (sqrt(1 + alpha^2 tan^2) - 1) / 2, from the cosine."""
    return 1.0 / (1.0 + 0.5 * (math.sqrt(1.0 + alpha * alpha * (1.0 - c * c) / (c * c)) - 1.0))


def _eq1(l: np.ndarray, v: np.ndarray, alpha: float, fresnel) -> float:
    """Bati 2019 eq. 1 with GGX D (cosine form) and separable Smith G = G1(l) G1(v)."""
    h = (l + v) / np.linalg.norm(l + v)
    d = alpha * alpha / (math.pi * (1.0 + (alpha * alpha - 1.0) * h[2] ** 2) ** 2)
    return fresnel(float(l @ h)) * d * _g1_cos(l[2], alpha) * _g1_cos(v[2], alpha) / (4.0 * l[2] * v[2])


def _inside(w: np.ndarray, m: np.ndarray, eta: float) -> np.ndarray:
    """w refracted through a facet m into index eta (Walter 2007 eq. 40), flipped to point up."""
    c = float(w @ m)
    return w / eta - (c / eta - math.sqrt(1.0 - (1.0 - c * c) / eta ** 2)) * m


def _bati2019_by_hand(name: str, stack: Stack, l: np.ndarray, v: np.ndarray) -> tuple[float, np.ndarray]:
    """(top, internal RGB) of ww09 / elek10 / ww-bati19 from Bati 2019 eq. 1, 2, 5 and table 2."""
    cb = coated_base(stack)
    eta, a0, tau = cb.eta0, cb.alpha0, np.asarray(cb.tau)
    n = np.array([0.0, 0.0, 1.0])
    h0 = (l + v) / np.linalg.norm(l + v)

    def f_r1(lb, vb, alpha1):
        if cb.base == "lambertian":
            return np.asarray(cb.rho) / math.pi
        return np.array([_eq1(lb, vb, alpha1, lambda c, i=i: _fresnel_complex(c, cb.eta1[i] / eta, cb.kappa1[i] / eta))
                         for i in range(3)])

    top = _eq1(l, v, a0, lambda c: _fresnel_g(c, eta))                     # f_r0, eq. 1
    if name == "ww09":                                                     # eq. 2, table 2 row 1
        t01 = 1.0 - _fresnel_g(float(l @ h0), eta)
        t10 = 1.0 - _fresnel_g(float(v @ h0), eta)
        l1, v1 = _inside(l, h0, eta), _inside(v, h0, eta)
        g = _g1_cos(l1[2], a0) * _g1_cos(v1[2], a0)
        x = (1.0 - g) + t10 * g
        fr1 = f_r1(l, v, cb.alpha1)                                        # at (l0, v0): the bug
    elif name == "elek10":                                                 # eq. 2, table 2 row 2
        t01 = 1.0 - _fresnel_g(float(l @ h0), eta)
        t10 = 1.0 - _fresnel_g(float(v @ h0), eta)
        l1, v1 = _inside(l, n, eta), _inside(v, n, eta)
        g = _g1_cos(l[2], a0) * _g1_cos(v[2], a0)
        x = (1.0 - g) + t10 * g
        fr1 = f_r1(l1, v1, max(a0, cb.alpha1) if cb.alpha1 is not None else None)
    else:                                                                  # eq. 5
        t01 = 1.0 - _fresnel_g(l[2], eta)
        t10 = 1.0 - _fresnel_g(v[2], eta)
        l1, v1 = _inside(l, n, eta), _inside(v, n, eta)
        x = t10 / eta ** 2
        fr1 = f_r1(l1, v1, max(a0, cb.alpha1) if cb.alpha1 is not None else None)
    a = np.exp(-tau * (1.0 / l1[2] + 1.0 / v1[2]))                         # eq. 2, a
    return top, t01 * fr1 * a * x


def _database_stack(name: str) -> Stack:
    """The Bati 2019 database materials used by the pins (configs/bati2019.toml)."""
    coat = {"plastic/P1-a0_0.2": 0.2, "metal/M2-a0_0.05-a1_0.2": 0.05, "metal/M4-a0_0.2-a1_0.001": 0.2}[name]
    if name.startswith("plastic/P1"):  # tau C, rho C
        return plastic_stack(alpha0=coat, tau=(0.05, 0.1, 0.4), rho=(0.2, 0.5, 0.8))
    if name.startswith("metal/M2"):    # tau C, eta1 = 1.45
        return metal_stack(alpha0=coat, tau=(0.05, 0.1, 0.4), eta1=1.45, alpha1=0.2)
    return metal_stack(alpha0=coat, tau=(0.2, 0.2, 0.2), eta1=1.45, alpha1=0.001)  # M4: tau A


#: (theta_l, phi_l), (theta_v, phi_v) in degrees
PIN_POINTS = {
    "N0": ((0.0, 0.0), (0.0, 0.0)),        # normal incidence, specular view
    "N1": ((0.0, 0.0), (30.0, 90.0)),      # normal incidence, off-specular view
    "O1": ((60.0, 0.0), (40.0, 135.0)),    # oblique, off-specular, out of the plane of incidence
    "O2": ((60.0, 0.0), (55.0, 180.0)),    # oblique, in the plane, near the base lobe
}

#: (material, point) -> (top, {model: internal RGB}); 15 significant digits
PINNED_WW = {
    ("plastic/P1-a0_0.2", "N0"): (0.0795774715459475, {
        "ww09": (0.0530876059637504, 0.120089130774876, 0.105450099740271),
        "elek10": (0.0530876059637504, 0.120089130774876, 0.105450099740271),
        "ww-bati19": (0.0235944915394446, 0.0533729470110559, 0.0468667109956758),
    }),
    ("plastic/P1-a0_0.2", "N1"): (0.0134952655629987, {
        "ww09": (0.0528011127737152, 0.118805405003399, 0.101035704208568),
        "elek10": (0.0529252458550765, 0.119359289713251, 0.10291915358345),
        "ww-bati19": (0.0234857285045023, 0.052966024576847, 0.0456706673709714),
    }),
    ("plastic/P1-a0_0.2", "O1"): (0.00820422343071611, {
        "ww09": (0.0505344442483724, 0.111181988612918, 0.0826410887975619),
        "elek10": (0.051164268853484, 0.11383572386232, 0.0904959848897713),
        "ww-bati19": (0.0218860994171913, 0.0486945289262943, 0.038710689442781),
    }),
    ("metal/M2-a0_0.05-a1_0.2", "N0"): (1.27323954473522, {
        "ww09": (0.1714130539122, 0.000448474794909965, 0.000246128185941471),
        "elek10": (0.1714130539122, 0.000448474794909965, 0.000246128185941471),
        "ww-bati19": (0.0761835795165331, 0.000199322131071095, 0.000109390304862876),
    }),
    ("metal/M2-a0_0.05-a1_0.2", "N1"): (0.00191571152673663, {
        "ww09": (0.0289503525811609, 7.5500122410111e-05, 4.01297400743279e-05),
        "elek10": (0.0636920690528038, 0.000166190635906508, 8.95625699834733e-05),
        "ww-bati19": (0.0282671988984588, 7.37571228269562e-05, 3.97487947436766e-05),
    }),
    ("metal/M2-a0_0.05-a1_0.2", "O1"): (0.000711198661527079, {
        "ww09": (0.0178949066515945, 7.44371850355176e-05, 3.45805225238503e-05),
        "elek10": (0.0444452589470784, 0.000118939932090314, 5.90960483012213e-05),
        "ww-bati19": (0.0190451576385968, 5.0966735481984e-05, 2.53231409238729e-05),
    }),
    # frosted metal: Elek's rule makes the base alpha1 = 0.2 for elek10 and ww-bati19; ww09 keeps
    # alpha1 = 0.001, evaluated at (l0, v0) whose half vector is 2.5 deg off the normal
    ("metal/M4-a0_0.2-a1_0.001", "O2"): (0.473243318500887, {
        "ww09": (0.00824637891263185, 0.000105491980320336, 0.000105491980320336),
        "elek10": (0.169819561846928, 0.000549744165115674, 0.000549744165115674),
        "ww-bati19": (0.0749764111585014, 0.00024271552763075, 0.00024271552763075),
    }),
}


@pytest.mark.parametrize("material, point", list(PINNED_WW))
@pytest.mark.parametrize("name", list(MODELS))
def test_pinned_values_from_bati2019_equations(name, material, point):
    """Each variant at database materials and (l, v) points against numbers computed from Bati
    2019 eq. 1, 2, 5 and table 2 (see the block comment above), exact to 1e-10 relative."""
    stack = _database_stack(material)
    (tl, pl), (tv, pv) = PIN_POINTS[point]
    l, v = direction(tl * DEG, pl * DEG), direction(tv * DEG, pv * DEG)
    want_top, want = PINNED_WW[(material, point)]
    want = np.array(want[name])
    # the derivation, repeated here, gives the pinned numbers ...
    top, internal = _bati2019_by_hand(name, stack, l, v)
    assert top == pytest.approx(want_top, rel=1e-12)
    np.testing.assert_allclose(internal, want, rtol=1e-12, atol=0)
    # ... and the model gives them too
    got = MODELS[name].evaluate(stack, l, v[None])
    np.testing.assert_allclose(got.top[0], [want_top] * 3, rtol=1e-10, atol=0)
    np.testing.assert_allclose(got.internal[0], want, rtol=1e-10, atol=0)


def test_pinned_normal_incidence_closed_forms():
    """At l = v = n every normal coincides (h0 = n, l1 = v1 = n, G = 1), so the three variants
    reduce to arithmetic (Bati 2019 eq. 1, 2, 5):
      T01 = T10 = 1 - ((1.5 - 1) / (1.5 + 1))^2 = 0.96,  a = exp(-2 tau),  t = T10 (G = 1);
      top = F(0) D(n) / 4 = 0.04 / (4 pi alpha0^2);
      ww09 = elek10 = 0.96 * 0.96 * f_r1 * exp(-2 tau),  ww-bati19 = that / 1.5^2;
      f_r1 = rho / pi (P1) or F_c(0) / (4 pi alpha1^2) (M2, alpha1 = 0.2), with
      F_c(0) = ((n - 1)^2 + k^2) / ((n + 1)^2 + k^2), n + i k = (1.45 + i kappa) / 1.5."""
    n = np.array([0.0, 0.0, 1.0])
    tau = np.array([0.05, 0.1, 0.4])
    # P1: red 0.9216 * 0.2 * e^-0.1 / pi = 0.053087606, ww-bati19 0.4096 * 0.2 * e^-0.1 / pi = 0.023594492
    plastic = _database_stack("plastic/P1-a0_0.2")
    fr1 = np.array([0.2, 0.5, 0.8]) / math.pi
    want = {"ww09": 0.9216 * fr1 * np.exp(-2 * tau), "elek10": 0.9216 * fr1 * np.exp(-2 * tau),
            "ww-bati19": 0.9216 * fr1 * np.exp(-2 * tau) / 2.25}
    assert want["ww09"][0] == pytest.approx(0.053087606, abs=5e-10)
    assert want["ww-bati19"][0] == pytest.approx(0.023594492, abs=5e-10)
    for name, m in MODELS.items():
        got = m.evaluate(plastic, n, n[None])
        np.testing.assert_allclose(got.top[0], [1.0 / (4.0 * math.pi)] * 3, rtol=1e-12)  # 0.04 / (4 pi 0.04)
        np.testing.assert_allclose(got.internal[0], want[name], rtol=1e-12)
    # M2 (alpha0 = 0.05, alpha1 = 0.2): red F_c(0) = 0.103323886, 0.9216 e^-0.1 0.103324 / (0.16 pi) = 0.17141305
    metal = _database_stack("metal/M2-a0_0.05-a1_0.2")
    nn, kk = 1.45 / 1.5, np.array([1.0, 0.01, 0.01]) / 1.5
    f0 = ((nn - 1.0) ** 2 + kk ** 2) / ((nn + 1.0) ** 2 + kk ** 2)
    assert f0[0] == pytest.approx(0.103323886, abs=5e-10)
    fr1 = f0 / (4.0 * math.pi * 0.2 ** 2)
    want = {"ww09": 0.9216 * fr1 * np.exp(-2 * tau), "elek10": 0.9216 * fr1 * np.exp(-2 * tau),
            "ww-bati19": 0.9216 * fr1 * np.exp(-2 * tau) / 2.25}
    assert want["ww09"][0] == pytest.approx(0.17141305, abs=5e-9)
    for name, m in MODELS.items():
        got = m.evaluate(metal, n, n[None])
        np.testing.assert_allclose(got.top[0], [0.04 / (4.0 * math.pi * 0.05 ** 2)] * 3, rtol=1e-12)
        np.testing.assert_allclose(got.internal[0], want[name], rtol=1e-11)
