"""The top interface's single reflection, integrated over the cells of a reflection slice.

With ``first_order = "integrated"`` (``docs/first-order.md``) the kernel traces every path as
usual but deposits no exit of bounce order 1 made of one microfacet reflection (a reflection on the
top interface from above that leaves at once; on a multiple-scattering top, a walk of one bounce);
:func:`first_order_fractions` supplies its expectation instead:

    I_c = Int_cell f_1(l, v) cos(theta_v) dw_v,

the fraction of the incident flux that leaves in cell ``c`` at order 1, with
``f_1 = F D G / (4 cos theta_l cos theta_v)`` (:func:`goniometer.optics.microfacet_reflection`,
the run's masking) for a rough interface and a Dirac peak of weight ``F(cos theta_l)`` in the
mirror direction's cell for a smooth one. ``l`` and ``v`` point away from the surface; ``I_c``
includes the cosine (it is a flux fraction, not a BRDF value).

Cells are integrated in their own coordinates ((theta_v, phi_v) for classic slices, (theta_h,
phi_h) for half slices) by adaptive Gauss-Legendre cubature (5 x 5 nodes checked against 3 x 3);
cells near the specular peak start from sub-cells a quarter of the lobe's width wide, so that no
sharp lobe falls between nodes.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from goniometer import optics
from goniometer.run.settings import SettingsError
from goniometer.grids.slice_grid import CLASSIC, PARAMETRIZATIONS, boundary_tables, cell_index_fast
from goniometer.stack import Interface, Medium, Stack

__all__ = ["first_order_fractions", "check_supported", "RTOL", "ATOL"]

#: relative and absolute (fraction of the incident flux per cell) tolerance of the cubature
RTOL = 1e-6
ATOL = 1e-11
#: Gauss-Legendre nodes per axis of the cubature rule, and of the coarser rule it is checked against
_GAUSS = 5
_GAUSS_COARSE = 3
#: subdivision levels of a sub-cell at most (each splits it in 2 x 2)
_MAX_DEPTH = 8
#: sub-cells per axis at most of a cell near the peak
_MAX_START = 256
#: a cell is "near the peak" when it comes within this many roughnesses of h = z (theta_h)
_NEAR = 20.0

_HALF_PI = 0.5 * math.pi
_TWO_PI = 2.0 * math.pi
# parameter vector layout (p): light, roughness, tangent-frame rotation, indices
_LX, _LY, _LZ, _AX, _AY, _RC, _RS, _ETA, _CE, _CK = 0, 1, 2, 3, 4, 5, 6, 7, 8, 11
_NP = 14


def check_supported(stack: Stack) -> None:
    """Raise :class:`SettingsError` unless the first layer is an interface without a thin film
    (whose single microfacet reflection has a closed form)."""
    top = stack.layers[0]
    if isinstance(top, Medium) or not isinstance(top, Interface):
        raise SettingsError(f"first_order: integrated needs an interface on top; {stack.name!r} starts with a "
                            f"{type(top).__name__.lower()}")
    if top.film is not None and top.film.thickness_nm > 0.0:
        raise SettingsError(f"first_order: integrated has no closed form for a thin film on the top interface "
                            f"({stack.name!r}); use first_order = \"traced\"")


def first_order_fractions(stack: Stack, parametrization: str, n_theta: int, n_phi: int, light: np.ndarray,
                          masking: str) -> np.ndarray:
    """Expected fraction of the incident flux that leaves each reflection cell at bounce order 1
    after one microfacet reflection, shape ``(3, n_theta, n_phi)`` (RGB), for the unit light
    direction ``light`` (pointing away from the surface) and the masking ``"separable"`` or
    ``"height-correlated"``. On a multiple-scattering top interface this is the walks of one bounce,
    whose masking is height-correlated whatever ``masking`` says (Heitz et al. 2016)."""
    check_supported(stack)
    top = stack.layers[0]
    p = np.zeros(_NP)
    p[_LX:_LZ + 1] = light
    p[_AX], p[_AY] = top.alpha_xy
    p[_RC], p[_RS] = 1.0, 0.0
    if top.is_anisotropic:
        psi = math.radians(top.rotation_deg)
        p[_RC], p[_RS] = math.cos(psi), math.sin(psi)
    conductor = top.is_conductor
    if conductor:
        p[_CE:_CE + 3] = top.ior
        p[_CK:_CK + 3] = top.extinction
    else:
        p[_ETA] = top.ior[0]
    param = PARAMETRIZATIONS[parametrization]
    out = np.zeros((3, n_theta, n_phi))
    if p[_AX] == 0.0 and p[_AY] == 0.0:
        _mirror_cell(out, p, conductor, param, n_theta, n_phi, *boundary_tables(parametrization, n_theta, n_phi))
        return out
    gx, gw = np.polynomial.legendre.leggauss(_GAUSS)
    hx, hw = np.polynomial.legendre.leggauss(_GAUSS_COARSE)
    hc = masking == "height-correlated" or top.multiple_scattering
    _integrate_cells(out, p, conductor, hc, param, n_theta, n_phi, gx, gw, hx, hw, RTOL, ATOL)
    return out


@numba.njit(cache=True, error_model='numpy')
def _fresnel(cos_i, p, conductor, c):
    """Fresnel reflectance of channel ``c`` (the run's exact formulas, :mod:`goniometer.optics`)."""
    if conductor:
        return optics.fresnel_conductor(cos_i, p[_CE + c], p[_CK + c])
    return optics.fresnel_dielectric(cos_i, p[_ETA])


def _mirror_cell(out, p, conductor, param, n_theta, n_phi, row_cos, col_cos, col_sin):
    """A smooth top interface: weight F(cos theta_l) in the cell the tracer bins the mirror
    direction into."""
    lx, ly, lz = p[_LX], p[_LY], p[_LZ]
    i, j = cell_index_fast(param, False, lx, ly, lz, -lx, -ly, lz, n_theta, n_phi, row_cos, col_cos, col_sin)
    if i >= 0:
        for c in range(3):
            out[c, i, j] = _fresnel(lz, p, conductor, c)


@numba.njit(cache=True, error_model='numpy')
def _integrand(param, su, cu, cw, sw, p, conductor, hc):
    """``f_1 cos(theta_v)`` times the Jacobian of the cell coordinates (u, w) per channel, given
    ``sin u, cos u, cos w, sin w``: (theta_v, phi_v) with ``dw = sin(theta_v)``, or (theta_h, phi_h)
    with ``dw = 4 (l.h) sin(theta_h)``."""
    lx, ly, lz = p[_LX], p[_LY], p[_LZ]
    if param == CLASSIC:
        vx = su * cw
        vy = su * sw
        vz = cu
        jac = su * vz
    else:
        hx = su * cw
        hy = su * sw
        hz = cu
        lh = lx * hx + ly * hy + lz * hz
        vx = 2.0 * lh * hx - lx
        vy = 2.0 * lh * hy - ly
        vz = 2.0 * lh * hz - lz
        jac = 4.0 * lh * su * vz
        if lh <= 0.0:
            return 0.0, 0.0, 0.0
    if vz <= 0.0:
        return 0.0, 0.0, 0.0
    # into the interface's tangent frame (world = R(psi) tangent)
    rc, rs = p[_RC], p[_RS]
    tlx, tly = rc * lx + rs * ly, rc * ly - rs * lx
    tvx, tvy = rc * vx + rs * vy, rc * vy - rs * vx
    ax, ay = p[_AX], p[_AY]
    if conductor:
        f0 = optics.microfacet_reflection(tlx, tly, lz, tvx, tvy, vz, ax, ay, p[_CE], p[_CK], hc)
        f1 = optics.microfacet_reflection(tlx, tly, lz, tvx, tvy, vz, ax, ay, p[_CE + 1], p[_CK + 1], hc)
        f2 = optics.microfacet_reflection(tlx, tly, lz, tvx, tvy, vz, ax, ay, p[_CE + 2], p[_CK + 2], hc)
        return f0 * jac, f1 * jac, f2 * jac
    f = optics.microfacet_reflection(tlx, tly, lz, tvx, tvy, vz, ax, ay, p[_ETA], 0.0, hc) * jac
    return f, f, f


@numba.njit(cache=True, error_model='numpy')
def _rule(param, u0, u1, w0, w1, p, conductor, hc, gx, gw, trig):
    """Product Gauss-Legendre rule (nodes ``gx``, weights ``gw`` on [-1, 1]) over the rectangle
    [u0, u1] x [w0, w1] (three channels); ``trig``: (2, len(gx)) scratch for the nodes' cos, sin w."""
    a0 = a1 = a2 = 0.0
    hu = 0.5 * (u1 - u0)
    hw = 0.5 * (w1 - w0)
    for b in range(gx.shape[0]):
        w = w0 + hw * (gx[b] + 1.0)
        trig[0, b] = math.cos(w)
        trig[1, b] = math.sin(w)
    for a in range(gx.shape[0]):
        u = u0 + hu * (gx[a] + 1.0)
        su = math.sin(u)
        cu = math.cos(u)
        for b in range(gx.shape[0]):
            f0, f1, f2 = _integrand(param, su, cu, trig[0, b], trig[1, b], p, conductor, hc)
            g = gw[a] * gw[b]
            a0 += g * f0
            a1 += g * f1
            a2 += g * f2
    s = hu * hw
    return a0 * s, a1 * s, a2 * s


@numba.njit(cache=True, error_model='numpy')
def _adaptive(param, u0, u1, w0, w1, p, conductor, hc, gx, gw, hx, hw, rtol, atol, stack, trig):
    """Adaptive cubature of one rectangle: the rule of ``gx`` against the coarser one of ``hx``;
    where they disagree beyond ``atol + rtol |value|`` (``atol`` shared out by area) the rectangle
    is split in 2 x 2, down to :data:`_MAX_DEPTH` levels. The finer rule's value is kept (the
    difference bounds the coarser rule's error, hence, generously, the finer's). ``stack``:
    (4 * _MAX_DEPTH + 4, 5) and ``trig`` (2, len(gx)) scratch."""
    t0 = t1 = t2 = 0.0
    n = 1
    stack[0, 0], stack[0, 1], stack[0, 2], stack[0, 3], stack[0, 4] = u0, u1, w0, w1, 0.0
    while n > 0:
        n -= 1
        a, b, c, d, depth = stack[n, 0], stack[n, 1], stack[n, 2], stack[n, 3], stack[n, 4]
        q0, q1, q2 = _rule(param, a, b, c, d, p, conductor, hc, gx, gw, trig)
        c0, c1, c2 = _rule(param, a, b, c, d, p, conductor, hc, hx, hw, trig)
        err = max(abs(q0 - c0), abs(q1 - c1), abs(q2 - c2))
        tol = atol * 0.25 ** depth + rtol * max(abs(q0), abs(q1), abs(q2))
        if err <= tol or depth >= _MAX_DEPTH:
            t0 += q0
            t1 += q1
            t2 += q2
            continue
        um = 0.5 * (a + b)
        wm = 0.5 * (c + d)
        for k in range(4):
            ua, ub = (a, um) if k < 2 else (um, b)
            wa, wb = (c, wm) if k % 2 == 0 else (wm, d)
            stack[n, 0], stack[n, 1], stack[n, 2], stack[n, 3], stack[n, 4] = ua, ub, wa, wb, depth + 1.0
            n += 1
    return t0, t1, t2


@numba.njit(cache=True, error_model='numpy')
def _theta_h(param, u, w, lx, ly, lz):
    """theta_h of the cell coordinates (u, w)."""
    if param != CLASSIC:
        return u
    su = math.sin(u)
    x = lx + su * math.cos(w)
    y = ly + su * math.sin(w)
    z = lz + math.cos(u)
    return math.acos(min(1.0, z / math.sqrt(x * x + y * y + z * z)))


@numba.njit(cache=True, error_model='numpy', parallel=True)
def _integrate_cells(out, p, conductor, hc, param, n_theta, n_phi, gx, gw, hx, hw, rtol, atol):
    """Every cell of the slice, rows in parallel (each cell's value is independent of threads)."""
    a_min = min(p[_AX], p[_AY])
    a_max = max(p[_AX], p[_AY])
    dphi = _TWO_PI / n_phi
    for i in numba.prange(n_theta):
        stack = np.empty((4 * _MAX_DEPTH + 4, 5))
        trig = np.empty((2, gx.shape[0]))
        if param == CLASSIC:
            u0 = i * _HALF_PI / n_theta
            u1 = (i + 1) * _HALF_PI / n_theta
        else:
            u0 = (i / n_theta) ** 2 * _HALF_PI
            u1 = ((i + 1.0) / n_theta) ** 2 * _HALF_PI
        # half the cell's diagonal, as an angle between directions
        radius = 0.5 * math.sqrt((u1 - u0) ** 2 + (math.sin(u1) * dphi) ** 2)
        for j in range(n_phi):
            w0 = j * dphi
            w1 = w0 + dphi
            th = _theta_h(param, 0.5 * (u0 + u1), 0.5 * (w0 + w1), p[_LX], p[_LY], p[_LZ])
            s = 1
            if th - radius < _NEAR * a_max:
                s = min(_MAX_START, max(1, int(math.ceil(4.0 * radius / a_min))))
            t0 = t1 = t2 = 0.0
            for a in range(s):
                for b in range(s):
                    x0, x1, x2 = _adaptive(param, u0 + (u1 - u0) * a / s, u0 + (u1 - u0) * (a + 1) / s,
                                           w0 + dphi * b / s, w0 + dphi * (b + 1) / s, p, conductor, hc, gx, gw,
                                           hx, hw, rtol, atol / (s * s), stack, trig)
                    t0 += x0
                    t1 += x1
                    t2 += x2
            out[0, i, j] = t0
            out[1, i, j] = t1
            out[2, i, j] = t2
