"""Directional-albedo tables of one GGX interface: the ``E(mu)`` and ``E_avg`` of Kulla & Conty's
energy compensation (2017), computed by our own deterministic quadrature for the exact roughness
and index of the interface being modelled (no interpolation in alpha or eta); used by
:mod:`models.production.kulla_conty`.

Light arrives from ``l`` (unit, pointing away from the interface, ``mu = l_z > 0``) onto an
isotropic GGX interface of roughness ``alpha``; the single-scattering microfacet BSDF is the
Walter 2007 one of :mod:`goniometer.optics` (separable or height-correlated Smith masking).

* ``kind="white"``: a conductor whose Fresnel factor is 1: ``E(mu) = Int f_r(l, v) v_z dv``, the
  energy that single scattering keeps (the rest is lost to masking).
* ``kind="dielectric"``: a dielectric of *relative* index ``eta = n_far / n_near`` with its exact
  Fresnel factor: ``E(mu) = Int f_r v_z dv + Int f_t |v_z| dv`` (flux-based transmission, the
  convention of :mod:`goniometer.optics`), reflection and transmission together; from the denser
  side (``eta < 1``) total internal reflection is included.

Both integrals are taken over the GGX visible normals of ``l`` (density ``D_l(m) = G1(l) (l.m)+
D(m) / l_z``): ``E(mu) = Int D_l(m) [F G2(l, o_r) + (1 - F) G2(l, o_t)] / G1(l) dm`` with ``o_r``,
``o_t`` the reflected and refracted directions (Walter's Jacobians cancel), by a product rule:
Gauss-Legendre in the height of Dupuy & Benyoub's spherical cap and midpoints in its azimuth
(half a turn; the other half is the mirror image). ``E`` is tabulated at ``N_MU`` cosines
``mu_k = MU_FLOOR + (1 - MU_FLOOR) (k / (N_MU - 1))^2`` and read by linear interpolation;
``E_avg = 2 Int E(mu) mu dmu`` is the exact integral of that interpolant, so that Kulla-Conty's
lobe ``(1 - E(mu_l)) (1 - E(mu_v)) / (pi (1 - E_avg))`` integrates to exactly ``1 - E(mu_l)``.

Each table is written once into ``$GONIOMETER_CACHE/microfacet-albedo/`` (one ``.npz`` per
interface, named by a digest of its signature, with the version stamp and signature of
:mod:`models.tables.cache`) and memoised in-process. Stated accuracy (``ERROR_E``) and choices:
``docs/production-models.md`` ("ggx-kulla-conty").
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from goniometer import optics
from models._jit import njit
from models.tables import cache as table_cache

#: bump whenever the definition, numerics or layout of the tables changes
TABLE_VERSION = 1

N_MU = 65
MU_FLOOR = 1e-4
QUAD_Z = 192
QUAD_PHI = 256
#: stated bound of |E_table(mu_k) - E(mu_k)| at the nodes (quadrature error; measured in the tests)
ERROR_E = 3e-4
KINDS = ("white", "dielectric")
DIRECTORY = "microfacet-albedo"


def mu_nodes() -> np.ndarray:
    """The tabulated cosines ``MU_FLOOR + (1 - MU_FLOOR) (k / (N_MU - 1))^2`` (dense at grazing)."""
    return MU_FLOOR + (1.0 - MU_FLOOR) * np.linspace(0.0, 1.0, N_MU) ** 2


@lru_cache(maxsize=8)
def gauss_legendre(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes and weights on [-1, 1] (memoised, read-only)."""
    x, w = np.polynomial.legendre.leggauss(n)
    x.setflags(write=False)
    w.setflags(write=False)
    return x, w


