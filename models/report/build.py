"""``build_report``: a report over a results directory of ``gonio database simulate`` (Bati et al.
2019: error tables, figure-4-style plots, per-material figures, the reproduction checks of section
4.2 and a static HTML browser).

Every finished material is evaluated with the models of :mod:`models.registry` (whatever
:func:`models.evaluation.evaluate` applies to it); evaluations and figures are cached in the
report directory, so a rerun only redoes what changed. What the directory holds, its keys and the
caching rules: ``docs/report.md``.

A figure never stops a report: a figure that cannot be drawn (or whose reference cannot be shown)
is listed with its reason in ``errors.json`` (``not_drawn`` of the material's records), in the
summary's ``not_drawn`` and warnings, and the errors, tables and reproduction checks are written
whatever the figures do.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

from models import registry
from models.base import ModelError
from models.report.appendix_e import appendix_e_markdown, appendix_e_section, is_appendix_e
from models.report.evaluation import cache_paths, evaluate_material, model_code_key, report_code_key, warm_up_models
from models.report.figures import material_figures, model_style
from models.report.files import read_json, safe_part, write_json, write_text
from models.report.multiple_scattering import evaluate_twins, multiple_scattering_markdown, multiple_scattering_section
from models.report.html import html_data, render_html
from models.report.panels import save_figure
from models.report.polarization import polarization_markdown, polarization_section
from models.report.reproduction import reproduction_checks, reproduction_markdown
from models.report.results import MaterialResult, ReportError, ReportMaterial, open_results
from models.report.spheres import FIGURE1_FILE, figure1, is_figure1, material_spheres
from models.report.tables import category_csv, category_markdown, error_records, errors_figure
from models.workers import check_jobs, run_in_workers

#: ``progress(done, total, message)``: once the inputs are read (``0``, ``"loading the models ..."``),
#: before each material (``done`` = materials finished so far, ``"<material>: evaluating ..."``) and
#: once after it
Progress = Callable[[int, int, str], None]


@dataclass
class ReportSummary:
    """What :func:`build_report` did."""

    out_dir: Path
    index_html: Path
    errors_json: Path
    materials: list[str] = field(default_factory=list)
    records: int = 0
    evaluated: list[str] = field(default_factory=list)
    reused: list[str] = field(default_factory=list)
    figures_drawn: list[str] = field(default_factory=list)
    figures_reused: list[str] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)
    failed: dict[str, dict[str, str]] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    reproduction: list[dict] = field(default_factory=list)
    #: the appendix E section (:mod:`models.report.appendix_e`) when the results hold that database
    appendix_e: dict | None = None
    #: the multiple-scattering table (:mod:`models.report.multiple_scattering`) with ``compare_to``
    multiple_scattering: dict | None = None
    #: the polarization table (:mod:`models.report.polarization`) with ``compare_to`` naming the scalar
    #: twin of polarized results
    polarization: dict | None = None
    #: Bati 2019 figure 1 (:func:`models.report.spheres.figure1`) when the results hold its material
    figure1: dict | None = None
    #: figures not drawn, or drawn without their reference: ``[{"material", "figure", "reason"}]``
    #: (``material`` None for the figure-4 plots of a category or of all)
    not_drawn: list[dict] = field(default_factory=list)
    elapsed_s: float = 0.0


def _figure_step(res: MaterialResult | None, figure: str, summary: ReportSummary | None, draw: Callable[[], object],
                 default: object) -> object:
    """``draw()``, or ``default`` when it raises: the failure is recorded as a figure not drawn (for
    the material ``res``, or for the report when None) and never stops the report."""
    try:
        return draw()
    except Exception as e:   # noqa: BLE001 -- any figure failure: the report goes on without that figure
        reason = f"{type(e).__name__}: {e}"
        if res is not None:
            res.missing_figure(figure, reason)
        else:
            summary.not_drawn.append({"material": None, "figure": figure, "reason": reason})
        return default


@dataclass(frozen=True)
class _MaterialJob:
    """What one material's evaluation and figures need (sent to a worker process)."""

    material: ReportMaterial
    out: Path
    models: tuple[str, ...] | None
    subcells: int
    code: str
    isotropize: str | None
    styles: dict
    incidents: tuple[float, ...] | None
    report_key: str


@dataclass
class _MaterialDone:
    """One material's result (its slices dropped: the figures are on disk) and what it cost."""

    res: MaterialResult
    drawn: bool | None
    evaluated_s: float
    figures_s: float
    #: the time of each model that states its cost (``Model.cost_note``: the stochastic ones)
    stochastic_s: dict[str, float] = field(default_factory=dict)


