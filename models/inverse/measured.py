"""The inverse method from a measurement: a measured BRDF (MERL ``.binary`` or RGL ``.bsdf``,
:mod:`goniometer.files.measured`) -> lobes at normal incidence -> a layered material, and the check of
that material by simulation against the measurement (``docs/inverse.md``, "From a measurement").

1. :func:`normal_reference`: the measurement at normal incidence resampled onto half-vector
   slices (90 x 8 by default, the validation's grid), as :func:`goniometer.files.measured.measured_reference`
   makes it: cell means of the file's own evaluation, NaN standard errors, no bounce orders.
2. :func:`measured_rings`: ring energies of that slice, the lobe estimator's rings
   (:func:`models.inverse.estimate.ring_data`: fractions of the incident flux per ring of half-vector
   elevation, ``theta_h < 45 deg``, the first ring kept); a ring with cells without data holds the
   mean of its other cells times its whole solid angle; a ring with none is left out.
3. :func:`fit_measured_lobes`: per channel, ``K`` normalised GGX lobes fitted to the total ring
   energies by :func:`models.inverse.estimate.fit_ring_lobes` (exact ring fractions,
   :func:`~models.inverse.estimate.lobe_ring_fractions`), each ring weighted as a count: its
   deviation ``sqrt(model x E)`` with ``E`` the total measured energy of the channel (a measurement has
   no standard errors; :data:`WEIGHTING`). Lobe ``k`` is the ``k``-th sharpest of every channel:
   top first, sharpest first (a lower lobe's variance holds the spread its light gathers crossing
   the interfaces above twice, eq. 19, so a lobe sharper than one above it mostly needs a negative
   roughness). Its :class:`~models.inverse.lobes.Lobe` has the fitted energies ``R`` (RGB) and
   the energy-weighted mean over channels of the fitted variances ``sigma = f(alpha)``.
4. :func:`invert_measured`: the Bati 2021 method (:func:`models.inverse.solver.solve`) on those
   lobes; :func:`simulate_against`: the retrieved stack simulated at normal incidence on the same
   grid, its eq. 4 RMSE against the measured slice over the cells valid in both
   (:func:`models.compare.errors.rmse`), the measurement's reference norm, the simulation's noise
   floor and the lobe estimator on the simulation (:func:`models.inverse.estimate.estimate_lobes`).

Energies are albedos at normal incidence (the paper's ``R_k``), variances Belcour's
``f(alpha) = alpha^1.1 / (1 - alpha^1.1)``.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from goniometer.files.measured import MeasuredBRDF, measured_reference, read_measured
from models.belcour import roughness_to_variance
from models.inverse.estimate import (SEPARABLE_RATIO, LobeFit, estimate_lobes, fit_ring_lobes, lobe_ring_fractions,
                                     sigma_stderr)
from models.inverse.lobes import InverseError, InverseOptions, Lobe, Pick, jsonable
from models.inverse.solver import Inversion, solve

__all__ = ["DEFAULT_LOBES", "MAX_LOBES", "MEASURED_RESOLUTION", "MeasuredFit", "MeasuredInversion", "MeasuredRings",
           "SIMULATE_RAYS", "WEIGHTING", "fit_measured_lobes", "invert_measured", "measured_rings", "normal_reference",
           "simulate_against"]

#: the half slices a measurement is resampled onto (the inverse validation's simulations)
MEASURED_RESOLUTION = (90, 8)
#: lobes fitted per channel unless asked: one GGX lobe is always identifiable
DEFAULT_LOBES = 1
MAX_LOBES = 3
#: rays of the check by simulation (``--simulate``)
SIMULATE_RAYS = 1_000_000
#: how the measured rings are weighted in the fit (module docstring, step 3)
WEIGHTING = "count: ring deviation sqrt(model x total energy)"
#: the fit's starting roughnesses: one lobe from ALPHA_START_ONE, K > 1 lobes spread geometrically over
#: ALPHA_START, each start also scaled by START_SCALES (one lobe, several lobes); the lowest cost wins
ALPHA_START_ONE = 0.1
ALPHA_START = (0.03, 0.5)
START_SCALES = ((1.0, 0.3, 3.0), (1.0, 0.5, 2.0))
#: lobes with less than this fraction of a channel's energy are not lobes of the measurement
ENERGY_MIN_FRACTION = 1e-3
#: a fitted energy at the fit's bound (1): no physical lobe
R_MAX = 1.0 - 1e-6


def normal_reference(measured: MeasuredBRDF, resolution: tuple[int, int] = MEASURED_RESOLUTION, subcells: int = 5,
                     stack=None):
    """The measurement at normal incidence on half slices of ``resolution`` (a
    :class:`goniometer.run.results.SimulationResult`, :func:`goniometer.files.measured.measured_reference`;
    ``stack`` is recorded as its material, None when unknown)."""
    from goniometer.run.settings import SimulationSettings
    settings = SimulationSettings(incident_deg=(0.0,), rays=1, parametrization="half", resolution=tuple(resolution))
    return measured_reference(measured, stack, settings, subcells=subcells)


@dataclass
class MeasuredRings:
    """Ring energies of a measured normal-incidence slice: ``energy[c, i]`` over the rings of
    half-vector edges ``theta_h_edges`` (radians); ``valid[i]`` False for a ring without data;
    ``filled[i]`` the fraction of the ring's projected solid angle with data."""

    theta_h_edges: np.ndarray
    energy: np.ndarray
    valid: np.ndarray
    filled: np.ndarray

    @property
    def total(self) -> np.ndarray:
        """The energy of the valid rings per channel (the albedo at normal incidence up to the rings left out)."""
        return self.energy[:, self.valid].sum(axis=1)


