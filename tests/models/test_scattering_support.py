"""Scattering media in the analytic models: Belcour's forward-scattering operator (the ``belcour-*``
models, g >= G_MIN) and one shared refusal, with a clear reason, everywhere else."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from goniometer.cli import main
from goniometer.stack import Interface, Lambertian, Medium, Stack
from models import registry
from models.base import ModelError, scattering_reason
from models.belcour import pack_stack
from models.belcour.adding import run_adding_doubling
from models.belcour.options import BelcourOptions
from models.belcour.packing import G_MIN, forward_scattering_variance
from models.belcour.covariance import roughness_to_variance, variance_to_roughness

#: Bati 2019 appendix E's medium (d = 2) over its rough conductor, under a smooth index-matched top
SCATTERING = Stack("appendix-e", (Interface(0.0, (1.0,) * 3), Medium((0.4, 0.4, 2.2), (0.5, 0.5, 1 / 1.1), 0.6),
                                  Interface(0.2, (1.5,) * 3, (3.0, 0.0, 0.0))), "metal")
#: the same with g = 0 (sigma_HG diverges): refused by every model
ISOTROPIC = Stack("appendix-e-g0", (Interface(0.0, (1.0,) * 3), Medium((0.4, 0.4, 2.2), (0.5, 0.5, 1 / 1.1), 0.0),
                                    Interface(0.2, (1.5,) * 3, (3.0, 0.0, 0.0))), "metal")
#: the same medium with the albedo only where tau = 0: it does not scatter
ABSORBING = Stack("absorbing", (Interface(0.1, (1.5,) * 3), Medium((0.4, 0.4, 0.0), (0.0, 0.0, 0.9), 0.6),
                                Lambertian((0.5,) * 3)), "plastic")

#: Belcour 2018's adding-doubling rows (belcour-iridescence is Belcour & Barla 2017: a single filmed
#: interface, refusing media like the other analytic models)
BELCOUR = [n for n in registry.all_models() if n.startswith("belcour") and n != "belcour-iridescence"]
#: pbrt-v4's layered BSDF rows walk through HG media of any g (tests/models/test_pbrt_layered.py)
PBRT = [n for n in registry.all_models() if n.startswith("pbrt-layered")]
OTHERS = [n for n in registry.all_models() if n not in BELCOUR and n not in PBRT]


def _sigma_hg(g: float) -> float:
    return ((1.0 - g) / g) ** 0.8 / (1.0 + g)


@pytest.mark.parametrize("name", OTHERS)
def test_every_other_analytic_model_refuses_a_scattering_medium(name):
    model = registry.all_models()[name]
    assert not model.scattering
    reason = model.reason(SCATTERING)
    assert reason == scattering_reason(SCATTERING)
    assert reason.startswith("purely absorbing media only (layers[1] is a scattering medium")
    with pytest.raises(ModelError, match="scattering medium"):
        model.evaluate(SCATTERING, [0.0, 0.0, 1.0], [[0.0, 0.0, 1.0]], model.sides[0])
    # a medium that does not scatter is not refused for scattering
    assert "scattering" not in (model.reason(ABSORBING) or "")


@pytest.mark.parametrize("name", PBRT)
def test_pbrt_rows_accept_scattering_media_of_any_g(name):
    model = registry.all_models()[name]
    assert model.scattering and PBRT
    for stack in (SCATTERING, ISOTROPIC, ABSORBING):
        assert model.reason(stack) is None


@pytest.mark.parametrize("name", BELCOUR)
def test_belcour_models_accept_g_at_least_g_min_and_refuse_below(name):
    model = registry.all_models()[name]
    assert model.scattering
    if name != "belcour-btdf":      # the BTDF refuses the conductor base, not the medium
        assert model.reason(SCATTERING) is None
    for g in (0.0, 0.05, -0.5, math.nextafter(G_MIN, 0.0)):
        stack = Stack("low-g", (SCATTERING.layers[0], Medium((0.4, 0.4, 2.2), (0.5, 0.5, 1 / 1.1), g),
                                SCATTERING.layers[2]), "metal")
        reason = model.reason(stack)
        assert reason is not None and f"needs g >= {G_MIN}" in reason and f"g = {g}" in reason
        with pytest.raises(ModelError, match="sigma_HG"):
            model.evaluate(stack, [0.0, 0.0, 1.0], [[0.0, 0.0, 1.0]], model.sides[0])
    with pytest.raises(ValueError, match="needs g >= "):
        pack_stack(ISOTROPIC)


def test_sigma_hg_values():
    # by hand: ((1 - g) / g)^0.8 / (1 + g)
    assert forward_scattering_variance(0.6) == pytest.approx(0.45186323799904105, rel=1e-14)
    assert forward_scattering_variance(0.9) == pytest.approx(0.09075120315294498, rel=1e-14)
    assert forward_scattering_variance(0.1) == pytest.approx(5.272314667995717, rel=1e-14)
    with pytest.raises(ValueError):
        forward_scattering_variance(0.0)


def _slab(tau, albedo, g):
    """A medium between two smooth index-matched interfaces: the stack transmits exactly the
    medium's operator (FGD = 0 at eta = 1, J = 1)."""
    return Stack("slab", (Interface(0.0, (1.0,) * 3), Medium(tau, albedo, g), Interface(0.0, (1.0,) * 3)), "slab")


