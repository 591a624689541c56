"""The appendix E section of a report (Bati 2019 appendix E, figures 16-17; ``configs/appendix-e.toml``):
the paper's two claims about Belcour's forward-scattering operator, stated with our numbers.

1. **"the best results are obtained for high values of g"** (the approximation holds for g > 0.7):
   at each depth d, the g at which ``belcour-fwd``'s error (total BRDF, Bati 2019 eq. 4, mean over
   R, G, B and the incident directions of the file) is lowest; the claim holds at d when that g is
   >= 0.7. g = 0 is outside the model's domain (g >= 0.1, ``docs/belcour.md``) and not compared.
2. **Bundles cannot "turn around" in the medium**: the fraction of the reflected energy that never
   reached the base, per d, g, incident elevation and channel: ``U / R`` from the simulator's
   per-path record (``/energy/reflected_without_base`` = U, a part of ``/energy/reflected`` = R;
   ``docs/slices-format.md``). Its standard error accounts for U and R coming from the same paths
   (per path U is either 0 or R, so their covariance is U's variance). Belcour's operator gives
   this light no energy at all (``R = 0`` in a medium).

:func:`appendix_e_section` returns the numbers (also written as ``appendix-e.json``) and
:func:`appendix_e_markdown` the text (``appendix-e.md``); :func:`build_report` calls them when
the results directory holds the appendix E database (``is_appendix_e``).
"""

from __future__ import annotations

import math
from collections import defaultdict

import h5py
import numpy as np

from models.report.numbers import number
from models.report.reproduction import verdict
from models.report.results import MaterialResult, ReportMaterial

MODEL = "belcour-fwd"
#: Bati 2019 appendix E: "the approximation in Belcour's model is only valid for g > 0.7"
G_VALID = 0.7
CHANNELS = ("R", "G", "B")


def is_appendix_e(materials: list[ReportMaterial]) -> bool:
    """Whether the materials include appendix E's metals (parameters d and g, category metal)."""
    return any(m.category == "metal" and "d" in m.params and "g" in m.params for m in materials)


def _energy(path) -> tuple[np.ndarray, ...] | None:
    """(theta, R, se_R, U, se_U) of a file; None when it predates the per-path record U."""
    with h5py.File(path, "r") as f:
        en = f["energy"]
        if "reflected_without_base" not in en:
            return None
        return (f["incident/theta_deg"][()], en["reflected"][()], en["reflected_stderr"][()],
                en["reflected_without_base"][()], en["reflected_without_base_stderr"][()])


