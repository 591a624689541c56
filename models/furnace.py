"""White-furnace / directional-albedo tables of a stack: the simulation's and every model's
(``gonio furnace``; contract in ``docs/furnace.md``).

The **directional albedo** ``E(l)`` is the fraction of the flux arriving from direction ``l``
that leaves the stack, on either side, per RGB channel -- or, for a spectral run
(``docs/spectral.md``), per wavelength bin, shown in linear sRGB:

* simulated: ``reflected + transmitted`` of the tracer's energy bookkeeping
  (``docs/material-format.md``, transport). A path leaves the stack at most once, upward or
  downward, so per path ``r * t = 0`` and the per-path second moment of the albedo is the sum of
  those of ``reflected`` and ``transmitted``: its standard error needs no new kernel output
  (:func:`simulated_albedo`). The slices are not needed, so the run uses a 1 x 1 classic grid
  (:data:`GRID`).
* a model's: ``E_brdf(l) + E_btdf(l)``, the hemispherical integrals of ``f * |cos theta_v|``
  over the sides the stack emits into (:func:`models.compare.albedo.directional_albedo`). A model
  must model every such side (both for a stack that transmits), otherwise it is skipped with
  the reason, like every model whose ``reason(stack)`` refuses the stack and every model of a
  stack with a perfectly smooth interface (a Dirac lobe is not an integrable function).

Models are taken from :func:`models.registry.all_models` (every analytic model, whatever its
name); fitted models need a simulated file's slices and are listed as skipped.

A **spectral run** (the material file's ``[simulation] spectral = true``, or ``--spectral``) has
one albedo per wavelength bin, each from ``rays`` paths: :func:`simulated_albedo` holds per bin, and
the per-bin table is kept in :class:`SpectralBins`. The table's channels are then the bins'
linear sRGB, reduced by the one colour pipeline, :meth:`SimulationResult.rgb`
(``docs/spectral.md`` section 4; standard errors are its upper bounds), as ``gonio evaluate``
judges a spectral reference; the models are RGB and read the material's RGB equivalent.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import dataclasses

import numpy as np

from goniometer.run.results import ENERGY_TERMS as SLICE_ENERGY_TERMS, SimulationResult
from goniometer.run.loop import run_incidents
from goniometer.run.settings import SimulationSettings
from goniometer.grids.slice_grid import light_direction
from goniometer.stack import Stack
from models import registry
from models.base import ModelFailure
from models.compare.albedo import MAX_PANEL, ORDER, directional_albedo, lobe_scale, smooth_interface

#: default incident elevations of ``gonio furnace`` (degrees): 0, 5, ..., 85
INCIDENT_DEG = tuple(float(x) for x in range(0, 90, 5))
#: default rays per incident direction
RAYS = 100_000
#: the slice grid of a furnace run: one cell (only the energy rows are used)
GRID = ("classic", (1, 1))
#: the energy terms of the bookkeeping, in the order of the JSON object
ENERGY_TERMS = SLICE_ENERGY_TERMS + ("roulette", "capped")


def furnace_settings(table: Mapping[str, Any] | None = None, *, incident_deg: tuple[float, ...] | None = None,
                     incident_phi_deg: tuple[float, ...] | None = None, rays: int | None = None,
                     seed: int | None = None, threads: int | None = None, spectral: bool | None = None,
                     wavelength_bins: int | None = None, source: str = "simulation") -> SimulationSettings:
    """The settings of a furnace run: the furnace defaults (:data:`INCIDENT_DEG`, :data:`RAYS`),
    then a material file's ``[simulation]`` table, then the given values; the slice grid is
    always :data:`GRID`. Raises :class:`goniometer.run.settings.SettingsError` naming the field."""
    base: dict[str, Any] = {"incident_deg": list(INCIDENT_DEG), "rays": RAYS}
    base.update(table or {})
    s = SimulationSettings.from_mapping(base, source=source)
    if incident_deg is not None and incident_phi_deg is None:
        incident_phi_deg = tuple(0.0 for _ in incident_deg)
    return s.with_overrides(incident_deg=incident_deg, incident_phi_deg=incident_phi_deg, rays=rays, seed=seed,
                            threads=threads, spectral=spectral, wavelength_bins=wavelength_bins,
                            parametrization=GRID[0], resolution=GRID[1])


def simulated_albedo(result: SimulationResult) -> tuple[np.ndarray, np.ndarray]:
    """(albedo, standard error), each (M, C): ``reflected + transmitted`` and the standard error
    of that mean from the per-path second moments (a path exits once, so ``E[(r + t)^2] =
    E[r^2] + E[t^2]``; the second moments are recovered from the means and standard errors
    :func:`goniometer.run.results.assemble` stores). ``C`` is 3 (RGB) or, for a spectral result, the
    wavelength bins, each estimated from ``rays`` paths (``docs/spectral.md`` section 1); not for a
    spectral result reduced to sRGB, whose standard errors are bounds (:func:`albedo_in_srgb`)."""
    n = result.settings.rays
    mean = result.energy["reflected"] + result.energy["transmitted"]
    second = np.zeros_like(mean)
    for k in ("reflected", "transmitted"):
        m, se = result.energy[k], result.energy_stderr[k]
        second += se * se * max(n - 1, 1) + m * m          # (sum of squared weights) / n
    var = np.maximum(second - mean * mean, 0.0) / max(n - 1, 1)
    return mean, np.sqrt(var)


def needed_sides(stack: Stack) -> tuple[str, ...]:
    """The sides a stack emits into: ``("brdf", "btdf")`` if it transmits, else ``("brdf",)``."""
    return ("brdf", "btdf") if stack.transmits else ("brdf",)


def model_reason(model, stack: Stack) -> str | None:
    """Why ``model``'s directional albedo of ``stack`` cannot be computed (None if it can)."""
    reason = model.reason(stack)
    if reason is not None:
        return reason
    missing = [s for s in needed_sides(stack) if s not in model.sides]
    if missing:
        return (f"models the {'/'.join(s.upper() for s in model.sides)} only; the albedo of this stack needs its "
                f"{' and '.join(s.upper() for s in needed_sides(stack))}")
    i = smooth_interface(stack)
    if i is not None:
        return (f"layers[{i}] is perfectly smooth (roughness 0): its Dirac lobe is not a function a quadrature "
                f"integrates (models return 0 there)")
    return None