def measured_rings(reference) -> MeasuredRings:
    """Rings of the first (normal-incidence) slice of a measured reference (module docstring, step 2).

    The rings are :func:`models.inverse.estimate.ring_data`'s (the same rows, the first one kept
    although the slice masks it: its width is degenerate, its value is the file's). A cell lacks
    data where the reference masks it although its geometry is valid (a MERL cell without data)."""
    from models.inverse.estimate import ring_data
    sd = reference.brdf
    if sd.grid.parametrization != "half":
        raise InverseError("measured rings: the reference must be on half-vector slices")
    rings = ring_data(reference)
    n = rings.energy.shape[1]
    from goniometer.grids.slice_grid import light_direction
    st = reference.settings
    geometric = sd.grid.mask(light_direction(float(st.incident_deg[0]), float(st.incident_phi_deg[0])),
                             int(reference.extra.get("measured", {}).get("subcells", 5)))
    has = sd.mask[0] | ~geometric                      # row 0: masked for its width only
    om = sd.proj_solid_angle[0][:n]
    has = has[:n]
    full = om.sum(axis=1)
    part = np.where(has, om, 0.0).sum(axis=1)
    filled = np.divide(part, full, out=np.zeros_like(full), where=full > 0)
    value = sd.value[0][:, :n]
    energy = np.where(has[None], value * om[None], 0.0).sum(axis=2)
    energy = np.divide(energy, filled[None], out=np.zeros_like(energy), where=filled[None] > 0)
    valid = filled > 0
    return MeasuredRings(rings.theta_h_edges, energy, valid, filled)


@dataclass
class MeasuredFit:
    """The lobes fitted to a measurement's rings: per lobe (sharpest first) and channel ``R``
    (albedo), ``alpha``, ``sigma = f(alpha)``, their fit standard errors (from the scatter of the
    rings about the model; the resampling's systematic error is not in them), and per channel the
    relative misfit ``sqrt(sum (model - E)^2 / sum E^2)`` of the ring energies."""

    n_lobes: int
    R: np.ndarray                 # (K, 3)
    alpha: np.ndarray             # (K, 3)
    R_err: np.ndarray
    alpha_err: np.ndarray
    misfit: np.ndarray            # (3,)
    rings: MeasuredRings
    fits: list[LobeFit] = field(default_factory=list, repr=False)

    @property
    def sigma(self) -> np.ndarray:
        return np.vectorize(roughness_to_variance)(self.alpha)

    def lobe_sigma(self) -> np.ndarray:
        """One variance per lobe: the energy-weighted mean of its channels' variances."""
        return np.sum(self.R * self.sigma, axis=1) / np.sum(self.R, axis=1)

    def lobes(self, layers: Sequence[int] | None = None) -> list[Lobe]:
        """The lobes for the solver, top (sharpest) first; ``layers`` per lobe (default 1 each)."""
        layers = [1] * self.n_lobes if layers is None else list(layers)
        if len(layers) != self.n_lobes:
            raise InverseError(f"layers: {len(layers)} value(s) for {self.n_lobes} fitted lobe(s)")
        sig = self.lobe_sigma()
        return [Lobe(tuple(float(x) for x in self.R[k]), float(sig[k]), int(layers[k])) for k in range(self.n_lobes)]

    def model(self) -> np.ndarray:
        """The fitted ring energies (3, n_rings)."""
        e = self.rings.theta_h_edges
        return np.array([sum(self.R[k, c] * lobe_ring_fractions(e, self.alpha[k, c]) for k in range(self.n_lobes))
                         for c in range(3)])

    def to_json(self) -> dict[str, Any]:
        sig = self.sigma
        ds = np.array([[sigma_stderr(a, ae) for a, ae in zip(ra, rae)] for ra, rae in zip(self.alpha, self.alpha_err)])
        sl = self.lobe_sigma()
        return jsonable({
            "lobes": self.n_lobes, "weighting": WEIGHTING, "misfit": self.misfit,
            "rings": int(self.rings.valid.sum()), "ring_energy_total": self.rings.total,
            "fitted": [{"R": self.R[k], "R_stderr": self.R_err[k], "alpha": self.alpha[k],
                        "alpha_stderr": self.alpha_err[k], "sigma": sig[k], "sigma_stderr": ds[k],
                        "sigma_lobe": sl[k]} for k in range(self.n_lobes)]})


