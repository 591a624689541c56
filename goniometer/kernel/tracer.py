"""The numba-parallel path-tracing kernel of the virtual goniometer.

Transport (``docs/material-format.md``, transport): a path starts above the top interface travelling along ``-l``
with weight (1, 1, 1). At an interface a microfacet normal is sampled from the visible
normals of the side the path comes from; a dielectric reflects with probability F (exact
Fresnel) and refracts otherwise, a conductor always reflects with weight *= F (RGB).
The weight is then multiplied by the masking term (separable: ``G1(o)``; height-correlated:
``G2 / G1(i)``) and an outgoing direction on the wrong side of the macro-surface ends the path
(``masking_loss``). On a multiple-scattering interface the event is instead a random walk on the
microsurface (:func:`goniometer.kernel.steps.microsurface_walk`, Heitz et al. 2016) that always leaves it: no masking loss. Absorbing media attenuate deterministically (Beer-Lambert); in a scattering
medium the path makes free flights between collisions (the lane kernel's event,
:mod:`goniometer.kernel.event`; the per-path kernel's :func:`goniometer.kernel.steps.free_flight`: spectral-MIS
distance sampling, Henyey-Greenstein directions). Lambertian bases reflect with cosine sampling
and weight *= rho. A path leaving the top upward is recorded in the BRDF
slice of its bounce order (number of events at the top layer); one leaving the bottom of a
transmitting stack downward in the BTDF slice.

Energy bookkeeping per channel and per path is exact: the weight a path loses is booked as
absorbed or masking loss, the weight it leaves with as reflected or transmitted; Russian
roulette books the weight it kills and the weight it adds (negative) in ``roulette``, and paths
stopped by the event cap book their weight in ``capped``. Hence, per chunk,
reflected + transmitted + absorbed + masking + roulette + capped = number of rays (to rounding).
A reflected path that never had an event at the base (the bottom layer) also books its weight in
``E_REFLECTED_WITHOUT_BASE`` (a part of reflected; ``docs/slices-format.md``, ``/energy``).

Kernel (``docs/kernel.md``): a chunk's paths run in :data:`~goniometer.kernel.layout.LANES`
lanes advanced in lock-step; each step is one vectorised event for every lane
(:mod:`goniometer.kernel.event`; on a multiple-scattering interface the first bounce of the
walk; in a scattering medium a free flight and what it meets), then a pass over the lanes that
continues the walks that go on (:mod:`goniometer.kernel.steps`), books the paths that ended and
gives their lanes the next path of the chunk. Every path draws its own random numbers, keyed by
(seed, incident index, chunk, path) (:mod:`goniometer.kernel.rng`), so neither the lane a path runs in
nor the number of threads changes a result. Kernel inputs are flat arrays (see
:class:`goniometer.kernel.packing.PackedStack`); outputs are per-chunk histograms.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from goniometer.grids.halfdiff import cell_of as halfdiff_cell
from goniometer.kernel.codegen import STACK_BLOCK
from goniometer.kernel.deposit import BUFFER, X_COLS, flush
from goniometer.kernel.event import RR_START, RR_THRESHOLD, step
from goniometer.kernel.layout import (A_AB, A_CP, A_MK, A_NCAP, A_NEV, A_RB, A_RE, A_RL, A_TR, C_CAPPED, C_EVENTS,
                                      E_ABSORBED, E_CAPPED, E_MASKING, E_REFLECTED, E_REFLECTED_WITHOUT_BASE,
                                      E_ROULETTE, E_TRANSMITTED, F_DX, F_DY, F_DZ, F_LX, F_LY, F_LZ, F_MULTI, F_ORDER,
                                      F_PATH, F_STATUS, F_W0, F_W1, F_W2, LANES, N_COUNTS, N_ENERGY, N_ENERGY_SQ,
                                      N_FIELDS, P_TABULATE, ST_DEAD, ST_REFLECTED, ST_SCALAR, ST_TRANSMITTED,
                                      TAU_SCATTER, stack_table)
from goniometer.kernel.paths import trace_paths
from goniometer.kernel.steps import continue_walk, free_flight, microsurface_walk
from goniometer.kernel.variants import KERNEL_AUTO, KERNEL_LANES, KERNEL_PATHS, StackFacts, stack_facts, variant_flags
from goniometer.kernel.rng import chunk_key, stream_state
from goniometer.kernel.packing import PackedStack

__all__ = ["trace_batch", "trace_batch_serial", "trace_chunk", "microsurface_walk", "free_flight",
           "E_REFLECTED", "E_TRANSMITTED", "E_ABSORBED", "E_MASKING", "E_REFLECTED_WITHOUT_BASE", "E_ROULETTE",
           "E_CAPPED", "N_ENERGY", "N_ENERGY_SQ", "C_CAPPED", "C_EVENTS", "N_COUNTS", "RR_START", "RR_THRESHOLD",
           "P_TABULATE", "TAU_SCATTER", "KERNEL_AUTO", "KERNEL_LANES", "KERNEL_PATHS",
           "kernel_flags", "DeviceError", "check_device", "thread_count", "Launch", "prepare", "launch",
           "no_exit_records"]

class DeviceError(ValueError):
    """What this machine cannot trace with (the message is one line, ``docs/gpu.md``): a device it
    lacks, or more numba threads than it has."""


def thread_count(threads: int | None) -> int:
    """The numba threads a run uses: ``threads``, or all of them (``NUMBA_NUM_THREADS``) for None."""
    return numba.config.NUMBA_NUM_THREADS if threads is None else int(threads)


def check_device(device: str, threads: int | None = None) -> None:
    """Raise :class:`DeviceError` when this machine cannot trace on ``device`` (one of
    :data:`goniometer.run.settings.DEVICES`) with ``threads``: ``"cuda"`` needs numba-cuda and a
    visible CUDA GPU, or numba-cuda's simulator (``NUMBA_ENABLE_CUDASIM=1``, for tests); the CPU at
    most numba's threads (``NUMBA_NUM_THREADS``)."""
    if threads is not None and not 1 <= threads <= numba.config.NUMBA_NUM_THREADS:
        raise DeviceError(f"threads: {threads} is outside [1, {numba.config.NUMBA_NUM_THREADS}] (the numba threads "
                          f"of this machine, NUMBA_NUM_THREADS)")
    if device != "cuda":
        return
    import importlib.util
    if importlib.util.find_spec("numba_cuda") is None:
        raise DeviceError("device: cuda needs numba-cuda (pip install 'goniometer[cuda]')")
    from numba import config, cuda
    if not config.ENABLE_CUDASIM and not cuda.is_available():
        raise DeviceError("device: cuda: no CUDA GPU is visible (numba.cuda.is_available() is False)")


