"""Worker processes for the harness's loops over materials: a report's evaluations and figures, the
production study's measurements (``docs/report.md``, "Workers").

:func:`run_in_workers` runs ``task(item)`` for every item in ``jobs`` worker processes and hands
each result back to the calling process as soon as it is done (``done``: a progress bar moves per
material), the results in the items' order. ``jobs=1`` runs everything here, one after the other.

* **Same results.** A task computes in a worker exactly what it computes here: the same functions
  on the same inputs; the numba kernels a model uses give the same bits whatever the thread count
  (``docs/architecture.md``, determinism). So a report written with ``--jobs 2`` holds the same
  ``errors.json``, tables and figures as a serial one.
* **Fresh workers.** Workers are started by multiprocessing's ``forkserver``: a clean process that
  has imported the modules the tasks need (:data:`PRELOAD`) forks each worker. Forking the calling
  process itself is not safe once it has run a parallel numba kernel (GNU OpenMP aborts the child),
  and starting each worker from scratch (``spawn``) would import everything again in each.
* **Threads.** Each worker runs its numba kernels on ``threads // jobs`` threads (at least 1), so
  that the workers together use the cores once.
* **numba's cache.** Two processes that compile the same function at once both write it to the
  on-disk cache. ``warm_up``, if given, runs here before any worker starts (it compiles, or loads
  from the cache, what the tasks will call), so that the workers only read the cache.
* **Ctrl-C** reaches the workers with the calling process (the terminal's process group; when
  only the calling process gets it, it passes it on): a worker stops its task at the next Python
  line (a numba kernel runs to its end; a Ctrl-C that lands inside numba's compiler is sent again
  a moment later rather than printed and lost), whatever it was writing is removed
  (:mod:`goniometer.atomic`), the tasks not yet handed out are dropped and
  :class:`KeyboardInterrupt` is raised here; what finished before stays finished (each file is
  written whole or not at all: a report's cache, ``docs/report.md``). When a task raises, the other
  workers are stopped the same way before the exception is raised here.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import sys
import threading
import time
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from pathlib import Path
from typing import Callable, Iterator, Sequence, TypeVar

from goniometer.atomic import TEMP_GLOB

T = TypeVar("T")
R = TypeVar("R")

#: modules the forkserver imports once, before it forks the workers
PRELOAD = ["numpy", "numba", "h5py", "goniometer", "models.report.build", "models.production.study.measure"]


def check_jobs(jobs: int) -> int:
    """``jobs`` as an int; ValueError naming ``jobs`` unless it is a whole number >= 1."""
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise ValueError(f"jobs = {jobs!r}: the number of worker processes must be a whole number >= 1")
    return jobs


#: in a worker: its task and whether it is running one
_TASK: Callable | None = None
_BUSY = False


class _Interrupted:
    """What a worker's task returns when Ctrl-C stopped it."""


def _on_sigint(signum: int, frame) -> None:
    """In a worker: Ctrl-C stops the running task (:class:`KeyboardInterrupt`: its ``finally``
    blocks run, so whatever it was writing is removed, :mod:`goniometer.atomic`); an idle worker
    ignores it and ends when it is told to."""
    if _BUSY:
        raise KeyboardInterrupt


def _unraisable(hook):
    """``sys.unraisablehook`` of a worker: a Ctrl-C that landed where Python cannot raise it (a
    callback of numba's compiler, a finalizer) is not printed but sent again a moment later, so
    that it stops the task where it can."""
    def handle(u) -> None:
        if isinstance(u.exc_value, KeyboardInterrupt):
            if _BUSY:
                threading.Timer(0.05, os.kill, (os.getpid(), signal.SIGINT)).start()
            return
        hook(u)
    return handle


def _init(task: Callable, threads: int) -> None:
    """A worker's start: its task, its Ctrl-C handler, its numba threads (until here it ignores
    SIGINT, as the forkserver it was forked from: :func:`_start_server`)."""
    global _TASK
    _TASK = task
    signal.signal(signal.SIGINT, _on_sigint)
    sys.unraisablehook = _unraisable(sys.unraisablehook)
    import numba
    numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))


def _ready(_: object) -> int:
    """A task that says which worker ran it (the pool's start, :func:`run_in_workers`)."""
    time.sleep(0.02)
    return os.getpid()


def _call(item: object) -> object:
    global _BUSY
    _BUSY = True
    try:
        return _TASK(item)
    except KeyboardInterrupt:
        return _Interrupted()
    finally:
        _BUSY = False


