"""The report's error tables and figure-4 plots: one record per (material, model) for
``errors.json``, per-category CSV and Markdown tables, and the per-category plots of the
channel-mean RMSE in the manner of Bati 2019, figure 4 (``docs/report.md``, outputs)."""

from __future__ import annotations

import csv
import io
import json
import math

import numpy as np

from models import registry
from models.report.numbers import number
from models.report.panels import DPI
from models.report.results import (PARAM_KEYS, PARAM_LABELS, MaterialResult, material_sort_key,
                                   param_text)


def error_records(results: list[MaterialResult]) -> list[dict]:
    """One record per (material, evaluated model): material, category, paper_name, parameters,
    model, side, internal, total (the error objects of ``gonio evaluate --json``) and ``not_drawn``,
    the material's figures that could not be drawn (``[{"material", "figure", "reason"}]``, empty
    when all were: the errors never depend on the figures)."""
    out = []
    for r in results:
        m = r.material
        for model, errs in r.evaluation["models"].items():
            rec = {"material": m.name, "category": m.category, "paper_name": m.paper_name}
            for k in PARAM_KEYS:
                if k in m.params:
                    rec[k] = m.params[k]
                    if f"{k}_name" in m.params:
                        rec[f"{k}_name"] = m.params[f"{k}_name"]
            rec.update({"model": model, "side": r.evaluation["side"], "internal": errs["internal"],
                        "total": errs["total"], "not_drawn": [dict(x) for x in r.not_drawn]})
            out.append(rec)
    return out


CSV_COLUMNS = ("material", "category", "paper_name", *PARAM_KEYS, "model", "side",
               "internal_rmse_mean", "internal_rmse_r", "internal_rmse_g", "internal_rmse_b",
               "internal_rmse_luminance", "internal_noise_floor_mean", "internal_noise_floor_luminance",
               "total_rmse_mean", "total_rmse_luminance", "total_noise_floor_mean", "rank_internal", "cells",
               "cells_total")


