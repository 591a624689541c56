"""Belcour 2018's layered model (models/belcour/): limits, closed forms, symmetries, robustness.

The tables come from the default cache ($GONIOMETER_CACHE or ~/.cache/goniometer), built on first
use. Smooth-limit tolerances are derived, not guessed:

* alpha = 0: FGD(mu, 0) is the exact Fresnel reflectance at the table's mu nodes, so the lobe
  energies differ from the adding equations only by the linear interpolation of Fresnel between
  mu nodes. The test measures that interpolation error ``eps`` for every interface of the stack
  (on a fine mu grid) and allows ``4 sum(eps)`` (every energy is a rational function of the
  interface terms with partial derivatives below 2 in magnitude, times the two appearances of
  each interface, R and T).
* alpha = 0.001: in addition, FGD departs from Fresnel by the part of GGX's heavy tail that
  crosses a steep part of the Fresnel curve; the test adds ``4 |FGD(c, a~) - F(c)|`` for every
  interface at the cosine where the model looks it up.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from goniometer import optics
from goniometer.testing import smooth
from goniometer.stack import Interface, Lambertian, Medium, Stack
from models import belcour
from models.tables import belcour as tables
from models.base import ModelError
from models.belcour import (BelcourBati19, BelcourBTDF, BelcourForward, BelcourOptions, BelcourSymmetric,
                            roughness_to_variance, variance_to_roughness)

ALL_MODELS = (BelcourForward, BelcourSymmetric, BelcourBati19, BelcourBTDF)


def coat(alpha0, tau, base):
    return Stack("s", (Interface(alpha0, (1.5,) * 3), Medium(tau), base))


def metal(alpha0=0.2, tau=(0.2,) * 3, eta1=1.45, alpha1=0.2, kappa1=(1.0, 0.01, 0.01)):
    return coat(alpha0, tau, Interface(alpha1, (eta1,) * 3, kappa1))


def slab(alpha0=0.05, tau=(0.05, 0.1, 0.4), alpha1=0.2):
    return coat(alpha0, tau, Interface(alpha1, (1.0,) * 3))


def three_interfaces(a=0.0):
    return Stack("t", (Interface(a, (1.5,) * 3), Medium((0.1, 0.2, 0.3)), Interface(a, (1.2,) * 3),
                       Interface(a, (1.7,) * 3), Medium((0.1, 0.0, 0.0)), Interface(a, (1.0,) * 3)))


def hemisphere(n_theta=45, n_phi=90, lower=False, theta_max=89.9):
    th = np.radians(np.linspace(0.0, theta_max, n_theta))
    ph = np.linspace(0.0, 2 * np.pi, n_phi, endpoint=False)
    T, P = np.meshgrid(th, ph, indexing="ij")
    v = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], axis=-1)
    if lower:
        v[..., 2] *= -1
    return v


def light(theta_deg, phi_deg=0.0):
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


# -------------------------------------------------------------------------- mappings and options


def test_variance_mapping_round_trip_and_guards():
    for a in (0.0, 1e-4, 0.05, 0.2, 0.7, 0.99):
        assert variance_to_roughness(roughness_to_variance(a)) == pytest.approx(a, abs=1e-12)
    assert variance_to_roughness(-1.0) == 0.0 and variance_to_roughness(math.nan) == 0.0
    assert variance_to_roughness(math.inf) == 1.0
    assert math.isfinite(roughness_to_variance(1.0))


def test_options_are_validated():
    with pytest.raises(ValueError):
        BelcourForward(incident="sideways")
    with pytest.raises(ValueError):
        BelcourSymmetric(transmission_scale="other")
    with pytest.raises(ValueError):
        BelcourBTDF(fgd_source="binary")


def test_registry_knows_the_four_models():
    from models.registry import all_models
    names = all_models()
    for cls, name in zip(ALL_MODELS, ("belcour-fwd", "belcour-sym", "belcour-bati19", "belcour-btdf")):
        assert cls.name == name and isinstance(names[name], cls)


# -------------------------------------------------------------------------- single interface


@pytest.mark.parametrize("iface", [Interface(0.2, (1.5,) * 3), Interface(0.05, (1.45,) * 3, (1.0, 0.01, 0.01)),
                                   Interface(0.3, (0.9, 1.1, 1.3), (3.0, 2.5, 2.0))])
def test_single_interface_gives_one_lobe_equal_to_fgd(iface):
    st = Stack("one", (iface,))
    for theta in (0.0, 40.0, 80.0):
        c = math.cos(math.radians(theta))
        lobes = belcour.lobe_statistics(st, c)
        assert len(lobes) == 1
        energy, alpha = lobes[0]
        expect = [float(tables.fgd_slice(e, k)(c, iface.roughness)) for e, k in zip(iface.ior, iface.extinction)]
        np.testing.assert_allclose(energy, expect, rtol=1e-14)
        np.testing.assert_allclose(alpha, iface.roughness, rtol=1e-12)


def test_height_correlated_option_reaches_lobes_and_top_brdf():
    """height_correlated=True: a single interface's lobe energy is the height-correlated FGD slice,
    and belcour-bati19's exact top lobe is the microfacet BRDF with height-correlated G2 (both differ
    from the separable values at grazing incidence, so an ignored option would fail)."""
    iface = Interface(0.5, (1.5,) * 3)
    st = Stack("one", (iface,))
    c = math.cos(math.radians(80.0))
    energy, _ = belcour.lobe_statistics(st, c, height_correlated=True)[0]
    hc = float(tables.fgd_slice(1.5, 0.0, height_correlated=True)(c, 0.5))
    sep = float(tables.fgd_slice(1.5, 0.0)(c, 0.5))
    np.testing.assert_allclose(energy, [hc] * 3, rtol=1e-14)
    assert abs(hc - sep) > 5e-3

    l = light(70.0)
    rng = np.random.default_rng(3)
    v = rng.normal(size=(50, 3))
    v[:, 2] = np.abs(v[:, 2])
    v /= np.linalg.norm(v, axis=1)[:, None]
    r = BelcourBati19(height_correlated=True).evaluate(st, l, v)
    exact = optics.np_microfacet_reflection(l[0], l[1], l[2], v[:, 0], v[:, 1], v[:, 2], 0.5, 0.5, 1.5, 0.0, True)
    np.testing.assert_allclose(r.top, np.repeat(exact[:, None], 3, axis=1), rtol=1e-12, atol=1e-300)
    sep_top = optics.np_microfacet_reflection(l[0], l[1], l[2], v[:, 0], v[:, 1], v[:, 2], 0.5, 0.5, 1.5, 0.0, False)
    assert np.max(np.abs(exact - sep_top) / exact) > 1e-2


# -------------------------------------------------------------------------- smooth limit


def _fresnel_interp_error(eta: float, kappa: float, mu_min: float) -> float:
    """Max |FGD(mu, 0) - F(mu)| over the cosines the model can look up (mu >= mu_min)."""
    s = tables.fgd_slice(eta, kappa, mu_min=mu_min)
    mu = np.linspace(mu_min, 1.0, 4001)
    exact = tables.fresnel_on(np.maximum(mu, tables.MU_FLOOR), eta, kappa)
    return float(np.max(np.abs(s(mu, 0.0) - exact)))


def _interfaces_relative(st: Stack, ch: int):
    """(eta, kappa, mu_min, n_above, alpha) per interface for colour channel ``ch`` (relative
    indices; ``mu_min`` the smallest cosine light from air reaches the interface with)."""
    out = []
    n_cur = 1.0
    for layer in st.layers:
        if isinstance(layer, Interface):
            mu_min = math.sqrt(max(0.0, 1 - 1 / n_cur ** 2))
            out.append((layer.ior[ch] / n_cur, layer.extinction[ch] / n_cur, mu_min, n_cur, layer.roughness))
            if not layer.is_conductor:
                n_cur = layer.ior[0]
    return out


@pytest.mark.parametrize("name,stack", [("metal", metal(0.0, (0.05, 0.1, 0.4), 1.2, 0.0)),
                                        ("metal-red", metal(0.0, (0.2,) * 3, 1.9, 0.0, (3.0, 1.0, 0.3))),
                                        ("slab", slab(0.0, (0.05, 0.1, 0.4), 0.0)),
                                        ("three", three_interfaces(0.0))])
@pytest.mark.parametrize("theta", [0.0, 45.0, 80.0, 89.0])
def test_smooth_limit_matches_adding_equations(name, stack, theta):
    """alpha = 0: sum of lobe energies (R) and T0N equal goniometer.testing.smooth.adding_energies."""
    c = math.cos(math.radians(theta))
    s = belcour.stack_statistics(stack, c)
    R, T = smooth.adding_energies(stack, theta)
    tol = np.array([4 * sum(_fresnel_interp_error(e, k, m) for e, k, m, _, _ in _interfaces_relative(stack, ch))
                    for ch in range(3)]) + 1e-12
    energy = sum(lobe.energy for lobe in s.lobes)
    assert np.all(np.abs(energy - R) <= tol), (energy, R, tol)
    np.testing.assert_allclose(s.R0N, energy, rtol=1e-14)
    assert np.all(np.abs(s.T0N - T) <= tol), (s.T0N, T, tol)
    assert np.all(tol < 1e-2)


@pytest.mark.parametrize("theta", [0.0, 45.0, 80.0])
def test_nearly_smooth_limit_matches_adding_equations(theta):
    """alpha = 0.001 (the database's smoothest): tolerance adds how far FGD is from Fresnel."""
    for st in (metal(0.001, (0.05, 0.1, 0.4), 1.9, 0.001), slab(0.001, (0.2,) * 3, 0.001)):
        c0 = math.cos(math.radians(theta))
        s = belcour.stack_statistics(st, c0)
        R, T = smooth.adding_energies(st, theta)
        # the roughness of the lookups: a~ = alpha at the top, f^-1(sT01 + f(alpha1)) at the base
        a0 = st.layers[0].roughness
        a_t = [a0, variance_to_roughness(roughness_to_variance(0.5 * (1 - 1 / 1.5) * a0)
                                         + roughness_to_variance(st.layers[2].roughness))]
        tol = np.full(3, 1e-12)
        for ch in range(3):
            for i, (e, k, m, n_cur, _) in enumerate(_interfaces_relative(st, ch)):
                c = math.sqrt(1 - (1 - c0 * c0) / n_cur ** 2)
                fg = float(tables.fgd_slice(e, k, mu_min=m)(c, a_t[i]))
                tol[ch] += 4 * (abs(fg - tables.fresnel_on(np.array([c]), e, k)[0]) + _fresnel_interp_error(e, k, m))
        energy = sum(lobe.energy for lobe in s.lobes)
        assert np.all(np.abs(energy - R) <= tol), (st, energy, R, tol)
        assert np.all(np.abs(s.T0N - T) <= tol), (st, s.T0N, T, tol)
        assert np.all(tol < 2e-2)


# -------------------------------------------------------------------------- two-layer closed forms


@pytest.mark.parametrize("per_channel", [True, False])
@pytest.mark.parametrize("stack", [metal(0.2, (0.05, 0.1, 0.4), 1.9, 0.2), slab(0.05, (0.05, 0.1, 0.4), 0.2),
                                   metal(0.05, (0.2,) * 3, 1.2, 0.001)])
def test_two_layer_lobes_follow_bati2021_adding_equations(stack, per_channel):
    """Normal incidence (where Bati 2021 works): E_1 = R01, E_2 = T01 R'12 T10 / (1 - R'12 R10)
    (eq. 2) and sigma_2 = sT10 + (eta1/eta0) (sT01 + (sR12 + R'12 R10 sR10) / (1 - R'12 R10)) (eq. 5),
    with the unitary operators of eq. 6 and the FGD lookups of the spec (R10 = R01, a~ for the
    base from the transmitted variance). Colour means replace R'12 R10 weights when per_channel
    is False."""
    top, med, base = stack.layers
    a0, a1, n1 = top.roughness, base.roughness, 1.5
    f = roughness_to_variance
    r01 = float(tables.fgd_slice(n1)(1.0, a0))
    t01 = 1 - r01
    sT01 = f(0.5 * abs(1 - 1 / n1) * a0)
    sT10 = f(0.5 * abs(1 - n1) * a0)
    sR = f(a0)
    a_t = variance_to_roughness(sT01 + f(a1))
    eta2 = np.asarray(base.ior) / n1
    kap2 = np.asarray(base.extinction) / n1
    r12 = np.array([float(tables.fgd_slice(e, k, mu_min=math.sqrt(1 - 1 / n1 ** 2))(1.0, a_t))
                    for e, k in zip(eta2, kap2)])
    att = np.exp(-2 * np.asarray(med.optical_depth))
    r12p = r12 * att
    e2 = t01 * r12p * t01 / (1 - r12p * r01)
    m = r12p * r01 / (1 - r12p * r01)
    if not per_channel:
        m = np.full(3, m.mean())
    s2 = sT10 + (n1 / 1.0) * (sT01 + f(a1) + m * (f(a1) + sR))
    s = belcour.stack_statistics(stack, 1.0, per_channel=per_channel)
    np.testing.assert_allclose(s.lobes[0].energy, r01, rtol=1e-13)
    np.testing.assert_allclose(s.lobes[0].variance, f(a0), rtol=1e-13)
    np.testing.assert_allclose(s.lobes[1].energy, e2, rtol=1e-12)
    np.testing.assert_allclose(s.lobes[1].variance, s2, rtol=1e-12)
    np.testing.assert_allclose(s.lobes[1].alpha, [variance_to_roughness(x) for x in s2], rtol=1e-12)
    if not per_channel:
        assert np.ptp(s.lobes[1].alpha) == 0.0


def test_transmission_and_reflection_variances_for_a_slab():
    """Eq. 4: the stack's reflected variance is the energy-weighted mean of the lobe variances."""
    st = slab(0.05, (0.05, 0.1, 0.4), 0.2)
    s = belcour.stack_statistics(st, 0.8)
    e = np.array([lobe.energy for lobe in s.lobes])
    v = np.array([lobe.variance for lobe in s.lobes])
    np.testing.assert_allclose(s.vR0N, (e * v).sum(0) / e.sum(0), rtol=1e-12)
    assert np.all(s.vT0N > 0) and np.all(s.T0N > 0) and s.cos_bottom == pytest.approx(0.8)


def test_angular_transmission_scale_equals_normal_one_at_normal_incidence():
    st = metal(0.2, (0.1,) * 3, 1.9, 0.2)
    a = belcour.lobe_statistics(st, 1.0)
    b = belcour.lobe_statistics(st, 1.0, transmission_scale="angular")
    for (ea, aa), (eb, ab) in zip(a, b):
        np.testing.assert_allclose(ea, eb, rtol=1e-12)
        np.testing.assert_allclose(aa, ab, rtol=1e-12)
    c = belcour.lobe_statistics(st, 0.3, transmission_scale="angular")
    d = belcour.lobe_statistics(st, 0.3)
    assert not np.allclose(c[1][1], d[1][1])


def test_tir_option_traps_light_between_interfaces():
    """With the TIR step, light reflected by the base outside the coat's escape cone stays inside:
    the base lobe loses energy at grazing incidence (rough base), never gains."""
    st = metal(0.05, (0.0,) * 3, 1.9, 0.6)
    for theta in (0.0, 60.0, 85.0):
        c = math.cos(math.radians(theta))
        off = belcour.lobe_statistics(st, c)
        on = belcour.lobe_statistics(st, c, use_tir=True)
        assert np.all(on[1][0] <= off[1][0] + 1e-12)
        np.testing.assert_allclose(on[0][0], off[0][0], rtol=1e-14)
    assert np.all(on[1][0] < off[1][0] - 1e-3)


def test_fgd_source_table_is_close_to_material_slices():
    st = metal(0.2, (0.2,) * 3, 1.9, 0.2)
    a = belcour.lobe_statistics(st, 0.7)
    b = belcour.lobe_statistics(st, 0.7, fgd_source="table")
    for (ea, _), (eb, _) in zip(a, b):
        np.testing.assert_allclose(ea, eb, atol=3e-3)


# -------------------------------------------------------------------------- symmetries and variants


def _random_pairs(n, seed):
    rng = np.random.default_rng(seed)
    th = np.arccos(rng.uniform(0.05, 1.0, (2, n)))
    ph = rng.uniform(0, 2 * np.pi, (2, n))
    d = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1)
    return d[0], d[1]