def kernel_flags(packed: PackedStack, height_correlated: bool, tabulate: bool, kernel: int = KERNEL_AUTO) -> tuple:
    """The variant arguments of :func:`trace_batch` for a packed stack, each None or True:
    ``(lanes, height_correlated, tabulate, media, lambertian, conductor, g_is_r, b_is_g, aniso, ms, film)``
    (:func:`goniometer.kernel.variants.variant_flags` of the stack's facts). ``kernel``:
    ``KERNEL_AUTO`` (the lane kernel), ``KERNEL_LANES`` or ``KERNEL_PATHS`` (the per-path kernel,
    :func:`goniometer.kernel.paths.trace_paths`: the second implementation the tests check the lane
    kernel against, docs/kernel.md). numba dispatches on None versus bool, so each variant is
    compiled (and cached) only when some stack needs it."""
    return variant_flags(stack_facts(packed), height_correlated, tabulate, kernel)


# ---------------------------------------------------------------------- the launch seam

@dataclass(frozen=True, eq=False)
class Launch:
    """A run's kernel call, prepared once (:func:`prepare`) and launched per batch of chunks
    (:func:`launch`; ``docs/gpu.md``, the seam): the stack's facts and its packed arrays (in
    :data:`goniometer.kernel.packing.PackedStack.KERNEL_FIELDS` order), the variant, the light direction,
    the chunk arithmetic's numbers, the grid and its boundary tables, and the device.

    ``stream`` is the incident index of the random keys (a tabulation's own stream); ``flags``
    the variant (:func:`kernel_flags`); ``tables`` the grid's boundary tables
    (:func:`goniometer.grids.slice_grid.boundary_tables`, or an RGL grid's kernel tables)."""

    facts: StackFacts
    flags: tuple
    light: tuple
    n_rays: int
    chunk_rays: int
    seed: int
    stream: int
    param: int
    n_theta: int
    n_phi: int
    tables: tuple
    max_order: int
    event_cap: int
    skip_first: bool
    device: str = "cpu"

    #: what the run derives from the stack once for the CPU kernels (:func:`prepare`): the regions'
    #: modes, the relative indices, the lane kernel's stack table and the offset of its region part
    derived: tuple = ()

    @property
    def stack_args(self) -> tuple:
        """The kernels' ``stack`` argument: the packed stack's arrays in
        :data:`goniometer.kernel.packing.PackedStack.KERNEL_FIELDS` order, then :attr:`derived`
        (``tau_mode, eta_dn, eta_up, table, off``)."""
        return self.facts.packed.as_tuple() + self.derived

    def scalars(self, first_chunk: int) -> tuple:
        """The numbers of a batch starting at ``first_chunk``, as :func:`trace_slot` unpacks them:
        ``(lx, ly, lz, n_rays, chunk_rays, first_chunk, seed, stream, param, n_theta, n_phi,
        max_order, event_cap, skip_first)``."""
        return (*self.light, self.n_rays, self.chunk_rays, int(first_chunk), self.seed, self.stream, self.param,
                self.n_theta, self.n_phi, self.max_order, self.event_cap, self.skip_first)

    @property
    def n_chunks(self) -> int:
        """Chunks of the run's ``n_rays`` (chunk ``c``: rays ``c * chunk_rays`` up to
        ``min((c + 1) * chunk_rays, n_rays)``, as :func:`trace_slot` reads them)."""
        return -(-self.n_rays // self.chunk_rays)

    def chunk_sizes(self, first_chunk: int, count: int) -> np.ndarray:
        """Rays of chunks ``first_chunk .. first_chunk + count - 1`` (0 past the last)."""
        c = np.arange(first_chunk, first_chunk + count, dtype=np.int64)
        return np.clip(self.n_rays - c * self.chunk_rays, 0, self.chunk_rays)


def prepare(packed: PackedStack, light, n_rays: int, chunk_rays: int, seed: int, stream: int, param: int,
            n_theta: int, n_phi: int, tables: tuple, max_order: int, event_cap: int, skip_first: bool = False,
            height_correlated: bool = False, tabulate: bool = False, kernel: int = KERNEL_AUTO,
            device: str = "cpu") -> Launch:
    """The :class:`Launch` of a run: the stack's facts and the variant worked out once.
    ``device``: ``"cpu"`` or ``"cuda"`` (:mod:`goniometer.kernel.cuda`, one kernel for every stack;
    ``kernel`` then must be ``KERNEL_AUTO``)."""
    if device not in ("cpu", "cuda"):
        raise ValueError(f"device: {device!r}: the kernels trace on cpu or cuda")
    if device != "cpu" and kernel != KERNEL_AUTO:
        raise ValueError(f"kernel: a {device} launch has one kernel (KERNEL_AUTO), not {kernel!r}")
    facts = stack_facts(packed)
    flags = variant_flags(facts, height_correlated, tabulate, kernel)
    p = packed
    table, off = stack_table(p.if_alpha, p.if_rot, p.if_ms, facts.eta_dn, facts.eta_up, p.region_tau, p.region_albedo,
                             p.region_g, facts.tau_mode, facts.n_if, facts.conductor, p.if_film, flags[10] is not None)
    if device == "cpu" and flags[0] is not None and table.shape[0] > STACK_BLOCK:   # the lane kernel's event
        raise ValueError(f"the stack's table ({table.shape[0]} numbers) does not fit the event's block "
                         f"({STACK_BLOCK}): too many layers")
    return Launch(facts, flags, (float(light[0]), float(light[1]), float(light[2])), int(n_rays), int(chunk_rays),
                  int(seed), int(stream), int(param), int(n_theta), int(n_phi), tuple(tables), int(max_order),
                  int(event_cap), bool(skip_first), device, (facts.tau_mode, facts.eta_dn, facts.eta_up, table, off))


def no_exit_records(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Empty per-path exit records for ``n`` chunks of slices (:func:`trace_chunk` writes them only
    for a tabulation)."""
    return np.empty((n, 0), dtype=np.int64), np.empty((n, 0, 3))


def launch(run: Launch, first_chunk: int, outs: tuple, exits: tuple | None = None, parallel: bool = True) -> None:
    """Trace chunks ``first_chunk .. first_chunk + B - 1`` of ``run`` into ``outs`` = (brdf, btdf,
    energy, energy_sq, counts), each with a leading dimension B (one slot per chunk, zeroed here;
    the layouts of :func:`trace_chunk`); ``exits`` = (exit_cell, exit_w) per path for a
    tabulation (None: none). On the CPU ``parallel`` runs the chunks on numba's threads
    (:func:`trace_batch`; the caller sets their number), otherwise one after the other
    (:func:`trace_batch_serial`): the same bits. A ``"cuda"`` run traces on the GPU
    (:func:`goniometer.kernel.cuda.trace_batch`)."""
    if exits is None:
        exits = no_exit_records(outs[0].shape[0])
    if run.device == "cuda":
        check_device(run.device)
        from goniometer.kernel import cuda
        cuda.trace_batch(run, first_chunk, outs, exits)
        return
    kernel = trace_batch if parallel else trace_batch_serial
    kernel(run.stack_args, run.scalars(first_chunk), run.tables, *run.flags, tuple(outs) + tuple(exits))


@numba.njit(cache=True, error_model='numpy')
def trace_chunk(stack, lx, ly, lz, n_rays, ckey, param, n_theta, n_phi, tables, max_order, event_cap, skip_first,
                height_correlated, tabulate, media, lambertian, conductor, g_is_r, b_is_g, aniso, ms, film, outs):
    """Trace the ``n_rays`` paths of the chunk keyed ``ckey`` (:func:`goniometer.kernel.rng.chunk_key`)
    for light direction ``l`` and accumulate into the given arrays: the lane kernel.

    ``param`` is the slice parametrization (:data:`goniometer.grids.slice_grid.CLASSIC`, ``HALF``) or
    :data:`P_TABULATE`: then path ``r`` first draws its own light direction ``l`` with density
    ``cos theta_l / pi``, and its reflected exit, if any, is written to ``exit_cell[r]`` (MERL
    cell, -1 if none) and ``exit_w[r]`` (weight) instead of to ``brdf``; transmitted exits are
    booked in ``energy`` only. Otherwise ``exit_cell``/``exit_w`` are not touched (they may be empty).

    ``stack``: the packed stack's arrays and what the run derived from them once
    (:attr:`Launch.stack_args`: the regions' modes, relative indices, the stack table of
    :func:`goniometer.kernel.layout.stack_table` made for this variant's ``film``, and its offset);
    ``tables``: the grid's ``(row_cos, col_cos, col_sin)``; ``outs``: ``(brdf, btdf, energy,
    energy_sq, counts, exit_cell, exit_w)``.
    ``brdf``/``btdf``: (n_theta, n_phi, K + 2, 3) (:mod:`goniometer.kernel.deposit`); ``energy``:
    (N_ENERGY, 3) weight sums; ``energy_sq``: (N_ENERGY_SQ, 3) sums of squared per-path totals;
    ``counts``: (N_COUNTS,) int64. ``skip_first`` (bool): reflected exits of bounce order 1 are
    booked in ``energy`` but not deposited (``first_order = "integrated"``,
    :mod:`goniometer.run.first_order`). ``height_correlated`` .. ``ms``: None or True, the compiled
    variant (:func:`kernel_flags`, :func:`goniometer.kernel.event.step`); ``tabulate`` True goes
    with ``param`` = :data:`P_TABULATE`.

    Lane ``i`` traces paths ``i, i + LANES, ...``; its sums are kept per lane and added in lane
    order at the end, exits are deposited in the order they happen: the same bits for any
    number of threads.
    """
    (if_alpha, if_rot, if_ms, if_film, region_eta, region_tau, region_albedo, region_g, cond, rho, base_kind, tau_mode,
     eta_dn, eta_up, table, off) = stack
    row_cos, col_cos, col_sin = tables
    brdf, btdf, energy, energy_sq, counts, exit_cell, exit_w = outs
    n_if = region_eta.shape[0] - 1
    transmit_base = base_kind == 0
    conductor_base = base_kind == 1
    # conductor channels that share their complex index share their Fresnel value (walks)
    walk_g_is_r = cond[1] == cond[0] and cond[4] == cond[3]
    walk_b_is_g = cond[2] == cond[1] and cond[5] == cond[4]
    # the interface that is the base (the bottom layer), -1 when the base is Lambertian
    base_k = -1 if base_kind == 2 else n_if - 1
    # every lane starts as if it had just ended a path of nothing (index i - LANES): the first step
    # books zeros and gives it path i
    S = np.zeros(N_FIELDS * LANES)
    for i in range(LANES):
        S[F_STATUS * LANES + i] = ST_DEAD
        S[F_PATH * LANES + i] = i - LANES
    xs = np.zeros(4, dtype=np.uint64)
    xi = np.empty(LANES, dtype=np.int64)
    xbuf = np.empty((X_COLS, BUFFER))
    cell = np.empty(BUFFER, dtype=np.int64)
    sqo = np.empty(BUFFER, dtype=np.int64)
    ce0, ce1, ce2, ck0, ck1, ck2 = cond[0], cond[1], cond[2], cond[3], cond[4], cond[5]
    rho0, rho1, rho2 = rho[0], rho[1], rho[2]
    n_exit = 0
    while True:
        # ---- one vectorised step for every lane (book ended paths, start new ones, one event)
        step(S, table, off, n_if, transmit_base, base_k, ce0, ce1, ce2, ck0, ck1, ck2, rho0, rho1, rho2, event_cap,
             lx, ly, lz, ckey, n_rays, max_order, height_correlated, tabulate, media, lambertian,
             conductor, g_is_r, b_is_g, aniso, ms, film)
        # ---- per-lane pass: the walks that go on, then the exits of the paths that left the stack
        # at this step (lanes listed without branches, then visited; booked at the next step)
        if ms is not None:
            for i in range(LANES):
                if S[F_STATUS * LANES + i] == ST_SCALAR:
                    S[F_STATUS * LANES + i] = continue_walk(S, i, xs, if_alpha, if_rot, eta_dn, eta_up, cond,
                                                            walk_g_is_r, walk_b_is_g, n_if, transmit_base,
                                                            conductor_base, event_cap, film, if_film)
        live = 0
        n_x = 0
        for i in range(LANES):
            st = S[F_STATUS * LANES + i]
            xi[n_x] = i
            n_x += (st == ST_REFLECTED) | (st == ST_TRANSMITTED)
            live += S[F_PATH * LANES + i] < n_rays
        for q in range(n_x):
            i = xi[q]
            trans = S[F_STATUS * LANES + i] == ST_TRANSMITTED
            if tabulate is not None:
                if not trans:
                    path = int(S[F_PATH * LANES + i])
                    exit_cell[path] = halfdiff_cell(S[F_LX * LANES + i], S[F_LY * LANES + i], S[F_LZ * LANES + i],
                                                    S[F_DX * LANES + i], S[F_DY * LANES + i], S[F_DZ * LANES + i])
                    exit_w[path, 0] = S[F_W0 * LANES + i]
                    exit_w[path, 1] = S[F_W1 * LANES + i]
                    exit_w[path, 2] = S[F_W2 * LANES + i]
            elif not (skip_first and not trans and S[F_ORDER * LANES + i] == 1.0 and S[F_MULTI * LANES + i] == 0.0):
                xbuf[0, n_exit] = S[F_DX * LANES + i]
                xbuf[1, n_exit] = S[F_DY * LANES + i]
                xbuf[2, n_exit] = S[F_DZ * LANES + i]
                xbuf[3, n_exit] = S[F_W0 * LANES + i]
                xbuf[4, n_exit] = S[F_W1 * LANES + i]
                xbuf[5, n_exit] = S[F_W2 * LANES + i]
                xbuf[6, n_exit] = min(S[F_ORDER * LANES + i], max_order) - 1.0
                xbuf[7, n_exit] = 1.0 if trans else 0.0
                n_exit += 1
                if n_exit == BUFFER:
                    flush(xbuf, n_exit, cell, sqo, param, lx, ly, lz, n_theta, n_phi, row_cos, col_cos, col_sin,
                          max_order, brdf, btdf)
                    n_exit = 0
        # (a lane whose path ended in its walk is booked at the next step; a lane is without paths
        # once its path index is past the chunk's)
        if live == 0:
            break
    if n_exit > 0:
        flush(xbuf, n_exit, cell, sqo, param, lx, ly, lz, n_theta, n_phi, row_cos, col_cos, col_sin, max_order,
              brdf, btdf)
    # ---- the lanes' sums, in lane order
    for i in range(LANES):
        for c in range(3):
            energy[E_REFLECTED, c] += S[(A_RE + c) * LANES + i]
            energy_sq[E_REFLECTED, c] += S[(A_RE + 3 + c) * LANES + i]
            energy[E_REFLECTED_WITHOUT_BASE, c] += S[(A_RB + c) * LANES + i]
            energy_sq[E_REFLECTED_WITHOUT_BASE, c] += S[(A_RB + 3 + c) * LANES + i]
            energy[E_TRANSMITTED, c] += S[(A_TR + c) * LANES + i]
            energy_sq[E_TRANSMITTED, c] += S[(A_TR + 3 + c) * LANES + i]
            energy[E_ABSORBED, c] += S[(A_AB + c) * LANES + i]
            energy_sq[E_ABSORBED, c] += S[(A_AB + 3 + c) * LANES + i]
            energy[E_MASKING, c] += S[(A_MK + c) * LANES + i]
            energy_sq[E_MASKING, c] += S[(A_MK + 3 + c) * LANES + i]
            energy[E_ROULETTE, c] += S[(A_RL + c) * LANES + i]
            energy[E_CAPPED, c] += S[(A_CP + c) * LANES + i]
        counts[C_CAPPED] += int(S[A_NCAP * LANES + i])
        counts[C_EVENTS] += int(S[A_NEV * LANES + i])


@numba.njit(cache=True, error_model='numpy')
def trace_slot(b, stack, run, tables, lanes, height_correlated, tabulate, media, lambertian, conductor, g_is_r, b_is_g,
               aniso, ms, film, outs):
    """Zero histogram slot ``b`` of ``outs`` and trace chunk ``first_chunk + b`` into it.

    ``stack``: the packed stack's arrays and what the run derived from them (:attr:`Launch.stack_args`); ``run``:
    the batch's numbers (:meth:`Launch.scalars`); ``tables``: the grid's ``(row_cos, col_cos,
    col_sin)``; ``outs``: ``(brdf, btdf, energy, energy_sq, counts, exit_cell, exit_w)``, each with
    a leading dimension B (:func:`trace_chunk` gives the layouts). ``lanes`` .. ``film``: the
    variant (:func:`kernel_flags`), None or True each; they are arguments, not a tuple, because
    numba prunes the branch of a None *argument* and so compiles each variant without the others.

    Chunk ``c`` covers rays ``[c * chunk_rays, min((c + 1) * chunk_rays, n_rays_total))`` and
    is keyed by ``(seed, incident_index, c)``: its paths' keys (:func:`goniometer.kernel.rng.chunk_key`)
    for the lane kernel (``lanes`` True), its random stream (:func:`goniometer.kernel.rng.stream_state`)
    for the per-path kernel (``lanes`` None).
    """
    (lx, ly, lz, n_rays_total, chunk_rays, first_chunk, seed, incident_index, param, n_theta, n_phi, max_order,
     event_cap, skip_first) = run
    slot = (outs[0][b], outs[1][b], outs[2][b], outs[3][b], outs[4][b], outs[5][b], outs[6][b])
    c = first_chunk + b
    n = min(chunk_rays, n_rays_total - c * chunk_rays)
    slot[0].fill(0.0)
    slot[1].fill(0.0)
    slot[2].fill(0.0)
    slot[3].fill(0.0)
    slot[4].fill(0)
    slot[5].fill(-1)
    if n <= 0:
        return
    if lanes is None:
        state = stream_state(np.uint64(seed), np.uint64(incident_index), np.uint64(c))
        trace_paths(stack, lx, ly, lz, n, state, param, n_theta, n_phi, tables, max_order,
                    height_correlated is not None, event_cap, skip_first, slot)
    else:
        ckey = chunk_key(np.uint64(seed), np.uint64(incident_index), np.uint64(c))
        trace_chunk(stack, lx, ly, lz, n, ckey, param, n_theta, n_phi, tables, max_order, event_cap, skip_first,
                    height_correlated, tabulate, media, lambertian, conductor, g_is_r, b_is_g, aniso, ms, film, slot)


@numba.njit(parallel=True, cache=True, error_model='numpy')
def trace_batch(stack, run, tables, lanes, height_correlated, tabulate, media, lambertian, conductor, g_is_r, b_is_g,
                aniso, ms, film, outs):
    """Trace chunks ``first_chunk .. first_chunk + B - 1`` in parallel, one histogram slot each
    (:func:`trace_slot`, which gives the arguments; :func:`launch` makes them from a
    :class:`Launch`). Output arrays carry a leading dimension B (the batch)."""
    for b in numba.prange(outs[0].shape[0]):
        trace_slot(b, stack, run, tables, lanes, height_correlated, tabulate, media, lambertian, conductor, g_is_r,
                   b_is_g, aniso, ms, film, outs)


@numba.njit(cache=True, error_model='numpy')
def trace_batch_serial(stack, run, tables, lanes, height_correlated, tabulate, media, lambertian, conductor, g_is_r,
                       b_is_g, aniso, ms, film, outs):
    """:func:`trace_batch` without threads (same per-chunk results, bit for bit).

    For callers that are themselves run concurrently, e.g. the threads of a Dask worker: numba's
    default threading layer must not be entered by several threads at once.
    """
    for b in range(outs[0].shape[0]):
        trace_slot(b, stack, run, tables, lanes, height_correlated, tabulate, media, lambertian, conductor, g_is_r,
                   b_is_g, aniso, ms, film, outs)
