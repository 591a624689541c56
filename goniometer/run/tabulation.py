"""The run of a tabulation: the whole isotropic BRDF of a stack on the MERL grid
(``docs/tabulated-format.md``).

The tracing kernel runs in its tabulation mode (:data:`goniometer.kernel.tracer.P_TABULATE`): chunk ``c``
of ``chunk_rays`` paths draws from the random stream ``(seed, TAB_STREAM, c)``, each path its own
incident direction (density ``cos theta_l / pi``), and records its reflected exit as a (MERL cell,
weight) pair. Chunks run in parallel in batches; their records are then added to the cell sums
one chunk after the other, in chunk order and path order within a chunk, so every cell receives
its additions in the order of a single sequential pass: the same (seed, chunk_rays) gives the same
bits whatever the thread count. Memory: the sums (sum, sum of squares, hits: ~82 MB) exist once;
a batch adds 32 bytes per path of its chunks (2 MB per chunk of 65 536 paths).

Resuming: the sums after a whole number of chunks are a checkpoint (``.FILE.h5.partial/`` beside
the output, saved compressed every :data:`CHECKPOINT_EVERY_S` seconds and on Ctrl-C); a rerun of
the same run continues from there and ends with the same bits as an uninterrupted run. A rerun of
another run (settings, stack, code version) raises
:class:`~goniometer.run.checkpoints.CheckpointMismatch` and leaves the checkpoint as it is.
"""

from __future__ import annotations

import contextlib
import json
import shutil
import time
from dataclasses import replace
from pathlib import Path
from typing import Callable

import numba
import numpy as np

from goniometer import atomic
from goniometer.grids import halfdiff
from goniometer.kernel import tracer
from goniometer.run import checkpoints as _checkpoint
from goniometer.run.checkpoints import UNREADABLE, CheckpointMismatch, check_meta, unreadable_reason, write_meta
from goniometer.run.settings import TabulationSettings
from goniometer.grids.slice_grid import boundary_tables
from goniometer.stack import Stack
from goniometer.kernel.packing import pack
from goniometer.run.results import TabulatedBRDF

__all__ = ["TAB_STREAM", "TabulationCheckpoint", "TabulationError", "check_tabulable", "launches", "tabulate",
           "tabulation_description", "warm_up"]

#: the "incident index" of a tabulation's random streams (slices use 0 .. M - 1): a tabulation and
#: a slices run of the same seed draw from unrelated streams
TAB_STREAM = 2**32 - 1
#: seconds between checkpoints of a run that has a checkpoint directory
CHECKPOINT_EVERY_S = 60.0
#: the checkpoint's state file in its directory
STATE = "state.npz"


class TabulationError(ValueError):
    """A stack or run that cannot be tabulated (the message says why)."""


def check_tabulable(stack: Stack, settings: TabulationSettings | None = None) -> None:
    """Raise :class:`TabulationError` unless the stack's BRDF is isotropic (what the MERL grid holds)
    and, for an RGB tabulation (``settings`` None or not spectral), has no thin film (a film needs
    wavelengths, docs/spectral.md)."""
    spectral = settings is not None and settings.spectral
    for k, x in enumerate(stack.layers):
        film = getattr(x, "film", None)
        if film is not None and film.thickness_nm > 0.0 and not spectral:
            raise TabulationError(f"{stack.name}: layers[{k}].film: a thin film needs wavelengths; tabulate with "
                                  f"--spectral (an RGB tabulation cannot carry it)")
    for k, x in enumerate(stack.interfaces):
        if x.is_anisotropic:
            ax, ay = x.alpha_xy
            raise TabulationError(
                f"{stack.name}: interface {k + 1} is anisotropic (roughness [{ax:g}, {ay:g}]); the MERL grid "
                f"drops the half-vector azimuth phi_h and holds isotropic BRDFs only")