@pytest.mark.parametrize("stack", [metal(0.2, (0.05, 0.1, 0.4), 1.9, 0.2), slab(0.05, (0.2,) * 3, 0.2)])
@pytest.mark.parametrize("per_channel", [True, False])
def test_symmetric_model_is_reciprocal(stack, per_channel):
    m = BelcourSymmetric(per_channel=per_channel)
    ls, vs = _random_pairs(40, 3)
    for l, v in zip(ls, vs):
        a = m.evaluate(stack, l, v[None]).total[0]
        b = m.evaluate(stack, v, l[None]).total[0]
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-300)


def test_forward_model_is_not_reciprocal():
    """The forward model computes its statistics for omega_i = l only, so f(l, v) != f(v, l) in
    general: at l = 10 deg, v = 70 deg the internal lobe differs by more than 5 percent."""
    st = metal(0.2, (0.05, 0.1, 0.4), 1.9, 0.2)
    m = BelcourForward()
    l, v = light(10.0), light(70.0, 180.0)
    a = m.evaluate(st, l, v[None]).internal[0]
    b = m.evaluate(st, v, l[None]).internal[0]
    assert np.max(np.abs(a - b) / np.maximum(a, b)) > 0.05
    # the view-incident switch is the same model with the roles swapped
    mv = BelcourForward(incident="view")
    np.testing.assert_allclose(mv.evaluate(st, v, l[None]).total[0], m.evaluate(st, l, v[None]).total[0],
                               rtol=1e-6)


