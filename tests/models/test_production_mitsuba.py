"""mitsuba-roughplastic and mitsuba-principled against hand-computed values and limits of Mitsuba's
own definitions (roughplastic with no diffuse = GGX dielectric reflection of goniometer.optics;
principled's clearcoat, metallic and diffuse lobes written out from principled.cpp), the cosine
conversion, the parameter mapping and the refusals. Never against the goniometer simulation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from goniometer import optics
from goniometer.stack import Interface, Lambertian, Medium, Stack
from models import registry
from models.production import mitsuba as pm
from models.production.mitsuba import MitsubaPrincipled, MitsubaRoughPlastic

mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is a test dependency: pip install mitsuba")

#: Mitsuba's rgb variants compute in single precision
REL = 2e-5


def plastic(alpha=0.2, ior=1.5, rho=(0.2, 0.5, 0.8), tau=None) -> Stack:
    layers = [Interface(alpha, (ior,) * 3)]
    if tau is not None:
        layers.append(Medium(tau))
    return Stack("p", (*layers, Lambertian(rho)), "plastic")


def coated_metal(alpha0=0.05, alpha1=0.3, ior=1.5, n=(0.2, 0.5, 1.0), k=(3.0, 2.5, 2.0)) -> Stack:
    return Stack("m", (Interface(alpha0, (ior,) * 3), Interface(alpha1, n, k)), "metal")


def directions(n: int, seed: int) -> np.ndarray:
    v = np.random.default_rng(seed).normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2]) + 0.05
    return v / np.linalg.norm(v, axis=1)[:, None]


LIGHTS = directions(6, 1)
VIEWS = directions(40, 2)


def schlick(f0, c):
    return f0 + (1.0 - f0) * (1.0 - c) ** 5


def g1(w, alpha):
    return 1.0 / (1.0 + optics.ggx_lambda(*w, alpha, alpha))


def test_registered_and_cited():
    names = registry.all_models()
    assert isinstance(names["mitsuba-roughplastic"], MitsubaRoughPlastic)
    assert isinstance(names["mitsuba-principled"], MitsubaPrincipled)
    assert "roughplastic.cpp" in MitsubaRoughPlastic.__doc__ and "principled.cpp" in MitsubaPrincipled.__doc__
    assert pm.mitsuba_variant() in (pm.VECTORISED, pm.SCALAR)


def test_without_mitsuba_both_refuse(monkeypatch):
    monkeypatch.setattr(pm, "mitsuba_module", lambda: None)
    pm.vectorised_variant_works.cache_clear()
    try:
        assert MitsubaRoughPlastic().reason(plastic()) == "mitsuba not installed"
        assert MitsubaPrincipled().reason(coated_metal()) == "mitsuba not installed"
    finally:
        pm.vectorised_variant_works.cache_clear()


def test_refusals():
    rp, pr = MitsubaRoughPlastic(), MitsubaPrincipled()
    assert rp.reason(plastic()) is None and rp.reason(plastic(tau=(0.0, 0.0, 0.0))) is None
    assert "no coat absorption" in rp.reason(plastic(tau=(0.1, 0.1, 0.1)))
    assert "Lambertian base only" in rp.reason(coated_metal())
    assert "rough coat only" in rp.reason(plastic(alpha=0.0))
    dispersive = Stack("p", (Interface(0.2, (1.5, 1.5, 1.52)), Lambertian((0.5,) * 3)), "plastic")
    assert "one coat index" in rp.reason(dispersive)
    bare = Stack("b", (Lambertian((0.5,) * 3),), "plastic")
    assert "exactly [dielectric coat" in rp.reason(bare)
    assert pr.reason(coated_metal()) is None and pr.reason(plastic(alpha=0.05)) is None
    assert "coat index 1.5 only" in pr.reason(coated_metal(ior=1.45))
    assert "coat roughness in [0.001, 0.1]" in pr.reason(coated_metal(alpha0=0.2))
    assert "no coat absorption" in pr.reason(plastic(alpha=0.05, tau=(0.2, 0.0, 0.0)))
    assert "base roughness >= 0.001" in pr.reason(coated_metal(alpha1=0.0))
    slab = Stack("s", (Interface(0.05, (1.5,) * 3), Interface(0.1, (1.2,) * 3)), "slab")
    assert "conductor or Lambertian base only" in pr.reason(slab)
    with pytest.raises(ValueError, match="base_color"):
        MitsubaPrincipled(base_color="metal")


def test_roughplastic_without_diffuse_is_ggx_dielectric_reflection():
    """diffuse_reflectance = 0 leaves Mitsuba's GGX specular lobe: optics' Walter 2007 reflection
    (separable Smith masking), without cosine -- a wrong cosine conversion fails this."""
    st = plastic(alpha=0.3, rho=(0.0, 0.0, 0.0))
    m = MitsubaRoughPlastic()
    for l in LIGHTS:
        got = m.evaluate(st, l, VIEWS)
        want = optics.np_microfacet_reflection(*l, VIEWS[:, 0], VIEWS[:, 1], VIEWS[:, 2], 0.3, 0.3, 1.5, 0.0, False)
        assert got.top[:, 1] == pytest.approx(want, rel=REL, abs=1e-7)
        assert np.all(got.internal == 0.0)


def test_cosine_conversion():
    """The models return Mitsuba's eval (value x cos(theta_o)) divided by v_z: checked against a raw
    eval, and through reciprocity of roughplastic's diffuse term, which is symmetric only without
    the cosine."""
    st = plastic()
    m = MitsubaRoughPlastic()
    (bsdf,) = m.bsdfs(st)
    t = getattr(mi, bsdf.variant)
    l, v = LIGHTS[0], VIEWS[0]
    si = t.SurfaceInteraction3f()
    si.wi = t.Vector3f(*l)
    raw = np.array(bsdf.bsdf.eval(mi.BSDFContext(mi.TransportMode.Importance), si, t.Vector3f(*v)))
    got = m.evaluate(st, l, v[None]).total[0]
    assert got * v[2] == pytest.approx(raw, rel=1e-6)
    for a, b in zip(LIGHTS, VIEWS[:6]):
        ab = m.evaluate(st, a, b[None]).internal[0]
        ba = m.evaluate(st, b, a[None]).internal[0]
        assert ab == pytest.approx(ba, rel=1e-5)
    assert np.all(m.evaluate(st, l, np.array([[0.0, 0.6, -0.8]])).total == 0.0)


def test_roughplastic_diffuse_series():
    """nonlinear: diffuse term ~ rho / (1 - rho F_dr); linear (Mitsuba's default): rho / (1 - F_dr):
    linear in rho, and one F_dr explains both (hand-solved from the ratios)."""
    l, v = LIGHTS[2], VIEWS[:5]
    lin = MitsubaRoughPlastic(nonlinear=False)
    non = MitsubaRoughPlastic(nonlinear=True)
    rho = (0.2, 0.5, 0.8)
    a = lin.evaluate(plastic(rho=rho), l, v).internal
    assert a[:, 2] / a[:, 0] == pytest.approx(np.full(5, 4.0), rel=REL)
    b = non.evaluate(plastic(rho=rho), l, v).internal
    # b / a = (1 - F) / (1 - rho F) per channel: F from the rho = 0.2 channel predicts the others
    r = b[0, 0] / a[0, 0]
    f_dr = (1.0 - r) / (1.0 - 0.2 * r)
    assert 0.3 < f_dr < 0.8
    for c in (1, 2):
        assert b[:, c] / a[:, c] == pytest.approx(np.full(5, (1 - f_dr) / (1 - rho[c] * f_dr)), rel=1e-4)


def test_principled_clearcoat_is_mitsubas_definition():
    """top = clearcoat / 4 * Schlick(0.04, l.h) * D_GTR1(h; alpha0) * G1(l; 0.25) G1(v; 0.25): the lobe as
    principled.cpp writes it (value x |cos_o| there, no 1 / (4 cos_l cos_v)), with
    clearcoat_gloss chosen so that lerp(0.1, 0.001, gloss) = alpha0."""
    m = MitsubaPrincipled()
    for alpha0 in (0.001, 0.03, 0.1):
        st = coated_metal(alpha0=alpha0)
        assert 0.1 + (0.001 - 0.1) * m.clearcoat_gloss(alpha0) == pytest.approx(alpha0, abs=1e-15)
        a2 = alpha0 * alpha0
        for l in LIGHTS[:3]:
            got = m.evaluate(st, l, VIEWS).top
            for v, g in zip(VIEWS, got):
                h = (l + v) / np.linalg.norm(l + v)
                d = (a2 - 1.0) / (math.pi * math.log(a2) * (1.0 + (a2 - 1.0) * h[2] ** 2))
                want = 0.25 * schlick(0.04, float(l @ h)) * d * g1(l, 0.25) * g1(v, 0.25)
                assert g == pytest.approx(np.full(3, want), rel=1e-4, abs=2e-6 * max(1.0, d))


@pytest.mark.parametrize("base_color", ["coat", "air"])
def test_principled_metallic_base(base_color):
    """internal = Schlick(F0, l.h) D(h) G1(l) G1(v) / (4 l_z v_z) with GGX alpha = roughness^2 = alpha1
    and F0 the conductor's normal-incidence reflectance relative to the coat (or air)."""
    n, k = (0.2, 0.5, 1.0), (3.0, 2.5, 2.0)
    st = coated_metal(alpha1=0.3, n=n, k=k)
    outside = 1.5 if base_color == "coat" else 1.0
    f0 = np.array([optics.fresnel_conductor(1.0, a / outside, b / outside) for a, b in zip(n, k)])
    got = MitsubaPrincipled(base_color=base_color).evaluate(st, LIGHTS[1], VIEWS).internal
    l = LIGHTS[1]
    for v, g in zip(VIEWS, got):
        h = (l + v) / np.linalg.norm(l + v)
        spec = optics.ggx_d(*h, 0.3, 0.3) * g1(l, 0.3) * g1(v, 0.3) / (4.0 * l[2] * v[2])
        assert g == pytest.approx(schlick(f0, float(l @ h)) * spec, rel=1e-4, abs=1e-6)


def test_principled_diffuse_base():
    """metallic 0, specular 0, roughness 0: internal = rho / pi (1 - F_l / 2)(1 - F_v / 2), F = (1 - cos)^5."""
    rho = np.array([0.2, 0.5, 0.8])
    st = plastic(alpha=0.05, rho=tuple(rho))
    for l in LIGHTS[:3]:
        got = MitsubaPrincipled().evaluate(st, l, VIEWS).internal
        want = rho[None] / math.pi * ((1 - 0.5 * (1 - l[2]) ** 5) * (1 - 0.5 * (1 - VIEWS[:, 2]) ** 5))[:, None]
        assert got == pytest.approx(want, rel=REL)


def test_vectorised_variant_agrees_with_scalar():
    if not pm.vectorised_variant_works():
        pytest.skip("llvm_ad_rgb does not evaluate on this machine (the models use scalar_rgb)")
    spec = MitsubaRoughPlastic().specs(plastic())[0]
    a = pm.MitsubaBSDF(spec, pm.VECTORISED).eval(LIGHTS[0], VIEWS)
    b = pm.MitsubaBSDF(spec, pm.SCALAR).eval(LIGHTS[0], VIEWS)
    assert a == pytest.approx(b, rel=1e-5)