def fit_measured_lobes(rings: MeasuredRings, n_lobes: int = DEFAULT_LOBES) -> MeasuredFit:
    """``n_lobes`` normalised GGX lobes per channel fitted to the measured ring energies (module
    docstring, step 3). Raises :class:`InverseError` when the measurement does not hold that many
    lobes: a lobe below :data:`ENERGY_MIN_FRACTION` of its channel's energy, two lobes whose
    variances are within :data:`models.inverse.estimate.SEPARABLE_RATIO` of each other, or a
    lobe whose energy would reach 1."""
    if isinstance(n_lobes, bool) or not isinstance(n_lobes, (int, np.integer)) or not 1 <= n_lobes <= MAX_LOBES:
        raise InverseError(f"lobes: {n_lobes!r} is not a number of lobes in 1..{MAX_LOBES}")
    K = int(n_lobes)
    ok = rings.valid
    if np.count_nonzero(ok) < 2 * K + 1:
        raise InverseError(f"measurement: {np.count_nonzero(ok)} ring(s) with data at normal incidence, too few "
                           f"for {K} lobe(s)")
    edges = rings.theta_h_edges
    a0 = list(np.geomspace(*ALPHA_START, K)) if K > 1 else [ALPHA_START_ONE]
    R = np.zeros((K, 3))
    A = np.zeros((K, 3))
    Re = np.zeros((K, 3))
    Ae = np.zeros((K, 3))
    misfit = np.zeros(3)
    fits: list[LobeFit] = []
    for c in range(3):
        E = np.where(ok, rings.energy[c], 0.0)
        tot = float(E.sum())
        if not tot > 0.0:
            raise InverseError(f"measurement: no energy in channel {'RGB'[c]} at normal incidence")
        if c > 0 and np.array_equal(E, np.where(ok, rings.energy[c - 1], 0.0)):
            f = fits[-1]
        else:
            floor = 1e-12 * tot

            def deviation(m: np.ndarray, tot=tot, floor=floor) -> np.ndarray:
                return np.where(ok, np.sqrt(np.maximum(m, floor) * tot), np.inf)

            f = fit_ring_lobes(E, edges, a0, [tot / K] * K, deviation, scales=START_SCALES[K > 1],
                               scale_errors="always")
        fits.append(f)
        order = np.argsort(f.alpha)
        R[:, c], A[:, c] = f.energy[order], f.alpha[order]
        Re[:, c], Ae[:, c] = f.energy_err[order], f.alpha_err[order]
        m = sum(R[k, c] * lobe_ring_fractions(edges, A[k, c]) for k in range(K))
        misfit[c] = math.sqrt(float(np.sum(np.where(ok, m - E, 0.0) ** 2)) / float(np.sum(E ** 2)))
        for k in range(K):
            if R[k, c] < ENERGY_MIN_FRACTION * tot:
                raise InverseError(f"measurement: fitted with {K} lobes, lobe {k + 1} holds {R[k, c]:.3g} of channel "
                                   f"{'RGB'[c]}'s {tot:.3g}: the measurement does not have {K} lobes (try fewer)")
        for k in range(K - 1):
            sa, sb = roughness_to_variance(A[k, c]), roughness_to_variance(A[k + 1, c])
            if sb < SEPARABLE_RATIO * sa:
                raise InverseError(f"measurement: fitted with {K} lobes, lobes {k + 1} and {k + 2} have variances "
                                   f"{sa:.3g} and {sb:.3g} in channel {'RGB'[c]}, within the ratio {SEPARABLE_RATIO} "
                                   f"that normal incidence tells apart (try fewer lobes)")
    if np.any(R >= R_MAX):
        k, c = np.argwhere(R >= R_MAX)[0]
        raise InverseError(f"measurement: lobe {k + 1} fitted in channel {'RGB'[c]} reflects all the light "
                           f"(R = {R[k, c]:.6g}, the fit's bound): not a lobe of a physical stack (is the file a "
                           f"BRDF without the cosine, 1/sr?)")
    return MeasuredFit(K, R, A, Re, Ae, misfit, rings, fits)


