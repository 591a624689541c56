"""The models' directional albedo quadrature (models.compare.albedo) against closed forms: a
Lambertian integrates to its albedo, a nearly smooth dielectric's microfacet BRDF and BTDF to the
Fresnel reflectance and transmittance, and a rough single-scattering conductor to an independent
Monte Carlo estimate of its albedo; the rule converges where the microfacet BTDF jumps."""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest

from goniometer import optics
from goniometer.grids.slice_grid import light_direction
from goniometer.stack import Interface, Lambertian, Stack
from models import registry
from models.base import Model, ModelValue
from models.compare.albedo import (directional_albedo, graded_breakpoints, hemisphere_rule, smooth_interface,
                                   transmission_horizon)

from goniometer.testing import Z_TOL


class Constant(Model):
    """f = rho / pi on both sides (a test model: its albedo per side is rho exactly)."""

    name = "constant"
    sides = ("brdf", "btdf")

    def __init__(self, rho):
        self.rho = np.asarray(rho, dtype=float)

    def support_reason(self, stack):
        return None

    def _evaluate(self, stack, l, v, side):
        f = np.broadcast_to(self.rho / math.pi, v.shape[:-1] + (3,)).copy()
        return ModelValue(np.zeros_like(f), f)


class Microfacet(Model):
    """The single-scattering microfacet BSDF of the stack's one interface (goniometer.optics:
    Walter 2007 BRDF and flux-based BTDF, separable masking)."""

    name = "microfacet"
    sides = ("brdf", "btdf")

    def support_reason(self, stack):
        return None

    def _evaluate(self, stack, l, v, side):
        x = stack.layers[0]
        a = x.roughness
        L = np.broadcast_to(l, v.shape)
        args = (L[..., 0], L[..., 1], L[..., 2], v[..., 0], v[..., 1], v[..., 2], a, a)
        if side == "brdf":
            f = optics.np_microfacet_reflection(*args, x.ior[0], x.extinction[0], False)
        else:
            f = optics.np_microfacet_transmission(*args, x.ior[0], False)
        f = np.repeat(f[..., None], 3, axis=-1)
        return ModelValue(np.zeros_like(f), f)


THETAS = (0.0, 30.0, 60.0, 75.0, 85.0)


def test_rule_weights_integrate_the_cosine_exactly():
    # Int |cos| d omega over a hemisphere = pi, on either side, however the rule is graded
    for side in ("brdf", "btdf"):
        for centre in (0.0, 0.3, 1.5):
            rule = hemisphere_rule(centre, 2.0, 1e-4, side)
            assert abs(rule.weights.sum() - math.pi) < 1e-12
            assert np.allclose(np.linalg.norm(rule.directions, axis=1), 1.0)
            assert np.all(rule.directions[:, 2] > 0) if side == "brdf" else np.all(rule.directions[:, 2] < 0)


def test_breakpoints_are_graded_and_bounded():
    b = graded_breakpoints(0.0, 1.5, 0.7, 1e-3, 0.2, extra=(0.123,))
    assert b[0] == 0.0 and b[-1] == 1.5 and np.all(np.diff(b) > 0) and np.max(np.diff(b)) <= 0.2 + 1e-12
    assert 0.7 in b and 0.123 in b and np.isclose(np.min(np.abs(b - 0.7 - 1e-3)), 0.0)


@pytest.mark.parametrize("theta", THETAS)
def test_lambertian_integrates_to_its_albedo(theta):
    rho = np.array([0.2, 0.5, 1.0])
    stack = Stack("lambert", (Lambertian(tuple(rho)),))
    l = light_direction(theta, 20.0)
    for side in ("brdf", "btdf"):
        np.testing.assert_allclose(directional_albedo(Constant(rho), stack, l, side), rho, atol=1e-13)
    # a registered model of a bare Lambertian: multilayer-lut
    np.testing.assert_allclose(directional_albedo(registry.get("multilayer-lut"), stack, l, "brdf"), rho, atol=1e-12)


