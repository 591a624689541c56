"""The CUDA kernel beside the CPU kernel (``docs/gpu.md``): paths/s, events/s and histogram traffic
for the bench's materials (``bench.py``'s MATERIALS) on the classic 90 x 360 grid and on the MERL
grid (a tabulation: per-path light directions, exits as MERL cells).

    python benchmarks/bench_gpu.py [--rays N] [--json OUT]
    python benchmarks/bench_gpu.py --compile-only

Without numba-cuda or without a visible CUDA GPU it says so in one line and exits 2: it never
prints a number it did not measure (the simulator is not a GPU, so it is refused too).

``--compile-only`` needs no GPU: it compiles every variant of the kernel for sm_80 and sm_90
(NVVM, then ``ptxas -v``; ``goniometer.kernel.cuda_build``) and prints one JSON object keyed
``"sm_80"``, ``"sm_90"``, each ``{"registers", "spill_bytes", "shared_bytes", "occupancy"}`` (the
most registers, spilled bytes and static shared memory over the variants, the least occupancy:
resident threads per multiprocessor / 2048 at the variant's block size) and ``"variants"``, the same
per variant. Without numba-cuda or ptxas it says so in one line and exits 2.

Per material and grid: the CUDA kernel's wall time of one launch of ``--rays`` paths (after a
warm-up launch that compiles), the CPU lane kernel's on all numba threads for the same paths,
paths/s and events/s of each (events: the kernel's own count), and the CUDA launch's histogram
traffic: the bytes of the two fixed-point histograms per chunk, whether they sat in shared memory,
and an upper bound of the integer atomics on them (9 per exit, at most one exit per path).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numba
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from goniometer.run.settings import EVENT_CAP  # noqa: E402
from goniometer.kernel import tracer  # noqa: E402
from goniometer.grids.slice_grid import boundary_tables, light_direction  # noqa: E402
from goniometer.kernel.packing import pack  # noqa: E402


def refuse_without_gpu() -> None:
    if os.environ.get("NUMBA_ENABLE_CUDASIM") == "1":
        print("bench_gpu: error: NUMBA_ENABLE_CUDASIM=1 is the simulator, not a GPU: no numbers to measure",
              file=sys.stderr)
        sys.exit(2)
    try:
        tracer.check_device("cuda")
    except tracer.DeviceError as e:
        print(f"bench_gpu: error: {e}", file=sys.stderr)
        sys.exit(2)


def _outs(nb, res, K, transmits):
    bt = res if transmits else (1, 1)
    return (np.empty((nb,) + res + (K + 2, 3)), np.empty((nb,) + bt + (K + 2, 3)), np.empty((nb, tracer.N_ENERGY, 3)),
            np.empty((nb, tracer.N_ENERGY_SQ, 3)), np.empty((nb, tracer.N_COUNTS), dtype=np.int64))


def measure(stack, grid: str, rays: int, device: str, chunk_rays: int = 1 << 17) -> dict:
    K = 5
    p = pack(stack)
    nb = tracer.chunk_count(rays, chunk_rays)
    if grid == "merl":
        res = (1, 1)
        run = tracer.prepare(p, (0.0, 0.0, 1.0), rays, chunk_rays, 1, 9, tracer.P_TABULATE, 1, 1,
                             boundary_tables("classic", 1, 1), 1, EVENT_CAP, tabulate=True, device=device)
        K = 1
        exits = (np.empty((nb, chunk_rays), dtype=np.int64), np.empty((nb, chunk_rays, 3)))
    else:
        res = (90, 360)
        run = tracer.prepare(p, light_direction(45.0, 0.0), rays, chunk_rays, 1, 0, 0, *res,
                             boundary_tables("classic", *res), K, EVENT_CAP, device=device)
        exits = None
    outs = _outs(nb, res, K, stack.transmits)
    tracer.launch(run, 0, outs, exits)           # compile, first touch
    t0 = time.perf_counter()
    tracer.launch(run, 0, outs, exits)
    dt = time.perf_counter() - t0
    e = outs[2].sum(0)
    left = float(np.mean(e[tracer.E_REFLECTED] + e[tracer.E_TRANSMITTED]))  # weight, not paths: a rough gauge
    events = int(outs[4][:, tracer.C_EVENTS].sum())
    row = {"device": device, "grid": grid, "rays": rays, "seconds": dt, "paths_per_s": rays / dt,
           "events_per_s": events / dt, "events_per_path": events / rays}
    if device == "cuda":
        from goniometer.kernel.cuda import SHARED_BYTES
        hist_bytes = 2 * outs[0][0].size * 8
        row.update({"histogram_bytes_per_chunk": hist_bytes, "histograms_in_shared_memory": hist_bytes <= SHARED_BYTES,
                    "exit_weight_left": left, "histogram_atomics_upper_bound": 9 * rays if grid != "merl" else 0})
    return row


def compile_only() -> int:
    """Print the kernel's resources for sm_80 and sm_90 as one JSON object (module docstring)."""
    import importlib.util
    if importlib.util.find_spec("numba_cuda") is None:
        print("bench_gpu: error: --compile-only needs numba-cuda (pip install 'goniometer[cuda]')", file=sys.stderr)
        return 2
    from goniometer.kernel import cuda_build
    ptxas = cuda_build.ptxas_path()
    if ptxas is None:
        print("bench_gpu: error: --compile-only needs ptxas (pip install 'numba-cuda[cu12]')", file=sys.stderr)
        return 2
    try:
        report = cuda_build.build_report(ptxas=ptxas)
    except cuda_build.BuildError as e:
        print(f"bench_gpu: error: {e}", file=sys.stderr)
        return 1
    print(json.dumps(report, indent=1))
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays", type=int, default=1 << 22)
    ap.add_argument("--json")
    ap.add_argument("--compile-only", action="store_true",
                    help="compile the kernel for sm_80 and sm_90 and print its registers, spills, shared memory "
                         "and occupancy as JSON (no GPU needed)")
    args = ap.parse_args(argv)
    if args.compile_only:
        return compile_only()
    refuse_without_gpu()
    from bench import MATERIALS
    rows = []
    for name, stack in MATERIALS.items():
        for grid in ("classic", "merl"):
            if grid == "merl" and any(x.is_anisotropic for x in stack.interfaces):
                continue
            for device in ("cuda", "cpu"):
                r = measure(stack, grid, args.rays, device)
                r["material"] = name
                r["threads"] = numba.get_num_threads() if device == "cpu" else None
                rows.append(r)
                print(f"{name:32s} {grid:8s} {device:5s} {r['paths_per_s']:14,.0f} paths/s "
                      f"{r['events_per_s']:16,.0f} events/s", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
