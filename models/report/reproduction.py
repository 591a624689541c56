"""The reproduction checks: each finding of Bati et al. 2019, section 4.2 / figure 4 (and the
error statements of sections 5.1-5.2) tested on our errors, with a verdict; ``reproduction.json``
and ``reproduction.md`` (``docs/report.md``, reproduction). Thresholds are fixed before looking at
the data."""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from models.report.causes import attach_causes
from models.report.results import PARAM_LABELS, MaterialResult, format_value

#: verdict thresholds of the reproduction checks (fraction of comparisons that agree)
HOLDS_AT = 0.9
PARTLY_AT = 0.5
#: "similar" / "close" / "indistinguishable" / "identical" as error ratios, fixed before looking
SIMILAR_RATIO = 1.25
CLOSE_RATIO = 1.5
INDISTINGUISHABLE_RATIO = 1.1
IDENTICAL_REL = 1e-6

WW09, ELEK, WW_BATI, B_FWD, B_SYM, B_BATI, B_BTDF = ("ww09", "elek10", "ww-bati19", "belcour-fwd", "belcour-sym",
                                                   "belcour-bati19", "belcour-btdf")


@dataclass
class _Row:
    name: str
    category: str
    params: dict
    errors: dict   # model -> {"internal": E, "total": E}


def verdict(passed: int, n: int) -> str:
    """The verdict of ``passed`` agreeing comparisons out of ``n``: ``holds`` (>= :data:`HOLDS_AT`),
    ``partly`` (>= :data:`PARTLY_AT`), ``does not hold``, or ``not testable`` when ``n = 0`` (the
    reproduction checks' and appendix E's rule, ``docs/report.md``)."""
    if n == 0:
        return "not testable"
    f = passed / n
    return "holds" if f >= HOLDS_AT else ("partly" if f >= PARTLY_AT else "does not hold")


def _check(cid: str, source: str, paper: str, test: str, models: Sequence[str], outcomes: list[tuple[bool, bool, str]],
           missing: Sequence[str], n_materials: int) -> dict:
    """A check's record; ``outcomes``: (agrees, noise_limited, detail) per comparison."""
    n = len(outcomes)
    passed = sum(1 for o in outcomes if o[0])
    note = ""
    if n == 0:
        if missing:
            note = f"not evaluated: {', '.join(missing)}"
        elif n_materials == 0:
            note = "no material of this kind in the results"
        else:
            note = "nothing to compare"
    elif missing:
        note = f"not evaluated on every material: {', '.join(missing)}"
    return {"id": cid, "source": source, "paper": paper, "test": test, "models": list(models), "n": n,
            "agree": passed, "fraction": (passed / n if n else None), "verdict": verdict(passed, n),
            "noise_limited": sum(1 for o in outcomes if o[1]),
            "noise_limited_disagreeing": sum(1 for o in outcomes if o[1] and not o[0]), "note": note,
            "details": [o[2] for o in outcomes]}


def _val(row: _Row, model: str, part: str, key: str = "rmse_mean"):
    e = row.errors.get(model)
    return None if e is None else e[part][key]


def _group_min(row: _Row, models: Sequence[str], part: str) -> float | None:
    vals = [_val(row, m, part) for m in models]
    return None if any(v is None for v in vals) else min(vals)


def _nf(row: _Row, part: str) -> float:
    return next(iter(row.errors.values()))[part]["noise_floor_mean"] if row.errors else 0.0


def _missing(rows: list[_Row], models: Sequence[str]) -> list[str]:
    return [m for m in models if any(m not in r.errors for r in rows)]


def _label(models: Sequence[str]) -> str:
    return models[0] if len(models) == 1 else "min(" + ", ".join(models) + ")"


def _order_check(cid, source, paper, rows: list[_Row], chain: Sequence[Sequence[str]], part="internal") -> dict:
    """Every row: value(chain[0]) < value(chain[1]) < ... (each item a group of models: its min)."""
    models = [m for g in chain for m in g]
    outcomes = []
    for r in rows:
        vals = [_group_min(r, g, part) for g in chain]
        if any(v is None for v in vals):
            continue
        ok = all(a < b for a, b in zip(vals, vals[1:]))
        noise = any(abs(b - a) < _nf(r, part) for a, b in zip(vals, vals[1:]))
        outcomes.append((ok, noise, f"{r.name}: " + " < ".join(f"{_label(g)} {v:.3g}" for g, v in zip(chain, vals))
                         + ("" if ok else "  (no)")))
    test = " < ".join(_label(g) for g in chain) + f" ({part} RMSE, channel mean), per material"
    return _check(cid, source, paper, test, models, outcomes, _missing(rows, models), len(rows))