def test_symmetric_equals_forward_at_the_mirror_direction():
    st = metal(0.2, (0.05, 0.1, 0.4), 1.45, 0.2)
    l = light(35.0)
    v = np.array([-l[0], -l[1], l[2]])
    a = BelcourSymmetric().evaluate(st, l, v[None]).total[0]
    b = BelcourForward().evaluate(st, l, v[None]).total[0]
    np.testing.assert_allclose(a, b, rtol=1e-4)


def test_bati19_top_lobe_is_the_exact_microfacet_brdf():
    st = metal(0.2, (0.05, 0.1, 0.4), 1.9, 0.2)
    v = hemisphere(20, 40).reshape(-1, 3)
    for theta in (0.0, 45.0, 80.0):
        l = light(theta, 30.0)
        r = BelcourBati19().evaluate(st, l, v)
        exact = optics.np_microfacet_reflection(l[0], l[1], l[2], v[:, 0], v[:, 1], v[:, 2], 0.2, 0.2, 1.5, 0.0,
                                                False)
        np.testing.assert_allclose(r.top, np.repeat(exact[:, None], 3, axis=1), rtol=1e-12, atol=1e-300)
        np.testing.assert_array_equal(r.internal, BelcourForward().evaluate(st, l, v).internal)


def test_lobes_sum_to_their_energies():
    """Integrating f cos over the hemisphere gives sum_k E_k times the F = 1 albedo of each GGX lobe
    (close to 1 for moderate roughness); checked at normal incidence with a fine grid."""
    st = metal(0.2, (0.05, 0.1, 0.4), 1.9, 0.2)
    m = BelcourForward()
    n_t, n_p = 400, 256
    th = (np.arange(n_t) + 0.5) * (np.pi / 2) / n_t
    ph = (np.arange(n_p) + 0.5) * 2 * np.pi / n_p
    T, P = np.meshgrid(th, ph, indexing="ij")
    v = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1)
    w = (np.cos(T) * np.sin(T) * (np.pi / 2 / n_t) * (2 * np.pi / n_p))[..., None]
    r = m.evaluate(st, light(0.0), v)
    s = belcour.stack_statistics(st, 1.0)
    top = (r.top * w).sum((0, 1))
    albedo0 = tables.fgd_direct(1.0, 0.2, 0.0, 0.0)   # F = 1 albedo of the lobe
    np.testing.assert_allclose(top, s.lobes[0].energy * albedo0, rtol=2e-3)
    internal = (r.internal * w).sum((0, 1))
    expect = sum(lobe.energy * np.array([tables.fgd_direct(1.0, max(a, 1e-4), 0.0, 0.0) for a in lobe.alpha])
                 for lobe in s.lobes[1:])
    np.testing.assert_allclose(internal, expect, rtol=3e-3)


