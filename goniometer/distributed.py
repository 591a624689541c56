"""Running a run's tasks on a Dask distributed cluster (the optional ``distributed`` extra).

Each (incident, task) unit runs :func:`goniometer.tasks.trace_tasks` on a worker without numba
threads; task results are summed per incident direction in task order, exactly as a local run
sums them, so the result is bit-identical to a local run's.
"""

from __future__ import annotations

import time
from collections import deque
from typing import Any, Callable, Iterator

from goniometer.settings import SimulationSettings
from goniometer.stack import Stack
from goniometer.results import IncidentPart, Sums
from goniometer.tasks import n_tasks, task_rays, trace_tasks


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


def run_task(stack_json: str, settings: SimulationSettings, m: int, task: int) -> Sums:
    """One (incident, task) unit of work, as run on a Dask worker (no numba threads)."""
    return trace_tasks(Stack.from_json(stack_json), settings, m, task, 1, parallel=False)[0]


def dask_incidents(client: Any, stack: Stack, settings: SimulationSettings, incidents: list[int],
                   progress: Callable[[int], None] | None, window: int | None = None
                   ) -> Iterator[tuple[int, IncidentPart]]:
    """Run the tasks of ``incidents`` on the cluster, keeping at most ``window`` in flight, and
    yield each incident's :class:`IncidentPart` (tasks summed in task order) as it completes."""
    if window is None:
        workers = max(1, sum(client.nthreads().values()))
        window = 4 * workers
    stack_json = stack.to_json()
    specs = [(k, t) for k in incidents for t in range(n_tasks(settings))]
    inflight: deque = deque()
    it = iter(specs)
    acc: dict[int, Sums] = {}
    started: dict[int, float] = {}
    last_task = {k: n_tasks(settings) - 1 for k in incidents}

    def submit_next() -> bool:
        spec = next(it, None)
        if spec is None:
            return False
        k, t = spec
        started.setdefault(k, time.perf_counter())
        inflight.append((k, t, client.submit(run_task, stack_json, settings, k, t, pure=False)))
        return True

    for _ in range(window):
        if not submit_next():
            break
    while inflight:
        k, t, fut = inflight.popleft()
        sums = fut.result()
        fut.release()
        if k not in acc:
            acc[k] = Sums.zeros(stack, settings)
        acc[k].add(sums)  # tasks arrive here in (incident, task) order
        if progress is not None:
            progress(task_rays(settings, t))
        submit_next()
        if t == last_task[k]:
            yield k, IncidentPart.from_sums(k, acc.pop(k), settings.max_order, stack.transmits,
                                            time.perf_counter() - started[k])