def _ratio_check(cid, source, paper, rows: list[_Row], a: Sequence[str], b: Sequence[str], limit: float,
                 symmetric: bool, part="internal") -> dict:
    """Every row: a / b <= limit (``symmetric``: max/min <= limit)."""
    models = [*a, *b]
    outcomes = []
    for r in rows:
        va, vb = _group_min(r, a, part), _group_min(r, b, part)
        if va is None or vb is None or vb <= 0 or va <= 0:
            continue
        ratio = va / vb
        q = max(ratio, 1 / ratio) if symmetric else ratio
        ok = q <= limit
        outcomes.append((ok, False, f"{r.name}: {_label(a)} / {_label(b)} = {ratio:.3g}" + ("" if ok else "  (no)")))
    rel = f"max/min of {_label(a)} and {_label(b)} <= {limit:g}" if symmetric else \
        f"{_label(a)} / {_label(b)} <= {limit:g}"
    return _check(cid, source, paper, f"{rel} ({part} RMSE, channel mean), per material", models, outcomes,
                  _missing(rows, models), len(rows))


def _identical_check(cid, source, paper, rows: list[_Row], a: str, b: str, part="internal") -> dict:
    outcomes = []
    for r in rows:
        va, vb = _val(r, a, part), _val(r, b, part)
        if va is None or vb is None:
            continue
        ok = abs(va - vb) <= IDENTICAL_REL * max(abs(va), abs(vb), 1e-300)
        outcomes.append((ok, False, f"{r.name}: {a} {va:.6g}, {b} {vb:.6g}" + ("" if ok else "  (differ)")))
    return _check(cid, source, paper, f"|{a} - {b}| <= {IDENTICAL_REL:g} x error ({part} RMSE), per material",
                  [a, b], outcomes, _missing(rows, [a, b]), len(rows))


def _trend_check(cid, source, paper, rows: list[_Row], model: str, param: str) -> dict:
    """Among materials equal but for ``param``: the error grows as ``param`` decreases (every
    consecutive pair in ``param`` order)."""
    groups: dict[str, list[_Row]] = {}
    for r in rows:
        if param not in r.params or model not in r.errors:
            continue
        rest = {k: v for k, v in r.params.items() if k != param and not k.endswith("_name")}
        groups.setdefault(json.dumps(rest, sort_keys=True), []).append(r)
    outcomes = []
    for members in groups.values():
        members.sort(key=lambda r: r.params[param])
        for lo, hi in zip(members, members[1:]):
            e_lo, e_hi = _val(lo, model, "internal"), _val(hi, model, "internal")
            ok = e_lo > e_hi
            noise = abs(e_lo - e_hi) < max(_nf(lo, "internal"), _nf(hi, "internal"))
            outcomes.append((ok, noise, f"{lo.name} ({PARAM_LABELS[param]}={lo.params[param]:g}) {e_lo:.3g} > "
                                        f"{hi.name} ({PARAM_LABELS[param]}={hi.params[param]:g}) {e_hi:.3g}"
                                        + ("" if ok else "  (no)")))
    test = (f"{model}: for materials equal but for {PARAM_LABELS[param]}, error at the smaller "
            f"{PARAM_LABELS[param]} > error at the next larger one (RMSE, channel mean), per pair")
    return _check(cid, source, paper, test, [model], outcomes, _missing(rows, [model]), len(rows))


def _chromatic(v: Any) -> bool:
    return isinstance(v, (list, tuple)) and len(set(float(x) for x in v)) > 1


def _channel_trend_check(cid, source, paper, rows: list[_Row], models: Sequence[str], param: str,
                         other: str, relative: bool = False) -> dict:
    """Materials whose ``param`` differs between channels and ``other`` does not: the per-channel
    error is ordered like the per-channel ``param`` (our reading of "errors increase with it").
    ``relative``: the error divided by the reference's own size (``reference_norm``, eq. 4 against
    zero), the other reading; records without it (older caches) are left out."""
    sel = [r for r in rows if _chromatic(r.params.get(param)) and not _chromatic(r.params.get(other))]
    outcomes = []
    for r in sel:
        order = np.argsort(r.params[param], kind="stable")
        for model in models:
            if model not in r.errors or (relative and "reference_norm" not in r.errors[model]["internal"]):
                continue
            e = np.array(r.errors[model]["internal"]["rmse"])
            what = "RMSE"
            if relative:
                e = e / np.array(r.errors[model]["internal"]["reference_norm"])
                what = "RMSE / reference norm"
            ok = bool(np.all(np.diff(e[order]) > 0))
            outcomes.append((ok, False, f"{r.name} {model}: {PARAM_LABELS[param]} = {format_value(r.params[param])}, "
                                        f"{what} R G B = {' '.join(f'{x:.3g}' for x in e)}" + ("" if ok else "  (no)")))
    measure = "internal RMSE relative to the reference's norm (eq. 4 against zero)" if relative else "internal RMSE"
    reading = "the other reading" if relative else "our reading"
    test = (f"materials with a chromatic {PARAM_LABELS[param]} and an achromatic {PARAM_LABELS[other]}: the "
            f"per-channel {measure} increases with the per-channel {PARAM_LABELS[param]} ({reading}), "
            f"per (material, model)")
    return _check(cid, source, paper, test, models, outcomes, _missing(sel, models), len(sel))