def category_csv(results: list[MaterialResult]) -> str:
    """The CSV table of one category (columns :data:`CSV_COLUMNS`), one row per (material, model);
    ``cells`` / ``cells_total``: the cells every RMSE of the row is summed over, of the grid's."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    for r in sorted(results, key=lambda r: material_sort_key(r.material)):
        m = r.material
        models = r.evaluation["models"]
        ranked = sorted(models, key=lambda n: models[n]["internal"]["rmse_mean"])
        for name in models:
            i, t = models[name]["internal"], models[name]["total"]
            w.writerow([m.name, m.category, m.paper_name, *[param_text(m.params, k) or "" for k in PARAM_KEYS],
                        name, r.evaluation["side"], _g(i["rmse_mean"]), *[_g(x) for x in i["rmse"]],
                        _g(i["rmse_luminance"]), _g(i["noise_floor_mean"]), _g(i["noise_floor_luminance"]),
                        _g(t["rmse_mean"]), _g(t["rmse_luminance"]), _g(t["noise_floor_mean"]),
                        ranked.index(name) + 1, t.get("cells", ""), t.get("cells_total", "")])
    return buf.getvalue()


def _g(x: float) -> str:
    return number(x, ".6g")


def category_markdown(category: str, results: list[MaterialResult]) -> str:
    """Markdown tables (materials x models) of the channel-mean RMSE, best per row in bold, ``failed``
    where a model failed on the material, and the cells every error of a row is summed over."""
    results = sorted(results, key=lambda r: material_sort_key(r.material))
    side = results[0].evaluation["side"] if results else "brdf"
    models = _ordered_models(results, with_failed=True)
    keys = [k for k in PARAM_KEYS if any(k in r.material.params for r in results)]
    parts = [f"# {category}: RMSE of Bati 2019 eq. 4, mean over R, G, B\n",
             f"{len(results)} material(s). Side compared: {side.upper()}. Lower is better; the best model of "
             f"each row is in bold; `noise floor` is the error a perfect model would show against this "
             f"reference; `cells`: the cells every error of the row is summed over, of the grid's on that side. "
             f"Full numbers (per channel, luminance): `{category}.csv`, `../errors.json`.\n"]
    sections = [("internal", "internal paths (bounce order 1 and the models' top lobe dropped)")] \
        if side == "brdf" else [("internal", "BTDF")]
    if side == "brdf":
        sections.append(("total", "total BRDF"))
    for part, label in sections:
        parts.append(f"\n## {label}\n")
        head = ["material", "name", *[PARAM_LABELS[k] for k in keys], *models, "noise floor", "cells"]
        parts.append("| " + " | ".join(head) + " |")
        parts.append("|" + "---|" * len(head))
        for r in results:
            errs = r.evaluation["models"]
            vals = {n: errs[n][part]["rmse_mean"] for n in models if n in errs}
            best = min(vals, key=vals.get) if vals else None
            failed = r.evaluation.get("failed", {})
            cells = [(f"**{vals[n]:.3e}**" if n == best else f"{vals[n]:.3e}") + _model_noise(errs[n][part])
                     if n in vals else "failed" if n in failed else "–" for n in models]
            nf = next(iter(errs.values()))[part]["noise_floor_mean"] if errs else float("nan")
            row = [r.material.name, r.material.paper_name,
                   *[param_text(r.material.params, k) or "" for k in keys], *cells, _floor(nf),
                   _cells(r.evaluation, part)]
            parts.append("| " + " | ".join(row) + " |")
    return "\n".join(parts) + "\n"


def _floor(x: float | None) -> str:
    """A noise floor in a Markdown cell: ``unknown`` when the reference has no standard errors."""
    return "unknown" if x is None else f"{x:.1e}"


def _cells(evaluation: dict, part: str) -> str:
    """``N of T`` cells the errors of one material are summed over (those of its first model: every
    model of a material shares the reference's cells), or the reference's own count, ``0 of T`` for
    a reference without a valid cell."""
    errs = evaluation["models"]
    e = next(iter(errs.values()))[part] if errs else evaluation
    if "cells" not in e:
        return "–"
    return f"{e['cells']:,} of {e['cells_total']:,}"


def _model_noise(e: dict) -> str:
    """`` (model noise N)`` after the error of a stochastic model (its own noise, beside the
    reference's floor; ``docs/models.md`` §3), nothing for an exact model."""
    return f" (model noise {e['model_noise_mean']:.1e})" if "model_noise_mean" in e else ""


def _ordered_models(results: list[MaterialResult], with_failed: bool = False) -> list[str]:
    """The models evaluated on any of ``results`` (and, ``with_failed``, those that failed on one), in
    the registry's order, then the others by name."""
    order = list(registry.all_models())
    seen = {n for r in results for n in r.evaluation["models"]}
    if with_failed:
        seen |= {n for r in results for n in r.evaluation.get("failed", {})}
    return [n for n in order if n in seen] + sorted(seen - set(order))


# ---------------------------------------------------------------------- figure-4 plots

def _label_keys(results: list[MaterialResult]) -> list[str]:
    """Parameters (besides alpha0) that a paper name does not determine within a category."""
    keys = []
    for k in PARAM_KEYS[1:]:
        by_name: dict[str, set] = {}
        for r in results:
            if k in r.material.params:
                by_name.setdefault(r.material.paper_name, set()).add(json.dumps(r.material.params[k]))
        if any(len(v) > 1 for v in by_name.values()):
            keys.append(k)
    return keys


def _plot_category(ax, category: str, results: list[MaterialResult], styles: dict) -> None:
    results = sorted(results, key=lambda r: material_sort_key(r.material))
    extra = _label_keys(results)
    xs = np.arange(len(results))
    labels = [r.material.paper_name + "".join(f"\n{PARAM_LABELS[k]}={param_text(r.material.params, k)}"
                                              for k in extra) for r in results]
    groups = [r.material.params.get("alpha0") for r in results]
    for name in _ordered_models(results):
        st = styles[name]
        ys = np.array([r.evaluation["models"][name]["internal"]["rmse_mean"] if name in r.evaluation["models"]
                       else np.nan for r in results])
        for g in dict.fromkeys(groups):
            sel = np.array([x == g for x in groups])
            ax.plot(xs[sel], ys[sel], "-", color=st["colour"], lw=0.8, alpha=0.6)
        ax.plot(xs, ys, st["marker"], color=st["colour"], ms=5, ls="none", label=name)
    nf = [next(iter(r.evaluation["models"].values()))["internal"]["noise_floor_mean"] if r.evaluation["models"]
          else np.nan for r in results]
    ax.plot(xs, nf, "_", color="0.4", ms=10, mew=1.5, ls="none", label="noise floor")
    for i in range(1, len(groups)):
        if groups[i] != groups[i - 1]:
            ax.axvline(i - 0.5, color="0.6", lw=0.8)
    starts = [i for i in range(len(groups)) if i == 0 or groups[i] != groups[i - 1]]
    for s, e in zip(starts, starts[1:] + [len(groups)]):
        if groups[s] is not None:
            ax.text((s + e - 1) / 2, 1.01, f"α0 = {groups[s]:g}", transform=ax.get_xaxis_transform(),
                    ha="center", va="bottom", fontsize=8)
    ax.set_yscale("log")
    log_ticks(ax)
    ax.set_xticks(xs, labels, fontsize=7)
    ax.set_xlim(-0.6, len(results) - 0.4)
    side = results[0].evaluation["side"] if results else "brdf"
    what = "internal paths, order 1 dropped" if side == "brdf" else "BTDF"
    ax.set_ylabel(f"RMSE ({what})\nmean over R, G, B", fontsize=8)
    ax.set_title(category, fontsize=10, pad=14)
    ax.tick_params(axis="y", labelsize=8)
    ax.legend(fontsize=7, frameon=False, loc="center left", bbox_to_anchor=(1.0, 0.5))


#: the fewest labelled ticks of a log axis of the figure-4 plots
MIN_TICKS = 3


def _ticks_between(lo: float, hi: float, subs: tuple[int, ...]) -> list[float]:
    return [m * 10.0 ** k for k in range(math.floor(math.log10(lo)) - 1, math.ceil(math.log10(hi)) + 1)
            for m in subs if lo <= m * 10.0 ** k <= hi]


def _power_of_ten_text(v: float, _pos=None) -> str:
    """``m x 10^k`` in mathtext (``10^k`` when m = 1)."""
    if not v > 0:
        return ""
    k = math.floor(math.log10(v) + 1e-9)
    m = round(v / 10.0 ** k, 6)
    return f"$10^{{{k}}}$" if m == 1 else f"${m:g}\\times10^{{{k}}}$"


def log_ticks(ax, minimum: int = MIN_TICKS) -> None:
    """At least ``minimum`` labelled ticks on the log y axis of ``ax`` (its data already drawn): the
    decades when they are enough, else 1-2-5 per decade, else every integer multiple of a power of
    ten, widening the axis about its geometric middle when even those are too few."""
    from matplotlib.ticker import FixedLocator, FuncFormatter, NullFormatter, NullLocator
    lo, hi = ax.get_ylim()
    if not (np.isfinite(lo) and np.isfinite(hi) and 0.0 < lo < hi):
        return
    for subs in ((1,), (1, 2, 5), tuple(range(1, 10))):
        ticks = _ticks_between(lo, hi, subs)
        if len(ticks) >= minimum:
            break
    while len(ticks) < minimum:
        mid, half = math.sqrt(lo * hi), math.sqrt(hi / lo) * 1.5
        lo, hi = mid / half, mid * half
        ticks = _ticks_between(lo, hi, subs)
    ax.set_ylim(lo, hi)
    ax.yaxis.set_major_locator(FixedLocator(ticks))
    ax.yaxis.set_major_formatter(FuncFormatter(_power_of_ten_text))
    if subs != (1,):
        ax.yaxis.set_minor_locator(NullLocator())
    ax.yaxis.set_minor_formatter(NullFormatter())


def errors_figure(groups: dict[str, list[MaterialResult]], styles: dict):
    """Figure 4: one panel per category of ``groups``, internal RMSE of every model per material."""
    from matplotlib.figure import Figure
    n = max(len(v) for v in groups.values())
    fig = Figure(figsize=(max(5.0, 0.32 * n + 2.8), 3.0 * len(groups)), dpi=DPI, layout="constrained")
    axes = fig.subplots(len(groups), 1, squeeze=False)[:, 0]
    for ax, (cat, res) in zip(axes, groups.items()):
        _plot_category(ax, cat, res, styles)
    return fig
