"""Measure every coated material of a production results directory (``docs/production.md`` 2-4).

For each coated material (:func:`models.production.study.effective.coated_base`) with a bare twin in
the same directory: the effective darkening (per channel) and, for conductor bases, the effective
base roughness; and the same two estimators applied to ``belcour-fwd``'s internal lobes integrated
onto the reference's cells (:func:`models.compare.integrate`), so the model is read with the very
yardstick the reference is (and, for reference, the roughness its variance statistics give the base
lobe directly). Lambertian bases are outside ``belcour-fwd``'s domain (it refuses
them; its reason is recorded).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from goniometer.files import slices as store
from goniometer.run.results import SimulationResult
from goniometer.stack import Stack
from models.compare import integrate
from models.production.study.effective import (CoatedBase, Darkening, ProductionError, Roughness, bare_key,
                                               coat_albedo_rows, coated_base, darkening_from, effective_darkening,
                                               effective_roughness, layered_prediction,
                                               normal_incidence_index, roughness_from)
from models.belcour import BelcourForward, lobe_statistics
from models.workers import run_in_workers

#: the existing model the production formulas are compared with
BELCOUR = "belcour-fwd"
#: sub-cells per cell side when integrating belcour-fwd onto the reference's cells
BELCOUR_SUBCELLS = 3


@dataclass(frozen=True)
class Measurement:
    """Everything measured on one coated material (and on belcour-fwd for it)."""

    name: str
    config: CoatedBase
    darkening: Darkening
    roughness: Roughness | None                   # conductor bases only
    belcour_darkening: np.ndarray | None          # (3,), None where belcour-fwd refuses the stack
    belcour_roughness: Roughness | None
    belcour_reason: str | None                    # why belcour-fwd has no value
    belcour_lobe_alpha: float | None = None       # its base lobe's own roughness at normal incidence


def belcour_lobe_alpha(stack: Stack) -> float:
    """Roughness of belcour-fwd's base lobe (lobe 1) at normal incidence, channel mean: what its
    variance statistics predict directly (``docs/belcour.md`` §2, §6)."""
    return float(np.mean(lobe_statistics(stack, 1.0)[1][1]))


def belcour_measure(coated: SimulationResult, bare: SimulationResult, cfg: CoatedBase
                    ) -> tuple[np.ndarray | None, Roughness | None, str | None]:
    """belcour-fwd's effective darkening and roughness by the reference's own estimators."""
    model = BelcourForward()
    reason = model.reason(coated.stack)
    if reason is not None:
        return None, None, reason
    ms = integrate(model, coated, "brdf", s=BELCOUR_SUBCELLS)
    sd = coated.brdf
    e = np.einsum("mcij,mij->mc", ms.internal, sd.proj_solid_angle)
    rows = coat_albedo_rows(cfg.coat_alpha, cfg.coat_ior, coated.settings.masking, sd.grid.n_theta)
    p, p_se = layered_prediction(bare, rows)
    d = darkening_from(e, np.zeros_like(e), p, p_se).value
    m = normal_incidence_index(coated)
    r = roughness_from(ms.internal[m], sd.proj_solid_angle[m], cfg, coated.settings.masking,
                       sd.grid.theta_edges_deg())
    return d, r, None


def measure_pair(coated: SimulationResult, bare: SimulationResult, with_belcour: bool = True) -> Measurement:
    """Measure one coated material against its bare twin."""
    cfg = coated_base(coated.stack)
    if cfg is None:
        raise ProductionError(f"{coated.stack.name}: not a clear coat over a conductor or a Lambertian")
    dark = effective_darkening(coated, bare)
    rough = effective_roughness(coated) if cfg.base == "conductor" else None
    bd, br, why = (belcour_measure(coated, bare, cfg) if with_belcour
                   else (None, None, "not evaluated (with_belcour=False)"))
    lobe = belcour_lobe_alpha(coated.stack) if bd is not None and cfg.base == "conductor" else None
    return Measurement(coated.stack.name, cfg, dark, rough, bd, br, why, lobe)


def result_files(results_dir: str | Path) -> list[Path]:
    """The material files of a results directory (paths starting with '.' skipped), sorted."""
    root = Path(results_dir)
    return sorted(p for p in root.rglob("*.h5")
                  if not any(part.startswith(".") for part in p.relative_to(root).parts))


def _measure_file(pair: tuple[Path, Path, bool]) -> Measurement:
    """:func:`measure_pair` of a coated file and its twin's file (here or in a worker process)."""
    coated, bare, with_belcour = pair
    return measure_pair(store.read(coated), store.read(bare), with_belcour)


def _warm_up(coated: Path) -> None:
    """Compile, or load from numba's cache, belcour-fwd's evaluation and the grid's sub-cells here,
    before worker processes start (:mod:`models.workers`); what fails is the measurement's to say."""
    from goniometer.grids.slice_grid import SliceGrid, light_direction
    try:
        stack, _ = store.describe(coated)
        model = BelcourForward()
        v, _ = SliceGrid("classic", 2, 4).subcells(light_direction(30.0, 0.0), 2)
        if model.reason(stack) is None:
            model.evaluate(stack, light_direction(30.0, 0.0), v.reshape(-1, 3)[:8], "brdf")
    except Exception:  # noqa: BLE001 -- the measurement reports what is wrong
        pass


def measure_results(results_dir: str | Path, with_belcour: bool = True,
                    progress: Callable[[int, int, str], None] | None = None,
                    jobs: int = 1) -> tuple[list[Measurement], list[str]]:
    """Measure every coated material of ``results_dir`` that has its bare twin, in ``jobs`` worker
    processes (:mod:`models.workers`; 1: here, one after the other; the measurements are the same).

    Returns the measurements (in file order) and the names of coated materials skipped for want of
    a twin. Files that are neither coated nor bare are ignored. ``progress(done, total, name)``
    when a material starts and once at the end. Raises :class:`ProductionError` if no coated
    material can be measured."""
    bare: dict[str, Path] = {}
    coated: list[tuple[Path, CoatedBase]] = []
    for path in result_files(results_dir):
        stack, settings = store.describe(path)
        if settings.spectral:
            raise ProductionError(f"{path}: a spectral run ({settings.wavelength_bins} wavelength bins); the "
                                  f"production study measures RGB channels: simulate the database without "
                                  f"spectral = true in [simulation] (docs/production.md)")
        key = bare_key(stack)
        if key is not None:
            bare[key] = path
            continue
        cfg = coated_base(stack)
        if cfg is not None:
            coated.append((path, cfg))
    missing = [cfg.name for _, cfg in coated if cfg.base_key not in bare]
    pairs = [(path, bare[cfg.base_key], with_belcour) for path, cfg in coated if cfg.base_key in bare]
    names = [cfg.name for _, cfg in coated if cfg.base_key in bare]
    finished = [len(missing)]

    def start(i: int) -> None:
        if progress is not None:
            progress(finished[0], len(coated), names[i])

    def done(i: int, m: Measurement) -> None:
        finished[0] += 1

    out = run_in_workers(_measure_file, pairs, jobs, done=done, start=start,
                         warm_up=(lambda: _warm_up(pairs[0][0])) if with_belcour and pairs else None)
    if progress is not None:
        progress(len(coated), len(coated), "")
    if not out:
        raise ProductionError(f"{results_dir}: no coated material with its bare twin to measure "
                              f"({len(coated)} coated, {len(bare)} bare files)")
    return out, missing