def tabulation_description(stack: Stack, settings: TabulationSettings) -> dict:
    """What makes two tabulations the same run (``threads`` excluded), JSON-ready."""
    run = {"rays": settings.rays, "seed": settings.seed, "masking": settings.masking,
           "chunk_rays": settings.chunk_rays, "event_cap": settings.event_cap}
    if settings.spectral:   # (the keys of RGB and CPU runs predate these fields: their identity stays)
        run.update(spectral=True, wavelength_bins=settings.wavelength_bins)
    if settings.device != "cpu":
        run["device"] = settings.device
    if settings.polarized:   # (the keys of scalar runs predate the field)
        run["polarized"] = True
    return {"kind": "tabulation", "stack": json.loads(stack.to_json()), "settings": run}


class _State:
    """The raw sums after ``next_chunk`` chunks; a polarized run's also the Mueller elements' sums
    and their squares' (``mueller``, ``mueller_sq``: (N_CELLS, C, 16), "plane" frames,
    ``docs/polarization.md`` section 5)."""

    #: the arrays of a saved state
    KEYS = ("next_chunk", "cells", "sums", "sums_sq", "hits", "energy", "energy_sq", "counts", "elapsed_s")
    #: the further arrays of a polarized run's saved state
    POLARIZED_KEYS = ("mueller", "mueller_sq")

    def __init__(self, n_channels: int = 3, polarized: bool = False) -> None:
        # [next chunk], updated with the sums (see _commit); a spectral run's chunks are numbered
        # launch after launch (chunk c of launch g is g * chunks per launch + c)
        self.chunk = np.zeros(1, dtype=np.int64)
        self.sums = np.zeros((halfdiff.N_CELLS, n_channels))
        self.sums_sq = np.zeros((halfdiff.N_CELLS, n_channels))
        self.hits = np.zeros(halfdiff.N_CELLS, dtype=np.int64)
        self.energy = np.zeros((tracer.N_ENERGY, n_channels))
        self.energy_sq = np.zeros((tracer.N_ENERGY_SQ, n_channels))
        self.counts = np.zeros(tracer.N_COUNTS, dtype=np.int64)
        self.elapsed_s = 0.0
        self.mueller = np.zeros((halfdiff.N_CELLS, n_channels, 16)) if polarized else None
        self.mueller_sq = np.zeros((halfdiff.N_CELLS, n_channels, 16)) if polarized else None

    @property
    def next_chunk(self) -> int:
        return int(self.chunk[0])

    def save(self, path: Path) -> None:
        nz = np.flatnonzero(self.hits)
        pol = {} if self.mueller is None else {"mueller": self.mueller[nz], "mueller_sq": self.mueller_sq[nz]}
        atomic.write_npz_compressed(path, next_chunk=self.next_chunk, cells=nz, sums=self.sums[nz],
                                    sums_sq=self.sums_sq[nz], hits=self.hits[nz], energy=self.energy,
                                    energy_sq=self.energy_sq, counts=self.counts, elapsed_s=self.elapsed_s, **pol)

    @classmethod
    def load(cls, path: Path, n_channels: int, polarized: bool = False) -> "_State":
        s = cls(n_channels, polarized)
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
            if polarized:
                s.mueller[nz] = z["mueller"]
                s.mueller_sq[nz] = z["mueller_sq"]
        return s


