"""Slice geometry: cells, sub-cells, projected solid angles, masks."""

from __future__ import annotations

import math

import numpy as np
import pytest

from goniometer.grids.slice_grid import SliceGrid, light_direction


@pytest.mark.parametrize("param", ["classic", "half"])
@pytest.mark.parametrize("side", ["reflection", "transmission"])
@pytest.mark.parametrize("theta_l, phi_l", [(0.0, 0.0), (30.0, 0.0), (75.0, 40.0), (89.0, 0.0)])
def test_projected_solid_angles_tile_the_hemisphere(param, side, theta_l, phi_l):
    """Int_hemisphere |cos theta| dw = pi: the cells tile the hemisphere of v exactly once,
    for any light direction (half cells included: every v has exactly one h = normalize(l + v))."""
    g = SliceGrid(param, 30, 72, side)
    l = light_direction(theta_l, phi_l)
    om = g.proj_solid_angle(l)
    assert om.shape == (30, 72) and (om >= 0).all()
    tol = 1e-12 if param == "classic" else 2e-4 if theta_l < 80 else 2e-3
    assert om.sum() == pytest.approx(math.pi, rel=tol)
    _, w = g.subcells(l, 4)
    assert w.sum() == pytest.approx(math.pi, rel=1e-12 if param == "classic" else 2e-2)


def test_classic_solid_angle_is_exact():
    g = SliceGrid("classic", 90, 360)
    om = g.proj_solid_angle(light_direction(0))
    i = 40
    th0, th1 = math.radians(i), math.radians(i + 1)
    assert om[i, 7] == pytest.approx(math.radians(1) * (math.sin(th1) ** 2 - math.sin(th0) ** 2) / 2, rel=1e-14)


@pytest.mark.parametrize("param", ["classic", "half"])
@pytest.mark.parametrize("side", ["reflection", "transmission"])
def test_subcell_centres_map_back_to_their_cell(param, side):
    g = SliceGrid(param, 18, 36, side)
    l = light_direction(50.0, 20.0)
    v, w = g.subcells(l, 3)
    ok = 0
    for i in range(18):
        for j in range(36):
            for a in range(3):
                for b in range(3):
                    if w[i, j, a, b] > 0:
                        assert g.cell_of(l, v[i, j, a, b]) == (i, j)
                        ok += 1
    assert ok > 18 * 36 * 9 * 0.5
    assert np.allclose(np.linalg.norm(v[w > 0], axis=-1), 1.0)
    assert ((v[..., 2] > 0) if side == "reflection" else (v[..., 2] < 0))[w > 0].all()


def test_cell_index_conventions():
    g = SliceGrid("classic", 90, 360)
    l = light_direction(30.5)
    # mirror direction of l (phi_l = 0) sits at phi_v = 180 deg, theta_v = 30.5 deg
    mirror = np.array([-l[0], -l[1], l[2]])
    assert g.cell_of(l, mirror) == (30, 180)
    assert g.cell_of(l, np.array([0.0, 0.0, -1.0])) == (-1, -1)
    h = SliceGrid("half", 90, 360)
    assert h.cell_of(l, mirror)[0] == 0  # h = n
    t = SliceGrid("half", 90, 360, "transmission")
    assert t.cell_of(l, -l)[0] == 0  # straight-through maps onto the mirror direction
    assert SliceGrid("classic", 90, 360, "transmission").cell_of(l, -l) == (30, 180)


@pytest.mark.parametrize("param", ["classic", "half"])
def test_constant_integrates_to_itself(param):
    g = SliceGrid(param, 45, 90)
    l = light_direction(60.0)
    val = g.integrate(l, lambda l_, v: np.full(v.shape[:-1] + (3,), 0.7), s=5)
    valid = g.mask(l)
    assert np.allclose(val[valid], 0.7, rtol=1e-14)


