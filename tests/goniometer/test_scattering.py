"""Scattering media (Henyey-Greenstein) against independent references.

* HG sampling: chi-square against the HG density (integrated by quadrature in this file), the
  exact isotropic limit, and the spectral-MIS free-flight sampling against its mixture density and
  the transmittances it must reproduce.
* Transport: conservation (albedo 1: R + T = 1 path by path), single scattering of a slab (closed
  form, cell by cell, isolated through the albedo: see ``test_single_scattering_matches_closed_form``),
  the semi-infinite isotropic medium (Chandrasekhar's H-function, computed here by iterating the
  H-equation), per-channel equivalence of chromatic extinction, reciprocity, g -> 0 vs isotropic,
  determinism, and that a medium without scattering takes exactly the old code path.
* Bad input: one line, exit status 2.

Tolerances are statistical: z-scores within Z_TOL (false-alarm probability P_FALSE_ALARM = 1e-6,
two-sided) of the Monte Carlo standard error and chi-square limits at the same probability
(:mod:`goniometer.testing`, docs/testing.md), plus, where a reference is only bracketed, the
stated rigorous bound.
"""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path

import numba
import numpy as np
import pytest
from scipy import integrate
from scipy.special import roots_legendre

from goniometer import optics
from goniometer.cli import main
from goniometer.run.loop import simulate
from goniometer.run.settings import SimulationSettings
from goniometer.grids.slice_grid import light_direction
from goniometer.stack import Interface, Lambertian, Medium, Stack, StackError, load_toml, stack_from_dict
from goniometer.kernel.packing import pack
from goniometer.testing import (Z_TOL, assert_cells_match, assert_energy_conserved, assert_energy_matches,
                                assert_samples_match, assert_z_close, chi2_interval, chi2_limit)

# ----------------------------------------------------------------------------- references


def hg_density(c, g):
    """Henyey-Greenstein phase function (1/sr, normalised over the sphere), written out here."""
    return (1.0 - g * g) / (4.0 * math.pi * (1.0 + g * g - 2.0 * g * np.asarray(c)) ** 1.5)


def matched(medium: Medium, name: str = "slab") -> Stack:
    """``medium`` between two smooth index-matched interfaces (no Fresnel, no refraction)."""
    return Stack(name, (Interface(0.0, (1.0,) * 3), medium, Interface(0.0, (1.0,) * 3)))


# ----------------------------------------------------------------------------- HG sampling


