"""What every cell of a table is, as simulator runs: the stacks, the incident directions, and how
a cell's value and standard error come out of the runs' results (``docs/lut.md`` section 3).

A table's cells are grouped into **rows**: the cells that share every parameter but the incident
direction. A row reads one or two **runs** (a stack traced at the row's incident directions,
:func:`goniometer.run.loop.run_incidents`); rows that need the same run (a coat table's bare base,
say) share it. Each quantity reuses the project's estimators:

* ``albedo``: ``reflected + transmitted`` of the tracer's energy bookkeeping with its exact
  standard error (:func:`models.furnace.simulated_albedo`, ``docs/furnace.md`` section 2), or
  one of the two terms (``part``);
* ``albedo-average``: ``2 Int_0^1 E(mu) mu dmu`` by Gauss-Legendre in mu over the row's runs at
  the nodes, standard errors added in quadrature with the weights;
* ``coat-albedo``: the albedo of the coated stack;
* ``coat-darkening``: the factor ``Delta`` of the albedo-scaling layering at the incident
  direction ``l``. ``darkening = "albedo"`` (default): the layering's own albedo relation
  ``E(l) = E_coat(l) + (1 - E_coat(l)) Delta E_bare(l)`` solved for ``Delta`` with the coated
  stack's internal albedo (bounce orders >= 2; :func:`models.production.study.effective.internal_albedo`),
  the coat's reflection albedo ``E_coat`` (Belcour's FGD quadrature) and the bare twin's albedo,
  ``Delta = E_int / ((1 - E_coat(l)) E_bare(l))``; ``"production"``: ``gonio production``'s
  effective darkening (``docs/production.md`` section 2) per incident direction, ``E_int`` over
  ``P = sum_cells (1 - E_coat(v)) f_bare Omega`` (the coat's exit weighting only);
* ``coat-roughness``: ``gonio production``'s effective base roughness (GGX alpha; section 3) at
  normal incidence.

Stacks are achromatic (the three channels are one estimate), so channel 0 is the cell's value.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from goniometer.run.results import SimulationResult
from goniometer.run.settings import SimulationSettings
from goniometer.stack import Interface, Lambertian, Stack
from models.furnace import GRID, simulated_albedo
from models.lut.definition import Definition, LutError
from models.production.study.effective import (coat_albedo_rows, effective_roughness, internal_albedo,
                                               layered_prediction)
from models.tables import fgd_direct_many

#: the index of a conductor that reflects everything: an index all but purely imaginary has
#: |r_s| = |r_p| = 1, F = 1 at every angle to double precision (``docs/furnace.md``)
WHITE_IOR, WHITE_EXTINCTION = 1e-9, 1.0


@dataclass(frozen=True)
class RunSpec:
    """One stack traced at some incident elevations (degrees), before its rays and seed are set."""

    stack: Stack
    incident_deg: tuple[float, ...]
    grid: tuple[str, tuple[int, int]]

    @property
    def key(self) -> str:
        """Identifies the run within a table (stack and incident directions and grid)."""
        text = json.dumps([json.loads(self.stack.to_json()), list(self.incident_deg), self.grid[0],
                           list(self.grid[1])])
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def settings(self, rays: int, seed: int, masking: str, **kw: Any) -> SimulationSettings:
        return SimulationSettings(incident_deg=self.incident_deg, rays=int(rays), seed=int(seed), masking=masking,
                                  parametrization=self.grid[0], resolution=self.grid[1], **kw)


@dataclass(frozen=True)
class Row:
    """The cells of a table that differ only in their incident direction.

    ``index``: the row's position in the table (a tuple with ``slice(None)`` on the incident
    axis); ``params``: its parameter values; ``runs``: the keys of the runs it reads, in the order
    :func:`reduce_row` takes them; ``incident``: for each cell along the incident axis, the index
    of its direction in the runs' ``incident_deg`` (an ``albedo-average`` row: for each
    Gauss-Legendre node; a table without an incident axis: one cell)."""

    index: tuple
    params: dict[str, float]
    runs: tuple[str, ...]
    incident: tuple[int, ...]


def incident_elevations(defn: Definition) -> tuple[np.ndarray, np.ndarray | None]:
    """The incident elevations (degrees) of every run of the table and, for an
    ``albedo-average`` table, the Gauss-Legendre weights of ``2 mu dmu`` at them (else None)."""
    k = defn.incident_axis
    if defn.quantity == "albedo-average":
        x, w = np.polynomial.legendre.leggauss(defn.average_nodes)
        mu = 0.5 * (x + 1.0)
        return np.degrees(np.arccos(mu)), w * mu       # 2 mu (w / 2)
    if k is None:
        return np.zeros(1), None
    a = defn.axes[k]
    v = a.values()
    return (np.degrees(np.arccos(v)) if a.parameter == "mu" else v), None


def build_rows(defn: Definition) -> tuple[list[Row], dict[str, RunSpec]]:
    """The rows of the table in C order of its non-incident axes, and the runs they read (key ->
    spec, in order of first use). Raises :class:`LutError` for a parameter value the stacks
    cannot take (naming it)."""
    theta, _ = incident_elevations(defn)
    distinct = sorted(set(float(t) for t in theta))
    incident = tuple(distinct.index(float(t)) for t in theta)
    thetas = tuple(distinct)
    inc = defn.incident_axis
    others = [k for k in range(len(defn.axes)) if k != inc]
    values = defn.axis_values()
    rows: list[Row] = []
    runs: dict[str, RunSpec] = {}
    for idx in np.ndindex(*[defn.axes[k].nodes for k in others]):
        params = {defn.axes[k].parameter: float(values[k][i]) for k, i in zip(others, idx)}
        full: list[Any] = list(idx)
        if inc is not None:
            full.insert(inc, slice(None))
        specs = row_runs(defn, params, thetas)
        for s in specs:
            runs.setdefault(s.key, s)
        rows.append(Row(tuple(full), params, tuple(s.key for s in specs), incident))
    return rows, runs


def _param(defn: Definition, section: str, key: str, params: dict[str, float], parameter: str,
           default: float | None = None) -> float:
    if parameter in params:
        return params[parameter]
    table = getattr(defn, section)
    return float(table[key]) if key in table else float(default)


def interface_stack(defn: Definition, params: dict[str, float]) -> Stack:
    """The one interface of an albedo table with the row's parameters (``docs/lut.md`` section 3)."""
    t = defn.interface
    alpha = _param(defn, "interface", "roughness", params, "roughness")
    ms = defn.multiple_scattering
    if t["fresnel"] == "white":
        layer = Interface(alpha, (WHITE_IOR,) * 3, (WHITE_EXTINCTION,) * 3, multiple_scattering=ms)
    elif t["fresnel"] == "conductor":
        eta = _param(defn, "interface", "ior", params, "ior")
        layer = Interface(alpha, (eta,) * 3, (float(t["extinction"]),) * 3, multiple_scattering=ms)
    else:
        eta = _param(defn, "interface", "ior", params, "ior")
        if eta == 1.0:
            raise LutError("interface.ior: a node gives index 1 (index-matched: the interface scatters nothing)")
        if t.get("side", "outside") == "inside":
            eta = 1.0 / eta
        layer = Interface(alpha, (eta,) * 3, multiple_scattering=ms)
    return Stack(f"lut/{defn.name}", (layer,))


