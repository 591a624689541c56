"""Slice parametrizations: direction -> cell, cells -> sub-cell directions, solid angles, masks.

See ``docs/slices-format.md`` for the contract. Conventions:

* ``l`` (light) and ``v`` (viewer) point away from the surface; z is the macro normal.
* Reflection cells cover ``v_z > 0``, transmission cells ``v_z < 0``.
* ``classic``: cell (i, j) holds ``theta_v in [i dth, (i+1) dth)``, ``phi_v in [j dphi, (j+1) dphi)``,
  ``dth = (pi/2) / n_theta``, ``dphi = 2 pi / n_phi`` (transmission uses ``theta = acos(-v_z)``).
* ``half``: ``h = normalize(l + v)`` (transmission: ``v`` mirrored to ``(v_x, v_y, -v_z)`` first),
  ``i = floor(sqrt(theta_h / (pi/2)) n_theta)``, ``j = floor(phi_h / dphi)``.
* Projected solid angle of a cell: ``Omega = Int_cell |cos theta_v| dw_v`` over the part of the
  cell that maps to real directions (``v`` on the slice's side of the surface).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from goniometer.grids.warp import invert_point

CLASSIC = 0
HALF = 1
#: the RGL format's sample space (``docs/rgl-format.md``): cells are the dual cells of its n x n nodes,
#: found through the warp of :mod:`goniometer.grids.warp` (3: 2 is the tracer's tabulation mode)
RGL = 3
PARAMETRIZATIONS = {"classic": CLASSIC, "half": HALF, "rgl": RGL}

#: Gauss-Legendre points per axis for the projected solid angle of half cells entirely above the
#: horizon (the integrand is smooth there: exact to rounding)
OMEGA_GAUSS = 6
#: midpoint sub-cells per axis for half cells that straddle the horizon (or the l.h = 0 curve)
OMEGA_STRADDLE_SUBCELLS = 64

_HALF_PI = 0.5 * math.pi
_TWO_PI = 2.0 * math.pi


@numba.njit(cache=True, error_model='numpy')
def slice_direction(param: int, transmission: bool, lx: float, ly: float, lz: float,
                    vx: float, vy: float, vz: float):
    """The unit vector whose polar angles the slice bins: ``v`` (classic) or ``normalize(l + v)``
    (half), with ``v`` mirrored to the upper side for transmission. ``z <= 0`` means ``v`` is on the
    wrong side of the surface for this slice."""
    z = -vz if transmission else vz
    if z <= 0.0:
        return vx, vy, z
    if param == CLASSIC:
        return vx, vy, z
    x = lx + vx
    y = ly + vy
    z = lz + z
    inv = 1.0 / math.sqrt(x * x + y * y + z * z)
    return x * inv, y * inv, z * inv


@numba.njit(cache=True, error_model='numpy')
def cell_index(param: int, transmission: bool, lx: float, ly: float, lz: float,
               vx: float, vy: float, vz: float, n_theta: int, n_phi: int):
    """Cell ``(i, j)`` of the outgoing direction ``v`` for light direction ``l``.

    ``param`` is :data:`CLASSIC` or :data:`HALF`. Returns ``(-1, -1)`` if ``v`` is
    not on the slice's side of the surface.
    """
    x, y, z = slice_direction(param, transmission, lx, ly, lz, vx, vy, vz)
    if z <= 0.0:
        return -1, -1
    theta = math.acos(min(1.0, z))
    phi = math.atan2(y + 0.0, x + 0.0)  # + 0.0 turns -0.0 into +0.0: the pole maps to j = 0
    if phi < 0.0:
        phi += _TWO_PI
    if param == CLASSIC:
        i = int(theta / _HALF_PI * n_theta)
    else:
        i = int(math.sqrt(theta / _HALF_PI) * n_theta)
    j = int(phi / _TWO_PI * n_phi)
    if i >= n_theta:
        i = n_theta - 1
    if j >= n_phi:
        j = n_phi - 1
    return i, j


@numba.njit(cache=True, error_model='numpy', inline='always')
def fast_acos(x: float) -> float:
    """arccos of ``x`` in [0, 1] to 2e-8 rad (Abramowitz & Stegun 4.4.46). Only used to guess a
    row that :func:`cell_index_fast` then corrects exactly against the row boundaries."""
    p = -0.0012624911
    p = p * x + 0.0066700901
    p = p * x - 0.0170881256
    p = p * x + 0.0308918810
    p = p * x - 0.0501743046
    p = p * x + 0.0889789874
    p = p * x - 0.2145988016
    p = p * x + 1.5707963050
    return math.sqrt(max(0.0, 1.0 - x)) * p


@numba.njit(cache=True, error_model='numpy', inline='always')
def fast_angle(x: float, y: float) -> float:
    """Azimuth of (x, y) in [0, 2 pi) to about 1e-5 rad (a guess corrected by the caller); 0 for
    the origin. Selects only (the quadrant of a random direction is not predictable)."""
    ax = abs(x)
    ay = abs(y)
    a = min(ax, ay) / max(max(ax, ay), 1e-300)
    s = a * a
    r = ((-0.0464964749 * s + 0.15931422) * s - 0.327622764) * s * a + a
    r = _HALF_PI - r if ay > ax else r
    r = math.pi - r if x < 0.0 else r
    return _TWO_PI - r if y < 0.0 else r


def boundary_tables(param: str, n_theta: int, n_phi: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cosines of the row boundaries (n_theta + 1, decreasing from 1) and cosines and sines of the
    column boundaries (n_phi + 1) that :func:`cell_index_fast` tests against."""
    u = np.arange(n_theta + 1) / n_theta
    theta = _HALF_PI * (u if param == "classic" else u * u)
    row_cos = np.cos(theta)
    row_cos[0] = 1.0
    phi = _TWO_PI * np.arange(n_phi + 1) / n_phi
    col_cos, col_sin = np.cos(phi), np.sin(phi)
    col_cos[n_phi], col_sin[n_phi] = 1.0, 0.0
    return row_cos, col_cos, col_sin


