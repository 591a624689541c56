"""The polarization table of a report (``polarization.md``, ``.json``): how far the scalar reference
is from the polarized one, and how the models' errors change when they are judged against the
intensity of polarized light (``docs/polarization.md`` section 6).

The report is built over the results directory of a polarized database (``gonio database
simulate ... --polarized``) with ``--compare-to`` naming the results directory of its scalar twin
(the same material names and rays). Per material paired by name, per incident direction, over the
cells where both runs expect at least :data:`MIN_EXITS` exits per channel (``docs/testing.md``:
where a cell's standard error is trustworthy):

* the largest relative difference of the intensity for unpolarized light, ``value`` (the polarized
  file's ``M[0, 0]``), from the scalar run's, in percent, and the largest difference in units of
  the two cells' combined standard error;
* the difference of the reflected (and transmitted) energy, in percent and in standard errors;
* for each model evaluated on both, its internal and total RMSE against the scalar and against the
  polarized reference (the model values are the same).

:func:`polarization_section` returns the numbers and :func:`polarization_markdown` the text;
:func:`models.report.build.build_report` calls them when ``compare_to`` names a scalar twin of a
polarized results directory.
"""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

from models.report.results import MaterialResult, ReportError, material_sort_key

#: exits per cell and channel both runs must expect before a cell is compared
MIN_EXITS = 20
#: a cell's difference counts as resolved beyond this many combined standard errors (about 1e-6
#: for one cell under normal noise: over the database's few million cells, a handful by chance)
RESOLVED_Z = 5.0


def _read(path: Path) -> dict[str, np.ndarray]:
    """The intensities, standard errors, cells' projected solid angles and energies of a slices file."""
    try:
        with h5py.File(path, "r") as f:
            sides = [s for s in ("brdf", "btdf") if s in f]
            out = {"theta": np.asarray(f["incident/theta_deg"][()], dtype=float),
                   "rays": int(f["simulation"].attrs["rays_per_slice"]),
                   "polarized": bool(f["simulation"].attrs.get("polarized", False))}
            for s in sides:
                out[s] = {k: np.asarray(f[f"{s}/{k}"][()]) for k in ("value", "stderr", "proj_solid_angle", "mask")}
            for k in ("reflected", "transmitted"):
                out[k] = np.asarray(f[f"energy/{k}"][()], dtype=float)
                out[k + "_stderr"] = np.asarray(f[f"energy/{k}_stderr"][()], dtype=float)
            return out
    except (OSError, KeyError) as e:
        raise ReportError(f"{path}: cannot read its slices: {e}") from None


def _cells(a: dict, b: dict, side: str, m: int) -> dict:
    """The comparison of one side and incident direction over the cells both runs sample well."""
    sa, sb = a[side], b[side]
    om = sa["proj_solid_angle"][m][None]
    expected = np.minimum(a["rays"] * sa["value"][m], b["rays"] * sb["value"][m]) * om
    sel = (expected >= MIN_EXITS) & sa["mask"][m][None] & (sa["stderr"][m] > 0) & (sb["stderr"][m] > 0)
    if not np.any(sel):
        return {"cells": 0}
    va, vb = sa["value"][m][sel], sb["value"][m][sel]
    z = (vb - va) / np.hypot(sa["stderr"][m][sel], sb["stderr"][m][sel])
    rel = (vb - va) / va
    k = int(np.argmax(np.abs(rel)))
    # the difference each cell vouches for at RESOLVED_Z: |d| - RESOLVED_Z se, relative, with d's sign
    se = np.hypot(sa["stderr"][m][sel], sb["stderr"][m][sel])
    bound = np.sign(vb - va) * np.maximum(np.abs(vb - va) - RESOLVED_Z * se, 0.0) / va
    kb = int(np.argmax(np.abs(bound)))
    return {"cells": int(np.count_nonzero(sel)), "max_rel_diff": float(rel[k]), "z_at_max_rel": float(z[k]),
            "max_abs_z": float(np.max(np.abs(z))), "rms_z": float(np.sqrt(np.mean(z * z))),
            "resolved_rel_diff": float(bound[kb]), "resolved_cells": int(np.count_nonzero(np.abs(z) > RESOLVED_Z))}


