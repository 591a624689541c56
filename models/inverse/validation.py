"""Validation of the inverse method (Bati 2021) on target lobe configurations: the library part.

Cases (:func:`load_cases`: a TOML file of ``[[case]]`` tables, ``configs/inverse/cases.toml``),
the forward check of the paper's figure 25 (:func:`forward_check`: the retrieved stack through
Belcour's forward model at ``cos theta = 1``, per channel; lobe energies summed over a lobe's
interfaces, variances energy-weighted, eq. 4), optional simulation at normal incidence with the
lobe estimator of :mod:`models.inverse.estimate` (:func:`run_case`, :func:`run_validation`) and
the JSON documents (:func:`validation_json`, :func:`inversion_json`). The markdown/HTML report
and the figures are the application's (:mod:`models.report.inverse`). Formats and limits:
``docs/inverse.md``, "Validation".
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from goniometer.stack import Stack
from goniometer.tomlfile import read_toml
from models import belcour
from models.inverse.estimate import RingData, estimate_lobes, ring_data
from models.inverse.lobes import InverseError, InverseOptions, Lobe, Pick, jsonable, parse_picks
from models.inverse.solver import Inversion, solve

#: relative tolerance of the forward check (figure 25): what the tests require of the round trip
FORWARD_RTOL = 0.01
#: default simulation settings of the validation
DEFAULT_RAYS = 4_000_000
DEFAULT_RESOLUTION = (90, 8)


# ============================================================================ cases

@dataclass(frozen=True)
class Case:
    """One target configuration: lobes (top first), base, optional picks and expectations."""

    name: str
    base: str
    lobes: tuple[Lobe, ...]
    pick: str = ""
    expect_achievable: bool = True
    note: str = ""

    def picks(self) -> list[Pick]:
        return parse_picks(self.pick, len(self.lobes))


def load_cases(path: str | os.PathLike) -> list[Case]:
    """Read a cases file; raises :class:`InverseError` naming the file, case and field."""
    p = Path(path)
    data = read_toml(p, InverseError)
    raw = data.get("case")
    if not isinstance(raw, list) or not raw:
        raise InverseError(f"{p}: no [[case]] tables")
    unknown = sorted(set(data) - {"case"})
    if unknown:
        raise InverseError(f"{p}: {unknown[0]}: unknown key (only [[case]] tables)")
    cases, names = [], set()
    for i, c in enumerate(raw):
        where = f"{p}: case[{i}]"
        if not isinstance(c, dict):
            raise InverseError(f"{where}: must be a table")
        bad = sorted(set(c) - {"name", "base", "lobe", "pick", "expect_achievable", "note"})
        if bad:
            raise InverseError(f"{where}.{bad[0]}: unknown key (name, base, lobe, pick, expect_achievable, note)")
        name = c.get("name")
        if not isinstance(name, str) or not name.strip():
            raise InverseError(f"{where}.name: required, a non-empty string")
        where = f"{p}: case {name!r}"
        if name in names:
            raise InverseError(f"{where}: duplicate name")
        names.add(name)
        base = c.get("base", "dielectric")
        if base not in ("dielectric", "conductor"):
            raise InverseError(f"{where}.base: {base!r} is not one of dielectric, conductor")
        lobes_raw = c.get("lobe")
        if not isinstance(lobes_raw, list) or not lobes_raw:
            raise InverseError(f"{where}.lobe: at least one [[case.lobe]] table is required")
        lobes = []
        for j, lr in enumerate(lobes_raw):
            w = f"{where}.lobe[{j}]"
            if not isinstance(lr, dict):
                raise InverseError(f"{w}: must be a table")
            bad = sorted(set(lr) - {"R", "sigma", "layers"})
            if bad:
                raise InverseError(f"{w}.{bad[0]}: unknown key (R, sigma, layers)")
            if "R" not in lr:
                raise InverseError(f"{w}.R: required")
            try:
                lobes.append(Lobe(lr["R"] if not isinstance(lr["R"], list) else tuple(lr["R"]),
                                  lr.get("sigma", 0.0), lr.get("layers", 1)))
            except (InverseError, TypeError, ValueError) as e:
                raise InverseError(f"{w}: {e}") from None
        pick = c.get("pick", "")
        if not isinstance(pick, str):
            raise InverseError(f"{where}.pick: a string in the --pick syntax (e.g. \"1.u1=0.3\")")
        try:
            parse_picks(pick, len(lobes))
        except InverseError as e:
            raise InverseError(f"{where}.pick: {e}") from None
        exp = c.get("expect_achievable", True)
        if not isinstance(exp, bool):
            raise InverseError(f"{where}.expect_achievable: true or false")
        note = c.get("note", "")
        cases.append(Case(name, base, tuple(lobes), pick, exp, str(note)))
    return cases


# ============================================================================ (a) forward check

@dataclass
class LobeCheck:
    """Requested vs forward (and simulated) statistics of one lobe (RGB arrays)."""

    R_requested: np.ndarray
    sigma_requested: float
    R_forward: np.ndarray
    sigma_forward: np.ndarray
    interfaces: list[int]
    R_predicted: np.ndarray
    sigma_predicted: np.ndarray
    R_simulated: np.ndarray | None = None
    sigma_simulated: np.ndarray | None = None
    R_simulated_err: np.ndarray | None = None
    sigma_simulated_err: np.ndarray | None = None
    group: list[int] | None = None

    @property
    def R_rel_error(self) -> np.ndarray:
        return self.R_forward / self.R_requested - 1.0

    @property
    def sigma_rel_error(self) -> np.ndarray:
        if self.sigma_requested > 0.0:
            return self.sigma_forward / self.sigma_requested - 1.0
        return self.sigma_forward  # absolute for a smooth lobe


def forward_lobes(stack: Stack, lobe_interfaces: Sequence[Sequence[int]],
                  options: belcour.BelcourOptions | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """Belcour's forward model of ``stack`` at normal incidence, grouped per requested lobe:
    ``[(energy RGB, variance RGB), ...]`` (energies summed, variances energy-weighted, eq. 4)."""
    s = belcour.stack_statistics(stack, 1.0, options)
    out = []
    for idx in lobe_interfaces:
        e = np.sum([s.lobes[i].energy for i in idx], axis=0)
        ev = np.sum([s.lobes[i].energy * s.lobes[i].variance for i in idx], axis=0)
        out.append((e, np.where(e > 0, ev / np.where(e > 0, e, 1.0), 0.0)))
    return out


def forward_check(inv: Inversion) -> list[LobeCheck]:
    """Requested vs forward-model statistics of every lobe of an achievable inversion."""
    fw = forward_lobes(inv.stack(), inv.lobe_interfaces)
    pred = inv.predicted()
    return [LobeCheck(lobe.rgb, lobe.sigma, e, v, idx, pe, pv)
            for lobe, (e, v), (pe, pv), idx in zip(inv.lobes, fw, pred, inv.lobe_interfaces)]


def inversion_json(inv: Inversion, stack: Stack | None = None,
                   checks: Sequence[LobeCheck] | None = None) -> dict[str, Any]:
    """The JSON document of ``gonio invert --json``: :meth:`Inversion.to_json` in JSON values, then
    for an achievable inversion its ``stack`` (the material's JSON form) and each lobe's
    ``R_forward`` and ``sigma_forward`` from its forward ``checks``."""
    d = jsonable(inv.to_json())
    if stack is not None:
        d["stack"] = json.loads(stack.to_json())
    for k, c in enumerate(checks or ()):
        d["lobes"][k]["R_forward"] = c.R_forward.tolist()
        d["lobes"][k]["sigma_forward"] = c.sigma_forward.tolist()
    return d


# ============================================================================ (b) simulation

def simulate_case(stack: Stack, lobes: Sequence[Lobe], rays: int = DEFAULT_RAYS,
                  resolution: tuple[int, int] = DEFAULT_RESOLUTION, seed: int = 1,
                  threads: int | None = None) -> tuple[Any, RingData]:
    """Simulate ``stack`` at normal incidence (half slices) and reduce to rings."""
    from goniometer.run.settings import SimulationSettings
    from goniometer.run.loop import simulate
    settings = SimulationSettings(incident_deg=(0.0,), rays=int(rays), parametrization="half",
                                  resolution=tuple(resolution), seed=int(seed), threads=threads)
    result = simulate(stack, settings)
    return result, ring_data(result)


# ============================================================================ running cases

@dataclass
class CaseResult:
    """Everything the validation found for one case."""

    case: Case
    inversion: Inversion
    checks: list[LobeCheck] = field(default_factory=list)
    simulated: dict[str, Any] | None = None
    rings: RingData | None = None
    top_order1: dict[str, Any] | None = None
    stack_json: dict | None = None
    elapsed_invert_s: float = 0.0
    elapsed_simulate_s: float = 0.0

    @property
    def achievable(self) -> bool:
        return self.inversion.achievable

    def max_forward_error(self) -> tuple[float, float]:
        """Largest relative error of R and sigma (absolute sigma for smooth lobes) over lobes and channels."""
        if not self.checks:
            return float("nan"), float("nan")
        er = max(float(np.max(np.abs(c.R_rel_error))) for c in self.checks)
        es = max(float(np.max(np.abs(c.sigma_rel_error))) for c in self.checks)
        return er, es

    def to_json(self) -> dict[str, Any]:
        d: dict[str, Any] = {"name": self.case.name, "base": self.case.base, "achievable": self.achievable,
                             "expect_achievable": self.case.expect_achievable}
        if self.case.note:
            d["note"] = self.case.note
        if self.case.pick:
            d["pick"] = self.case.pick
        if not self.achievable:
            d["reason"] = self.inversion.reason
            d["lobes"] = [{"R_requested": list(lb.R), "sigma_requested": [lb.sigma] * 3, "layers": lb.layers}
                          for lb in self.case.lobes]
            return d
        d["stack"] = self.stack_json
        d["searched"] = self.inversion.searched
        d["elapsed_invert_s"] = self.elapsed_invert_s
        lobes = []
        for k, c in enumerate(self.checks):
            e: dict[str, Any] = {
                "layers": self.case.lobes[k].layers,
                "interfaces": c.interfaces,
                "R_requested": c.R_requested.tolist(),
                "R_forward": c.R_forward.tolist(),
                "sigma_requested": [c.sigma_requested] * 3,
                "sigma_forward": c.sigma_forward.tolist(),
                "R_forward_rel_error": c.R_rel_error.tolist(),
                "sigma_forward_error": c.sigma_rel_error.tolist(),
                "sigma_forward_error_kind": "relative" if c.sigma_requested > 0 else "absolute",
                "choices": jsonable(self.inversion.solutions[k].choices),
            }
            if self.simulated is not None:
                s = self.simulated["lobes"][k]
                e["R_simulated"] = None if s.get("R") is None else np.asarray(s["R"]).tolist()
                e["sigma_simulated"] = None if s.get("sigma") is None else np.asarray(s["sigma"]).tolist()
                e["R_simulated_stderr"] = None if s.get("R_err") is None else np.asarray(s["R_err"]).tolist()
                e["sigma_simulated_stderr"] = None if s.get("sigma_err") is None else np.asarray(s["sigma_err"]).tolist()
                if s.get("group"):
                    e["simulated_group"] = s["group"]
            lobes.append(e)
        d["lobes"] = lobes
        if self.simulated is not None:
            d["simulation"] = {
                "rays": self.rings.rays if self.rings else None,
                "groups": jsonable(self.simulated["groups"]),
                "fit_chi2_dof_internal": self.simulated["chi2_dof"],
                "fit_chi2_dof_order1": self.simulated["chi2_dof_top"],
                "top_interface_order1": jsonable(self.top_order1),
                "elapsed_s": self.elapsed_simulate_s,
            }
        return d


def run_case(case: Case, simulate: bool = False, rays: int = DEFAULT_RAYS,
             resolution: tuple[int, int] = DEFAULT_RESOLUTION, seed: int = 1,
             options: InverseOptions | None = None, threads: int | None = None) -> CaseResult:
    """Invert one case, check it through the forward model and optionally simulate it."""
    t0 = time.perf_counter()
    inv = solve(list(case.lobes), case.base, case.picks(), options, name=case.name)
    res = CaseResult(case, inv, elapsed_invert_s=time.perf_counter() - t0)
    if not inv.achievable:
        return res
    stack = inv.stack()
    res.stack_json = json.loads(stack.to_json())
    res.checks = forward_check(inv)
    if simulate:
        t1 = time.perf_counter()
        result, rings = simulate_case(stack, case.lobes, rays, resolution, seed, threads)
        res.elapsed_simulate_s = time.perf_counter() - t1
        res.rings = rings
        est = estimate_lobes(rings, case.lobes)
        res.simulated = est
        for k, c in enumerate(res.checks):
            s = est["lobes"][k]
            if s.get("R") is not None:
                c.R_simulated, c.sigma_simulated = s["R"], s["sigma"]
                c.R_simulated_err, c.sigma_simulated_err = s["R_err"], s["sigma_err"]
            else:
                c.group = s.get("group")
        # order 1 = reflection off the top interface = FGD(1, alpha_0, eta_1) in the forward model
        fs = belcour.stack_statistics(stack, 1.0)
        o1 = rings.orders[0].sum(axis=1) if rings.orders.shape[0] else np.zeros(3)
        res.top_order1 = {"simulated": o1, "fgd": fs.lobes[0].energy,
                          "stderr": np.sqrt(np.maximum(o1, 0.0) / rings.rays)}
    return res


def run_validation(cases: Sequence[Case], simulate: bool = False, rays: int = DEFAULT_RAYS,
                   resolution: tuple[int, int] = DEFAULT_RESOLUTION, seed: int = 1,
                   options: InverseOptions | None = None, threads: int | None = None,
                   progress: Callable[[int, int, str], None] | None = None) -> list[CaseResult]:
    """Run every case (``progress(done, total, name)`` after each)."""
    out = []
    for i, c in enumerate(cases):
        out.append(run_case(c, simulate, rays, resolution, seed, options, threads))
        if progress:
            progress(i + 1, len(cases), c.name)
    return out


def validation_json(results: Sequence[CaseResult], simulate: bool, meta: dict | None = None) -> dict[str, Any]:
    """The JSON document of :func:`run_validation` (docs/inverse.md, "Validation")."""
    achieved = [r for r in results if r.achievable]
    errs = [r.max_forward_error() for r in achieved]
    return {
        "format": "goniometer.inverse-validation",
        "version": 1,
        "simulated": simulate,
        "meta": meta or {},
        "summary": {
            "cases": len(results),
            "achievable": len(achieved),
            "unexpected": [r.case.name for r in results if r.achievable != r.case.expect_achievable],
            "max_R_forward_rel_error": max((e[0] for e in errs), default=None),
            "max_sigma_forward_error": max((e[1] for e in errs), default=None),
            "forward_rtol": FORWARD_RTOL,
        },
        "cases": [r.to_json() for r in results],
    }
