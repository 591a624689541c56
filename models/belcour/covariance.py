"""Belcour 2018's roughness <-> variance mapping (§2), the transmission scales of an interface (§3),
and the 2 x 2 covariance algebra of the anisotropic extension (Yamaguchi et al. 2019).

Roughness <-> variance: ``f(a) = a^1.1 / (1 - a^1.1)`` (a clamped to [0, ALPHA_MAX]),
``f^-1(s) = (s / (1 + s))^(1/1.1)``. A covariance is stored as its entries ``(xx, xy, yy)`` in the
macro tangent plane (x towards phi = 0); an interface's tangent frame is rotated by ``psi`` about z,
``t_x = (cos psi, sin psi)``, ``t_y = (-sin psi, cos psi)``. Section numbers §n and the rationale of
the FGD lookup roughness: ``docs/belcour.md``.
"""

from __future__ import annotations

import math

from models._jit import njit

ALPHA_MAX = 0.9999


# --------------------------------------------------------------------------- variance mapping

@njit(cache=True)
def roughness_to_variance(alpha: float) -> float:
    """``f(a) = a^1.1 / (1 - a^1.1)`` with ``a`` clamped to [0, 0.9999] (§2)."""
    a = min(max(alpha, 0.0), ALPHA_MAX)
    p = a ** 1.1
    return p / (1.0 - p)


@njit(cache=True)
def variance_to_roughness(var: float) -> float:
    """``f^-1(s) = (s / (1 + s))^(1/1.1)``; ``s <= 0`` (or NaN) gives 0, ``s = inf`` gives 1."""
    if not var > 0.0:
        return 0.0
    if math.isinf(var):
        return 1.0
    return (1.0 / (1.0 + 1.0 / var)) ** (1.0 / 1.1)


@njit(cache=True, inline="always")
def transmission_roughness(a: float, n: float, c: float, c2: float, angular: bool) -> tuple:
    """Roughnesses ``(s_down a, s_up a)`` of the transmission lobes down and up through an interface
    of mean relative index ``n`` (§3): normal-incidence scales ``s_down = |n - 1| / (2 n)``,
    ``s_up = |1 - n| / 2`` (Bati 2021 eq. 6), or with ``angular`` ``s_down = |1 - c / (n c2)| / 2``,
    ``s_up = |1 - n c2 / c| / 2`` (``c``, ``c2``: mean cosines above and below)."""
    if angular:
        return a * 0.5 * abs(1.0 - c / (n * c2)), a * 0.5 * abs(1.0 - n * c2 / c)
    return a * 0.5 * abs(n - 1.0) / n, a * 0.5 * abs(1.0 - n)


# --------------------------------------------------------------------------- 2 x 2 covariances

@njit(cache=True, inline="always")
def interface_covariance(sx: float, sy: float, c: float, s: float) -> tuple:
    """``[t_x t_y] diag(sx, sy) [t_x t_y]^T`` with ``t_x = (c, s)``, ``t_y = (-s, c)`` (Y19 section 3.1):
    ``(xx, xy, yy)``."""
    return sx * c * c + sy * s * s, (sx - sy) * c * s, sx * s * s + sy * c * c


@njit(cache=True, inline="always")
def principal(xx: float, xy: float, yy: float) -> tuple:
    """Eigen-decomposition of a symmetric 2 x 2 matrix: ``(l1, l2, ex, ey)`` with ``l1 >= l2`` and
    ``(ex, ey)`` the unit eigenvector of ``l1`` (``(1, 0)`` when the matrix is a multiple of I)."""
    m = 0.5 * (xx + yy)
    h = 0.5 * (xx - yy)
    r = math.sqrt(h * h + xy * xy)
    if r == 0.0:
        return m, m, 1.0, 0.0
    if h >= 0.0:
        ex, ey = h + r, xy
    else:
        ex, ey = xy, r - h
    inv = 1.0 / math.sqrt(ex * ex + ey * ey)
    return m + r, m - r, ex * inv, ey * inv


@njit(cache=True, inline="always")
def blended_alpha(a1: float, a2: float, ex: float, ey: float, c: float, dx: float, dy: float) -> float:
    """FGD lookup roughness of an anisotropic GGX ``(a1 along (ex, ey), a2 across)`` seen at mean
    cosine ``c`` from azimuth ``d = (dx, dy)``:
    ``sqrt(c^2 (a1^2 + a2^2) / 2 + (1 - c^2) a_d^2)``, ``a_d^2 = a1^2 (d.e1)^2 + a2^2 (d.e2)^2``
    (rationale: ``docs/belcour.md``, "Anisotropic extension")."""
    p = dx * ex + dy * ey
    q = dy * ex - dx * ey
    ad2 = a1 * a1 * p * p + a2 * a2 * q * q
    c2 = c * c
    return math.sqrt(c2 * 0.5 * (a1 * a1 + a2 * a2) + (1.0 - c2) * ad2)


@njit(cache=True)
def lookup_alpha(xx: float, xy: float, yy: float, c: float, dx: float, dy: float) -> float:
    """FGD/TIR lookup roughness of the covariance ``(xx, xy, yy)``: ``f^-1(xx)`` if isotropic, else
    :func:`blended_alpha` of its principal roughnesses ``f^-1(eigenvalue)``."""
    if xy == 0.0 and xx == yy:
        return variance_to_roughness(xx)
    l1, l2, ex, ey = principal(xx, xy, yy)
    return blended_alpha(variance_to_roughness(l1), variance_to_roughness(l2), ex, ey, c, dx, dy)


@njit(cache=True, inline="always")
def lobe_covariance(ax: float, ay: float, c: float, s: float, iso: bool) -> tuple:
    """``(xx, xy, yy)`` of a GGX lobe of roughnesses ``(ax, ay)`` along the tangent axes ``t_x = (c, s)``,
    ``t_y = (-s, c)``: ``(f(ax), 0, f(ax))`` if ``iso`` (so that ``xx`` is the scalar variance), else
    :func:`interface_covariance` of ``f(ax), f(ay)``."""
    if iso:
        v = roughness_to_variance(ax)
        return v, 0.0, v
    return interface_covariance(roughness_to_variance(ax), roughness_to_variance(ay), c, s)


@njit(cache=True, inline="always")
def unit_azimuth(x: float, y: float) -> tuple:
    """Unit azimuth of (x, y); ``(1, 0)`` at the pole."""
    r = math.sqrt(x * x + y * y)
    if r > 0.0:
        return x / r, y / r
    return 1.0, 0.0


@njit(cache=True, inline="always")
def same_as_previous_channel(a, i, ch, nq) -> bool:
    """``a[i, ch, :nq] == a[i, ch - 1, :nq]`` (``ch > 0``): channel ``ch`` of the (co)variances ``a[i]``
    equals channel ``ch - 1``."""
    for q in range(nq):
        if a[i, ch, q] != a[i, ch - 1, q]:
            return False
    return True