@pytest.mark.parametrize("tau,albedo,g,cos", [
    ((0.4, 0.4, 2.2), (0.5, 0.5, 1 / 1.1), 0.6, 0.5),
    ((1.0, 0.2, 4.0), (0.3, 1.0, 0.8), 0.9, 1.0),
    ((0.1, 0.8, 0.05), (0.9, 0.1, 0.5), 0.3, 0.2),
])
def test_forward_scattering_operator_by_hand(tau, albedo, g, cos):
    r = run_adding_doubling(pack_stack(_slab(tau, albedo, g)), cos, BelcourOptions())
    for ch in range(3):
        # T = (1 + sigma_s d / cos) exp(-sigma_t d / cos), sigma_t d = tau, sigma_s d = albedo tau
        t = (1.0 + albedo[ch] * tau[ch] / cos) * math.exp(-tau[ch] / cos)
        assert r.T0N[ch] == pytest.approx(t, rel=1e-12, abs=0.0)
        assert r.R0N[ch] == 0.0
        assert r.cov_T0N[ch, 0] == pytest.approx(_sigma_hg(g), rel=1e-12)
    # one point with literal numbers: tau 0.4, albedo 0.5, cos 0.5 -> 1.4 exp(-0.8)
    if cos == 0.5:
        assert r.T0N[0] == pytest.approx(0.6290605497641102, rel=1e-12)


def test_round_trip_to_the_base_by_hand():
    """Lobe of the conductor base: energy T^2 FGD(c, a~) with the lookup roughness
    a~ = f^-1(sigma_HG + f(alpha)) (§4), variance 2 sigma_HG + f(alpha) (down and up)."""
    tau, albedo, g, c = (0.4, 0.4, 2.2), (0.5, 0.5, 1 / 1.1), 0.6, 0.7
    a_lookup = variance_to_roughness(_sigma_hg(g) + roughness_to_variance(0.2))
    bare = Stack("bare", (SCATTERING.layers[0], Interface(a_lookup, (1.5,) * 3, (3.0, 0.0, 0.0))), "metal")
    rb = run_adding_doubling(pack_stack(bare), c, BelcourOptions())
    r = run_adding_doubling(pack_stack(SCATTERING), c, BelcourOptions())
    for ch in range(3):
        t = (1.0 + albedo[ch] * tau[ch] / c) * math.exp(-tau[ch] / c)
        assert r.energy[1, ch] == pytest.approx(t * t * rb.energy[1, ch], rel=1e-12)
        assert r.covariance[1, ch, 0] == pytest.approx(2 * _sigma_hg(g) + roughness_to_variance(0.2), rel=1e-12)


def test_zero_albedo_is_the_absorbing_medium_bit_for_bit():
    tau = (0.4, 0.9, 2.2)
    stacks = [Stack("m", (Interface(0.1, (1.5,) * 3), Medium(tau, alb, g), Interface(0.2, (1.5,) * 3, (3.0, 0.0, 0.0))),
                    "metal") for alb, g in (((0.0,) * 3, 0.0), ((0.0,) * 3, 0.6), ((0.5, 0.5, 0.0), 0.6))]
    l = np.array([np.sin(0.6), 0.0, np.cos(0.6)])
    v = np.array([[np.sin(-0.5) * np.cos(p), np.sin(-0.5) * np.sin(p), np.cos(0.5)] for p in (0.0, 0.3, 2.0)])
    for name in ("belcour-fwd", "belcour-sym", "belcour-aniso"):
        model = registry.all_models()[name]
        ref, zero, partial = (model.evaluate(s, l, v) for s in stacks)
        assert np.array_equal(ref.total, zero.total)
        # a channel that does not scatter (blue here) keeps the absorbing operator's bits
        assert np.array_equal(ref.total[:, 2], partial.total[:, 2])
        assert not np.array_equal(ref.total[:, 0], partial.total[:, 0])
    for c in (1.0, 0.5, 0.1):
        a = run_adding_doubling(pack_stack(stacks[0]), c, BelcourOptions())
        b = run_adding_doubling(pack_stack(stacks[2]), c, BelcourOptions())
        assert np.array_equal(a.energy[:, 2], b.energy[:, 2])
        assert np.array_equal(a.covariance[:, 2], b.covariance[:, 2])


def test_gonio_models_says_who_supports_scattering(capsys):
    assert all(c.scattering for c in registry.fitted_models().values())
    assert main(["models", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert {n for n, m in d.items() if m["scattering"]} == set(registry.fitted_models()) | set(BELCOUR) | set(PBRT)
    assert main(["models"]) == 0
    out = capsys.readouterr().out
    for line in out.splitlines():
        name = line.split(" ")[0]
        if name in d:
            assert (" scatter " in line) == d[name]["scattering"], line
    assert f"g >= {G_MIN}" in out


def test_every_model_without_films_refuses_a_filmed_stack_with_the_shared_reason():
    """Thin films (docs/material-format.md 2.4): a model that does not model them says so, rather
    than evaluating the bare interface; the same stack without its film is not refused for it."""
    from goniometer.stack import Film
    filmed = Stack("filmed", (Interface(0.2, (1.5,) * 3, film=Film(300.0, (1.33,) * 3)), Lambertian((0.5,) * 3)),
                   "plastic", wavelengths_nm=(450.0, 550.0, 650.0))
    bare = Stack("bare", (Interface(0.2, (1.5,) * 3), Lambertian((0.5,) * 3)), "plastic")
    for name, model in registry.all_models().items():
        if model.films:
            continue
        assert model.reason(filmed) == "no thin films (layers[0] carries a film of 300 nm)", name
        assert model.reason(bare) is None or "film" not in model.reason(bare), name
