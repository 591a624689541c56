"""Computing a table: the rays of every run (given, or from a pilot run for a target standard
error), the runs with per-cell checkpoints, and the table with its standard errors
(``docs/lut.md`` sections 4-5).

Checkpoints (``docs/outputs.md`` rule 3) live in ``OUT/.partial/``: ``meta.json`` holds the
table's identity (:meth:`Definition.identity` and the simulator's code key), and each run keeps
its finished incident directions -- its cells -- in ``run-<key>/`` (``pilot-<key>/`` for the
pilot) through :class:`goniometer.run.checkpoints.Checkpoints`. A rerun of the same table resumes
them; one whose definition, rays or code differ is refused naming each differing key
(:class:`goniometer.run.checkpoints.CheckpointMismatch`).

Seeds: run ``k`` of the table (in order of first use) is traced with seed ``seed + k`` and its
pilot with ``seed + k + PILOT_SEED_OFFSET``, so no two runs share a random stream and the table
is the same bits whatever the thread count (``docs/architecture.md``, determinism).
"""

from __future__ import annotations

import math
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from goniometer.kernel.tracer import thread_count
from goniometer.run import checkpoints as ckpt
from goniometer.run.results import SimulationResult, run_description
from goniometer.run.loop import run_incidents
from goniometer.run.settings import SimulationSettings
from goniometer.run.tasks import warm_up_runs
from models.lut.definition import Definition
from models.lut.quantities import Row, RunSpec, build_rows, incident_elevations, reduce_row

#: rays per incident direction of a pilot run (a target standard error)
PILOT_RAYS = 1 << 16
#: the pilot runs' seeds are offset by this from the table's
PILOT_SEED_OFFSET = 1 << 40
#: the rays a pilot's standard error asks for are multiplied by this (the pilot's own noise)
SAFETY = 1.25
#: rays per run are rounded up to a multiple of this
RAYS_STEP = 1024
#: chunks of a pilot run (its rays split so that every thread has work)
PILOT_CHUNKS = 8
#: chunks per thread of a calibration run (enough to keep every thread busy, as the table's runs do)
CALIBRATION_CHUNKS = 2
PARTIAL = ".partial"


