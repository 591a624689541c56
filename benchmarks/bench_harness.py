"""Benchmark of the harness that judges the models (`make bench`; issue 34).

Rows:

* **evaluation**: seconds of ``models.evaluation.evaluate(reference, [model])`` -- the sub-cell
  directions and weights (shared: ``models.compare.cells``), the model's evaluation, the reduction
  onto the cells and the errors -- per model and per material, 7 incident directions, 90 x 360
  cells, 5 x 5 sub-cells, with 1 and 2 numba threads, best of ``--repeats`` after a warm-up (one
  run for a stochastic model; the first use in a process, which loads the model from numba's cache,
  is ``first_s``);
* **start-up**: seconds of whole ``gonio`` processes (best of ``--repeats``): ``--help``,
  ``models``, ``info FILE``, ``evaluate FILE --model ww09``;
* **files**: the bytes of a slices file and of a report cache entry as written now, against the
  same data written the way they were before issue 34 (HDF5's own chunks, no shared arrays): the
  ratio.

The materials are simulated here at a small ray count (the evaluation's cost does not depend on
it): a plastic, a metal and a slab of the database at alpha0 = 0.05 (half slices) and a metal at
alpha0 = 0.2 (classic slices). Writes ``benchmarks/results/<date>-<host>-harness.json`` and prints a
table.

Usage: python benchmarks/bench_harness.py [--repeats 3] [--rays 200000] [--out FILE]
"""

from __future__ import annotations

import argparse
import datetime as dt
import io
import json
import os
import platform
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numba
import numpy as np

import goniometer as g
from goniometer.stack import Interface, Lambertian, Medium, Stack

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
INCIDENT = (0.0, 15.0, 30.0, 45.0, 60.0, 70.0, 80.0)
TAU_C = (0.05, 0.1, 0.4)
MATERIALS = {
    "plastic/P1-a0_0.05": (Stack("plastic/P1-a0_0.05", (Interface(0.05, (1.5,) * 3), Medium(TAU_C),
                                                         Lambertian((0.2, 0.5, 0.8))), "plastic"), "half"),
    "metal/M2-a0_0.05-a1_0.2": (Stack("metal/M2-a0_0.05-a1_0.2", (Interface(0.05, (1.5,) * 3), Medium(TAU_C),
                                                                   Interface(0.2, (1.45,) * 3, (1.0, 0.01, 0.01))),
                                      "metal"), "half"),
    "metal/M4-a0_0.2-a1_0.2": (Stack("metal/M4-a0_0.2-a1_0.2", (Interface(0.2, (1.5,) * 3), Medium((0.2,) * 3),
                                                                 Interface(0.2, (1.45,) * 3, (1.0, 0.01, 0.01))),
                                     "metal"), "classic"),
    "slab/S1-a0_0.05-a1_0.2": (Stack("slab/S1-a0_0.05-a1_0.2", (Interface(0.05, (1.5,) * 3), Medium(TAU_C),
                                                                 Interface(0.2, (1.0,) * 3)), "slab"), "half"),
}


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def simulate_files(tmp: Path, rays: int) -> dict[str, Path]:
    """The benchmark's materials, simulated into ``tmp`` (quick: their values do not matter)."""
    paths = {}
    for name, (stack, param) in MATERIALS.items():
        p = tmp / (name.replace("/", "_") + ".h5")
        s = g.SimulationSettings(incident_deg=INCIDENT, rays=rays, resolution=(90, 360), parametrization=param,
                                 seed=1)
        g.write(p, g.simulate(stack, s))
        paths[name] = p
    return paths


def bench_evaluation(paths: dict[str, Path], repeats: int) -> list[dict]:
    """One row per (material, model, threads): ``seconds`` (best of ``repeats``) and ``first_s``."""
    from goniometer.files import slices as store
    from models import registry
    from models.evaluation import comparison_side, evaluate
    rows = []
    threads_max = numba.config.NUMBA_NUM_THREADS
    for name, path in paths.items():
        ref = store.read(path)
        side = comparison_side(ref.stack)
        for mname, model in registry.all_models().items():
            if model.on_request or side not in model.sides or model.reason(ref.stack) is not None:
                continue
            first = None
            for threads in (1, 2):
                if threads > threads_max:
                    continue
                numba.set_num_threads(threads)
                times = []
                n = 1 if model.cost_note(1) is not None else repeats   # a stochastic model: one run (seconds each)
                for k in range(n + (1 if first is None else 0)):
                    t = time.perf_counter()
                    evaluate(ref, [mname])
                    times.append(time.perf_counter() - t)
                if first is None:
                    first, times = times[0], times[1:]
                row = {"material": name, "model": mname, "threads": threads, "seconds": min(times), "first_s": first,
                       "stochastic": model.cost_note(1) is not None}
                rows.append(row)
                print(f"evaluate {mname:24s} on {name:26s} {threads} thread(s): {row['seconds']:6.3f} s "
                      f"(first use {first:.2f} s)", flush=True)
            numba.set_num_threads(threads_max)
    return rows