def polarization_section(scalar: list[MaterialResult], polarized: list[MaterialResult]) -> dict:
    """The numbers of the table for the scalar results ``scalar`` and the polarized ones
    ``polarized``, paired by material name."""
    sc = {r.material.name: r for r in scalar}
    po = {r.material.name: r for r in polarized}
    paired = sorted((n for n in po if n in sc), key=lambda n: material_sort_key(po[n].material))
    rows = []
    for name in paired:
        a, b = _read(sc[name].material.path), _read(po[name].material.path)
        if a["polarized"] or not b["polarized"]:
            raise ReportError(f"{name}: --compare-to needs the scalar twin of a polarized results directory")
        if a["theta"].shape != b["theta"].shape or not np.allclose(a["theta"], b["theta"]):
            raise ReportError(f"{name}: the two twins have other incident directions "
                              f"({a['theta'].tolist()} and {b['theta'].tolist()})")
        incidents = []
        for m, th in enumerate(a["theta"]):
            row = {"theta": float(th)}
            for side in ("brdf", "btdf"):
                if side in a and side in b:
                    row[side] = _cells(a, b, side, m)
            for k in ("reflected", "transmitted"):
                ea, eb = a[k][m], b[k][m]
                se = np.hypot(a[k + "_stderr"][m], b[k + "_stderr"][m])
                ok = ea > 0
                row[k] = {"rel_diff": float(np.mean(np.where(ok, (eb - ea) / np.where(ok, ea, 1.0), 0.0))),
                          "z": float(np.max(np.abs(np.divide(eb - ea, se, out=np.zeros_like(se), where=se > 0))))}
            incidents.append(row)
        models = {}
        for mo in sorted(set(sc[name].evaluation["models"]) & set(po[name].evaluation["models"])):
            ma, mb = sc[name].evaluation["models"][mo], po[name].evaluation["models"][mo]
            models[mo] = {part: {"scalar": ma[part]["rmse_mean"], "polarized": mb[part]["rmse_mean"],
                                 "change": mb[part]["rmse_mean"] - ma[part]["rmse_mean"]}
                          for part in ("internal", "total")}
        rows.append({"material": name, "category": po[name].material.category,
                     "paper_name": po[name].material.paper_name, "incidents": incidents, "models": models})
    return {"materials": rows, "by_category": _by_category(rows), "min_exits": MIN_EXITS,
            "only_scalar": sorted(n for n in sc if n not in po), "only_polarized": sorted(n for n in po if n not in sc)}


def _by_category(rows: list[dict]) -> dict:
    """Per category and incident: the largest relative difference over the materials, and the
    mean change of each model's total RMSE."""
    out = {}
    for cat in sorted({r["category"] for r in rows}):
        cr = [r for r in rows if r["category"] == cat]
        per_side = {}
        for side in ("brdf", "btdf"):
            per_side[side] = {}
            for k, row in enumerate(cr[0]["incidents"]):
                vals = [r["incidents"][k].get(side, {}) for r in cr]
                vals = [v for v in vals if v.get("cells")]
                if vals:
                    worst = max(vals, key=lambda v: abs(v["max_rel_diff"]))
                    resolved = max(vals, key=lambda v: abs(v["resolved_rel_diff"]))
                    energy = "reflected" if side == "brdf" else "transmitted"
                    en = max((r["incidents"][k][energy] for r in cr), key=lambda e: abs(e["rel_diff"]))
                    per_side[side][f"{row['theta']:g}"] = {
                        "max_rel_diff": worst["max_rel_diff"], "z": worst["z_at_max_rel"],
                        "max_abs_z": max(v["max_abs_z"] for v in vals),
                        "resolved_rel_diff": resolved["resolved_rel_diff"],
                        "resolved_cells": sum(v["resolved_cells"] for v in vals),
                        "cells": sum(v["cells"] for v in vals), "max_rms_z": max(v["rms_z"] for v in vals),
                        "energy_rel_diff": en["rel_diff"], "energy_z": en["z"]}
        per_inc = per_side["brdf"]
        models = {}
        for mo in sorted({m for r in cr for m in r["models"]}):
            vals = [r["models"][mo] for r in cr if mo in r["models"]]
            models[mo] = {part: {k: float(np.mean([v[part][k] for v in vals])) for k in ("scalar", "polarized", "change")}
                          for part in ("internal", "total")} | {"materials": len(vals)}
        out[cat] = {"materials": len(cr), "incidents": per_inc, "models": models}
        if per_side["btdf"]:
            out[cat]["incidents_btdf"] = per_side["btdf"]
    return out


