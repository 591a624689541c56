"""The report's static page ``index.html``: the template and assets of ``assets/`` with the CSS and
JS inlined, the report data embedded as JSON (``REPORT_FORMAT``), and the static sections
(reproduction table, overview figures, table links). It works from ``file://``: no server, no
network; images are referenced relatively (``docs/report.md``, the page)."""

from __future__ import annotations

import json
from html import escape
from pathlib import Path
from typing import Any

from models import registry
from models.report.figures import DISK_PX, ORDER_DISK_PX, PANEL_GAP_PX
from models.report.hover import HOVER_PX
from models.report.panels import ISO_LEVELS, legend_colours
from models.report.reproduction import (CLOSE_RATIO, HOLDS_AT, IDENTICAL_REL, INDISTINGUISHABLE_RATIO, PARTLY_AT,
                                        SIMILAR_RATIO)
from models.report.results import (PARAM_KEYS, PARAM_LABELS, MaterialResult, ReportError, material_sort_key,
                                   param_text)

#: format and version of the data embedded in the page (``docs/file-identity.md``)
REPORT_FORMAT = "goniometer.report"
REPORT_VERSION = 1
#: the page template, its CSS and JS
ASSETS = Path(__file__).resolve().parent / "assets"


def _selectors(results: list[MaterialResult]) -> tuple[dict[str, list[dict]], dict[str, dict[str, str]]]:
    """Per category the parameter selectors (those that vary) and per material its values;
    ``paper_name`` / ``name`` are added when the parameters do not single out a material."""
    sel: dict[str, list[dict]] = {}
    values: dict[str, dict[str, str]] = {}
    by_cat: dict[str, list[MaterialResult]] = {}
    for r in results:
        by_cat.setdefault(r.material.category, []).append(r)
    for cat, res in by_cat.items():
        res = sorted(res, key=lambda r: material_sort_key(r.material))
        table = {r.material.name: {k: param_text(r.material.params, k) for k in PARAM_KEYS
                                   if k in r.material.params} for r in res}
        for r in res:
            table[r.material.name]["paper_name"] = r.material.paper_name
            table[r.material.name]["name"] = r.material.name
        keys = [k for k in PARAM_KEYS if len({t.get(k) for t in table.values()}) > 1]
        for extra in ("paper_name", "name"):
            if len({tuple(t.get(k) for k in keys) for t in table.values()}) == len(table):
                break
            keys.append(extra)
        sel[cat] = [{"key": k, "label": PARAM_LABELS[k],
                     "values": list(dict.fromkeys(t[k] for t in table.values() if t.get(k) is not None))}
                    for k in keys]
        for name, t in table.items():
            values[name] = {k: t.get(k) for k in keys}
    return sel, values


def html_data(results: list[MaterialResult], styles: dict, overview: dict, meta: dict) -> dict:
    """The data embedded in the page: meta, categories, selectors, materials (errors, figures), models,
    and what the page needs to draw the colour bars and map a pointer on an image to a direction
    (``views``: disk and gap sizes of the composed images in pixels, the hover grid; ``colours``:
    the band and diverging colours of :func:`models.report.panels.legend_colours`)."""
    sel, values = _selectors(results)
    cats = list(dict.fromkeys(r.material.category for r in results))
    models = registry.catalogue()
    mats = []
    for r in sorted(results, key=lambda r: (cats.index(r.material.category), material_sort_key(r.material))):
        m = r.material
        mats.append({"name": m.name, "category": m.category, "paper_name": m.paper_name, "sel": values[m.name],
                     "params": {k: param_text(m.params, k) for k in PARAM_KEYS if k in m.params},
                     "side": r.evaluation["side"], "parametrization": m.parametrization,
                     "resolution": list(m.resolution), "rays": m.rays,
                     "errors": r.evaluation["models"], "skipped": r.evaluation.get("skipped", {}),
                     "approximations": r.evaluation.get("approximations", {}),
                     "failed": r.evaluation.get("failed", {}), **r.figures,
                     "not_drawn": [{"figure": x["figure"], "reason": x["reason"]} for x in r.not_drawn]})
    return {"format": REPORT_FORMAT, "version": REPORT_VERSION, "meta": meta, "categories": cats,
            "selectors": sel, "materials": mats, "overview": overview,
            "views": {"top": {"disk_px": DISK_PX, "gap_px": PANEL_GAP_PX, "panels": 3},
                      "orders": {"disk_px": ORDER_DISK_PX, "gap_px": PANEL_GAP_PX}, "hover_px": HOVER_PX},
            "colours": {**legend_colours(), "iso_levels": ISO_LEVELS},
            "models": {n: {**styles[n], "description": getattr(models.get(n), "description", "")} for n in styles}}


def _script_json(obj: Any) -> str:
    text = json.dumps(obj, separators=(",", ":"), allow_nan=False)
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


def _esc(x: Any) -> str:
    return escape(str(x), quote=True)