@dataclass
class ModelAlbedos:
    """Models' directional albedos: ``albedo[name]`` (M, 3), ``sides[name][side]`` (M, 3), the
    models that were not evaluated with the reason (``skipped``) and those that failed
    (``failed``: :class:`models.base.ModelFailure`'s reason; ``docs/models.md`` §3)."""

    albedo: dict[str, np.ndarray] = field(default_factory=dict)
    sides: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    skipped: dict[str, str] = field(default_factory=dict)
    failed: dict[str, str] = field(default_factory=dict)


def model_albedos(stack: Stack, theta_deg: tuple[float, ...], phi_deg: tuple[float, ...] | None = None,
                  order: int = ORDER, progress: Callable[[str], None] | None = None) -> ModelAlbedos:
    """Directional albedo of every registered analytic model that can represent ``stack``, at the
    incident directions (``theta_deg``, ``phi_deg``); the others under ``skipped`` with their
    reason. A model that fails (:class:`models.base.ModelFailure`) is recorded under ``failed`` and
    the others go on."""
    phi_deg = phi_deg if phi_deg is not None else tuple(0.0 for _ in theta_deg)
    out = ModelAlbedos()
    for name, model in registry.all_models().items():
        try:
            reason = model_reason(model, stack)
            if reason is not None:
                out.skipped[name] = reason
                continue
            if progress is not None:
                progress(name)
            per_side = {}
            for side in needed_sides(stack):
                per_side[side] = np.array([directional_albedo(model, stack, light_direction(t, p), side, order)
                                           for t, p in zip(theta_deg, phi_deg)])
        except ModelFailure as e:
            out.failed[name] = e.reason
            continue
        out.sides[name] = per_side
        out.albedo[name] = sum(per_side.values())
    for name in registry.fitted_models():
        out.skipped[name] = "a fitted model is fitted to a simulated file's slices (gonio fit); a furnace run keeps none"
    return out


