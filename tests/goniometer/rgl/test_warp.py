"""The sample-space warp against Mitsuba 3's continuous 2-D distribution (the one its and pbrt-v4's
``measured`` readers build from a file's ``vndf``), and the tracer's per-exit inversion against it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from goniometer.grids.warp import Warp2D, invert_point, pack_kernel_tables

mi = pytest.importorskip("mitsuba")


@pytest.fixture(scope="module", autouse=True)
def scalar_rgb():
    mi.set_variant("scalar_rgb")


def _table(rng, H=7, W=9):
    d = (rng.random((H, W)) + 0.05).astype(np.float32)
    d[2] = 0.0            # an empty row
    d[:, 0] *= 0.01       # a steep column
    return d


def test_invert_sample_and_pdf_are_mitsubas():
    rng = np.random.default_rng(1)
    d = _table(rng)
    ours = Warp2D.from_density(d.astype(np.float64))
    theirs = mi.MarginalContinuous2D0(d)
    x, y = rng.random(500), rng.random(500)
    ux, uy = ours.invert(x, y)
    u = rng.random((500, 2))
    sx, sy = ours.sample(u[:, 0], u[:, 1])
    for k in range(500):
        t = theirs.invert(mi.Point2f(x[k], y[k]))[0]
        assert abs(ux[k] - t[0]) < 1e-5 and abs(uy[k] - t[1]) < 1e-5      # float32 there
        p, pdf = theirs.sample(mi.Point2f(*u[k]))
        assert abs(sx[k] - p[0]) < 1e-4 and abs(sy[k] - p[1]) < 1e-4
        assert ours.pdf(np.array(p[0]), np.array(p[1])) == pytest.approx(pdf, rel=1e-4)
    # sample is invert's inverse
    bx, by = ours.invert(sx, sy)
    np.testing.assert_allclose(bx, u[:, 0], atol=1e-9)
    np.testing.assert_allclose(by, u[:, 1], atol=1e-9)


@pytest.mark.parametrize("isotropic", [True, False])
def test_the_tracers_inversion_finds_the_node_of_the_warps_u(isotropic):
    rng = np.random.default_rng(2)
    warp = Warp2D.from_density(_table(rng, 16, 24).astype(np.float64))
    phi_i = 0.7
    head, data, cum = pack_kernel_tables(warp, phi_i, isotropic)
    n = 12
    lt = math.radians(40.0)
    l = np.array([math.sin(lt) * math.cos(phi_i), math.sin(lt) * math.sin(phi_i), math.cos(lt)])
    hits = 0
    for _ in range(2000):
        v = rng.normal(size=3)
        v /= np.linalg.norm(v)
        r, c = invert_point(l[0], l[1], l[2], v[0], v[1], v[2], n, head, data, cum)
        if v[2] <= 0:
            assert (r, c) == (-1, -1)
            continue
        h = (l + v) / np.linalg.norm(l + v)
        theta = math.acos(min(1.0, h[2]))
        phi = math.atan2(h[1], h[0]) - (phi_i if isotropic else 0.0)
        y = ((phi + math.pi) / (2 * math.pi)) % 1.0
        ux, uy = warp.invert(np.array(math.sqrt(theta / (math.pi / 2))), np.array(y))
        assert (r, c) == (int(np.rint(uy * (n - 1))), int(np.rint(ux * (n - 1))))
        hits += 1
    assert hits > 800


def test_the_polynomial_atan2_is_libms_to_a_few_ulp():
    from goniometer.grids.warp import atan2_poly
    rng = np.random.default_rng(4)
    pts = np.concatenate([rng.normal(size=(20000, 2)), rng.normal(size=(2000, 2)) * 1e-9,
                          [[0.0, 1.0], [1.0, 0.0], [0.0, -1.0], [-1.0, 0.0], [1.0, 1.0], [-1.0, -1e-300],
                           [0.0, 0.0], [1e-300, -1.0]]])
    worst = max(abs(atan2_poly(y, x) - math.atan2(y, x)) for y, x in pts if not (y == 0.0 and x < 0))
    assert worst < 4e-15
