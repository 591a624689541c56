"""The smooth-stack oracles themselves, against brute-force sums and hand values."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate

from goniometer import optics
from goniometer.testing import smooth
from goniometer.stack import Interface, Lambertian, Medium, Stack


def test_single_interface_is_fresnel():
    st = Stack("g", (Interface(0.0, (1.5,) * 3),))
    for t in (0.0, 45.0, 80.0):
        R, T = smooth.adding_energies(st, t)
        f = optics.fresnel_dielectric(math.cos(math.radians(t)), 1.5)
        np.testing.assert_allclose(R, f, rtol=1e-14)
        np.testing.assert_allclose(R + T, 1.0, rtol=1e-14)


def test_coated_conductor_against_explicit_bounce_series():
    """Sum the paths bounce by bounce (air -> coat -> base -> ... -> air) explicitly."""
    st = Stack("cc", (Interface(0.0, (1.5,) * 3), Medium((0.1, 0.3, 0.0)), Interface(0.0, (1.45, 1.2, 0.9), (1.0, 0.5, 2.0))))
    for t in (0.0, 40.0, 75.0):
        c0 = math.cos(math.radians(t))
        c1 = math.sqrt(1 - (1 - c0 * c0) / 2.25)
        r01 = optics.fresnel_dielectric(c0, 1.5)
        r10 = optics.fresnel_dielectric(c1, 1 / 1.5)
        rb = np.array([optics.fresnel_conductor(c1, e / 1.5, k / 1.5) for e, k in zip((1.45, 1.2, 0.9), (1.0, 0.5, 2.0))])
        a = np.exp(-np.array([0.1, 0.3, 0.0]) / c1)
        total = np.full(3, r01)
        inside = (1 - r01) * np.ones(3)
        for _ in range(500):
            inside = inside * a * rb * a
            total += inside * (1 - r10)
            inside = inside * r10
        R, T = smooth.adding_energies(st, t)
        np.testing.assert_allclose(R, total, rtol=1e-12)
        assert np.all(T == 0)


def test_lossless_slab_conserves_energy():
    st = Stack("s", (Interface(0.0, (1.5,) * 3), Interface(0.0, (1.2,) * 3), Interface(0.0, (1.0,) * 3)))
    for t in (0.0, 50.0, 85.0):
        R, T = smooth.adding_energies(st, t)
        np.testing.assert_allclose(R + T, 1.0, rtol=1e-13)
    # absorbing: strictly less, and the thicker the less transmitted
    a = smooth.adding_energies(Stack("a", (Interface(0.0, (1.5,) * 3), Medium((0.1,) * 3), Interface(0.0, (1.0,) * 3))), 30)
    b = smooth.adding_energies(Stack("b", (Interface(0.0, (1.5,) * 3), Medium((0.5,) * 3), Interface(0.0, (1.0,) * 3))), 30)
    assert np.all(a[0] + a[1] < 1) and np.all(b[1] < a[1])


def test_internal_reflectance_hand_values():
    # no absorption, n = 1.5: the classic internal diffuse reflectance ~ 0.596 (1 - (1 - r_e)/n^2 with
    # the external diffuse reflectance r_e ~ 0.0918 for n = 1.5: Egan & Hilgeman)
    ri = smooth.internal_diffuse_reflectance(1.5, 0.0)
    re = integrate.quad(lambda mu: 2 * mu * optics.fresnel_dielectric(mu, 1.5), 0, 1, epsabs=1e-13)[0]
    np.testing.assert_allclose(ri, 1 - (1 - re) / 1.5**2, rtol=1e-9)
    assert re == pytest.approx(0.0918, abs=5e-4)
    np.testing.assert_allclose(smooth.internal_diffuse_reflectance(1.0, 0.0), 0.0, atol=1e-15)
    np.testing.assert_allclose(smooth.coat_escape(1.5, 0.0) + smooth.internal_diffuse_reflectance(1.5, 0.0), 1.0, rtol=1e-9)


def test_coated_lambertian_albedo_is_the_integral_of_its_brdf():
    st = Stack("p", (Interface(0.0, (1.5,) * 3), Medium((0.05, 0.1, 0.4)), Lambertian((0.2, 0.5, 0.8))))
    for t in (0.0, 60.0):
        cl = math.cos(math.radians(t))
        x, w = np.polynomial.legendre.leggauss(400)
        mu = 0.5 * (x + 1)
        f = smooth.coated_lambertian_brdf(st, cl, mu)
        integral = 2 * math.pi * np.sum(f * (0.5 * w * mu)[:, None], axis=0)
        np.testing.assert_allclose(integral, smooth.coated_lambertian_albedo(st, cl), rtol=1e-6)
    with pytest.raises(ValueError):
        smooth.adding_energies(st, 0.0)


# ---------------------------------------------------------------------- polarized adding

def _inc_tmm(stack_n: list, theta_deg: float, tau: float, lam: float = 500.0, d: float = 1e5) -> dict:
    """tmm's incoherent transfer matrices (an independent code): the slab's R and T per polarization,
    its absorption as an index ``n + i k`` with ``exp(-4 pi k d / (lambda cos)) = exp(-tau / cos)``."""
    import tmm
    k = tau * lam / (4 * math.pi * d)
    n = [stack_n[0], complex(stack_n[1], k), stack_n[2]]
    return {pol: tmm.inc_tmm(pol, n, [np.inf, d, np.inf], ["i", "i", "i"], math.radians(theta_deg), lam)
            for pol in "sp"}


@pytest.mark.parametrize("theta", [0.0, 30.0, 56.31, 70.0, 80.0, 89.0])
@pytest.mark.parametrize("tau", [0.0, 1.0])
def test_the_polarized_adding_of_a_slab_is_tmm_and_the_scalar_adding_is_not(theta, tau):
    """A smooth slab between air and air: s and p added separately (tmm's incoherent layers) against
    adding_mueller; the scalar adding (every event unpolarized, what a scalar tracer computes) differs
    off the normal by more than the agreement."""
    slab = Stack("slab", (Interface(0.0, (1.5,) * 3), Medium((tau,) * 3), Interface(0.0, (1.0,) * 3)), "slab")
    R, T = smooth.adding_mueller(slab, theta)
    ref = _inc_tmm([1.0, 1.5, 1.0], theta, tau)
    # the absorbing index tmm needs moves its interface Fresnel terms by ~k^2 ~ 1e-14; 1e-7 covers
    # its own quadrature of the thick layer
    for side, M in (("R", R), ("T", T)):
        s, p = ref["s"][side], ref["p"][side]
        assert M[0] == pytest.approx(0.5 * (s + p), abs=1e-7)
        assert M[1] == pytest.approx(0.5 * (s - p), abs=1e-7)
    scalar_R, scalar_T = smooth.adding_energies(slab, theta)
    gap = max(abs(scalar_R[0] - R[0, 0]), abs(scalar_T[0] - T[0, 0]))
    assert gap < 1e-12 if theta == 0.0 else gap > 1e-4
    # an incoherent sum of paths depolarizes partly: c^2 + s^2 <= a^2 - b^2, equal for one path
    for M in (R, T):
        assert np.all(M[2] ** 2 + M[3] ** 2 <= (M[0] + M[1]) * (M[0] - M[1]) + 1e-15)


def test_the_polarized_adding_over_a_conductor_has_retardance():
    """A clear coat over a metal: the cross term of the reflection is complex (the metal's phase)."""
    coat = Stack("coat", (Interface(0.0, (1.5,) * 3), Medium((0.0,) * 3),
                          Interface(0.0, (0.2,) * 3, (3.0,) * 3)), "metal")
    R, T = smooth.adding_mueller(coat, 60.0)
    assert not T.any() and abs(R[3, 0]) > 1e-3 and np.allclose(R[:, 0], R[:, 2])
    # a metal under a smooth clear coat reflects as polarized light as it receives: no loss but absorption
    assert np.all(R[2] ** 2 + R[3] ** 2 <= (R[0] + R[1]) * (R[0] - R[1]) + 1e-15)
