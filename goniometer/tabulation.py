"""The run of a tabulation: the whole isotropic BRDF of a stack on the MERL grid
(``docs/tabulated-format.md``).

The tracing kernel runs in its tabulation mode (:data:`goniometer.tracer.P_TABULATE`): chunk ``c``
of ``chunk_rays`` paths draws from the random stream ``(seed, TAB_STREAM, c)``, each path its own
incident direction (density ``cos theta_l / pi``), and records its reflected exit as a (MERL cell,
weight) pair. Chunks run in parallel in batches; their records are then added to the cell sums
one chunk after the other, in chunk order and path order within a chunk, so every cell receives
its additions in the order of a single sequential pass: the same (seed, chunk_rays) gives the same
bits whatever the thread count. Memory: the sums (sum, sum of squares, hits: ~82 MB) exist once;
a batch adds 32 bytes per path of its chunks (2 MB per chunk of 65 536 paths).

Resuming: the sums after a whole number of chunks are a checkpoint (``.FILE.h5.partial/`` beside
the output, saved every :data:`CHECKPOINT_EVERY_S` seconds and on Ctrl-C); a rerun of the same
run continues from there and ends with the same bits as an uninterrupted run.
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path
from typing import Callable

import numba
import numpy as np

from goniometer import atomic, halfdiff, tracer
from goniometer.checkpoint import code_key
from goniometer.settings import TabulationSettings
from goniometer.slices import boundary_tables
from goniometer.stack import Stack, pack
from goniometer.tabulated import TabulatedBRDF, from_sums

__all__ = ["TAB_STREAM", "TabulationCheckpoint", "TabulationError", "check_tabulable", "tabulate",
           "tabulation_description", "warm_up"]

#: the "incident index" of a tabulation's random streams (slices use 0 .. M - 1): a tabulation and
#: a slices run of the same seed draw from unrelated streams
TAB_STREAM = 2**32 - 1
#: seconds between checkpoints of a run that has a checkpoint directory
CHECKPOINT_EVERY_S = 60.0


class TabulationError(ValueError):
    """A stack or run that cannot be tabulated (the message says why)."""


def check_tabulable(stack: Stack) -> None:
    """Raise :class:`TabulationError` unless the stack's BRDF is isotropic (what the MERL grid holds)
    and has no thin film (a tabulation is an RGB run; a film needs wavelengths, docs/spectral.md)."""
    for k, x in enumerate(stack.layers):
        film = getattr(x, "film", None)
        if film is not None and film.thickness_nm > 0.0:
            raise TabulationError(f"{stack.name}: layers[{k}].film: a tabulation traces RGB (the MERL grid is RGB) "
                                  f"and a thin film needs a spectral run; simulate slices with --spectral instead")
    for k, x in enumerate(stack.interfaces):
        if x.is_anisotropic:
            ax, ay = x.alpha_xy
            raise TabulationError(
                f"{stack.name}: interface {k + 1} is anisotropic (roughness [{ax:g}, {ay:g}]); the MERL grid "
                f"drops the half-vector azimuth phi_h and holds isotropic BRDFs only")


def tabulation_description(stack: Stack, settings: TabulationSettings) -> dict:
    """What makes two tabulations the same run (``threads`` excluded), JSON-ready."""
    return {"kind": "tabulation", "stack": json.loads(stack.to_json()),
            "settings": {"rays": settings.rays, "seed": settings.seed, "masking": settings.masking,
                         "chunk_rays": settings.chunk_rays, "event_cap": settings.event_cap}}


class _State:
    """The raw sums after ``next_chunk`` chunks."""

    def __init__(self) -> None:
        self.chunk = np.zeros(1, dtype=np.int64)  # [next chunk], updated with the sums (see _commit)
        self.sums = np.zeros((halfdiff.N_CELLS, 3))
        self.sums_sq = np.zeros((halfdiff.N_CELLS, 3))
        self.hits = np.zeros(halfdiff.N_CELLS, dtype=np.int64)
        self.energy = np.zeros((tracer.N_ENERGY, 3))
        self.energy_sq = np.zeros((tracer.N_ENERGY_SQ, 3))
        self.counts = np.zeros(tracer.N_COUNTS, dtype=np.int64)
        self.elapsed_s = 0.0

    @property
    def next_chunk(self) -> int:
        return int(self.chunk[0])

    def save(self, path: Path) -> None:
        nz = np.flatnonzero(self.hits)
        atomic.write_npz(path, next_chunk=self.next_chunk, cells=nz, sums=self.sums[nz], sums_sq=self.sums_sq[nz],
                         hits=self.hits[nz], energy=self.energy, energy_sq=self.energy_sq, counts=self.counts,
                         elapsed_s=self.elapsed_s)

    @classmethod
    def load(cls, path: Path) -> "_State":
        s = cls()
        with np.load(path) as z:
            nz = z["cells"]
            s.chunk[0] = int(z["next_chunk"])
            s.sums[nz] = z["sums"]
            s.sums_sq[nz] = z["sums_sq"]
            s.hits[nz] = z["hits"]
            s.energy[...] = z["energy"]
            s.energy_sq[...] = z["energy_sq"]
            s.counts[...] = z["counts"]
            s.elapsed_s = float(z["elapsed_s"])
        return s


class TabulationCheckpoint:
    """The checkpoint directory of one tabulation: ``meta.json`` (the run and the code key, as
    :class:`goniometer.checkpoint.Checkpoints`) and ``state.npz`` (the sums after whole chunks)."""

    def __init__(self, directory: str | Path, meta: dict) -> None:
        self.directory = Path(directory)
        self.meta = dict(meta, code=code_key())

    def _current(self) -> bool:
        try:
            return json.loads((self.directory / "meta.json").read_text()) == self.meta
        except (OSError, ValueError):
            return False

    def load(self) -> _State | None:
        """The saved state of this run, or None (a checkpoint of another run or code is deleted)."""
        if not self.directory.is_dir():
            return None
        if not self._current():
            self.clear()
            return None
        try:
            return _State.load(self.directory / "state.npz")
        except (OSError, ValueError, KeyError):
            return None

    def save(self, state: _State) -> None:
        if not self._current():
            self.clear()
            self.directory.mkdir(parents=True, exist_ok=True)
            atomic.write_bytes(self.directory / "meta.json", json.dumps(self.meta, indent=1).encode())
        state.save(self.directory / "state.npz")

    def clear(self) -> None:
        shutil.rmtree(self.directory, ignore_errors=True)


@numba.njit(cache=True)
def _commit(exit_cell, exit_w, n_valid, energy, energy_sq, counts, sums, sums_sq, hits, acc_energy, acc_energy_sq,
            acc_counts, chunk):
    """Add a batch of chunks to the state: the exit records to the cell sums (chunk by chunk, path
    by path), the energy sums chunk by chunk, and advance ``chunk[0]`` past the batch. One compiled
    call, so a Ctrl-C (handled by Python between calls) never sees half of it."""
    for b in range(exit_cell.shape[0]):
        for r in range(energy.shape[1]):
            for k in range(3):
                acc_energy[r, k] += energy[b, r, k]
        for r in range(energy_sq.shape[1]):
            for k in range(3):
                acc_energy_sq[r, k] += energy_sq[b, r, k]
        for r in range(counts.shape[1]):
            acc_counts[r] += counts[b, r]
        for r in range(n_valid[b]):
            c = exit_cell[b, r]
            if c >= 0:
                for k in range(3):
                    w = exit_w[b, r, k]
                    sums[c, k] += w
                    sums_sq[c, k] += w * w
                hits[c] += 1
    chunk[0] += exit_cell.shape[0]


def warm_up(stack: Stack | None = None, settings: TabulationSettings | None = None) -> float:
    """Compile (or load from the on-disk cache) the tabulation kernel variant ``stack`` needs under
    ``settings``' masking and the accumulation, by tabulating 8 rays; returns the seconds spent.
    Without arguments: a Lambertian stack, separable masking."""
    from goniometer.stack import Lambertian
    t0 = time.perf_counter()
    if stack is None:
        stack = Stack("warm-up", (Lambertian((0.5,) * 3),))
    masking = settings.masking if settings is not None else "separable"
    tabulate(stack, TabulationSettings(rays=8, chunk_rays=8, threads=1, masking=masking))
    return time.perf_counter() - t0


def tabulate(stack: Stack, settings: TabulationSettings, *, checkpoint: TabulationCheckpoint | None = None,
             progress: Callable[[int], None] | None = None, on_resume: Callable[[int], None] | None = None,
             compile_s: float = 0.0) -> TabulatedBRDF:
    """Tabulate the isotropic BRDF of ``stack`` (raises :class:`TabulationError` for an
    anisotropic stack). ``checkpoint``: resume from it and save to it (the caller clears it once
    the file is written); ``on_resume(rays)`` is told how many rays were loaded. ``progress(rays)``
    is called after every batch. A KeyboardInterrupt (from ``progress`` or a signal handler)
    saves the checkpoint, then propagates; once every chunk is traced the checkpoint is saved too,
    so that an interrupt while the caller writes the file loses nothing."""
    check_tabulable(stack)
    settings.validate()
    state = checkpoint.load() if checkpoint is not None else None
    if state is None:
        state = _State()
    cr = settings.chunk_rays
    n_chunks = -(-settings.rays // cr)
    done_rays = min(state.next_chunk * cr, settings.rays)
    if done_rays:
        if on_resume is not None:
            on_resume(done_rays)
        if progress is not None:
            progress(done_rays)
    p = pack(stack)
    threads = settings.n_threads
    numba.set_num_threads(threads)
    B = min(2 * threads, n_chunks)
    brdf = np.empty((B, 1, 1, 3, 3))
    btdf = np.empty((B, 1, 1, 3, 3))
    energy = np.empty((B, tracer.N_ENERGY, 3))
    energy_sq = np.empty((B, tracer.N_ENERGY_SQ, 3))
    counts = np.empty((B, tracer.N_COUNTS), dtype=np.int64)
    exit_cell = np.empty((B, cr), dtype=np.int64)
    exit_w = np.empty((B, cr, 3))
    run = tracer.prepare(p, (0.0, 0.0, 1.0), settings.rays, cr, settings.seed, TAB_STREAM, tracer.P_TABULATE, 1, 1,
                         boundary_tables("classic", 1, 1), 1, settings.event_cap,
                         height_correlated=settings.masking == "height-correlated", tabulate=True)
    last_save = time.monotonic()
    try:
        while state.next_chunk < n_chunks:
            t0 = time.perf_counter()
            first = state.next_chunk
            nb = min(B, n_chunks - first)
            tracer.launch(run, first, (brdf[:nb], btdf[:nb], energy[:nb], energy_sq[:nb], counts[:nb]),
                          (exit_cell[:nb], exit_w[:nb]))
            n_valid = run.chunk_sizes(first, nb)
            _commit(exit_cell[:nb], exit_w[:nb], n_valid, energy[:nb], energy_sq[:nb], counts[:nb], state.sums,
                    state.sums_sq, state.hits, state.energy, state.energy_sq, state.counts, state.chunk)
            state.elapsed_s += time.perf_counter() - t0
            if checkpoint is not None and time.monotonic() - last_save > CHECKPOINT_EVERY_S \
                    and state.next_chunk < n_chunks:
                checkpoint.save(state)
                last_save = time.monotonic()
            if progress is not None:
                progress(int(n_valid.sum()))
        if checkpoint is not None and n_chunks > 0 and state.next_chunk * cr > done_rays:
            checkpoint.save(state)
        return from_sums(stack, settings, state.sums, state.sums_sq, state.hits, state.energy, state.energy_sq,
                         state.counts, state.elapsed_s, threads, compile_s)
    except KeyboardInterrupt:
        # the state is always whole chunks (_commit is one compiled call): keep it
        if checkpoint is not None and state.next_chunk > 0:
            checkpoint.save(state)
        raise
