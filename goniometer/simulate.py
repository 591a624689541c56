"""Orchestration of a goniometer run: settings, chunking, deterministic seeding, results.

Work for one incident direction is split into chunks of ``chunk_rays`` rays. Chunk ``c`` of
incident index ``m`` draws from the random stream keyed by ``(seed, m, c)`` and fills its own
histogram; histograms are summed in chunk order. Hence a result is bit-identical whatever
the number of threads (which only decides how many chunks run at once). Memory is bounded
by the histograms of one batch of chunks, independent of the number of rays.

Cell values follow SLICES.md: ``fbar = (sum of exit weights in the cell) / (N Omega)`` with
``N`` the rays sent for that incident direction and ``Omega`` the cell's projected solid
angle; the standard error comes from the per-cell sum of squared weights.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Any, Callable, Mapping

import numba
import numpy as np

from goniometer import atomic, tracer
from goniometer.slices import SliceGrid, boundary_tables, light_direction
from goniometer.stack import Stack, pack

DEFAULT_INCIDENT = (0.0, 15.0, 30.0, 45.0, 60.0, 70.0, 80.0)
MASKING = ("separable", "height-correlated")
ENERGY_TERMS = ("reflected", "transmitted", "absorbed", "masking_loss")


class SettingsError(ValueError):
    """Invalid simulation settings; the message names the field and the allowed range."""


@dataclass(frozen=True)
class SimulationSettings:
    """What to simulate. ``rays`` is per incident direction.

    ``incident_deg`` are elevations theta_l in [0, 90); ``incident_phi_deg`` azimuths in
    [0, 360) (default 0 for all). ``chunk_rays`` (rays per random stream and histogram) and
    ``chunks_per_task`` (chunks summed together before being added to the total) are part of the
    determinism contract: the same (seed, chunk_rays, chunks_per_task) gives the same bits
    whatever ``threads``, locally or distributed.
    """

    incident_deg: tuple[float, ...] = DEFAULT_INCIDENT
    incident_phi_deg: tuple[float, ...] | None = None
    rays: int = 1_000_000
    parametrization: str = "classic"
    resolution: tuple[int, int] = (90, 360)
    seed: int = 1
    masking: str = "separable"
    max_order: int = 5
    threads: int | None = None
    chunk_rays: int = 1 << 17
    chunks_per_task: int = 8
    event_cap: int = tracer.EVENT_CAP

    def __post_init__(self) -> None:
        inc = tuple(float(x) for x in self.incident_deg)
        object.__setattr__(self, "incident_deg", inc)
        phi = self.incident_phi_deg
        phi = tuple(0.0 for _ in inc) if phi is None else tuple(float(x) for x in phi)
        object.__setattr__(self, "incident_phi_deg", phi)
        object.__setattr__(self, "resolution", tuple(self.resolution))
        self.validate()

    def validate(self) -> None:
        if not self.incident_deg:
            raise SettingsError("incident_deg: at least one incident direction is required")
        for t in self.incident_deg:
            if not (math.isfinite(t) and 0.0 <= t < 90.0):
                raise SettingsError(f"incident_deg: {t:g} is outside [0, 90)")
        if len(self.incident_phi_deg) != len(self.incident_deg):
            raise SettingsError("incident_phi_deg: needs one azimuth per incident elevation")
        for p in self.incident_phi_deg:
            if not (math.isfinite(p) and 0.0 <= p < 360.0):
                raise SettingsError(f"incident_phi_deg: {p:g} is outside [0, 360)")
        _int_in(self.rays, "rays", 1, 10**13)
        if self.parametrization not in ("classic", "half"):
            raise SettingsError(f"parametrization: {self.parametrization!r} is not one of classic, half")
        if len(self.resolution) != 2:
            raise SettingsError(f"resolution: {list(self.resolution)} must be [n_theta, n_phi]")
        _int_in(self.resolution[0], "resolution (n_theta)", 1, 10_000)
        _int_in(self.resolution[1], "resolution (n_phi)", 1, 40_000)
        _int_in(self.seed, "seed", 0, 2**63 - 1)
        if self.masking not in MASKING:
            raise SettingsError(f"masking: {self.masking!r} is not one of {', '.join(MASKING)}")
        _int_in(self.max_order, "max_order", 1, 64)
        if self.threads is not None:
            _int_in(self.threads, "threads", 1, numba.config.NUMBA_NUM_THREADS)
        _int_in(self.chunk_rays, "chunk_rays", 1, 1 << 30)
        _int_in(self.chunks_per_task, "chunks_per_task", 1, 1 << 20)
        _int_in(self.event_cap, "event_cap", 1, 10**9)

    @property
    def n_threads(self) -> int:
        return self.threads if self.threads is not None else numba.config.NUMBA_NUM_THREADS

    def with_overrides(self, **kw: Any) -> "SimulationSettings":
        """A copy with the given non-None fields replaced."""
        return replace(self, **{k: v for k, v in kw.items() if v is not None})

    @classmethod
    def from_mapping(cls, table: Mapping[str, Any], source: str = "simulation") -> "SimulationSettings":
        """Settings from a material file's ``[simulation]`` table (keys of SIMULATION.md)."""
        kw: dict[str, Any] = {}
        for key, value in table.items():
            if key == "incident_deg":
                if not isinstance(value, list) or not all(_is_num(x) for x in value):
                    raise SettingsError(f"{source}.incident_deg: must be a list of numbers")
                kw[key] = tuple(value)
            elif key == "resolution":
                if not isinstance(value, list) or len(value) != 2:
                    raise SettingsError(f"{source}.resolution: must be [n_theta, n_phi]")
                kw[key] = tuple(value)
            elif key in ("rays", "seed", "max_order", "threads"):
                kw[key] = value
            elif key in ("parametrization", "masking"):
                kw[key] = value
            else:
                raise SettingsError(f"{source}.{key}: unknown key")
        try:
            return cls(**kw)
        except SettingsError as e:
            raise SettingsError(f"{source}.{e}") from None