def _material_step(job: _MaterialJob) -> _MaterialDone:
    """Evaluate one material (or read its cached evaluation) and draw its figures and spheres: the
    work of one material, the same here or in a worker process (:mod:`models.workers`)."""
    models = list(job.models) if job.models is not None else None
    incidents = list(job.incidents) if job.incidents is not None else None
    t1 = time.perf_counter()
    res, ref = evaluate_material(job.material, job.out, models, job.subcells, job.code, job.isotropize)
    t2 = time.perf_counter()
    drawn = _figure_step(res, "figures", None,
                         lambda: material_figures(res, ref, job.out, job.styles, incidents, job.report_key), None)
    if drawn is None:
        res.figures = {}
    spheres = _figure_step(res, "spheres", None, lambda: material_spheres(res, ref, job.out, job.report_key),
                           {"spheres": [], "spheres_note": "no spheres: they could not be drawn"})
    for x in spheres.pop("not_drawn", []):
        res.missing_figure(x["figure"], x["reason"])
    res.figures = {**res.figures, **spheres}
    t3 = time.perf_counter()
    res.slices = None   # free memory: the figures are on disk
    return _MaterialDone(res, drawn, t2 - t1, t3 - t2, _stochastic_seconds(job, res))


def _stochastic_seconds(job: _MaterialJob, res: MaterialResult) -> dict[str, float]:
    """The time each model that states its cost took on this material (a fresh evaluation only)."""
    if res.from_cache:
        return {}
    seconds = (read_json(cache_paths(job.out, res.material.name)[0]) or {}).get("model_elapsed_s", {})
    analytic = registry.all_models()
    return {n: t for n, t in seconds.items() if n in analytic and analytic[n].cost_note(1) is not None}


def _done_message(name: str, d: _MaterialDone) -> str:
    """The progress line of a finished material (with the time of each stochastic model: the ones
    that state their cost, ``Model.cost_note``)."""
    res = d.res
    n_models = len(res.evaluation["models"])
    ev = "from cache" if res.from_cache else f"evaluated in {d.evaluated_s:.1f} s"
    if d.stochastic_s:
        ev += " (" + ", ".join(f"{n} {t:.1f} s, stochastic" for n, t in d.stochastic_s.items()) + ")"
    fg = (f"drawn in {d.figures_s:.1f} s" if d.drawn else "up to date" if d.drawn is not None else "not drawn")
    if res.not_drawn:
        fg += f" ({len(res.not_drawn)} not drawn or without their reference)"
    failed = len(res.evaluation.get("failed", {}))
    return f"{name}: {n_models} model(s) {ev}" + (f", {failed} failed" if failed else "") + f"; figures {fg}"