def test_direction_grid_matches_per_direction_adding_doubling():
    """The default tabulation of direction-dependent statistics over the cosine (2048 nodes) agrees
    with running the adding-doubling for every direction."""
    st = metal(0.2, (0.05, 0.1, 0.4), 1.9, 0.2)
    v = hemisphere(30, 60).reshape(-1, 3)
    for cls in (BelcourSymmetric, lambda **k: BelcourForward(incident="view", **k)):
        for theta in (10.0, 70.0):
            a = cls().evaluate(st, light(theta), v).total
            b = cls(direction_grid=0).evaluate(st, light(theta), v).total
            np.testing.assert_allclose(a, b, rtol=1e-3, atol=1e-8 * b.max())


# -------------------------------------------------------------------------- BTDF


def test_btdf_peak_direction_energy_and_smooth_limit():
    st = slab(0.05, (0.05, 0.1, 0.4), 0.2)
    m = BelcourBTDF()
    for theta in (0.0, 30.0, 60.0):
        l = light(theta, 20.0)
        T, alpha, c_n = m.transmission_lobe(st, l[2])
        assert c_n == pytest.approx(l[2])          # a slab in air: straight through
        # the value peaks straight through (v = -l)
        vals = m.evaluate(st, l, np.stack([-l, -light(theta + 3.0, 20.0)]), side="btdf").internal
        assert np.all(vals[0] > vals[1])
        # energy: integral over the lower hemisphere ~ T0N times the F = 1 lobe albedo
        n_t, n_p = 300, 256
        th = (np.arange(n_t) + 0.5) * (np.pi / 2) / n_t
        ph = (np.arange(n_p) + 0.5) * 2 * np.pi / n_p
        TT, PP = np.meshgrid(th, ph, indexing="ij")
        v = np.stack([np.sin(TT) * np.cos(PP), np.sin(TT) * np.sin(PP), -np.cos(TT)], -1)
        w = (np.cos(TT) * np.sin(TT) * (np.pi / 2 / n_t) * (2 * np.pi / n_p))[..., None]
        flux = (m.evaluate(st, l, v, side="btdf").internal * w).sum((0, 1))
        albedo = np.array([tables.fgd_direct(c_n, a, 0.0, 0.0) for a in alpha])
        np.testing.assert_allclose(flux, T * albedo, rtol=3e-3)
    # smooth limit of the transmitted energy
    sm = slab(0.0, (0.05, 0.1, 0.4), 0.0)
    for theta in (0.0, 45.0, 80.0):
        T, _, _ = m.transmission_lobe(sm, math.cos(math.radians(theta)))
        np.testing.assert_allclose(T, smooth.adding_energies(sm, theta)[1], atol=1e-3)


