"""Effective darkening and effective base roughness of a coated base, measured on simulated slices.

Definitions (``docs/production.md`` sections 2 and 3, which this module implements):

* **coat albedo** ``E_coat(mu)``: the directional albedo of the coat's GGX reflection lobe seen
  from air, single scattering, Fresnel of the coat index, Smith masking of the run (Belcour's FGD
  by direct quadrature, :func:`models.tables.fgd_direct_many`), evaluated at the centre polar
  angle of each row of the classic grid.
* **effective darkening** ``D_eff`` (per colour channel): the simulated albedo of the internal
  light (bounce orders >= 2: everything but the lobe reflected off the coat) divided by what
  OpenPBR's albedo-scaling layering predicts without darkening from the *bare* base (the same
  base alone in air, simulated): ``P(l) = sum_cells (1 - E_coat(mu_v)) fbar_bare(l, cell) Omega``,
  both summed over the incident directions of the files: ``D_eff = sum_l E_int(l) / sum_l P(l)``.
* **effective base roughness** ``alpha_eff`` (conductor bases): the GGX alpha of the base whose
  lobe seen through the coat as the spec layers it, ``(1 - E_coat(mu_v)) f_base(z, v; alpha)``,
  has the same energy-weighted median exit polar angle at normal incidence as the simulated
  internal light (channel mean). Rows of the classic grid are rings about the normal, so the
  cumulative energy is exact at row edges on both sides and both are interpolated alike.

Conventions: ``l`` and ``v`` point away from the surface; slice values without cosine, in 1/sr
(``docs/slices-format.md``); roughness is GGX alpha (``docs/material-format.md``); the bare base is
in air (OpenPBR's base parameters describe the uncoated base).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.optimize import brentq

from goniometer.optics import np_microfacet_reflection
from goniometer.run.results import SimulationResult
from goniometer.stack import Interface, Lambertian, Stack
from models.tables import fgd_direct_many

#: incident elevation (degrees) at which the effective roughness is read
ROUGHNESS_INCIDENT_DEG = 0.0
#: the range of GGX alpha searched for the effective roughness
ALPHA_MIN, ALPHA_MAX = 1e-3, 1.0
#: Gauss-Legendre points per row of the model's ring integrals
RING_POINTS = 8
#: Gaussian redraws of the rings for the standard error of the effective roughness (fixed seed)
NOISE_DRAWS = 32


class ProductionError(ValueError):
    """A file or stack that the production measurement cannot use (the message names it)."""


@dataclass(frozen=True)
class CoatedBase:
    """A stack ``[isotropic dielectric coat, base]`` with the base a GGX conductor or a Lambertian.

    ``base_key`` identifies the bare twin (the base layer's canonical JSON).
    """

    name: str
    base: str                       # "conductor" | "lambertian"
    coat_ior: float
    coat_alpha: float
    base_alpha: float | None        # None for a Lambertian
    base_eta: tuple[float, float, float] | None
    base_kappa: tuple[float, float, float] | None
    multiple_scattering: bool
    base_key: str


def _layer_key(stack: Stack, index: int) -> str:
    return json.dumps(stack.to_dict()["layers"][index], sort_keys=True, separators=(",", ":"))


def bare_key(stack: Stack) -> str | None:
    """The base key of a one-layer stack (a bare conductor or Lambertian), else None."""
    if len(stack.layers) != 1 or stack.base not in ("conductor", "lambertian"):
        return None
    last = stack.layers[0]
    if isinstance(last, Interface) and last.is_anisotropic:
        return None
    return _layer_key(stack, 0)


def coated_base(stack: Stack) -> CoatedBase | None:
    """Describe ``stack`` if it is a clear isotropic dielectric coat directly over a GGX conductor or a
    Lambertian (the production families, ``configs/production.toml``); None otherwise."""
    if len(stack.layers) != 2 or stack.base not in ("conductor", "lambertian"):
        return None
    coat, base = stack.layers
    if not isinstance(coat, Interface) or coat.is_conductor or coat.is_anisotropic:
        return None
    if isinstance(base, Interface) and base.is_anisotropic:
        return None
    if isinstance(base, Lambertian):
        kind, alpha, eta, kappa = "lambertian", None, None, None
        ms = coat.multiple_scattering
    else:
        kind, alpha, eta, kappa = "conductor", base.roughness, tuple(base.ior), tuple(base.extinction)
        if base.multiple_scattering != coat.multiple_scattering:
            return None
        ms = coat.multiple_scattering
    return CoatedBase(name=stack.name, base=kind, coat_ior=float(coat.ior[0]), coat_alpha=float(coat.roughness),
                      base_alpha=alpha, base_eta=eta, base_kappa=kappa,
                      multiple_scattering=ms, base_key=_layer_key(stack, 1))


# --------------------------------------------------------------------------- the coat's albedo

@lru_cache(maxsize=256)
def _coat_albedo_rows(coat_alpha: float, coat_ior: float, height_correlated: bool, n_theta: int) -> np.ndarray:
    mu = np.cos(np.radians((np.arange(n_theta) + 0.5) * 90.0 / n_theta))
    e = fgd_direct_many(mu, coat_alpha, coat_ior, 0.0, height_correlated)
    e.setflags(write=False)
    return e


def coat_albedo_rows(coat_alpha: float, coat_ior: float, masking: str, n_theta: int) -> np.ndarray:
    """``E_coat`` at the centre polar angle of each of the ``n_theta`` rows of a classic grid (n_theta,)."""
    return _coat_albedo_rows(float(coat_alpha), float(coat_ior), masking == "height-correlated", int(n_theta))


# --------------------------------------------------------------------------- darkening

@dataclass(frozen=True)
class Darkening:
    """Effective darkening of one coated material: ``value``/``stderr`` (3,) and per incident (M, 3).

    ``internal``/``predicted``: the simulated internal albedo ``E_int`` and the spec's undarkened
    prediction ``P`` per incident direction and channel; ``stderr`` is an upper bound (cells
    treated as independent, which overstates the variance of a sum of exits of one ray).
    """

    value: np.ndarray
    stderr: np.ndarray
    per_incident: np.ndarray
    internal: np.ndarray
    predicted: np.ndarray


def _check_classic(result: SimulationResult, what: str) -> None:
    if result.brdf.grid.parametrization != "classic":
        raise ProductionError(f"{what}: needs classic slices (rings about the normal), the file has "
                              f"{result.brdf.grid.parametrization!r}")


def internal_albedo(result: SimulationResult) -> tuple[np.ndarray, np.ndarray]:
    """Albedo of bounce orders >= 2 per incident direction and channel (M, 3), and its stderr bound."""
    sd = result.brdf
    om = sd.proj_solid_angle[:, None]
    e = np.einsum("mkcij,mij->mc", sd.orders[:, 1:].astype(np.float64), sd.proj_solid_angle)
    se = sd.stderr_internal if sd.stderr_internal is not None else sd.stderr
    return e, np.sqrt(np.sum((se * om) ** 2, axis=(2, 3)))


def layered_prediction(bare: SimulationResult, e_coat_rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``P = sum_cells (1 - E_coat(mu_v)) fbar_bare Omega`` per incident and channel (M, 3), and its stderr bound."""
    sd = bare.brdf
    w = (1.0 - e_coat_rows)[None, None, :, None] * sd.proj_solid_angle[:, None]
    return np.sum(sd.value * w, axis=(2, 3)), np.sqrt(np.sum((sd.stderr * w) ** 2, axis=(2, 3)))


def _same_geometry(a: SimulationResult, b: SimulationResult, what: str) -> None:
    if (a.brdf.grid.shape != b.brdf.grid.shape or not np.array_equal(a.theta_deg, b.theta_deg)
            or not np.array_equal(a.phi_deg, b.phi_deg)):
        raise ProductionError(f"{what}: the coated file and its bare twin differ in grid or incident directions")


def darkening_from(internal: np.ndarray, internal_se: np.ndarray, predicted: np.ndarray,
                   predicted_se: np.ndarray) -> Darkening:
    """``D_eff = sum_l E_int / sum_l P`` (per channel) with its propagated stderr bound."""
    e, p = internal.sum(axis=0), predicted.sum(axis=0)
    d = e / p
    se = np.abs(d) * np.sqrt((np.sqrt(np.sum(internal_se ** 2, axis=0)) / e) ** 2
                             + (np.sqrt(np.sum(predicted_se ** 2, axis=0)) / p) ** 2)
    return Darkening(value=d, stderr=se, per_incident=internal / predicted, internal=internal, predicted=predicted)


def effective_darkening(coated: SimulationResult, bare: SimulationResult) -> Darkening:
    """Effective darkening of a coated material from its file and its bare twin's (``docs/production.md`` 2)."""
    cfg = coated_base(coated.stack)
    if cfg is None:
        raise ProductionError(f"{coated.stack.name}: not a clear coat over a conductor or a Lambertian")
    _check_classic(coated, coated.stack.name)
    _check_classic(bare, bare.stack.name)
    _same_geometry(coated, bare, coated.stack.name)
    if bare_key(bare.stack) != cfg.base_key:
        raise ProductionError(f"{bare.stack.name}: is not the bare base of {coated.stack.name}")
    rows = coat_albedo_rows(cfg.coat_alpha, cfg.coat_ior, coated.settings.masking, coated.brdf.grid.n_theta)
    e, e_se = internal_albedo(coated)
    p, p_se = layered_prediction(bare, rows)
    return darkening_from(e, e_se, p, p_se)


# --------------------------------------------------------------------------- roughness

def median_angle(edges_deg: np.ndarray, ring_energy: np.ndarray) -> float:
    """Polar angle (deg) below which half of the energy lies: the cumulative energy is known at
    the ring edges and interpolated linearly inside the ring that holds the median."""
    cum = np.concatenate(([0.0], np.cumsum(ring_energy)))
    if not cum[-1] > 0.0:
        raise ProductionError("no internal energy at normal incidence: no median exit angle")
    half = 0.5 * cum[-1]
    i = int(np.searchsorted(cum, half, side="left"))
    i = min(max(i, 1), len(cum) - 1)
    c0, c1 = cum[i - 1], cum[i]
    t = 0.0 if c1 == c0 else (half - c0) / (c1 - c0)
    return float(edges_deg[i - 1] + t * (edges_deg[i] - edges_deg[i - 1]))


def _ring_rule(edges_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    x, w = np.polynomial.legendre.leggauss(RING_POINTS)
    t0, t1 = np.radians(edges_deg[:-1])[:, None], np.radians(edges_deg[1:])[:, None]
    theta = 0.5 * (t1 - t0) * x[None] + 0.5 * (t1 + t0)
    # ring integral of g(theta): 2 pi int g cos sin dtheta
    weight = 2.0 * np.pi * 0.5 * (t1 - t0) * w[None] * np.cos(theta) * np.sin(theta)
    return theta, weight


def model_ring_energy(alpha: float, cfg: CoatedBase, e_coat_rows: np.ndarray, edges_deg: np.ndarray,
                      masking: str) -> np.ndarray:
    """Energy per ring (channel mean) of the spec's layered base lobe at normal incidence:
    ``2 pi int (1 - E_coat(row)) f_base(z, v(theta); alpha) cos sin dtheta`` (rows,)."""
    if cfg.base != "conductor":
        raise ProductionError(f"{cfg.name}: a Lambertian base has no roughness")
    theta, weight = _ring_rule(edges_deg)
    sx, cz = np.sin(theta), np.cos(theta)
    f = np.zeros_like(theta)
    for eta, kappa in zip(cfg.base_eta, cfg.base_kappa):
        f += np_microfacet_reflection(0.0, 0.0, 1.0, sx, 0.0, cz, alpha, alpha, eta, kappa,
                                      masking == "height-correlated") / 3.0
    return (1.0 - e_coat_rows) * np.sum(f * weight, axis=1)


@dataclass(frozen=True)
class Roughness:
    """Effective base roughness: GGX ``alpha`` and its stderr; ``median_deg`` of the internal light;
    ``clamped`` if the median lies outside what alpha in [ALPHA_MIN, ALPHA_MAX] can give."""

    alpha: float
    stderr: float
    median_deg: float
    clamped: bool


def invert_median(median_deg: float, cfg: CoatedBase, e_coat_rows: np.ndarray, edges_deg: np.ndarray,
                  masking: str) -> tuple[float, bool]:
    """The alpha whose layered model lobe has median exit angle ``median_deg`` (clamped to the range)."""
    def gap(a: float) -> float:
        return median_angle(edges_deg, model_ring_energy(a, cfg, e_coat_rows, edges_deg, masking)) - median_deg
    lo, hi = gap(ALPHA_MIN), gap(ALPHA_MAX)
    if lo >= 0.0:
        return ALPHA_MIN, True
    if hi <= 0.0:
        return ALPHA_MAX, True
    return float(brentq(gap, ALPHA_MIN, ALPHA_MAX, xtol=1e-6, rtol=1e-8)), False


def ring_energy(internal: np.ndarray, proj_solid_angle: np.ndarray) -> np.ndarray:
    """Channel-mean energy per row of one incident direction's classic cells: (3, nt, nph) -> (nt,)."""
    return np.einsum("cij,ij->i", internal, proj_solid_angle) / 3.0


def roughness_from(internal: np.ndarray, proj_solid_angle: np.ndarray, cfg: CoatedBase, masking: str,
                   edges_deg: np.ndarray, internal_se: np.ndarray | None = None) -> Roughness:
    """Effective roughness from the internal cells at normal incidence, (3, nt, nph) each; with
    ``internal_se`` its stderr from Gaussian redraws of the rings (fixed seed), else 0."""
    rows = coat_albedo_rows(cfg.coat_alpha, cfg.coat_ior, masking, internal.shape[1])
    med = median_angle(edges_deg, ring_energy(internal, proj_solid_angle))
    alpha, clamped = invert_median(med, cfg, rows, edges_deg, masking)
    se = 0.0
    if internal_se is not None and not clamped:
        ring = ring_energy(internal, proj_solid_angle)
        ring_se = np.sqrt(np.einsum("cij,ij->i", internal_se ** 2, proj_solid_angle ** 2)) / np.sqrt(3.0)
        rng = np.random.default_rng(12345)
        meds = [median_angle(edges_deg, np.maximum(ring + ring_se * rng.standard_normal(ring.shape), 0.0))
                for _ in range(NOISE_DRAWS)]
        h = max(1e-4, 1e-2 * alpha)
        lo, hi = max(ALPHA_MIN, alpha - h), min(ALPHA_MAX, alpha + h)
        slope = (median_angle(edges_deg, model_ring_energy(hi, cfg, rows, edges_deg, masking))
                 - median_angle(edges_deg, model_ring_energy(lo, cfg, rows, edges_deg, masking))) / (hi - lo)
        se = float(np.std(meds, ddof=1) / slope) if slope > 0 else float("nan")
    return Roughness(alpha=alpha, stderr=se, median_deg=med, clamped=clamped)


def normal_incidence_index(result: SimulationResult) -> int:
    """Index of the incident direction at ``ROUGHNESS_INCIDENT_DEG``; raises if the file has none."""
    hit = np.flatnonzero(np.isclose(result.theta_deg, ROUGHNESS_INCIDENT_DEG))
    if len(hit) == 0:
        raise ProductionError(f"{result.stack.name}: no incident direction at {ROUGHNESS_INCIDENT_DEG} deg "
                              "(the effective roughness is read at normal incidence)")
    return int(hit[0])


def effective_roughness(coated: SimulationResult) -> Roughness:
    """Effective base roughness of a coated conductor from its file (``docs/production.md`` 3)."""
    cfg = coated_base(coated.stack)
    if cfg is None or cfg.base != "conductor":
        raise ProductionError(f"{coated.stack.name}: not a clear coat over a conductor")
    _check_classic(coated, coated.stack.name)
    m = normal_incidence_index(coated)
    sd = coated.brdf
    internal = sd.orders[m, 1:].astype(np.float64).sum(axis=0)
    se = sd.stderr_internal[m] if sd.stderr_internal is not None else sd.stderr[m]
    return roughness_from(internal, sd.proj_solid_angle[m], cfg, coated.settings.masking,
                          sd.grid.theta_edges_deg(), se)
