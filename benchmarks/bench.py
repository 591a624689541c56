"""Throughput benchmark of the goniometer (`make bench`).

For a plastic, a metal and a slab of the database (alpha0 = 0.05, half slices, 7 incident
directions), the metal with multiple-scattering interfaces and a scattering medium (Bati 2019
appendix E), it measures rays per second of
wall time and rays per CPU-second (the stable figure on a shared machine), mean events per ray and
the kernel that traced it (``kernel``: lanes or paths), with 1 and 2 threads, compile time excluded; and the compile time
of the kernel from an empty numba cache (in a subprocess) and its load time from the cache.
For the plastic, metal and slab it also times the yardstick (``reference_kernel.py``: a plain
textbook kernel of the same physics, one thread) in the same run and reports the tracing speed
as a ratio to it (1-thread rows), and the noise floor per second of the whole simulate,
``1 / (noise floor^2 x CPU-s)`` (noise floor as in ``bench_accuracy.py``), of the side models are
judged on (internal BRDF, or BTDF) and of the whole BRDF; and, where it applies, the same whole
simulate with bounce order 1 integrated (``first_order = "integrated"``, docs/first-order.md).
Rows of ``kind = "rgl"``: recording on the RGL grid (``--parametrization rgl``) against a classic run
of the same rays, and the export's time. Rows of ``kind = "spectral"``: a 30-bin spectral run against
the RGB run of the same paths (CPU time per path, noise floor per CPU-second). Rows of
``kind = "polarized"``: a polarized run of the bench coated metal against its scalar run, the same
paths (CPU time per path; issue 33's goal is at most 4x, docs/polarization.md section 3). Writes ``benchmarks/results/<date>-<host>.json`` and prints
a table.

Usage: python benchmarks/bench.py [--rays-per-incident N] [--threads 1,2] [--out FILE] [--only-rgl] [--only-spectral]
       [--only-polarized]
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numba
import numpy as np

from goniometer.run.results import cell_geometry
from goniometer.run.settings import DEFAULT_INCIDENT, SimulationSettings
from goniometer.run.loop import simulate
from goniometer.run.tasks import warm_up
from goniometer.stack import Interface, Lambertian, Medium, Stack
from goniometer.kernel.packing import pack
from goniometer.kernel.tracer import kernel_flags
from goniometer.grids.slice_grid import light_direction

from models.compare import noise_floor, reference_parts
from reference_kernel import trace_reference

HERE = Path(__file__).resolve().parent
INCIDENT = DEFAULT_INCIDENT   # the paper's seven elevations
TAU_C = (0.05, 0.1, 0.4)

MATERIALS = {
    "plastic/P1-a0_0.05": Stack("plastic/P1-a0_0.05", (Interface(0.05, (1.5,) * 3), Medium(TAU_C),
                                                        Lambertian((0.2, 0.5, 0.8))), "plastic"),
    "metal/M2-a0_0.05-a1_0.2": Stack("metal/M2-a0_0.05-a1_0.2", (Interface(0.05, (1.5,) * 3), Medium(TAU_C),
                                                                  Interface(0.2, (1.45,) * 3, (1.0, 0.01, 0.01))), "metal"),
    "slab/S1-a0_0.05-a1_0.2": Stack("slab/S1-a0_0.05-a1_0.2", (Interface(0.05, (1.5,) * 3), Medium(TAU_C),
                                                                Interface(0.2, (1.0,) * 3)), "slab"),
}
#: materials timed against the yardstick kernel (``reference_kernel.py``)
YARDSTICK = ("plastic/P1-a0_0.05", "metal/M2-a0_0.05-a1_0.2", "slab/S1-a0_0.05-a1_0.2")
# the metal with multiple scattering on both interfaces (Heitz et al. 2016 random walks)
MATERIALS["metal/M2-a0_0.05-a1_0.2+ms"] = MATERIALS["metal/M2-a0_0.05-a1_0.2"].with_multiple_scattering()
# a scattering medium (Bati 2019 appendix E at d = 2, g = 0.8: sigma_s = (0.1, 0.1, 1), sigma_a = 0.1)
MATERIALS["metal/E-d_2-g_0.8"] = Stack("metal/E-d_2-g_0.8", (
    Interface(0.0, (1.0,) * 3), Medium((0.4, 0.4, 2.2), scattering_albedo=(0.5, 0.5, 1.0 / 1.1), g=0.8),
    Interface(0.2, (1.5,) * 3, (3.0, 0.0, 0.0))), "metal")


def floor_of(result) -> float:
    """Channel-mean noise floor of the side a model is judged on (internal BRDF, or BTDF)."""
    if result.stack.transmits:
        sd = result.btdf
        se = sd.stderr
    else:
        sd = result.brdf
        _, se = reference_parts(sd, internal=True)
    return float(np.mean(noise_floor(se, sd.proj_solid_angle, sd.mask)))


def total_floor_of(result) -> float:
    """Channel-mean noise floor of the whole BRDF (every bounce order: what a rendering sees)."""
    sd = result.brdf
    return float(np.mean(noise_floor(sd.stderr, sd.proj_solid_angle, sd.mask)))

def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def compile_times() -> dict[str, float]:
    """Seconds to compile the kernel into an empty cache, and to load it from that cache."""
    code = ("import time; t=time.perf_counter(); from goniometer.run.tasks import warm_up; warm_up(); "
            "print(time.perf_counter()-t)")
    with tempfile.TemporaryDirectory() as d:
        env = dict(os.environ, NUMBA_CACHE_DIR=d)
        cold = float(subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                                    check=True).stdout.strip())
        warm = float(subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                                    check=True).stdout.strip())
    return {"compile_s": cold, "cache_load_s": warm}


def run(rays_per_incident: int, threads: list[int]) -> list[dict]:
    """Per material and thread count: the tracing alone (all tasks of the 7 incident directions,
    histogram merging included) and the whole ``simulate`` call (plus cell solid angles, masks
    and the conversion to cell values)."""
    from goniometer.run.tasks import trace_incident
    warm_up()
    rows = []
    t_first = min(threads) if threads else None
    for name, stack in MATERIALS.items():
        yard = None
        if name in YARDSTICK:
            # the yardstick, one thread, the same rays and directions (compiled on the first call)
            trace_reference(stack, light_direction(INCIDENT[0]), 1000, 1, 90, 360)
            c0 = time.process_time()
            for m, th in enumerate(INCIDENT):
                trace_reference(stack, light_direction(th), rays_per_incident, 1, 90, 360, seed=1, incident_index=m)
            yard = rays_per_incident * len(INCIDENT) / (time.process_time() - c0)
            print(f"{name:28s} yardstick  tracing {yard / 1e6:5.2f} M rays/CPU-s (1 thread)", flush=True)
        # compile (or load) the kernel variant this stack needs, and the integrated first order's
        # cubature, outside the timed runs
        tiny = SimulationSettings(incident_deg=(30.0,), rays=2000, parametrization="half", threads=1)
        simulate(stack, tiny)
        if _integrable(stack):
            simulate(stack, tiny.with_overrides(first_order="integrated"))
        for t in threads:
            s = SimulationSettings(incident_deg=INCIDENT, rays=rays_per_incident, parametrization="half",
                                   threads=t, seed=1)
            n = rays_per_incident * len(INCIDENT)
            c0, w0 = time.process_time(), time.perf_counter()
            for m in range(len(INCIDENT)):
                trace_incident(stack, s, m)
            tcpu, twall = time.process_time() - c0, time.perf_counter() - w0
            cell_geometry.cache_clear()  # a single run computes its solid angles and masks
            c0, w0 = time.process_time(), time.perf_counter()
            r = simulate(stack, s)
            cpu, wall = time.process_time() - c0, time.perf_counter() - w0
            nf = floor_of(r)
            nft = total_floor_of(r)
            row = {
                "material": name, "threads": t, "rays": n, "first_order": "traced",
                "kernel": "lanes" if kernel_flags(pack(stack), False, False)[0] else "paths",
                "trace_wall_s": twall, "trace_cpu_s": tcpu,
                "trace_rays_per_s": n / twall, "trace_rays_per_cpu_s": n / tcpu,
                "simulate_wall_s": wall, "simulate_cpu_s": cpu,
                "rays_per_s": n / wall, "rays_per_cpu_s": n / cpu,
                "mean_events_per_ray": float(np.mean(r.mean_events)),
                "noise_floor": nf, "noise_floor_per_cpu_s": 1.0 / (nf * nf * cpu),
                "noise_floor_total": nft, "noise_floor_total_per_cpu_s": 1.0 / (nft * nft * cpu),
            }
            extra = ""
            if yard is not None and t == 1:
                row["yardstick_rays_per_cpu_s"] = yard
                row["trace_vs_yardstick"] = n / tcpu / yard
                extra = f"  {n / tcpu / yard:4.2f}x the yardstick"
            rows.append(row)
            print(f"{name:28s} threads={t}  tracing {n / twall / 1e6:5.2f} M rays/s wall, {n / tcpu / 1e6:5.2f} M rays/CPU-s;"
                  f"  whole simulate {n / wall / 1e6:5.2f} M rays/s wall, {n / cpu / 1e6:5.2f} M rays/CPU-s;"
                  f"  {row['mean_events_per_ray']:.2f} events/ray; 1/(nf^2 CPU-s) {row['noise_floor_per_cpu_s']:.3g}"
                  f" (total BRDF {row['noise_floor_total_per_cpu_s']:.3g}){extra}", flush=True)
        if t_first is not None and _integrable(stack):
            # the same whole simulate with bounce order 1 integrated (docs/first-order.md), one thread
            s = SimulationSettings(incident_deg=INCIDENT, rays=rays_per_incident, parametrization="half",
                                   threads=t_first, seed=1, first_order="integrated")
            cell_geometry.cache_clear()
            c0, w0 = time.process_time(), time.perf_counter()
            r = simulate(stack, s)
            cpu, wall = time.process_time() - c0, time.perf_counter() - w0
            nf, nft = floor_of(r), total_floor_of(r)
            traced = next(x for x in rows if x["material"] == name and x["threads"] == t_first)
            row = {"material": name, "threads": t_first, "rays": n, "first_order": "integrated",
                   "simulate_wall_s": wall, "simulate_cpu_s": cpu, "rays_per_s": n / wall, "rays_per_cpu_s": n / cpu,
                   "mean_events_per_ray": float(np.mean(r.mean_events)),
                   "noise_floor": nf, "noise_floor_per_cpu_s": 1.0 / (nf * nf * cpu),
                   "noise_floor_total": nft, "noise_floor_total_per_cpu_s": 1.0 / (nft * nft * cpu),
                   "total_per_cpu_s_vs_traced": 1.0 / (nft * nft * cpu) / traced["noise_floor_total_per_cpu_s"]}
            rows.append(row)
            print(f"{name:28s} threads={t_first}  first order integrated: whole simulate {n / cpu / 1e6:5.2f} M rays/CPU-s;"
                  f"  1/(nf^2 CPU-s) {row['noise_floor_per_cpu_s']:.3g} (total BRDF {row['noise_floor_total_per_cpu_s']:.3g},"
                  f" {row['total_per_cpu_s_vs_traced']:.3g}x traced)", flush=True)
    return rows


def bench_rgl(rays_per_incident: int, repeats: int = 5) -> list[dict]:
    """Recording on the RGL grid against a classic 90 x 360 run of the same rays and incident
    directions (the grid's 8 elevations), one thread, whole simulate, alternated ``repeats`` times
    (median ratio), and the export of the default-size file (docs/rgl-format.md)."""
    from goniometer.files.rgl_export import bsdf_fields
    from goniometer.grids.rgl import grid_for
    rows = []
    for name in ("metal/M2-a0_0.05-a1_0.2", "plastic/P1-a0_0.05"):
        stack = MATERIALS[name]
        grid = grid_for(stack)
        s_rgl = SimulationSettings.on_rgl_grid(grid, rays=rays_per_incident, threads=1, seed=1)
        s_cl = SimulationSettings(incident_deg=grid.incidents()[0], rays=rays_per_incident, threads=1, seed=1)
        warm_up(stack, s_rgl)
        warm_up(stack, s_cl)
        simulate(stack, SimulationSettings.on_rgl_grid(grid, rays=1000, threads=1))   # the grid's tables
        cpu = {"rgl": [], "classic": []}
        for _ in range(repeats):
            for kind, st in (("rgl", s_rgl), ("classic", s_cl)):
                cell_geometry.cache_clear()
                c0 = time.process_time()
                r = simulate(stack, st)
                cpu[kind].append(time.process_time() - c0)
                if kind == "rgl":
                    result = r
        ratios = sorted(a / b for a, b in zip(cpu["rgl"], cpu["classic"]))
        c0 = time.perf_counter()
        bsdf_fields(result)
        export_s = time.perf_counter() - c0
        n = rays_per_incident * len(grid.theta_i_deg)
        row = {"material": name, "kind": "rgl", "threads": 1, "rays": n, "grid": [len(grid.theta_i_deg), 1, grid.n],
               "rgl_rays_per_cpu_s": n / min(cpu["rgl"]), "classic_rays_per_cpu_s": n / min(cpu["classic"]),
               "rgl_vs_classic_cpu": ratios[len(ratios) // 2], "rgl_vs_classic_cpu_all": ratios, "export_s": export_s}
        rows.append(row)
        print(f"{name:28s} rgl grid 8x1x32: whole simulate {row['rgl_rays_per_cpu_s'] / 1e6:5.2f} M rays/CPU-s, "
              f"{row['rgl_vs_classic_cpu']:.3f}x the CPU time of classic 90x360 (median of {repeats} alternated "
              f"pairs); export {export_s:.1f} s", flush=True)
    return rows


def bench_spectral(rays_per_incident: int, repeats: int = 3, bins: int = 30) -> list[dict]:
    """A spectral run (``bins`` wavelength bins, three hero wavelengths per path, docs/spectral.md)
    of ``rays_per_incident`` paths per bin against the RGB run of the same stack and the same
    number of paths (``bins / 3`` times ``rays_per_incident``), one thread, half 90 x 360,
    7 incident directions, whole simulate, alternated ``repeats`` times (median ratio of CPU time
    per path); and the noise floor per CPU-second ``1 / (floor^2 x CPU-s)`` of both, the spectral
    run's taken in linear sRGB (``result.rgb()``, its standard errors an upper bound), of the whole BRDF."""
    from goniometer.stack import stack_from_dict
    gold = stack_from_dict({"name": "metal/Au-a0_0.2", "category": "metal", "layers": [
        {"type": "interface", "roughness": 0.2, "conductor": "Au"}]})
    rows = []
    for name, stack in (("metal/M2-a0_0.05-a1_0.2", MATERIALS["metal/M2-a0_0.05-a1_0.2"]), (gold.name, gold)):
        launches = bins // 3
        per_bin = rays_per_incident   # a user's --rays: paths per bin (the spectral run traces bins / 3 times more)
        common = dict(incident_deg=INCIDENT, parametrization="half", threads=1, seed=1)
        s_sp = SimulationSettings(rays=per_bin, spectral=True, wavelength_bins=bins, **common)
        s_rgb = SimulationSettings(rays=per_bin * launches, **common)
        warm_up(stack, s_sp)
        warm_up(stack, s_rgb)
        cpu = {"spectral": [], "rgb": []}
        res = {}
        for _ in range(repeats):
            for kind, st in (("spectral", s_sp), ("rgb", s_rgb)):
                c0 = time.process_time()
                res[kind] = simulate(stack, st)
                cpu[kind].append(time.process_time() - c0)
        ratios = sorted(a / b for a, b in zip(cpu["spectral"], cpu["rgb"]))
        n = per_bin * launches * len(INCIDENT)
        f_sp, f_rgb = total_floor_of(res["spectral"].rgb()), total_floor_of(res["rgb"])
        row = {"material": name, "kind": "spectral", "threads": 1, "paths": n, "wavelength_bins": bins,
               "spectral_paths_per_cpu_s": n / min(cpu["spectral"]), "rgb_paths_per_cpu_s": n / min(cpu["rgb"]),
               "spectral_vs_rgb_cpu_per_path": ratios[len(ratios) // 2], "spectral_vs_rgb_all": ratios,
               "noise_floor_spectral_srgb": f_sp, "noise_floor_rgb": f_rgb,
               "floor_per_cpu_s_spectral": 1.0 / (f_sp ** 2 * min(cpu["spectral"])),
               "floor_per_cpu_s_rgb": 1.0 / (f_rgb ** 2 * min(cpu["rgb"]))}
        rows.append(row)
        print(f"{name:28s} spectral {bins} bins: {row['spectral_paths_per_cpu_s'] / 1e6:5.2f} M paths/CPU-s, "
              f"{row['spectral_vs_rgb_cpu_per_path']:.3f}x the RGB run's CPU time per path (median of {repeats}); "
              f"noise floor per CPU-s {row['floor_per_cpu_s_spectral']:.3g} (sRGB of the bins) vs "
              f"{row['floor_per_cpu_s_rgb']:.3g} (RGB run)", flush=True)
    return rows


def bench_polarized(rays_per_incident: int, repeats: int = 3) -> list[dict]:
    """A polarized run (Mueller matrices, docs/polarization.md section 3) of the bench coated metal
    against its scalar run, ``rays_per_incident`` paths per incident direction each, one thread, half
    90 x 360, 7 incident directions, whole simulate (compile excluded: both warmed up first),
    alternated ``repeats`` times (median ratio of CPU time per path)."""
    name = "metal/M2-a0_0.05-a1_0.2"
    stack = MATERIALS[name]
    common = dict(rays=rays_per_incident, incident_deg=INCIDENT, parametrization="half", threads=1, seed=1)
    settings = {"polarized": SimulationSettings(polarized=True, **common), "scalar": SimulationSettings(**common)}
    for st in settings.values():
        warm_up(stack, st)
    cpu = {k: [] for k in settings}
    for _ in range(repeats):
        for kind, st in settings.items():
            c0 = time.process_time()
            simulate(stack, st)
            cpu[kind].append(time.process_time() - c0)
    ratios = sorted(a / b for a, b in zip(cpu["polarized"], cpu["scalar"]))
    n = rays_per_incident * len(INCIDENT)
    row = {"material": name, "kind": "polarized", "threads": 1, "paths": n,
           "polarized_paths_per_cpu_s": n / min(cpu["polarized"]), "scalar_paths_per_cpu_s": n / min(cpu["scalar"]),
           "polarized_vs_scalar_cpu_per_path": ratios[len(ratios) // 2], "polarized_vs_scalar_all": ratios}
    print(f"{name:28s} polarized: {row['polarized_paths_per_cpu_s'] / 1e6:5.2f} M paths/CPU-s, "
          f"{row['polarized_vs_scalar_cpu_per_path']:.2f}x the scalar run's CPU time per path (median of {repeats}; "
          f"scalar {row['scalar_paths_per_cpu_s'] / 1e6:.2f} M paths/CPU-s)", flush=True)
    return [row]


def _integrable(stack) -> bool:
    """True when ``first_order = "integrated"`` applies (a single-scattering interface on top)."""
    from goniometer.run.first_order import check_supported
    from goniometer.run.settings import SettingsError
    try:
        check_supported(stack)
    except SettingsError:
        return False
    return True


def bench_models(repeats: int = 3) -> list[dict]:
    """Seconds to integrate each model onto one material (7 incident directions, 90 x 360 cells,
    5 x 5 sub-cells) on one thread, after warm-up (best of ``repeats``)."""
    from models.compare import integrate
    from models.registry import all_models
    numba.set_num_threads(1)
    rows = []
    refs = {}
    for name in ("plastic/P1-a0_0.05", "metal/M2-a0_0.05-a1_0.2", "slab/S1-a0_0.05-a1_0.2"):
        st = MATERIALS[name]
        refs[name] = simulate(st, SimulationSettings(incident_deg=INCIDENT, rays=1000, parametrization="half", threads=1))
    for mname, model in all_models().items():
        if getattr(model, "stochastic", False):
            print(f"integrate {mname:16s} (stochastic: benchmarks/bench_pbrt_layered.py times it)", flush=True)
            continue
        for name, ref in refs.items():
            side = "btdf" if ref.stack.transmits else "brdf"
            if not model.supports(ref.stack) or side not in model.sides:
                continue
            integrate(model, ref, side)  # warm-up (compilation, tables)
            best = min(_timed(lambda: integrate(model, ref, side)) for _ in range(repeats))
            rows.append({"model": mname, "material": name, "seconds": best})
            print(f"integrate {mname:16s} on {name:28s} {best:6.2f} s (1 thread)", flush=True)
    return rows


def _timed(fn) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays-per-incident", type=int, default=1_500_000, help="7 incident directions each (default 1.5M: 10.5M rays per run)")
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--out", type=Path)
    ap.add_argument("--no-compile-time", action="store_true")
    ap.add_argument("--no-models", action="store_true", help="skip the model-integration timings")
    ap.add_argument("--only-rgl", action="store_true", help="only the RGL-grid rows")
    ap.add_argument("--only-spectral", action="store_true", help="only the spectral rows")
    ap.add_argument("--only-polarized", action="store_true", help="only the polarized row")
    args = ap.parse_args()
    threads = [int(x) for x in args.threads.split(",")]
    threads = [t for t in threads if t <= numba.config.NUMBA_NUM_THREADS]
    print(f"machine: {cpu_model()}, {os.cpu_count()} logical CPUs; numba {numba.__version__}")
    only = args.only_rgl or args.only_spectral or args.only_polarized
    ct = {} if args.no_compile_time or only else compile_times()
    if ct:
        print(f"kernel compile {ct['compile_s']:.1f} s, load from cache {ct['cache_load_s']:.2f} s")
    rows = [] if only else run(args.rays_per_incident, threads)
    if not (args.only_spectral or args.only_polarized):
        rows += bench_rgl(args.rays_per_incident)
    if not (args.only_rgl or args.only_polarized):
        rows += bench_spectral(args.rays_per_incident)
    if not (args.only_rgl or args.only_spectral):
        rows += bench_polarized(args.rays_per_incident)
    model_rows = [] if args.no_models or only else bench_models()
    host = socket.gethostname()
    out = args.out or HERE / "results" / f"{dt.date.today().isoformat()}-{host}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    doc = {
        "date": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"),
        "host": host, "cpu": cpu_model(), "logical_cpus": os.cpu_count(),
        "python": platform.python_version(), "numba": numba.__version__, "numpy": np.__version__,
        "incident_deg": list(INCIDENT), "parametrization": "half", "resolution": [90, 360],
        **ct, "results": rows, "model_integration": model_rows,
        "model_integration_note": "one material, 7 incident directions, 90x360 half cells, 5x5 sub-cells, 1 thread, after warm-up",
        "target_rays_per_cpu_s": 3.2e6,
        "target_note": "Bati 2019's C++/OpenMP simulator: 160 million rays per slice in 50 s on one core",
    }
    tmp = out.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(doc, indent=2))
    tmp.replace(out)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