def test_btdf_top_is_zero_and_upper_hemisphere_is_zero():
    st = slab()
    r = BelcourBTDF().evaluate(st, light(30.0), hemisphere(10, 20, lower=True), side="btdf")
    assert np.all(r.top == 0.0) and r.internal.max() > 0
    up = BelcourBTDF().evaluate(st, light(30.0), hemisphere(10, 20), side="btdf")
    assert np.all(up.internal == 0.0)


# -------------------------------------------------------------------------- robustness


def _database_stacks():
    taus = [(0.2,) * 3, (0.05, 0.1, 0.4)]
    out = []
    for a0 in (0.001, 0.05, 0.2):
        for tau in taus:
            for eta1 in (1.9, 1.45, 1.2):
                for a1 in (0.001, 0.2):
                    out.append(metal(a0, tau, eta1, a1))
            for a1 in (0.001, 0.2):
                out.append(slab(a0, tau, a1))
    return out


@pytest.mark.parametrize("cls", ALL_MODELS)
def test_finite_and_non_negative_over_the_database(cls):
    m = cls()
    side = m.sides[0]
    v = hemisphere(60, 72, lower=(side == "btdf")).reshape(-1, 3)
    extra = np.array([[0.0, 0.0, 1.0], [math.sin(math.radians(89.9)), 0.0, math.cos(math.radians(89.9))]])
    if side == "btdf":
        extra[:, 2] *= -1
    v = np.concatenate([v, extra])
    n_checked = 0
    for st in _database_stacks():
        if not m.supports(st):
            assert cls is BelcourBTDF and st.base == "conductor"
            continue
        for theta in (0.0, 45.0, 80.0, 89.0, 89.9):
            r = m.evaluate(st, light(theta, 17.0), v, side=side)
            for part in (r.top, r.internal):
                assert part.shape == v.shape
                assert np.all(np.isfinite(part)) and part.min() >= 0.0
            n_checked += 1
    assert n_checked >= 5 * 12