class TabulationCheckpoint:
    """The checkpoint directory of one tabulation: ``meta.json`` (the run and the code key, as
    :class:`goniometer.run.checkpoints.Checkpoints`) and ``state.npz`` (the sums after whole chunks,
    compressed). A state of another run or code version, or one that cannot be read, raises
    :class:`goniometer.run.checkpoints.CheckpointMismatch` and is kept: only :meth:`clear`
    (``--restart``) discards it (the state is all the progress of the run: it is never dropped
    behind the user's back)."""

    def __init__(self, directory: str | Path, meta: dict) -> None:
        self.directory = Path(directory)
        self.meta = dict(meta, code=_checkpoint.code_key())
        self.polarized = bool(meta.get("settings", {}).get("polarized", False))

    @property
    def state_path(self) -> Path:
        return self.directory / STATE

    def kept(self) -> list[Path]:
        """The state file, if there is one."""
        return [self.state_path] if self.state_path.is_file() else []

    def check(self) -> None:
        """Raise :class:`~goniometer.run.checkpoints.CheckpointMismatch` if the directory holds a state
        of another run or code version, or one that cannot be opened; changes nothing."""
        check_meta(self.directory, self.meta, self.kept())
        if self.kept():
            with self._readable():
                with np.load(self.state_path) as z:
                    keys = _State.KEYS + (_State.POLARIZED_KEYS if self.polarized else ())
                    missing = sorted(set(keys) - set(z.files))
                if missing:
                    raise KeyError(f"no {missing[0]}")

    def load(self, n_channels: int = 3) -> _State | None:
        """The saved state of this run, or None if there is none."""
        self.check()
        if not self.kept():
            return None
        with self._readable():
            return _State.load(self.state_path, n_channels, self.polarized)

    @contextlib.contextmanager
    def _readable(self):
        """An unreadable state file: CheckpointMismatch (it holds all the run's progress; only
        :meth:`clear` discards it)."""
        try:
            yield
        except UNREADABLE as e:
            raise CheckpointMismatch(self.directory, reason=f"{STATE} cannot be read "
                                                            f"({unreadable_reason(self.state_path, e)})") from None

    def save(self, state: _State) -> None:
        write_meta(self.directory, self.meta, self.kept())
        state.save(self.state_path)

    def clear(self) -> None:
        """Discard the checkpoint (``--restart``; after the file is written)."""
        shutil.rmtree(self.directory, ignore_errors=True)


@numba.njit(cache=True, error_model='numpy')
def _commit(exit_cell, exit_w, n_valid, energy, energy_sq, counts, sums, sums_sq, hits, acc_energy, acc_energy_sq,
            acc_counts, chunk):
    """Add a batch of chunks to the state: the exit records to the cell sums (chunk by chunk, path
    by path), the energy sums chunk by chunk, and advance ``chunk[0]`` past the batch. One compiled
    call, so a Ctrl-C (handled by Python between calls) never sees half of it. The accumulators'
    channels (views of a spectral run's bins: 3, or 1 for a launch of one wavelength) take the
    kernel's first channels."""
    nc = sums.shape[1]
    for b in range(exit_cell.shape[0]):
        for r in range(energy.shape[1]):
            for k in range(nc):
                acc_energy[r, k] += energy[b, r, k]
        for r in range(energy_sq.shape[1]):
            for k in range(nc):
                acc_energy_sq[r, k] += energy_sq[b, r, k]
        for r in range(counts.shape[1]):
            acc_counts[r] += counts[b, r]
        for r in range(n_valid[b]):
            c = exit_cell[b, r]
            if c >= 0:
                for k in range(nc):
                    w = exit_w[b, r, k]
                    sums[c, k] += w
                    sums_sq[c, k] += w * w
                hits[c] += 1
    chunk[0] += exit_cell.shape[0]


@numba.njit(cache=True, error_model='numpy')
def _commit_polarized(exit_cell, exit_w, exit_m, n_valid, energy, energy_sq, counts, sums, sums_sq, hits, acc_energy,
                      acc_energy_sq, acc_counts, chunk, mueller, mueller_sq):
    """:func:`_commit` of a polarized run, and in the same compiled call the exits' Mueller
    matrices ``exit_m`` ((B, chunk_rays, 1, 16, 3), :func:`goniometer.kernel.polarized.tabulated_exit`)
    to ``mueller``/``mueller_sq`` ((N_CELLS, C, 16) views), in the same order."""
    nc = sums.shape[1]
    for b in range(exit_cell.shape[0]):
        for r in range(n_valid[b]):
            c = exit_cell[b, r]
            if c >= 0:
                for k in range(nc):
                    for e in range(16):
                        m = exit_m[b, r, 0, e, k]
                        mueller[c, k, e] += m
                        mueller_sq[c, k, e] += m * m
    _commit(exit_cell, exit_w, n_valid, energy, energy_sq, counts, sums, sums_sq, hits, acc_energy, acc_energy_sq,
            acc_counts, chunk)