def conductor_extinction(f0: float, eta: float) -> float:
    """The extinction ``kappa`` of a conductor of real index ``eta`` whose normal-incidence
    reflectance in air is ``f0``: ``((eta-1)^2 + kappa^2) / ((eta+1)^2 + kappa^2) = f0``. Raises
    :class:`LutError` if no ``kappa > 0`` gives it (``f0 <= ((eta-1)/(eta+1))^2``)."""
    low = ((eta - 1.0) / (eta + 1.0)) ** 2
    if not low < f0 < 1.0:
        raise LutError(f"base.albedo: {f0:g} is outside ({low:g}, 1] for a conductor of base.ior {eta:g} (its F0 "
                       f"in air; 1 is the white conductor)")
    return math.sqrt((f0 * (eta + 1.0) ** 2 - (eta - 1.0) ** 2) / (1.0 - f0))


def base_layer(defn: Definition, params: dict[str, float]):
    """The base of a coat table: a Lambertian of the albedo, or a GGX conductor whose F0 in air is
    the albedo (the white conductor at 1)."""
    b = defn.base
    albedo = _param(defn, "base", "albedo", params, "base_albedo")
    if b["kind"] == "lambertian":
        return Lambertian((albedo,) * 3)
    alpha = _param(defn, "base", "roughness", params, "base_roughness")
    if albedo == 1.0:
        eta, kappa = WHITE_IOR, WHITE_EXTINCTION
    else:
        eta = float(b.get("ior", 1.0))
        kappa = conductor_extinction(albedo, eta)
    return Interface(alpha, (eta,) * 3, (kappa,) * 3, multiple_scattering=defn.multiple_scattering)


