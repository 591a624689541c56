"""FGD and TIR tables for Belcour 2018's layered model, computed by our own numerics.

* ``FGD(mu, alpha, eta, kappa)``: the directional albedo of one isotropic GGX interface seen from
  above (exact unpolarised Fresnel of the complex *relative* index ``eta + i kappa``,
  single-scattering Smith G, separable or height-correlated), ``mu = cos theta_i``. A fraction.
* ``TIR(mu, alpha, eta_up)``: the fraction of a single-scattering GGX reflection lobe (F = 1) that
  can escape through an interface of relative index ``eta_up = n_above / n_current`` above.

Both are moments of one angular quadrature (the *angular kernel* ``kernel[mu, alpha, x]`` over
``x = wi.m``), so a *material slice* -- a (mu, alpha) table for one (eta, kappa), :func:`fgd_slice`,
:func:`tir_slice` -- is exact in (eta, kappa). Grids: ``mu`` uniform in ``sqrt(mu)``, ``alpha``
uniform in ``sqrt(alpha)``, ``eta`` on [0, ETA_MAX], ``kappa`` on [0, KAPPA_MAX], ``eta_up`` on [0, 1];
axis order ``fgd[mu, alpha, eta, kappa]`` (float32), ``tir[mu, alpha, eta_up]``,
``kernel[mu, alpha, x]`` (float64); inputs outside a range are clamped. Stated lookup errors:
:data:`FGD_ERROR`, :data:`TIR_ERROR`. Files ``belcour-fgd-<masking>.npz`` and
``belcour-tir-<masking>.npz`` in the cache directory (:mod:`models.tables.cache`), built on first
use and memoised in ``lru_cache``s (the module's only state). Definitions, numerics, grids, measured
errors and the split slices: ``docs/tables.md``.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Callable

import numba
import numpy as np

from goniometer import optics
from models._jit import njit
from models.tables import cache as table_cache

#: bump whenever the definition, numerics or layout of a table changes
TABLE_VERSION = 2
#: stated absolute error of 4D FGD table lookups where Fresnel has no critical angle (eta >= 1.2 or
#: kappa >= 0.5) for mu >= 0.05
FGD_ERROR = 3e-3
#: stated absolute error of TIR lookups (table and slices) for alpha >= 0.1, mu >= 0.05
TIR_ERROR = 6e-3

N_MU = 64
N_ALPHA = 64
N_X = 257
N_X_LOWER = 65
ETA_MAX = 4.0
N_ETA = 65
KAPPA_MAX = 8.0
N_KAPPA = 65
N_ETA_UP = 65
N_MU_LOWER = 40
N_MU_UPPER = 64
QUAD_R = 96
QUAD_PHI = 192
#: mu = 0 nodes are evaluated at this cosine (the limit is reached well before)
MU_FLOOR = 1e-6
#: relative offset of the two nodes that meet at a split point (one-sided limits of the step)
SPLIT_NUDGE = 1e-9
#: a Fresnel curve with eta < 1 is treated as having a critical angle when kappa < SPLIT_KAPPA
SPLIT_KAPPA = 0.25
#: a slice is split only if its critical cosine is at least (smallest cosine used) - SPLIT_MARGIN
SPLIT_MARGIN = 0.05

Progress = Callable[[str, float], None]


# --------------------------------------------------------------------------- grids

def mu_nodes() -> np.ndarray:
    """Universal mu nodes: ``(k / (N_MU - 1))**2``."""
    return np.linspace(0.0, 1.0, N_MU) ** 2


def alpha_nodes() -> np.ndarray:
    """Alpha nodes: ``(k / (N_ALPHA - 1))**2``."""
    return np.linspace(0.0, 1.0, N_ALPHA) ** 2


def eta_nodes() -> np.ndarray:
    return np.linspace(0.0, ETA_MAX, N_ETA)


def kappa_nodes() -> np.ndarray:
    return np.linspace(0.0, KAPPA_MAX, N_KAPPA)


def eta_up_nodes() -> np.ndarray:
    return np.linspace(0.0, 1.0, N_ETA_UP)


def x_nodes() -> np.ndarray:
    """Universal x nodes ``(k / (N_X - 1))**2`` (:func:`split_x_nodes` without split)."""
    return split_x_nodes(0.0)


def split_lower_nodes(mu_split: float) -> np.ndarray:
    """Lower-piece mu nodes on [0, mu_split], dense at both ends."""
    t = np.linspace(0.0, 1.0, N_MU_LOWER)
    s = np.where(t <= 0.5, 2.0 * t * t, 1.0 - 2.0 * (1.0 - t) ** 2)
    return mu_split * s


def split_x_nodes(x_split: float) -> np.ndarray:
    """x nodes of split kernels: ``N_X_LOWER`` uniform on [0, x_split], then ``N_X`` nodes
    ``x_split + (1 - x_split) t^2`` (dense at the Fresnel kink of total internal reflection)."""
    t = np.linspace(0.0, 1.0, N_X)
    upper = x_split + (1.0 - x_split) * t * t
    if x_split <= 0.0:
        return upper
    return np.concatenate([np.linspace(0.0, x_split, N_X_LOWER)[:-1], upper])


def split_upper_nodes(mu_split: float) -> np.ndarray:
    """Upper-piece mu nodes on [mu_split, 1], dense at the split."""
    t = np.linspace(0.0, 1.0, N_MU_UPPER)
    return mu_split + (1.0 - mu_split) * t * t


def _grid_signature(height_correlated: bool) -> str:
    return json.dumps({
        "version": TABLE_VERSION, "masking": _masking(height_correlated),
        "N_MU": N_MU, "N_ALPHA": N_ALPHA, "N_X": N_X, "ETA_MAX": ETA_MAX, "N_ETA": N_ETA,
        "KAPPA_MAX": KAPPA_MAX, "N_KAPPA": N_KAPPA, "N_ETA_UP": N_ETA_UP, "QUAD_R": QUAD_R,
        "QUAD_PHI": QUAD_PHI, "MU_FLOOR": MU_FLOOR, "x_nodes": "(k/(N_X-1))^2", "mu_nodes": "(k/(N_MU-1))^2",
        "alpha_nodes": "(k/(N_ALPHA-1))^2", "quadrature": "vndf-disc GL r x GL phi halves",
    }, sort_keys=True)


def _masking(height_correlated: bool) -> str:
    return "height-correlated" if height_correlated else "separable"


def _quadrature_rule() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Product rule over the VNDF parameter disc: radius ``r`` (Gauss-Legendre on [0, 1], weights
    including the Jacobian 2 r of ``u1 = r^2``) and azimuth ``u2`` (Gauss-Legendre on each half
    [0, 1/2] and [1/2, 1], whose ends are where the disc warp of Heitz 2018 is singular).
    Both weight sets sum to 1."""
    x, w = np.polynomial.legendre.leggauss(QUAD_R)
    r = 0.5 * (x + 1.0)
    xp, wp = np.polynomial.legendre.leggauss(QUAD_PHI // 2)
    half = 0.25 * (xp + 1.0)
    return r, 0.5 * w * 2.0 * r, np.concatenate([half, 0.5 + half]), np.concatenate([0.25 * wp, 0.25 * wp])


# --------------------------------------------------------------------------- quadrature kernels

@njit(cache=True, inline="always")
def _hat_add(row: np.ndarray, x_split: float, n_lower: int, x: float, w: float) -> None:
    """Add weight ``w`` at ``x`` in [0, 1] to the hat functions of :func:`split_x_nodes`.

    The hats are linear in the mapped coordinate of each piece (``x / x_split`` on the lower
    piece, ``t = sqrt((x - x_split) / (1 - x_split))`` on the upper one), so ``sum_j W_j F(x_j)`` is
    exact for F piecewise linear in that coordinate -- in particular for the ``sqrt`` kink of
    Fresnel at the critical angle when ``x_split`` is the critical cosine. ``n_lower`` is the
    index of the split node (0 without split)."""
    n = row.shape[0]
    x = min(max(x, 0.0), 1.0)
    if x < x_split:
        t = x / x_split * n_lower
        k = int(t)
    else:
        t = math.sqrt((x - x_split) / (1.0 - x_split)) * (n - 1 - n_lower) if x_split < 1.0 else 0.0
        k = int(t)
        t += n_lower
        k += n_lower
    if k > n - 2:
        k = n - 2
    f = min(max(t - k, 0.0), 1.0)
    row[k] += w * (1.0 - f)
    row[k + 1] += w * f


@njit(cache=True)
def _node_moments(mu: float, alpha: float, rr: np.ndarray, rw: np.ndarray, pp: np.ndarray,
                  pw: np.ndarray, height_correlated: bool, x_split: float, n_lower: int, w_row: np.ndarray,
                  eta_up: np.ndarray,
                  c_row: np.ndarray, hist: np.ndarray) -> None:
    """Angular kernel of one (mu, alpha) node (see the module docstring).

    Fills ``w_row`` (hat moments over :func:`split_x_nodes` of ``x_split``, ``n_lower`` nodes below
    the split) and ``c_row`` (escaping fraction at each ``eta_up``,
    sorted ascending). ``hist`` is scratch of the size of ``eta_up``.
    """
    mu = min(max(mu, MU_FLOOR), 1.0)
    wx = math.sqrt(max(0.0, 1.0 - mu * mu))
    wy = 0.0
    wz = mu
    n_up = eta_up.shape[0]
    hist[:] = 0.0
    if alpha <= 0.0:
        _hat_add(w_row, x_split, n_lower, mu, 1.0)
        for k in range(n_up):
            c_row[k] = 1.0 if wx <= eta_up[k] else 0.0
        return
    lam_i = optics.ggx_lambda(wx, wy, wz, alpha, alpha)
    total = 0.0
    for p in range(rr.shape[0]):
        u1 = rr[p] * rr[p]
        for q in range(pp.shape[0]):
            mx, my, mz = optics.sample_vndf(wx, wy, wz, alpha, alpha, u1, pp[q])
            ox, oy, oz = optics.reflect(wx, wy, wz, mx, my, mz)
            if oz <= 0.0:
                continue
            lam_o = optics.ggx_lambda(ox, oy, oz, alpha, alpha)
            if height_correlated:
                g = (1.0 + lam_i) / (1.0 + lam_i + lam_o)
            else:
                g = 1.0 / (1.0 + lam_o)
            w = rw[p] * pw[q] * g
            _hat_add(w_row, x_split, n_lower, wx * mx + wy * my + wz * mz, w)
            if n_up > 0:
                total += w
                s = math.sqrt(max(0.0, 1.0 - oz * oz))
                k0 = np.searchsorted(eta_up, s)
                if k0 < n_up:
                    hist[k0] += w
    if n_up > 0:
        acc = 0.0
        for k in range(n_up):
            acc += hist[k]
            c_row[k] = min(acc / total, 1.0) if total > 0.0 and eta_up[k] < 1.0 else 1.0


@njit(parallel=True, cache=True)
def _angular_kernel(mus: np.ndarray, alphas: np.ndarray, x_split: float, eta_up: np.ndarray,
                    rr: np.ndarray, rw: np.ndarray, pp: np.ndarray, pw: np.ndarray,
                    height_correlated: bool):
    """Hat moments ``W[i, j, :]`` and escaping fractions ``C[i, j, :]`` for all node pairs."""
    nm = mus.shape[0]
    na = alphas.shape[0]
    n_up = eta_up.shape[0]
    n_lower = N_X_LOWER - 1 if x_split > 0.0 else 0
    W = np.zeros((nm, na, n_lower + N_X))
    C = np.ones((nm, na, n_up))
    for idx in numba.prange(nm * na):
        i = idx // na
        j = idx % na
        hist = np.zeros(n_up)
        _node_moments(mus[i], alphas[j], rr, rw, pp, pw, height_correlated, x_split, n_lower, W[i, j], eta_up,
                      C[i, j], hist)
    return W, C


@njit(cache=True)
def _fresnel_column(x: np.ndarray, eta: float, kappa: float, out: np.ndarray) -> None:
    """``out[j] = F(x_j; eta + i kappa)``; the degenerate index 0 + 0i reflects everything."""
    for j in range(x.shape[0]):
        if eta == 0.0 and kappa == 0.0:
            out[j] = 1.0
        else:
            out[j] = optics.fresnel_conductor(x[j], eta, kappa)


@njit(parallel=True, cache=True)
def _fresnel_matrix(x: np.ndarray, etas: np.ndarray, kappas: np.ndarray) -> np.ndarray:
    """F[x, eta, kappa] on the given nodes."""
    ne = etas.shape[0]
    nk = kappas.shape[0]
    out = np.empty((x.shape[0], ne, nk))
    for idx in numba.prange(ne * nk):
        i = idx // nk
        k = idx % nk
        col = np.empty(x.shape[0])
        _fresnel_column(x, etas[i], kappas[k], col)
        out[:, i, k] = col
    return out


def fresnel_on(x: np.ndarray, eta: float, kappa: float) -> np.ndarray:
    """Fresnel reflectance at the cosines ``x`` for one relative complex index."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    out = np.empty(x.shape[0])
    _fresnel_column(x, float(eta), float(kappa), out)
    return out


# --------------------------------------------------------------------------- lookups (njit)

@njit(cache=True, inline="always")
def axis_cell(t: float, n: int):
    """Cell index and fraction of a coordinate t in [0, 1] over n uniform nodes (clamped)."""
    s = min(max(t, 0.0), 1.0) * (n - 1)
    k = min(int(s), n - 2)
    return k, s - k


@njit(cache=True, inline="always")
def _bilinear(tab: np.ndarray, tm: float, ta: float) -> float:
    """Bilinear interpolation of ``tab[mu, alpha]`` at mapped coordinates tm, ta in [0, 1]."""
    i, fi = axis_cell(tm, tab.shape[0])
    j, fj = axis_cell(ta, tab.shape[1])
    v0 = tab[i, j] * (1.0 - fj) + tab[i, j + 1] * fj
    v1 = tab[i + 1, j] * (1.0 - fj) + tab[i + 1, j + 1] * fj
    return v0 * (1.0 - fi) + v1 * fi


@njit(cache=True, inline="always")
def mu_coordinate(mu: float, mu_split: float) -> tuple:
    """Piece (0 lower, 1 upper) and mapped coordinate in [0, 1] of ``mu`` for a slice split at
    ``mu_split`` (0 = no split: the universal ``sqrt(mu)`` mapping)."""
    mu = min(max(mu, 0.0), 1.0)
    if mu < mu_split:
        s = mu / mu_split
        if s <= 0.5:
            return 0, math.sqrt(0.5 * s)
        return 0, 1.0 - math.sqrt(0.5 * (1.0 - s))
    if mu_split >= 1.0:
        return 1, 0.0
    return 1, math.sqrt((mu - mu_split) / (1.0 - mu_split))


@njit(cache=True, inline="always")
def slice_lookup(mu_split: float, lower: np.ndarray, upper: np.ndarray, mu: float, alpha: float) -> float:
    """Value of a material slice (see :class:`TableSlice`) at (mu, alpha), bilinear."""
    piece, tm = mu_coordinate(mu, mu_split)
    ta = math.sqrt(min(max(alpha, 0.0), 1.0))
    if piece == 0:
        return _bilinear(lower, tm, ta)
    return _bilinear(upper, tm, ta)


@njit(cache=True, inline="always")
def _bilinear_at(tab: np.ndarray, e: int, ch: int, tm: float, ta: float) -> float:
    """:func:`_bilinear` on ``tab[e, ch]`` of a 4D stack of 2D tables (no view is created)."""
    i, fi = axis_cell(tm, tab.shape[2])
    j, fj = axis_cell(ta, tab.shape[3])
    v0 = tab[e, ch, i, j] * (1.0 - fj) + tab[e, ch, i, j + 1] * fj
    v1 = tab[e, ch, i + 1, j] * (1.0 - fj) + tab[e, ch, i + 1, j + 1] * fj
    return v0 * (1.0 - fi) + v1 * fi


@njit(cache=True, inline="always")
def stacked_slice_lookup(split: np.ndarray, lower: np.ndarray, upper: np.ndarray, e: int, ch: int,
                         mu: float, alpha: float) -> float:
    """:func:`slice_lookup` of slice ``(split[e, ch], lower[e, ch], upper[e, ch])`` of stacked
    slices (arrays of shape (n, n_channels[, n_mu, n_alpha])), for hot kernels."""
    piece, tm = mu_coordinate(mu, split[e, ch])
    ta = math.sqrt(min(max(alpha, 0.0), 1.0))
    if piece == 0:
        return _bilinear_at(lower, e, ch, tm, ta)
    return _bilinear_at(upper, e, ch, tm, ta)


@njit(cache=True)
def fgd_lookup(fgd: np.ndarray, mu: float, alpha: float, eta: float, kappa: float,
               eta_max: float, kappa_max: float) -> float:
    """Quadrilinear lookup in the 4D table ``fgd[mu, alpha, eta, kappa]`` (clamped ranges)."""
    i, fi = axis_cell(math.sqrt(min(max(mu, 0.0), 1.0)), fgd.shape[0])
    j, fj = axis_cell(math.sqrt(min(max(alpha, 0.0), 1.0)), fgd.shape[1])
    k, fk = axis_cell(eta / eta_max, fgd.shape[2])
    m, fm = axis_cell(kappa / kappa_max, fgd.shape[3])
    acc = 0.0
    for di in range(2):
        wi = fi if di else 1.0 - fi
        for dj in range(2):
            wj = fj if dj else 1.0 - fj
            for dk in range(2):
                wk = fk if dk else 1.0 - fk
                for dm in range(2):
                    wm = fm if dm else 1.0 - fm
                    acc += wi * wj * wk * wm * fgd[i + di, j + dj, k + dk, m + dm]
    return acc


@njit(cache=True)
def tir_lookup(tir: np.ndarray, mu: float, alpha: float, eta_up: float) -> float:
    """Trilinear lookup in ``tir[mu, alpha, eta_up]``; 1 for ``eta_up >= 1``."""
    if eta_up >= 1.0:
        return 1.0
    i, fi = axis_cell(math.sqrt(min(max(mu, 0.0), 1.0)), tir.shape[0])
    j, fj = axis_cell(math.sqrt(min(max(alpha, 0.0), 1.0)), tir.shape[1])
    k, fk = axis_cell(eta_up, tir.shape[2])
    acc = 0.0
    for di in range(2):
        wi = fi if di else 1.0 - fi
        for dj in range(2):
            wj = fj if dj else 1.0 - fj
            for dk in range(2):
                wk = fk if dk else 1.0 - fk
                acc += wi * wj * wk * tir[i + di, j + dj, k + dk]
    return acc


# --------------------------------------------------------------------------- tables and cache

@dataclass(frozen=True)
class BelcourTables:
    """The loaded tables of one masking model (read-only arrays; grids as in the module docstring)."""

    height_correlated: bool
    kernel: np.ndarray      # (N_MU, N_ALPHA, N_X) float64
    fgd: np.ndarray         # (N_MU, N_ALPHA, N_ETA, N_KAPPA) float32
    tir: np.ndarray         # (N_MU, N_ALPHA, N_ETA_UP) float64

    def fgd_at(self, mu, alpha, eta, kappa) -> np.ndarray:
        """Vectorised 4D-table FGD (broadcast inputs)."""
        mu, alpha, eta, kappa = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (mu, alpha, eta, kappa)))
        out = np.empty(mu.shape)
        _fgd_many(self.fgd, mu.ravel(), alpha.ravel(), eta.ravel(), kappa.ravel(), out.reshape(-1))
        return out

    def tir_at(self, mu, alpha, eta_up) -> np.ndarray:
        """Vectorised 3D-table TIR (broadcast inputs)."""
        mu, alpha, eta_up = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (mu, alpha, eta_up)))
        out = np.empty(mu.shape)
        _tir_many(self.tir, mu.ravel(), alpha.ravel(), eta_up.ravel(), out.reshape(-1))
        return out


@njit(cache=True)
def _fgd_many(fgd, mu, alpha, eta, kappa, out):
    for n in range(mu.shape[0]):
        out[n] = fgd_lookup(fgd, mu[n], alpha[n], eta[n], kappa[n], ETA_MAX, KAPPA_MAX)


@njit(cache=True)
def _tir_many(tir, mu, alpha, eta_up, out):
    for n in range(mu.shape[0]):
        out[n] = tir_lookup(tir, mu[n], alpha[n], eta_up[n])


#: the project's cache directory (``$GONIOMETER_CACHE`` or ``~/.cache/goniometer``)
default_cache_dir = table_cache.default_cache_dir


def table_paths(cache_dir: str | os.PathLike | None = None, height_correlated: bool = False) -> dict[str, Path]:
    """Where the FGD and TIR tables of one masking model live."""
    d = table_cache.cache_directory(cache_dir)
    m = _masking(height_correlated)
    return {"fgd": d / f"belcour-fgd-{m}.npz", "tir": d / f"belcour-tir-{m}.npz"}


def compute_tables(height_correlated: bool = False, progress: Progress | None = None) -> dict[str, np.ndarray]:
    """Compute the angular kernel, the 4D FGD table and the 3D TIR table (no disk access)."""
    report = progress or (lambda stage, frac: None)
    report("angular kernel", 0.0)
    rr, rw, pp, pw = _quadrature_rule()
    kernel, tir = _angular_kernel(mu_nodes(), alpha_nodes(), 0.0, eta_up_nodes(), rr, rw, pp, pw,
                                  height_correlated)
    report("fresnel", 0.6)
    F = _fresnel_matrix(x_nodes(), eta_nodes(), kappa_nodes())
    report("fgd table", 0.7)
    fgd = (kernel.reshape(-1, N_X) @ F.reshape(N_X, -1)).reshape(N_MU, N_ALPHA, N_ETA, N_KAPPA)
    # alpha = 0 is a Dirac at x = mu: use Fresnel itself rather than its interpolant on the x nodes
    fgd[:, 0] = _fresnel_matrix(_eval_mu(mu_nodes()), eta_nodes(), kappa_nodes())
    fgd = np.clip(fgd, 0.0, 1.0).astype(np.float32)
    report("done", 1.0)
    return {"kernel": kernel, "fgd": fgd, "tir": np.clip(tir, 0.0, 1.0)}


def build_belcour_tables(cache_dir: str | os.PathLike | None = None, progress: Progress | None = None,
                 height_correlated: bool = False) -> dict[str, Path]:
    """(Re)build the FGD and TIR tables of one masking model and write them atomically.

    ``progress(stage, fraction)`` is called as the build advances. Returns the paths
    ``{"fgd": ..., "tir": ...}``. Clears the in-process loader cache.
    """
    paths = table_paths(cache_dir, height_correlated)
    t = compute_tables(height_correlated, progress)
    sig = _grid_signature(height_correlated)
    common = dict(version=np.int64(TABLE_VERSION), signature=np.array(sig), mu=mu_nodes(), alpha=alpha_nodes())
    table_cache.save_atomic(paths["fgd"], kernel=t["kernel"], fgd=t["fgd"], eta=eta_nodes(), kappa=kappa_nodes(),
                            x=x_nodes(), **common)
    table_cache.save_atomic(paths["tir"], tir=t["tir"], eta_up=eta_up_nodes(), **common)
    _load_cached.cache_clear()
    return paths


def read_if_current(path: Path, height_correlated: bool, keys: tuple[str, ...]) -> dict[str, np.ndarray] | None:
    """The arrays ``keys`` of the table file ``path`` if it holds tables of the current version and
    grid for this masking model, else None (missing, stale or unreadable)."""
    return table_cache.read_current(path, TABLE_VERSION, _grid_signature(height_correlated), keys)


@lru_cache(maxsize=8)
def _load_cached(cache_dir: str, height_correlated: bool) -> BelcourTables:
    paths = table_paths(cache_dir, height_correlated)

    def read() -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]] | None:
        a = read_if_current(paths["fgd"], height_correlated, ("kernel", "fgd"))
        b = read_if_current(paths["tir"], height_correlated, ("tir",))
        return None if a is None or b is None else (a, b)

    a, b = table_cache.load_or_build(read, lambda: build_belcour_tables(cache_dir, None, height_correlated),
                                     f"the Belcour tables in {cache_dir}")
    for arr in (a["kernel"], a["fgd"], b["tir"]):
        arr.setflags(write=False)
    return BelcourTables(height_correlated, a["kernel"], a["fgd"], b["tir"])


def load_belcour_tables(cache_dir: str | os.PathLike | None = None, height_correlated: bool = False) -> BelcourTables:
    """The tables of one masking model, built (and cached on disk) on first use.

    A file with another version or grid is rebuilt. The result is memoised per
    (cache directory, masking) in an ``lru_cache``.
    """
    return _load_cached(table_cache.memo_key(cache_dir), bool(height_correlated))


# --------------------------------------------------------------------------- material slices

@dataclass(frozen=True)
class TableSlice:
    """A 2D (mu, alpha) table for one fixed material parameter, split at ``mu_split``.

    ``lower[N_MU_LOWER, N_ALPHA]`` covers [0, mu_split] and ``upper[n, N_ALPHA]`` covers
    [mu_split, 1] with the mappings of the module docstring (``mu_split = 0``: only ``upper``,
    on the universal mu nodes). Look values up with :func:`slice_lookup` or :meth:`__call__`.
    """

    mu_split: float
    lower: np.ndarray
    upper: np.ndarray

    def __call__(self, mu, alpha) -> np.ndarray:
        mu, alpha = np.broadcast_arrays(np.asarray(mu, dtype=float), np.asarray(alpha, dtype=float))
        out = np.empty(mu.shape)
        _slice_many(self.mu_split, self.lower, self.upper, mu.ravel(), alpha.ravel(), out.reshape(-1))
        return out


@njit(cache=True)
def _slice_many(mu_split, lower, upper, mu, alpha, out):
    for n in range(mu.shape[0]):
        out[n] = slice_lookup(mu_split, lower, upper, mu[n], alpha[n])


def fgd_split_point(eta: float, kappa: float) -> float:
    """Cosine where the slice of (eta, kappa) is split (0 = no critical angle, no split)."""
    if eta < 1.0 and kappa < SPLIT_KAPPA:
        return math.sqrt(max(0.0, 1.0 - eta * eta + kappa * kappa))
    return 0.0


@lru_cache(maxsize=32)
def _split_kernel(mu_split: float, height_correlated: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Angular kernel (over :func:`split_x_nodes`) and escaping fractions (at
    eta_up = sqrt(1 - mu_split^2)) on the split mu nodes (lower piece, upper piece)."""
    lo, hi = _split_eval_nodes(mu_split)
    eta_up = np.array([math.sqrt(max(0.0, 1.0 - mu_split * mu_split))])
    rr, rw, pp, pw = _quadrature_rule()
    mus = np.concatenate([lo, hi])
    W, C = _angular_kernel(mus, alpha_nodes(), mu_split, eta_up, rr, rw, pp, pw, height_correlated)
    n = lo.shape[0]
    for a in (W, C):
        a.setflags(write=False)
    return W[:n], W[n:], C[:n, :, 0], C[n:, :, 0]


def _split_eval_nodes(mu_split: float) -> tuple[np.ndarray, np.ndarray]:
    """Split mu nodes as evaluated: the two nodes at the split are nudged apart (one-sided limits)."""
    lo = split_lower_nodes(mu_split)
    hi = split_upper_nodes(mu_split)
    lo[-1] = mu_split * (1.0 - SPLIT_NUDGE)
    hi[0] = min(1.0, mu_split * (1.0 + SPLIT_NUDGE))
    return _eval_mu(lo), _eval_mu(hi)


def _eval_mu(mus: np.ndarray) -> np.ndarray:
    """The cosines at which mu nodes are evaluated (mu = 0 at MU_FLOOR)."""
    return np.clip(mus, MU_FLOOR, 1.0)


def _freeze(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a, dtype=np.float64)
    a.setflags(write=False)
    return a


def _fgd_from_kernel(W: np.ndarray, xs: np.ndarray, mus: np.ndarray, eta: float, kappa: float) -> np.ndarray:
    """FGD[mu, alpha] = W @ F(x nodes), with the exact Fresnel F(mu) in the alpha = 0 column."""
    out = W @ fresnel_on(xs, eta, kappa)
    out[:, 0] = fresnel_on(mus, eta, kappa)
    return _freeze(np.clip(out, 0.0, 1.0))


@lru_cache(maxsize=256)
def _fgd_slice_cached(eta: float, kappa: float, height_correlated: bool, cache_dir: str | None,
                      split: bool) -> TableSlice:
    mu_split = fgd_split_point(eta, kappa) if split else 0.0
    if mu_split > 0.0:
        w_lo, w_hi, _, _ = _split_kernel(mu_split, height_correlated)
        lo, hi = _split_eval_nodes(mu_split)
        xs = split_x_nodes(mu_split)
        return TableSlice(mu_split, _fgd_from_kernel(w_lo, xs, lo, eta, kappa),
                          _fgd_from_kernel(w_hi, xs, hi, eta, kappa))
    kernel = load_belcour_tables(cache_dir, height_correlated).kernel
    return TableSlice(0.0, _freeze(np.zeros((2, N_ALPHA))),
                      _fgd_from_kernel(kernel, x_nodes(), _eval_mu(mu_nodes()), eta, kappa))


def fgd_slice(eta: float, kappa: float = 0.0, height_correlated: bool = False,
              cache_dir: str | os.PathLike | None = None, mu_min: float = 0.0) -> TableSlice:
    """FGD over (mu, alpha) for one relative complex index, exact in (eta, kappa) (memoised).

    ``mu_min``: the smallest cosine the caller will look up. The slice is split at the critical
    cosine (which needs its own angular kernel, about a second) only if that cosine is above
    ``mu_min - SPLIT_MARGIN``; otherwise the universal mu nodes are exact enough where it is used.
    """
    mu_c = fgd_split_point(eta, kappa)
    split = mu_c > 0.0 and mu_c >= mu_min - SPLIT_MARGIN
    return _fgd_slice_cached(float(eta), float(kappa), bool(height_correlated),
                             None if cache_dir is None else str(cache_dir), split)


def fgd_slice_from_table(tables: BelcourTables, eta: float, kappa: float = 0.0) -> TableSlice:
    """The 4D table interpolated at (eta, kappa): identical to quadrilinear lookups."""
    k, fk = _axis_py(eta / ETA_MAX, N_ETA)
    m, fm = _axis_py(kappa / KAPPA_MAX, N_KAPPA)
    f = tables.fgd.astype(np.float64)
    s = ((1 - fk) * ((1 - fm) * f[:, :, k, m] + fm * f[:, :, k, m + 1])
         + fk * ((1 - fm) * f[:, :, k + 1, m] + fm * f[:, :, k + 1, m + 1]))
    return TableSlice(0.0, _freeze(np.zeros((2, N_ALPHA))), _freeze(s))


def _axis_py(t: float, n: int) -> tuple[int, float]:
    s = min(max(float(t), 0.0), 1.0) * (n - 1)
    k = min(int(s), n - 2)
    return k, s - k


@lru_cache(maxsize=64)
def _tir_slice_cached(eta_up: float, height_correlated: bool) -> TableSlice:
    mu_split = math.sqrt(max(0.0, 1.0 - eta_up * eta_up))
    _, _, c_lo, c_hi = _split_kernel(mu_split, height_correlated)
    return TableSlice(mu_split, _freeze(np.clip(c_lo, 0.0, 1.0)), _freeze(np.clip(c_hi, 0.0, 1.0)))


def tir_slice(eta_up: float, height_correlated: bool = False, cache_dir: str | os.PathLike | None = None,
              mu_min: float = 0.0) -> TableSlice:
    """TIR (escaping fraction) over (mu, alpha) for one ``eta_up``, split at its critical cosine.

    ``eta_up >= 1`` gives the constant 1 (nothing is trapped). When the critical cosine is below
    ``mu_min - SPLIT_MARGIN`` (``mu_min``: smallest cosine the caller looks up) the 3D table
    interpolated at ``eta_up`` is returned instead (no new angular kernel is needed)."""
    eta_up = float(eta_up)
    if eta_up >= 1.0:
        return TableSlice(0.0, _freeze(np.ones((2, N_ALPHA))), _freeze(np.ones((2, N_ALPHA))))
    if math.sqrt(1.0 - eta_up * eta_up) < mu_min - SPLIT_MARGIN:
        return tir_slice_from_table(load_belcour_tables(cache_dir, height_correlated), eta_up)
    return _tir_slice_cached(eta_up, bool(height_correlated))


def tir_slice_from_table(tables: BelcourTables, eta_up: float) -> TableSlice:
    """The 3D TIR table interpolated at ``eta_up`` (identical to trilinear lookups)."""
    if eta_up >= 1.0:
        return TableSlice(0.0, _freeze(np.ones((2, N_ALPHA))), _freeze(np.ones((2, N_ALPHA))))
    k, fk = _axis_py(eta_up, N_ETA_UP)
    s = (1 - fk) * tables.tir[:, :, k] + fk * tables.tir[:, :, k + 1]
    return TableSlice(0.0, _freeze(np.zeros((2, N_ALPHA))), _freeze(s))


# --------------------------------------------------------------------------- direct values

def fgd_direct(mu: float, alpha: float, eta: float, kappa: float = 0.0, height_correlated: bool = False) -> float:
    """FGD at one point by the quadrature itself (no interpolation in mu or alpha; slow-ish: ~1 ms)."""
    rr, rw, pp, pw = _quadrature_rule()
    x_c = fgd_split_point(eta, kappa)
    xs = split_x_nodes(x_c)
    W, _ = _angular_kernel(np.array([float(mu)]), np.array([float(alpha)]), x_c, np.zeros(0), rr, rw,
                           pp, pw, bool(height_correlated))
    return float(min(max(W[0, 0] @ fresnel_on(xs, eta, kappa), 0.0), 1.0))


def fgd_direct_many(mus: np.ndarray, alpha: float, eta: float, kappa: float = 0.0,
                    height_correlated: bool = False) -> np.ndarray:
    """:func:`fgd_direct` at several cosines ``mus`` at once (one angular kernel for all of them)."""
    mus = np.asarray(mus, dtype=np.float64).ravel()
    rr, rw, pp, pw = _quadrature_rule()
    x_c = fgd_split_point(eta, kappa)
    xs = split_x_nodes(x_c)
    W, _ = _angular_kernel(mus, np.array([float(alpha)]), x_c, np.zeros(0), rr, rw, pp, pw,
                           bool(height_correlated))
    return np.clip(W[:, 0] @ fresnel_on(xs, eta, kappa), 0.0, 1.0)


def tir_direct(mu: float, alpha: float, eta_up: float, height_correlated: bool = False) -> float:
    """TIR (escaping fraction) at one point by the quadrature itself."""
    if eta_up >= 1.0:
        return 1.0
    rr, rw, pp, pw = _quadrature_rule()
    _, C = _angular_kernel(np.array([float(mu)]), np.array([float(alpha)]), 0.0,
                           np.array([float(eta_up)]),
                           rr, rw, pp, pw, bool(height_correlated))
    return float(C[0, 0, 0])