def _is_num(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _int_in(value: Any, name: str, lo: int, hi: int) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise SettingsError(f"{name}: {value!r} is not an integer")
    if not lo <= value <= hi:
        raise SettingsError(f"{name}: {value} is outside [{lo}, {hi}]")


@dataclass
class SliceData:
    """Simulated slices of one side (reflection or transmission) for all M incident directions.

    ``value``/``stderr``: (M, 3, n_theta, n_phi) in 1/sr, no cosine; ``orders``:
    (M, K, 3, n_theta, n_phi), order K meaning "K or more"; ``mask`` and
    ``proj_solid_angle``: (M, n_theta, n_phi); ``stderr_internal``: standard error of the
    internal part (orders >= 2, i.e. ``value - orders[:, 0]``), or None if unknown.
    """

    grid: SliceGrid
    value: np.ndarray
    stderr: np.ndarray
    orders: np.ndarray
    mask: np.ndarray
    proj_solid_angle: np.ndarray
    stderr_internal: np.ndarray | None = None


@dataclass
class SimulationResult:
    """Everything one simulation produced (what :mod:`goniometer.store` writes)."""

    stack: Stack
    settings: SimulationSettings
    theta_deg: np.ndarray
    phi_deg: np.ndarray
    brdf: SliceData
    btdf: SliceData | None
    energy: dict[str, np.ndarray]          # (M, 3) per term, fractions of the incident flux
    energy_stderr: dict[str, np.ndarray]   # (M, 3)
    roulette: np.ndarray                   # (M, 3) net weight booked by Russian roulette / N
    capped: np.ndarray                     # (M, 3) weight stopped by the event cap / N
    capped_paths: np.ndarray               # (M,) int
    mean_events: np.ndarray                # (M,) events per path
    elapsed_s: np.ndarray                  # (M,) wall time of each incident direction
    threads: int
    compile_s: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def rays_per_s(self) -> float:
        total = float(np.sum(self.elapsed_s))
        return self.settings.rays * len(self.theta_deg) / total if total > 0 else float("nan")


def warm_up() -> float:
    """Compile (or load from the on-disk cache) the tracing kernel; returns the seconds spent."""
    from goniometer.stack import Interface, Lambertian, Medium
    t0 = time.perf_counter()
    tiny = Stack("warm-up", (Interface(0.1, (1.5,) * 3), Medium((0.1,) * 3), Lambertian((0.5,) * 3)))
    trace_incident(tiny, SimulationSettings(incident_deg=(30.0,), rays=8, resolution=(2, 4),
                                            chunk_rays=8, threads=1), 0)
    return time.perf_counter() - t0


def simulate(stack: Stack, settings: SimulationSettings,
             progress: Callable[[int], None] | None = None) -> SimulationResult:
    """Simulate all incident directions of ``settings`` for ``stack``.

    ``progress``, if given, is called with the number of rays just finished (after every task).
    Compile time of the kernel is measured apart (``compile_s``), not in ``elapsed_s``.
    """
    settings.validate()
    compile_s = warm_up()
    buffers = incident_buffers(stack, settings)
    parts = [trace_incident(stack, settings, m, progress, buffers) for m in range(len(settings.incident_deg))]
    return assemble(stack, settings, parts, compile_s=compile_s)


@dataclass
class Sums:
    """Raw kernel sums in the kernel's layout: what a task returns and an incident accumulates.

    ``brdf``/``btdf``: (n_theta, n_phi, K + 2, 3) (see :func:`goniometer.tracer.trace_chunk`;
    ``btdf`` is (1, 1, K + 2, 3) for opaque stacks); ``energy`` (N_ENERGY, 3); ``energy_sq``
    (N_ENERGY_SQ, 3); ``counts`` (N_COUNTS,) int64.
    """

    brdf: np.ndarray
    btdf: np.ndarray
    energy: np.ndarray
    energy_sq: np.ndarray
    counts: np.ndarray

    @classmethod
    def zeros(cls, stack: Stack, settings: SimulationSettings) -> "Sums":
        nt, nph = settings.resolution
        k2 = settings.max_order + 2
        bt = (nt, nph) if stack.transmits else (1, 1)
        return cls(np.zeros((nt, nph, k2, 3)), np.zeros(bt + (k2, 3)), np.zeros((tracer.N_ENERGY, 3)),
                   np.zeros((tracer.N_ENERGY_SQ, 3)), np.zeros(tracer.N_COUNTS, dtype=np.int64))

    def add(self, other: "Sums") -> None:
        """In-place ``self += other`` (field by field; the order of additions is the caller's)."""
        self.brdf += other.brdf
        self.btdf += other.btdf
        self.energy += other.energy
        self.energy_sq += other.energy_sq
        self.counts += other.counts


def n_tasks(settings: SimulationSettings) -> int:
    """Number of tasks of one incident direction (task t covers chunks t*c .. t*c + c - 1)."""
    return -(-settings.rays // (settings.chunk_rays * settings.chunks_per_task))


def chunk_buffers(stack: Stack, settings: SimulationSettings, n: int) -> tuple[np.ndarray, ...]:
    """Per-chunk output arrays of the kernel for ``n`` chunks (reusable between calls)."""
    nt, nph = settings.resolution
    k2 = settings.max_order + 2
    bt = (nt, nph) if stack.transmits else (1, 1)
    return (np.empty((n, nt, nph, k2, 3)), np.empty((n,) + bt + (k2, 3)), np.empty((n, tracer.N_ENERGY, 3)),
            np.empty((n, tracer.N_ENERGY_SQ, 3)), np.empty((n, tracer.N_COUNTS), dtype=np.int64))


def trace_tasks(stack: Stack, settings: SimulationSettings, m: int, first_task: int, count: int,
                parallel: bool = True, buffers: tuple[np.ndarray, ...] | None = None) -> list[Sums]:
    """Trace tasks ``first_task .. first_task + count - 1`` of incident direction ``m``.

    All their chunks run in parallel (numba threads); each task's chunk histograms are then
    summed in chunk order starting from zero. A task's result depends only on (stack, settings,
    m, task index) -- not on threads or on which machine runs it -- which is what makes local and
    distributed runs bit-identical. ``parallel=False`` uses no numba threads (for callers that
    run concurrently themselves, like Dask worker threads). ``buffers`` (from
    :func:`chunk_buffers`) saves allocating the per-chunk histograms on every call.
    """
    p = pack(stack)
    l = light_direction(settings.incident_deg[m], settings.incident_phi_deg[m])
    nt, nph = settings.resolution
    K = settings.max_order
    cpt = settings.chunks_per_task
    n_chunks_total = -(-settings.rays // settings.chunk_rays)
    first_chunk = first_task * cpt
    nb = max(0, min(count * cpt, n_chunks_total - first_chunk))
    if buffers is None or buffers[0].shape[0] < nb:
        buffers = chunk_buffers(stack, settings, nb)
    outs = tuple(b[:nb] for b in buffers)
    if parallel:
        numba.set_num_threads(settings.n_threads)
    kernel = tracer.trace_batch if parallel else tracer.trace_batch_serial
    if nb > 0:
        tables = boundary_tables(settings.parametrization, nt, nph)
        kernel(*p.as_tuple(), l[0], l[1], l[2], settings.rays, settings.chunk_rays,
               first_chunk, settings.seed, m, 0 if settings.parametrization == "classic" else 1,
               nt, nph, *tables, K, settings.masking == "height-correlated", settings.event_cap, *outs)
    results = []
    for t in range(count):
        first, last = t * cpt, min((t + 1) * cpt, nb)
        if first >= last:
            results.append(Sums.zeros(stack, settings))
            continue
        # the task's sum starts from its first chunk (0 + x == x) and adds the others in chunk order
        total = Sums(*(o[first].copy() for o in outs))
        for b in range(first + 1, last):
            total.add(Sums(*(o[b] for o in outs)))
        results.append(total)
    return results


def task_rays(settings: SimulationSettings, task: int) -> int:
    """Number of rays of task ``task``."""
    per = settings.chunk_rays * settings.chunks_per_task
    return max(0, min(per, settings.rays - task * per))


def _tasks_per_call(settings: SimulationSettings) -> int:
    """Tasks traced by one parallel kernel call of :func:`trace_incident` (enough chunks for
    two per thread)."""
    return min(max(1, -(-2 * settings.n_threads // settings.chunks_per_task)), n_tasks(settings))


def incident_buffers(stack: Stack, settings: SimulationSettings) -> tuple[np.ndarray, ...]:
    """The per-chunk buffers :func:`trace_incident` needs, to reuse over a run's incident
    directions (one run at a time: they are scratch space)."""
    return chunk_buffers(stack, settings, _tasks_per_call(settings) * settings.chunks_per_task)


def trace_incident(stack: Stack, settings: SimulationSettings, m: int,
                   progress: Callable[[int], None] | None = None,
                   buffers: tuple[np.ndarray, ...] | None = None) -> "IncidentPart":
    """Trace every task of incident direction ``m`` locally and sum them in task order.
    ``buffers`` (from :func:`incident_buffers`) saves allocating and faulting in the per-chunk
    histograms for every direction."""
    T = n_tasks(settings)
    per_call = _tasks_per_call(settings)
    acc = Sums.zeros(stack, settings)
    if buffers is None:
        buffers = incident_buffers(stack, settings)
    t0 = time.perf_counter()
    for first in range(0, T, per_call):
        count = min(per_call, T - first)
        for t, sums in enumerate(trace_tasks(stack, settings, m, first, count, buffers=buffers)):
            acc.add(sums)
            if progress is not None:
                progress(task_rays(settings, first + t))
    return IncidentPart.from_sums(m, acc, settings.max_order, stack.transmits, time.perf_counter() - t0)


@dataclass
class IncidentPart:
    """Raw sums for one incident direction, split into orders and squares (what checkpoints hold)."""

    index: int
    brdf: np.ndarray           # (K, 3, n_theta, n_phi) weight sums per order
    brdf_sq: np.ndarray        # (2, 3, n_theta, n_phi) squared weights: all exits, orders >= 2
    btdf: np.ndarray | None
    btdf_sq: np.ndarray | None
    energy: np.ndarray         # (N_ENERGY, 3)
    energy_sq: np.ndarray      # (N_ENERGY_SQ, 3)
    counts: np.ndarray         # (N_COUNTS,)
    elapsed_s: float

    @classmethod
    def from_sums(cls, m: int, acc: Sums, K: int, transmits: bool, elapsed_s: float) -> "IncidentPart":
        def split(h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            # (n_theta, n_phi, K + 2, 3) -> orders (K, 3, n_theta, n_phi) and squared weights
            # (2, 3, n_theta, n_phi): [all exits, internal exits (order >= 2)]
            return (np.ascontiguousarray(h[:, :, :K, :].transpose(2, 3, 0, 1)),
                    np.ascontiguousarray(h[:, :, K:, :].transpose(2, 3, 0, 1)))

        brdf, brdf_sq = split(acc.brdf)
        btdf, btdf_sq = split(acc.btdf) if transmits else (None, None)
        return cls(m, brdf, brdf_sq, btdf, btdf_sq, acc.energy, acc.energy_sq, acc.counts, elapsed_s)

    def save(self, path) -> None:
        """Checkpoint to an ``.npz`` file (atomically: temporary name, then rename)."""
        arrays = {k: v for k, v in self.__dict__.items() if isinstance(v, np.ndarray)}
        atomic.write_npz(path, index=self.index, elapsed_s=self.elapsed_s, **arrays)

    @classmethod
    def load(cls, path) -> "IncidentPart":
        with np.load(path) as z:
            get = (lambda k: z[k] if k in z.files else None)
            return cls(int(z["index"]), z["brdf"], z["brdf_sq"], get("btdf"), get("btdf_sq"), z["energy"],
                       z["energy_sq"], z["counts"], float(z["elapsed_s"]))


def _slice_from_sums(grid: SliceGrid, omegas: list[np.ndarray], masks: list[np.ndarray],
                     sums: list[np.ndarray], sqs: list[np.ndarray], n: int) -> SliceData:
    M = len(omegas)
    K = sums[0].shape[0]
    nt, nph = grid.shape
    value = np.zeros((M, 3, nt, nph))
    stderr = np.zeros((M, 3, nt, nph))
    stderr_internal = np.zeros((M, 3, nt, nph))
    orders = np.zeros((M, K, 3, nt, nph))

    def std_error(s1: np.ndarray, s2: np.ndarray, inv: np.ndarray) -> np.ndarray:
        # standard error of the mean of N per-ray contributions, divided by N Omega
        var = np.maximum(s2 - s1 * s1 / n, 0.0) / max(n - 1, 1)
        return np.sqrt(var * n) * inv

    for m, om in enumerate(omegas):
        inv = np.divide(1.0, n * om, out=np.zeros_like(om), where=om > 0)
        s1 = sums[m].sum(axis=0)
        value[m] = s1 * inv
        orders[m] = sums[m] * inv
        stderr[m] = std_error(s1, sqs[m][0], inv)
        stderr_internal[m] = std_error(sums[m][1:].sum(axis=0), sqs[m][1], inv)
    return SliceData(grid, value, stderr, orders, np.array(masks), np.array(omegas), stderr_internal)


@lru_cache(maxsize=64)
def cell_geometry(parametrization: str, n_theta: int, n_phi: int, theta_deg: float,
                  phi_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Projected solid angles and comparison mask of a slice grid for one incident direction
    (:meth:`SliceGrid.proj_solid_angle`, :meth:`SliceGrid.mask`), read-only and memoised: the
    materials of a database share their incident directions and grids, and the exact half-cell
    solid angles cost ~50 ms per direction."""
    grid = SliceGrid(parametrization, n_theta, n_phi, "reflection")
    light = light_direction(theta_deg, phi_deg)
    omega, mask = grid.proj_solid_angle(light), grid.mask(light)
    omega.setflags(write=False)
    mask.setflags(write=False)
    return omega, mask


def assemble(stack: Stack, settings: SimulationSettings, parts: list[IncidentPart],
             compile_s: float = 0.0) -> SimulationResult:
    """Turn the raw per-incident sums into cell values, errors and energies."""
    parts = sorted(parts, key=lambda p: p.index)
    n = settings.rays
    nt, nph = settings.resolution
    grid = SliceGrid(settings.parametrization, nt, nph, "reflection")
    # |cos theta_v| and the validity of sub-cells are the same on both sides: computed once
    geometry = [cell_geometry(settings.parametrization, nt, nph, t, p)
                for t, p in zip(settings.incident_deg, settings.incident_phi_deg)]
    omegas = [g[0] for g in geometry]
    masks = [g[1] for g in geometry]
    brdf = _slice_from_sums(grid, omegas, masks, [p.brdf for p in parts], [p.brdf_sq for p in parts], n)
    btdf = None
    if stack.transmits:
        btdf = _slice_from_sums(SliceGrid(settings.parametrization, nt, nph, "transmission"), omegas, masks,
                                [p.btdf for p in parts], [p.btdf_sq for p in parts], n)
    energy: dict[str, np.ndarray] = {}
    energy_se: dict[str, np.ndarray] = {}
    for t, name in enumerate(ENERGY_TERMS):
        s1 = np.array([p.energy[t] for p in parts])
        s2 = np.array([p.energy_sq[t] for p in parts])
        mean = s1 / n
        energy[name] = mean
        energy_se[name] = np.sqrt(np.maximum(s2 / n - mean * mean, 0.0) / max(n - 1, 1))
    return SimulationResult(
        stack=stack, settings=settings,
        theta_deg=np.array(settings.incident_deg), phi_deg=np.array(settings.incident_phi_deg),
        brdf=brdf, btdf=btdf, energy=energy, energy_stderr=energy_se,
        roulette=np.array([p.energy[tracer.E_ROULETTE] for p in parts]) / n,
        capped=np.array([p.energy[tracer.E_CAPPED] for p in parts]) / n,
        capped_paths=np.array([p.counts[tracer.C_CAPPED] for p in parts]),
        mean_events=np.array([p.counts[tracer.C_EVENTS] for p in parts]) / n,
        elapsed_s=np.array([p.elapsed_s for p in parts]),
        threads=settings.n_threads, compile_s=compile_s,
    )