@numba.njit(cache=True, error_model='numpy')
def cell_index_fast(param: int, transmission: bool, lx: float, ly: float, lz: float,
                    vx: float, vy: float, vz: float, n_theta: int, n_phi: int,
                    row_cos: np.ndarray, col_cos: np.ndarray, col_sin: np.ndarray):
    """:func:`cell_index` for the tracer: :func:`cell_index_lanes` for ``n_phi >= 8``, libm's
    ``atan2`` for the azimuth of coarser grids. Agrees with :func:`cell_index` except within
    rounding of a boundary. On the RGL grid (``param`` = :data:`RGL`; reflection only) the tables
    are the warp's (:func:`goniometer.grids.warp.invert_point`)."""
    if param == RGL:
        if transmission:
            return -1, -1
        return invert_point(lx, ly, lz, vx, vy, vz, n_theta, row_cos, col_cos, col_sin)
    if n_phi >= 8:
        return cell_index_lanes(param, transmission, lx, ly, lz, vx, vy, vz, n_theta, n_phi, row_cos, col_cos,
                                col_sin)
    x, y, z = slice_direction(param, transmission, lx, ly, lz, vx, vy, vz)
    if z <= 0.0:
        return -1, -1
    i = _row_of(min(1.0, z), param != CLASSIC, n_theta, row_cos)
    phi = math.atan2(y + 0.0, x + 0.0)
    if phi < 0.0:
        phi += _TWO_PI
    return i, min(int(phi / _TWO_PI * n_phi), n_phi - 1)


@numba.njit(cache=True, error_model='numpy', inline='always')
def _row_of(z: float, half: bool, n_theta: int, row_cos) -> int:
    """The row of ``cos theta = z`` (in [0, 1]): a guess within one row, corrected by one step."""
    u = fast_acos(z) / _HALF_PI
    g = math.sqrt(u) * n_theta if half else u * n_theta
    i = min(max(np.int64(g), 0), n_theta - 1)
    i = i - 1 if (i > 0) & (z > row_cos[i]) else i
    return i + 1 if (i < n_theta - 1) & (z <= row_cos[i + 1]) else i