def quadrature_rule(n_z: int = QUAD_Z, n_phi: int = QUAD_PHI) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(u2, w2, u1, w1)``: Gauss-Legendre nodes/weights on [0, 1] for the cap height and midpoint
    nodes on the half turn [0, 1/2] for the azimuth (weights ``1 / n_phi``); each set sums to 1."""
    x, w = gauss_legendre(n_z)
    u1 = (np.arange(n_phi) + 0.5) / (2.0 * n_phi)
    return 0.5 * (x + 1.0), 0.5 * w, u1, np.full(n_phi, 1.0 / n_phi)


# --------------------------------------------------------------------------- quadrature (njit)

@njit(cache=True)
def albedo_at(mu: float, alpha: float, eta: float, white: bool, height_correlated: bool,
              u2: np.ndarray, w2: np.ndarray, u1: np.ndarray, w1: np.ndarray) -> float:
    """``E(mu)`` of one interface by the product rule (module docstring). ``white``: Fresnel 1 and
    no transmission (``eta`` unused); otherwise a dielectric of relative index ``eta``."""
    lx = math.sqrt(max(0.0, 1.0 - mu * mu))
    lz = mu
    lam_l = optics.ggx_lambda(lx, 0.0, lz, alpha, alpha)
    g1_l = 1.0 / (1.0 + lam_l)
    acc = 0.0
    for i in range(u2.shape[0]):
        for j in range(u1.shape[0]):
            mx, my, mz = optics.sample_vndf(lx, 0.0, lz, alpha, alpha, u1[j], u2[i])
            w = w2[i] * w1[j]
            lm = lx * mx + lz * mz
            f = 1.0 if white else optics.fresnel_dielectric(lm, eta)
            ox, oy, oz = optics.reflect(lx, 0.0, lz, mx, my, mz)
            if f > 0.0 and oz > 0.0:
                lam_o = optics.ggx_lambda(ox, oy, oz, alpha, alpha)
                acc += w * f * optics.smith_g2(lam_l, lam_o, False, height_correlated) / g1_l
            if not white and f < 1.0:
                tx, ty, tz, ok = optics.refract(lx, 0.0, lz, mx, my, mz, eta)
                if ok and tz < 0.0:
                    lam_t = optics.ggx_lambda(tx, ty, tz, alpha, alpha)
                    acc += w * (1.0 - f) * optics.smith_g2(lam_l, lam_t, True, height_correlated) / g1_l
    return acc


@njit(cache=True)
def _fill(mus: np.ndarray, alpha: float, eta: float, white: bool, height_correlated: bool,
          u2: np.ndarray, w2: np.ndarray, u1: np.ndarray, w1: np.ndarray, out: np.ndarray) -> None:
    for k in range(mus.shape[0]):
        out[k] = albedo_at(mus[k], alpha, eta, white, height_correlated, u2, w2, u1, w1)


def direct(mu, alpha: float, eta: float = 1.0, kind: str = "white", height_correlated: bool = False,
           n_z: int = QUAD_Z, n_phi: int = QUAD_PHI) -> np.ndarray:
    """``E`` by the quadrature itself at each cosine of ``mu`` (no table, no cache)."""
    _check(kind, alpha, eta)
    mus = np.ascontiguousarray(np.atleast_1d(np.asarray(mu, dtype=np.float64)).ravel())
    out = np.empty(mus.shape[0])
    _fill(mus, float(alpha), float(eta), kind == "white", bool(height_correlated), *quadrature_rule(n_z, n_phi), out)
    return out.reshape(np.shape(mu))


def _check(kind: str, alpha: float, eta: float) -> None:
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {', '.join(KINDS)}, got {kind!r}")
    if not 0.0 < alpha <= 1.0:
        raise ValueError(f"alpha must be in (0, 1], got {alpha!r}")
    if kind == "dielectric" and not (eta > 0.0 and eta != 1.0):
        raise ValueError(f"eta must be > 0 and != 1 for a dielectric table, got {eta!r}")


def average(mus: np.ndarray, e: np.ndarray) -> float:
    """``2 Int_0^1 E(mu) mu dmu`` of the piecewise-linear interpolant through ``(mus, e)``, held
    constant below ``mus[0]`` (exact: two-point Gauss-Legendre on each segment)."""
    a, b = mus[:-1], mus[1:]
    ea, eb = e[:-1], e[1:]
    g = 0.5 / math.sqrt(3.0)
    total = 0.0
    for t in (0.5 - g, 0.5 + g):
        m = a + t * (b - a)
        total += float(np.sum(0.5 * (b - a) * (ea + t * (eb - ea)) * m))
    return 2.0 * total + e[0] * mus[0] ** 2


# --------------------------------------------------------------------------- tables and cache

@dataclass(frozen=True)
class AlbedoTable:
    """``E`` at :func:`mu_nodes` of one interface and its average ``E_avg`` (read-only)."""

    mu: np.ndarray
    e: np.ndarray
    e_avg: float

    def at(self, mu) -> np.ndarray:
        """``E`` at cosines ``mu`` (linear interpolation, clamped to the table's ends)."""
        return np.interp(np.abs(np.asarray(mu, dtype=np.float64)), self.mu, self.e)


def signature(kind: str, alpha: float, eta: float, height_correlated: bool) -> str:
    """The table's identity: definition, interface and grid (stored in the file, hashed into its name)."""
    return json.dumps({
        "version": TABLE_VERSION, "kind": kind, "alpha": repr(float(alpha)),
        "eta": repr(float(eta)) if kind == "dielectric" else None,
        "masking": "height-correlated" if height_correlated else "separable",
        "N_MU": N_MU, "MU_FLOOR": MU_FLOOR, "QUAD_Z": QUAD_Z, "QUAD_PHI": QUAD_PHI,
        "mu_nodes": "MU_FLOOR + (1 - MU_FLOOR) (k/(N_MU-1))^2", "quadrature": "vndf cap GL z x midpoint phi half",
    }, sort_keys=True)


def table_path(kind: str, alpha: float, eta: float, height_correlated: bool,
               cache_dir: str | os.PathLike | None = None) -> Path:
    """Where the table of this interface lives."""
    digest = hashlib.sha256(signature(kind, alpha, eta, height_correlated).encode()).hexdigest()[:24]
    return table_cache.cache_directory(cache_dir) / DIRECTORY / f"{kind}-{digest}.npz"


def compute_table(kind: str, alpha: float, eta: float = 1.0, height_correlated: bool = False) -> np.ndarray:
    """``E`` at :func:`mu_nodes` (no disk access)."""
    return direct(mu_nodes(), alpha, eta, kind, height_correlated)


@lru_cache(maxsize=256)
def _load_cached(kind: str, alpha: float, eta: float, height_correlated: bool, cache_dir: str) -> AlbedoTable:
    path = table_path(kind, alpha, eta, height_correlated, cache_dir)
    sig = signature(kind, alpha, eta, height_correlated)

    def read():
        t = table_cache.read_current(path, TABLE_VERSION, sig, ("e",), np.float64)
        return None if t is None or t["e"].shape != (N_MU,) else t

    def build():
        table_cache.save_atomic(path, version=np.int64(TABLE_VERSION), signature=np.array(sig),
                                e=compute_table(kind, alpha, eta, height_correlated), mu=mu_nodes())

    t = table_cache.load_or_build(read, build, f"the albedo table at {path}")
    e = t["e"]
    mus = mu_nodes()
    e.setflags(write=False)
    mus.setflags(write=False)
    return AlbedoTable(mus, e, average(mus, e))


def load_albedo_table(kind: str, alpha: float, eta: float = 1.0, height_correlated: bool = False,
                      cache_dir: str | os.PathLike | None = None) -> AlbedoTable:
    """The table of one interface, built (and cached on disk) on first use; a stale file is
    rebuilt. ``eta`` is ignored for ``kind="white"``. Memoised per interface and cache directory."""
    _check(kind, alpha, eta)
    eta = float(eta) if kind == "dielectric" else 1.0
    return _load_cached(kind, float(alpha), eta, bool(height_correlated), table_cache.memo_key(cache_dir))


# --------------------------------------------------------------------------- Fresnel averages

@lru_cache(maxsize=1024)
def fresnel_average(eta: float, kappa: float = 0.0, n: int = 256) -> float:
    """``F_avg = 2 Int_0^1 F(mu) mu dmu`` of a smooth interface of relative index ``eta + i kappa``
    (Gauss-Legendre, split at the critical cosine when ``eta < 1`` and ``kappa = 0``, where
    ``F = 1`` below it). Memoised."""
    x, w = gauss_legendre(n)
    if kappa == 0.0 and eta < 1.0:
        mu_c = math.sqrt(1.0 - eta * eta)
        mu = mu_c + 0.5 * (x + 1.0) * (1.0 - mu_c)
        f = optics.np_fresnel_dielectric(mu, eta)
        return float(mu_c * mu_c + np.sum(0.5 * (1.0 - mu_c) * w * f * 2.0 * mu))
    mu = 0.5 * (x + 1.0)
    f = optics.np_fresnel_conductor(mu, eta, kappa) if kappa > 0.0 else optics.np_fresnel_dielectric(mu, eta)
    return float(np.sum(0.5 * w * f * 2.0 * mu))