@dataclass
class Plan:
    """The runs of a table and their rays: ``rows`` (C order), ``specs`` (key -> run),
    ``rays`` and ``seeds`` per run key, and the pilot's rays (0 without a pilot)."""

    definition: Definition
    rows: list[Row]
    specs: dict[str, RunSpec]
    rays: dict[str, int] = field(default_factory=dict)
    pilot_rays: int = 0

    @property
    def ordinal(self) -> dict[str, int]:
        return {k: i for i, k in enumerate(self.specs)}

    def settings(self, key: str, rays: int | None = None, pilot: bool = False, **kw: Any) -> SimulationSettings:
        """The settings of run ``key`` (its planned rays unless ``rays``; the pilot's seed if ``pilot``)."""
        d = self.definition
        seed = d.seed + self.ordinal[key] + (PILOT_SEED_OFFSET if pilot else 0)
        n = rays if rays is not None else self.rays[key]
        if pilot:
            kw["chunk_rays"] = max(1, n // PILOT_CHUNKS)
        return self.specs[key].settings(n, seed, d.masking, **kw)

    def total_rays(self) -> int:
        return sum(self.rays[k] * len(s.incident_deg) for k, s in self.specs.items())

    def pilot_total(self) -> int:
        return sum(self.pilot_rays * len(s.incident_deg) for s in self.specs.values())


def plan_table(defn: Definition) -> Plan:
    """The rows and runs of ``defn``; with ``rays`` given, every run gets them (a target
    standard error leaves ``rays`` empty until :func:`pilot`)."""
    rows, specs = build_rows(defn)
    plan = Plan(defn, rows, specs)
    if defn.rays is not None:
        plan.rays = {k: int(defn.rays) for k in specs}
    else:
        plan.pilot_rays = PILOT_RAYS
    return plan


def rays_for_target(pilot_stderr: float, pilot_rays: int, target: float) -> int:
    """Rays per incident direction whose standard error is ``target``, from a pilot's standard
    error at ``pilot_rays`` (``stderr ~ 1/sqrt(rays)``), times :data:`SAFETY`, rounded up to
    :data:`RAYS_STEP`; at least one step."""
    need = SAFETY * pilot_rays * (pilot_stderr / target) ** 2
    return int(max(1, math.ceil(need / RAYS_STEP)) * RAYS_STEP)


@dataclass
class Runner:
    """How runs are traced: threads, device, a Dask client, the checkpoint root (None: none),
    ``progress(rays)`` (finished rays, those loaded from checkpoints included) and
    ``on_resume(rays)`` (before a run's checkpoints are counted: how many rays they hold)."""

    threads: int | None = None
    device: str = "cpu"
    client: Any = None
    root: Path | None = None
    progress: Callable[[int], None] | None = None
    on_resume: Callable[[int], None] | None = None

    def settings(self, plan: Plan, key: str, rays: int | None = None, pilot: bool = False) -> SimulationSettings:
        kw: dict[str, Any] = {"threads": self.threads}
        if self.device != "cpu":
            kw["device"] = self.device
        return plan.settings(key, rays, pilot, **kw)

    def checkpoints(self, plan: Plan, key: str, settings: SimulationSettings, pilot: bool) -> ckpt.Checkpoints | None:
        if self.root is None:
            return None
        name = f"{'pilot' if pilot else 'run'}-{key}"
        return ckpt.Checkpoints(self.root / name, run_description(plan.specs[key].stack, settings))

    def run(self, plan: Plan, key: str, rays: int | None = None, pilot: bool = False) -> SimulationResult:
        s = self.settings(plan, key, rays, pilot)
        cps = self.checkpoints(plan, key, s, pilot)
        resumed = None if self.on_resume is None else (lambda n: self.on_resume(n * s.rays))
        return run_incidents(plan.specs[key].stack, s, checkpoints=cps, client=self.client, progress=self.progress,
                             on_resume=resumed)


def table_meta(defn: Definition) -> dict[str, Any]:
    """The identity of a table's checkpoints (``meta.json`` of ``.partial``)."""
    return dict(defn.identity(), code=ckpt.code_key())


def check_checkpoints(root: Path, defn: Definition) -> None:
    """Raise :class:`goniometer.run.checkpoints.CheckpointMismatch` if ``root`` holds checkpoints of
    another table (or code); changes nothing."""
    ckpt.check_meta(root, table_meta(defn), kept_runs(root))


def kept_runs(root: Path) -> list[Path]:
    """The run directories of a checkpoint root."""
    return sorted(p for p in root.glob("*-*") if p.is_dir()) if root.is_dir() else []


def kept_cells(root: Path) -> int:
    """Finished incident directions (cells of the pilot or the table) kept under ``root``."""
    return sum(len(list(p.glob("m*.npz"))) for p in kept_runs(root))


def start_checkpoints(root: Path, defn: Definition) -> None:
    """Write ``meta.json`` of ``root`` (after :func:`check_checkpoints`)."""
    root.mkdir(parents=True, exist_ok=True)
    ckpt.write_meta(root, table_meta(defn), kept_runs(root))


def clear_checkpoints(root: Path) -> None:
    shutil.rmtree(root, ignore_errors=True)


def warm_up(plan: Plan, runner: Runner) -> float:
    """Compile (or load) every kernel variant of the table's runs; seconds spent."""
    return warm_up_runs((s.stack, runner.settings(plan, k, rays=1)) for k, s in plan.specs.items())


def calibrate(plan: Plan, runner: Runner, samples: int = 3) -> float:
    """Rays per second of this machine on up to ``samples`` of the table's runs (first, middle,
    last) at one incident direction each, :data:`CALIBRATION_CHUNKS` chunks per thread, nothing
    kept."""
    keys = list(plan.specs)
    picks = list(dict.fromkeys([keys[0], keys[len(keys) // 2], keys[-1]]))[:samples]
    rays, t0 = 0, time.perf_counter()
    for k in picks:
        s = plan.specs[k]
        mid = s.incident_deg[len(s.incident_deg) // 2]
        base = runner.settings(plan, k, rays=1)
        n = base.chunk_rays * thread_count(base.threads) * CALIBRATION_CHUNKS
        run_incidents(s.stack, base.with_overrides(rays=n, incident_deg=(mid,), incident_phi_deg=(0.0,)),
                      client=runner.client)
        rays += n
    return rays / max(time.perf_counter() - t0, 1e-9)


def pilot(plan: Plan, runner: Runner) -> dict[str, float]:
    """Trace every run at :data:`PILOT_RAYS`, set ``plan.rays`` for the definition's target
    standard error (per row, the most its cells need; a shared run, the most its rows need), and
    return the pilot's largest standard error per run key."""
    target = plan.definition.stderr
    results = {k: runner.run(plan, k, rays=plan.pilot_rays, pilot=True) for k in plan.specs}
    _, weights = incident_elevations(plan.definition)
    plan.rays = {k: RAYS_STEP for k in plan.specs}
    worst: dict[str, float] = {k: 0.0 for k in plan.specs}
    for row in plan.rows:
        _, se = reduce_row(plan.definition, row, [results[k] for k in row.runs], weights)
        s = float(np.max(se)) if se.size else 0.0
        n = rays_for_target(s, plan.pilot_rays, target)
        for k in row.runs:
            plan.rays[k] = max(plan.rays[k], n)
            worst[k] = max(worst[k], s)
    return worst


@dataclass
class LutResult:
    """A computed table: ``values`` and ``stderr`` in the table's layout (the definition's axes,
    slowest first), ``rays`` per cell (per incident direction of the cell's first run), the
    axes' parameter values, and the run's facts."""

    definition: Definition
    values: np.ndarray
    stderr: np.ndarray
    rays: np.ndarray
    axis_values: list[np.ndarray]
    seed: int
    pilot_rays: int
    total_rays: int
    elapsed_s: float
    threads: int
    device: str
    code: str

    def to_json(self) -> dict[str, Any]:
        """The JSON output (``docs/lut.md`` section 6), without the checks."""
        import datetime
        d = self.definition
        created = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
        return {
            "format": "goniometer.lut", "version": 1, "name": d.name, "quantity": d.quantity, "created": created,
            "shape": list(d.shape), "layout": "row-major (C order): the axes slowest first, as the header prints them",
            "axes": [dict(a.to_dict(), coordinate=a.coordinates().tolist(), values=v.tolist())
                     for a, v in zip(d.axes, self.axis_values)],
            "values": self.values.tolist(), "stderr": self.stderr.tolist(), "rays": self.rays.tolist(),
            "definition": d.to_dict(), "seed": self.seed, "pilot_rays": self.pilot_rays,
            "total_rays": self.total_rays, "elapsed_s": self.elapsed_s, "threads": self.threads,
            "device": self.device, "code": self.code,
            "stderr_max": float(np.max(self.stderr)) if self.stderr.size else 0.0,
        }


def run_table(plan: Plan, runner: Runner) -> LutResult:
    """Trace every run of ``plan`` (rays set) and assemble the table."""
    defn = plan.definition
    t0 = time.perf_counter()
    results = {k: runner.run(plan, k) for k in plan.specs}
    elapsed = time.perf_counter() - t0
    _, weights = incident_elevations(defn)
    values = np.empty(defn.shape)
    stderr = np.empty(defn.shape)
    rays = np.empty(defn.shape, dtype=np.int64)
    for row in plan.rows:
        v, se = reduce_row(defn, row, [results[k] for k in row.runs], weights)
        values[row.index] = v if defn.incident_axis is not None else v[0]
        stderr[row.index] = se if defn.incident_axis is not None else se[0]
        rays[row.index] = plan.rays[row.runs[0]]
    first = next(iter(results.values()))
    return LutResult(defn, values, stderr, rays, defn.axis_values(), defn.seed, plan.pilot_rays, plan.total_rays(),
                     elapsed, first.threads, runner.device, ckpt.code_key())


def compute_table(defn: Definition, threads: int | None = None) -> LutResult:
    """The table of ``defn`` in memory (no checkpoints, no progress): the Python API's form."""
    plan = plan_table(defn)
    runner = Runner(threads=threads)
    if plan.pilot_rays:
        pilot(plan, runner)
    return run_table(plan, runner)


__all__ = ["PILOT_RAYS", "PILOT_CHUNKS", "PILOT_SEED_OFFSET", "SAFETY", "RAYS_STEP", "PARTIAL", "Plan", "plan_table",
           "rays_for_target", "Runner", "table_meta", "check_checkpoints", "kept_runs", "kept_cells",
           "start_checkpoints", "clear_checkpoints", "warm_up", "calibrate", "pilot", "LutResult", "run_table",
           "compute_table"]