def build_report(results_dir: str | Path, out_dir: str | Path, *, models: Sequence[str] | None = None,
                 subcells: int = 5, progress: Progress | None = None,
                 incidents_for_figures: Sequence[float] | None = None,
                 definition: str | Path | None = None, fits: bool = False,
                 isotropize: str | None = None, compare_to: str | Path | None = None,
                 jobs: int = 1) -> ReportSummary:
    """Evaluate every finished material of ``results_dir`` and write the report into ``out_dir``.

    ``models``: model names (default: every model of the registry that applies to each
    material); ``subcells``: sub-cells per cell axis for the model integration;
    ``progress(done, total, message)``: called once the inputs are read, before each material and
    once it is done (:data:`Progress`);
    ``incidents_for_figures``: incident elevations (degrees) to draw figures for (default all;
    errors always use every incident); ``definition``: the database definition when the one named
    in the manifest has moved; ``fits``: also fit the compact models (hp15-fit, ggx1-fit,
    ggx2-fit) to every BRDF (seconds to minutes each); ``isotropize="mean"``: let isotropic models
    evaluate anisotropic stacks with the mean roughness (noted per material); ``compare_to``: the
    results directory of the single-scattering twin of this (multiple-scattering) database, which
    adds ``multiple-scattering.md`` / ``.json`` (:mod:`models.report.multiple_scattering`). Raises
    :class:`ReportError` on bad input, and when no (material, model) pair could be judged because
    the references have no valid cell. A model that fails on a material (or a material whose
    reference has no valid cell) is recorded under ``failed`` and in ``warnings`` (one line per
    material and reason), and the report goes on. ``jobs``: worker processes that evaluate the
    materials and draw their figures side by side (:mod:`models.workers`; 1: one after the other
    here); the report's files are the same whatever ``jobs`` (``docs/report.md``, "Workers").
    """
    if fits:
        models = list(dict.fromkeys([*(models or registry.all_models()), *registry.FITTED]))
    t0 = time.perf_counter()
    rd, out = Path(results_dir), Path(out_dir)
    if rd.exists() and out.exists() and rd.resolve() == out.resolve():
        raise ReportError(f"{out}: the report must go to its own directory, not the results directory itself")
    if out.exists() and not out.is_dir():
        raise ReportError(f"{out}: exists and is not a directory")
    if subcells < 1:
        raise ReportError(f"subcells = {subcells}: must be >= 1")
    try:
        jobs = check_jobs(jobs)
    except ValueError as e:
        raise ReportError(str(e)) from None
    if models is not None:
        try:
            registry.check_names(models)
        except ModelError as e:
            raise ReportError(str(e)) from None
        models = list(dict.fromkeys(models))
    manifest, materials, missing, warnings = open_results(rd, definition, exclude=out)
    if progress is not None:
        progress(0, len(materials), "loading the models ...")
    out.mkdir(parents=True, exist_ok=True)
    summary = ReportSummary(out, out / "index.html", out / "errors.json", missing=missing, warnings=list(warnings))
    code, report_key = model_code_key(), report_code_key()
    styles = model_style([*registry.all_models(), *(models or ())])
    steps = [_MaterialJob(mat, out, None if models is None else tuple(models), subcells, code, isotropize, styles,
                          None if incidents_for_figures is None else tuple(incidents_for_figures), report_key)
             for mat in materials]
    finished = [0]

    def start(k: int) -> None:
        if progress is not None:
            progress(finished[0], len(materials), f"{materials[k].name}: evaluating ...")

    def done(k: int, d: _MaterialDone) -> None:
        finished[0] += 1
        if progress is not None:
            progress(finished[0], len(materials), _done_message(materials[k].name, d))

    finished_steps = run_in_workers(_material_step, steps, jobs, done=done, start=start, writes_under=out,
                                    warm_up=lambda: warm_up_models(materials, models, subcells, isotropize))
    results: list[MaterialResult] = []
    for mat, d in zip(materials, finished_steps):
        res = d.res
        results.append(res)
        summary.materials.append(mat.name)
        (summary.reused if res.from_cache else summary.evaluated).append(mat.name)
        if d.drawn is not None:
            (summary.figures_drawn if d.drawn else summary.figures_reused).append(mat.name)
        if res.evaluation.get("failed"):
            summary.failed[mat.name] = dict(res.evaluation["failed"])
            summary.warnings.extend(failure_warnings(mat.name, res.evaluation["failed"]))
    no_cells = [r.material.name for r in results if r.evaluation.get("cells") == 0]
    if no_cells and not any(r.evaluation["models"] for r in results):
        raise ReportError(f"{rd}: nothing to report: no (material, model) pair was judged, as the reference of "
                          f"{len(no_cells)} material(s) ({', '.join(no_cells[:3])}{' ...' if len(no_cells) > 3 else ''}) "
                          f"has no valid cell; the evaluations are cached in {out / 'cache'}")
    if incidents_for_figures is not None:
        drawn_at = {i["theta"] for r in results for i in r.figures.get("incidents", [])}
        unknown_angles = [w for w in incidents_for_figures if not any(abs(w - t) < 1e-6 for t in drawn_at)]
        if unknown_angles:
            summary.warnings.append(f"no material has the incident direction(s) {unknown_angles} asked for figures")
    fig1_res = next((r for r in results if is_figure1(r.material)), None)
    summary.figure1 = _figure_step(fig1_res, FIGURE1_FILE, summary, lambda: figure1(results, out, report_key), None)
    if summary.figure1 is not None:
        for x in summary.figure1.pop("not_drawn", []):
            fig1_res.missing_figure(x["figure"], x["reason"])
    for r in results:
        summary.not_drawn.extend(r.not_drawn)
    _write_outputs(results, manifest, out, styles, summary, rd, subcells, code)
    if is_appendix_e([r.material for r in results]):
        sec = appendix_e_section(results)
        write_json(out / "appendix-e.json", sec)
        write_text(out / "appendix-e.md", appendix_e_markdown(sec))
        summary.appendix_e = sec
    if compare_to is not None:
        single, twin_warnings = evaluate_twins(compare_to, out, [r.material.name for r in results], models,
                                               subcells, code, isotropize, jobs)
        summary.warnings.extend(twin_warnings)
        if _polarized(results):
            sec = polarization_section(single, results)
            name, markdown = "polarization", polarization_markdown
        else:
            sec = multiple_scattering_section(single, results)
            name, markdown = "multiple-scattering", multiple_scattering_markdown
        if not sec["materials"]:
            raise ReportError(f"--compare-to {compare_to}: no material name in common with {rd}")
        write_json(out / f"{name}.json", sec)
        write_text(out / f"{name}.md", markdown(sec))
        if name == "polarization":
            summary.polarization = sec
        else:
            summary.multiple_scattering = sec
    summary.elapsed_s = time.perf_counter() - t0
    return summary


