"""Thin-film optics (``goniometer.optics.film_rt``, ``docs/material-format.md``, thin films)
against the transfer-matrix package ``tmm`` (Byrnes): reflectance and transmittance of a film
between two media, s and p averaged, for dielectric and conductor substrates, absorbing and
non-absorbing films, from above and from below; the limits (thickness 0: the bare Fresnel terms;
a non-absorbing film conserves energy; total internal reflection; grazing incidence)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from goniometer import optics

tmm = pytest.importorskip("tmm")

ANGLES = (0.0, 30.0, 60.0, 80.0)
WAVELENGTHS = (400.0, 475.0, 550.0, 625.0, 700.0)
THICKNESSES = (10.0, 120.0, 350.0, 1500.0)
#: (region above n1, film nf + i kf, below n3 + i k3)
SYSTEMS = {
    "soap-on-glass": (1.0, 1.33 + 0.0j, 1.5 + 0.0j),
    "absorbing-film-on-glass": (1.0, 2.0 + 0.3j, 1.5 + 0.0j),
    "film-under-coat": (1.5, 1.38 + 0.0j, 1.7 + 0.0j),
    "oxide-on-metal": (1.0, 1.46 + 0.0j, 0.2 + 3.5j),
    "absorbing-film-on-metal": (1.5, 1.8 + 0.05j, 1.1 + 2.0j),
    "soap-bubble": (1.0, 1.33 + 0.0j, 1.0 + 0.0j),
}


def _tmm(n_list, d, theta, lam):
    r = [tmm.coh_tmm(pol, n_list, [np.inf, d, np.inf], theta, lam) for pol in "sp"]
    return 0.5 * (r[0]["R"] + r[1]["R"]), 0.5 * (r[0]["T"] + r[1]["T"])


def _ours(n1, nf, n3, d, theta, lam):
    return optics.film_rt(math.cos(theta), n1, nf.real, nf.imag, n3.real, n3.imag, d / lam)


@pytest.mark.parametrize("name", sorted(SYSTEMS))
def test_from_above_matches_tmm(name):
    n1, nf, n3 = SYSTEMS[name]
    for deg in ANGLES:
        th = math.radians(deg)
        for d in THICKNESSES:
            for lam in WAVELENGTHS:
                r0, t0 = _tmm([n1, nf, n3], d, th, lam)
                r, t = _ours(n1, nf, n3, d, th, lam)
                assert abs(r - r0) < 1e-10, (name, deg, d, lam, r, r0)
                assert abs(t - t0) < 1e-10, (name, deg, d, lam, t, t0)


@pytest.mark.parametrize("name", [n for n in sorted(SYSTEMS) if SYSTEMS[n][2].imag == 0.0])
def test_from_below_matches_tmm_reversed(name):
    """Light travelling up in a dielectric substrate: the same film, the list reversed (total
    internal reflection included: 60 and 80 degrees in glass)."""
    n1, nf, n3 = SYSTEMS[name]
    below = n3.real
    for deg in ANGLES:
        th = math.radians(deg)
        for d in THICKNESSES:
            for lam in WAVELENGTHS:
                r0, t0 = _tmm([below, nf, n1], d, th, lam)
                r, t = optics.film_rt(math.cos(th), below, nf.real, nf.imag, n1, 0.0, d / lam)
                assert abs(r - r0) < 1e-10, (name, deg, d, lam, r, r0)
                assert abs(t - t0) < 1e-10, (name, deg, d, lam, t, t0)


def test_thickness_zero_is_the_bare_interface():
    for c in np.linspace(0.0, 1.0, 41):
        for n1, n3 in ((1.0, 1.5), (1.5, 1.0), (1.0, 1.0), (1.33, 1.7)):
            if c == 0.0 and n1 == n3:
                continue  # grazing on an index-matched interface: the bare Fresnel's convention is 0
            r, t = optics.film_rt(c, n1, 1.9, 0.2, n3, 0.0, 0.0)
            f = optics.fresnel_dielectric(c, n3 / n1)
            assert abs(r - f) < 1e-13 and abs(t - (1.0 - f)) < 1e-13, (c, n1, n3, r, t, f)
        for eta, kappa in ((0.2, 3.5), (1.1, 2.0), (1.45, 0.01)):
            r, _ = optics.film_rt(c, 1.0, 1.4, 0.0, eta, kappa, 0.0)
            assert abs(r - optics.fresnel_conductor(c, eta, kappa)) < 1e-13, (c, eta, kappa)


def test_non_absorbing_film_conserves_energy():
    rng = np.random.default_rng(3)
    for _ in range(2000):
        c = rng.uniform(0.0, 1.0)
        n1, nf, n3 = rng.uniform(1.0, 2.5, 3)
        r, t = optics.film_rt(c, n1, nf, 0.0, n3, 0.0, rng.uniform(0.0, 5.0))
        assert 0.0 <= r <= 1.0 + 1e-12 and 0.0 <= t <= 1.0 + 1e-12
        assert abs(r + t - 1.0) < 1e-12, (c, n1, nf, n3, r, t)


def test_absorbing_film_absorbs():
    for c in np.linspace(0.05, 1.0, 20):
        r, t = optics.film_rt(c, 1.0, 2.0, 0.3, 1.5, 0.0, 0.5)
        assert r + t < 1.0 - 1e-3


def test_total_internal_reflection_and_grazing():
    # from glass into air beyond the critical angle: R = 1, T = 0 whatever the (clear) film
    for c in (0.0, 0.3, 0.55):
        for nf in (1.2, 1.33, 1.7):
            r, t = optics.film_rt(c, 1.5, nf, 0.0, 1.0, 0.0, 0.37)
            assert t == 0.0 and abs(r - 1.0) < 1e-13, (c, nf, r, t)
    r, t = optics.film_rt(0.0, 1.0, 1.33, 0.0, 1.5, 0.0, 0.37)
    assert t == 0.0 and abs(r - 1.0) < 1e-13
    # the film's own critical angle (q2 = 0: the Airy sum's 0 / 0) gives its limit
    c = math.sqrt(1.0 - (1.2 / 1.5) ** 2)
    lo = optics.film_rt(c * (1 - 1e-6), 1.5, 1.2, 0.0, 1.7, 0.0, 0.3)
    at = optics.film_rt(c, 1.5, 1.2, 0.0, 1.7, 0.0, 0.3)
    assert all(math.isfinite(x) for x in at) and abs(at[0] - lo[0]) < 1e-4 and abs(at[1] - lo[1]) < 1e-4


def test_channel_form_is_film_rt():
    rng = np.random.default_rng(5)
    for _ in range(500):
        args = (rng.uniform(0, 1), rng.uniform(1, 2), rng.uniform(1, 2.5), rng.uniform(0, 0.5), rng.uniform(0.1, 2),
                rng.uniform(0, 4), rng.uniform(0, 3))
        a = optics.film_rt(*args)
        b = optics.film_rt_channel(*args)
        assert abs(a[0] - b[0]) < 1e-14 and abs(a[1] - b[1]) < 1e-14