def warm_up(stack: Stack | None = None, settings: TabulationSettings | None = None) -> float:
    """Compile (or load from the on-disk cache) the tabulation kernel variants ``stack`` needs under
    ``settings`` (masking, device, a spectral run's launches) and the accumulation, by tabulating 8
    rays; returns the seconds spent.
    Without arguments: a Lambertian stack, separable masking."""
    from goniometer.stack import Lambertian
    t0 = time.perf_counter()
    if stack is None:
        stack = Stack("warm-up", (Lambertian((0.5,) * 3),))
    settings = settings if settings is not None else TabulationSettings(rays=8)
    tabulate(stack, replace(settings, rays=8, chunk_rays=8, threads=1))
    return time.perf_counter() - t0


def launches(stack: Stack, settings: TabulationSettings) -> list[tuple[tuple[int, ...], Stack, int]]:
    """(channels of the state, three-channel stack, seed) of every kernel launch: one launch of the
    stack for an RGB tabulation; a spectral one's launches of
    :func:`goniometer.run.launches.launch_stacks` (``docs/spectral.md`` section 2)."""
    if not settings.spectral:
        return [((0, 1, 2), stack, settings.seed)]
    from goniometer.run.launches import launch_stacks
    return [(bins, st, s.seed) for bins, st, s in launch_stacks(stack, settings)]


def _channels(bins: tuple[int, ...]) -> slice:
    """The launch's bins as a slice of the channel axis: ``(k, k + G, k + 2G)`` or one bin."""
    return slice(bins[0], None, bins[1] - bins[0]) if len(bins) == 3 else slice(bins[0], bins[0] + 1)


