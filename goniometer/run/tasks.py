"""The units of work of a run: tasks of chunks traced by the kernel, summed into incident directions.

Work for one incident direction is split into chunks of ``chunk_rays`` rays. Chunk ``c`` of
incident index ``m`` draws from the random stream keyed by ``(seed, m, c)`` and fills its own
histogram; a task sums ``chunks_per_task`` chunk histograms in chunk order, and an incident
direction sums its tasks in task order. A result is therefore bit-identical whatever the number
of threads or machines (``docs/architecture.md``). Memory is bounded by the histograms of one
batch of chunks, whatever the number of rays.
"""

from __future__ import annotations

import time
from typing import Callable, Iterable

import numba
import numpy as np

from goniometer.kernel import tracer
from goniometer.run.results import N_MUELLER, IncidentPart, Sums
from goniometer.run.settings import SimulationSettings
from goniometer.grids.slice_grid import PARAMETRIZATIONS, boundary_tables, light_direction
from goniometer.stack import Stack
from goniometer.kernel.packing import pack


def run_variant(stack: Stack, settings: SimulationSettings) -> tuple:
    """What decides which compiled code a local run of ``stack`` under ``settings`` needs: the
    kernel's variant (:func:`goniometer.kernel.tracer.kernel_flags`), the grid, the first
    order and the device (a spectral run: those of its launches). Two runs with the same key run
    the same compiled functions."""
    if settings.spectral:
        from goniometer.run.launches import launch_stacks
        return tuple(sorted({run_variant(st, s) for _, st, s in launch_stacks(stack, settings)}, key=repr))
    flags = tracer.kernel_flags(pack(stack), settings.masking == "height-correlated", False,
                                polarized=settings.polarized)
    key = (flags, settings.parametrization, settings.first_order)
    key = key if settings.device == "cpu" else key + (settings.device,)
    return key + ("polarized",) if settings.polarized else key


def warm_up(stack: Stack | None = None, settings: SimulationSettings | None = None) -> float:
    """Compile (or load from the on-disk cache) every numba function a local run of ``stack``
    under ``settings`` calls -- the kernel variant its layers need, the chunk summation, the
    assembly (cell geometry, the integrated first order) -- by running that code on 8 rays and a
    2 x 4 grid; returns the seconds spent. Without arguments: a coated diffuse stack under the
    default settings. Callers time this as compile time, so that a first run does not book
    compiling as tracing."""
    from goniometer.run.results import assemble
    from goniometer.stack import Interface, Lambertian, Medium
    t0 = time.perf_counter()
    if stack is None:
        stack = Stack("warm-up", (Interface(0.1, (1.5,) * 3), Medium((0.1,) * 3), Lambertian((0.5,) * 3)))
    s = settings if settings is not None else SimulationSettings()
    if s.spectral:   # each distinct variant of the run's launches (goniometer.run.launches)
        from goniometer.run.launches import launch_stacks
        seen: set = set()
        for _, st, ss in launch_stacks(stack, s):
            key = run_variant(st, ss)
            if key not in seen:
                seen.add(key)
                warm_up(st, ss)
        return time.perf_counter() - t0
    # the RGL grid runs the classic grid's compiled code (the grid is a value, not a variant); its
    # own numba functions are those of its tables
    tiny = SimulationSettings(incident_deg=(30.0,), rays=8, resolution=(2, 4), chunk_rays=8, threads=1,
                              parametrization=s.parametrization if s.rgl is None else "classic", masking=s.masking,
                              max_order=s.max_order, first_order=s.first_order, event_cap=s.event_cap, device=s.device,
                              polarized=s.polarized)
    assemble(stack, tiny, [trace_incident(stack, tiny, 0)])
    if s.rgl is not None:
        s.rgl.tables()
    return time.perf_counter() - t0


def warm_up_runs(runs) -> float:
    """:func:`warm_up` for each distinct :func:`run_variant` of the (stack, settings) pairs
    ``runs`` (a database's materials, say); returns the seconds spent."""
    t0 = time.perf_counter()
    seen: set = set()
    for stack, settings in runs:
        key = run_variant(stack, settings)
        if key not in seen:
            seen.add(key)
            warm_up(stack, settings)
    return time.perf_counter() - t0