@numba.njit(cache=True)
def _scatter_many(d, g, u):
    out = np.empty((u.shape[0], 3))
    for i in range(u.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = optics.hg_scatter(d[0], d[1], d[2], g, u[i, 0], u[i, 1])
    return out


@pytest.mark.parametrize("g", [-0.7, 0.0, 0.3, 0.9])
@pytest.mark.parametrize("d", [(0.3, -0.5, -0.8124038404635961), (0.0, 0.0, -1.0), (0.0, 0.0, 1.0)])
def test_hg_directions_follow_the_hg_density(g, d):
    """Chi-square of hg_scatter's directions about d in 40 cosine x 8 azimuth bins against the HG
    density integrated by quadrature (azimuth uniform); P_FALSE_ALARM."""
    n = 400_000
    d = np.asarray(d) / np.linalg.norm(d)
    o = _scatter_many(d, g, np.random.default_rng(3).random((n, 2)))
    np.testing.assert_allclose(np.linalg.norm(o, axis=1), 1.0, atol=1e-12)
    # a frame of our own about d
    a = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t1 = np.cross(d, a)
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(d, t1)
    c = np.clip(o @ d, -1.0, 1.0)
    phi = np.mod(np.arctan2(o @ t2, o @ t1), 2 * math.pi)
    nc, nphi = 40, 8
    ic = np.minimum(((c + 1.0) * 0.5 * nc).astype(int), nc - 1)
    ip = np.minimum((phi / (2 * math.pi) * nphi).astype(int), nphi - 1)
    observed = np.bincount(ic * nphi + ip, minlength=nc * nphi)
    edges = np.linspace(-1.0, 1.0, nc + 1)
    p_bin = np.array([integrate.quad(lambda x: 2 * math.pi * hg_density(x, g), edges[i], edges[i + 1],
                                     epsabs=1e-14)[0] for i in range(nc)])
    assert p_bin.sum() == pytest.approx(1.0, abs=1e-10)
    expected = np.repeat(p_bin / nphi, nphi) * n
    assert expected.min() > 5
    chi2 = np.sum((observed - expected) ** 2 / expected)
    assert chi2 < chi2_limit(nc * nphi - 1), f"chi2 {chi2:.1f}"


@pytest.mark.parametrize("g", [-0.95, -0.4, 0.0, 0.5, 0.95])
def test_hg_phase_is_normalised_and_its_mean_cosine_is_g(g):
    """The defining properties of the HG phase function: Int p dw = 1 and Int cos p dw = g."""
    norm = integrate.quad(lambda c: 2 * math.pi * optics.hg_phase(c, g), -1, 1, epsabs=1e-13)[0]
    mean = integrate.quad(lambda c: 2 * math.pi * c * optics.hg_phase(c, g), -1, 1, epsabs=1e-13)[0]
    assert norm == pytest.approx(1.0, abs=1e-9) and mean == pytest.approx(g, abs=1e-9)
    c = np.linspace(-1, 1, 11)
    np.testing.assert_allclose(optics.np_hg_phase(c, g), hg_density(c, g), rtol=1e-13)


def test_hg_sampling_has_an_exact_isotropic_limit():
    """g = 0 gives exactly the isotropic cosine 2u - 1; small |g| deviates by at most 1.5 |g|
    (the first-order term); no division by g anywhere (tiny and subnormal g give finite values);
    u = 0 gives exactly -1."""
    u = np.random.default_rng(1).random(2000)
    iso = 2.0 * u - 1.0
    assert all(optics.sample_hg_cos(0.0, x) == y for x, y in zip(u, iso))
    for g in (1e-6, -1e-6):
        dev = np.array([optics.sample_hg_cos(g, x) for x in u]) - iso
        assert np.all(np.abs(dev) <= 1.5 * abs(g) * (1 + 1e-6))
    for g in (1e-300, -1e-300, 5e-324, -5e-324):
        assert all(optics.sample_hg_cos(g, x) == y for x, y in zip(u[:50], iso[:50]))
    for g in (-0.99, 0.0, 0.99):
        assert optics.sample_hg_cos(g, 0.0) == -1.0
        assert optics.sample_hg_cos(g, 1.0 - 2.0**-53) == pytest.approx(1.0, abs=1e-10)


@numba.njit(cache=True)
def _first_flights(u, t0, t1, t2):
    """First flight lengths of paths whose hero channel is picked uniformly by ``u[:, 0]``."""
    s = np.empty(u.shape[0])
    for i in range(u.shape[0]):
        h = min(int(u[i, 0] * 3.0), 2)
        s[i] = optics.hero_free_flight(u[i, 1], t0 if h == 0 else (t1 if h == 1 else t2))
    return s


@numba.njit(cache=True)
def _rods(n, t, a, length, seed):
    """Paths through a rod of ``length`` (collisions scatter straight on: albedo only), weighted
    as the tracer weights them (hero channel, :func:`goniometer.optics.spectral_mis_update`);
    returns each path's exit weights (0 if it never leaves) and the largest weight ever held."""
    np.random.seed(seed)
    out = np.zeros((n, 3))
    wmax = 0.0
    for i in range(n):
        h = min(int(np.random.random() * 3.0), 2)
        q0 = q1 = q2 = 1.0 / 3.0
        w = np.ones(3)
        left = length
        while True:
            s = optics.hero_free_flight(np.random.random(), t[h])
            if s >= left:
                r0, r1, r2, q0, q1, q2 = optics.spectral_mis_update(
                    math.exp(-t[0] * left), math.exp(-t[1] * left), math.exp(-t[2] * left), q0, q1, q2)
                w[0] *= r0
                w[1] *= r1
                w[2] *= r2
                out[i] = w
                break
            r0, r1, r2, q0, q1, q2 = optics.spectral_mis_update(
                t[0] * math.exp(-t[0] * s), t[1] * math.exp(-t[1] * s), t[2] * math.exp(-t[2] * s), q0, q1, q2)
            w[0] *= a[0] * r0
            w[1] *= a[1] * r1
            w[2] *= a[2] * r2
            wmax = max(wmax, w.max())
            left -= s
        wmax = max(wmax, w.max())
    return out, wmax


@pytest.mark.parametrize("taus", [(0.5, 1.0, 3.0), (0.0, 1.0, 2.0), (2.0, 2.0, 2.0)])
def test_hero_flights_follow_the_channel_mixture(taus):
    """A path's first flight, its hero channel picked uniformly, has the density
    mean_c t_c exp(-t_c s) (chi-square against its closed-form CDF); a channel with t_c = 0 never
    collides."""
    n = 400_000
    t = np.asarray(taus)
    s = _first_flights(np.random.default_rng(5).random((n, 2)), *taus)
    edges = np.concatenate([np.linspace(0.0, 4.0, 41), [np.inf]])
    cdf = 1.0 - np.mean(np.exp(-np.outer(edges[:-1], t)), axis=1)
    p = np.diff(np.concatenate([cdf, [1.0 - np.mean(t == 0.0)]]))
    observed = np.histogram(s[np.isfinite(s)], bins=edges)[0]
    expected = p * n
    keep = expected > 5
    chi2 = np.sum((observed[keep] - expected[keep]) ** 2 / expected[keep])
    assert chi2 < chi2_limit(int(keep.sum()) - 1)
    assert np.count_nonzero(~np.isfinite(s)) == pytest.approx(n * np.mean(t == 0.0), abs=Z_TOL * math.sqrt(n / 4))


@pytest.mark.parametrize("taus, albedo", [((1.6, 1.6, 8.8), (0.5, 0.5, 0.909)), ((0.0, 1.0, 4.0), (0.9, 0.9, 0.99))])
def test_path_level_spectral_mis_is_unbiased_with_bounded_weights(taus, albedo):
    """A rod of optical depth t_c whose collisions only scale by the albedo (straight on) transmits
    exp(-t_c (1 - a_c) L) per channel (closed form); the path weights reproduce it within Z_TOL
    standard errors, and no weight ever exceeds 3 (the path-level bound), even through ~35
    collisions."""
    n, length = 200_000, 4.0
    t, a = np.asarray(taus, float), np.asarray(albedo, float)
    out, wmax = _rods(n, t, a, length, 11)
    assert wmax <= 3.0 + 1e-12
    assert_z_close(out.mean(axis=0), out.std(axis=0) / math.sqrt(n), np.exp(-t * (1.0 - a) * length))


# ----------------------------------------------------------------------------- the stack contract


def test_new_keys_default_and_are_omitted_from_the_canonical_json():
    base = {"name": "m", "layers": [{"type": "interface", "roughness": 0.1, "ior": 1.5},
                                    {"type": "medium", "optical_depth": [0.1, 0.2, 0.3]},
                                    {"type": "lambertian", "albedo": 0.5}]}
    old = stack_from_dict(base)
    explicit = json.loads(json.dumps(base))
    explicit["layers"][1].update(scattering_albedo=0.0, g=0.0)
    assert stack_from_dict(explicit) == old
    assert old.to_json() == ('{"category":"other","layers":[{"ior":1.5,"roughness":0.1,"type":"interface"},'
                             '{"optical_depth":[0.1,0.2,0.3],"type":"medium"},'
                             '{"albedo":[0.5,0.5,0.5],"type":"lambertian"}],"name":"m"}')
    sc = json.loads(json.dumps(base))
    sc["layers"][1].update(scattering_albedo=[0.5, 0.0, 0.25], g=-0.3)
    st = stack_from_dict(sc)
    d = json.loads(st.to_json())["layers"][1]
    assert d == {"type": "medium", "optical_depth": [0.1, 0.2, 0.3], "scattering_albedo": [0.5, 0.0, 0.25], "g": -0.3}
    assert Stack.from_json(st.to_json()) == st and st.layers[1].scatters
    scalar = json.loads(json.dumps(base))
    scalar["layers"][1]["scattering_albedo"] = 0.7
    assert stack_from_dict(scalar).layers[1].scattering_albedo == (0.7, 0.7, 0.7)
    p = pack(st)
    np.testing.assert_array_equal(p.region_albedo[1], [0.5, 0.0, 0.25])
    assert p.region_g[1] == -0.3 and not p.region_albedo[0].any()
    # albedo only where the optical depth is 0: nothing scatters, nothing is packed
    none = Medium((0.1, 0.2, 0.0), (0.0, 0.0, 0.9), 0.5)
    assert not none.scatters
    assert not pack(Stack("n", (Interface(0.1, (1.5,) * 3), none, Lambertian((0.5,) * 3)))).region_albedo.any()


@pytest.mark.parametrize("medium, field", [(Medium((1.0,) * 3, (0.5,) * 3, 1.0), "g"),
                                           (Medium((1.0,) * 3, (0.5,) * 3, -1.0), "g"),
                                           (Medium((1.0,) * 3, (0.5, 1.2, 0.5)), "scattering_albedo"),
                                           (Medium((1.0,) * 3, (-0.1, 0.5, 0.5)), "scattering_albedo")])
def test_python_built_stacks_are_validated(medium, field):
    with pytest.raises(StackError, match=rf"layers\[1\]\.{field}: .* is outside"):
        Stack("x", (Interface(0.1, (1.5,) * 3), medium, Lambertian((0.5,) * 3)))


# ----------------------------------------------------------------------------- off means the old path


def test_no_scattering_takes_exactly_the_absorbing_path():
    """Bit-identical slices and energies for a medium written without the new keys, with them
    explicitly at 0, and with an albedo only in a channel of zero optical depth (which does not
    scatter): any free flight would draw random numbers and change the bits."""
    settings = SimulationSettings(incident_deg=(0.0, 60.0), rays=60_000, resolution=(9, 18), seed=8)
    runs = [simulate(Stack("m", (Interface(0.2, (1.5,) * 3), med, Interface(0.2, (1.45,) * 3, (1.0, 0.3, 0.1)))),
                     settings)
            for med in (Medium((0.3, 0.5, 0.0)), Medium((0.3, 0.5, 0.0), (0.0, 0.0, 0.0), 0.0),
                        Medium((0.3, 0.5, 0.0), (0.0, 0.0, 1.0), 0.8))]
    for r in runs[1:]:
        np.testing.assert_array_equal(r.brdf.orders, runs[0].brdf.orders)
        np.testing.assert_array_equal(r.brdf.stderr, runs[0].brdf.stderr)
        for k in r.energy:
            np.testing.assert_array_equal(r.energy[k], runs[0].energy[k])
        np.testing.assert_array_equal(r.mean_events, runs[0].mean_events)


# ----------------------------------------------------------------------------- conservation


@pytest.mark.parametrize("g", [0.0, 0.6, -0.4])
def test_conservative_slab_keeps_every_path_whole(g):
    """Albedo 1 with achromatic extinction between index-matched smooth interfaces: every path
    leaves with its whole weight, so R + T = 1 and absorbed = roulette = 0 exactly (no tolerance)."""
    r = simulate(matched(Medium((2.0,) * 3, (1.0,) * 3, g)),
                 SimulationSettings(incident_deg=(0.0, 60.0, 85.0), rays=50_000, resolution=(9, 18)))
    assert np.all(r.energy["absorbed"] == 0) and np.all(r.roulette == 0) and np.all(r.capped == 0)
    assert np.all(r.energy["masking_loss"] == 0)
    np.testing.assert_allclose(r.energy["reflected"] + r.energy["transmitted"], 1.0, rtol=0, atol=1e-12)
    assert np.all(r.mean_events > 2.5)  # two crossings and, on average, several collisions


def test_conservative_chromatic_slab_absorbs_nothing_on_average():
    """Albedo 1 with chromatic extinction: the spectral-MIS weights move weight between channels
    path by path, but the absorbed term is zero within Z_TOL standard errors and the bookkeeping
    still closes exactly."""
    r = simulate(matched(Medium((0.5, 1.0, 3.0), (1.0,) * 3, 0.3)),
                 SimulationSettings(incident_deg=(0.0, 70.0), rays=200_000, resolution=(9, 18), seed=2))
    assert_energy_conserved(r, atol=1e-10)
    assert_energy_matches(r, "absorbed", 0.0, extra=np.abs(r.roulette))


SCATTER_STACKS = {
    "lambertian base": Stack("a", (Interface(0.3, (1.5,) * 3), Medium((0.5, 1.0, 2.0), (0.9, 0.7, 0.5), 0.5),
                                   Lambertian((0.6, 0.5, 0.4)))),
    "conductor base": Stack("b", (Interface(0.2, (1.5,) * 3), Medium((1.0,) * 3, (0.8, 0.9, 0.99), -0.5),
                                  Interface(0.2, (1.2, 1.3, 1.45), (3.0, 0.0, 0.0)))),
    "slab": Stack("c", (Interface(0.05, (1.5,) * 3), Medium((0.0, 0.8, 4.0), (0.5, 0.0, 0.95), 0.9),
                        Interface(0.3, (1.0,) * 3))),
    "two media": Stack("d", (Interface(0.1, (1.3,) * 3), Medium((0.4,) * 3, (0.6,) * 3, 0.2),
                             Interface(0.2, (1.6,) * 3), Medium((1.0, 2.0, 0.5), (0.3, 0.9, 0.5), 0.7),
                             Interface(0.0, (1.0,) * 3))),
}


@pytest.mark.parametrize("name", list(SCATTER_STACKS))
def test_energy_terms_of_scattering_stacks_sum_to_one(name):
    r = simulate(SCATTER_STACKS[name], SimulationSettings(incident_deg=(0.0, 45.0, 89.0), rays=40_000,
                                                          resolution=(9, 18), parametrization="half"))
    assert_energy_conserved(r, atol=1e-10)
    for sd in (r.brdf, r.btdf):
        if sd is not None:
            for a in (sd.value, sd.stderr, sd.orders):
                assert np.isfinite(a).all() and (a >= 0).all()
            np.testing.assert_allclose(sd.orders.sum(axis=1), sd.value, rtol=1e-12, atol=0)
    for v in list(r.energy.values()) + list(r.energy_stderr.values()):
        assert np.isfinite(v).all()
    assert (r.capped_paths == 0).all() and np.all(np.abs(r.roulette) < 0.01)


# ----------------------------------------------------------------------------- single scattering

#: albedo of the channel that isolates single scattering (see the test below)
A_SMALL = 1e-4


def single_brdf(tau, g, l, v):
    """Single-scattering BRDF of an index-matched slab per unit albedo:
    p(-l.v) (1 - exp(-tau (1/mu_l + 1/mu_v))) / (mu_l + mu_v)."""
    mu0, mu = l[2], v[..., 2]
    return hg_density(-(v @ l), g) * -np.expm1(-tau * (1.0 / mu0 + 1.0 / mu)) / (mu0 + mu)


def single_btdf(tau, g, l, v):
    """Single-scattering BTDF (diffuse part) per unit albedo:
    p(-l.v) (exp(-tau/mu_l) - exp(-tau/mu_v)) / (mu_l - mu_v), mu_v = |v_z|, written without the
    removable singularity at mu_v = mu_l."""
    mu0, mu = l[2], -v[..., 2]
    x = tau * (mu0 - mu) / (mu * mu0)
    small = np.abs(x) < 1e-12
    ratio = np.where(small, 1.0, -np.expm1(-x) / np.where(small, 1.0, x))
    return hg_density(-(v @ l), g) * math.exp(-tau / mu0) * tau / (mu * mu0) * ratio


def single_albedo(tau, g):
    """R1 / a at normal incidence: Int_0^1 2 pi p(-mu) mu / (1 + mu) (1 - exp(-tau (1 + 1/mu))) dmu."""
    return integrate.quad(lambda m: 2 * math.pi * hg_density(-m, g) * m / (1 + m) * -math.expm1(-tau * (1 + 1 / m)),
                          0, 1, epsabs=1e-14, epsrel=1e-12)[0]


@pytest.mark.parametrize("g", [0.0, 0.7])
def test_single_scattering_matches_closed_form(g):
    """Single scattering of an index-matched slab (tau = 0.5), cell by cell (BRDF and BTDF, the
    direct-beam cell excluded) and in total at normal incidence.

    Isolation: with achromatic extinction a path that scattered n times carries a^n in a channel of
    albedo a, so channel 1 (a = A_SMALL) estimates a K1 + a^2 K2 + ..., where K_n is what the
    conservative slab returns after exactly n collisions; channel 0 (a = 1, which also keeps the
    Russian roulette off) estimates R0 = sum K_n. Hence 0 <= R_1 / a - K1 <= a (R0 - K1) <= a R0:
    a rigorous bound (1e-4 R0 here) added to Z_TOL standard errors. Per cell the same bias is
    below 1e-4 of the conservative cell value, far below the cells' noise.
    """
    tau = 0.5
    st = matched(Medium((tau,) * 3, (1.0, A_SMALL, 0.5), g))
    s = SimulationSettings(incident_deg=(0.0, 50.0), rays=600_000, resolution=(18, 36), seed=21)
    r = simulate(st, s)
    assert np.all(r.roulette == 0)
    for m, theta in enumerate(r.theta_deg):
        l = light_direction(theta)
        for sd, f in ((r.brdf, single_brdf), (r.btdf, single_btdf)):
            model = sd.grid.integrate(l, lambda l_, v: f(tau, g, l_, v), s=5)
            where = np.ones(sd.grid.shape, bool)
            if sd is r.btdf:
                where[sd.grid.cell_of(l, -l)] = False
            assert_cells_match(sd.value[m][1] / A_SMALL, sd.stderr[m][1] / A_SMALL, model,
                               sd.proj_solid_angle[m], s.rays, where=where)
    r0, r1 = r.energy["reflected"][0, 0], r.energy["reflected"][0, 1]
    se1 = r.energy_stderr["reflected"][0, 1]
    k1 = single_albedo(tau, g)
    assert -Z_TOL * se1 / A_SMALL <= r1 / A_SMALL - k1 <= A_SMALL * r0 + Z_TOL * se1 / A_SMALL, (r1 / A_SMALL, k1)
    # the unscattered beam: transmitted in every channel with weight 1 (Beer-Lambert)
    t_direct = [math.exp(-tau / math.cos(math.radians(t))) for t in r.theta_deg]
    for m, t in enumerate(t_direct):
        cell = r.btdf.grid.cell_of(light_direction(r.theta_deg[m]), -light_direction(r.theta_deg[m]))
        direct = r.btdf.orders[m, :, :, cell[0], cell[1]].sum(axis=0)[1] * r.btdf.proj_solid_angle[m][cell]
        assert_z_close(direct, math.sqrt(t * (1 - t) / s.rays), t, extra=A_SMALL)


# ----------------------------------------------------------------------------- semi-infinite medium


def h_function(w: float, mu, n: int = 200):
    """Chandrasekhar's H-function of isotropic scattering with single-scattering albedo w < 1,
    iterating 1/H(mu) = sqrt(1 - w) + (w/2) Int_0^1 mu' H(mu') / (mu + mu') dmu' on n
    Gauss-Legendre nodes (Nystrom: evaluated at ``mu`` by the same formula)."""
    x, wt = roots_legendre(n)
    nodes, wt = 0.5 * (x + 1.0), 0.5 * wt
    h = np.ones(n)
    for _ in range(10_000):
        new = 1.0 / (math.sqrt(1 - w) + 0.5 * w * np.sum(wt * nodes * h / (nodes[:, None] + nodes), axis=1))
        done = np.max(np.abs(new - h)) < 1e-15
        h = new
        if done:
            break
    mu = np.atleast_1d(np.asarray(mu, dtype=float))
    out = 1.0 / (math.sqrt(1 - w) + 0.5 * w * np.sum(wt * nodes * h / (mu[:, None] + nodes), axis=1))
    # the zeroth moment identity Int_0^1 H = 2 (1 - sqrt(1 - w)) / w checks the iteration
    assert np.sum(wt * h) == pytest.approx(2 * (1 - math.sqrt(1 - w)) / w, rel=1e-9)
    return out


def plane_albedo(w: float, mu0) -> np.ndarray:
    """Plane albedo of a semi-infinite isotropic medium (no Fresnel): 1 - H(mu0) sqrt(1 - w)."""
    return 1.0 - h_function(w, mu0) * math.sqrt(1.0 - w)


def _check_half_space(albedos, tau, rays, thetas=(0.0, 60.0)):
    """The slab's reflectance R brackets the half-space albedo A: R <= A <= R + U, where U bounds
    what the half-space below depth tau would send back up: U <= A_max T / (1 - A_max^2), with T
    the slab's transmittance (the flux crossing depth tau for the first time) and
    A_max = 1 - sqrt(1 - w) the largest plane albedo (grazing; it also bounds the slab's
    reflectance from below)."""
    r = simulate(matched(Medium((tau,) * 3, albedos, 0.0)),
                 SimulationSettings(incident_deg=thetas, rays=rays, resolution=(9, 18), seed=31))
    for c, w in enumerate(albedos):
        ref = plane_albedo(w, np.cos(np.radians(thetas)))
        a_max = 1.0 - math.sqrt(1.0 - w)
        refl, se = r.energy["reflected"][:, c], r.energy_stderr["reflected"][:, c]
        u = a_max * r.energy["transmitted"][:, c] / (1.0 - a_max**2)
        rr = np.abs(r.roulette[:, c])
        assert np.all(refl - Z_TOL * se - rr <= ref), (w, refl, ref)
        assert np.all(ref <= refl + u + Z_TOL * se + rr), (w, refl, u, ref)
    return r


def test_semi_infinite_isotropic_medium_matches_h_function():
    """Absorbing isotropic media (w = 0.3, 0.6, 0.9, one per channel), tau = 10: the H-function
    albedo within the bracket of ``_check_half_space`` (T(0.9) ~ 0.006, so U is ~1 % of A)."""
    _check_half_space((0.3, 0.6, 0.9), 10.0, 400_000)


@pytest.mark.slow
def test_semi_infinite_weakly_absorbing_medium_matches_h_function():
    """The same at w = 0.95, 0.98, 0.99 with tau = 30 (hundreds of collisions per path)."""
    _check_half_space((0.95, 0.98, 0.99), 30.0, 1_000_000, thetas=(0.0, 45.0, 75.0))


@pytest.mark.slow
def test_thick_conservative_forward_scattering_slab_keeps_every_path_whole():
    r = simulate(matched(Medium((30.0,) * 3, (1.0,) * 3, 0.9)),
                 SimulationSettings(incident_deg=(0.0, 60.0), rays=100_000, resolution=(9, 18)))
    assert np.all(r.energy["absorbed"] == 0) and np.all(r.roulette == 0) and np.all(r.capped == 0)
    np.testing.assert_allclose(r.energy["reflected"] + r.energy["transmitted"], 1.0, rtol=0, atol=1e-12)


# ----------------------------------------------------------------------------- channels


def test_chromatic_extinction_equals_one_channel_at_a_time():
    """Spectral MIS is unbiased per channel: each channel of a chromatic medium (tau = 0.5, 1, 2)
    reflects, transmits and absorbs what an achromatic medium of that channel's tau does
    (independent runs, Z_TOL combined standard errors), below a rough coat of index 1.5."""
    taus = (0.5, 1.0, 2.0)

    def stack(t):
        return Stack("c", (Interface(0.2, (1.5,) * 3), Medium(t, (0.8,) * 3, 0.3), Interface(0.0, (1.0,) * 3)))

    s = dict(incident_deg=(0.0, 60.0), rays=150_000, resolution=(9, 18))
    chrom = simulate(stack(taus), SimulationSettings(seed=1, **s))
    for c, t in enumerate(taus):
        one = simulate(stack((t,) * 3), SimulationSettings(seed=2 + c, **s))
        for k in ("reflected", "transmitted", "absorbed"):
            assert_z_close(chrom.energy[k][:, c], chrom.energy_stderr[k][:, c],
                           one.energy[k][:, c], one.energy_stderr[k][:, c],
                           extra=np.abs(chrom.roulette[:, c]) + np.abs(one.roulette[:, c]))


def test_a_channel_without_scattering_is_beer_lambert():
    """A channel of albedo 0 in a scattering medium never returns (R = 0 exactly) and transmits
    exp(-tau/mu) in expectation; a channel of optical depth 0 transmits everything in expectation
    and is never reflected either."""
    r = simulate(matched(Medium((0.5, 1.0, 0.0), (0.0, 0.8, 0.8), 0.2)),
                 SimulationSettings(incident_deg=(0.0, 60.0), rays=200_000, resolution=(9, 18), seed=4))
    mu = np.cos(np.radians(r.theta_deg))
    assert np.all(r.energy["reflected"][:, 0] == 0) and np.all(r.energy["reflected"][:, 2] == 0)
    for c, ref in ((0, np.exp(-0.5 / mu)), (2, np.ones_like(mu))):
        assert_z_close(r.energy["transmitted"][:, c], r.energy_stderr["transmitted"][:, c], ref,
                       extra=np.abs(r.roulette[:, c]))


# ----------------------------------------------------------------------------- reciprocity, g -> 0


def test_scattering_brdf_is_reciprocal():
    """f(l, v) = f(v, l) for a rough coat over a chromatic scattering medium over a Lambertian
    base: slices at 21 and 51 deg compared at the reciprocal cells column by column, chi-square
    over cells both slices hit (as tests/goniometer/test_tracer.py does for the plastic)."""
    st = Stack("r", (Interface(0.3, (1.5,) * 3), Medium((0.5, 1.0, 2.0), (0.9, 0.7, 0.5), 0.5),
                     Lambertian((0.5,) * 3)))
    r = simulate(st, SimulationSettings(incident_deg=(21.0, 51.0), rays=1_500_000, resolution=(45, 90), seed=4))
    a, sa = r.brdf.value[0][:, 25, :], r.brdf.stderr[0][:, 25, :]
    b, sb = r.brdf.value[1][:, 10, :], r.brdf.stderr[1][:, 10, :]
    assert_samples_match(a, sa, b, sb, (sa > 0) & (sb > 0), min_cells=201)


def test_tiny_g_is_isotropic_scattering():
    """g = 1e-6 and g = 0 (independent seeds) give the same slices within noise: a two-sample
    chi-square over the cells both hit, and energies within Z_TOL combined standard errors."""
    s = dict(incident_deg=(0.0, 60.0), rays=300_000, resolution=(18, 36))
    runs = [simulate(Stack("g", (Interface(0.2, (1.5,) * 3), Medium((1.0, 1.5, 2.0), (0.9,) * 3, g),
                                 Interface(0.0, (1.0,) * 3))), SimulationSettings(seed=seed, **s))
            for g, seed in ((0.0, 1), (1e-6, 2))]
    a, b = runs
    for sa_, sb_ in ((a.brdf, b.brdf), (a.btdf, b.btdf)):
        sel = (sa_.stderr > 0) & (sb_.stderr > 0) & (sa_.value > 0) & (sb_.value > 0)
        assert_samples_match(sa_.value, sa_.stderr, sb_.value, sb_.stderr, sel, min_cells=501)
    for k in ("reflected", "transmitted", "absorbed"):
        assert_z_close(a.energy[k], a.energy_stderr[k], b.energy[k], b.energy_stderr[k],
                       extra=np.abs(a.roulette) + np.abs(b.roulette))


# ----------------------------------------------------------------------------- determinism


def test_same_seed_same_bits_whatever_the_threads():
    st = SCATTER_STACKS["slab"]
    base = dict(incident_deg=(10.0, 70.0), rays=40_000, resolution=(9, 18), chunk_rays=4096, seed=77)
    one = simulate(st, SimulationSettings(threads=1, **base))
    two = simulate(st, SimulationSettings(threads=2, **base))
    for x, y in ((one.brdf, two.brdf), (one.btdf, two.btdf)):
        np.testing.assert_array_equal(x.orders, y.orders)
        np.testing.assert_array_equal(x.stderr, y.stderr)
    for k in one.energy:
        np.testing.assert_array_equal(one.energy[k], two.energy[k])
    np.testing.assert_array_equal(one.mean_events, two.mean_events)


# ----------------------------------------------------------------------------- the command line

GOOD = """name = "s"
[[layers]]
type = "interface"
roughness = 0.0
ior = 1.0
[[layers]]
type = "medium"
optical_depth = [0.4, 0.4, 2.2]
scattering_albedo = [0.5, 0.5, 0.9090909090909091]
g = 0.6
[[layers]]
type = "interface"
roughness = 0.2
ior = 1.5
extinction = [3.0, 0.0, 0.0]
[simulation]
incident_deg = [0, 45]
rays = 3000
resolution = [9, 18]
"""

BAD = [
    (GOOD.replace("g = 0.6", "g = 1.0"), "layers[1].g: 1.0 is outside (-1, 1)"),
    (GOOD.replace("g = 0.6", "g = -1.5"), "layers[1].g: -1.5 is outside (-1, 1)"),
    (GOOD.replace("g = 0.6", 'g = "forward"'), "layers[1].g: 'forward' is not a number"),
    (GOOD.replace("g = 0.6", "g = [0.1, 0.2, 0.3]"), "layers[1].g: [0.1, 0.2, 0.3] is not a number"),
    (GOOD.replace("[0.5, 0.5, 0.9090909090909091]", "1.5"), "layers[1].scattering_albedo: 1.5 is outside [0.0, 1.0]"),
    (GOOD.replace("[0.5, 0.5, 0.9090909090909091]", "[0.5, -0.1, 0.5]"),
     "layers[1].scattering_albedo: -0.1 is outside"),
    (GOOD.replace("ior = 1.0\n", "ior = 1.0\ng = 0.3\n"), "layers[0].g: only a medium layer takes g"),
    (GOOD.replace("extinction = [3.0, 0.0, 0.0]", "extinction = [3.0, 0.0, 0.0]\nscattering_albedo = 0.5"),
     "layers[2].scattering_albedo: only a medium layer takes scattering_albedo"),
]


@pytest.mark.parametrize("text, expected", BAD)
def test_bad_scattering_input_is_one_line_exit_2(tmp_path, capsys, text, expected):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(text)
    out = tmp_path / "out.h5"
    assert main(["simulate", str(cfg), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("gonio: error: ") and expected in err and "\n" not in err, err
    assert not out.exists()


def test_the_example_is_appendix_e_at_d_2():
    """configs/examples/scattering-metal.toml: sigma_s = (0.1, 0.1, 1.0), sigma_a = 0.1, d = 2."""
    stack, _ = load_toml(Path(__file__).resolve().parents[2] / "configs" / "examples" / "scattering-metal.toml")
    sigma_s, sigma_a, d = np.array([0.1, 0.1, 1.0]), 0.1, 2.0
    medium = stack.layers[1]
    np.testing.assert_allclose(medium.optical_depth, (sigma_s + sigma_a) * d, rtol=1e-15)
    np.testing.assert_allclose(medium.scattering_albedo, sigma_s / (sigma_s + sigma_a), rtol=1e-15)
    assert stack.layers[1:] == stack_from_dict(tomllib.loads(GOOD)).layers[1:]


def test_the_file_records_the_scattering_medium(tmp_path, capsys):
    """Appendix E's medium at d = 2 (see docs/material-format.md): gonio simulate, then gonio info
    shows the layer parameters from the file's canonical stack."""
    cfg = tmp_path / "s.toml"
    cfg.write_text(GOOD)
    out = tmp_path / "s.h5"
    assert main(["simulate", str(cfg), "--out", str(out)]) == 0
    capsys.readouterr()
    assert main(["info", str(out), "--json"]) == 0
    layer = json.loads(capsys.readouterr().out)["material"]["config"]["layers"][1]
    assert layer == {"type": "medium", "optical_depth": [0.4, 0.4, 2.2],
                     "scattering_albedo": [0.5, 0.5, 0.9090909090909091], "g": 0.6}
    assert main(["info", str(out)]) == 0
    assert '"scattering_albedo": [0.5, 0.5, 0.9090909090909091]' in capsys.readouterr().out


def test_deep_chromatic_medium_standard_errors_match_replicates():
    """Bati 2019 appendix E at d = 8 (optical depths 1.6, 1.6, 8.8; blue albedo 0.91): the reported
    standard error of the reflected energy matches the scatter of 24 independent seeds (the
    ratio of variances within a two-sided chi-square band at P_FALSE_ALARM)."""
    stack = Stack("e", (Interface(0.0, (1.0,) * 3),
                        Medium((1.6, 1.6, 8.8), (0.5, 0.5, 1.0 / 1.1), 0.3),
                        Interface(0.2, (1.5,) * 3, (3.0, 0.0, 0.0))), "metal")
    k = 24
    runs = [simulate(stack, SimulationSettings(incident_deg=(30.0,), rays=8_000, resolution=(9, 18), seed=s))
            for s in range(1, k + 1)]
    r = np.array([x.energy["reflected"][0] for x in runs])
    se = np.array([x.energy_stderr["reflected"][0] for x in runs])
    ratio = r.var(axis=0, ddof=1) / np.mean(se ** 2, axis=0)
    lo, hi = (x / (k - 1) for x in chi2_interval(k - 1))
    assert np.all((ratio > lo) & (ratio < hi)), (ratio, lo, hi)