def _reproduction_html(checks: list[dict]) -> str:
    rows = []
    for c in checks:
        agree = f"{c['agree']}/{c['n']}" if c["n"] else "–"
        if c["noise_limited"]:
            agree += f"<br><small>{c['noise_limited']} noise-limited</small>"
        details = ""
        if c["details"]:
            items = "".join(f"<li>{_esc(d)}</li>" for d in c["details"])
            details = f"<details><summary>{len(c['details'])} comparison(s)</summary><ul>{items}</ul></details>"
        rows.append(f"<tr class=\"verdict-{_esc(c['verdict'].replace(' ', '-'))}\" data-check=\"{_esc(c['id'])}\">"
                    f"<td>{_esc(c['paper'])}<br><small>{_esc(c['source'])}</small></td>"
                    f"<td>{_esc(c['test'])}{details}</td><td class=\"num\">{agree}</td>"
                    f"<td class=\"verdict\">{_esc(c['verdict'])}</td><td>{_cause_html(c)}</td>"
                    f"<td>{_esc(c['note'])}</td></tr>")
    return ("<table class=\"repro\"><thead><tr><th>finding (paper)</th><th>our test</th><th>agree</th>"
            "<th>verdict</th><th>cause</th><th>note</th></tr></thead><tbody>" + "".join(rows) + "</tbody></table>")


def _cause_html(c: dict) -> str:
    if "cause_text" not in c:
        return ""
    head = f"<strong>{_esc(c['cause'])}</strong>: " if c.get("cause") else ""
    return head + _esc(c["cause_text"])


def _tables_html(tables: dict[str, dict[str, str]]) -> str:
    items = "".join(f"<li>{_esc(cat)}: <a href=\"{_esc(t['md'])}\">Markdown</a> · <a href=\"{_esc(t['csv'])}\">CSV</a></li>"
                    for cat, t in tables.items())
    return f"<ul>{items}<li>all records: <a href=\"errors.json\">errors.json</a></li></ul>"


def _overview_html(overview: dict[str, str]) -> str:
    figs = "".join(f"<figure class=\"overview\" data-category=\"{_esc(cat)}\"><img src=\"{_esc(src)}\" "
                   f"alt=\"errors of the {_esc(cat)} category\" loading=\"lazy\"></figure>"
                   for cat, src in overview.items() if cat != "_all")
    link = (f"<p class=\"hint\">All categories in one figure: <a href=\"{_esc(overview['_all'])}\">"
            f"{_esc(overview['_all'])}</a></p>") if "_all" in overview else ""
    return figs + link


def _asset(name: str) -> str:
    try:
        return (ASSETS / name).read_text(encoding="utf-8")
    except OSError as e:
        raise ReportError(f"{ASSETS / name}: report asset missing ({e.strerror or e})") from None


def _figure1_html(fig: dict | None) -> str:
    """The static section of Bati 2019 figure 1 (:func:`models.report.spheres.figure1`)."""
    if fig is None:
        return ("<p class=\"hint\">The results hold no frosted metal with α0 = 0.05, α1 = 0.2, η1 = 1.2 and a "
                "yellow-tinted τ (metal/M5-a0_0.05-a1_0.2 of configs/bati2019.toml), so figure 1 is not drawn.</p>")
    rmse = ", ".join(f"{_esc(n)} {v:.3g}" for n, v in fig["rmse"].items() if v is not None)
    missing = (f" Not evaluated for this material: {_esc(', '.join(fig['missing']))}." if fig["missing"] else "")
    img = (f"<img id=\"img-figure1\" src=\"{_esc(fig['src'])}\" alt=\"Bati 2019 figure 1: {_esc(fig['material'])} "
           f"on lit spheres\">") if fig["src"] else ""
    return (f"<figure class=\"wide\">{img}<figcaption>{_esc(fig['material'])}: the reference (left), then "
            f"{_esc(', '.join(fig['models']))} beside it (top row) and split with it (bottom row: left half "
            f"reference, right half model). Reference: {_esc(fig['caption'])}. Image RMSE (display units, white = 1): "
            f"{rmse or '–'}.{missing}</figcaption></figure>")


def render_html(data: dict, checks: list[dict], tables: dict, summary_lines: list[str],
                figure1: dict | None = None) -> str:
    """The static page: template + inlined CSS/JS + embedded data + static sections (``figure1``:
    Bati 2019 figure 1, :func:`models.report.spheres.figure1`)."""
    page = _asset("index.html")
    meta = data["meta"]
    subs = {
        "<!--TITLE-->": _esc(f"{meta['database']} — layered model errors"),
        "/*CSS*/": _asset("report.css"),
        "/*JS*/": _asset("report.js"),
        "<!--DATA-->": _script_json(data),
        "<!--SUMMARY-->": "".join(f"<li>{_esc(s)}</li>" for s in summary_lines),
        "<!--REPRODUCTION-->": _reproduction_html(checks),
        "<!--OVERVIEW-->": _overview_html(data["overview"]),
        "<!--TABLES-->": _tables_html(tables),
        "<!--FIGURE1-->": _figure1_html(figure1),
        "<!--THRESHOLDS-->": _esc(f"holds: ≥ {HOLDS_AT:.0%} of the comparisons agree; partly: ≥ {PARTLY_AT:.0%}; "
                                  f"similar: ratio ≤ {SIMILAR_RATIO}; close: ≤ {CLOSE_RATIO}; indistinguishable: ≤ "
                                  f"{INDISTINGUISHABLE_RATIO}; identical: relative difference ≤ {IDENTICAL_REL:g}"),
    }
    data_key = "<!--DATA-->"
    for k, v in [*((k, v) for k, v in subs.items() if k != data_key), (data_key, subs[data_key])]:
        if k not in page:
            raise ReportError(f"{ASSETS / 'index.html'}: placeholder {k} missing")
        page = page.replace(k, v) if k != data_key else page.replace(k, v, 1)   # the data goes in last
    return page
