"""Mean-transmission and mean-refraction tables of a rough GGX dielectric interface: the two look-up
tables of the real-time multi-layered microfacet model (S. Steinberg 2016, "Light transport through
a microfacet layer"), computed by our own deterministic quadrature instead of the article's curve
fits; used by :mod:`models.multilayer_lut`.

Light arrives from ``v`` (unit, pointing away from the interface, ``mu = v_z > 0``, z the macro
normal) onto an isotropic GGX interface of roughness ``alpha`` and *relative* index
``eta = n_far / n_near``; facets are weighted by the GGX visible normal distribution ``D_v`` of ``v``:

* ``T(mu, alpha, eta) = Int D_v(m) (1 - F(v.m, eta)) dm``, the mean Fresnel transmission;
* ``C(mu, alpha, eta)``, the cosine (to the macro normal) of the mean refracted direction, weighted
  by the transmitted energy; stored as the residual ``dC = C - C0`` from Snell's cosine ``C0``.

Tables ``up[mu, alpha, eta, q]`` (``eta >= 1``) and ``down[mu, alpha, eta, q]`` (``eta < 1``, mu
split at the critical cosine), ``q`` = 0: ``T``, 1: ``dC``; float64, trilinear in mapped
coordinates, inputs clamped to [ETA_MIN, ETA_MAX]. Stated lookup errors: ``ERROR_*`` below. One file
``multilayer-lut.npz`` in the cache directory (:mod:`models.tables.cache`), built on first use and
memoised in an ``lru_cache`` (the module's only state). Definitions, choices, smooth limits,
quadrature, grids and measured errors: ``docs/tables.md``.
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
from models.tables.belcour import axis_cell

#: bump whenever the definition, numerics or layout of the tables changes
TABLE_VERSION = 1

ETA_MIN = 1.0 / 3.0
ETA_MAX = 3.0
N_ALPHA = 40
N_MU_UP = 48
N_ETA_UP = 33
N_ETA_DOWN = 41
N_MU_LOWER = 24
N_MU_UPPER = 40
QUAD_Z = 32
QUAD_PHI = 64
MU_FLOOR = 1e-6

#: stated interpolation error bounds (where each holds: ``docs/tables.md``)
ERROR_T_UP = 6e-3
ERROR_T_DOWN = 1.2e-2
ERROR_T_KINK = 2.5e-2
ERROR_TC = 3e-3
#: the corner |eta - 1| < CORNER_ETA with mu < CORNER_MU, and the kink band half-width in mu
CORNER_ETA = 0.02
CORNER_MU = 0.1
KINK_BAND = 0.01

Progress = Callable[[str, float], None]
FILE_NAME = "multilayer-lut.npz"


# --------------------------------------------------------------------------- grids

def n_mu_down() -> int:
    return N_MU_LOWER + N_MU_UPPER - 1


def c_split() -> float:
    """Mapped mu coordinate of the critical-cosine node in the ``down`` table."""
    return (N_MU_LOWER - 1) / (n_mu_down() - 1)


def alpha_nodes() -> np.ndarray:
    """``(k / (N_ALPHA - 1))**2``."""
    return np.linspace(0.0, 1.0, N_ALPHA) ** 2


def mu_up_nodes() -> np.ndarray:
    """``(k / (N_MU_UP - 1))**2``."""
    return np.linspace(0.0, 1.0, N_MU_UP) ** 2


def eta_up_nodes() -> np.ndarray:
    """``1 + (ETA_MAX - 1) t^2``, t uniform: dense next to eta = 1."""
    return 1.0 + (ETA_MAX - 1.0) * np.linspace(0.0, 1.0, N_ETA_UP) ** 2


def eta_down_nodes() -> np.ndarray:
    """``1 - (1 - ETA_MIN) (1 - t)^1.5``, t uniform: dense next to eta = 1."""
    return 1.0 - (1.0 - ETA_MIN) * (1.0 - np.linspace(0.0, 1.0, N_ETA_DOWN)) ** 1.5


def critical_cosine(eta: float) -> float:
    """``sqrt(1 - eta^2)`` for eta < 1 (0 otherwise): beyond it a smooth interface reflects totally."""
    return math.sqrt(max(0.0, 1.0 - eta * eta))


def mu_down_nodes(eta: float) -> np.ndarray:
    """The mu nodes of the ``down`` column of one eta (split at its critical cosine)."""
    mu_c = critical_cosine(eta)
    t = np.linspace(0.0, 1.0, N_MU_LOWER)
    lower = mu_c * (1.0 - (1.0 - t) ** 2)
    t = np.linspace(0.0, 1.0, N_MU_UPPER)
    upper = mu_c + (1.0 - mu_c) * t * t
    return np.concatenate([lower[:-1], upper])


def _grid_signature() -> str:
    return json.dumps({
        "version": TABLE_VERSION, "ETA_MIN": ETA_MIN, "ETA_MAX": ETA_MAX, "N_ALPHA": N_ALPHA,
        "N_MU_UP": N_MU_UP, "N_ETA_UP": N_ETA_UP, "N_ETA_DOWN": N_ETA_DOWN, "N_MU_LOWER": N_MU_LOWER,
        "N_MU_UPPER": N_MU_UPPER, "QUAD_Z": QUAD_Z, "QUAD_PHI": QUAD_PHI, "MU_FLOOR": MU_FLOOR,
    }, sort_keys=True)


def quadrature_rule(n_z: int = QUAD_Z, n_phi: int = QUAD_PHI) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(u2, w2, u1, w1)``: Gauss-Legendre nodes/weights on [0, 1] for the cap height ``u2`` and
    midpoint nodes on the half period [0, 1/2] for the azimuth ``u1`` (weights ``1 / n_phi``: the
    other half is the mirror image). Each weight set sums to 1."""
    x, w = np.polynomial.legendre.leggauss(n_z)
    u1 = (np.arange(n_phi) + 0.5) / (2.0 * n_phi)
    return 0.5 * (x + 1.0), 0.5 * w, u1, np.full(n_phi, 1.0 / n_phi)


