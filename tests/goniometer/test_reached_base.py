"""The per-path record of light that never reached the base (``reflected_without_base``,
``docs/slices-format.md``, ``/energy``), against exact identities, a closed form (Fresnel) and an
independent simulation (the same medium over a black base)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from goniometer.run.loop import simulate
from goniometer.run.settings import SimulationSettings
from goniometer.stack import Interface, Lambertian, Medium, Stack
from goniometer.files.slices import read, write
from goniometer.testing import Z_TOL

SETTINGS = SimulationSettings(incident_deg=(0.0, 45.0, 75.0), rays=60_000, resolution=(9, 18), seed=5)
MEDIUM = Medium((0.6, 0.6, 1.5), (0.5, 0.5, 0.8), 0.6)
MATCHED = Interface(0.0, (1.0,) * 3)


def fresnel_unpolarised(cos_i: float, eta: float) -> float:
    """Fresnel reflectance of a smooth dielectric seen from the side of index 1, written out."""
    sin_t2 = (1.0 - cos_i * cos_i) / (eta * eta)
    cos_t = math.sqrt(1.0 - sin_t2)
    rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    return 0.5 * (rs * rs + rp * rp)


def test_one_interface_is_its_own_base():
    r = simulate(Stack("metal", (Interface(0.3, (0.2, 0.9, 1.1), (3.0, 2.5, 2.0)),)), SETTINGS)
    assert np.all(r.reflected_without_base == 0.0)
    assert np.all(r.energy["reflected"] > 0.3)


def test_everything_a_black_base_reflects_never_reached_it():
    """Over a black Lambertian every path that reaches the base ends there, and in a slab every path
    that reaches the bottom leaves downward: in both, the record equals the reflected energy, bit
    for bit."""
    for stack in (Stack("black", (MATCHED, MEDIUM, Lambertian((0.0,) * 3))),
                  Stack("slab", (MATCHED, MEDIUM, MATCHED))):
        r = simulate(stack, SETTINGS)
        np.testing.assert_array_equal(r.reflected_without_base, r.energy["reflected"])
        np.testing.assert_array_equal(r.reflected_without_base_stderr, r.energy_stderr["reflected"])
        assert np.all(r.reflected_without_base > 0.01)


def test_a_smooth_coat_sends_back_only_its_fresnel_reflection_without_the_base():
    """Smooth dielectric coat over a Lambertian: the only light that leaves without reaching the base
    is the coat's specular reflection, F(theta) by the Fresnel equations."""
    r = simulate(Stack("plastic", (Interface(0.0, (1.5,) * 3), Lambertian((0.8, 0.5, 0.2)))), SETTINGS)
    for m, theta in enumerate(SETTINGS.incident_deg):
        f = fresnel_unpolarised(math.cos(math.radians(theta)), 1.5)
        got, se = r.reflected_without_base[m], r.reflected_without_base_stderr[m]
        assert np.all(se > 0)
        assert np.all(np.abs(got - f) <= Z_TOL * se), (theta, got, f, se)
        # the rest of the reflection reached the base (and is coloured by it)
        assert np.all(r.energy["reflected"][m] - got > 0.05)


def test_light_that_turns_around_in_the_medium_matches_a_black_base_run():
    """Over a conductor, what never reached the base has the same expectation as all that a black
    base reflects (the paths are the same until they reach the base): two independent runs."""
    metal = simulate(Stack("metal", (MATCHED, MEDIUM, Interface(0.2, (1.5,) * 3, (3.0, 0.0, 0.0)))), SETTINGS)
    black = simulate(Stack("black", (MATCHED, MEDIUM, Lambertian((0.0,) * 3))),
                     replace(SETTINGS, seed=99))
    a, sa = metal.reflected_without_base, metal.reflected_without_base_stderr
    b, sb = black.energy["reflected"], black.energy_stderr["reflected"]
    assert np.all(np.abs(a - b) <= Z_TOL * np.hypot(sa, sb)), (a, b)
    assert np.all(a < metal.energy["reflected"])


def test_the_record_is_written_and_read_back(tmp_path):
    r = simulate(Stack("black", (MATCHED, MEDIUM, Lambertian((0.3,) * 3))), SETTINGS)
    p = tmp_path / "r.h5"
    write(p, r)
    back = read(p)
    np.testing.assert_array_equal(back.reflected_without_base, r.reflected_without_base)
    np.testing.assert_array_equal(back.reflected_without_base_stderr, r.reflected_without_base_stderr)
