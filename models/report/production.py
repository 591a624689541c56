"""The production-coat report (``gonio production``, ``make production``; ``docs/production.md`` 7):
``summary.json``, ``configurations.json``, ``production.md`` and its figures, from a production
results directory (``configs/production.toml``).

The numbers come from :mod:`models.production` (measurement, split, fits, errors); this module only
writes them down and draws them.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from goniometer import atomic
from goniometer.files import slices as store
from models.production.study.fitting_formulas import SPLIT_SEED
from models.production.study.measure import BELCOUR, measure_results, result_files
from models.production.openpbr_coat import openpbr_parameters
from models.production.study.analysis import QUANTITIES, REFERENCE_SCATTERING, QuantityResult, run_study, summary_document
from models.report.files import write_json, write_text
from models.report.numbers import number
from models.report.panels import figure_png

FIGURES = {"darkening": "darkening.png", "roughening": "roughening.png", "roughening_ior": "roughening-vs-ior.png"}
UNITS = {"darkening": "darkening factor D (dimensionless)", "roughening": "effective base roughness (GGX alpha)"}


def _finite(x):
    """JSON-safe value: NaN/inf -> None, numpy scalars -> Python."""
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(float(x)) else None
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def _records(r: QuantityResult) -> list[dict]:
    s = r.samples
    out = []
    for i in range(len(s)):
        rec = {"name": s.names[i], "channel": s.channel[i], "scattering": s.scattering[i],
               "split": "heldout" if s.columns["heldout"][i] else "train"}
        rec.update({k: float(v[i]) for k, v in s.columns.items() if k != "heldout"})
        out.append(rec)
    return out


def _provenance(results_dir: Path) -> dict:
    manifest = {}
    try:
        manifest = json.loads((results_dir / "database.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        pass
    return {"results": str(results_dir.resolve()), "database": manifest.get("database"),
            "quality": manifest.get("quality"), "rays_per_slice": manifest.get("rays_per_slice")}


def scatter_figure(r: QuantityResult) -> bytes:
    """Effective (measured) against predicted, held-out reference configurations: spec, fitted, belcour-fwd."""
    from matplotlib.figure import Figure
    s = r.samples
    sel = (s.columns["heldout"] > 0) & np.array([x == REFERENCE_SCATTERING for x in s.scattering])
    y = s.columns["measured"][sel]
    fig = Figure(figsize=(6.2, 5.6))
    ax = fig.add_subplot(1, 1, 1)
    lo = 0.0
    hi = 1.05 * max(1e-6, float(np.nanmax(np.concatenate([y, s.columns["spec"][sel], s.columns["fitted"][sel]]))))
    ax.plot([lo, hi], [lo, hi], color="0.6", lw=1, label="prediction = reference")
    for key, label, style in (("spec", "OpenPBR 1.1 formula", dict(marker="o", color="tab:red", mfc="none")),
                              ("fitted", "fitted formula", dict(marker="s", color="tab:blue", mfc="none")),
                              ("belcour", BELCOUR, dict(marker="^", color="tab:green", mfc="none"))):
        x = s.columns[key][sel]
        ok = np.isfinite(x)
        if ok.any():
            e = np.sqrt(np.mean((x[ok] - y[ok]) ** 2))
            ax.plot(y[ok], x[ok], ls="none", ms=4, label=f"{label} (RMSE {e:.3f}, n = {ok.sum()})", **style)
    ax.set_xlim(lo, hi)
    ax.set_ylim(lo, hi)
    ax.set_xlabel(f"effective (reference, multiple scattering): {UNITS[r.quantity]}")
    ax.set_ylabel(f"predicted: {UNITS[r.quantity]}")
    ax.set_title(f"{r.quantity}: held-out coat indices, predicted vs effective")
    ax.legend(loc="upper left", fontsize=8)
    ax.grid(alpha=0.3)
    return figure_png(fig, tight=True)


def roughening_ior_figure(r: QuantityResult) -> bytes:
    """Effective roughness against the coat index, one colour per (coat, base) roughness, reference
    configurations (mean over the base metals); the fitted formula (solid) and OpenPBR 1.1 (dotted,
    flat in n) drawn over the whole index range."""
    import matplotlib
    from matplotlib.figure import Figure
    s = r.samples
    ref = np.array([x == REFERENCE_SCATTERING for x in s.scattering])
    c = s.columns
    fig = Figure(figsize=(7.5, 5.6))
    ax = fig.add_subplot(1, 1, 1)
    pairs = sorted({(a, b) for a, b in zip(c["coat_alpha"][ref], c["base_alpha"][ref])})
    cmap = matplotlib.colormaps["viridis"]
    n_all = c["coat_ior"][ref]
    grid = np.linspace(float(n_all.min()), float(n_all.max()), 60)
    held = sorted({float(x) for x in c["coat_ior"][ref & (c["heldout"] > 0)]})
    for j, (ac, ab) in enumerate(pairs):
        sel = ref & (c["coat_alpha"] == ac) & (c["base_alpha"] == ab)
        col = cmap(j / max(1, len(pairs) - 1))
        n = c["coat_ior"][sel]
        un = np.unique(n)
        mean = np.array([np.mean(c["measured"][sel][n == u]) for u in un])
        ax.plot(un, mean, "o", color=col, ms=4, label=f"alpha_coat {ac:g}, alpha_base {ab:g}")
        if r.fit is not None:
            X = {"coat_ior": grid, "base_alpha": np.full_like(grid, ab), "coat_alpha": np.full_like(grid, ac)}
            ax.plot(grid, r.fit.predict(X), "-", color=col, lw=1)
        ax.plot(grid, np.full_like(grid, np.mean(c["spec"][sel])), ":", color=col, lw=1)
    for h in held:
        ax.axvline(h, color="0.8", lw=6, zorder=0)
    ax.set_xlabel("coat index of refraction n (grey bands: held-out indices)")
    ax.set_ylabel("effective base roughness (GGX alpha)")
    ax.set_title("roughening vs coat index: reference (dots), fitted (solid), OpenPBR 1.1 (dotted)")
    ax.legend(fontsize=6, ncol=2, loc="upper left")
    ax.grid(alpha=0.3)
    return figure_png(fig, tight=True)


def _fmt(x, d=3) -> str:
    return number(x, f".{d}f", missing="-")


def _table_rows(r: QuantityResult, limit: int | None = None) -> list[str]:
    s = r.samples
    c = s.columns
    sel = [i for i in range(len(s)) if c["heldout"][i] and s.scattering[i] == REFERENCE_SCATTERING]
    if r.quantity == "darkening":
        head = ["| material | ch | n | E_base | effective D (+- se) | OpenPBR | fitted | belcour-fwd |",
                "|---|---|---|---|---|---|---|---|"]
        body = [f"| {s.names[i]} | {s.channel[i]} | {c['coat_ior'][i]:g} | {c['base_albedo'][i]:.3f} | "
                f"{c['measured'][i]:.3f} +- {c['stderr'][i]:.3f} | {c['spec'][i]:.3f} | {_fmt(c['fitted'][i])} | "
                f"{_fmt(c['belcour'][i])} |" for i in sel]
    else:
        head = ["| material | n | alpha_coat | alpha_base | effective alpha (+- se) | OpenPBR | fitted | belcour-fwd |",
                "|---|---|---|---|---|---|---|---|"]
        body = [f"| {s.names[i]} | {c['coat_ior'][i]:g} | {c['coat_alpha'][i]:g} | {c['base_alpha'][i]:g} | "
                f"{c['measured'][i]:.3f} +- {c['stderr'][i]:.3f}{' (clamped)' if c['clamped'][i] else ''} | "
                f"{c['spec'][i]:.3f} | {_fmt(c['fitted'][i])} | {_fmt(c['belcour'][i])} |" for i in sel]
    if limit is not None and len(body) > limit:
        body = body[:limit] + [f"| ... {len(body) - limit} more rows in configurations.json | | | | | | | |"]
    return head + body


def markdown(summary: dict, results: dict[str, QuantityResult]) -> str:
    """The report page."""
    split = summary["split"]
    lines = [
        "# Production coats: effective darkening and roughening against OpenPBR 1.1",
        "",
        f"Results: `{summary.get('results')}` (database `{summary.get('database')}`, quality "
        f"`{summary.get('quality')}`, {summary.get('rays_per_slice')} rays per incident direction). "
        f"{summary.get('n_measured')} coated materials measured. Definitions of every quantity: "
        "`docs/production.md`.",
        "",
        "Reference: configurations with **multiple-scattering interfaces** (energy-conserving, the "
        "behaviour a renderer with energy compensation should match); fits use them only. "
        f"Held-out coat indices (seed {split['seed']}): {', '.join(str(float(x)) for x in split['heldout_coat_ior'])}; "
        f"training: {', '.join(str(float(x)) for x in split['train_coat_ior'])}.",
        "",
        "## Summary (held-out configurations, RMSE in the quantity's own units)",
        "",
        "| quantity | units | n train | n held out | OpenPBR 1.1 | fitted | belcour-fwd (n) | OpenPBR / fitted on belcour's samples | noise (rms stderr) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for q in QUANTITIES:
        d = summary[q]
        b = "-" if d.get("belcour_rmse") is None else f"{d['belcour_rmse']:.4f} ({d['belcour_n']})"
        sb = ("-" if d.get("spec_rmse_belcour_samples") is None
              else f"{d['spec_rmse_belcour_samples']:.4f} / {d['fitted_rmse_belcour_samples']:.4f}")
        lines.append(f"| {q} | {d['units']} | {d['n_train']} | {d['n_heldout']} | {_fmt(d['spec_rmse'], 4)} | "
                     f"{_fmt(d['fitted_rmse'], 4)} | {b} | {sb} | {_fmt(d['noise_rms'], 4)} |")
    lr = summary["roughening"].get("belcour_lobe_alpha_rmse")
    if lr is not None:
        lines += ["", f"belcour-fwd's base-lobe roughness read directly from its variance statistics (lobe 1 at "
                  f"normal incidence, channel mean) has a held-out RMSE of {lr:.4f} against the effective "
                  "roughness (the table's belcour-fwd column reads its integrated lobe with the reference's "
                  "estimator)."]
    lines += ["", "Darkening samples are (material, colour channel) pairs: the coat is achromatic, so each "
              "channel is an independent base albedo. Roughening samples are coated conductors. belcour-fwd "
              "refuses Lambertian bases, so it is compared on the conductor samples only (the column beside "
              "it gives the two formulas on those same samples).", ""]
    lines += ["## The fitted formulas", "",
              "Inputs are OpenPBR's: `n` = `coat_ior`; `E_base` = `base_color * specular_weight` (metal) or "
              "`base_color` (diffuse); GGX alphas `alpha = r^2` of `coat_roughness` and `specular_roughness`.", ""]
    for q in QUANTITIES:
        d = summary[q]
        lines += [f"**{q}** (converged: {d['converged']}; training RMSE {_fmt(d['train'].get('fitted_rmse'), 4)}, "
                  f"OpenPBR on the training set {_fmt(d['train'].get('spec_rmse'), 4)}):", "", "```",
                  str(d["formula"]), "```", "", "coefficients: " + ", ".join(
                      f"`{k} = {v:.6g}`" for k, v in (d["coefficients"] or {}).items()), ""]
    lines += ["OpenPBR 1.1 for comparison: `D = (1 - K) / (1 - E_base K)`, `K = 1 - (1 - F0(n)) / n^2`; "
              "`alpha_eff^2 = min(1, alpha_base^2 + 2 alpha_coat^2)` (independent of n).", ""]
    lines += ["## By base and for single-scattering interfaces (held out)", "",
              "| quantity | subset | n | OpenPBR | fitted | belcour-fwd |", "|---|---|---|---|---|---|"]
    for q in QUANTITIES:
        d = summary[q]
        for base, e in d["heldout_by_base"].items():
            lines.append(f"| {q} | {base} (MS) | {e['n']} | {_fmt(e['spec_rmse'], 4)} | {_fmt(e['fitted_rmse'], 4)} | "
                         f"{_fmt(e.get('belcour_rmse'), 4)} |")
        e = d.get("single_scattering_heldout")
        if e:
            lines.append(f"| {q} | all bases (SS) | {e['n']} | {_fmt(e['spec_rmse'], 4)} | "
                         f"{_fmt(e['fitted_rmse'], 4)} | {_fmt(e.get('belcour_rmse'), 4)} |")
    lines += ["", "Single-scattering interfaces lose the energy of their inter-microfacet bounces; the formulas "
              "fitted on the multiple-scattering reference are applied to them unchanged.", ""]
    lines += ["## Figures", "",
              f"![darkening]({FIGURES['darkening']})", "",
              f"![roughening]({FIGURES['roughening']})", "",
              f"![roughening vs coat index]({FIGURES['roughening_ior']})", ""]
    for q in QUANTITIES:
        lines += [f"## Held-out configurations: {q}", ""] + _table_rows(results[q], limit=400) + [""]
    return "\n".join(lines)


def write_production_report(results_dir: str | Path, out_dir: str | Path, with_belcour: bool = True,
                            seed: int = SPLIT_SEED,
                            progress: Callable[[int, int, str], None] | None = None, jobs: int = 1) -> dict:
    """Measure, fit and write the report of ``results_dir`` into ``out_dir``; returns the summary.
    ``jobs``: worker processes that measure the materials side by side (:mod:`models.workers`; the
    summary is the same whatever ``jobs``)."""
    results_dir, out = Path(results_dir), Path(out_dir)
    measurements, missing = measure_results(results_dir, with_belcour=with_belcour, progress=progress, jobs=jobs)
    params = {}
    for path in result_files(results_dir):
        stack, _ = store.describe(path)
        if stack.name in {m.name for m in measurements}:
            params[stack.name] = openpbr_parameters(stack)
    results = run_study(measurements, params, seed=seed)
    extra = _provenance(results_dir)
    extra.update({"n_measured": len(measurements), "skipped_without_twin": missing,
                  "files": {"report": "production.md", "configurations": "configurations.json",
                            "figures": list(FIGURES.values())}})
    summary = _finite(summary_document(results, measurements, seed, extra))
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "configurations.json", _finite({q: _records(r) for q, r in results.items()}))
    atomic.write_bytes(out / FIGURES["darkening"], scatter_figure(results["darkening"]))
    atomic.write_bytes(out / FIGURES["roughening"], scatter_figure(results["roughening"]))
    atomic.write_bytes(out / FIGURES["roughening_ior"], roughening_ior_figure(results["roughening"]))
    write_text(out / "production.md", markdown(summary, results))
    write_json(out / "summary.json", summary)
    return summary


__all__ = ["write_production_report", "markdown", "scatter_figure", "roughening_ior_figure"]