# --------------------------------------------------------------------------- physics (njit)

@njit(cache=True)
def smooth_limit(mu: float, eta: float) -> tuple:
    """``(T0, C0)`` of a perfectly smooth interface: ``1 - F(mu, eta)`` and Snell's cosine of the
    refracted direction (0 under total internal reflection). ``mu`` is clamped to [0, 1]."""
    mu = min(max(mu, 0.0), 1.0)
    t0 = 1.0 - optics.fresnel_dielectric(mu, eta)
    s2 = (1.0 - mu * mu) / (eta * eta)
    c0 = math.sqrt(1.0 - s2) if s2 < 1.0 else 0.0
    return t0, c0


@njit(cache=True)
def quadrature(mu: float, alpha: float, eta: float, u2: np.ndarray, w2: np.ndarray,
               u1: np.ndarray, w1: np.ndarray) -> tuple:
    """``(T, C, S)`` at one point by the product rule (no tables): transmission, cosine of the
    mean refracted direction, and the (signed, forward positive) sine of that direction.

    ``alpha = 0`` returns the smooth limit exactly (``S`` = Snell's sine).
    """
    mu = min(max(mu, MU_FLOOR), 1.0)
    vx = math.sqrt(max(0.0, 1.0 - mu * mu))
    vz = mu
    if alpha <= 0.0:
        t0, c0 = smooth_limit(mu, eta)
        return t0, c0, math.sqrt(max(0.0, 1.0 - c0 * c0))
    acc = 0.0
    tx = 0.0
    tz = 0.0
    for i in range(u2.shape[0]):
        for j in range(u1.shape[0]):
            mx, my, mz = optics.sample_vndf(vx, 0.0, vz, alpha, alpha, u1[j], u2[i])
            f = optics.fresnel_dielectric(vx * mx + vz * mz, eta)
            w = w2[i] * w1[j] * (1.0 - f)
            if w <= 0.0:
                continue
            acc += w
            rx, ry, rz, ok = optics.refract(vx, 0.0, vz, mx, my, mz, eta)
            if ok and rz < 0.0:
                tx += w * rx
                tz += w * rz
    norm = math.sqrt(tx * tx + tz * tz)
    if norm <= 0.0:
        t0, c0 = smooth_limit(mu, eta)
        return acc, c0, math.sqrt(max(0.0, 1.0 - c0 * c0))
    return acc, -tz / norm, -tx / norm


