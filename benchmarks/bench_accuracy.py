"""Accuracy per second of the goniometer (`make bench`).

For the plastic, metal and slab of ``bench.py`` (half slices 90 x 360, 7 incident directions) it
simulates with several ray counts per direction and records the CPU time and the **noise floor**
of the comparison a model would be judged on (eq. 4 with the squared difference replaced by the
squared standard error, channel mean: internal paths for the plastic and the metal, the BTDF for
the slab; see ``models.compare.errors``). From these it reports

* the exponent of noise floor ~ rays^-b (Monte Carlo: b = 1/2; a clear departure would mean the
  standard errors are wrong or the cost per ray is not constant),
* the figure of merit ``1 / (noise_floor^2 x CPU seconds)`` (constant for an unbiased estimator
  whose cost is linear in the rays; higher is better),
* the noise floor and CPU time extrapolated to the database's qualities (``configs/bati2019.toml``:
  demo, quick, paper rays per slice).

Writes ``benchmarks/results/<date>-<host>-accuracy.json`` and prints a table.

Usage: python benchmarks/bench_accuracy.py [--rays 250000,1000000,4000000] [--out FILE]
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import socket
import time
import tomllib
from pathlib import Path

import numba
import numpy as np

from goniometer.run.results import cell_geometry
from goniometer.run.settings import SimulationSettings
from goniometer.run.loop import simulate
from goniometer.run.tasks import warm_up

from bench import INCIDENT, MATERIALS, cpu_model, floor_of

HERE = Path(__file__).resolve().parent
QUALITIES = tomllib.loads((HERE.parent / "configs" / "bati2019.toml").read_text())["quality"]


def run(rays: list[int]) -> list[dict]:
    warm_up()
    rows = []
    for name, stack in MATERIALS.items():
        points = []
        for n in rays:
            s = SimulationSettings(incident_deg=INCIDENT, rays=n, parametrization="half", seed=1)
            cell_geometry.cache_clear()
            c0 = time.process_time()
            r = simulate(stack, s)
            cpu = time.process_time() - c0
            nf = floor_of(r)
            points.append({"rays_per_incident": n, "cpu_s": cpu, "noise_floor": nf,
                           "figure_of_merit": 1.0 / (nf * nf * cpu)})
            print(f"{name:28s} {n:>11,} rays/direction  {cpu:7.1f} CPU-s (all directions)  noise floor {nf:.3e}  "
                  f"1/(nf^2 s) {points[-1]['figure_of_merit']:.3e}", flush=True)
        n_arr = np.array([p["rays_per_incident"] for p in points], dtype=float)
        nf_arr = np.array([p["noise_floor"] for p in points])
        cpu_arr = np.array([p["cpu_s"] for p in points])
        slope, intercept = np.polyfit(np.log(n_arr), np.log(nf_arr), 1)
        # CPU seconds per ray per direction, all directions together, from the largest run (fixed
        # costs -- solid angles, masks, assembly -- amortised best there)
        cpu_per_ray = float(cpu_arr[-1] / n_arr[-1])
        predicted = {q: {"rays_per_incident": int(nq), "noise_floor": float(np.exp(intercept) * nq ** slope),
                         "cpu_s_all_directions": cpu_per_ray * nq}
                     for q, nq in QUALITIES.items()}
        rows.append({"material": name, "points": points, "exponent": float(-slope), "predicted": predicted})
        print(f"{name:28s} noise floor ~ rays^-{-slope:.3f};  " + ", ".join(
            f"{q}: {p['noise_floor']:.2e} in {p['cpu_s_all_directions']:.0f} CPU-s" for q, p in predicted.items())
              + f" (all {len(INCIDENT)} directions)", flush=True)
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays", default="250000,1000000,4000000", help="rays per incident direction, comma-separated")
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    rays = [int(x) for x in args.rays.split(",")]
    if len(rays) < 2 or min(rays) <= 0:
        ap.error("--rays: at least two positive ray counts")
    print(f"machine: {cpu_model()}, {numba.config.NUMBA_NUM_THREADS} threads; numba {numba.__version__}")
    rows = run(rays)
    host = socket.gethostname().split(".")[0]
    out = args.out or HERE / "results" / f"{dt.date.today().isoformat()}-{host}-accuracy.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({
        "date": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"), "host": host, "cpu": cpu_model(),
        "threads": numba.config.NUMBA_NUM_THREADS, "incident_deg": list(INCIDENT), "parametrization": "half",
        "resolution": [90, 360], "qualities": QUALITIES, "results": rows,
    }, indent=2) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