@numba.njit(cache=True, error_model='numpy', inline='always')
def cell_index_lanes(param: int, transmission: bool, lx: float, ly: float, lz: float,
                     vx: float, vy: float, vz: float, n_theta: int, n_phi: int, row_cos, col_cos, col_sin):
    """The cell ``(i, j)`` of ``v`` (``(-1, -1)`` on the wrong side), without branches, for
    ``n_phi >= 8``: a polynomial guess of the row and column, corrected against the exact
    boundaries of :func:`boundary_tables` (row i holds ``row_cos[i+1] < cos theta <= row_cos[i]``,
    column j the azimuths between boundaries j and j + 1; the tables may be any indexable, e.g.
    copies on a vectorised loop's stack). The guesses are within one cell (``fast_acos`` to 2e-8
    rad, ``fast_angle`` to 1e-5 rad), so one correction step each way, as a select, makes them
    exact: a loop over exits vectorises (``goniometer.kernel.deposit``)."""
    z0 = -vz if transmission else vz
    # the half vector normalize(l + v) (v mirrored up for transmission); v itself for classic
    hx = lx + vx
    hy = ly + vy
    hz = lz + z0
    inv = 1.0 / math.sqrt(max(1e-300, hx * hx + hy * hy + hz * hz))
    half = param != CLASSIC
    x = hx * inv if half else vx
    y = hy * inv if half else vy
    z = min(1.0, max(0.0, hz * inv if half else z0))
    i = _row_of(z, half, n_theta, row_cos)
    j = min(np.int64(fast_angle(x, y) * (n_phi / _TWO_PI)), n_phi - 1)
    below = col_cos[j] * y - col_sin[j] * x < 0.0
    above = col_cos[j + 1] * y - col_sin[j + 1] * x >= 0.0
    j = (j - 1 if j > 0 else n_phi - 1) if below else ((j + 1 if j < n_phi - 1 else 0) if above else j)
    # the azimuth of the normal itself is 0
    j = 0 if (x == 0.0) & (y == 0.0) else j
    ok = z0 > 0.0
    return (i if ok else -1), (j if ok else -1)


@numba.njit(cache=True, error_model='numpy')
def _half_subcell(lx, ly, lz, i, a, j, b, n_theta, n_phi, s):
    """Centre direction v (reflection side) and projected solid angle of half sub-cell (i, a; j, b)."""
    u0 = (i + a / s) / n_theta
    u1 = (i + (a + 1.0) / s) / n_theta
    uc = (i + (a + 0.5) / s) / n_theta
    dw_h = (math.cos(u0 * u0 * _HALF_PI) - math.cos(u1 * u1 * _HALF_PI)) * (_TWO_PI / n_phi / s)
    thc = uc * uc * _HALF_PI
    st = math.sin(thc)
    ph = (j + (b + 0.5) / s) * (_TWO_PI / n_phi)
    hx = st * math.cos(ph)
    hy = st * math.sin(ph)
    hz = math.cos(thc)
    lh = lx * hx + ly * hy + lz * hz
    vx = 2.0 * lh * hx - lx
    vy = 2.0 * lh * hy - ly
    vz = 2.0 * lh * hz - lz
    w = dw_h * vz * 4.0 * lh if (lh > 0.0 and vz > 0.0) else 0.0
    return vx, vy, vz, w


@numba.njit(cache=True, error_model='numpy', parallel=True)
def _half_subcells(lx, ly, lz, n_theta, n_phi, s, transmission):
    """Sub-cell centre directions and weights of a half slice (see :meth:`SliceGrid.subcells`)."""
    dirs = np.empty((n_theta, n_phi, s, s, 3))
    weights = np.empty((n_theta, n_phi, s, s))
    for i in numba.prange(n_theta):
        for j in range(n_phi):
            for a in range(s):
                for b in range(s):
                    vx, vy, vz, w = _half_subcell(lx, ly, lz, i, a, j, b, n_theta, n_phi, s)
                    dirs[i, j, a, b, 0] = vx
                    dirs[i, j, a, b, 1] = vy
                    dirs[i, j, a, b, 2] = -vz if transmission else vz
                    weights[i, j, a, b] = w
    return dirs, weights


