"""The CUDA kernel compiled for a GPU without one (``docs/gpu.md``, compiled in CI): PTX through
NVVM for a compute capability, ``ptxas -v``'s resource report (registers, spills, shared memory)
and the theoretical occupancy that follows.

Needs numba-cuda with its CUDA toolkit wheels (``pip install 'numba-cuda[cu12]'``: NVVM, and
``ptxas`` in the ``nvidia-cuda-nvcc`` wheel), not a driver or a GPU. The kernel compiled is the
real one: each variant's :func:`goniometer.kernel.cuda.kernel_source` with its launch bounds
(:func:`goniometer.kernel.cuda.kernel_options`), for the argument types of every launch the
simulator makes (:func:`launch_signatures`).

numba-cuda 0.30 asks the driver for the current device's compute capability when it compiles a
device function that a kernel calls (``CUDADispatcher.compile_device``), even when the kernel
itself is compiled for a given one (``numba.cuda.compile(..., cc=...)``); :func:`_compute_capability`
answers that question with the target's while a compile runs. It changes no code numba-cuda
generates: the PTX of the linked module is made for the target's architecture (``arch=sm_XX``).
(numba-cuda compiles a device function once per process and argument types, for the first
target asked; nothing the transport calls lowers differently for 8.0 and 9.0.)

NVVM gives the same PTX for 8.0 and 9.0, but for the ``.target`` line and the names numba makes
unique per compile (checked for every variant with numba-cuda 0.30.4; ``make test-slow`` checks one
again): :func:`compile_ptx` compiles each variant once, for :data:`BASE_CC`, and gives it to the
other architectures with their ``.target``, and ``ptxas`` assembles it for each.
"""

from __future__ import annotations

import contextlib
import functools
import re
import subprocess
import tempfile
from pathlib import Path

import numpy as np

#: the architectures the compile check builds for (the A100's and the H100's / H200's)
ARCHITECTURES = ((8, 0), (9, 0))
#: per multiprocessor (compute capabilities 8.0 and 9.0): registers, threads, resident blocks,
#: shared memory (bytes); the register file is allocated per warp in units of 256 registers
REGISTERS_PER_SM = 65536
THREADS_PER_SM = 2048
BLOCKS_PER_SM = 32
REGISTER_UNIT = 256
#: the most registers a thread may have (compute capabilities 8.0 and 9.0)
MAX_REGISTERS_PER_THREAD = 255
WARP = 32
SHARED_PER_SM = {(8, 0): 164 * 1024, (9, 0): 228 * 1024}
#: shared memory the CUDA runtime reserves per block (compute capability 8.0 and later)
SHARED_RESERVED = 1024
#: the compute capability each variant is compiled for by NVVM (module docstring)
BASE_CC = (8, 0)
#: an event cap for the launches compiled here (a value of the argument's type: any will do)
_CAP = 10_000


class BuildError(RuntimeError):
    """The kernel does not compile for a device, or its tools are missing (the message says which)."""


def ptxas_path() -> str | None:
    """``ptxas`` of the CUDA toolkit wheels (``nvidia-cuda-nvcc``), or of a CUDA installation
    (``cuda.pathfinder``); None where neither is found."""
    try:
        from cuda.pathfinder import find_nvidia_binary_utility
    except ImportError:
        return None
    return find_nvidia_binary_utility("ptxas")


@contextlib.contextmanager
def _compute_capability(cc: tuple[int, int]):
    """While it is entered, numba-cuda's compile of device functions takes ``cc`` for the current
    device's compute capability (module docstring)."""
    import numba.cuda.dispatcher as dispatcher

    class _Target:
        compute_capability = cc

    real = dispatcher.get_current_device
    dispatcher.get_current_device = lambda: _Target()
    try:
        yield
    finally:
        dispatcher.get_current_device = real