def test_smoothest_stacks_and_alpha_zero_stay_finite():
    st = Stack("z", (Interface(0.0, (1.5,) * 3), Medium((0.1,) * 3), Interface(0.0, (1.2,) * 3, (1.0, 0.01, 0.01))))
    v = hemisphere(30, 36).reshape(-1, 3)
    for cls in (BelcourForward, BelcourSymmetric, BelcourBati19):
        r = cls().evaluate(st, light(30.0), v)
        assert np.all(np.isfinite(r.total)) and r.total.min() >= 0 and r.total.max() > 0


def test_lambertian_base_is_refused():
    st = Stack("p", (Interface(0.2, (1.5,) * 3), Medium((0.1,) * 3), Lambertian((0.5,) * 3)))
    for cls in ALL_MODELS:
        m = cls()
        reason = m.support_reason(st)
        assert reason is not None and "Lambertian" in reason
        with pytest.raises(ModelError, match="Lambertian"):
            m.evaluate(st, light(0.0), hemisphere(2, 4, lower=cls is BelcourBTDF), side=m.sides[0])
    with pytest.raises(ValueError):
        belcour.lobe_statistics(st, 1.0)


def test_btdf_asked_of_brdf_models_raises_and_btdf_refuses_metals():
    for cls in (BelcourForward, BelcourSymmetric, BelcourBati19):
        with pytest.raises(ModelError):
            cls().evaluate(slab(), light(0.0), hemisphere(2, 4, lower=True), side="btdf")
    m = BelcourBTDF()
    assert m.support_reason(slab()) is None
    assert "dielectric" in m.support_reason(metal())
    with pytest.raises(ModelError):
        m.evaluate(slab(), light(0.0), hemisphere(2, 4), side="brdf")
    # the BRDF models accept slabs (per-interface reflection lobes)
    assert BelcourForward().support_reason(slab()) is None