def bench_start_up(paths: dict[str, Path], repeats: int) -> list[dict]:
    """Whole ``gonio`` processes, best of ``repeats`` (after one run that fills the caches)."""
    gonio = [sys.executable, "-m", "goniometer.cli"]
    metal = str(paths["metal/M4-a0_0.2-a1_0.2"])
    commands = {"gonio --help": ["--help"], "gonio models": ["models"], "gonio info FILE": ["info", metal],
                "gonio evaluate FILE --model ww09": ["evaluate", metal, "--model", "ww09"]}
    rows = []
    for label, argv in commands.items():
        times = []
        for _ in range(repeats + 1):
            t = time.perf_counter()
            subprocess.run(gonio + argv, check=True, capture_output=True, cwd=ROOT)
            times.append(time.perf_counter() - t)
        rows.append({"command": label, "seconds": min(times[1:]), "file": "metal/M4-a0_0.2-a1_0.2 (7 x 90 x 360)"})
        print(f"{label:36s} {rows[-1]['seconds']:.2f} s", flush=True)
    return rows


def _old_layout_bytes(groups: dict[str, np.ndarray], level: int) -> int:
    """The bytes of ``groups`` written as before issue 34: HDF5's own chunks, gzip ``level`` + shuffle,
    every array its own dataset."""
    buf = io.BytesIO()
    with h5py.File(buf, "w") as f:
        for k, a in groups.items():
            f.create_dataset(k, data=a, chunks=True, compression="gzip", compression_opts=level, shuffle=True)
    return len(buf.getvalue())


def _arrays(path: Path) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}

    def visit(name, obj) -> None:
        if isinstance(obj, h5py.Dataset) and obj.ndim >= 3:
            out[name] = obj[()]
    with h5py.File(path, "r") as f:
        f.visititems(visit)
    return out


def bench_files(paths: dict[str, Path], tmp: Path) -> list[dict]:
    """Bytes now and as before, for each slices file and for the report cache of one metal."""
    from goniometer.files import slices as store
    from models.report.evaluation import _save_cache, run_evaluation
    rows = []
    for name, path in paths.items():
        arrays = _arrays(path)
        now = sum(h5py.File(path, "r")[k].id.get_storage_size() for k in arrays)
        before = _old_layout_bytes(arrays, 4)
        rows.append({"file": f"slices {name}", "bytes": now, "bytes_before": before, "ratio": now / before})
        print(f"slices {name:28s} {now / 1e6:6.2f} MB, before {before / 1e6:6.2f} MB: {now / before:.2f}", flush=True)
    name = "metal/M2-a0_0.05-a1_0.2"
    ref = store.read(paths[name])
    doc, slices = run_evaluation(ref, None, 5)
    h5 = tmp / "cache.h5"
    _save_cache(tmp / "cache.json", h5, {"key": "bench"}, slices)
    with h5py.File(h5, "r") as f:   # every link: arrays stored once are several models' datasets
        arrays = {f"{m}/{part}": f[m][part][()] for m in f for part in f[m]}
    now = h5.stat().st_size
    before = _old_layout_bytes(arrays, 4)
    rows.append({"file": f"report cache {name} ({len(slices)} models)", "bytes": now, "bytes_before": before,
                 "ratio": now / before})
    print(f"report cache {name} {now / 1e6:6.2f} MB, before {before / 1e6:6.2f} MB: {now / before:.2f}", flush=True)
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--rays", type=int, default=200_000, help="rays per incident direction of the simulated files")
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    print(f"machine: {cpu_model()}, {os.cpu_count()} logical CPUs; numba {numba.__version__}; "
          f"load {os.getloadavg()[0]:.2f}")
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        paths = simulate_files(tmp, args.rays)
        evaluation = bench_evaluation(paths, args.repeats)
        start_up = bench_start_up(paths, args.repeats)
        files = bench_files(paths, tmp)
    host = socket.gethostname()
    out = args.out or HERE / "results" / f"{dt.date.today().isoformat()}-{host}-harness.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    doc = {
        "date": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"),
        "host": host, "cpu": cpu_model(), "logical_cpus": os.cpu_count(), "load_avg_before": list(load_before),
        "load_avg_after": list(os.getloadavg()), "python": platform.python_version(), "numba": numba.__version__,
        "numpy": np.__version__, "incident_deg": list(INCIDENT), "resolution": [90, 360], "subcells": 5,
        "evaluation": evaluation, "start_up": start_up, "files": files,
        "evaluation_note": "models.evaluation.evaluate(reference, [model]): sub-cells, model, reduction, errors; "
                           "best of repeats after the first use (first_s)",
        "target_note": "issue 34: <= 0.3 s per analytic model per 7-direction material at 90x360, 5x5 sub-cells; "
                       "gonio evaluate FILE --model ww09 <= 1 s",
    }
    tmp_out = out.with_suffix(".json.tmp")
    tmp_out.write_text(json.dumps(doc, indent=2))
    tmp_out.replace(out)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