def n_tasks(settings: SimulationSettings) -> int:
    """Number of tasks of one incident direction (task t covers chunks t*c .. t*c + c - 1, the last
    task what is left of the chunks, :func:`goniometer.kernel.tracer.chunk_count`)."""
    return -(-tracer.chunk_count(settings.rays, settings.chunk_rays) // settings.chunks_per_task)


def chunk_buffers(stack: Stack, settings: SimulationSettings, n: int) -> tuple[np.ndarray, ...]:
    """Per-chunk output arrays of the kernel for ``n`` chunks (reusable between calls), in the order
    of :class:`Sums`' fields (a polarized run's Mueller histograms last)."""
    nt, nph = settings.resolution
    k2 = settings.max_order + 2
    bt = (nt, nph) if stack.transmits else (1, 1)
    out = (np.empty((n, nt, nph, k2, 3)), np.empty((n,) + bt + (k2, 3)), np.empty((n, tracer.N_ENERGY, 3)),
           np.empty((n, tracer.N_ENERGY_SQ, 3)), np.empty((n, tracer.N_COUNTS), dtype=np.int64))
    if settings.polarized:
        out += (np.empty((n, nt, nph, 2 * N_MUELLER, 3)), np.empty((n,) + bt + (2 * N_MUELLER, 3)))
    return out


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
    outs = _trace_chunks(stack, settings, m, first_task, count, parallel, buffers)
    nb = outs[0].shape[0]
    cpt = settings.chunks_per_task
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


def _add_task(acc: Sums, outs: tuple[np.ndarray, ...], first: int, last: int) -> None:
    """``acc += (task sum of chunks first .. last - 1)``, bit for bit what adding the
    :func:`trace_tasks` sum does, without materialising it: each histogram element's chunk values
    are added in chunk order and the total added to ``acc`` in one pass (:func:`_add_chunk_sum`)."""
    for a, o in zip((acc.brdf, acc.btdf, acc.mbrdf, acc.mbtdf), outs[:2] + outs[5:]):
        _add_chunk_sum(a.reshape(-1), o.reshape(o.shape[0], -1), first, last)
    for a, o in zip((acc.energy, acc.energy_sq, acc.counts), outs[2:5]):
        total = o[first].copy()
        for b in range(first + 1, last):
            total += o[b]
        a += total


@numba.njit(cache=True, error_model='numpy')
def _add_chunk_sum(acc, chunks, first, last):
    """``acc[e] += ((chunks[first, e] + chunks[first + 1, e]) + ...)`` for every element ``e``."""
    for e in range(acc.shape[0]):
        t = chunks[first, e]
        for b in range(first + 1, last):
            t += chunks[b, e]
        acc[e] += t


def _trace_chunks(stack: Stack, settings: SimulationSettings, m: int, first_task: int, count: int,
                  parallel: bool, buffers: tuple[np.ndarray, ...] | None) -> tuple[np.ndarray, ...]:
    """Run the kernel on the chunks of tasks ``first_task .. first_task + count - 1`` of incident
    direction ``m``; returns the per-chunk outputs (views of ``buffers`` when given)."""
    run = _kernel_inputs(stack, settings, m)
    first_chunk, nb = _chunk_range(run, settings.chunks_per_task, first_task, count)
    if buffers is None or buffers[0].shape[0] < nb:
        buffers = chunk_buffers(stack, settings, nb)
    outs = tuple(b[:nb] for b in buffers)
    if nb > 0:
        _run_kernel(run, settings, first_chunk, outs, parallel)
    return outs


def _chunk_range(run: tracer.Launch, cpt: int, first_task: int, count: int) -> tuple[int, int]:
    """(first chunk, number of chunks) of tasks ``first_task .. first_task + count - 1`` of
    ``cpt`` chunks each."""
    first_chunk = first_task * cpt
    return first_chunk, max(0, min(count * cpt, run.n_chunks - first_chunk))


def _kernel_inputs(stack: Stack, settings: SimulationSettings, m: int) -> tracer.Launch:
    """The kernel launch of incident direction ``m`` (:func:`goniometer.kernel.tracer.prepare`): worked
    out once per direction."""
    l = light_direction(settings.incident_deg[m], settings.incident_phi_deg[m])
    nt, nph = settings.resolution
    tables = settings.rgl.kernel_tables(m) if settings.rgl is not None else boundary_tables(settings.parametrization,
                                                                                              nt, nph)
    return tracer.prepare(pack(stack), l, settings.rays, settings.chunk_rays, settings.seed, m,
                          PARAMETRIZATIONS[settings.parametrization], nt, nph, tables, settings.max_order,
                          settings.event_cap, settings.first_order == "integrated",
                          height_correlated=settings.masking == "height-correlated", device=settings.device,
                          polarized=settings.polarized, phi_deg=settings.incident_phi_deg[m])


def _run_kernel(run: tracer.Launch, settings: SimulationSettings, first_chunk: int, outs: tuple[np.ndarray, ...],
                parallel: bool) -> None:
    """Trace chunks ``first_chunk .. first_chunk + len(outs[0]) - 1`` into ``outs``."""
    if parallel and run.device == "cpu":
        numba.set_num_threads(tracer.thread_count(settings.threads))
    tracer.launch(run, first_chunk, outs[:5], parallel=parallel, mueller=outs[5:] if len(outs) > 5 else None)


def task_rays(settings: SimulationSettings, task: int) -> int:
    """Number of rays of task ``task``."""
    cpt = settings.chunks_per_task
    return tracer.rays_in_chunks(settings.rays, settings.chunk_rays, task * cpt, cpt)


def _tasks_per_call(settings: SimulationSettings) -> int:
    """Tasks traced by one parallel kernel call of :func:`trace_incident` (enough chunks for
    two per thread)."""
    return min(max(1, -(-2 * tracer.thread_count(settings.threads) // settings.chunks_per_task)), n_tasks(settings))


def incident_buffers(stack: Stack, settings: SimulationSettings) -> tuple[np.ndarray, ...]:
    """The per-chunk buffers :func:`trace_incident` needs, to reuse over a run's incident
    directions (one run at a time: they are scratch space)."""
    return chunk_buffers(stack, settings, _tasks_per_call(settings) * settings.chunks_per_task)


def trace_incident(stack: Stack, settings: SimulationSettings, m: int,
                   progress: Callable[[int], None] | None = None,
                   buffers: tuple[np.ndarray, ...] | None = None) -> "IncidentPart":
    """Trace every task of incident direction ``m`` locally and sum them in task order.
    ``buffers`` (from :func:`incident_buffers`) saves allocating and faulting in the per-chunk
    histograms for every direction. ``progress(rays)`` is told after every kernel call, each of
    one chunk per thread (so a bar moves within a direction); which chunks a call traces changes
    no bit of the result (each chunk fills its own histogram). A spectral run traces its launches
    (:func:`trace_spectral_incident`)."""
    if settings.spectral:
        return trace_spectral_incident(stack, settings, m, progress, buffers)
    T = n_tasks(settings)
    per_call = _tasks_per_call(settings)
    acc = Sums.zeros(stack, settings)
    if buffers is None:
        buffers = incident_buffers(stack, settings)
    t0 = time.perf_counter()
    cpt = settings.chunks_per_task
    inputs = _kernel_inputs(stack, settings, m)
    step = max(1, tracer.thread_count(settings.threads))
    for first in range(0, T, per_call):
        count = min(per_call, T - first)
        first_chunk, nb = _chunk_range(inputs, cpt, first, count)
        outs = tuple(b[:nb] for b in buffers)
        for lo in range(0, nb, step):
            hi = min(lo + step, nb)
            _run_kernel(inputs, settings, first_chunk + lo, tuple(o[lo:hi] for o in outs), True)
            if progress is not None:
                progress(inputs.rays_in(first_chunk + lo, hi - lo))
        for t in range(count):
            lo, hi = t * cpt, min((t + 1) * cpt, nb)
            if lo < hi:
                _add_task(acc, outs, lo, hi)
    return IncidentPart.from_sums(m, acc, settings.max_order, stack.transmits, time.perf_counter() - t0)


def trace_spectral_incident(stack: Stack, settings: SimulationSettings, m: int,
                            progress: Callable[[int], None] | None = None,
                            buffers: tuple[np.ndarray, ...] | None = None) -> IncidentPart:
    """Incident direction ``m`` of a spectral run: every launch traced
    (:func:`trace_incident`, ``docs/spectral.md`` section 2) and its channels placed in their bins
    (:func:`merge_launches`)."""
    from goniometer.run.launches import launch_stacks
    return merge_launches(((bins, trace_incident(st, s, m, progress, buffers))
                           for bins, st, s in launch_stacks(stack, settings)), settings.wavelength_bins)


def merge_launches(launched: Iterable[tuple[tuple[int, ...], IncidentPart]], B: int) -> IncidentPart:
    """One incident direction of a spectral run of ``B`` bins from its launches' parts, given as
    (bins, three-channel part) in launch order (``docs/spectral.md`` section 2): each launch's
    channels written into its bins, counts and ``elapsed_s`` summed. Local runs and Dask runs
    (:func:`goniometer.run.distributed.dask_incidents`) both merge here, so their bits agree."""
    merged: IncidentPart | None = None
    for bins, part in launched:
        if merged is None:
            merged = _empty_part(part, B)
        # the launch's channels as a strided view of the bin axis: bins (k, k + G, k + 2G), or one bin
        dst = slice(bins[0], None, bins[1] - bins[0]) if len(bins) == 3 else slice(bins[0], bins[0] + 1)
        n = len(bins)
        for name in IncidentPart.PER_CHANNEL:
            a = getattr(part, name)
            if a is not None:
                getattr(merged, name)[:, dst] = a[:, :n]
        merged.energy[:, dst] = part.energy[:, :n]
        merged.energy_sq[:, dst] = part.energy_sq[:, :n]
        merged.counts += part.counts
        merged.elapsed_s += part.elapsed_s
    if merged is None:
        raise ValueError("merge_launches: a spectral incident direction needs at least one launch")
    return merged


def _empty_part(part: IncidentPart, B: int) -> IncidentPart:
    def widen(a: np.ndarray | None, axis: int) -> np.ndarray | None:
        if a is None:
            return None
        shape = list(a.shape)
        shape[axis] = B
        return np.zeros(shape, dtype=a.dtype)
    channels = {name: widen(getattr(part, name), 1) for name in IncidentPart.PER_CHANNEL}
    return IncidentPart(part.index, energy=widen(part.energy, 1), energy_sq=widen(part.energy_sq, 1),
                        counts=np.zeros_like(part.counts), elapsed_s=0.0, **channels)