@dataclass
class MeasuredInversion:
    """A measurement, its normal-incidence reference and rings, the fitted lobes and the inversion."""

    measured: MeasuredBRDF
    reference: Any
    fit: MeasuredFit
    lobes: list[Lobe]
    inversion: Inversion

    def to_json(self) -> dict[str, Any]:
        ref = self.reference
        return jsonable({"file": self.measured.path, "kind": self.measured.kind,
                         "resampling": self.measured.resampling,
                         "slices": {"incident_deg": 0.0, "parametrization": "half",
                                    "resolution": list(ref.settings.resolution),
                                    "subcells": ref.extra["measured"]["subcells"]},
                         "fit": self.fit.to_json()})


def invert_measured(measured: MeasuredBRDF | str | os.PathLike, n_lobes: int = DEFAULT_LOBES,
                    layers: Sequence[int] | None = None, base: str = "dielectric",
                    picks: Sequence[Pick | dict | None] | None = None, options: InverseOptions | None = None,
                    name: str = "inverse", resolution: tuple[int, int] = MEASURED_RESOLUTION,
                    subcells: int = 5) -> MeasuredInversion:
    """Fit ``n_lobes`` lobes to a measurement at normal incidence and invert them (Bati 2021,
    :func:`models.inverse.solver.solve`; never raises for an unachievable request: see
    ``inversion.achievable``). Raises :class:`goniometer.files.measured.MeasuredError` for a file that is
    not a measurement and :class:`InverseError` for lobes the measurement does not hold."""
    m = measured if isinstance(measured, MeasuredBRDF) else read_measured(measured)
    ref = normal_reference(m, resolution, subcells)
    fit = fit_measured_lobes(measured_rings(ref), n_lobes)
    lobes = fit.lobes(layers)
    inv = solve(lobes, base, picks, options, name=name)
    return MeasuredInversion(m, ref, fit, lobes, inv)


def simulate_against(reference, stack, lobes: Sequence[Lobe], rays: int = SIMULATE_RAYS, seed: int = 1,
                     threads: int | None = None) -> dict[str, Any]:
    """Simulate ``stack`` at normal incidence on the reference's half slices and compare (module
    docstring, step 4): per channel ``rmse`` (eq. 4 over the cells valid in both), ``reference_norm``
    (eq. 4 of the measurement against zero), ``relative_rmse``, the simulation's ``noise_floor``,
    ``excess_rmse = sqrt(max(rmse^2 - noise_floor^2, 0))`` (the simulation's noise is independent of
    the measurement, so ``E[rmse^2] = noise_floor^2 + d^2`` with ``d`` the RMSE of the simulation's
    expectation against the measurement: ``excess_rmse`` estimates ``d``) and ``relative_excess``;
    per lobe the estimator's ``R_simulated``, ``sigma_simulated`` and standard errors
    (:func:`models.inverse.estimate.estimate_lobes` with ``lobes`` as the requested lobes); ``result``
    the simulation itself."""
    from models.compare.errors import noise_floor, rmse
    from models.inverse.validation import simulate_case
    sim, rings = simulate_case(stack, lobes, rays, tuple(reference.settings.resolution), seed, threads)
    rb, sb = reference.brdf, sim.brdf
    mask = rb.mask & sb.mask
    omega = rb.proj_solid_angle
    e = rmse(rb.value, sb.value, omega, mask)
    norm = rmse(rb.value, np.zeros_like(rb.value), omega, mask)
    est = estimate_lobes(rings, lobes)
    out_lobes = []
    for k, s in enumerate(est["lobes"]):
        out_lobes.append({"R_simulated": s.get("R"), "R_simulated_stderr": s.get("R_err"),
                          "sigma_simulated": s.get("sigma"), "sigma_simulated_stderr": s.get("sigma_err"),
                          **({"simulated_group": s["group"]} if s.get("group") else {})})
    nf = noise_floor(sb.stderr, omega, mask)
    excess = np.sqrt(np.maximum(e * e - nf * nf, 0.0))
    scale = np.where(norm > 0, norm, np.nan)
    return {"rays": int(rays), "seed": int(seed), "cells": int(mask.sum()), "rmse": e, "reference_norm": norm,
            "relative_rmse": e / scale, "noise_floor": nf, "excess_rmse": excess, "relative_excess": excess / scale,
            "reflected": sim.energy["reflected"][0], "lobes": out_lobes, "elapsed_s": float(sim.elapsed_s.sum()),
            "result": sim}