def coat_stacks(defn: Definition, params: dict[str, float]) -> tuple[Stack, Stack]:
    """(coated, bare): the coat over the base, and the base alone in air (its twin)."""
    n = _param(defn, "coat", "ior", params, "coat_ior")
    alpha = _param(defn, "coat", "roughness", params, "coat_roughness")
    base = base_layer(defn, params)
    coat = Interface(alpha, (n,) * 3, multiple_scattering=defn.multiple_scattering)
    return Stack(f"lut/{defn.name}", (coat, base)), Stack(f"lut/{defn.name}/bare", (base,))


def row_runs(defn: Definition, params: dict[str, float], thetas: tuple[float, ...]) -> list[RunSpec]:
    """The runs a row reads (:func:`reduce_row` takes their results in this order)."""
    if defn.quantity in ("albedo", "albedo-average"):
        return [RunSpec(interface_stack(defn, params), thetas, GRID)]
    coated, bare = coat_stacks(defn, params)
    grid = ("classic", defn.resolution) if defn.uses_slices else GRID
    if defn.quantity == "coat-albedo":
        return [RunSpec(coated, thetas, GRID)]
    if defn.quantity == "coat-roughness":
        return [RunSpec(coated, thetas, grid)]
    return [RunSpec(coated, thetas, grid), RunSpec(bare, thetas, grid)]


def reduce_row(defn: Definition, row: Row, results: list[SimulationResult],
               weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The row's cells (value, standard error), each (cells along the incident axis,) -- one cell
    for a table without an incident axis."""
    q = defn.quantity
    r = results[0]
    if q in ("albedo", "albedo-average", "coat-albedo"):
        if defn.part == "both" or q == "coat-albedo":
            e, se = simulated_albedo(r)
        else:
            e, se = r.energy[defn.part], r.energy_stderr[defn.part]
        e, se = e[list(row.incident), 0], se[list(row.incident), 0]
        if q == "albedo-average":
            return np.array([np.sum(weights * e)]), np.array([math.sqrt(np.sum((weights * se) ** 2))])
        return e, se
    if q == "coat-roughness":
        rough = effective_roughness(r)
        return np.array([rough.alpha]), np.array([rough.stderr])
    bare = results[1]
    coat = r.stack.layers[0]
    e, e_se = internal_albedo(r)
    if defn.darkening == "albedo":
        mu = np.cos(np.radians(np.asarray(r.settings.incident_deg)))
        e_coat = fgd_direct_many(mu, coat.roughness, coat.ior[0], 0.0, r.settings.masking == "height-correlated")
        e_bare, e_bare_se = simulated_albedo(bare)
        p, p_se = (1.0 - e_coat)[:, None] * e_bare, (1.0 - e_coat)[:, None] * e_bare_se
    else:
        rows = coat_albedo_rows(coat.roughness, coat.ior[0], r.settings.masking, r.brdf.grid.n_theta)
        p, p_se = layered_prediction(bare, rows)
    e, e_se, p, p_se = e[:, 0], e_se[:, 0], p[:, 0], p_se[:, 0]
    d = e / p
    se = np.abs(d) * np.sqrt((e_se / e) ** 2 + (p_se / p) ** 2)
    return d[list(row.incident)], se[list(row.incident)]


def cell_parameters(defn: Definition) -> dict[str, np.ndarray]:
    """Every parameter of the table at every cell (arrays of the table's shape): the axes' values
    broadcast, and the fixed values of the quantity's sections (roughness as GGX alpha)."""
    shape = defn.shape
    out: dict[str, np.ndarray] = {}
    for k, (a, v) in enumerate(zip(defn.axes, defn.axis_values())):
        view = [1] * len(shape)
        view[k] = a.nodes
        out[a.parameter] = np.broadcast_to(v.reshape(view), shape)
    if "theta" in out:
        out["mu"] = np.cos(np.radians(out["theta"]))
    names = {"interface": {"roughness": "roughness", "ior": "ior"},
             "coat": {"ior": "coat_ior", "roughness": "coat_roughness"},
             "base": {"albedo": "base_albedo", "roughness": "base_roughness"}}
    for section, keys in names.items():
        table = getattr(defn, section)
        for key, parameter in keys.items():
            if key in table and parameter not in out:
                out[parameter] = np.full(shape, float(table[key]))
    return out


__all__ = ["WHITE_IOR", "WHITE_EXTINCTION", "RunSpec", "Row", "incident_elevations", "build_rows",
           "interface_stack", "conductor_extinction", "base_layer", "coat_stacks", "row_runs", "reduce_row",
           "cell_parameters"]