def test_half_mask():
    g = SliceGrid("half", 90, 360)
    m0 = g.mask(light_direction(0.0))
    assert not m0[0].any() and m0[1:60].all()
    m80 = g.mask(light_direction(80.0))
    assert m80.sum() < m0.sum()
    # a masked cell has a sub-cell centre below the horizon; a valid one none
    _, w = g.subcells(light_direction(80.0), 5)
    assert (w[m80] > 0).all()
    assert (w[~m80 & (np.arange(90)[:, None] > 0)] == 0).any(axis=(-1, -2)).all()
    assert SliceGrid("classic").mask(light_direction(80)).all()


def test_bad_grid():
    with pytest.raises(ValueError, match="parametrization"):
        SliceGrid("polar")
    with pytest.raises(ValueError, match="n_theta"):
        SliceGrid("classic", 0, 10)


@pytest.mark.parametrize("param", ["classic", "half"])
def test_transmission_cells_share_solid_angles_and_masks(param):
    l = light_direction(35.0, 10.0)
    r, t = SliceGrid(param, 18, 36), SliceGrid(param, 18, 36, "transmission")
    np.testing.assert_array_equal(r.proj_solid_angle(l), t.proj_solid_angle(l))
    np.testing.assert_array_equal(r.mask(l), t.mask(l))


@pytest.mark.parametrize("param", ["classic", "half"])
@pytest.mark.parametrize("side", ["reflection", "transmission"])
@pytest.mark.parametrize("res", [(90, 360), (7, 11), (300, 1000), (3, 4)])
def test_fast_cell_index_agrees_with_the_exact_one(param, side, res):
    """The tracer's polynomial-guess-then-correct binning equals the acos/atan2 binning for random
    directions, directions on the cell boundaries' neighbourhood, the pole and the horizon."""
    from goniometer.grids.slice_grid import boundary_tables, cell_index, cell_index_fast, CLASSIC, HALF
    nt, nph = res
    code = CLASSIC if param == "classic" else HALF
    tables = boundary_tables(param, nt, nph)
    rng = np.random.default_rng(1)
    v = rng.normal(size=(20000, 3))
    v /= np.linalg.norm(v, axis=1)[:, None]
    v[:, 2] = np.abs(v[:, 2]) * (-1 if side == "transmission" else 1)
    # add directions 1e-9 rad either side of classic boundaries
    th = np.repeat((np.arange(nt + 1) / nt) * np.pi / 2, 2) + np.tile([-1e-9, 1e-9], nt + 1)
    ph = rng.random(th.size) * 2 * np.pi
    extra = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1)
    extra[:, 2] *= -1 if side == "transmission" else 1
    v = np.concatenate([v, extra, [[0, 0, 1 if side == "reflection" else -1]]])
    for theta_l, phi_l in ((0.0, 0.0), (50.0, 30.0), (85.0, 200.0)):
        l = light_direction(theta_l, phi_l)
        for d in v:
            a = cell_index(code, side == "transmission", *l, *d, nt, nph)
            b = cell_index_fast(code, side == "transmission", *l, *d, nt, nph, *tables)
            assert a == b, (d, a, b)


def test_half_solid_angles_are_exact_where_the_cell_is_above_the_horizon():
    """Gauss-Legendre with 6 and 9 points agree to rounding on cells entirely above the horizon,
    and a 256 x 256 midpoint rule converges to them (its own error ~1e-7)."""
    from goniometer.grids.slice_grid import _half_omega, _half_omega_exact
    l = light_direction(45.0, 20.0)
    g6 = np.polynomial.legendre.leggauss(6)
    g9 = np.polynomial.legendre.leggauss(9)
    a = _half_omega_exact(*l, 30, 72, *g6, 64)
    b = _half_omega_exact(*l, 30, 72, *g9, 64)
    fine = _half_omega_exact(*l, 30, 72, *g6, 128)
    gl = a == fine  # cells that never went through the midpoint branch
    assert gl.sum() > 0.5 * gl.size
    np.testing.assert_allclose(a[gl], b[gl], rtol=1e-12)
    mid = _half_omega(*l, 30, 72, 256)[0]
    np.testing.assert_allclose(a[gl], mid[gl], rtol=2e-6)
