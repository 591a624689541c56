"""standard-surface-coat (models.production.standard_surface), against the MaterialX node graph of
Autodesk Standard Surface (loaded with the MaterialX API), hand-computed values and the limits of
its own definition -- never against the goniometer."""

from __future__ import annotations

import math

import numpy as np
import pytest

import goniometer as g
from models.base import ModelError
from models.production import (StandardSurfaceCoat, StandardSurfaceParameters, evaluate_standard_surface,
                               standard_surface_parameters)
from models.production.fresnel import artistic_from_ior, artistic_ior
from models.production.standard_surface import BASE_INPUTS, COAT_INPUTS, standard_surface_layering
from models.registry import all_models
from models.tables import FGD_ERROR
from tests.models.helpers import direction, fresnel_conductor_tb, fresnel_dielectric_tb, polar
from tests.models.production_helpers import (STANDARD_SURFACE, GraphEvaluator, ggx_brdf_hc_tb, hemisphere_rule,
                                             input_names, load)


def stack(*layers, category="metal"):
    return g.stack_from_dict({"name": "t", "category": category, "layers": list(layers)})


COAT = {"type": "interface", "roughness": 0.09, "ior": 1.5}
MEDIUM = {"type": "medium", "optical_depth": [0.1, 0.2, 0.5]}
METAL = {"type": "interface", "roughness": 0.16, "ior": [1.9, 1.45, 1.2], "extinction": [1.0, 0.01, 2.0]}
LAMBERT = {"type": "lambertian", "albedo": [0.2, 0.5, 0.8]}
L = direction(math.radians(35.0), 0.3)
VIEWS = np.array([direction(math.radians(t), p) for t in (0.0, 20.0, 45.0, 70.0, 85.0) for p in (0.0, 2.0, 3.5)])


def conductor_tb(l, v, alpha, eta, kappa):
    return np.array([ggx_brdf_hc_tb(l, v, alpha, lambda t: fresnel_conductor_tb(t, eta[c], kappa[c])) for c in range(3)])


# --------------------------------------------------------------------------- the node graph

def test_mapping_names_every_coat_input_of_the_node_graph():
    nodedef, _ = load(STANDARD_SURFACE)
    names = input_names(nodedef)
    assert {n for n in names if "coat" in n} == set(COAT_INPUTS)
    assert set(BASE_INPUTS) <= set(names), set(BASE_INPUTS) - set(names)
    assert set(StandardSurfaceParameters.__dataclass_fields__) <= set(names)


@pytest.mark.parametrize("values", [
    dict(specular_roughness=0.3, coat=1.0, coat_roughness=0.5, coat_affect_roughness=0.0),
    dict(specular_roughness=0.3, coat=0.8, coat_roughness=0.5, coat_affect_roughness=0.7),
    dict(specular_roughness=0.1, coat=1.0, coat_roughness=1.0, coat_affect_roughness=1.0),
])
def test_base_roughness_and_coat_attenuation_are_the_node_graphs(values):
    nodedef, graph = load(STANDARD_SURFACE)
    ev = GraphEvaluator(nodedef, graph, dict(values, coat_color=(0.2, 0.5, 0.9)))
    p = StandardSurfaceParameters(metalness=1.0, base_color=(0.5, 0.5, 0.5), **values)
    lay = standard_surface_layering(p)
    np.testing.assert_allclose(ev.node("coat_affected_roughness") ** 2, lay.base_alpha, rtol=1e-12)
    np.testing.assert_allclose(ev.node("coat_attenuation"), 1 + values["coat"] * (np.array([0.2, 0.5, 0.9]) - 1),
                               rtol=1e-12)


def test_artistic_ior_round_trip():
    """Our conductor -> (reflectivity, edge colour) -> Gulbrandsen's map gives (eta, kappa) back."""
    eta, kappa = np.array([1.9, 1.45, 0.2, 1.2]), np.array([1.0, 0.01, 3.0, 2.0])
    r, gc = artistic_from_ior(eta, kappa)
    for c in range(4):
        assert r[c] == pytest.approx(fresnel_conductor_tb(0.0, eta[c], kappa[c]), rel=1e-12)
    n, k = artistic_ior(r, gc)
    np.testing.assert_allclose(n, eta, rtol=1e-10)
    np.testing.assert_allclose(k, kappa, rtol=1e-8)
    # edge colour 0 is the dielectric of the same reflectivity, 1 the minimal index n_min
    n0, k0 = artistic_ior(0.04, 0.0)
    assert n0 == pytest.approx(1.5, rel=1e-12) and k0 == pytest.approx(0.0, abs=1e-6)


# --------------------------------------------------------------------------- the model's limits

def test_coat_zero_is_the_bare_base():
    eta, kappa = np.array([1.9, 1.45, 0.2]), np.array([1.0, 0.01, 3.0])
    r, gc = artistic_from_ior(eta, kappa)
    metal = StandardSurfaceParameters(coat=0.0, coat_roughness=0.7, coat_IOR=1.8, coat_color=(0.2, 0.3, 0.4),
                                      metalness=1.0, base_color=tuple(r), specular_color=tuple(gc),
                                      specular_roughness=0.5, coat_affect_roughness=1.0)
    got = evaluate_standard_surface(metal, L, VIEWS)
    np.testing.assert_array_equal(got.top, 0.0)
    for i, v in enumerate(VIEWS):
        np.testing.assert_allclose(got.internal[i], conductor_tb(L, v, 0.25, eta, kappa), rtol=1e-8)
    diffuse = StandardSurfaceParameters(coat=0.0, coat_roughness=0.7, base_color=(0.2, 0.5, 0.8), specular=0.0,
                                        coat_affect_color=1.0)
    got = evaluate_standard_surface(diffuse, L, VIEWS)
    np.testing.assert_allclose(got.total, np.broadcast_to(np.array([0.2, 0.5, 0.8]) / math.pi, got.total.shape),
                               rtol=1e-14)