@numba.njit(cache=True, error_model='numpy', parallel=True)
def _half_omega(lx, ly, lz, n_theta, n_phi, s):
    """Sum of sub-cell weights per half cell and whether every sub-cell centre is valid
    (:func:`_half_subcell`'s values, the sines and cosines taken once per row and per column)."""
    omega = np.zeros((n_theta, n_phi))
    valid = np.ones((n_theta, n_phi), dtype=np.bool_)
    cp = np.empty((n_phi, s))
    sp = np.empty((n_phi, s))
    for j in range(n_phi):
        for b in range(s):
            ph = (j + (b + 0.5) / s) * (_TWO_PI / n_phi)
            cp[j, b] = math.cos(ph)
            sp[j, b] = math.sin(ph)
    for i in numba.prange(n_theta):
        dw = np.empty(s)
        st = np.empty(s)
        ct = np.empty(s)
        for a in range(s):
            u0 = (i + a / s) / n_theta
            u1 = (i + (a + 1.0) / s) / n_theta
            uc = (i + (a + 0.5) / s) / n_theta
            dw[a] = (math.cos(u0 * u0 * _HALF_PI) - math.cos(u1 * u1 * _HALF_PI)) * (_TWO_PI / n_phi / s)
            thc = uc * uc * _HALF_PI
            st[a] = math.sin(thc)
            ct[a] = math.cos(thc)
        for j in range(n_phi):
            acc = 0.0
            ok = True
            for a in range(s):
                for b in range(s):
                    hx = st[a] * cp[j, b]
                    hy = st[a] * sp[j, b]
                    hz = ct[a]
                    lh = lx * hx + ly * hy + lz * hz
                    vz = 2.0 * lh * hz - lz
                    w = dw[a] * vz * 4.0 * lh if (lh > 0.0 and vz > 0.0) else 0.0
                    acc += w
                    ok = ok and w > 0.0
            omega[i, j] = acc
            valid[i, j] = ok
    return omega, valid


@numba.njit(cache=True, error_model='numpy', inline='always')
def _half_weight_sc(lx, ly, lz, st, ct, cp, sp):
    """:func:`_half_weight` from ``sin theta_h, cos theta_h, cos phi_h, sin phi_h``."""
    hx = st * cp
    hy = st * sp
    hz = ct
    lh = lx * hx + ly * hy + lz * hz
    vz = 2.0 * lh * hz - lz
    w = 4.0 * lh * vz * st if (lh > 0.0 and vz > 0.0) else 0.0
    return w, vz, lh


@numba.njit(cache=True, error_model='numpy')
def _half_weight(lx, ly, lz, th, ph):
    """Integrand of the projected solid angle of a half cell in (theta_h, phi_h), per unit
    ``dtheta dphi``: ``4 (l.h) max(0, v_z) sin(theta_h)``, 0 where l.h <= 0; and v_z, l.h."""
    return _half_weight_sc(lx, ly, lz, math.sin(th), math.cos(th), math.cos(ph), math.sin(ph))


