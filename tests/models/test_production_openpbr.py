"""openpbr-coat and OpenPBR's coat formulas (models.production), against the MaterialX node graph
of OpenPBR Surface (loaded with the MaterialX API), hand-computed values and the limits the
specification states -- never against the goniometer."""

from __future__ import annotations

import math

import numpy as np
import pytest

import goniometer as g
from models.base import ModelError
from models.production import (OpenPBRCoat, OpenPBRParameters, coat_darkening, coat_internal_reflection,
                               coat_roughening, evaluate_openpbr, openpbr_parameters)
from models.production.fresnel import F82_MU, f82_tint, f82_tint_from_ior
from models.production.openpbr_coat import BASE_INPUTS, COAT_INPUTS
from models.registry import all_models
from models.tables import FGD_ERROR
from tests.models.helpers import direction, fresnel_conductor_tb, fresnel_dielectric_tb, polar
from tests.models.production_helpers import (OPENPBR, GraphEvaluator, ggx_brdf_hc_tb, hemisphere_rule,
                                             input_names, load)


def stack(*layers, category="metal"):
    return g.stack_from_dict({"name": "t", "category": category, "layers": list(layers)})


COAT = {"type": "interface", "roughness": 0.09, "ior": 1.5}
MEDIUM = {"type": "medium", "optical_depth": [0.1, 0.2, 0.5]}
METAL = {"type": "interface", "roughness": 0.16, "ior": [1.9, 1.45, 1.2], "extinction": [1.0, 0.01, 2.0]}
LAMBERT = {"type": "lambertian", "albedo": [0.2, 0.5, 0.8]}
L = direction(math.radians(35.0), 0.3)
VIEWS = np.array([direction(math.radians(t), p) for t in (0.0, 20.0, 45.0, 70.0, 85.0) for p in (0.0, 2.0, 3.5)])


# --------------------------------------------------------------------------- the node graph

def test_mapping_names_every_coat_input_of_the_node_graph():
    nodedef, _ = load(OPENPBR)
    names = input_names(nodedef)
    assert {n for n in names if "coat" in n} == set(COAT_INPUTS)
    assert set(BASE_INPUTS) <= set(names), set(BASE_INPUTS) - set(names)
    assert set(OpenPBRParameters.__dataclass_fields__) <= set(names)


@pytest.mark.parametrize("values", [
    dict(coat_ior=1.5, base_color=(0.2, 0.5, 0.9), base_metalness=1.0, specular_weight=1.0, coat_weight=1.0),
    dict(coat_ior=1.7, base_color=(0.2, 0.5, 0.9), base_metalness=1.0, specular_weight=0.8, coat_weight=0.7,
         coat_darkening=0.6),
    dict(coat_ior=2.4, base_color=(0.0, 0.3, 1.0), base_metalness=0.0, coat_weight=1.0),
    dict(coat_ior=1.0, base_color=(0.4, 0.4, 0.4), base_metalness=1.0, coat_weight=1.0),
])
def test_darkening_is_the_node_graphs(values):
    """coat_darkening reproduces the graph's modulated_base_darkening node."""
    nodedef, graph = load(OPENPBR)
    ev = GraphEvaluator(nodedef, graph, values)
    color = np.asarray(values["base_color"])
    e_base = color * values.get("specular_weight", 1.0) if values["base_metalness"] == 1.0 else color
    ours = coat_darkening(values["coat_ior"], e_base, values["coat_weight"], values.get("coat_darkening", 1.0))
    np.testing.assert_allclose(ev.node("modulated_base_darkening"), ours, rtol=1e-12)


@pytest.mark.parametrize("rb, rc, w", [(0.3, 0.0, 1.0), (0.3, 0.6, 1.0), (0.1, 0.9, 1.0), (0.5, 0.5, 0.4), (0.9, 0.9, 1.0)])
def test_roughening_is_the_node_graphs(rb, rc, w):
    nodedef, graph = load(OPENPBR)
    ev = GraphEvaluator(nodedef, graph, dict(specular_roughness=rb, coat_roughness=rc, coat_weight=w))
    np.testing.assert_allclose(ev.node("effective_specular_roughness"), coat_roughening(rb, rc, w), rtol=1e-12)