@njit(parallel=True, cache=True)
def _fill(mus: np.ndarray, alphas: np.ndarray, etas: np.ndarray, u2: np.ndarray, w2: np.ndarray,
          u1: np.ndarray, w1: np.ndarray, out: np.ndarray, sines: np.ndarray) -> None:
    """Table ``out[i, j, k, :] = (T, C - C0)`` at ``(mus[i, k], alphas[j], etas[k])`` (``T`` is 0 at
    alpha = 0, where :func:`lookup` uses the exact smooth value);
    ``sines[i, j, k]`` receives the signed sine of the mean direction (a build-time check)."""
    n_mu = mus.shape[0]
    n_a = alphas.shape[0]
    n_e = etas.shape[0]
    for idx in numba.prange(n_mu * n_a * n_e):
        k = idx % n_e
        j = (idx // n_e) % n_a
        i = idx // (n_e * n_a)
        mu = max(mus[i, k], MU_FLOOR)
        t, c, s = quadrature(mu, alphas[j], etas[k], u2, w2, u1, w1)
        t0, c0 = smooth_limit(mu, etas[k])
        out[i, j, k, 0] = t if alphas[j] > 0.0 else 0.0
        out[i, j, k, 1] = c - c0
        sines[i, j, k] = s


# --------------------------------------------------------------------------- lookups (njit)

@njit(cache=True)
def down_coordinate(mu: float, mu_c: float, split: float) -> float:
    """Mapped mu coordinate in the ``down`` table for a column whose critical cosine is ``mu_c``."""
    mu = min(max(mu, 0.0), 1.0)
    if mu < mu_c:
        return split * (1.0 - math.sqrt(1.0 - mu / mu_c))
    if mu_c >= 1.0:
        return split
    return split + (1.0 - split) * math.sqrt((mu - mu_c) / (1.0 - mu_c))


@njit(cache=True)
def prepare(up: np.ndarray, down: np.ndarray, alpha: float, eta: float) -> tuple:
    """The part of a lookup that depends only on the interface: ``(j, fj, k, fk, w0)``.

    ``j, fj``: alpha cell and fraction; ``k, fk``: eta cell and fraction in the table of ``eta``
    (``up`` for eta >= 1, ``down`` otherwise); ``w0``: weight of the alpha = 0 node (0 if alpha is
    at or beyond the first non-zero node). See :func:`lookup_prepared`.
    """
    alpha = min(max(alpha, 0.0), 1.0)
    ta = math.sqrt(alpha)
    if eta >= 1.0:
        te = math.sqrt(min(eta - 1.0, ETA_MAX - 1.0) / (ETA_MAX - 1.0))
        k, fk = axis_cell(te, up.shape[2])
    else:
        te = 1.0 - (min(1.0 - eta, 1.0 - ETA_MIN) / (1.0 - ETA_MIN)) ** (2.0 / 3.0)
        k, fk = axis_cell(te, down.shape[2])
    j, fj = axis_cell(ta, up.shape[1])
    w0 = (1.0 - fj) if j == 0 else 0.0
    return j, fj, k, fk, w0


@njit(cache=True)
def lookup_prepared(up: np.ndarray, down: np.ndarray, split: float, j: int, fj: float, k: int, fk: float,
                    w0: float, mu: float, eta: float) -> tuple:
    """``(T, C)`` at ``mu`` for an interface prepared by :func:`prepare` (same ``eta``)."""
    mu = min(max(mu, 0.0), 1.0)
    s2 = (1.0 - mu * mu) / (eta * eta)
    c0 = math.sqrt(1.0 - s2) if s2 < 1.0 else 0.0
    if eta >= 1.0:
        tab = up
        tm = math.sqrt(mu)
    else:
        tab = down
        tm = down_coordinate(mu, math.sqrt(max(0.0, 1.0 - eta * eta)), split)
    i, fi = axis_cell(tm, tab.shape[0])
    t = 0.0
    dc = 0.0
    for di in range(2):
        wi = fi if di else 1.0 - fi
        for dj in range(2):
            wj = fj if dj else 1.0 - fj
            for dk in range(2):
                w = wi * wj * (fk if dk else 1.0 - fk)
                t += w * tab[i + di, j + dj, k + dk, 0]
                dc += w * tab[i + di, j + dj, k + dk, 1]
    if w0 > 0.0:
        # the alpha = 0 nodes of T hold 0: blend in the exact smooth transmission of the query
        t += w0 * (1.0 - optics.fresnel_dielectric(mu, eta))
    return min(max(t, 0.0), 1.0), min(max(c0 + dc, 0.0), 1.0)


@njit(cache=True)
def lookup(up: np.ndarray, down: np.ndarray, split: float, mu: float, alpha: float, eta: float) -> tuple:
    """``(T, C)`` at ``(mu, alpha, eta)`` (usable from numba kernels).

    ``mu = cos theta`` of the incident direction on the side of the light (clamped to [0, 1]),
    ``alpha`` the GGX roughness (clamped to [0, 1]), ``eta`` the relative index ``n_far / n_near``
    (the table part is clamped to [ETA_MIN, ETA_MAX]; the analytic part is exact for any eta).
    ``split`` is :func:`c_split` of the tables. Both results are clamped to [0, 1]. ``T`` is
    interpolated directly, with the exact smooth ``1 - F(mu, eta)`` in place of the alpha = 0 nodes;
    ``C`` is Snell's cosine at the query plus the interpolated residual.
    """
    j, fj, k, fk, w0 = prepare(up, down, alpha, eta)
    return lookup_prepared(up, down, split, j, fj, k, fk, w0, mu, eta)


@njit(cache=True)
def _lookup_many(up, down, split, mu, alpha, eta, out_t, out_c):
    for n in range(mu.shape[0]):
        out_t[n], out_c[n] = lookup(up, down, split, mu[n], alpha[n], eta[n])


@njit(parallel=True, cache=True)
def _quadrature_many(mu, alpha, eta, u2, w2, u1, w1, out):
    for n in numba.prange(mu.shape[0]):
        t, c, s = quadrature(mu[n], alpha[n], eta[n], u2, w2, u1, w1)
        out[n, 0] = t
        out[n, 1] = c
        out[n, 2] = s


def direct(mu, alpha, eta, n_z: int = QUAD_Z, n_phi: int = QUAD_PHI) -> np.ndarray:
    """``(T, C, S)`` by the quadrature itself at each (broadcast) point, shape (..., 3), no tables.

    ``S`` is the signed sine of the mean refracted direction (positive: forward)."""
    mu, alpha, eta = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (mu, alpha, eta)))
    out = np.empty((mu.size, 3))
    _quadrature_many(np.ascontiguousarray(mu).ravel(), np.ascontiguousarray(alpha).ravel(),
                     np.ascontiguousarray(eta).ravel(), *quadrature_rule(n_z, n_phi), out)
    return out.reshape(mu.shape + (3,))


