"""The sample-space warp of the RGL format (``docs/rgl-format.md``, the warp): a density tabulated
at the nodes of a uniform grid over the unit square, bilinear between them, and its marginal and
conditional CDFs -- the continuous 2-D distribution (``Marginal2D<..., true>``) Mitsuba 3 and pbrt-v4
build from a file's ``vndf`` slice. ``invert`` maps a half vector's square coordinates ``(x, y)``
to the sample-space point ``u`` the readers look the stored values up at; ``sample`` is its inverse.

Coordinates: a table of shape ``(H, W)`` has node ``(k, j)`` at ``(x, y) = (j / (W - 1), k / (H - 1))``
(x along the last axis). For a direction of polar angles ``(theta, phi)``:
``x = sqrt(theta / (pi / 2))``, ``y = (phi + pi) / (2 pi)`` (``docs/rgl-format.md``).

The CDFs: row ``k``'s density ``p_k(x)`` is linear between nodes; ``C_k(x) = int_0^x p_k``;
``m_k = C_k(1)``. Between rows ``k`` and ``k + 1`` (fraction ``t``) the density is
``(1 - t) p_k + t p_{k+1}``, so ``u_x = ((1 - t) C_k(x) + t C_{k+1}(x)) / ((1 - t) m_k + t m_{k+1})``
and ``u_y = F(y) / F(1)`` with ``F`` the integral of the (piecewise-linear) marginal ``m(y)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

__all__ = ["Warp2D", "bilinear", "invert_point", "pack_kernel_tables"]

#: header entries of the packed kernel tables before the marginal CDF (H, W, phi_i, isotropic)
HEAD = 4


@dataclass(frozen=True)
class Warp2D:
    """One slice's warp: the node densities ``data`` (H, W), >= 0, positive somewhere, and its CDF
    tables (see the module docstring). Vectorised numpy for everything but the tracer."""

    data: np.ndarray
    row_cum: np.ndarray   # (H, W): C_k at the nodes x_j
    row_int: np.ndarray   # (H,): m_k
    marg_cum: np.ndarray  # (H,): F at the nodes y_k

    @classmethod
    def from_density(cls, data: np.ndarray) -> "Warp2D":
        d = np.asarray(data, dtype=np.float64)
        if d.ndim != 2 or d.shape[0] < 2 or d.shape[1] < 2:
            raise ValueError(f"warp: a density table needs at least 2 x 2 nodes, got {d.shape}")
        if not np.all(np.isfinite(d)) or np.any(d < 0) or not np.any(d > 0):
            raise ValueError("warp: the density must be finite, >= 0 and positive somewhere")
        H, W = d.shape
        dx, dy = 1.0 / (W - 1), 1.0 / (H - 1)
        row_cum = np.zeros((H, W))
        row_cum[:, 1:] = np.cumsum(0.5 * dx * (d[:, 1:] + d[:, :-1]), axis=1)
        row_int = row_cum[:, -1].copy()
        marg_cum = np.zeros(H)
        marg_cum[1:] = np.cumsum(0.5 * dy * (row_int[1:] + row_int[:-1]))
        return cls(d, row_cum, row_int, marg_cum)

    @property
    def shape(self) -> tuple[int, int]:
        return self.data.shape

    def pdf(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Density at ``(x, y)`` per unit area of the square (integrates to 1)."""
        H, W = self.shape
        j, s = _cell(np.asarray(x, dtype=np.float64), W)
        k, t = _cell(np.asarray(y, dtype=np.float64), H)
        d = self.data
        v = ((1 - t) * ((1 - s) * d[k, j] + s * d[k, j + 1]) + t * ((1 - s) * d[k + 1, j] + s * d[k + 1, j + 1]))
        return v / self.marg_cum[-1]

    def invert(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Sample-space point ``(u_x, u_y)`` of square point ``(x, y)`` (the readers' ``invert``)."""
        H, W = self.shape
        x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
        y = np.clip(np.asarray(y, dtype=np.float64), 0.0, 1.0)
        j, s = _cell(x, W)
        k, t = _cell(y, H)
        dx, dy = 1.0 / (W - 1), 1.0 / (H - 1)
        d, c = self.data, self.row_cum
        ck0 = c[k, j] + dx * (d[k, j] * s + 0.5 * (d[k, j + 1] - d[k, j]) * s * s)
        ck1 = c[k + 1, j] + dx * (d[k + 1, j] * s + 0.5 * (d[k + 1, j + 1] - d[k + 1, j]) * s * s)
        m0, m1 = self.row_int[k], self.row_int[k + 1]
        den = (1 - t) * m0 + t * m1
        ux = np.where(den > 0, ((1 - t) * ck0 + t * ck1) / np.where(den > 0, den, 1.0), 0.0)
        fy = self.marg_cum[k] + dy * (m0 * t + 0.5 * (m1 - m0) * t * t)
        return np.clip(ux, 0.0, 1.0), np.clip(fy / self.marg_cum[-1], 0.0, 1.0)

    def sample(self, ux: np.ndarray, uy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Square point ``(x, y)`` of sample-space point ``(u_x, u_y)`` (the readers' ``sample``)."""
        H, W = self.shape
        ux = np.clip(np.asarray(ux, dtype=np.float64), 0.0, 1.0)
        uy = np.clip(np.asarray(uy, dtype=np.float64), 0.0, 1.0)
        dx, dy = 1.0 / (W - 1), 1.0 / (H - 1)
        # y: the marginal's row, then the root of F_k + dy (m0 t + (m1 - m0) t^2 / 2) = target
        target = uy * self.marg_cum[-1]
        k = np.clip(np.searchsorted(self.marg_cum, target, side="right") - 1, 0, H - 2)
        m0, m1 = self.row_int[k], self.row_int[k + 1]
        t = _linear_root(m0, m1, (target - self.marg_cum[k]) / dy)
        y = (k + t) * dy
        # x: the conditional row blended between rows k and k + 1
        d, c = self.data, self.row_cum
        rows = (1 - t)[..., None] * c[k] + t[..., None] * c[k + 1]           # (..., W)
        target_x = ux * ((1 - t) * m0 + t * m1)
        j = np.clip(np.sum(rows <= target_x[..., None], axis=-1) - 1, 0, W - 2)
        p0 = (1 - t) * d[k, j] + t * d[k + 1, j]
        p1 = (1 - t) * d[k, j + 1] + t * d[k + 1, j + 1]
        base = np.take_along_axis(rows, j[..., None], axis=-1)[..., 0]
        s = _linear_root(p0, p1, (target_x - base) / dx)
        return (j + s) * dx, y


def bilinear(table: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The readers' bilinear interpolant of a node table (H, W) at square points (x, y) (clipped
    to the square); how they evaluate ``ndf``, ``sigma`` and the stored values."""
    H, W = table.shape
    j, s = _cell(np.asarray(x, dtype=np.float64), W)
    k, t = _cell(np.asarray(y, dtype=np.float64), H)
    return ((1 - t) * ((1 - s) * table[k, j] + s * table[k, j + 1])
            + t * ((1 - s) * table[k + 1, j] + s * table[k + 1, j + 1]))


def _cell(x: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Patch index (0 .. n - 2) and fraction in it of node coordinates in [0, 1]."""
    g = np.clip(x, 0.0, 1.0) * (n - 1)
    i = np.minimum(np.floor(g).astype(np.int64), n - 2)
    return i, g - i


def _linear_root(a, b, target):
    """The t in [0, 1] with a t + (b - a) t^2 / 2 = target (the integral of a density linear from a
    to b): the stable root of the quadratic, linear where b == a."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    target = np.maximum(np.asarray(target, dtype=np.float64), 0.0)
    q = b - a
    disc = np.sqrt(np.maximum(a * a + 2.0 * q * target, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(np.abs(q) > 1e-12 * np.maximum(np.abs(a), 1e-300), 2.0 * target / (a + disc),
                     np.where(a > 0, target / np.where(a > 0, a, 1.0), 0.0))
    return np.clip(np.nan_to_num(t), 0.0, 1.0)


def pack_kernel_tables(warp: Warp2D, phi_i: float, isotropic: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The warp of one incident direction as the tracer's three table arguments (in the slots the
    classic and half grids use for their boundary tables): ``head`` = [H, W, phi_i (rad),
    isotropic, F at the nodes (H), m_k (H)], the node densities and the row CDFs, flat."""
    H, W = warp.shape
    head = np.concatenate([[H, W, phi_i, 1.0 if isotropic else 0.0], warp.marg_cum, warp.row_int])
    return head, np.ascontiguousarray(warp.data.ravel()), np.ascontiguousarray(warp.row_cum.ravel())


#: atan(w) / w as a polynomial in w^2 on [0, tan^2(pi / 8)] (least squares at Chebyshev nodes against
#: the long-double arctan; relative error below 2.5e-15): :func:`atan2_poly`
_ATAN = (1.0, -0.3333333333323848, 0.19999999980351277, -0.14285712758863092, 0.1111105143299935,
         -0.09089569795051582, 0.0767390481382, -0.06508007841765179, 0.050308075230791796, -0.02539222997833019)
_TAN_PI_8 = 0.41421356237309503


@numba.njit(cache=True, error_model='numpy', inline='always')
def atan2_poly(y: float, x: float) -> float:
    """``atan2(y, x)`` in (-pi, pi] to a few ulp without libm and without branches (selects only),
    so that a loop calling it is cheap: the octant by selects, the argument reduced to
    |w| <= tan(pi / 8) (``atan z = pi / 4 + atan((z - 1) / (z + 1))``), then :data:`_ATAN`.
    ``atan2(0, 0) = 0`` as libm's for +0."""
    ax = abs(x)
    ay = abs(y)
    mx = max(ax, ay)
    z = min(ax, ay) / (mx if mx > 0.0 else 1.0)
    big = z > _TAN_PI_8
    w = (z - 1.0) / (z + 1.0) if big else z
    t = w * w
    p = _ATAN[9]
    p = p * t + _ATAN[8]
    p = p * t + _ATAN[7]
    p = p * t + _ATAN[6]
    p = p * t + _ATAN[5]
    p = p * t + _ATAN[4]
    p = p * t + _ATAN[3]
    p = p * t + _ATAN[2]
    p = p * t + _ATAN[1]
    p = p * t + _ATAN[0]
    r = w * p + (0.25 * math.pi if big else 0.0)
    r = 0.5 * math.pi - r if ay > ax else r
    r = math.pi - r if x < 0.0 else r
    return -r if y < 0.0 else r


@numba.njit(cache=True, error_model='numpy', inline='always')
def invert_point(lx, ly, lz, vx, vy, vz, n, head, data, cum):
    """The node ``(row, col)`` of the ``n x n`` sample-space grid whose dual cell holds exit ``v``
    for light ``l`` (both pointing away from the surface), through the warp packed by
    :func:`pack_kernel_tables`: ``(-1, -1)`` for ``v`` below the horizon. The dual cell of node
    ``(k, c)`` spans ``u`` within half a node spacing of ``(c, k) / (n - 1)``."""
    if vz <= 0.0:
        return -1, -1
    # the half vector l + v, unnormalised: both its angles are ratios (atan2 keeps the pole exact)
    hx = lx + vx
    hy = ly + vy
    hz = lz + vz
    theta = atan2_poly(math.sqrt(hx * hx + hy * hy), hz)
    phi = atan2_poly(hy, hx)
    H = int(head[0])
    W = int(head[1])
    if head[3] != 0.0:
        phi -= head[2]
    x = math.sqrt(theta / (0.5 * math.pi))
    y = (phi + math.pi) / (2.0 * math.pi)
    y -= math.floor(y)
    x = min(max(x, 0.0), 1.0)
    gx = x * (W - 1)
    j = min(int(gx), W - 2)
    s = gx - j
    gy = y * (H - 1)
    k = min(int(gy), H - 2)
    t = gy - k
    dx = 1.0 / (W - 1)
    dy = 1.0 / (H - 1)
    a = k * W + j
    b = a + W
    ck0 = cum[a] + dx * (data[a] * s + 0.5 * (data[a + 1] - data[a]) * s * s)
    ck1 = cum[b] + dx * (data[b] * s + 0.5 * (data[b + 1] - data[b]) * s * s)
    m0 = head[HEAD + H + k]
    m1 = head[HEAD + H + k + 1]
    den = (1.0 - t) * m0 + t * m1
    ux = ((1.0 - t) * ck0 + t * ck1) / den if den > 0.0 else 0.0
    fy = head[HEAD + k] + dy * (m0 * t + 0.5 * (m1 - m0) * t * t)
    uy = fy / head[HEAD + H - 1]
    c = int(min(max(ux, 0.0), 1.0) * (n - 1) + 0.5)
    r = int(min(max(uy, 0.0), 1.0) * (n - 1) + 0.5)
    return min(r, n - 1), min(c, n - 1)