def _blue_vs_luminance_check(cid, source, paper, rows: list[_Row], model: str) -> dict:
    sel = [r for r in rows if _chromatic(r.params.get("tau"))]
    outcomes = []
    for r in sel:
        if model not in r.errors:
            continue
        e = r.errors[model]["internal"]
        ok = e["rmse"][2] < e["rmse_luminance"]
        outcomes.append((ok, False, f"{r.name}: blue {e['rmse'][2]:.3g}, luminance {e['rmse_luminance']:.3g}"
                         + ("" if ok else "  (no)")))
    return _check(cid, source, paper, f"{model}, slabs with a chromatic τ: RMSE of the blue channel < RMSE of the "
                                      f"luminance, per material", [model], outcomes, _missing(sel, [model]), len(sel))


def reproduction_checks(results: list[MaterialResult], run: dict | None = None) -> list[dict]:
    """Each finding of Bati 2019 section 4.2 / figure 4 (and the error statements of 5.1-5.2)
    computed from our errors, with a verdict by :data:`HOLDS_AT` / :data:`PARTLY_AT`. ``run``: the
    results' ``database``, ``quality`` and ``rays_per_slice`` (the manifest's), which the cause
    texts name as this run's (:func:`models.report.causes.attach_causes`)."""
    run = {**(run or {}), "materials": len(results)}
    rows = [_Row(r.material.name, r.material.category, r.material.params, r.evaluation["models"]) for r in results]
    plastics = [r for r in rows if r.category == "plastic"]
    metals = [r for r in rows if r.category == "metal"]
    slabs = [r for r in rows if r.category == "slab"]

    def metal(a1=None, a0=None):
        return [r for r in metals if (a1 is None or _close(r.params.get("alpha1"), a1))
                and (a0 is None or any(_close(r.params.get("alpha0"), x) for x in np.atleast_1d(a0)))]

    belcour = (B_FWD, B_SYM)
    return attach_causes([
        _order_check("plastic-ww09-vs-elek", "Fig. 4(a) caption; Sec. 4.2 Plastics",
                     "For plastics, Weidlich and Wilkie's model is consistently more accurate than Elek's.",
                     plastics, [(WW09,), (ELEK,)]),
        _channel_trend_check("plastic-rho", "Sec. 4.2 Plastics",
                             "The errors of both models increase when ρ increases.", plastics, (WW09, ELEK),
                             "rho", "tau"),
        _channel_trend_check("plastic-tau", "Sec. 4.2 Plastics",
                             "The errors of both models increase when τ increases.", plastics, (WW09, ELEK),
                             "tau", "rho"),
        _channel_trend_check("plastic-tau-relative", "Sec. 4.2 Plastics",
                             "The errors of both models increase when τ increases.", plastics, (WW09, ELEK),
                             "tau", "rho", relative=True),
        _order_check("plastic-ww-bati19", "Fig. 4 caption; Sec. 5.1",
                     "Bati's corrected Weidlich-Wilkie (eq. 5) has a consistently smaller error on plastics.",
                     plastics, [(WW_BATI,), (WW09, ELEK)]),
        _order_check("metal-belcour-best", "Sec. 4.2 Metals",
                     "On internal paths Belcour's variants clearly produce the smallest RMSE on metals.",
                     metals, [belcour, (WW09, ELEK)]),
        _order_check("metal-elek-vs-ww09", "Sec. 4.2 Metals",
                     "On metals, Elek's model is more accurate than Weidlich and Wilkie's.", metals, [(ELEK,), (WW09,)]),
        _order_check("metal-a1-0.2-ranking", "Fig. 4(b) caption",
                     "Metals with α1 = 0.2: Belcour's models give the best results, followed by Elek's, then "
                     "Weidlich and Wilkie's.", metal(a1=0.2), [belcour, (ELEK,), (WW09,)]),
        _ratio_check("metal-belcour-fwd-sym-similar", "Fig. 4(b) caption; Sec. 5.2",
                     "Belcour's forward and symmetric variants have similar errors on internal paths.",
                     metals, (B_FWD,), (B_SYM,), SIMILAR_RATIO, symmetric=True),
        _ratio_check("metal-a1-0.001-a0-0.05-elek-close", "Fig. 4(b) caption",
                     "Metals with α1 = 0.001, α0 = 0.05: Elek's errors are close to Belcour's.",
                     metal(a1=0.001, a0=0.05), (ELEK,), belcour, CLOSE_RATIO, symmetric=False),
        _ratio_check("metal-a1-0.001-a0-0.2-elek-same", "Fig. 4(b) caption; Sec. 4.2 Metals",
                     "Metals with α1 = 0.001, α0 = 0.2: Elek's errors are indistinguishable from Belcour's.",
                     metal(a1=0.001, a0=0.2), (ELEK,), belcour, INDISTINGUISHABLE_RATIO, symmetric=True),
        _order_check("metal-a1-0.2-ww-bati19", "Fig. 4 caption; Sec. 5.1",
                     "Eq. 5 yields smaller errors than the other Weidlich-Wilkie variants on metallic paints and "
                     "patinas (α1 = 0.2).", metal(a1=0.2), [(WW_BATI,), (WW09, ELEK)]),
        _order_check("metal-a1-0.001-a0-0.001-ww-bati19", "Sec. 5.1",
                     "Frosted metals (α1 = 0.001): eq. 5 beats Elek's when α0 = 0.001 ...",
                     metal(a1=0.001, a0=0.001), [(WW_BATI,), (ELEK,)]),
        _order_check("metal-a1-0.001-rough-ww-bati19", "Sec. 5.1",
                     "... and only then: for α0 = 0.05 and 0.2, Elek's is not worse than eq. 5.",
                     metal(a1=0.001, a0=(0.05, 0.2)), [(ELEK,), (WW_BATI,)]),
        _identical_check("metal-belcour-bati19-internal", "Sec. 5.2",
                         "Errors of eq. 6 on internal paths are identical to Belcour's forward model.",
                         metals, B_BATI, B_FWD),
        _order_check("metal-belcour-bati19-total", "Fig. 10 caption; Sec. 5.2",
                     "Eq. 6 (exact top lobe) systematically improves Belcour's forward model (total BRDF).",
                     metals, [(B_BATI,), (B_FWD,)], part="total"),
        _order_check("metal-belcour-sym-total", "Sec. 4.2 Metals",
                     "With the top reflection included, Belcour's symmetric variant is slightly more accurate than "
                     "the forward one.", metals, [(B_SYM,), (B_FWD,)], part="total"),
        _trend_check("slab-alpha0", "Fig. 4(c) caption; Sec. 4.2 Slabs",
                     "Slabs: the errors of Belcour's forward model increase with decreasing α0.", slabs, B_BTDF, "alpha0"),
        _trend_check("slab-alpha1", "Fig. 4(c) caption; Sec. 4.2 Slabs",
                     "Slabs: the errors of Belcour's forward model increase with decreasing α1.", slabs, B_BTDF, "alpha1"),
        _blue_vs_luminance_check("slab-blue-vs-luminance", "Sec. 4.2 Slabs",
                                 "Slabs with a yellow-tinted τ (S1, S3): errors of the blue channel are smaller "
                                 "than those of the luminance.", slabs, B_BTDF),
    ], run)