def launch_signatures() -> list[tuple[tuple, tuple]]:
    """``(variant, argument types)`` of every kind of launch the simulator makes
    (:func:`goniometer.kernel.cuda.trace_batch`): slices on the classic, half and RGL grids, with
    separable and height-correlated masking, stacks with and without films, transmitting and
    reflecting, order 1 integrated (scalar light), and a tabulation, each with scalar and
    polarized light; ``variant`` the kernel's ``(height_correlated, film, polarized)``, the types
    as :func:`numba.typeof` gives them; the distinct pairs, in a fixed order."""
    from numba import typeof

    from goniometer.grids.rgl import RGLGrid
    from goniometer.grids.slice_grid import CLASSIC, HALF, RGL, boundary_tables
    from goniometer.kernel import cuda, tracer
    from goniometer.kernel.packing import pack
    from goniometer.stack import Film, Interface, Lambertian, Medium, Stack

    stacks = (
        Stack("slab", (Interface(0.2, (1.5,) * 3), Medium((0.1, 0.2, 0.3), (0.9, 0.6, 0.3), 0.5),
                       Interface(0.3, (1.0,) * 3, multiple_scattering=True)), "slab"),
        Stack("metal", (Interface(0.2, (1.5,) * 3, roughness_y=0.1, rotation_deg=20.0,
                                  film=Film(300.0, (1.4,) * 3)), Medium((0.1, 0.2, 0.3)),
                        Interface(0.3, (0.2, 0.9, 1.3), (3.5, 2.5, 2.0))), "metal",
              wavelengths_nm=(450.0, 550.0, 650.0)),
        Stack("plastic", (Interface(0.2, (1.5,) * 3), Lambertian((0.5,) * 3)), "plastic"))
    rgl = RGLGrid(theta_i_deg=(0.0, 30.0), n=8)
    seen: dict[str, tuple] = {}
    for stack in stacks:
        p = pack(stack)
        for hc in (False, True):
            for pol in (False, True):
                def prepared(light, stream, param, n_theta, n_phi, tables, max_order, **kw):
                    return tracer.prepare(p, light, 100, 64, 1, stream, param, n_theta, n_phi, tables, max_order,
                                          _CAP, height_correlated=hc, device="cuda", polarized=pol, **kw)

                launches = [prepared((0.3, 0.0, 0.95), 0, param, 4, 8,
                                     boundary_tables("classic" if param == CLASSIC else "half", 4, 8), 3,
                                     skip_first=skip)
                            for param, skip in ((CLASSIC, False), (HALF, False), (CLASSIC, True))
                            if not (pol and skip)]   # (order 1 integrated is for scalar runs)
                launches.append(prepared((0.3, 0.0, 0.95), 0, RGL, rgl.n, rgl.n, rgl.kernel_tables(0), 3))
                launches.append(prepared((0.0, 0.0, 1.0), 9, tracer.P_TABULATE, 1, 1, boundary_tables("classic", 1, 1),
                                         1, tabulate=True))
                for run in launches:
                    B = 2
                    tab = run.param == tracer.P_TABULATE
                    cells = 2 * run.n_theta * run.n_phi * (run.max_order + 2) * 3
                    args, _, _ = cuda.kernel_args(run, 0, run.chunk_sizes(0, B), B, cells,
                                                  (B, run.chunk_rays) if tab else (B, 0))
                    key = (run.variant.height_correlated, run.variant.film, True if pol else None)
                    sig = tuple(typeof(a) for a in args)
                    seen.setdefault(str((key, sig)), (key, sig))
    return list(seen.values())


def compile_ptx(cc: tuple[int, int], variant: tuple, signature: tuple) -> str:
    """The PTX of the CUDA kernel's ``variant`` (``(height_correlated, film, polarized)``) for argument types
    ``signature`` and compute capability ``cc``: :data:`BASE_CC`'s (compiled once a process) with
    ``cc``'s ``.target`` (module docstring). Raises :class:`BuildError` if it does not compile."""
    ptx = _compiled_ptx(BASE_CC, variant, signature)
    base, target = f".target sm_{BASE_CC[0]}{BASE_CC[1]}", f".target sm_{cc[0]}{cc[1]}"
    if base not in ptx:
        raise BuildError(f"the PTX for sm_{BASE_CC[0]}{BASE_CC[1]} names no {base!r} to retarget to "
                         f"sm_{cc[0]}{cc[1]}")
    return ptx.replace(base, target, 1)


@functools.lru_cache(maxsize=None)
def _compiled_ptx(cc: tuple[int, int], variant: tuple, signature: tuple) -> str:
    """The PTX NVVM gives for ``cc`` itself (no GPU needed); :func:`compile_ptx` uses it for
    :data:`BASE_CC`, and the check that the other architectures' PTX is the same for the rest."""
    from numba import cuda

    from goniometer.kernel import cuda as kernel
    try:
        with _compute_capability(cc):
            ptx, _ = cuda.compile(kernel.kernel_source(*variant), signature, device=False, abi="numba", cc=cc,
                                  output="ptx", **kernel.kernel_options(*variant[1:]))
    except Exception as e:   # numba's typing and lowering errors, NVVM's
        raise BuildError(f"the CUDA kernel does not compile for sm_{cc[0]}{cc[1]}: {type(e).__name__}: {e}") from e
    return ptx


def ptxas_report(ptx: str, cc: tuple[int, int], ptxas: str | None = None) -> dict:
    """Assemble ``ptx`` for ``sm_XX`` with ``ptxas -v`` and read its report of the kernel entry:
    ``registers`` per thread, ``spill_bytes`` (spill stores plus loads), ``stack_bytes`` (the
    stack frame), ``shared_bytes`` (static shared memory). Raises :class:`BuildError` on an
    assembly error."""
    ptxas = ptxas or ptxas_path()
    if ptxas is None:
        raise BuildError("ptxas not found (pip install 'numba-cuda[cu12]' brings it)")
    arch = f"sm_{cc[0]}{cc[1]}"
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "kernel.ptx"
        src.write_text(ptx)
        r = subprocess.run([ptxas, f"-arch={arch}", "-v", str(src), "-o", str(Path(tmp) / "kernel.cubin")],
                           capture_output=True, text=True)
    out = r.stdout + r.stderr
    if r.returncode != 0:
        raise BuildError(f"ptxas -arch={arch} failed: {out.strip()[-2000:]}")
    return _entry_report(out, arch)


