"""The multiple-scattering table of a report (``multiple-scattering.md``, ``.json``): what single
scattering loses at the database's roughnesses, and how the models' errors change when the
reference includes multiple scattering.

The report is built over the results directory of a multiple-scattering (MS) database -- e.g.
``configs/bati2019-ms.toml``, every interface ``multiple_scattering = true`` -- with
``--compare-to`` naming the results directory of its single-scattering (SS) twin (the same
material names). Per material paired by name:

* the energy single scattering loses: the SS file's ``/energy/masking_loss`` per channel, mean over
  the incident directions of the file, and at the incidents nearest 0 and 80 degrees;
* what the MS walk gives back: MS minus SS ``/energy/reflected`` and ``/energy/transmitted`` (same
  averages; with height-correlated masking the two would balance, with separable masking the
  SS loss is the larger), and the MS file's own masking loss (a check: 0 when every interface walks);
* for each model evaluated on both, its internal and total RMSE (Bati 2019 eq. 4, channel mean)
  against the SS reference and against the MS reference (the model values are the same: the
  models know nothing of the walk).

:func:`evaluate_twins` evaluates the SS twins (cached under ``<out>/multiple-scattering/cache``),
:func:`multiple_scattering_section` returns the numbers and :func:`multiple_scattering_markdown`
the text; :func:`models.report.build.build_report` calls them when given ``compare_to``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import h5py
import numpy as np

from models.report.evaluation import evaluate_material, warm_up_models
from models.report.results import MaterialResult, ReportError, material_sort_key, open_results
from models.workers import run_in_workers

#: incident elevations the table shows beside the mean (the nearest incident of the file)
AT_DEG = (0.0, 80.0)
CHANNELS = ("R", "G", "B")
#: sub-directory of the report that caches the evaluations of the single-scattering twins
TWIN_DIR = "multiple-scattering"


def evaluate_twins(compare_to: str | Path, out: Path, names: Sequence[str], models: Sequence[str] | None,
                   subcells: int, code: str, isotropize: str | None = None,
                   jobs: int = 1) -> tuple[list[MaterialResult], list[str]]:
    """Evaluations of the materials of the results directory ``compare_to`` whose names are in
    ``names`` (cached under ``out/multiple-scattering``; ``jobs`` worker processes,
    :mod:`models.workers`), and warnings."""
    rd = Path(compare_to)
    _, materials, _, warnings = open_results(rd, None, exclude=out)
    wanted = set(names)
    twins = [(mat, out / TWIN_DIR, None if models is None else tuple(models), subcells, code, isotropize)
             for mat in materials if mat.name in wanted]
    results = run_in_workers(_twin_step, twins, jobs, writes_under=out / TWIN_DIR,
                             warm_up=lambda: warm_up_models([t[0] for t in twins], models, subcells, isotropize))
    return results, [f"--compare-to {rd}: {w}" for w in warnings]


def _twin_step(twin: tuple) -> MaterialResult:
    """The evaluation of one twin (its slices dropped), here or in a worker process."""
    mat, out, models, subcells, code, isotropize = twin
    res, _ = evaluate_material(mat, out, None if models is None else list(models), subcells, code, isotropize)
    res.slices = None
    return res


def _energies(path: Path) -> dict[str, np.ndarray]:
    try:
        with h5py.File(path, "r") as f:
            return {k: np.asarray(f[f"energy/{k}"][()], dtype=float) if k != "theta"
                    else np.asarray(f["incident/theta_deg"][()], dtype=float)
                    for k in ("theta", "masking_loss", "reflected", "transmitted")}
    except (OSError, KeyError) as e:
        raise ReportError(f"{path}: cannot read the energies: {e}") from None


def _summary(theta: np.ndarray, e: np.ndarray) -> dict:
    """Mean over incidents (per channel and channel mean) and the values at :data:`AT_DEG`."""
    mean = e.mean(axis=0)
    out = {"mean": mean.tolist(), "mean_channels": float(mean.mean())}
    for a in AT_DEG:
        k = int(np.argmin(np.abs(theta - a)))
        out[f"at_{a:g}"] = {"theta": float(theta[k]), "value": e[k].tolist(), "mean_channels": float(e[k].mean())}
    return out


def multiple_scattering_section(single: list[MaterialResult], multiple: list[MaterialResult]) -> dict:
    """The numbers of the table for the SS results ``single`` and the MS results ``multiple``,
    paired by material name."""
    ss = {r.material.name: r for r in single}
    ms = {r.material.name: r for r in multiple}
    paired = sorted((n for n in ms if n in ss), key=lambda n: material_sort_key(ms[n].material))
    rows = []
    for name in paired:
        a, b = ss[name], ms[name]
        ea, eb = _energies(a.material.path), _energies(b.material.path)
        if ea["theta"].shape != eb["theta"].shape or not np.allclose(ea["theta"], eb["theta"]):
            raise ReportError(f"{name}: the two twins have other incident directions "
                              f"({ea['theta'].tolist()} and {eb['theta'].tolist()})")
        th = ea["theta"]
        models = {}
        for m in sorted(set(a.evaluation["models"]) & set(b.evaluation["models"])):
            ma, mb = a.evaluation["models"][m], b.evaluation["models"][m]
            models[m] = {part: {"ss": ma[part]["rmse_mean"], "ms": mb[part]["rmse_mean"],
                                "change": mb[part]["rmse_mean"] - ma[part]["rmse_mean"],
                                "ss_noise_floor": ma[part]["noise_floor_mean"],
                                "ms_noise_floor": mb[part]["noise_floor_mean"]}
                         for part in ("internal", "total")}
        rows.append({"material": name, "category": b.material.category, "paper_name": b.material.paper_name,
                     "params": {k: v for k, v in b.material.params.items() if k in ("alpha0", "alpha1")},
                     "incident_deg": th.tolist(),
                     "ss_masking_loss": _summary(th, ea["masking_loss"]),
                     "ms_masking_loss": _summary(th, eb["masking_loss"]),
                     "reflected_gain": _summary(th, eb["reflected"] - ea["reflected"]),
                     "transmitted_gain": _summary(th, eb["transmitted"] - ea["transmitted"]),
                     "models": models})
    summary = {}
    for cat in sorted({r["category"] for r in rows}):
        cr = [r for r in rows if r["category"] == cat]
        per_model = {}
        for m in sorted({m for r in cr for m in r["models"]}):
            vals = [r["models"][m] for r in cr if m in r["models"]]
            per_model[m] = {part: {k: float(np.mean([v[part][k] for v in vals])) for k in ("ss", "ms", "change")}
                            | {"materials": len(vals)} for part in ("internal", "total")}
        summary[cat] = {"materials": len(cr),
                        "ss_masking_loss_mean": float(np.mean([r["ss_masking_loss"]["mean_channels"] for r in cr])),
                        "ss_masking_loss_max": float(max(r["ss_masking_loss"]["mean_channels"] for r in cr)),
                        "models": per_model}
    return {"materials": rows, "by_category": summary,
            "only_single": sorted(n for n in ss if n not in ms), "only_multiple": sorted(n for n in ms if n not in ss)}


def _f(x: float) -> str:
    return f"{x:.4f}"


def multiple_scattering_markdown(sec: dict) -> str:
    """``multiple-scattering.md``: the loss and gain table, the error tables, the unpaired names."""
    rows = sec["materials"]
    at = [f"{a:g}" for a in AT_DEG]
    lines = ["# Multiple scattering: what single scattering loses, and the models' errors", "",
             "Single scattering (SS) books as `masking_loss` the energy the microfacet masking removes; "
             "the multiple-scattering (MS) twin (same stack, `multiple_scattering = true` on every interface) "
             "keeps it in the walk. Energies are fractions of the incident energy; *mean* is over the incident "
             f"directions of the files, columns at {' and '.join(at)} deg use the nearest incident. "
             "Errors are Bati 2019 eq. 4 RMSE, channel mean, of the same model values against each reference.", ""]
    lines += ["## Energy", "",
              "| material | SS loss R, G, B (mean) | SS loss (mean) | " + " | ".join(f"SS loss at {a}°" for a in at)
              + " | MS reflected gain (mean) | " + " | ".join(f"R gain at {a}°" for a in at)
              + " | MS transmitted gain (mean) | MS loss (mean) |",
              "|---|---|---|" + "---|" * len(at) + "---|" + "---|" * len(at) + "---|---|"]
    for r in rows:
        l, g, t = r["ss_masking_loss"], r["reflected_gain"], r["transmitted_gain"]
        lines.append(f"| {r['material']} | {', '.join(_f(x) for x in l['mean'])} | {_f(l['mean_channels'])} | "
                     + " | ".join(_f(l[f'at_{a}']['mean_channels']) for a in at)
                     + f" | {_f(g['mean_channels'])} | " + " | ".join(_f(g[f'at_{a}']['mean_channels']) for a in at)
                     + f" | {_f(t['mean_channels'])} | {_f(r['ms_masking_loss']['mean_channels'])} |")
    lines += ["", "## Errors by category (mean over the paired materials)", "",
              "| category | materials | mean SS loss | max SS loss | model | internal vs SS | internal vs MS | change | "
              "total vs SS | total vs MS | change |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for cat, c in sec["by_category"].items():
        for m, v in c["models"].items():
            i, t = v["internal"], v["total"]
            lines.append(f"| {cat} | {v['internal']['materials']} | {_f(c['ss_masking_loss_mean'])} | "
                         f"{_f(c['ss_masking_loss_max'])} | {m} | {_f(i['ss'])} | {_f(i['ms'])} | {i['change']:+.4f} | "
                         f"{_f(t['ss'])} | {_f(t['ms'])} | {t['change']:+.4f} |")
    lines += ["", "## Errors per material", "",
              "| material | model | internal vs SS | internal vs MS | change | total vs SS | total vs MS | change |",
              "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        for m, v in r["models"].items():
            i, t = v["internal"], v["total"]
            lines.append(f"| {r['material']} | {m} | {_f(i['ss'])} | {_f(i['ms'])} | {i['change']:+.4f} | "
                         f"{_f(t['ss'])} | {_f(t['ms'])} | {t['change']:+.4f} |")
    for key, label in (("only_single", "only in the single-scattering directory"),
                       ("only_multiple", "only in the multiple-scattering directory")):
        if sec[key]:
            lines += ["", f"Not paired ({label}): " + ", ".join(sec[key])]
    return "\n".join(lines) + "\n"