@pytest.mark.parametrize("theta", THETAS)
def test_nearly_smooth_dielectric_gives_fresnel(theta):
    # the alpha -> 0 limit of the microfacet BSDF: E_brdf -> F(theta), E_btdf -> 1 - F(theta).
    # At alpha = 1e-4 the lobes are ~2e-4 rad wide; the deviation from the limit is
    # O(alpha^2 / cos^2 theta) <= 1.3e-6 here, a rule that missed a lobe would be off by O(F).
    stack = Stack("glass", (Interface(1e-4, (1.5,) * 3),))
    l = light_direction(theta)
    F = optics.fresnel_dielectric(math.cos(math.radians(theta)), 1.5)
    R = directional_albedo(Microfacet(), stack, l, "brdf")
    T = directional_albedo(Microfacet(), stack, l, "btdf")
    np.testing.assert_allclose(R, F, atol=1e-5)
    np.testing.assert_allclose(T, 1.0 - F, atol=1e-5)


@pytest.mark.parametrize("theta", (30.0, 60.0, 85.0))
def test_rough_btdf_converges_across_its_jump(theta):
    # the microfacet BTDF jumps where its generalized half vector reaches the horizon; with a
    # panel end there, doubling the Gauss-Legendre order changes the albedo by < 1e-6
    stack = Stack("glass", (Interface(0.3, (1.5,) * 3),))
    l = light_direction(theta)
    (t,) = transmission_horizon(stack, l)
    assert abs(math.cos(t) - l[2] / 1.5) < 1e-12
    a8 = directional_albedo(Microfacet(), stack, l, "btdf", order=8)
    a16 = directional_albedo(Microfacet(), stack, l, "btdf", order=16)
    np.testing.assert_allclose(a8, a16, atol=1e-6)


@numba.njit(cache=True)
def _vndf_albedo(lx, ly, lz, a, n, seed):
    # single-scattering albedo of a GGX mirror (F = 1, separable masking) by sampling visible
    # normals: E = E_{h ~ D_l}[ G1(v) [v_z > 0] ], v the mirror of l about h; (mean, second moment)
    np.random.seed(seed)
    s1 = 0.0
    s2 = 0.0
    for _ in range(n):
        hx, hy, hz = optics.sample_vndf(lx, ly, lz, a, a, np.random.random(), np.random.random())
        vx, vy, vz = optics.reflect(lx, ly, lz, hx, hy, hz)
        if vz > 0.0:
            g = 1.0 / (1.0 + optics.ggx_lambda(vx, vy, vz, a, a))
            s1 += g
            s2 += g * g
    return s1 / n, s2 / n


@pytest.mark.parametrize("theta", (0.0, 60.0, 85.0))
def test_rough_mirror_matches_visible_normal_sampling(theta):
    stack = Stack("mirror", (Interface(0.3, (1e-9,) * 3, (1.0,) * 3),))
    l = light_direction(theta)
    n = 200_000
    mean, second = _vndf_albedo(l[0], l[1], l[2], 0.3, n, 7)
    se = math.sqrt(max(second - mean * mean, 0.0) / (n - 1))
    E = directional_albedo(Microfacet(), stack, l, "brdf")
    assert np.all(np.abs(E - mean) < Z_TOL * se), (E, mean, se)


def test_smooth_interfaces_are_named_unless_index_matched():
    assert smooth_interface(Stack("s", (Interface(0.0, (1.5,) * 3),))) == 0
    assert smooth_interface(Stack("s", (Interface(0.1, (1.5,) * 3), Interface(0.0, (1.5,) * 3)))) is None
    assert smooth_interface(Stack("s", (Interface(0.1, (1.5,) * 3), Interface(0.0, (1.2,) * 3)))) == 1
    assert smooth_interface(Stack("s", (Interface((0.0), (1.0,) * 3, (1.0,) * 3),))) == 0
