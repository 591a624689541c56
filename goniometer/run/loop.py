"""The run loop: trace the incident directions of one stack, locally or on a Dask cluster, with
or without checkpoints, and assemble the result.

:func:`run_incidents` is the one loop every caller uses (``gonio simulate``, databases, the
Python API); :func:`simulate` is its convenience form that compiles the kernel first and keeps
nothing on disk.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Callable

from goniometer.kernel import tracer
from goniometer.run.first_order import check_supported
from goniometer.run.results import IncidentPart, SimulationResult, assemble
from goniometer.run.settings import SettingsError, SimulationSettings
from goniometer.stack import Stack
from goniometer.run.tasks import incident_buffers, trace_incident, warm_up

if TYPE_CHECKING:
    from goniometer.run.checkpoints import Checkpoints

__all__ = ["SettingsError", "SimulationSettings", "run_incidents", "simulate", "simulate_resumable"]


def run_incidents(stack: Stack, settings: SimulationSettings, *,
                  checkpoints: "Checkpoints | None" = None, client: Any = None,
                  progress: Callable[[int], None] | None = None,
                  on_resume: Callable[[int], None] | None = None,
                  compile_s: float = 0.0) -> SimulationResult:
    """Trace every incident direction of ``settings`` for ``stack`` and assemble the result.

    ``checkpoints``: finished directions found there are loaded instead of traced
    (``on_resume(n)`` is told how many), and every newly finished one is saved there; the caller
    clears them once the result is safely written. ``client`` (a ``distributed.Client``) runs the
    tasks on a Dask cluster instead of local numba threads (a spectral run's too, one unit per
    launch and task: ``docs/spectral.md`` section 2); the result is bit-identical.
    ``progress(rays)`` is called as rays finish (directions loaded from checkpoints count too).
    The kernel is compiled on first use unless the caller has done it (:func:`warm_up`, whose
    time it passes as ``compile_s``).
    """
    settings.validate()
    if client is None:   # (a cluster's workers have machines of their own)
        tracer.check_device(settings.device, settings.threads)
    if settings.first_order == "integrated":
        check_supported(stack)
    M = len(settings.incident_deg)
    parts: dict[int, IncidentPart] = checkpoints.load(M) if checkpoints is not None else {}
    if parts and on_resume is not None:
        on_resume(len(parts))
    if progress is not None:
        per = settings.rays * (_launches(stack, settings))
        for _ in parts:
            progress(per)
    remaining = [k for k in range(M) if k not in parts]
    if client is None:
        buffers = incident_buffers(stack, settings) if remaining else None
        produced = ((k, trace_incident(stack, settings, k, progress, buffers)) for k in remaining)
    else:
        from goniometer.run.distributed import dask_incidents
        produced = dask_incidents(client, stack, settings, remaining, progress)
    for k, part in produced:
        if checkpoints is not None:
            checkpoints.save(k, part)
        parts[k] = part
    return assemble(stack, settings, [parts[k] for k in range(M)], compile_s=compile_s)


def _launches(stack: Stack, settings: SimulationSettings) -> int:
    if not settings.spectral:
        return 1
    from goniometer.run.launches import launches
    return len(launches(stack, settings))


def simulate(stack: Stack, settings: SimulationSettings,
             progress: Callable[[int], None] | None = None) -> SimulationResult:
    """Simulate all incident directions of ``settings`` for ``stack`` (in memory, nothing kept).

    ``progress``, if given, is called with the number of rays just finished (after every task).
    Compile time of the kernel is measured apart (``compile_s``), not in ``elapsed_s``.
    """
    settings.validate()
    return run_incidents(stack, settings, progress=progress, compile_s=warm_up(stack, settings))


def simulate_resumable(stack: Stack, settings: SimulationSettings, checkpoints: "Checkpoints",
                       progress: Callable[[int], None] | None = None,
                       on_resume: Callable[[int], None] | None = None) -> SimulationResult:
    """:func:`run_incidents` with ``checkpoints`` (the form ``gonio simulate`` uses); ``compile_s``
    of the result is 0 (the caller compiles)."""
    return run_incidents(stack, settings, checkpoints=checkpoints, progress=progress, on_resume=on_resume)