def _close(a: Any, b: float) -> bool:
    return isinstance(a, (int, float)) and abs(float(a) - b) <= 1e-9 * max(1.0, abs(b))


def reproduction_markdown(checks: list[dict]) -> str:
    """``reproduction.md``: the table of findings and verdicts, then the comparisons of each check."""
    lines = ["# Reproduction of Bati et al. 2019, section 4.2\n",
             f"Each finding of the paper next to what our errors show. Verdict: *holds* if at least "
             f"{HOLDS_AT:.0%} of the comparisons agree, *partly* if at least {PARTLY_AT:.0%}, else *does not hold*; "
             f"thresholds and ratios (similar <= {SIMILAR_RATIO}, close <= {CLOSE_RATIO}, indistinguishable <= "
             f"{INDISTINGUISHABLE_RATIO}) were fixed before looking at the data. *noise-limited*: comparisons whose "
             f"error difference is below the reference noise floor.\n",
             "*cause*: why a finding does not fully hold or has noise-limited comparisons -- our implementation "
             "(fixed), our reading of the sentence, the paper, or noise -- with the evidence.\n",
             "| finding (paper) | source | our test | agree | verdict | cause | note |", "|---|---|---|---|---|---|---|"]
    for c in checks:
        agree = f"{c['agree']}/{c['n']}" + (f" ({c['noise_limited']} noise-limited)" if c["noise_limited"] else "")
        cause = f"**{c['cause']}**: {c['cause_text']}" if c.get("cause") else c.get("cause_text", "")
        lines.append(f"| {c['paper']} | {c['source']} | {c['test']} | {agree} | **{c['verdict']}** | {cause} | "
                     f"{c['note']} |")
    for c in checks:
        if c["details"]:
            lines.append(f"\n## {c['id']}: {c['verdict']}\n")
            lines.extend(f"- {d}" for d in c["details"])
    return "\n".join(lines) + "\n"