def fraction_stderr(u: np.ndarray, su: np.ndarray, r: np.ndarray, sr: np.ndarray) -> np.ndarray:
    """Standard error of ``u / r`` when ``u`` is a part of ``r`` measured on the same paths (per
    path U is 0 or R, so cov(U, R) = var(U)): var(f) = ((1 - 2 f) var U + f^2 var R) / R^2 (delta
    method; the O(1/n) term of the covariance is dropped)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        f = u / r
        return np.sqrt(np.maximum((1.0 - 2.0 * f) * su**2 + f**2 * sr**2, 0.0)) / np.abs(r)


def appendix_e_section(results: list[MaterialResult]) -> dict:
    """The two claims' numbers from the evaluated appendix E metals ``results``."""
    metals = {(r.material.params["d"], r.material.params["g"]): r for r in results
              if r.material.category == "metal" and "d" in r.material.params and "g" in r.material.params}
    depths = sorted({d for d, _ in metals})
    # claim 1: belcour-fwd's error against g at each d
    claim1 = []
    for d in depths:
        rows = []
        for g in sorted(g for dd, g in metals if dd == d):
            ev = metals[(d, g)].evaluation["models"].get(MODEL)
            if ev is None:
                rows.append({"g": g, "evaluated": False})
                continue
            rows.append({"g": g, "evaluated": True, "total_rmse_mean": ev["total"]["rmse_mean"],
                         "internal_rmse_mean": ev["internal"]["rmse_mean"],
                         "total_noise_floor_mean": ev["total"]["noise_floor_mean"]})
        ok = [r for r in rows if r["evaluated"]]
        best = min(ok, key=lambda r: r["total_rmse_mean"]) if ok else None
        errs = [r["total_rmse_mean"] for r in ok]
        # the spread of the errors across g is below the reference's noise floor: not decided by this run
        noise = bool(ok) and max(r["total_noise_floor_mean"] for r in ok) >= max(errs) - min(errs)
        claim1.append({"d": d, "rows": rows, "best_g": best["g"] if best else None,
                       "holds": (best["g"] >= G_VALID) if best else None, "noise_limited": noise})
    n1 = [c for c in claim1 if c["holds"] is not None]
    # claim 2: reflected energy that never reached the base
    claim2, unrecorded = [], []
    for (d, g), r in sorted(metals.items()):
        e = _energy(r.material.path)
        if e is None:
            unrecorded.append(r.material.name)
            continue
        th, rm, sm, rb, sb = e
        se = fraction_stderr(rb, sb, rm, sm)
        with np.errstate(divide="ignore", invalid="ignore"):
            frac = rb / rm
            mean_frac = rb.mean(axis=1) / rm.mean(axis=1)
        for k, t in enumerate(th):
            claim2.append({"d": d, "g": g, "theta_deg": float(t), "reflected": rm[k].tolist(),
                           "never_reached_base": rb[k].tolist(), "fraction": frac[k].tolist(),
                           "fraction_stderr": se[k].tolist(), "fraction_mean": float(mean_frac[k])})
    return {"model": MODEL, "g_valid": G_VALID,
            "claim_best_g": {"paper": "at each d, belcour-fwd's error is lowest for g >= 0.7 "
                                      "(Bati 2019 appendix E: 'only valid for g > 0.7 ... best results for high g')",
                             "per_depth": claim1, "n": len(n1), "agree": sum(bool(c["holds"]) for c in n1),
                             "verdict": verdict(sum(bool(c["holds"]) for c in n1), len(n1))},
            "claim_turn_around": {"paper": "bundles cannot turn around in the medium: the blueish light reflected "
                                           "without reaching the red base is missing, more so toward grazing angles",
                                  "rows": claim2, "unrecorded": unrecorded}}


def _f(x: float, fmt: str = ".3e") -> str:
    return number(x, fmt)