# --------------------------------------------------------------------------- formulas by hand

def test_darkening_by_hand_and_limits():
    # n = 1.5: F0 = 0.04, K = 1 - 0.96 / 2.25 = 0.57333..., Delta(E = 0.5) = (1 - K) / (1 - K / 2)
    k = 1.0 - 0.96 / 2.25
    assert coat_internal_reflection(1.5) == pytest.approx(k, rel=1e-14)
    assert coat_darkening(1.5, 0.5) == pytest.approx((1 - k) / (1 - 0.5 * k), rel=1e-14)
    assert coat_darkening(1.5, 0.0) == pytest.approx(1 - k, rel=1e-14)
    assert coat_darkening(1.5, 1.0) == pytest.approx(1.0, rel=1e-14)  # white base: no energy lost
    assert coat_darkening(1.0, 0.3) == pytest.approx(1.0, rel=1e-14)  # index-matched coat: K = 0
    assert coat_darkening(1.8, 0.3, coat_weight=0.0) == 1.0
    assert coat_darkening(1.8, 0.3, darkening=0.0) == 1.0
    # the modulation is linear in coat_weight * coat_darkening
    d = coat_darkening(1.8, 0.3)
    assert coat_darkening(1.8, 0.3, 0.5, 0.5) == pytest.approx(1 + 0.25 * (d - 1), rel=1e-14)


def test_roughening_by_hand_and_limits():
    assert coat_roughening(0.3, 0.0) == pytest.approx(0.3, rel=1e-14)
    assert coat_roughening(0.3, 0.6, coat_weight=0.0) == pytest.approx(0.3, rel=1e-14)
    assert coat_roughening(0.3, 0.6) == pytest.approx((0.3 ** 4 + 2 * 0.6 ** 4) ** 0.25, rel=1e-14)
    assert coat_roughening(0.9, 0.9) == 1.0  # clamped at 1
    # in alphas: alpha'^2 = alpha_b^2 + 2 alpha_c^2
    ab, ac = 0.09, 0.16
    assert coat_roughening(math.sqrt(ab), math.sqrt(ac)) ** 2 == pytest.approx(math.sqrt(ab ** 2 + 2 * ac ** 2), rel=1e-12)


def test_f82_tint_matches_the_conductor_at_normal_incidence_and_82_degrees():
    eta, kappa = np.array([1.9, 1.45, 0.2]), np.array([1.0, 0.01, 3.0])
    f0, tint = f82_tint_from_ior(eta, kappa)
    for c in range(3):
        assert f0[c] == pytest.approx(fresnel_conductor_tb(0.0, eta[c], kappa[c]), rel=1e-12)
        assert f82_tint(1.0, f0[c], tint[c]) == pytest.approx(f0[c], rel=1e-12)
        assert f82_tint(F82_MU, f0[c], tint[c]) == pytest.approx(
            fresnel_conductor_tb(math.acos(F82_MU), eta[c], kappa[c]), rel=1e-12)
        # tint 1 is the Schlick curve
        assert f82_tint(0.3, f0[c], 1.0) == pytest.approx(f0[c] + (1 - f0[c]) * 0.7 ** 5, rel=1e-14)


# --------------------------------------------------------------------------- the model's limits

def f82_metal_tb(l, v, alpha, f0, tint):
    """Bare F82-tint GGX metal, per channel, in angle form."""
    return np.array([ggx_brdf_hc_tb(l, v, alpha, lambda t: f0[c] + (1 - f0[c]) * (1 - math.cos(t)) ** 5
                                    - math.cos(t) * (1 - math.cos(t)) ** 6 / (F82_MU * (1 - F82_MU) ** 6)
                                    * (1 - tint[c]) * (f0[c] + (1 - f0[c]) * (1 - F82_MU) ** 5))
                     for c in range(3)])


