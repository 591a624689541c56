"""Rusinkiewicz half/difference angles on the MERL grid: a pair of directions -> cell, and the
cell's measure (``docs/tabulated-format.md``).

Conventions: ``l`` (light) and ``v`` (viewer) are unit vectors pointing away from the surface, z
the macro normal. ``h = normalize(l + v)`` has polar angles ``(theta_h, phi_h)``; the difference
vector ``d`` is ``l`` rotated by ``-phi_h`` about z, then by ``-theta_h`` about y, with polar
angles ``(theta_d, phi_d)``. Hence, in the frame of ``h``, ``l = d`` and ``v = (-d_x, -d_y, d_z)``,
and ``l_z = cos th cos td - sin th sin td cos pd``, ``v_z = cos th cos td + sin th sin td cos pd``.

The MERL grid: ``i_h = floor(sqrt(theta_h / (pi/2)) 90)``, ``i_d = floor(theta_d / (pi/2) 90)``,
``i_p = floor(phi_d' / pi 180)`` with ``phi_d' = phi_d + pi`` where ``phi_d < 0``, each clamped to
its range; the flat index is ``i_p + 180 (i_d + 90 i_h)``. Two symmetries are folded: isotropy
(``phi_h`` is dropped) and reciprocity (``phi_d`` and ``phi_d + pi``, i.e. ``l`` and ``v``
exchanged, share a cell). ``phi_d`` and ``pi - phi_d`` (the mirror image about the plane of
``n`` and ``h``) are kept apart, as MERL keeps them.

The measure of a cell is ``mu = Int_cell cos theta_l cos theta_v dw_l dw_v`` over the pairs of
upper-hemisphere directions whose cell it is (``dw_l dw_v = 4 cos theta_d dw_h dw_d``); the
measures of all cells sum to ``pi^2``.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numba
import numpy as np

N_THETA_H = 90
N_THETA_D = 90
N_PHI_D = 180
SHAPE = (N_THETA_H, N_THETA_D, N_PHI_D)
N_CELLS = N_THETA_H * N_THETA_D * N_PHI_D

_HALF_PI = 0.5 * math.pi

#: Gauss-Legendre points in theta_h, and per smooth piece in phi_d, for :func:`cell_measure` (the
#: theta_d integral is exact); relative error against 16 x 16 points: < 1e-3 on the cells of
#: measure above 1e-2 of the largest, < 2e-2 above 1e-4 (far below the noise of their few hits)
MEASURE_GAUSS = (8, 3)


@numba.njit(cache=True, error_model='numpy')
def halfdiff_angles(lx: float, ly: float, lz: float, vx: float, vy: float, vz: float):
    """``(theta_h, theta_d, phi_d)`` of the unit directions ``l`` and ``v``, ``phi_d`` in [-pi, pi]."""
    hx = lx + vx
    hy = ly + vy
    hz = lz + vz
    n = math.sqrt(hx * hx + hy * hy + hz * hz)
    if n == 0.0:
        return _HALF_PI, _HALF_PI, 0.0
    hx /= n
    hy /= n
    hz /= n
    st = math.sqrt(hx * hx + hy * hy)
    theta_h = math.atan2(st, hz)
    if st > 0.0:
        cp = hx / st
        sp = hy / st
    else:
        cp = 1.0
        sp = 0.0
    ct = hz
    # d = R_y(-theta_h) R_z(-phi_h) l
    ax = cp * lx + sp * ly
    ay = -sp * lx + cp * ly
    dx = ct * ax - st * lz
    dz = st * ax + ct * lz
    theta_d = math.acos(min(1.0, max(-1.0, dz)))
    phi_d = math.atan2(ay, dx)
    return theta_h, theta_d, phi_d


@numba.njit(cache=True, error_model='numpy')
def cell_of_angles(theta_h: float, theta_d: float, phi_d: float) -> int:
    """Flat MERL index ``i_p + 180 (i_d + 90 i_h)`` of half/difference angles (radians)."""
    if theta_h <= 0.0:
        ih = 0
    else:
        ih = min(max(int(math.sqrt(theta_h / _HALF_PI) * N_THETA_H), 0), N_THETA_H - 1)
    idd = min(max(int(theta_d / _HALF_PI * N_THETA_D), 0), N_THETA_D - 1)
    if phi_d < 0.0:
        phi_d += math.pi
    ip = min(max(int(phi_d / math.pi * N_PHI_D), 0), N_PHI_D - 1)
    return ip + N_PHI_D * (idd + N_THETA_D * ih)


@numba.njit(cache=True, error_model='numpy')
def cell_of(lx: float, ly: float, lz: float, vx: float, vy: float, vz: float) -> int:
    """Flat MERL cell of the pair ``(l, v)`` of unit directions, or -1 if either lies at or below
    the horizon."""
    if lz <= 0.0 or vz <= 0.0:
        return -1
    th, td, pd = halfdiff_angles(lx, ly, lz, vx, vy, vz)
    return cell_of_angles(th, td, pd)


@numba.njit(cache=True, error_model='numpy')
def _cells(l: np.ndarray, v: np.ndarray, out: np.ndarray) -> None:
    for k in range(l.shape[0]):
        out[k] = cell_of(l[k, 0], l[k, 1], l[k, 2], v[k, 0], v[k, 1], v[k, 2])


def cell_indices(l: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Flat cells of arrays of direction pairs ``l``, ``v`` (..., 3), broadcast together;
    -1 where either is at or below the horizon. Directions are normalised first."""
    l = np.asarray(l, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    l, v = np.broadcast_arrays(l, v)
    shape = l.shape[:-1]
    lf = np.ascontiguousarray(l.reshape(-1, 3))
    vf = np.ascontiguousarray(v.reshape(-1, 3))
    lf = lf / np.linalg.norm(lf, axis=1, keepdims=True)
    vf = vf / np.linalg.norm(vf, axis=1, keepdims=True)
    out = np.empty(lf.shape[0], dtype=np.int64)
    _cells(lf, vf, out)
    return out.reshape(shape)


def theta_h_edges_deg() -> np.ndarray:
    """The 91 edges of the theta_h rows (square-root mapping), degrees."""
    u = np.arange(N_THETA_H + 1) / N_THETA_H
    return 90.0 * u * u


def theta_d_edges_deg() -> np.ndarray:
    return np.linspace(0.0, 90.0, N_THETA_D + 1)


def phi_d_edges_deg() -> np.ndarray:
    return np.linspace(0.0, 180.0, N_PHI_D + 1)


def theta_h_centers_deg() -> np.ndarray:
    """Row centres, mid-row in the square-root coordinate (as the half slices), degrees."""
    u = (np.arange(N_THETA_H) + 0.5) / N_THETA_H
    return 90.0 * u * u


def theta_d_centers_deg() -> np.ndarray:
    return (np.arange(N_THETA_D) + 0.5) * (90.0 / N_THETA_D)


def phi_d_centers_deg() -> np.ndarray:
    return (np.arange(N_PHI_D) + 0.5) * (180.0 / N_PHI_D)


@numba.njit(cache=True, error_model='numpy')
def _theta_d_integral(ch: float, sh: float, d0: float, c0: float, s0: float, d1: float, c1: float,
                      s1: float, cphi: float) -> float:
    """``Int 4 cos td sin td max(0, l_z v_z) dtd`` over ``[d0, d1]`` (cosines ``c``, sines ``s``)
    at fixed ``theta_h`` (``ch``, ``sh``) and ``phi_d``: ``l_z v_z = C cos^2 td - S sin^2 td``
    (``C = ch^2``, ``S = sh^2 cos^2 phi``) is positive below ``td = atan2(ch, sh |cos phi|)``, and
    ``-(C cos^4 td + S sin^4 td)`` is an antiderivative."""
    tmax = math.atan2(ch, sh * abs(cphi))
    if tmax <= d0:
        return 0.0
    if tmax < d1:
        c1 = math.cos(tmax)
        s1 = math.sin(tmax)
    S = sh * sh * cphi * cphi
    c02 = c0 * c0
    c12 = c1 * c1
    s02 = s0 * s0
    s12 = s1 * s1
    return ch * ch * (c02 * c02 - c12 * c12) + S * (s02 * s02 - s12 * s12)


@numba.njit(cache=True, error_model='numpy', parallel=True)
def _measure(gx: np.ndarray, gw: np.ndarray, px: np.ndarray, pw: np.ndarray, th_edges: np.ndarray, td_edges: np.ndarray,
             pd_edges: np.ndarray) -> np.ndarray:
    """theta_d exactly, phi_d by Gauss-Legendre on the pieces between the kinks of the
    theta_d-integral (where the horizon curve crosses the cell's theta_d edges), theta_h by
    Gauss-Legendre."""
    nh = th_edges.shape[0] - 1
    nd = td_edges.shape[0] - 1
    npd = pd_edges.shape[0] - 1
    g = gx.shape[0]
    out = np.zeros((nh, nd, npd))
    for i in numba.prange(nh):
        h0 = th_edges[i]
        h1 = th_edges[i + 1]
        kinks = np.empty(4)
        bk = np.empty(6)
        for a_ in range(g):
            th = h0 + 0.5 * (h1 - h0) * (gx[a_] + 1.0)
            # 2 pi (phi_h) x 2 (fold) x sin th (solid angle of h)
            wh = gw[a_] * 0.5 * (h1 - h0) * 4.0 * math.pi * math.sin(th)
            ch = math.cos(th)
            sh = math.sin(th)
            for k in range(nd):
                d0 = td_edges[k]
                d1 = td_edges[k + 1]
                c0 = math.cos(d0)
                s0 = math.sin(d0)
                c1 = math.cos(d1)
                s1 = math.sin(d1)
                # kinks in phi: |cos phi| = cos th cos d / (sin th sin d) for d = d0, d1
                nk = 0
                for cd, sd in ((c0, s0), (c1, s1)):
                    den = sh * sd
                    if den > 0.0:
                        t = ch * cd / den
                        if t < 1.0:
                            c = math.acos(t)
                            kinks[nk] = c
                            kinks[nk + 1] = math.pi - c
                            nk += 2
                for j in range(npd):
                    p0 = pd_edges[j]
                    p1 = pd_edges[j + 1]
                    n = 0
                    bk[n] = p0
                    n += 1
                    for q in range(nk):
                        if p0 < kinks[q] < p1:
                            bk[n] = kinks[q]
                            n += 1
                    bk[n] = p1
                    n += 1
                    if n > 2:
                        bk[:n].sort()
                    acc = 0.0
                    for q in range(n - 1):
                        q0 = bk[q]
                        q1 = bk[q + 1]
                        part = 0.0
                        for b_ in range(px.shape[0]):
                            p = q0 + 0.5 * (q1 - q0) * (px[b_] + 1.0)
                            part += pw[b_] * _theta_d_integral(ch, sh, d0, c0, s0, d1, c1, s1, math.cos(p))
                        acc += 0.5 * (q1 - q0) * part
                    out[i, k, j] += wh * acc
    return out


@lru_cache(maxsize=1)
def cell_measure() -> np.ndarray:
    """The measure ``mu`` of every cell, shape (90, 90, 180), in sr^2 (read-only, memoised):
    ``Int cos theta_l cos theta_v dw_l dw_v`` over the cell, both folds included. The phi_d
    integral is exact; phi_d and theta_h use :data:`MEASURE_GAUSS` Gauss-Legendre points, phi_d
    on each piece between the kinks the horizon makes."""
    gx, gw = np.polynomial.legendre.leggauss(MEASURE_GAUSS[0])
    px, pw = np.polynomial.legendre.leggauss(MEASURE_GAUSS[1])
    out = _measure(gx, gw, px, pw, np.radians(theta_h_edges_deg()), np.radians(theta_d_edges_deg()),
                   np.radians(phi_d_edges_deg()))
    out.setflags(write=False)
    return out