def _entry_report(out: str, arch: str) -> dict:
    """The kernel entry's figures in ``ptxas -v`` output (the entry is the function compiled as
    ``Compiling entry function``)."""
    m = re.search(r"Compiling entry function '([^']+)' for '" + arch + r"'(.*?)(?=Compiling entry function|\Z)",
                  out, re.S)
    if m is None:
        raise BuildError(f"ptxas -v reported no entry function for {arch}: {out.strip()[-2000:]}")
    text = m.group(2)

    def number(pattern: str) -> int:
        g = re.search(pattern, text)
        return int(g.group(1)) if g else 0

    stores = number(r"(\d+) bytes spill stores")
    loads = number(r"(\d+) bytes spill loads")
    return {"registers": number(r"Used (\d+) registers"), "spill_bytes": stores + loads,
            "stack_bytes": number(r"(\d+) bytes stack frame"), "shared_bytes": number(r"(\d+) bytes smem")}


def occupancy(registers: int, shared_bytes: int, cc: tuple[int, int], block: int) -> float:
    """Theoretical occupancy: resident threads per multiprocessor / 2048 for blocks of ``block``
    threads using ``registers`` per thread and ``shared_bytes`` of shared memory each. Resident
    blocks = the least of 2048 / block, 32, the register file's 65536 / (warps per block x
    registers per warp rounded up to 256), and the shared memory's ``SHARED_PER_SM`` / (shared
    bytes + 1 KiB reserved per block)."""
    warps = -(-block // WARP)
    per_warp = -(-registers * WARP // REGISTER_UNIT) * REGISTER_UNIT
    limits = [THREADS_PER_SM // block, BLOCKS_PER_SM, REGISTERS_PER_SM // max(1, warps * per_warp)]
    limits.append(SHARED_PER_SM[cc] // (shared_bytes + SHARED_RESERVED))
    return min(limits) * block / THREADS_PER_SM


#: the kernel's variants by name (``(height_correlated, film, polarized)``,
#: :func:`goniometer.kernel.cuda.kernel_source`)
VARIANT_NAMES = {(None, None, None): "separable", (True, None, None): "height-correlated", (None, True, None): "film",
                 (True, True, None): "height-correlated film", (None, None, True): "separable polarized",
                 (True, None, True): "height-correlated polarized", (None, True, True): "film polarized",
                 (True, True, True): "height-correlated film polarized"}


def variant_report(cc: tuple[int, int], variant: tuple, signature: tuple, ptxas: str | None = None) -> dict:
    """:func:`ptxas_report` of a variant for ``cc`` with its ``occupancy`` (:func:`occupancy` at the
    variant's launch bounds, :func:`goniometer.kernel.cuda.kernel_options`) and ``max_registers``
    (the registers the launch bounds allow a thread)."""
    from goniometer.kernel.cuda import kernel_options
    threads, blocks = kernel_options(*variant[1:])["launch_bounds"]
    r = ptxas_report(compile_ptx(cc, variant, signature), cc, ptxas)
    r["max_registers"] = min(MAX_REGISTERS_PER_THREAD, REGISTERS_PER_SM // (threads * blocks))
    r["occupancy"] = occupancy(r["registers"], r["shared_bytes"], cc, threads)
    return r


def build_report(architectures=ARCHITECTURES, ptxas: str | None = None, variants=None) -> dict:
    """Per architecture (``"sm_80"``, ``"sm_90"``): ``{"registers", "spill_bytes", "shared_bytes",
    "occupancy"}`` of the kernel over every launch signature (:func:`launch_signatures`): the most
    registers, spilled bytes and static shared memory, the least occupancy; and ``"variants"``,
    each variant's :func:`variant_report` by name (:data:`VARIANT_NAMES`). ``variants``: the keys
    (``(height_correlated, film, polarized)``) to compile, or None for all. Occupancy counts the
    static shared memory; a launch whose histograms sit in shared memory adds up to
    :data:`goniometer.kernel.cuda.SHARED_BYTES` of dynamic shared memory, within which the
    launch bounds' blocks still fit."""
    sigs = [(key, sig) for key, sig in launch_signatures() if variants is None or key in variants]
    report = {}
    for cc in architectures:
        per_variant = {}
        for key, sig in sigs:
            name = VARIANT_NAMES[key]
            while name in per_variant:   # (several argument types of one variant)
                name += "'"
            per_variant[name] = variant_report(cc, key, sig, ptxas)
        v = list(per_variant.values())
        report[f"sm_{cc[0]}{cc[1]}"] = {
            "registers": max(x["registers"] for x in v), "spill_bytes": max(x["spill_bytes"] for x in v),
            "shared_bytes": max(x["shared_bytes"] for x in v), "occupancy": min(x["occupancy"] for x in v),
            "variants": per_variant}
    return report