def polarization_markdown(sec: dict) -> str:
    """``polarization.md``: the differences by category and incidence, per material, and the errors."""
    lines = ["# Polarized light: how far the scalar reference is, and the models' errors", "",
             "The scalar run gives every Fresnel event unpolarized light; the polarized run traces Mueller "
             "matrices (docs/polarization.md). Compared: the intensity for unpolarized light (BRDF `value`, the "
             f"polarized file's M[0, 0]) over the cells where both runs expect at least {sec['min_exits']} exits; "
             "differences are polarized minus scalar, relative to the scalar value, and in units of the two "
             "cells' combined standard error (z).", ""]
    lines += [f"Per cell the noise dominates a single cell's relative difference (a cell of {sec['min_exits']} "
              "exits has a relative standard error near 22 %), so the tables lead with what the cells vouch for: "
              f"the largest difference resolved at {RESOLVED_Z:g} combined standard errors (|d| - "
              f"{RESOLVED_Z:g} se, relative to the scalar value, with d's sign; 0 where no cell resolves one), "
              f"the cells resolved beyond {RESOLVED_Z:g} se, the largest root-mean-square z of a material (1 where "
              "the two runs agree), and the largest difference of the hemispherical energy (channel mean) with "
              "its z. The single cell's largest relative difference follows for reference.", ""]
    for cat, c in sec["by_category"].items():
        lines += [f"## {cat} ({c['materials']} materials)", ""]
        for key, side, energy in (("incidents", "BRDF", "reflected"), ("incidents_btdf", "BTDF", "transmitted")):
            if not c.get(key):
                continue
            lines += [f"| incident | {side}: largest difference resolved at {RESOLVED_Z:g} se | cells resolved | "
                      f"largest rms z | {energy} energy: largest difference | its z | one cell's largest "
                      "relative difference | its z |", "|---|---|---|---|---|---|---|---|"]
            for th, v in c[key].items():
                lines.append(f"| {th}° | {100 * v['resolved_rel_diff']:+.2f} % | {v['resolved_cells']} of "
                             f"{v['cells']} | {v['max_rms_z']:.2f} | {100 * v['energy_rel_diff']:+.3f} % | "
                             f"{v['energy_z']:.1f} | {100 * v['max_rel_diff']:+.2f} % | {v['z']:+.1f} |")
            lines.append("")
        if c["models"]:
            lines += ["", "| model | materials | total RMSE vs scalar | vs polarized | change | internal vs scalar | "
                          "vs polarized | change |", "|---|---|---|---|---|---|---|---|"]
            for mo, v in c["models"].items():
                t, i = v["total"], v["internal"]
                lines.append(f"| {mo} | {v['materials']} | {t['scalar']:.4f} | {t['polarized']:.4f} | "
                             f"{t['change']:+.4f} | {i['scalar']:.4f} | {i['polarized']:.4f} | {i['change']:+.4f} |")
        lines.append("")
    lines += ["## Per material", "",
              f"| material | incident | cells | BRDF resolved at {RESOLVED_Z:g} se | rms z | reflected energy "
              "difference | its z | transmitted energy difference | its z | one cell's largest relative difference "
              "| its z |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in sec["materials"]:
        for row in r["incidents"]:
            b = row.get("brdf", {})
            e, t = row["reflected"], row["transmitted"]
            if b.get("cells"):
                lines.append(f"| {r['material']} | {row['theta']:g}° | {b['cells']} | "
                             f"{100 * b['resolved_rel_diff']:+.2f} % | {b['rms_z']:.2f} | {100 * e['rel_diff']:+.3f} % | "
                             f"{e['z']:.1f} | {100 * t['rel_diff']:+.3f} % | {t['z']:.1f} | "
                             f"{100 * b['max_rel_diff']:+.2f} % | {b['z_at_max_rel']:+.1f} |")
    for key, label in (("only_scalar", "only in the scalar directory"), ("only_polarized", "only in the polarized "
                                                                                         "directory")):
        if sec[key]:
            lines += ["", f"Not paired ({label}): " + ", ".join(sec[key])]
    return "\n".join(lines) + "\n"