def test_options_object_and_keywords_agree():
    st = metal()
    a = belcour.lobe_statistics(st, 0.6, BelcourOptions(per_channel=False))
    b = belcour.lobe_statistics(st, 0.6, per_channel=False)
    for (ea, aa), (eb, ab) in zip(a, b):
        np.testing.assert_array_equal(ea, eb)
        np.testing.assert_array_equal(aa, ab)


@pytest.mark.parametrize("theta_deg", [0.0, 60.0, 80.0])
def test_btdf_transmitted_variance_by_hand(theta_deg):
    # Slab S2 of Bati 2019 with an absorbing core (tau = 3, so the inter-reflection factor m is
    # below 1e-5 and drops out): the transmission lobe's variance is the top interface's
    # transmitted variance carried into the bottom medium plus the exit interface's own,
    # v_T = v_d0 / j1 + v_d1 (consistent bookkeeping, docs/belcour.md) or j1 v_d0 + v_d1 (the
    # published adding code), with v_d = f(alpha * |n - 1| / (2 n)) (normal-incidence s),
    # j1 = n1 cos(theta_out) / cos(theta_glass) and f(a) = a^1.1 / (1 - a^1.1). By hand:
    def f(a):
        return a ** 1.1 / (1.0 - a ** 1.1)

    a0 = a1 = 0.2
    n0, n1 = 1.5, 1.0 / 1.5
    stack = Stack("s2", (Interface(a0, (1.5,) * 3), Medium((3.0,) * 3), Interface(a1, (1.0,) * 3)), "slab")
    c = math.cos(math.radians(theta_deg))
    c_glass = math.sqrt(1.0 - (1.0 - c * c) / n0 ** 2)
    c_out = math.sqrt(1.0 - (1.0 - c_glass ** 2) / n1 ** 2)
    j1 = (c_out / c_glass) * n1
    vd0 = f(a0 * abs(n0 - 1.0) / (2.0 * n0))
    vd1 = f(a1 * abs(n1 - 1.0) / (2.0 * n1))
    f_inv = variance_to_roughness
    for jac, expect in (("consistent", vd0 / j1 + vd1), ("reference", j1 * vd0 + vd1)):
        T, alpha, cos_n = BelcourBTDF(transmitted_jacobian=jac).transmission_lobe(stack, c)
        assert cos_n == pytest.approx(c_out, rel=1e-12)
        assert alpha == pytest.approx(np.full(3, f_inv(expect)), rel=1e-3)
    # leaving glass widens the lobe with the consistent bookkeeping, narrows it with the published one
    assert vd0 / j1 > vd0 > j1 * vd0


def test_btdf_jacobian_changes_no_brdf_of_a_two_interface_stack():
    # the transmitted-variance bookkeeping only reaches a BRDF lobe through a third interface
    st = metal()
    rng = np.random.default_rng(3)
    v = rng.normal(size=(64, 3))
    v[:, 2] = np.abs(v[:, 2])
    v /= np.linalg.norm(v, axis=1)[:, None]
    l = np.array([math.sin(0.9), 0.0, math.cos(0.9)])
    a = BelcourForward(transmitted_jacobian="reference", direction_grid=0).evaluate(st, l, v)
    b = BelcourForward(transmitted_jacobian="consistent", direction_grid=0).evaluate(st, l, v)
    assert np.array_equal(a.top, b.top) and np.array_equal(a.internal, b.internal)