def test_coat_weight_zero_is_the_bare_base():
    metal = OpenPBRParameters(coat_weight=0.0, coat_roughness=0.7, coat_ior=1.8, coat_color=(0.2, 0.3, 0.4),
                              base_metalness=1.0, base_color=(0.9, 0.6, 0.3), specular_color=(0.8, 0.9, 1.0),
                              specular_roughness=0.5)
    r = evaluate_openpbr(metal, L, VIEWS)
    np.testing.assert_array_equal(r.top, 0.0)
    for k, v in enumerate(VIEWS):
        np.testing.assert_allclose(r.internal[k], f82_metal_tb(L, v, 0.25, metal.base_color, metal.specular_color),
                                   rtol=1e-9)
    diffuse = OpenPBRParameters(coat_weight=0.0, coat_roughness=0.7, coat_ior=1.8, base_color=(0.2, 0.5, 0.8),
                                specular_weight=0.0)
    r = evaluate_openpbr(diffuse, L, VIEWS)
    np.testing.assert_allclose(r.total, np.broadcast_to(np.array([0.2, 0.5, 0.8]) / math.pi, r.total.shape), rtol=1e-14)


def test_index_matched_coat_leaves_absorption_and_roughening():
    """coat_ior = 1: no coat lobe, E_coat = 0, K = 0 (no darkening), straight paths; only the
    absorption exp(-tau (1/mu_l + 1/mu_v)) and the (index-blind) roughening remain."""
    tau = np.array([0.1, 0.2, 0.5])
    p = OpenPBRParameters(coat_ior=1.0, coat_roughness=0.4, coat_color=tuple(np.exp(-2 * tau)), base_metalness=1.0,
                          base_color=(0.9, 0.6, 0.3), specular_color=(0.8, 0.9, 1.0), specular_roughness=0.5)
    r = evaluate_openpbr(p, L, VIEWS)
    np.testing.assert_array_equal(r.top, 0.0)
    alpha = math.sqrt(0.25 ** 2 + 2 * 0.16 ** 2)
    for k, v in enumerate(VIEWS):
        a = np.exp(-tau * (1 / L[2] + 1 / v[2]))
        np.testing.assert_allclose(r.internal[k], a * f82_metal_tb(L, v, alpha, p.base_color, p.specular_color),
                                   rtol=1e-9)


def test_smooth_coat_on_lambertian_by_hand():
    """Smooth coat (E_coat = F(mu_v), the alpha = 0 column of the table), n = 1.5, rho = 0.5, tau:
    internal = exp(-tau (1/mu_l' + 1/mu_v')) (1 - F(theta_v)) Delta rho / pi, up to the table's
    stated error on E_coat (it interpolates F between its mu nodes)."""
    tau = np.array([0.0, 0.3, 1.0])
    p = OpenPBRParameters(coat_ior=1.5, coat_roughness=0.0, coat_color=tuple(np.exp(-2 * tau)),
                          base_color=(0.5, 0.5, 0.5), specular_weight=0.0)
    k = 1.0 - 0.96 / 2.25
    delta = (1 - k) / (1 - 0.5 * k)
    r = evaluate_openpbr(p, L, VIEWS)
    np.testing.assert_array_equal(r.top, 0.0)
    for i, v in enumerate(VIEWS):
        mul = math.cos(math.asin(math.sin(polar(L)) / 1.5))
        muv = math.cos(math.asin(math.sin(polar(v)) / 1.5))
        rest = np.exp(-tau * (1 / mul + 1 / muv)) * delta * 0.5 / math.pi
        expect = (1 - fresnel_dielectric_tb(polar(v), 1.5)) * rest
        np.testing.assert_allclose(r.internal[i], expect, rtol=1e-12, atol=FGD_ERROR * float(rest.max()))
        if polar(v) == 0.0:  # a table node: exact
            np.testing.assert_allclose(r.internal[i], expect, rtol=1e-9)