#: the key under which :func:`albedo_in_srgb` passes the albedo through the colour pipeline
_ALBEDO = "directional_albedo"


def albedo_in_srgb(result: SimulationResult, albedo: np.ndarray, stderr: np.ndarray
                   ) -> tuple[SimulationResult, np.ndarray, np.ndarray]:
    """A spectral ``result`` and its per-bin ``albedo`` and ``stderr`` (M, B) in linear sRGB:
    ``(result.rgb(), albedo (M, 3), stderr (M, 3))``. The albedo rides through
    :meth:`SimulationResult.rgb` as one more energy term, so it gets exactly the reduction the
    energies get (the bins' D65 / CIE 1931 weights; the standard error bounded over the bins of
    one launch and added in quadrature over launches, ``docs/spectral.md`` section 4)."""
    carrier = dataclasses.replace(result, energy={**result.energy, _ALBEDO: albedo},
                                  energy_stderr={**result.energy_stderr, _ALBEDO: stderr})
    rgb = carrier.rgb()
    return rgb, rgb.energy.pop(_ALBEDO), rgb.energy_stderr.pop(_ALBEDO)



@dataclass
class SpectralBins:
    """A spectral furnace run per wavelength bin: ``albedo``, ``stderr`` and every energy term
    (M, B), ``wavelength_nm`` the bin centres (B,), ``launches`` the launches per incident
    direction (each of ``rays`` paths; ``docs/spectral.md`` section 2)."""

    wavelength_nm: np.ndarray                # (B,)
    albedo: np.ndarray                       # (M, B)
    stderr: np.ndarray                       # (M, B)
    energy: dict[str, np.ndarray]            # ENERGY_TERMS -> (M, B)
    energy_stderr: dict[str, np.ndarray]     # reflected, transmitted, absorbed, masking_loss -> (M, B)
    launches: int

    @property
    def bins(self) -> int:
        return int(self.wavelength_nm.size)

    def to_json(self) -> dict[str, Any]:
        """``spectral`` of ``gonio furnace --json`` (``docs/furnace.md`` section 4)."""
        rows = (lambda a: np.asarray(a, dtype=float).tolist())
        return {"wavelength_bins": self.bins, "wavelength_nm": rows(self.wavelength_nm),
                "launches": self.launches,
                "per_bin": {"albedo": rows(self.albedo), "stderr": rows(self.stderr),
                            "energy": {k: rows(self.energy[k]) for k in ENERGY_TERMS},
                            "energy_stderr": {k: rows(v) for k, v in self.energy_stderr.items()}}}


def spectral_bins(result: SimulationResult) -> SpectralBins:
    """The per-bin table of a spectral run's ``result``."""
    from goniometer.run.launches import launches
    albedo, stderr = simulated_albedo(result)
    energy = {k: result.energy[k] for k in SLICE_ENERGY_TERMS}
    energy["roulette"] = result.roulette
    energy["capped"] = result.capped
    return SpectralBins(np.asarray(result.wavelengths_nm), albedo, stderr, energy, dict(result.energy_stderr),
                        len(launches(result.stack, result.settings)))