# --------------------------------------------------------------------------- tables and cache

@dataclass(frozen=True)
class MultilayerTables:
    """The loaded tables (read-only; grids, axis order and contents in the module docstring)."""

    up: np.ndarray      # (N_MU_UP, N_ALPHA, N_ETA_UP, 2) float64
    down: np.ndarray    # (N_MU_DOWN, N_ALPHA, N_ETA_DOWN, 2) float64
    split: float        # mapped mu coordinate of the critical-cosine node of ``down``

    @property
    def args(self) -> tuple[np.ndarray, np.ndarray, float]:
        """``(up, down, split)``: the leading arguments of :func:`lookup`."""
        return self.up, self.down, self.split

    def at(self, mu, alpha, eta) -> tuple[np.ndarray, np.ndarray]:
        """Vectorised :func:`lookup`: ``(T, C)`` arrays of the broadcast shape."""
        mu, alpha, eta = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (mu, alpha, eta)))
        t = np.empty(mu.size)
        c = np.empty(mu.size)
        _lookup_many(self.up, self.down, self.split, np.ascontiguousarray(mu).ravel(),
                     np.ascontiguousarray(alpha).ravel(), np.ascontiguousarray(eta).ravel(), t, c)
        return t.reshape(mu.shape), c.reshape(mu.shape)