@pytest.mark.parametrize("mu_v", [0.95, 0.6, 0.2])
def test_white_furnace_of_a_white_diffuse_base(mu_v):
    """The spec's layering statement: with E_sub = 1 (white Lambertian, clear coat: Delta = 1) the
    albedo E(v) = Int f(l, v) cos dl is 1, whatever the coat. Tolerance: the stated error of the
    E_coat table (the quadrature's own error is far below it)."""
    p = OpenPBRParameters(coat_roughness=0.5, coat_ior=1.5, base_color=(1.0, 1.0, 1.0), specular_weight=0.0)
    d, w = hemisphere_rule(96, 192)
    v = np.array([math.sqrt(1 - mu_v ** 2), 0.0, mu_v])
    r = evaluate_openpbr(p, d, v)
    albedo = (w[:, None] * r.total).sum(axis=0)
    np.testing.assert_allclose(albedo, 1.0, atol=FGD_ERROR)
    assert (w * r.top[:, 0]).sum() > 0.03  # the coat lobe carries part of it


def test_darkened_lambertian_albedo_has_the_interfaced_lambertian_form():
    """Clear coat over a Lambertian rho: internal albedo = (1 - E_coat(v)) Delta(rho) rho (spec,
    'interfaced Lambertian' form), exactly, since the base lobe is constant in l."""
    rho = np.array([0.1, 0.5, 0.9])
    p = OpenPBRParameters(coat_roughness=0.5, coat_ior=1.6, base_color=tuple(rho), specular_weight=0.0)
    d, w = hemisphere_rule(24, 48)
    v = direction(math.radians(50.0), 1.0)
    r = evaluate_openpbr(p, d, v)
    white = evaluate_openpbr(OpenPBRParameters(coat_roughness=0.5, coat_ior=1.6, base_color=(1, 1, 1),
                                               specular_weight=0.0), d, v)
    one_minus_e = (w * white.internal[:, 0]).sum()  # (1 - E_coat(v)) Delta(1) with Delta(1) = 1
    np.testing.assert_allclose((w[:, None] * r.internal).sum(axis=0), one_minus_e * coat_darkening(1.6, rho) * rho,
                               rtol=1e-12)


# --------------------------------------------------------------------------- the registered model

def test_model_maps_our_stack_and_evaluates_it():
    s = stack(COAT, MEDIUM, METAL)
    p = openpbr_parameters(s)
    np.testing.assert_allclose(p.coat_color, np.exp(-2 * np.array([0.1, 0.2, 0.5])), rtol=1e-15)
    assert p.coat_roughness == pytest.approx(0.3) and p.coat_ior == 1.5 and p.coat_weight == 1.0
    assert p.specular_roughness == pytest.approx(0.4) and p.base_metalness == 1.0
    np.testing.assert_allclose(p.base_color, [fresnel_conductor_tb(0.0, n, k) for n, k in
                                              zip(METAL["ior"], METAL["extinction"])], rtol=1e-12)
    model = all_models()["openpbr-coat"]
    assert isinstance(model, OpenPBRCoat) and model.sides == ("brdf",) and not model.anisotropic
    got = model.evaluate(s, L, VIEWS)
    want = evaluate_openpbr(p, L, VIEWS)
    np.testing.assert_array_equal(got.top, want.top)
    np.testing.assert_array_equal(got.internal, want.internal)
    assert np.all(got.internal > 0) and np.all(np.isfinite(got.total))
    lam = openpbr_parameters(stack(COAT, LAMBERT, category="plastic"))
    assert lam.base_metalness == 0.0 and lam.specular_weight == 0.0 and lam.base_color == (0.2, 0.5, 0.8)


@pytest.mark.parametrize("layers, words", [
    ([METAL], "dielectric coat on top"),
    ([COAT], "missing coat"),
    ([COAT, COAT, LAMBERT], "one coat only"),
    ([COAT, {"type": "interface", "roughness": 0.1, "ior": 1.3}], "dielectric base"),
    ([COAT, {"type": "medium", "optical_depth": [1, 1, 1], "scattering_albedo": [0.5, 0.5, 0.5]}, LAMBERT],
     "scattering medium"),
    ([{"type": "interface", "roughness": [0.1, 0.3], "ior": 1.5}, LAMBERT], "isotropic"),
])
def test_model_refuses_what_it_cannot_represent(layers, words):
    model = OpenPBRCoat()
    s = stack(*layers, category="other")
    reason = model.reason(s)
    assert reason is not None and words in reason, reason
    with pytest.raises(ModelError, match="openpbr-coat"):
        model.evaluate(s, L, VIEWS)