def _start_server(ctx) -> None:
    """Start the forkserver (once per process) with SIGINT ignored, which it inherits: a Ctrl-C
    while it imports :data:`PRELOAD` would print a traceback. It ignores SIGINT once it serves, and
    so do its workers until :func:`_init`."""
    ctx.set_forkserver_preload(PRELOAD)
    from multiprocessing import forkserver
    with _ignoring_sigint():
        forkserver.ensure_running()


@contextlib.contextmanager
def _holding_sigint() -> Iterator[None]:
    """SIGINT within the block is held and raised (:class:`KeyboardInterrupt`) when it ends (in the
    main thread; elsewhere Python cannot change it)."""
    if threading.current_thread() is not threading.main_thread() or \
            signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        yield
        return
    got: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: got.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if got:
        raise KeyboardInterrupt


def _started(executor: ProcessPoolExecutor, jobs: int) -> set[int]:
    """Wait until every worker has started (run :func:`_init`), Ctrl-C held meanwhile (a worker
    still unpacking its start when the pool is shut down prints a traceback); their pids."""
    seen: set[int] = set()
    with _holding_sigint():
        for _ in range(100):
            seen.update(f.result() for f in [executor.submit(_ready, None) for _ in range(jobs)])
            if len(seen) >= jobs:
                break
    return seen


def _interrupt(pids: set[int]) -> None:
    """Ctrl-C for the workers (when only this process got it: ``kill -INT``, a test, a failed task)."""
    for pid in pids:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.kill(pid, signal.SIGINT)


@contextlib.contextmanager
def _ignoring_sigint():
    """SIGINT ignored within the block (in the main thread; elsewhere Python cannot change it)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _sweep(root: Path, pids: set[int]) -> None:
    """Remove the temporary files (:data:`goniometer.atomic.TEMP_GLOB`, named after their writer's
    pid) that the workers ``pids`` left under ``root`` (none, unless a worker was killed mid-write
    before its own cleanup ran)."""
    mine = {f"tmp-{pid}-" for pid in pids}
    for p in root.rglob(TEMP_GLOB):
        if any(m in p.name for m in mine):
            with contextlib.suppress(OSError):
                p.unlink()


def run_in_workers(task: Callable[[T], R], items: Sequence[T], jobs: int = 1,
                   done: Callable[[int, R], None] | None = None, start: Callable[[int], None] | None = None,
                   warm_up: Callable[[], None] | None = None, writes_under: Path | None = None) -> list[R]:
    """``[task(item) for item in items]``, in ``jobs`` worker processes (``jobs=1``: here).

    ``start(index)`` is called here when a task is handed to a worker (in the items' order) and
    ``done(index, result)`` as each task finishes (in the order they finish; with one job, in the
    items' order). ``task`` must be a module-level function (the workers import it by name) and its
    items and results picklable; a script that calls this with ``jobs > 1`` needs the usual
    ``if __name__ == "__main__":`` guard of multiprocessing. An exception a task raises is raised
    here once the other workers have stopped. ``warm_up()`` runs here first when there are workers
    (see the module docstring). ``writes_under``: the directory the tasks write into, swept of the
    temporary files of stopped workers."""
    jobs = min(check_jobs(jobs), max(1, len(items)))
    if jobs == 1:
        results = []
        for i, item in enumerate(items):
            if start is not None:
                start(i)
            r = task(item)
            results.append(r)
            if done is not None:
                done(i, r)
        return results
    if warm_up is not None:
        warm_up()
    import numba
    threads = max(1, numba.get_num_threads() // jobs)
    ctx = multiprocessing.get_context("forkserver")
    _start_server(ctx)
    out: list = [None] * len(items)
    running: dict[Future, int] = {}
    ok = False
    executor = ProcessPoolExecutor(jobs, mp_context=ctx, initializer=_init, initargs=(task, threads))
    pids: set[int] = set()
    try:
        pids = _started(executor, jobs)
        following = 0
        while following < len(items) or running:
            while following < len(items) and len(running) < jobs:
                if start is not None:
                    start(following)
                running[executor.submit(_call, items[following])] = following
                following += 1
            finished, _ = wait(running, return_when=FIRST_COMPLETED)
            for f in sorted(finished, key=running.get):
                r = f.result()
                if isinstance(r, _Interrupted):
                    raise KeyboardInterrupt   # a worker got Ctrl-C; this process has it too, or will
                i = running.pop(f)
                out[i] = r
                if done is not None:
                    done(i, r)
        ok = True
    finally:
        if not ok:
            with _ignoring_sigint():   # one Ctrl-C is enough: the second would stop the cleanup
                for f in running:
                    f.cancel()
                _interrupt(pids)
                executor.shutdown(wait=True, cancel_futures=True)
                if writes_under is not None:
                    _sweep(Path(writes_under), pids)
        else:
            executor.shutdown(wait=True)
    return out