def test_smooth_coat_on_metal_by_hand():
    """Smooth coat: internal = coat_color (1 - F(theta_v)) f_conductor(l, v), with the constant
    coat colour (no path length) and the base roughness untouched (coat_affect_roughness = 0)."""
    s = stack({"type": "interface", "roughness": 0.0, "ior": 1.5}, MEDIUM, METAL)
    p = standard_surface_parameters(s)
    got = StandardSurfaceCoat().evaluate(s, L, VIEWS)
    np.testing.assert_array_equal(got.top, 0.0)
    cc = np.exp(-2 * np.array([0.1, 0.2, 0.5]))
    np.testing.assert_allclose(p.coat_color, cc, rtol=1e-15)
    for i, v in enumerate(VIEWS):
        base = cc * conductor_tb(L, v, 0.16, np.array(METAL["ior"]), np.array(METAL["extinction"]))
        expect = (1 - fresnel_dielectric_tb(polar(v), 1.5)) * base
        np.testing.assert_allclose(got.internal[i], expect, rtol=1e-12, atol=FGD_ERROR * float(base.max()))


def test_coat_affect_color_by_hand():
    p = StandardSurfaceParameters(coat=0.5, coat_roughness=0.0, coat_IOR=1.0, base_color=(0.2, 0.5, 0.8), specular=0.0,
                                  coat_affect_color=1.0)
    got = evaluate_standard_surface(p, L, VIEWS)
    np.testing.assert_allclose(got.internal, np.broadcast_to(np.array([0.2, 0.5, 0.8]) ** 1.5 / math.pi,
                                                             got.internal.shape), rtol=1e-12)


@pytest.mark.parametrize("mu_v", [0.95, 0.6, 0.2])
def test_white_furnace_of_a_white_diffuse_base(mu_v):
    """Albedo scaling over a white Lambertian under a clear coat conserves energy: E(v) = 1
    (tolerance: the stated error of the E_coat table)."""
    p = StandardSurfaceParameters(coat_roughness=0.6, coat_IOR=1.7, base_color=(1.0, 1.0, 1.0), specular=0.0)
    d, w = hemisphere_rule(96, 192)
    v = np.array([math.sqrt(1 - mu_v ** 2), 0.0, mu_v])
    got = evaluate_standard_surface(p, d, v)
    np.testing.assert_allclose((w[:, None] * got.total).sum(axis=0), 1.0, atol=FGD_ERROR)


# --------------------------------------------------------------------------- the registered model

def test_model_maps_our_stack_and_evaluates_it():
    s = stack(COAT, MEDIUM, METAL)
    p = standard_surface_parameters(s)
    assert p.coat == 1.0 and p.coat_IOR == 1.5 and p.coat_roughness == pytest.approx(0.3)
    assert p.metalness == 1.0 and p.specular == 1.0 and p.specular_roughness == pytest.approx(0.4)
    model = all_models()["standard-surface-coat"]
    assert isinstance(model, StandardSurfaceCoat) and model.sides == ("brdf",) and not model.anisotropic
    got = model.evaluate(s, L, VIEWS)
    want = evaluate_standard_surface(p, L, VIEWS)
    np.testing.assert_array_equal(got.total, want.total)
    assert np.all(got.internal > 0) and np.all(np.isfinite(got.total))
    lam = standard_surface_parameters(stack(COAT, LAMBERT, category="plastic"))
    assert lam.metalness == 0.0 and lam.specular == 0.0 and lam.base_color == (0.2, 0.5, 0.8)


@pytest.mark.parametrize("layers, words", [
    ([METAL], "dielectric coat on top"),
    ([COAT], "missing coat"),
    ([COAT, COAT, LAMBERT], "one coat only"),
    ([COAT, {"type": "interface", "roughness": 0.1, "ior": 1.3}], "dielectric base"),
    ([COAT, {"type": "medium", "optical_depth": [1, 1, 1], "scattering_albedo": [0.5, 0.5, 0.5]}, LAMBERT],
     "scattering medium"),
    ([{"type": "interface", "roughness": [0.1, 0.3], "ior": 1.5}, LAMBERT], "isotropic"),
    ([COAT, {"type": "interface", "roughness": 0.1, "ior": 0.05, "extinction": 10.0}], "artistic_ior clamps"),
])
def test_model_refuses_what_it_cannot_represent(layers, words):
    model = StandardSurfaceCoat()
    s = stack(*layers, category="other")
    reason = model.reason(s)
    assert reason is not None and words in reason, reason
    with pytest.raises(ModelError, match="standard-surface-coat"):
        model.evaluate(s, L, VIEWS)


def test_parameters_it_cannot_evaluate_are_refused():
    with pytest.raises(ModelError, match="anisotropic"):
        evaluate_standard_surface(StandardSurfaceParameters(coat_anisotropy=0.5), L, VIEWS)
    with pytest.raises(ModelError, match="metalness"):
        evaluate_standard_surface(StandardSurfaceParameters(metalness=0.5), L, VIEWS)
    with pytest.raises(ModelError, match="specular 0"):
        evaluate_standard_surface(StandardSurfaceParameters(metalness=0.0, specular=1.0), L, VIEWS)
