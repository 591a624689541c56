"""Running a run's tasks on a Dask distributed cluster (the optional ``distributed`` extra).

Each (incident, task) unit -- (incident, launch, task) in a spectral run (``docs/spectral.md``
section 2) -- runs :func:`goniometer.run.tasks.trace_tasks` on a worker without numba threads; task
results are summed per incident direction (per launch) in task order, exactly as a local run sums
them, and a spectral run's launches are merged into their bins by the local run's
:func:`goniometer.run.tasks.merge_launches`, so the result is bit-identical to a local run's
(``docs/database-format.md`` section 4).
"""

from __future__ import annotations

import time
from collections import deque
from typing import Any, Callable, Iterator

from goniometer.run.settings import SimulationSettings
from goniometer.stack import Stack
from goniometer.run.results import IncidentPart, Sums
from goniometer.run.tasks import merge_launches, n_tasks, task_rays, trace_tasks


class ClusterError(ValueError):
    """The cluster cannot be used (package missing, scheduler unreachable)."""


def dask_client(address: str):
    """A ``distributed.Client`` connected to ``address`` (raises :class:`ClusterError`)."""
    try:
        from distributed import Client
    except ImportError:
        raise ClusterError("--scheduler needs the Dask distributed package: pip install 'goniometer[distributed]'") from None
    try:
        return Client(address, timeout="30s")
    except (OSError, TimeoutError) as e:
        raise ClusterError(f"cannot reach the Dask scheduler at {address}: {e}") from None


def run_task(stack_json: str, settings: SimulationSettings, m: int, task: int, launch: int | None = None) -> Sums:
    """One (incident, task) unit of work, as run on a Dask worker (no numba threads). ``launch``:
    in a spectral run, the launch whose task it is; the worker rebuilds that launch's stack and
    settings from the spectral ones (:func:`goniometer.run.launches.launch_stacks`, the
    local run's own)."""
    stack = Stack.from_json(stack_json)
    if launch is not None:
        from goniometer.run.launches import launch_stacks
        _, stack, settings = launch_stacks(stack, settings)[launch]
    return trace_tasks(stack, settings, m, task, 1, parallel=False)[0]


def dask_incidents(client: Any, stack: Stack, settings: SimulationSettings, incidents: list[int],
                   progress: Callable[[int], None] | None, window: int | None = None
                   ) -> Iterator[tuple[int, IncidentPart]]:
    """Run the tasks of ``incidents`` on the cluster, keeping at most ``window`` in flight, and
    yield each incident's :class:`IncidentPart` (tasks summed in task order; a spectral run's
    launches, each summed so, merged into bins in launch order) as it completes. An incident's
    ``elapsed_s`` is the wall time from its first submitted task to its last result (in a spectral
    run, split over its launches at the times their last results arrive)."""
    if window is None:
        workers = max(1, sum(client.nthreads().values()))
        window = 4 * workers
    stack_json = stack.to_json()
    if settings.spectral:
        from goniometer.run.launches import launch_stacks
        runs: list[tuple[tuple[int, ...], Stack, SimulationSettings]] = launch_stacks(stack, settings)
    else:
        runs = [((), stack, settings)]
    # units in (incident, launch, task) order: the order results are consumed and summed in
    specs = [(k, g, t) for k in incidents for g, (_, _, s) in enumerate(runs) for t in range(n_tasks(s))]
    inflight: deque = deque()
    it = iter(specs)
    acc: dict[int, Sums] = {}
    launched: dict[int, list[tuple[tuple[int, ...], IncidentPart]]] = {}  # a spectral run's finished launches
    since: dict[int, float] = {}

    def submit_next() -> bool:
        spec = next(it, None)
        if spec is None:
            return False
        k, g, t = spec
        since.setdefault(k, time.perf_counter())
        launch = g if settings.spectral else None
        inflight.append((k, g, t, client.submit(run_task, stack_json, settings, k, t, launch, pure=False)))
        return True

    for _ in range(window):
        if not submit_next():
            break
    while inflight:
        k, g, t, fut = inflight.popleft()
        sums = fut.result()
        fut.release()
        bins, st, s = runs[g]
        if k not in acc:
            acc[k] = Sums.zeros(st, s)
        acc[k].add(sums)  # tasks arrive here in (incident, launch, task) order
        if progress is not None:
            progress(task_rays(s, t))
        submit_next()
        if t == n_tasks(s) - 1:
            now = time.perf_counter()
            part = IncidentPart.from_sums(k, acc.pop(k), s.max_order, st.transmits, now - since[k])
            since[k] = now
            if not settings.spectral:
                yield k, part
                continue
            launched.setdefault(k, []).append((bins, part))
            if g == len(runs) - 1:
                yield k, merge_launches(launched.pop(k), settings.wavelength_bins)