#: the project's cache directory (``$GONIOMETER_CACHE`` or ``~/.cache/goniometer``)
default_cache_dir = table_cache.default_cache_dir


def table_path(cache_dir: str | os.PathLike | None = None) -> Path:
    """Where the tables live."""
    return table_cache.cache_directory(cache_dir) / FILE_NAME


def compute_tables(progress: Progress | None = None) -> dict[str, np.ndarray]:
    """Compute both tables (no disk access). Raises RuntimeError if a mean refracted
    direction ever points backwards (the cosine would not determine it)."""
    report = progress or (lambda stage, frac: None)
    rule = quadrature_rule()
    alphas = alpha_nodes()
    eta_up = eta_up_nodes()
    eta_dn = eta_down_nodes()
    mus_up = np.repeat(mu_up_nodes()[:, None], N_ETA_UP, axis=1)
    mus_dn = np.stack([mu_down_nodes(e) for e in eta_dn], axis=1)
    n_total = N_ETA_UP + N_ETA_DOWN
    out = {}
    done = 0
    for name, mus, etas in (("up", mus_up, eta_up), ("down", mus_dn, eta_dn)):
        tab = np.zeros((mus.shape[0], N_ALPHA, etas.shape[0], 2))
        sines = np.zeros((mus.shape[0], N_ALPHA, etas.shape[0]))
        step = 8
        for k0 in range(0, etas.shape[0], step):
            report(f"{name} table", done / n_total)
            sl = slice(k0, min(k0 + step, etas.shape[0]))
            part = np.zeros((mus.shape[0], N_ALPHA, sl.stop - sl.start, 2))
            s_part = np.zeros((mus.shape[0], N_ALPHA, sl.stop - sl.start))
            _fill(np.ascontiguousarray(mus[:, sl]), alphas, np.ascontiguousarray(etas[sl]), *rule, part, s_part)
            tab[:, :, sl] = part
            sines[:, :, sl] = s_part
            done += sl.stop - sl.start
        if sines.min() < -1e-9:
            raise RuntimeError(f"multilayer tables: a mean refracted direction points backwards ({name})")
        out[name] = tab
    report("done", 1.0)
    return out


def build_multilayer_tables(cache_dir: str | os.PathLike | None = None, progress: Progress | None = None) -> Path:
    """(Re)build the tables and write them atomically; returns the file's path.

    ``progress(stage, fraction)`` is called as the build advances. Clears the loader's memo.
    """
    path = table_path(cache_dir)
    t = compute_tables(progress)
    table_cache.save_atomic(path, version=np.int64(TABLE_VERSION), signature=np.array(_grid_signature()),
                            up=t["up"], down=t["down"], alpha=alpha_nodes(), mu_up=mu_up_nodes(),
                            eta_up=eta_up_nodes(), eta_down=eta_down_nodes())
    _load_cached.cache_clear()
    return path


def read_if_current(path: Path) -> dict[str, np.ndarray] | None:
    """The arrays of ``path`` if it holds tables of the current version and grid, else None."""
    t = table_cache.read_current(path, TABLE_VERSION, _grid_signature(), ("up", "down"), np.float64)
    if t is None:
        return None
    if t["up"].shape != (N_MU_UP, N_ALPHA, N_ETA_UP, 2) or t["down"].shape != (n_mu_down(), N_ALPHA, N_ETA_DOWN, 2):
        return None
    return t


@lru_cache(maxsize=4)
def _load_cached(cache_dir: str) -> MultilayerTables:
    path = table_path(cache_dir)
    t = table_cache.load_or_build(lambda: read_if_current(path), lambda: build_multilayer_tables(cache_dir),
                                  f"the multilayer tables at {path}")
    for a in t.values():
        a.setflags(write=False)
    return MultilayerTables(t["up"], t["down"], c_split())


def load_multilayer_tables(cache_dir: str | os.PathLike | None = None) -> MultilayerTables:
    """The tables, built (and cached on disk) on first use; a stale file is rebuilt.

    Memoised per cache directory in an ``lru_cache``.
    """
    return _load_cached(table_cache.memo_key(cache_dir))