def _polarized(results: list[MaterialResult]) -> bool:
    """True when the results are a polarized run's (their files say so, ``/simulation@polarized``)."""
    import h5py
    with h5py.File(results[0].material.path, "r") as f:
        return bool(f["simulation"].attrs.get("polarized", False))


def failure_warnings(material: str, failed: dict[str, str]) -> list[str]:
    """The warnings of one material's failed models: one line per distinct reason, naming the models
    that failed for it (a reference without a valid cell fails every model for one reason)."""
    by_reason: dict[str, list[str]] = {}
    for name, msg in failed.items():
        by_reason.setdefault(msg, []).append(name)
    return [f"{material}: {', '.join(names)} failed: {msg}" for msg, names in by_reason.items()]


def _write_outputs(results: list[MaterialResult], manifest: dict, out: Path, styles: dict, summary: ReportSummary,
                   rd: Path, subcells: int, code: str) -> None:
    # the errors, tables and checks first: they never depend on a figure
    records = error_records(results)
    write_json(out / "errors.json", records)
    summary.records = len(records)
    by_cat: dict[str, list[MaterialResult]] = {}
    for r in results:
        by_cat.setdefault(r.material.category, []).append(r)
    tables = {}
    for cat, res in by_cat.items():
        safe = safe_part(cat)
        write_text(out / "tables" / f"{safe}.csv", category_csv(res))
        write_text(out / "tables" / f"{safe}.md", category_markdown(cat, res))
        tables[cat] = {"csv": f"tables/{safe}.csv", "md": f"tables/{safe}.md"}
    run = {"database": manifest.get("database", rd.name), "quality": manifest.get("quality"),
           "rays_per_slice": manifest.get("rays_per_slice")}
    checks = reproduction_checks(results, run)
    summary.reproduction = checks
    write_json(out / "reproduction.json", checks)
    write_text(out / "reproduction.md", reproduction_markdown(checks))
    used = {n for r in results for n in r.evaluation["models"]}
    styles = {n: s for n, s in styles.items() if n in used}
    overview = {}

    def plot(groups: dict[str, list[MaterialResult]], src: str) -> bool:
        """The figure-4 plot of ``groups`` into ``out / src``; False (recorded) if it cannot be drawn."""
        return _figure_step(None, src, summary, lambda: _save_errors_figure(groups, styles, out / src), False)

    for cat, res in by_cat.items():
        src = f"figures/errors_{safe_part(cat)}.png"
        if any(r.evaluation["models"] for r in res) and plot({cat: res}, src):
            overview[cat] = src
    plotted = {c: r for c, r in by_cat.items() if c in overview}
    if plotted and plot(plotted, "figures/errors_overview.png"):
        overview["_all"] = "figures/errors_overview.png"
    summary.warnings.extend(f"{x['material'] or 'report'}: {x['figure']} not drawn or drawn without its reference: "
                            f"{x['reason']}" for x in summary.not_drawn)
    meta = {**run, "results_dir": os.path.relpath(rd, out),
            "subcells": subcells, "model_code": code,
            "generated": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
            "materials": len(results), "missing": summary.missing, "warnings": summary.warnings,
            "not_drawn": summary.not_drawn}
    data = html_data(results, styles, overview, meta)
    lines = [f"database {meta['database']}, quality {meta['quality']} ({meta['rays_per_slice']:,} rays per slice)"
             if isinstance(meta["rays_per_slice"], int) else f"database {meta['database']}",
             f"{len(results)} material(s), {len(records)} (material, model) errors, models integrated with "
             f"{subcells}×{subcells} sub-cells per cell; model code {code}",
             f"generated {meta['generated']}"]
    if summary.missing:
        lines.append(f"{len(summary.missing)} material(s) of the definition not simulated yet: "
                     + ", ".join(summary.missing[:8]) + (" …" if len(summary.missing) > 8 else ""))
    lines += [f"warning: {w}" for w in summary.warnings]
    write_text(out / "index.html", render_html(data, checks, tables, lines, summary.figure1))


def _save_errors_figure(groups: dict[str, list[MaterialResult]], styles: dict, path: Path) -> bool:
    """Draw :func:`models.report.tables.errors_figure` of ``groups`` into ``path``; True."""
    save_figure(errors_figure(groups, styles), path)
    return True