@numba.njit(cache=True, error_model='numpy', parallel=True)
def _half_omega_exact(lx, ly, lz, n_theta, n_phi, gx, gw, s_fine):
    """Projected solid angle of every half cell: Gauss-Legendre (nodes ``gx``, weights ``gw`` on
    [-1, 1]) in (theta_h, phi_h) where the cell lies entirely on the valid side (all of a grid of
    (k+1)^2 points valid), ``s_fine`` x ``s_fine`` midpoint sub-cells where it straddles, 0 where
    no grid point is valid. The sines and cosines of the points' angles are taken once per row
    and per column (the integrand is :func:`_half_weight`'s, value for value)."""
    omega = np.zeros((n_theta, n_phi))
    k = gx.shape[0]
    dphi = _TWO_PI / n_phi
    # per column: cos, sin of the test grid's, the Gauss nodes' and the sub-cells' azimuths
    cg = np.empty((n_phi, k + 1))
    sg = np.empty((n_phi, k + 1))
    cn = np.empty((n_phi, k))
    sn = np.empty((n_phi, k))
    cf = np.empty((n_phi, s_fine))
    sf = np.empty((n_phi, s_fine))
    for j in range(n_phi):
        ph0 = j * dphi
        for b in range(k + 1):
            ph = ph0 + dphi * b / k
            cg[j, b] = math.cos(ph)
            sg[j, b] = math.sin(ph)
        for b in range(k):
            ph = ph0 + 0.5 * dphi * (gx[b] + 1.0)
            cn[j, b] = math.cos(ph)
            sn[j, b] = math.sin(ph)
        for b in range(s_fine):
            ph = ph0 + dphi * (b + 0.5) / s_fine
            cf[j, b] = math.cos(ph)
            sf[j, b] = math.sin(ph)
    for i in numba.prange(n_theta):
        th0 = (i / n_theta) ** 2 * _HALF_PI
        th1 = ((i + 1.0) / n_theta) ** 2 * _HALF_PI
        stg = np.empty(k + 1)
        ctg = np.empty(k + 1)
        stn = np.empty(k)
        ctn = np.empty(k)
        for a in range(k + 1):
            th = th0 + (th1 - th0) * a / k
            stg[a] = math.sin(th)
            ctg[a] = math.cos(th)
        for a in range(k):
            th = th0 + 0.5 * (th1 - th0) * (gx[a] + 1.0)
            stn[a] = math.sin(th)
            ctn[a] = math.cos(th)
        fine = False
        stf = np.empty(s_fine)
        ctf = np.empty(s_fine)
        dwf = np.empty(s_fine)
        for j in range(n_phi):
            n_in = 0
            for a in range(k + 1):
                for b in range(k + 1):
                    _, vz, lh = _half_weight_sc(lx, ly, lz, stg[a], ctg[a], cg[j, b], sg[j, b])
                    if vz > 0.0 and lh > 0.0:
                        n_in += 1
            acc = 0.0
            if n_in == 0:
                pass  # entirely on the invalid side
            elif n_in == (k + 1) * (k + 1):
                for a in range(k):
                    for b in range(k):
                        acc += gw[a] * gw[b] * _half_weight_sc(lx, ly, lz, stn[a], ctn[a], cn[j, b], sn[j, b])[0]
                acc *= 0.25 * (th1 - th0) * dphi
            else:
                if not fine:
                    # the row's sub-cell centres and h-space solid angles, once
                    for a in range(s_fine):
                        u0 = (i + a / s_fine) / n_theta
                        u1 = (i + (a + 1.0) / s_fine) / n_theta
                        uc = (i + (a + 0.5) / s_fine) / n_theta
                        dwf[a] = (math.cos(u0 * u0 * _HALF_PI) - math.cos(u1 * u1 * _HALF_PI)) * dphi / s_fine
                        thc = uc * uc * _HALF_PI
                        stf[a] = math.sin(thc)
                        ctf[a] = math.cos(thc)
                    fine = True
                for a in range(s_fine):
                    for b in range(s_fine):
                        w = _half_weight_sc(lx, ly, lz, stf[a], ctf[a], cf[j, b], sf[j, b])[0]
                        if w > 0.0:
                            acc += w / stf[a] * dwf[a]
            omega[i, j] = acc
    return omega


