"""Bias table of pbrt-v4's layered BSDF rows against the goniometer (docs/pbrt-layered.md).

For coats like the database's (plastic P1 with alpha0 = 0.05, 0.2 and 0.3, metal M2) and for
Henyey-Greenstein coats, it simulates the stack with height-correlated masking (pbrt's reflection
masking ``1 / (1 + Lambda_o + Lambda_i)`` is that form) and integrates ``pbrt-layered`` (pbrt's
defaults), ``pbrt-layered-converged`` and ``pbrt-layered-fixed`` onto the same cells. Per material
and row it reports

* the internal directional albedo (the integral of the internal BRDF times cos over the
  hemisphere, three channels summed) of the row divided by the simulator's, at each incident angle;
* Bati 2019's eq. 4 RMSE of the internal part (channel mean) beside the reference's noise floor and
  the row's own (its standard errors through the same formula);
* the decomposition of pbrt's bias: the depth cap (``pbrt-layered`` / converged), the MIS density
  (converged / fixed), and the transmission-masking form (fixed / the fixed row with the exact
  height-correlated transmission masking, same random numbers);

then, from a quadrature, pbrt's masking against the exact one for a single crossing of the coat,
and the cost per cell of ``models.compare.integrate`` (5 x 5 sub-cells, one thread) for the rows
and ``belcour-fwd`` on the same file.

Writes ``benchmarks/results/<date>-<host>-pbrt-layered.json`` and prints the Markdown tables.
The default size (2 M rays per direction, 30 x 60 classic cells, 3 x 3 sub-cells, incident
0 / 45 / 70 degrees) takes about 10 minutes on two cores.

Usage: python benchmarks/bench_pbrt_layered.py [--rays N] [--resolution 30x60] [--subcells 3]
       [--only NAME,...] [--no-timing] [--out FILE]
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import socket
import time
from pathlib import Path

import numba
import numpy as np

from goniometer.optics import np_microfacet_transmission, np_ggx_lambda
from goniometer.run.loop import simulate
from goniometer.run.settings import SimulationSettings
from goniometer.grids.slice_grid import light_direction
from goniometer.stack import Interface, Lambertian, Medium, Stack
from models.compare import integrate, noise_floor, rmse
from models.compare import integrate
from models.pbrt_layered import PBRTLayered, PBRTLayeredConverged, PBRTLayeredFixed
from models.registry import get

HERE = Path(__file__).resolve().parent
INCIDENT = (0.0, 45.0, 70.0)
TAU_C = (0.05, 0.1, 0.4)
RHO_C = (0.2, 0.5, 0.8)
M2_BASE = Interface(0.2, (1.45,) * 3, (1.0, 0.01, 0.01))


def _plastic(alpha0: float) -> Stack:
    return Stack(f"plastic/P1-a0_{alpha0}", (Interface(alpha0, (1.5,) * 3), Medium(TAU_C), Lambertian(RHO_C)), "plastic")


MATERIALS = {
    "P1 a0 0.05": _plastic(0.05),
    "P1 a0 0.2": _plastic(0.2),
    "P1 a0 0.3": _plastic(0.3),
    "M2 a0 0.2 a1 0.2": Stack("metal/M2-a0_0.2-a1_0.2", (Interface(0.2, (1.5,) * 3), Medium(TAU_C), M2_BASE), "metal"),
    "M2 a0 0.05 a1 0.2": Stack("metal/M2-a0_0.05-a1_0.2", (Interface(0.05, (1.5,) * 3), Medium(TAU_C), M2_BASE),
                               "metal"),
    # Henyey-Greenstein coats: a smooth coat over an HG slab over M2's conductor; Bati 2019
    # appendix E (d = 2, g = 0.6, index-matched smooth top); a rough coat over an HG slab over P1's base
    "HG smooth coat, M2 base": Stack("hg/smooth-a0.8-g0.5", (Interface(0.0, (1.5,) * 3),
                                                            Medium((0.5,) * 3, (0.8,) * 3, 0.5), M2_BASE), "metal"),
    "HG appendix E d 2 g 0.6": Stack("hg/appendix-e-d_2-g_0.6", (Interface(0.0, (1.0,) * 3),
                                                                Medium((0.4, 0.4, 2.2), (0.5, 0.5, 1 / 1.1), 0.6),
                                                                Interface(0.2, (1.5,) * 3, (3.0, 0.0, 0.0))), "metal"),
    "HG rough coat 0.2, P1 base": Stack("hg/rough-a0.9-g0.3", (Interface(0.2, (1.5,) * 3),
                                                               Medium((0.5,) * 3, (0.9,) * 3, 0.3), Lambertian(RHO_C)),
                                        "plastic"),
}

ROWS = {"pbrt-layered": PBRTLayered, "pbrt-layered-converged": PBRTLayeredConverged,
        "pbrt-layered-fixed": PBRTLayeredFixed}


def _internal_albedo(values: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """Per incident direction, the three channels summed: sum over cells of f Omega_proj."""
    return (values * omega[:, None]).sum(axis=(1, 2, 3))


def _albedo_se(stderr: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """The standard error of :func:`_internal_albedo` (cells independent; channels counted as
    fully correlated, an upper bound)."""
    return np.sqrt(((stderr.sum(axis=1) * omega) ** 2).sum(axis=(1, 2)))


def material_rows(name: str, stack: Stack, rays: int, resolution: tuple[int, int], s: int) -> dict:
    t0 = time.perf_counter()
    ref = simulate(stack, SimulationSettings(incident_deg=INCIDENT, rays=rays, resolution=resolution, seed=7,
                                             masking="height-correlated"))
    sim_s = time.perf_counter() - t0
    sd = ref.brdf
    om, mask = sd.proj_solid_angle, sd.mask
    value = sd.orders[:, 1:].astype(np.float64).sum(axis=1)
    a_ref = _internal_albedo(value, om)
    se_ref = _albedo_se(sd.stderr_internal, om)
    nf_ref = float(np.mean(noise_floor(sd.stderr_internal, om, mask)))
    out = {"material": name, "stack": stack.to_dict(), "simulate_s": sim_s,
           "reference_internal_albedo": a_ref.tolist(), "reference_noise_floor": nf_ref, "rows": {}}
    albedos = {}
    for row, cls in ROWS.items():
        t0 = time.perf_counter()
        ms = integrate(cls(), ref, "brdf", s=s)
        dt_s = time.perf_counter() - t0
        a = _internal_albedo(ms.internal, om)
        se = _albedo_se(ms.stderr("internal"), om)
        albedos[row] = a
        out["rows"][row] = {
            "albedo_ratio": (a / a_ref).tolist(),
            "albedo_ratio_se": (a / a_ref * np.hypot(se / a, se_ref / a_ref)).tolist(),
            "rmse_internal": float(np.mean(rmse(value, ms.internal, om, mask))),
            "rmse_total": float(np.mean(rmse(sd.value, ms.total, om, mask))),
            "noise_floor_model": float(np.mean(noise_floor(ms.stderr("internal"), om, mask))),
            "integrate_s": dt_s,
        }
    exact = integrate(PBRTLayeredFixed(exact_transmission_masking=True), ref, "brdf", s=s)
    a_exact = _internal_albedo(exact.internal, om)
    out["exact_masking_fixed_albedo_ratio"] = (a_exact / a_ref).tolist()
    out["factors"] = {
        "depth_cap": (albedos["pbrt-layered"] / albedos["pbrt-layered-converged"]).tolist(),
        "mis_density": (albedos["pbrt-layered-converged"] / albedos["pbrt-layered-fixed"]).tolist(),
        "masking_form": (albedos["pbrt-layered-fixed"] / a_exact).tolist(),
    }
    return out


def masking_quadrature(alphas=(0.05, 0.2, 0.3), thetas=(0.0, 30.0, 45.0, 60.0, 70.0, 80.0), eta=1.5, n=600) -> list[dict]:
    """One crossing of the coat from air at theta: the transmitted fraction (integral of the flux
    BTDF times |cos| over the inside hemisphere) with pbrt's ``1 / (1 + Lambda_o + Lambda_i)``
    divided by the same with the exact height-correlated Beta function (and the separable G1 G1)."""
    t = (np.arange(n) + 0.5) / n * (np.pi / 2)
    p = (np.arange(2 * n) + 0.5) / (2 * n) * (2 * np.pi)
    T, P = np.meshgrid(t, p, indexing="ij")
    v = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), -np.cos(T)], axis=-1)
    dw = np.sin(T) * np.cos(T) * (np.pi / 2 / n) * (2 * np.pi / (2 * n))
    rows = []
    for a in alphas:
        for th in thetas:
            l = light_direction(th, 0.0)
            sep = np_microfacet_transmission(l[0], l[1], l[2], v[..., 0], v[..., 1], v[..., 2], a, a, eta, False)
            hc = np_microfacet_transmission(l[0], l[1], l[2], v[..., 0], v[..., 1], v[..., 2], a, a, eta, True)
            li = np_ggx_lambda(l[0], l[1], l[2], a, a)
            lo = np_ggx_lambda(v[..., 0], v[..., 1], v[..., 2], a, a)
            pbrt = sep * (1.0 + li) * (1.0 + lo) / (1.0 + li + lo)
            e_hc = float((hc * dw).sum())
            rows.append({"alpha": a, "theta_deg": th, "T_exact_hc": e_hc,
                         "pbrt_over_exact": float((pbrt * dw).sum()) / e_hc,
                         "separable_over_exact": float((sep * dw).sum()) / e_hc})
    return rows


def cost_per_cell(rays: int, repeats: int = 2) -> list[dict]:
    """Seconds per cell of ``models.compare.integrate`` (5 x 5 sub-cells, one thread, best of
    ``repeats`` after a warm-up) of belcour-fwd and the three rows on one file each."""
    numba.set_num_threads(1)
    rows = []
    for name in ("M2 a0 0.2 a1 0.2", "M2 a0 0.05 a1 0.2"):  # Belcour has no Lambertian base
        ref = simulate(MATERIALS[name], SimulationSettings(incident_deg=INCIDENT, rays=1000, resolution=(30, 60),
                                                           threads=1))
        cells = len(INCIDENT) * 30 * 60
        for model in (get("belcour-fwd"), *[get(n) for n in ROWS]):
            integrate(model, ref, "brdf", s=1)
            best = min(_timed(lambda: integrate(model, ref, "brdf", s=5)) for _ in range(repeats))
            rows.append({"model": model.name, "material": name, "cells": cells, "seconds": best,
                         "ms_per_cell": 1e3 * best / cells})
            print(f"integrate {model.name:24s} {name:18s} {1e3 * best / cells:8.4f} ms/cell (1 thread, 5 x 5 sub-cells)",
                  flush=True)
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    return rows


def _timed(fn) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def markdown(results: list[dict], masking: list[dict], cost: list[dict]) -> str:
    inc = " / ".join(f"{t:g}" for t in INCIDENT)
    lines = [f"| material | row | internal albedo / goniometer ({inc} deg; (n): standard error in 1e-3) | eq. 4 internal RMSE | "
             "noise floor (ref, row) |", "|---|---|---|---|---|"]
    for r in results:
        for row, d in r["rows"].items():
            ratios = " / ".join(f"{x:.3f}({round(1e3 * e):d})" for x, e in zip(d["albedo_ratio"], d["albedo_ratio_se"]))
            lines.append(f"| {r['material']} | `{row}` | {ratios} | {d['rmse_internal']:.2e} | "
                         f"{r['reference_noise_floor']:.1e}, {d['noise_floor_model']:.1e} |")
    lines += ["", f"| material | depth cap | MIS density | masking form | fixed, exact masking / goniometer |",
              "|---|---|---|---|---|"]
    for r in results:
        f = r["factors"]
        cols = [" / ".join(f"{x:.3f}" for x in f[k]) for k in ("depth_cap", "mis_density", "masking_form")]
        cols.append(" / ".join(f"{x:.3f}" for x in r["exact_masking_fixed_albedo_ratio"]))
        lines.append(f"| {r['material']} | " + " | ".join(cols) + " |")
    if masking:
        thetas = sorted({m["theta_deg"] for m in masking})
        lines += ["", "| alpha | " + " | ".join(f"{t:g} deg" for t in thetas) + " |",
                  "|---|" + "---|" * len(thetas)]
        for a in sorted({m["alpha"] for m in masking}):
            vals = [m for m in masking if m["alpha"] == a]
            lines.append(f"| {a:g} | " + " | ".join(f"{m['pbrt_over_exact']:.5f}" for m in vals) + " |")
    if cost:
        lines += ["", "| model | material | ms per cell (5 x 5 sub-cells, 1 thread) |", "|---|---|---|"]
        for c in cost:
            lines.append(f"| `{c['model']}` | {c['material']} | {c['ms_per_cell']:.4f} |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays", type=int, default=2_000_000, help="rays per incident direction (default 2M)")
    ap.add_argument("--resolution", default="30x60", help="classic cells n_theta x n_phi (default 30x60)")
    ap.add_argument("--subcells", type=int, default=3, help="sub-cells per cell side for the table (default 3)")
    ap.add_argument("--only", default="", help="comma-separated material names of the table (default all)")
    ap.add_argument("--no-timing", action="store_true", help="skip the cost-per-cell timings")
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    res = tuple(int(x) for x in args.resolution.lower().split("x"))
    names = [n for n in MATERIALS if not args.only or n in args.only.split(",")]
    t0 = time.perf_counter()
    results = []
    for name in names:
        results.append(material_rows(name, MATERIALS[name], args.rays, res, args.subcells))
        r = results[-1]
        print(f"{name:28s} " + "  ".join(f"{k} {np.round(v['albedo_ratio'], 3).tolist()}" for k, v in r["rows"].items()),
              flush=True)
    masking = masking_quadrature()
    cost = [] if args.no_timing else cost_per_cell(args.rays)
    doc = {"date": dt.date.today().isoformat(), "host": socket.gethostname(), "incident_deg": INCIDENT,
           "rays": args.rays, "resolution": res, "subcells": args.subcells, "masking": "height-correlated",
           "materials": results, "masking_quadrature": masking, "cost_per_cell": cost,
           "elapsed_s": time.perf_counter() - t0}
    out = args.out or HERE / "results" / f"{doc['date']}-{doc['host']}-pbrt-layered.json"
    out.write_text(json.dumps(doc, indent=1))
    print(markdown(results, masking, cost))
    print(f"\nwritten {out} ({doc['elapsed_s']:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
