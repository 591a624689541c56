"""The launch face of the tracing kernels (``docs/kernel.md``, ``docs/gpu.md``): a run's kernel
call prepared once (:func:`prepare`, a :class:`Launch`: the stack's facts, the variant, the chunk
arithmetic) and launched per batch of chunks (:func:`launch`) on the kernel it picks -- the lane
kernel (the default on the CPU), the per-path kernel (``KERNEL_PATHS``, the tests' second
implementation) or the CUDA kernel (``device="cuda"``). Nothing else calls a kernel.

The transport every kernel traces is :mod:`goniometer.kernel.onepath`'s (its module docstring
states the rules; ``docs/material-format.md``, transport). The kernels' outputs per chunk:
histograms (n_theta, n_phi, K + 2, 3) of the exits by bounce order with their squares, the energy
terms (``E_*``, ``N_ENERGY``; per-path second moments for the first ``N_ENERGY_SQ``) and counters
(``C_*``, ``N_COUNTS``); a tabulation's exits per path (``P_TABULATE``).

The lane kernel (:func:`_trace_chunk`): a chunk's paths run in
:data:`~goniometer.kernel.layout.LANES` lanes advanced in lock-step; each step is one vectorised
event for every lane (:mod:`goniometer.kernel.event`; on a multiple-scattering interface the first
bounce of the walk; in a scattering medium a free flight and what it meets), then a pass over the
lanes that continues the walks that go on (:mod:`goniometer.kernel.steps`), books the paths that
ended and gives their lanes the next path of the chunk. Every path draws its own random numbers,
keyed by (seed, incident index, chunk, path) (:mod:`goniometer.kernel.rng`), so neither the lane a
path runs in nor the number of threads changes a result.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from goniometer.grids.halfdiff import cell_of as halfdiff_cell
from goniometer.grids.halfdiff import halfdiff_angles
from goniometer.kernel.codegen import STACK_BLOCK
from goniometer.kernel import polarized
from goniometer.kernel.deposit import BUFFER, X_COLS, flush, flush_mueller
from goniometer.kernel.event import RR_START, RR_THRESHOLD, step
from goniometer.kernel.layout import (A_AB, A_CP, A_MK, A_NCAP, A_NEV, A_RB, A_RE, A_RL, A_TR, C_CAPPED, C_EVENTS,
                                      E_ABSORBED, E_CAPPED, E_MASKING, E_REFLECTED, E_REFLECTED_WITHOUT_BASE,
                                      E_ROULETTE, E_TRANSMITTED, F_DX, F_DY, F_DZ, F_FRAME, F_LX, F_LY, F_LZ, F_MULTI, F_ORDER,
                                      F_MUELLER, F_PATH, F_STATUS, F_W0, F_W1, F_W2, LANES, N_COUNTS, N_ENERGY,
                                      N_ENERGY_SQ, N_FIELDS, N_FIELDS_POLARIZED, P_TABULATE, ST_DEAD, ST_REFLECTED, ST_SCALAR, ST_TRANSMITTED,
                                      stack_table)
from goniometer.kernel.packing import PackedStack
from goniometer.kernel.paths import trace_paths
from goniometer.kernel.rng import chunk_key
from goniometer.kernel.steps import continue_walk
from goniometer.kernel.variants import (KERNEL_AUTO, KERNEL_LANES, KERNEL_PATHS, Derived, KernelStack, StackFacts,
                                        Variant, derive, stack_facts, variant_flags)

__all__ = ["DeviceError", "check_device", "thread_count", "KERNEL_AUTO", "KERNEL_LANES", "KERNEL_PATHS",
           "Variant", "kernel_flags", "Launch", "prepare", "launch", "chunk_count", "rays_in_chunks",
           "E_REFLECTED", "E_TRANSMITTED", "E_ABSORBED", "E_MASKING", "E_REFLECTED_WITHOUT_BASE", "E_ROULETTE",
           "E_CAPPED", "N_ENERGY", "N_ENERGY_SQ", "C_CAPPED", "C_EVENTS", "N_COUNTS", "P_TABULATE", "RR_START",
           "RR_THRESHOLD"]


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


def kernel_flags(packed: PackedStack, height_correlated: bool, tabulate: bool, kernel: int = KERNEL_AUTO,
                 polarized: bool = False) -> Variant:
    """The kernel's :class:`~goniometer.kernel.variants.Variant` for a packed stack
    (:func:`goniometer.kernel.variants.variant_flags` of the stack's facts). ``kernel``:
    ``KERNEL_AUTO`` (the lane kernel), ``KERNEL_LANES`` or ``KERNEL_PATHS`` (the per-path kernel,
    :mod:`goniometer.kernel.paths`: the second implementation the tests check the lane kernel
    against, ``docs/kernel.md``); ``polarized``: a polarized run's. Two runs with equal variants
    (and light) run the same compiled kernel."""
    return variant_flags(stack_facts(packed), height_correlated, tabulate, kernel, polarized)


# ---------------------------------------------------------------------- chunk arithmetic

def chunk_count(n_rays: int, chunk_rays: int) -> int:
    """Chunks of ``n_rays`` rays: chunk ``c`` holds rays ``c * chunk_rays`` up to
    ``min((c + 1) * chunk_rays, n_rays)`` (``docs/architecture.md``, determinism)."""
    return -(-int(n_rays) // int(chunk_rays))


def rays_in_chunks(n_rays: int, chunk_rays: int, first_chunk: int, count: int) -> int:
    """Rays of chunks ``first_chunk .. first_chunk + count - 1`` of ``n_rays`` rays (0 past the
    last chunk)."""
    lo = min(int(first_chunk) * chunk_rays, n_rays)
    return max(0, min((int(first_chunk) + int(count)) * chunk_rays, n_rays) - lo)


# ---------------------------------------------------------------------- the launch seam

@dataclass(frozen=True, eq=False)
class Launch:
    """A run's kernel call, prepared once (:func:`prepare`) and launched per batch of chunks
    (:func:`launch`; ``docs/gpu.md``, the seam): the stack's facts, the variant, the light
    direction, the chunk arithmetic's numbers, the grid and its boundary tables, the device, and
    what the run derived from the stack for the kernels.

    ``stream`` is the incident index of the random keys (a tabulation's own stream); ``variant``
    the lane kernel's variant (:func:`kernel_flags`); ``tables`` the grid's boundary tables
    (:func:`goniometer.grids.slice_grid.boundary_tables`, or an RGL grid's kernel tables);
    ``derived`` the stack's facts as the kernels take them
    (:class:`~goniometer.kernel.variants.Derived`)."""

    facts: StackFacts
    variant: Variant
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
    device: str
    derived: Derived
    #: a polarized run's initial path state (:func:`goniometer.kernel.polarized.initial_state`; the
    #: incident beam's s/p frame), None for scalar light
    polar: np.ndarray | None = None

    @property
    def stack_args(self) -> KernelStack:
        """The kernels' ``stack`` argument (:data:`~goniometer.kernel.variants.KernelStack`): the
        packed arrays, then :attr:`derived`."""
        return KernelStack(*self.facts.packed.as_tuple(), *self.derived)

    def scalars(self, first_chunk: int) -> tuple:
        """The numbers of a batch starting at ``first_chunk``, as the kernels unpack them:
        ``(lx, ly, lz, first_chunk, seed, stream, param, n_theta, n_phi, max_order, event_cap,
        skip_first)``."""
        return (*self.light, int(first_chunk), self.seed, self.stream, self.param, self.n_theta, self.n_phi,
                self.max_order, self.event_cap, self.skip_first)

    @property
    def n_chunks(self) -> int:
        """Chunks of the run's ``n_rays`` (:func:`chunk_count`)."""
        return chunk_count(self.n_rays, self.chunk_rays)

    def chunk_sizes(self, first_chunk: int, count: int) -> np.ndarray:
        """Rays of each of chunks ``first_chunk .. first_chunk + count - 1`` (0 past the last): the
        kernels' ``sizes`` argument."""
        c = np.arange(first_chunk, first_chunk + count, dtype=np.int64)
        return np.clip(self.n_rays - c * self.chunk_rays, 0, self.chunk_rays)

    def rays_in(self, first_chunk: int, count: int) -> int:
        """Rays of chunks ``first_chunk .. first_chunk + count - 1`` (:func:`rays_in_chunks`)."""
        return rays_in_chunks(self.n_rays, self.chunk_rays, first_chunk, count)


def prepare(packed: PackedStack, light, n_rays: int, chunk_rays: int, seed: int, stream: int, param: int,
            n_theta: int, n_phi: int, tables: tuple, max_order: int, event_cap: int, skip_first: bool = False,
            height_correlated: bool = False, tabulate: bool = False, kernel: int = KERNEL_AUTO,
            device: str = "cpu", polarized: bool = False, phi_deg: float = 0.0) -> Launch:
    """The :class:`Launch` of a run: the stack's facts, the variant and the kernels' derived
    arguments worked out once. ``device``: ``"cpu"`` or ``"cuda"`` (:mod:`goniometer.kernel.cuda`,
    one kernel for every stack; ``kernel`` then must be ``KERNEL_AUTO``). ``polarized``: trace
    polarized light (``docs/polarization.md``), the incident beam's s/p frame taking its limit along
    the azimuth ``phi_deg`` at the normal (a tabulation's paths take their own), in either CPU
    kernel (the lane kernel by default)."""
    if device not in ("cpu", "cuda"):
        raise ValueError(f"device: {device!r}: the kernels trace on cpu or cuda")
    if device != "cpu" and kernel != KERNEL_AUTO:
        raise ValueError(f"kernel: a {device} launch has one kernel (KERNEL_AUTO), not {kernel!r}")
    facts = stack_facts(packed)
    variant = variant_flags(facts, height_correlated, tabulate, kernel, polarized)
    polar = None
    if polarized:
        from goniometer import optics
        from goniometer.kernel.polarized import initial_state
        phi = np.radians(phi_deg)
        frame = (0.0, 0.0, 0.0) if tabulate else optics.normal_frame(-light[0], -light[1], -light[2], -np.cos(phi),
                                                                      -np.sin(phi))
        polar = initial_state(frame)
    p = packed
    table, off = stack_table(p.if_alpha, p.if_rot, p.if_ms, facts.eta_dn, facts.eta_up, p.region_tau, p.region_albedo,
                             p.region_g, facts.tau_mode, facts.n_if, facts.conductor, p.if_film,
                             variant.film is not None)
    if device == "cpu" and variant.lanes is not None and table.shape[0] > STACK_BLOCK:   # the lane kernel's event
        raise ValueError(f"the stack's table ({table.shape[0]} numbers) does not fit the event's block "
                         f"({STACK_BLOCK}): too many layers")
    return Launch(facts, variant, (float(light[0]), float(light[1]), float(light[2])), int(n_rays), int(chunk_rays),
                  int(seed), int(stream), int(param), int(n_theta), int(n_phi), tuple(tables), int(max_order),
                  int(event_cap), bool(skip_first), device, derive(facts, table, off), polar)


def launch(run: Launch, first_chunk: int, outs: tuple, exits: tuple | None = None, parallel: bool = True,
           mueller: tuple | None = None) -> None:
    """Trace chunks ``first_chunk .. first_chunk + B - 1`` of ``run`` into ``outs`` = (brdf, btdf,
    energy, energy_sq, counts), each with a leading dimension B (one slot per chunk, zeroed here;
    the layouts of :func:`_trace_chunk`); ``exits`` = (exit_cell, exit_w) per path for a
    tabulation (None: none). On the CPU ``parallel`` runs the chunks on numba's threads (the
    caller sets their number), otherwise one after the other: the same bits. A ``"cuda"`` run
    traces on the GPU (:func:`goniometer.kernel.cuda.trace_batch`). ``mueller``: a polarized run's
    (mbrdf, mbtdf), (B, n_theta, n_phi, 32, 3) each (:func:`goniometer.kernel.paths.trace_paths`)."""
    B = outs[0].shape[0]
    if exits is None:
        exits = np.empty((B, 0), dtype=np.int64), np.empty((B, 0, 3))
    if (mueller is None) != (run.polar is None):
        raise ValueError("mueller: a polarized launch needs its Mueller histograms, a scalar one has none")
    if mueller is None:
        mueller = (np.empty((B, 0, 0, 0, 3)),) * 2
    sizes = run.chunk_sizes(first_chunk, B)
    if run.device == "cuda":
        check_device(run.device)
        from goniometer.kernel import cuda
        cuda.trace_batch(run, first_chunk, sizes, outs, exits, mueller if run.polar is not None else None)
        return
    kernel = _trace_batch if parallel else _trace_batch_serial
    kernel(run.stack_args, run.scalars(first_chunk), run.tables, sizes, *run.variant,
           tuple(outs) + tuple(exits) + tuple(mueller), run.polar)


@numba.njit(cache=True, error_model='numpy')
def _trace_chunk(stack, lx, ly, lz, n_rays, ckey, param, n_theta, n_phi, tables, max_order, event_cap, skip_first,
                height_correlated, tabulate, media, lambertian, conductor, g_is_r, b_is_g, aniso, ms, film, outs,
                polar=None):
    """Trace the ``n_rays`` paths of the chunk keyed ``ckey`` (:func:`goniometer.kernel.rng.chunk_key`)
    for light direction ``l`` and accumulate into the given arrays: the lane kernel.

    ``param`` is the slice parametrization (:data:`goniometer.grids.slice_grid.CLASSIC`, ``HALF``) or
    :data:`P_TABULATE`: then path ``r`` first draws its own light direction ``l`` with density
    ``cos theta_l / pi``, and its reflected exit, if any, is written to ``exit_cell[r]`` (MERL
    cell, -1 if none) and ``exit_w[r]`` (weight) instead of to ``brdf``; transmitted exits are
    booked in ``energy`` only. Otherwise ``exit_cell``/``exit_w`` are not touched (they may be empty).

    ``stack``: the packed stack's arrays and what the run derived from them once
    (:attr:`Launch.stack_args`, read by field name: the base, the stack table of
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

    ``polar``: None (scalar light), or a polarized run's initial path state
    (:func:`goniometer.kernel.polarized.initial_state`): the lanes then carry Mueller matrices
    (:func:`goniometer.kernel.event.step`) and ``outs`` has two more, ``mbrdf``/``mbtdf``, which
    take each exit's matrices in its exit frames as :func:`goniometer.kernel.paths.trace_paths`
    describes (a tabulation's reflected exit: ``mbrdf[r, 0]``, the "plane" frames of its MERL cell).

    Lane ``i`` traces paths ``i, i + LANES, ...``; its sums are kept per lane and added in lane
    order at the end, exits are deposited in the order they happen: the same bits for any
    number of threads.
    """
    if_alpha, if_rot, if_film, cond, rho, eta_dn, eta_up = (stack.if_alpha, stack.if_rot, stack.if_film, stack.cond,
                                                             stack.rho, stack.eta_dn, stack.eta_up)
    table, off, n_if, base_k = stack.table, stack.off, stack.n_if, stack.base_k
    transmit_base, conductor_base = stack.transmit_base, stack.conductor_base
    row_cos, col_cos, col_sin = tables
    brdf, btdf, energy, energy_sq, counts, exit_cell, exit_w, mbrdf, mbtdf = outs
    # every lane starts as if it had just ended a path of nothing (index i - LANES): the first step
    # books zeros and gives it path i
    S = np.zeros((N_FIELDS if polar is None else N_FIELDS_POLARIZED) * LANES)
    pw = np.zeros((4, 16)) if polar is not None else None
    mbuf = np.empty((BUFFER, 48)) if polar is not None else None
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
             conductor, g_is_r, b_is_g, aniso, ms, film, polar)
        # ---- per-lane pass: the walks that go on, then the exits of the paths that left the stack
        # at this step (lanes listed without branches, then visited; booked at the next step)
        if ms is not None:
            for i in range(LANES):
                if S[F_STATUS * LANES + i] == ST_SCALAR:
                    S[F_STATUS * LANES + i] = continue_walk(S, i, xs, if_alpha, if_rot, eta_dn, eta_up, cond,
                                                            stack.g_is_r, stack.b_is_g, n_if, transmit_base,
                                                            conductor_base, event_cap, film, if_film, pw)
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
            if polar is not None and tabulate is not None:
                # the exit's Mueller matrices in its exit frames (docs/polarization.md section 2)
                polarized.lane_load(S, i, LANES, F_MUELLER, F_FRAME, pw)
                polarized.to_exit(pw, S[F_DX * LANES + i], S[F_DY * LANES + i], S[F_DZ * LANES + i])
            if tabulate is not None:
                if not trans:
                    path = int(S[F_PATH * LANES + i])
                    plx = S[F_LX * LANES + i]
                    ply = S[F_LY * LANES + i]
                    plz = S[F_LZ * LANES + i]
                    dx = S[F_DX * LANES + i]
                    dy = S[F_DY * LANES + i]
                    dz = S[F_DZ * LANES + i]
                    exit_cell[path] = halfdiff_cell(plx, ply, plz, dx, dy, dz)
                    exit_w[path, 0] = S[F_W0 * LANES + i]
                    exit_w[path, 1] = S[F_W1 * LANES + i]
                    exit_w[path, 2] = S[F_W2 * LANES + i]
                    if polar is not None:
                        polarized.tabulated_exit(pw, plx, ply, plz, dx, dy, dz,
                                                 halfdiff_angles(plx, ply, plz, dx, dy, dz)[2] < 0.0, mbrdf[path, 0])
            elif not (skip_first and not trans and S[F_ORDER * LANES + i] == 1.0 and S[F_MULTI * LANES + i] == 0.0):
                xbuf[0, n_exit] = S[F_DX * LANES + i]
                xbuf[1, n_exit] = S[F_DY * LANES + i]
                xbuf[2, n_exit] = S[F_DZ * LANES + i]
                xbuf[3, n_exit] = S[F_W0 * LANES + i]
                xbuf[4, n_exit] = S[F_W1 * LANES + i]
                xbuf[5, n_exit] = S[F_W2 * LANES + i]
                xbuf[6, n_exit] = min(S[F_ORDER * LANES + i], max_order) - 1.0
                xbuf[7, n_exit] = 1.0 if trans else 0.0
                if polar is not None:
                    # its Mueller matrices in its exit frames (docs/polarization.md section 2), added
                    # where flush() puts its intensity (flush_mueller)
                    polarized.lane_exit(S, i, LANES, F_MUELLER, F_FRAME, S[F_DX * LANES + i], S[F_DY * LANES + i],
                                        S[F_DZ * LANES + i], mbuf, n_exit)
                n_exit += 1
                if n_exit == BUFFER:
                    flush(xbuf, n_exit, cell, sqo, param, lx, ly, lz, n_theta, n_phi, row_cos, col_cos, col_sin,
                          max_order, brdf, btdf)
                    if polar is not None:
                        flush_mueller(mbuf, xbuf, n_exit, cell, max_order, n_theta, n_phi, mbrdf, mbtdf)
                    n_exit = 0
        # (a lane whose path ended in its walk is booked at the next step; a lane is without paths
        # once its path index is past the chunk's)
        if live == 0:
            break
    if n_exit > 0:
        flush(xbuf, n_exit, cell, sqo, param, lx, ly, lz, n_theta, n_phi, row_cos, col_cos, col_sin, max_order,
              brdf, btdf)
        if polar is not None:
            flush_mueller(mbuf, xbuf, n_exit, cell, max_order, n_theta, n_phi, mbrdf, mbtdf)
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
def _trace_slot(b, stack, run, tables, sizes, lanes, height_correlated, tabulate, media, lambertian, conductor, g_is_r,
                b_is_g, aniso, ms, film, outs, polar):
    """Zero histogram slot ``b`` of ``outs`` and trace chunk ``first_chunk + b`` (``sizes[b]``
    rays) into it.

    ``stack``: the packed stack's arrays and what the run derived from them (:attr:`Launch.stack_args`); ``run``:
    the batch's numbers (:meth:`Launch.scalars`); ``tables``: the grid's ``(row_cos, col_cos,
    col_sin)``; ``sizes``: the rays of each chunk of the batch (:meth:`Launch.chunk_sizes`); ``outs``:
    ``(brdf, btdf, energy, energy_sq, counts, exit_cell, exit_w)``, each with a leading dimension B
    (:func:`_trace_chunk` gives the layouts). ``lanes`` .. ``film``: the variant (:func:`kernel_flags`),
    None or True each; they are arguments, not a tuple, because numba prunes the branch of a None
    *argument* and so compiles each variant without the others.

    Chunk ``c`` is keyed by ``(seed, incident_index, c)``: its paths' keys
    (:func:`goniometer.kernel.rng.chunk_key`, then ``path_key``) in every kernel: the lane kernel
    (``lanes`` True), the per-path kernel (``lanes`` None, :func:`goniometer.kernel.paths.trace_paths`).
    """
    lx, ly, lz, first_chunk, seed, incident_index, param, n_theta, n_phi, max_order, event_cap, skip_first = run
    slot = (outs[0][b], outs[1][b], outs[2][b], outs[3][b], outs[4][b], outs[5][b], outs[6][b])
    n = sizes[b]
    slot[0].fill(0.0)
    slot[1].fill(0.0)
    slot[2].fill(0.0)
    slot[3].fill(0.0)
    slot[4].fill(0)
    slot[5].fill(-1)
    outs[7][b].fill(0.0)
    outs[8][b].fill(0.0)
    if n <= 0:
        return
    ckey = chunk_key(np.uint64(seed), np.uint64(incident_index), np.uint64(first_chunk + b))
    if lanes is None:
        trace_paths(stack, lx, ly, lz, n, ckey, param, n_theta, n_phi, tables, max_order, height_correlated, film,
                    event_cap, skip_first, slot + (outs[7][b], outs[8][b]), polar)
    else:
        _trace_chunk(stack, lx, ly, lz, n, ckey, param, n_theta, n_phi, tables, max_order, event_cap, skip_first,
                     height_correlated, tabulate, media, lambertian, conductor, g_is_r, b_is_g, aniso, ms, film,
                     slot + (outs[7][b], outs[8][b]), polar)


@numba.njit(parallel=True, cache=True, error_model='numpy')
def _trace_batch(stack, run, tables, sizes, lanes, height_correlated, tabulate, media, lambertian, conductor, g_is_r,
                 b_is_g, aniso, ms, film, outs, polar):
    """Trace chunks ``first_chunk .. first_chunk + B - 1`` in parallel, one histogram slot each
    (:func:`_trace_slot`, which gives the arguments; :func:`launch` makes them from a
    :class:`Launch`). Output arrays carry a leading dimension B (the batch)."""
    for b in numba.prange(outs[0].shape[0]):
        _trace_slot(b, stack, run, tables, sizes, lanes, height_correlated, tabulate, media, lambertian, conductor,
                    g_is_r, b_is_g, aniso, ms, film, outs, polar)


@numba.njit(cache=True, error_model='numpy')
def _trace_batch_serial(stack, run, tables, sizes, lanes, height_correlated, tabulate, media, lambertian, conductor,
                        g_is_r, b_is_g, aniso, ms, film, outs, polar):
    """:func:`_trace_batch` without threads (same per-chunk results, bit for bit).

    For callers that are themselves run concurrently, e.g. the threads of a Dask worker: numba's
    default threading layer must not be entered by several threads at once.
    """
    for b in range(outs[0].shape[0]):
        _trace_slot(b, stack, run, tables, sizes, lanes, height_correlated, tabulate, media, lambertian, conductor,
                    g_is_r, b_is_g, aniso, ms, film, outs, polar)