@dataclass(frozen=True)
class SliceGrid:
    """The cells of one slice family: a parametrization and a resolution.

    ``side`` is ``"reflection"`` (BRDF, ``v_z > 0``) or ``"transmission"`` (BTDF, ``v_z < 0``).
    """

    parametrization: str = "classic"
    n_theta: int = 90
    n_phi: int = 360
    side: str = "reflection"

    def __post_init__(self) -> None:
        if self.parametrization not in PARAMETRIZATIONS:
            raise ValueError(f"parametrization: {self.parametrization!r} is not one of classic, half, rgl")
        if self.side not in ("reflection", "transmission"):
            raise ValueError(f"side: {self.side!r} is not one of reflection, transmission")
        for name in ("n_theta", "n_phi"):
            n = getattr(self, name)
            if not isinstance(n, (int, np.integer)) or isinstance(n, bool) or not 1 <= n <= 100_000:
                raise ValueError(f"resolution: {name} = {n!r} must be an integer in [1, 100000]")

    @property
    def code(self) -> int:
        return PARAMETRIZATIONS[self.parametrization]

    @property
    def transmission(self) -> bool:
        return self.side == "transmission"

    @property
    def shape(self) -> tuple[int, int]:
        return (self.n_theta, self.n_phi)

    def theta_edges_deg(self) -> np.ndarray:
        """Cell edges along the first axis: theta_v (classic) or theta_h (half), in degrees."""
        u = np.linspace(0.0, 1.0, self.n_theta + 1)
        return 90.0 * (u if self.parametrization == "classic" else u * u)

    def phi_edges_deg(self) -> np.ndarray:
        """Cell edges along the second axis: phi_v (classic) or phi_h (half), in degrees."""
        return np.linspace(0.0, 360.0, self.n_phi + 1)

    def theta_centers_deg(self) -> np.ndarray:
        """Cell centres in the slice's own coordinate (mid-cell in sqrt-space for half), degrees."""
        u = (np.arange(self.n_theta) + 0.5) / self.n_theta
        return 90.0 * (u if self.parametrization == "classic" else u * u)

    def phi_centers_deg(self) -> np.ndarray:
        return (np.arange(self.n_phi) + 0.5) * (360.0 / self.n_phi)

    def subcells(self, light: np.ndarray, s: int = 5) -> tuple[np.ndarray, np.ndarray]:
        """Sub-cell centre directions and their projected solid angles.

        Each cell is split into ``s x s`` sub-cells uniform in the slice's own coordinates
        (theta or the square-root-mapped index for half slices, and phi). Returns
        ``(v, w)``: ``v`` of shape ``(n_theta, n_phi, s, s, 3)`` (unit outgoing directions on
        the slice's side) and ``w`` of shape ``(n_theta, n_phi, s, s)``, the sub-cell's projected
        solid angle (exact for classic; for half, the exact h-space solid angle times
        ``|cos theta_v| 4 (l.h)`` at the centre; 0 where the centre maps to no real direction).
        """
        l = _unit(light)
        if s < 1:
            raise ValueError(f"sub-cells: s = {s} must be >= 1")
        if self.parametrization == "half":
            return _half_subcells(l[0], l[1], l[2], self.n_theta, self.n_phi, s, self.transmission)
        dth = _HALF_PI / self.n_theta / s
        dph = _TWO_PI / self.n_phi / s
        th_e = np.arange(self.n_theta * s + 1) * dth
        th_c = (np.arange(self.n_theta * s) + 0.5) * dth
        ph_c = (np.arange(self.n_phi * s) + 0.5) * dph
        w_th = 0.5 * (np.sin(th_e[1:]) ** 2 - np.sin(th_e[:-1]) ** 2) * dph
        st, ct = np.sin(th_c), np.cos(th_c)
        if self.transmission:
            ct = -ct
        v = np.empty((self.n_theta * s, self.n_phi * s, 3))
        v[..., 0] = st[:, None] * np.cos(ph_c)[None, :]
        v[..., 1] = st[:, None] * np.sin(ph_c)[None, :]
        v[..., 2] = ct[:, None]
        w = np.broadcast_to(w_th[:, None], (self.n_theta * s, self.n_phi * s))
        v = v.reshape(self.n_theta, s, self.n_phi, s, 3).transpose(0, 2, 1, 3, 4)
        w = w.reshape(self.n_theta, s, self.n_phi, s).transpose(0, 2, 1, 3)
        return np.ascontiguousarray(v), np.ascontiguousarray(w)

    def proj_solid_angle(self, light: np.ndarray) -> np.ndarray:
        """Projected solid angle ``Omega`` of every cell, shape ``(n_theta, n_phi)``, in sr.

        Exact for classic cells; for half cells, Gauss-Legendre (:data:`OMEGA_GAUSS` points per axis)
        over cells entirely on the valid side (exact to rounding), and
        :data:`OMEGA_STRADDLE_SUBCELLS` midpoint sub-cells per axis (exact h-space solid angles,
        clipped at the horizon) over cells the horizon crosses: those are masked for comparisons
        unless the horizon only clips a corner, where the relative error is ~3e-5 at worst.
        """
        if self.parametrization == "classic":
            th = np.linspace(0.0, _HALF_PI, self.n_theta + 1)
            row = 0.5 * (np.sin(th[1:]) ** 2 - np.sin(th[:-1]) ** 2) * (_TWO_PI / self.n_phi)
            return np.repeat(row[:, None], self.n_phi, axis=1)
        l = _unit(light)
        gx, gw = np.polynomial.legendre.leggauss(OMEGA_GAUSS)
        return _half_omega_exact(l[0], l[1], l[2], self.n_theta, self.n_phi, gx, gw, OMEGA_STRADDLE_SUBCELLS)

    def mask(self, light: np.ndarray, s: int = 5) -> np.ndarray:
        """Cells valid for comparisons, shape ``(n_theta, n_phi)`` bool.

        Classic: every cell. Half: every sub-cell centre (``s x s``) maps to a real direction
        on the slice's side, and row 0 (degenerate, width ``(1/n_theta)^2 90`` deg) is excluded.
        """
        if self.parametrization == "classic":
            return np.ones(self.shape, dtype=bool)
        l = _unit(light)
        valid = _half_omega(l[0], l[1], l[2], self.n_theta, self.n_phi, s)[1]
        valid[0, :] = False
        return valid

    def integrate(self, light: np.ndarray, f, s: int = 5) -> np.ndarray:
        """Cell values ``fbar = Int f |cos theta_v| dw / Int |cos theta_v| dw`` of a BSDF ``f``.

        ``f(l, v)`` receives the unit light direction ``l`` (3,) and an array ``v`` (..., 3) of
        sub-cell centre directions and returns values of shape (...) or (..., C). The result has
        shape (n_theta, n_phi) or (n_theta, n_phi, C); cells without any valid sub-cell get 0.
        """
        l = _unit(light)
        v, w = self.subcells(l, s)
        vals = np.asarray(f(l, v), dtype=np.float64)
        extra = vals.shape[4:]
        ww = w.reshape(w.shape + (1,) * len(extra))
        num = np.sum(vals * ww, axis=(2, 3))
        den = np.sum(w, axis=(2, 3)).reshape(self.shape + (1,) * len(extra))
        return np.divide(num, den, out=np.zeros_like(num), where=den > 0)

    def cell_of(self, light: np.ndarray, v: np.ndarray) -> tuple[int, int]:
        """Cell of one outgoing direction ``v`` (``(-1, -1)`` if on the wrong side)."""
        l = _unit(light)
        d = _unit(v)
        return cell_index(self.code, self.transmission, l[0], l[1], l[2], d[0], d[1], d[2],
                          self.n_theta, self.n_phi)


def light_direction(theta_deg: float, phi_deg: float = 0.0) -> np.ndarray:
    """Unit light direction ``l`` (pointing towards the light) from its elevation and azimuth."""
    t = math.radians(theta_deg)
    p = math.radians(phi_deg)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


def _unit(x) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64).reshape(3)
    n = float(np.linalg.norm(a))
    if not n > 0.0:
        raise ValueError("direction: zero vector")
    return a / n