def appendix_e_markdown(sec: dict) -> str:
    """The section as Markdown: a table per claim and the claims' verdicts with numbers."""
    c1, c2 = sec["claim_best_g"], sec["claim_turn_around"]
    out = ["# Bati 2019 appendix E: Belcour's forward scattering against the simulation\n",
           "Base: GGX conductor alpha = 0.2, eta = 1.5 + i(3, 0, 0); medium sigma_s = (0.1, 0.1, 1.0), "
           "sigma_a = 0.1, depth d, HG anisotropy g; smooth index-matched top (`configs/appendix-e.toml`).\n",
           f"## Claim 1: {c1['paper']}\n",
           f"Verdict: **{c1['verdict']}** ({c1['agree']} of {c1['n']} depths). Error: RMSE of Bati 2019 eq. 4 on "
           f"the total BRDF, mean over R, G, B and the file's incident directions; g = 0 is outside "
           f"belcour-fwd's domain (g >= 0.1). A depth is noise-limited when the noise floor of the reference "
           f"(the error a perfect model would show) exceeds the spread of the errors across g: its best g is not "
           f"decided by this run (more rays: quality `full`).\n"]
    gs = sorted({r["g"] for c in c1["per_depth"] for r in c["rows"]})
    out.append("| d | " + " | ".join(f"g = {g:g}" for g in gs) + " | best g | holds | noise floor | noise-limited |")
    out.append("|" + "---|" * (len(gs) + 5))
    for c in c1["per_depth"]:
        by_g = {r["g"]: r for r in c["rows"]}
        cells = []
        for g in gs:
            r = by_g.get(g)
            if r is None or not r["evaluated"]:
                cells.append("refused" if r is not None else "–")
            else:
                s = _f(r["total_rmse_mean"])
                cells.append(f"**{s}**" if g == c["best_g"] else s)
        nf = [r["total_noise_floor_mean"] for r in c["rows"] if r["evaluated"]]
        out.append(f"| {c['d']:g} | " + " | ".join(cells) +
                   f" | {_f(c['best_g'], 'g')} | {'yes' if c['holds'] else 'no' if c['holds'] is not None else '–'} "
                   f"| {_f(max(nf)) if nf else '–'} | {'yes' if c.get('noise_limited') else 'no'} |")
    out.append(f"\n## Claim 2: {c2['paper']}\n")
    rows = c2["rows"]
    if c2.get("unrecorded"):
        out.append(f"{len(c2['unrecorded'])} file(s) predate the per-path record `/energy/reflected_without_base` "
                   f"(re-simulate them): {', '.join(c2['unrecorded'][:5])}{' ...' if len(c2['unrecorded']) > 5 else ''}\n")
    if not rows:
        out.append("Not testable: no file records the light that never reached the base.\n")
        return "\n".join(out) + "\n"
    out.append("Fraction of the reflected energy carried by paths that never reached the base, "
               "`reflected_without_base / reflected` (the simulator's per-path record), per channel; belcour-fwd "
               "gives this light no energy (R = 0 in a medium), so this is energy it misses. ± is one standard "
               "error.\n")
    thetas = sorted({r["theta_deg"] for r in rows})
    summary = defaultdict(list)
    for r in rows:
        summary[(r["d"], r["g"])].append(r)
    out.append("Blue channel (the scattering one; sigma_s = 1.0):\n")
    out.append("| d | g | " + " | ".join(f"{t:g}°" for t in thetas) + " |")
    out.append("|" + "---|" * (len(thetas) + 2))
    for (d, g), rs in sorted(summary.items()):
        by_t = {r["theta_deg"]: r for r in rs}
        out.append(f"| {d:g} | {g:g} | " + " | ".join(
            f"{by_t[t]['fraction'][2]:.3f} ± {by_t[t]['fraction_stderr'][2]:.3f}" if t in by_t else "–"
            for t in thetas) + " |")
    out.append("\nMean over R, G, B (energy-weighted: mean of U over R, G, B / mean of R):\n")
    out.append("| d | g | " + " | ".join(f"{t:g}°" for t in thetas) + " |")
    out.append("|" + "---|" * (len(thetas) + 2))
    for (d, g), rs in sorted(summary.items()):
        by_t = {r["theta_deg"]: r for r in rs}
        out.append(f"| {d:g} | {g:g} | " + " | ".join(_f(by_t[t]["fraction_mean"], ".3f") if t in by_t else "–"
                                                     for t in thetas) + " |")
    lo, hi = thetas[0], thetas[-1]
    grazing = [(s[-1]["fraction_mean"], s[0]["fraction_mean"]) for s in
               (sorted(rs, key=lambda r: r["theta_deg"]) for rs in summary.values())]
    more = sum(a > b for a, b in grazing)
    fr = [r["fraction_mean"] for r in rows if math.isfinite(r["fraction_mean"])]
    blue = [r["fraction"][2] for r in rows if math.isfinite(r["fraction"][2])]
    out.append(f"\nOver all (d, g, angle): the missed fraction is {min(fr):.3f} to {max(fr):.3f} of the reflected "
               f"energy (channel mean), {min(blue):.3f} to {max(blue):.3f} in blue. It is larger at {hi:g}° than at "
               f"{lo:g}° for {more} of {len(grazing)} (d, g) materials (the paper: 'more problematic toward grazing "
               f"angles').\n")
    return "\n".join(out) + "\n"