@dataclass
class FurnaceResult:
    """A furnace table: the simulated albedo with its standard error and energy terms, and the
    models' albedos, at the incident directions (``docs/furnace.md``). The (M, 3) arrays are RGB,
    or for a spectral run (``spectral`` not None, holding the bins) the bins' linear sRGB."""

    material: str
    category: str
    base: str
    incident_deg: np.ndarray                 # (M,)
    incident_phi_deg: np.ndarray             # (M,)
    albedo: np.ndarray                       # (M, 3)
    stderr: np.ndarray                       # (M, 3)
    energy: dict[str, np.ndarray]            # ENERGY_TERMS -> (M, 3)
    energy_stderr: dict[str, np.ndarray]     # reflected, transmitted, absorbed, masking_loss -> (M, 3)
    models: ModelAlbedos
    rays: int
    seed: int
    masking: str
    capped_paths: int
    quadrature: dict[str, Any]
    spectral: SpectralBins | None = None

    @property
    def sides(self) -> tuple[str, ...]:
        return ("brdf", "btdf") if self.base == "transmit" else ("brdf",)

    @property
    def channels(self) -> str:
        """What the (M, 3) arrays' channels are, in words."""
        if self.spectral is None:
            return "R G B"
        return f"linear sRGB (D65) of {self.spectral.bins} wavelength bins"

    def to_json(self) -> dict[str, Any]:
        """The object printed by ``gonio furnace --json`` (``docs/furnace.md``, JSON)."""
        rows = (lambda a: np.asarray(a, dtype=float).tolist())
        return {
            "material": self.material, "category": self.category, "base": self.base,
            "sides": list(self.sides),
            "incident_deg": rows(self.incident_deg),
            "incident_phi_deg": rows(self.incident_phi_deg),
            "channels": self.channels,
            "simulated": {
                "albedo": rows(self.albedo),
                "stderr": rows(self.stderr),
                "energy": {k: rows(self.energy[k]) for k in ENERGY_TERMS},
                "energy_stderr": {k: rows(v) for k, v in self.energy_stderr.items()},
                "rays": self.rays, "seed": self.seed, "masking": self.masking, "capped_paths": self.capped_paths,
            },
            "models": {n: rows(a) for n, a in self.models.albedo.items()},
            "model_sides": {n: {s: rows(a) for s, a in d.items()} for n, d in self.models.sides.items()},
            "skipped": dict(self.models.skipped),
            "failed": dict(self.models.failed),
            "quadrature": dict(self.quadrature),
            **({} if self.spectral is None else {"spectral": self.spectral.to_json()}),
        }


def run_furnace(stack: Stack, settings: SimulationSettings, progress: Callable[[int], None] | None = None,
                model_progress: Callable[[str], None] | None = None,
                models: ModelAlbedos | None = None) -> FurnaceResult:
    """Simulate ``stack`` at the incident directions of ``settings`` (its grid is replaced by
    :data:`GRID`) and evaluate every model that applies. The models run first, so a model that
    fails does so before the simulation; ``models`` (from :func:`model_albedos` at the same
    directions) are taken as they are. ``progress(paths)`` as in
    :func:`goniometer.run.loop.run_incidents` (which compiles the kernel on first use; a spectral run
    reports the paths of all its launches), ``model_progress(name)`` before each model. A
    spectral ``settings`` gives the table in linear sRGB and the bins in ``spectral``."""
    if settings.resolution != GRID[1] or settings.parametrization != GRID[0]:
        settings = settings.with_overrides(parametrization=GRID[0], resolution=GRID[1])
    settings.validate()
    theta, phi = settings.incident_deg, settings.incident_phi_deg
    if models is None:
        models = model_albedos(stack, theta, phi, progress=model_progress)
    result = run_incidents(stack, settings, progress=progress)
    bins = None
    if settings.spectral:
        bins = spectral_bins(result)
        result, albedo, stderr = albedo_in_srgb(result, bins.albedo, bins.stderr)
    else:
        albedo, stderr = simulated_albedo(result)
    energy = {k: result.energy[k] for k in SLICE_ENERGY_TERMS}
    energy["roulette"] = result.roulette
    energy["capped"] = result.capped
    quadrature = {"rule": "composite Gauss-Legendre in (theta, phi), graded about the mirror and Snell directions",
                  "order": ORDER, "max_panel_rad": MAX_PANEL, "finest_panel_rad": lobe_scale(stack)}
    return FurnaceResult(stack.name, stack.category, stack.base, np.array(theta), np.array(phi), albedo, stderr,
                         energy, dict(result.energy_stderr), models, settings.rays, settings.seed, settings.masking,
                         int(np.sum(result.capped_paths)), quadrature, bins)


__all__ = ["INCIDENT_DEG", "RAYS", "GRID", "ENERGY_TERMS", "furnace_settings", "simulated_albedo", "albedo_in_srgb",
           "needed_sides", "model_reason", "ModelAlbedos", "model_albedos", "SpectralBins", "spectral_bins",
           "FurnaceResult", "run_furnace"]