def tabulate(stack: Stack, settings: TabulationSettings, *, checkpoint: TabulationCheckpoint | None = None,
             progress: Callable[[int], None] | None = None, on_resume: Callable[[int], None] | None = None,
             compile_s: float = 0.0) -> TabulatedBRDF:
    """Tabulate the isotropic BRDF of ``stack`` (raises :class:`TabulationError` for an
    anisotropic stack). ``checkpoint``: resume from it and save to it (the caller clears it once
    the file is written); ``on_resume(rays)`` is told how many rays were loaded. ``progress(rays)``
    is called after every batch. A KeyboardInterrupt (from ``progress`` or a signal handler)
    saves the checkpoint, then propagates; once every chunk is traced the checkpoint is saved too,
    so that an interrupt while the caller writes the file loses nothing.

    A spectral tabulation (``settings.spectral``) traces ``settings.rays`` paths per launch, each
    launch's three channels landing in its wavelength bins (``docs/spectral.md`` section 2); its
    chunks are numbered launch after launch, so that it resumes like an RGB one."""
    check_tabulable(stack, settings)
    settings.validate()
    tracer.check_device(settings.device, settings.threads)
    runs = launches(stack, settings)
    pol = settings.polarized
    state = checkpoint.load(settings.n_channels) if checkpoint is not None else None
    if state is None:
        state = _State(settings.n_channels, pol)
    cr = settings.chunk_rays
    per_launch = tracer.chunk_count(settings.rays, cr)
    n_chunks = per_launch * len(runs)
    done_rays = _rays_in(state.next_chunk, per_launch, settings.rays, cr)
    if done_rays:
        if on_resume is not None:
            on_resume(done_rays)
        if progress is not None:
            progress(done_rays)
    threads = tracer.thread_count(settings.threads)
    if settings.device == "cpu":
        numba.set_num_threads(threads)
    B = min(2 * threads, per_launch)
    brdf = np.empty((B, 1, 1, 3, 3))
    btdf = np.empty((B, 1, 1, 3, 3))
    energy = np.empty((B, tracer.N_ENERGY, 3))
    energy_sq = np.empty((B, tracer.N_ENERGY_SQ, 3))
    counts = np.empty((B, tracer.N_COUNTS), dtype=np.int64)
    exit_cell = np.empty((B, cr), dtype=np.int64)
    exit_w = np.empty((B, cr, 3))
    # a polarized run's exits' Mueller matrices (the per-path kernel's mbrdf slot; docs/polarization.md section 5)
    mueller = (np.empty((B, cr, 1, 16, 3)), np.empty((B, 0, 0, 0, 3))) if pol else None
    last_save = time.monotonic()
    try:
        while state.next_chunk < n_chunks:
            g, first = divmod(state.next_chunk, per_launch)
            bins, st, seed = runs[g]
            run = tracer.prepare(pack(st), (0.0, 0.0, 1.0), settings.rays, cr, seed, TAB_STREAM, tracer.P_TABULATE,
                                 1, 1, boundary_tables("classic", 1, 1), 1, settings.event_cap,
                                 height_correlated=settings.masking == "height-correlated", tabulate=True,
                                 device=settings.device, polarized=pol)
            ch = _channels(bins)
            sums, sums_sq = state.sums[:, ch], state.sums_sq[:, ch]
            acc_energy, acc_energy_sq = state.energy[:, ch], state.energy_sq[:, ch]
            if pol:
                acc_m, acc_m_sq = state.mueller[:, ch], state.mueller_sq[:, ch]
            while first < per_launch:
                t0 = time.perf_counter()
                nb = min(B, per_launch - first)
                tracer.launch(run, first, (brdf[:nb], btdf[:nb], energy[:nb], energy_sq[:nb], counts[:nb]),
                              (exit_cell[:nb], exit_w[:nb]), mueller=None if mueller is None else
                              (mueller[0][:nb], mueller[1][:nb]))
                n_valid = run.chunk_sizes(first, nb)
                if pol:
                    _commit_polarized(exit_cell[:nb], exit_w[:nb], mueller[0][:nb], n_valid, energy[:nb],
                                      energy_sq[:nb], counts[:nb], sums, sums_sq, state.hits, acc_energy,
                                      acc_energy_sq, state.counts, state.chunk, acc_m, acc_m_sq)
                else:
                    _commit(exit_cell[:nb], exit_w[:nb], n_valid, energy[:nb], energy_sq[:nb], counts[:nb], sums,
                            sums_sq, state.hits, acc_energy, acc_energy_sq, state.counts, state.chunk)
                first += nb
                state.elapsed_s += time.perf_counter() - t0
                if checkpoint is not None and time.monotonic() - last_save > CHECKPOINT_EVERY_S \
                        and state.next_chunk < n_chunks:
                    checkpoint.save(state)
                    last_save = time.monotonic()
                if progress is not None:
                    progress(int(n_valid.sum()))
        if checkpoint is not None and n_chunks > 0 and \
                _rays_in(state.next_chunk, per_launch, settings.rays, cr) > done_rays:
            checkpoint.save(state)
        return TabulatedBRDF.from_sums(stack, settings, state.sums, state.sums_sq, state.hits, state.energy,
                                       state.energy_sq, state.counts, state.elapsed_s, threads, compile_s,
                                       launches=len(runs), mueller=state.mueller, mueller_sq=state.mueller_sq)
    except KeyboardInterrupt:
        # the state is always whole chunks (_commit is one compiled call): keep it
        if checkpoint is not None and state.next_chunk > 0:
            checkpoint.save(state)
        raise


def _rays_in(chunks: int, per_launch: int, rays: int, chunk_rays: int) -> int:
    """Paths traced by the first ``chunks`` chunks of a run of launches of ``rays`` paths each."""
    g, c = divmod(chunks, per_launch)
    return g * rays + tracer.rays_in_chunks(rays, chunk_rays, 0, c)