def test_parameters_it_cannot_evaluate_are_refused():
    with pytest.raises(ModelError, match="anisotropic"):
        evaluate_openpbr(OpenPBRParameters(coat_roughness_anisotropy=0.5), L, VIEWS)
    with pytest.raises(ModelError, match="base_metalness"):
        evaluate_openpbr(OpenPBRParameters(base_metalness=0.5), L, VIEWS)
    with pytest.raises(ModelError, match="specular_weight"):
        evaluate_openpbr(OpenPBRParameters(base_metalness=0.0, specular_weight=1.0), L, VIEWS)


def test_specification_darkening_and_the_corrected_numerator_by_hand():
    from goniometer.optics import np_fresnel_dielectric
    from models.production.openpbr import coat_darkening_spec
    from models.tables.microfacet_albedo import fresnel_average
    n, e, mu = 1.5, 0.6, 0.7
    g = (1.0 - fresnel_average(n)) / n ** 2          # the escaping fraction, 1 - K_r
    f = float(np_fresnel_dielectric(mu, n))           # K_s
    # a rough base (r_b = 1): K = K_r, both forms the interfaced-Lambertian series
    for corrected in (False, True):
        np.testing.assert_allclose(coat_darkening_spec(n, e, 1.0, mu, corrected), g / (1 - e * (1 - g)), rtol=1e-12)
    # a smooth base (r_b = 0): K = K_s = F(mu); the specification's numerator is 1 - F, the corrected 1 - K_r
    np.testing.assert_allclose(coat_darkening_spec(n, e, 0.0, mu), (1 - f) / (1 - e * f), rtol=1e-12)
    np.testing.assert_allclose(coat_darkening_spec(n, e, 0.0, mu, True), g / (1 - e * f), rtol=1e-12)
    # a white base: the specification's factor is 1 for every K, the corrected one is not
    np.testing.assert_allclose(coat_darkening_spec(n, 1.0, 0.3, mu), 1.0, rtol=1e-12)
    assert abs(coat_darkening_spec(n, 1.0, 0.3, mu, True) - 1.0) > 0.05
    # an index-matched coat is absent
    np.testing.assert_allclose(coat_darkening_spec(1.0, e, 0.3, mu, True), 1.0, rtol=1e-12)


def test_pr261_roughening_by_hand():
    from models.production.openpbr import coat_roughening_pr261
    rb, rc, n = 0.4, 0.5, 1.5
    b = 1.05 * (n - 1) * np.sqrt(1 + n * n) / n
    raw = np.hypot(n * rb ** 2, b * rc ** 2)
    np.testing.assert_allclose(coat_roughening_pr261(rb, rc, n), np.sqrt(0.85 * np.tanh(raw / 0.85)), rtol=1e-12)
    # an index-matched coat leaves alpha_b, up to the cap 0.85 tanh(alpha / 0.85)
    np.testing.assert_allclose(coat_roughening_pr261(0.3, 0.9, 1.0), np.sqrt(0.85 * np.tanh(0.09 / 0.85)), rtol=1e-12)
    np.testing.assert_allclose(coat_roughening_pr261(rb, rc, n, coat_weight=0.0), rb)
    assert coat_roughening_pr261(1.0, 1.0, 2.0) ** 2 < 0.85


def test_standard_surface_coat_affected_roughness_and_color():
    from models.production.standard_surface import coat_affected_color, coat_affected_roughness
    np.testing.assert_allclose(coat_affected_color(np.array([0.5, 0.2])), [0.25, 0.04])
    np.testing.assert_allclose(coat_affected_color(np.array([0.5]), coat=0.5, coat_affect_color=0.5), [0.5 ** 1.25])
    assert coat_affected_roughness(0.3, 0.5) == pytest.approx(0.3 + 0.5 * 0.7)
    assert coat_affected_roughness(0.3, 0.5, coat_affect_roughness=0.0) == 0.3
    assert coat_affected_roughness(0.3, 1.0) == pytest.approx(1.0)
