"""``gonio models``, ``gonio evaluate``, ``gonio fit`` and ``gonio plot``: the models against one
simulated file (the comparison harness, :mod:`models.compare`, and fitted models, :mod:`models.fitted`)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from goniometer.cli.common import (UsageError, add_overwrite, at_least_one, incident_list, output_path, usage_errors,
                                   whole_number)
from models.commands.references import add_reference_options, load_reference


def register(sub) -> None:
    """Add ``fit``, ``models``, ``evaluate`` and ``plot`` to the ``gonio`` sub-command parser."""
    p = sub.add_parser("fit", help="fit a compact model (hp15, ggx1, ggx2) to the BRDF slices of a file "
                                   "(a simulation, or a measured file with --stack)")
    p.add_argument("file", metavar="FILE", help="a slices file, or a measured MERL .binary / RGL .bsdf")
    p.add_argument("--model", required=True, choices=("hp15", "ggx1", "ggx2"), help="the compact model (required)")
    p.add_argument("--json", action="store_true", help="print one JSON object (default: a table)")
    p.add_argument("--starts", type=whole_number, default=4, help="optimiser starts (default 4)")
    p.add_argument("--seed", type=whole_number, default=0, help="seed of the optimiser starts (default: %(default)s)")
    p.add_argument("--weighting", choices=("paper", "eq4"), default="paper",
                   help="the paper's eq. 29 weighting (default) or eq. 4 directly")
    add_reference_options(p)
    p.set_defaults(func=cmd_fit)

    p = sub.add_parser("models", help="list the analytic models and what they support")
    p.add_argument("--json", action="store_true", help="print one JSON object (default: a table)")
    p.set_defaults(func=cmd_models)

    p = sub.add_parser("evaluate", help="integrate models onto a simulated (or measured) file and print their errors",
                       description="Integrate models onto the cells of a simulated (or measured) file and print "
                                   "their errors (RMSE of Bati 2019 eq. 4) beside the reference's noise floor. On a "
                                   "polarized file (gonio simulate --polarized) every model keeps its intensity "
                                   "error against M00 (the file's value), and polarized models (mitsuba:FILE of "
                                   "conductor, roughconductor, dielectric or pplastic; a plugin Model with "
                                   "polarized = True) also get the RMSE and noise floor of each of the 16 Mueller "
                                   "elements, per channel (docs/polarization.md, 'Models on polarized files').")
    p.add_argument("file", metavar="FILE", help="a slices file, or a measured MERL .binary / RGL .bsdf (with --stack)")
    p.add_argument("--model", action="append", metavar="NAME",
                   help="a model to evaluate: a name of gonio models, python:MODULE:NAME or mitsuba:FILE.xml|.json "
                        "(repeatable; default: all that apply)")
    p.add_argument("--json", action="store_true", help="print one JSON object (default: a table)")
    p.add_argument("--save-slices", dest="save_slices", metavar="OUT.h5",
                   help="write the integrated model slices (default: not written)")
    p.add_argument("--subcells", type=whole_number, default=5, help="sub-cells per cell axis (default 5)")
    p.add_argument("--isotropize", choices=("mean",),
                   help="let isotropic models evaluate an anisotropic stack with the mean roughness (noted in the "
                        "output) (default: isotropic models skip anisotropic stacks)")
    add_overwrite(p)
    add_reference_options(p)
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser("plot", help="figures of one simulated file (incident plane, top views, bounce orders; a "
                                    "polarized file's Mueller elements and degree of polarization), "
                                    "optionally with models")
    p.add_argument("file", metavar="FILE.h5")
    p.add_argument("--out", required=True, metavar="DIR", help="directory for the PNG figures")
    p.add_argument("--model", action="append", metavar="NAME",
                   help="draw this model too (repeatable; 'all': every model that supports the stack) "
                        "(default: the simulation alone)")
    p.add_argument("--incident", metavar="THETAS",
                   help="only these incident angles of the file, e.g. 0,60 (default: all of the file's)")
    p.add_argument("--subcells", type=whole_number, default=5,
                   help="sub-cells per cell side when integrating models (default: %(default)s)")
    p.add_argument("--isotropize", choices=("mean",),
                   help="feed isotropic models the mean roughness (default: isotropic models skip anisotropic stacks)")
    p.add_argument("--json", action="store_true",
                   help="print the figure paths (and the model errors) as JSON (default: one path a line)")
    add_overwrite(p)
    p.set_defaults(func=cmd_plot)



def cmd_models(args: argparse.Namespace) -> int:
    from models.registry import FITTED, catalogue, sources
    models = catalogue()
    source = sources()
    if args.json:
        print(json.dumps({n: {"description": m.description, "sides": list(m.sides), "fitted": n in FITTED,
                              "anisotropic": bool(m.anisotropic), "scattering": bool(m.scattering),
                              "films": bool(getattr(m, "films", False)),
                              "on_request": bool(getattr(m, "on_request", False)), "source": source[n]}
                          for n, m in models.items()}, indent=2))
        return 0
    width = max(len(n) for n in models)
    described = max(len("description"), *(len(m.description) for m in models.values()))
    print(f"{'model':<{width}}  {'sides':9s} {'kind':8s}  {'aniso':5s}  {'scatter':7s}  {'description':<{described}}  "
          f"source")
    for name, m in models.items():
        kind = "fitted" if name in FITTED else "analytic"
        scat = "scatter" if m.scattering else "-"
        aniso = "yes" if m.anisotropic else "-"
        print(f"{name:<{width}}  {'/'.join(x.upper() for x in m.sides):9s} {kind:8s}  {aniso:5s}  {scat:7s}  "
              f"{m.description:<{described}}  {source[name]}")
    print("(source: built-in, or the distribution (and version) whose plugin registers the model, entry-point group "
          "goniometer.models; --model also takes python:MODULE:NAME and mitsuba:FILE.xml|.json, docs/models.md)")
    print("(aniso: evaluates anisotropic stacks; the others skip them unless --isotropize mean)")
    print("(scatter: accepts scattering media (scattering_albedo > 0); the belcour-* models need g >= 0.1)")
    films = [n for n, m in models.items() if getattr(m, "films", False) and n not in FITTED]
    if films:
        print(f"(thin films on interfaces: {', '.join(films)}; the others skip filmed stacks, docs/spectral.md)")
    asked = [n for n, m in models.items() if getattr(m, "on_request", False)]
    if asked:
        print(f"(evaluated only when named with --model: {', '.join(asked)})")
    print("(fitted models are fitted to a file on request: gonio fit FILE.h5 --model hp15|ggx1|ggx2, "
          "or gonio evaluate FILE.h5 --model hp15-fit)")
    return 0


def cmd_fit(args: argparse.Namespace) -> int:
    from goniometer.files import slices as store
    from models.base import ModelError
    from models.fitted import fit
    from models.compare.errors import coverage
    reference = load_reference(args)
    try:
        if reference.brdf is None:
            raise ModelError(f"{args.model}: the file has no BRDF slices to fit")
        cov = coverage(reference, "brdf")
        if cov.cells and cov.warning():   # at once, before the fit's minutes (none: fit refuses it)
            print(f"warning: {args.file}: {cov.warning()}", file=sys.stderr)

        def progress(start: int, cost: float) -> None:
            if not args.json:
                print(f"start {start}: cost {cost:.6g}", file=sys.stderr)

        result = fit(reference, args.model, starts=args.starts, seed=args.seed, weighting=args.weighting,
                     progress=progress)
    except (store.StoreError, ModelError) as e:
        raise UsageError(f"{args.file}: {e}") from None
    d = result.to_json()
    if args.json:
        print(json.dumps(d, indent=2))
        return 0
    print(f"{reference.stack.name}: {result.model.name} fitted to the BRDF of {len(reference.theta_deg)} incident "
          f"direction(s) ({result.weighting} weighting, {result.starts} start(s), {result.elapsed_s:.1f} s)")
    grazing = " (the paper weighting leaves out the grazing ones)" if result.weighting == "paper" else ""
    print(f"fitted on {result.n_cells:,} cells{grazing}; the reference has valid data in {cov.text()} of its grid")
    print(("converged: " if result.converged else "NOT converged: ") + result.message)
    for k, v in result.params.items():
        print(f"  {k:8s} = {v}")
    if result.errors:
        e = result.errors["total"]
        print(f"RMSE (eq. 4) mean {e['rmse_mean']:.4e}  (R G B) {' '.join(f'{x:.3e}' for x in e['rmse'])}  "
              f"luminance {e['rmse_luminance']:.3e}  noise floor "
              + (f"{e['noise_floor_mean']:.2e}" if e["noise_floor_mean"] is not None else "unknown (a measurement)")
              + f"  over {e['cells']:,} of {e['cells_total']:,} cells")
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    from goniometer.files import slices as store
    from models.base import ModelError
    from models.commands.failures import report_failures
    from models.evaluation import evaluate, save_slices

    at_least_one(args.subcells, "--subcells", "the number of sub-cells per cell side")
    if args.save_slices:
        output_path(args.save_slices, inputs=[args.file], overwrite=args.overwrite, option="--save-slices")
    reference = load_reference(args, subcells=args.subcells)

    def progress(name: str) -> None:
        note = _cost_line(name, reference, args.subcells)
        print(f"integrating {name}" + (f" ({note})" if note else "") + " ...", file=sys.stderr)
    try:
        ev = evaluate(reference, args.model or None, s=args.subcells, isotropize=args.isotropize,
                      progress=None if args.json else progress)
    except (store.StoreError, ModelError) as e:
        raise UsageError(f"{args.file}: {e}" if not str(e).startswith(str(args.file)) else str(e)) from None
    if not ev.errors and not ev.failed:
        raise UsageError(no_model_applies(str(args.file), ev))
    if args.save_slices:
        save_slices(args.save_slices, reference, ev)
    warning = ev.coverage.warning() if ev.coverage is not None else None
    if warning:
        print(f"warning: {args.file}: {warning}", file=sys.stderr)
    if args.json:
        print(json.dumps(ev.to_json(), indent=2))
        return report_failures(ev.failed)
    support = f" over {ev.coverage.text()}" if ev.coverage is not None else ""
    print(f"{ev.material} ({ev.category}): RMSE of eq. 4 on the {ev.side.upper()}{support}, "
          f"{len(reference.theta_deg)} incident direction(s), {args.subcells}x{args.subcells} sub-cells")
    if ev.errors:
        width = max([16] + [len(n) for n in ev.errors])
        noisy = any("model_noise_mean" in e["total"] for e in ev.errors.values())
        print(f"{'model':{width}s} {'internal mean':>13s} {'(R G B)':>30s} {'luminance':>10s} {'its floor':>9s} "
              f"{'total mean':>11s} {'its floor':>9s}" + (f" {'model noise':>11s} {'(total)':>9s}" if noisy else ""))
        for name, e in ev.errors.items():
            print(table_row(name, e["internal"], e["total"], width) + (noise_cells(e["internal"], e["total"]) if noisy
                                                                        else ""))
        print(f"('internal' = {ev.internal_compares}; each floor = the error a perfect model would show against this "
              f"reference on the part beside it, channel mean)")
        if noisy:
            print("(model noise = a stochastic model's own noise on the internal part and on the total, computed as "
                  "the floor; '-' for an exact model)")
    if ev.polarized:
        for line in mueller_block(ev):
            print(line)
    for name, note in ev.approximations.items():
        print(f"note {name}: {note}")
    if ev.reference_note:
        print(f"note: {ev.reference_note}")
    for name, reason in ev.skipped.items():
        print(f"skipped {name}: {reason}")
    if args.save_slices:
        print(f"wrote {args.save_slices}")
    return report_failures(ev.failed)


def _cost_line(name: str, reference, subcells: int) -> str | None:
    """The cost a model states for integrating onto ``reference``'s cells (``Model.cost_note``: the
    stochastic ones), or None."""
    from models import registry
    from models.evaluation import comparison_side
    model = registry.models_for([name]).get(name)
    sd = reference.brdf if comparison_side(reference.stack) == "brdf" else reference.btdf
    if model is None or sd is None:
        return None
    return model.cost_note(len(reference.theta_deg) * sd.grid.n_theta * sd.grid.n_phi * subcells * subcells)


def no_model_applies(file: str, ev) -> str:
    """The one line of an evaluation where every model was skipped (none evaluated, none failed)."""
    hint = ("; --isotropize mean lets the isotropic models evaluate it with the mean roughness"
            if any("--isotropize mean" in r for r in ev.skipped.values()) else "")
    fitted = "; or fit a compact model to it (--model ggx1-fit)" if ev.side == "brdf" else ""
    return (f"{file}: no model applies to {ev.material} (judged on its {ev.side.upper()}): all {len(ev.skipped)} "
            f"model(s) skip it{hint}; name one (--model NAME) to see why it does not apply{fitted}")


def mueller_block(ev) -> list[str]:
    """The lines ``gonio evaluate`` prints on a polarized file: per polarized model a 4 x 4 grid,
    each element's channel-mean RMSE over its noise floor (1/sr, ``models.compare.errors.mueller_errors``),
    then one line per reason some models are judged on the intensity only, naming them."""
    lines = [f"polarized file: the intensity errors above compare M00 (the file's value); the Mueller matrices "
             f"of polarized models, element by element in the file's s/p frames (whole {ev.side.upper()}):"]
    for name, e in ev.mueller.items():
        note = f" ({e['note']})" if e.get("note") else ""
        lines.append(f"{name}: RMSE of M_ij / its noise floor (1/sr, channel mean; R G B in --json){note}")
        for i in range(4):
            cells = [f"{e['mueller_rmse_mean'][i][j]:8.2e}/{e['mueller_noise_mean'][i][j]:8.2e}" for j in range(4)]
            lines.append(f"  M{i}j " + "  ".join(cells))
    if not ev.mueller:
        lines.append("  (no evaluated model gives Mueller matrices)")
    by_reason: dict[str, list[str]] = {}
    for name, reason in ev.intensity_only.items():     # one line per reason (every scalar model shares one)
        by_reason.setdefault(reason, []).append(name)
    for reason, names in by_reason.items():
        lines.append(f"intensity only {', '.join(names)}: {reason}")
    return lines


def table_row(name: str, internal: dict, total: dict, width: int = 16) -> str:
    """One line of ``gonio evaluate``'s table: each part's channel-mean RMSE beside its own noise
    floor (the total error is compared with the total floor, the internal error with the internal
    floor; ``models.compare.errors``)."""
    rgb = " ".join(f"{x:9.3e}" for x in internal["rmse"])

    def floor(x) -> str:
        return f"{x:9.2e}" if x is not None else f"{'unknown':>9s}"
    return (f"{name:{width}s} {internal['rmse_mean']:13.4e} {rgb:>30s} {internal['rmse_luminance']:10.3e} "
            f"{floor(internal['noise_floor_mean'])} {total['rmse_mean']:11.4e} {floor(total['noise_floor_mean'])}")


def noise_cells(internal: dict, total: dict) -> str:
    """The two columns that ``gonio evaluate``'s table adds when a stochastic model reports its own
    noise (``model_noise_mean`` of each part, ``models.compare.errors``), ``-`` for an exact model."""
    cells = [f"{e['model_noise_mean']:.2e}" if "model_noise_mean" in e else "-" for e in (internal, total)]
    return f" {cells[0]:>11s} {cells[1]:>9s}"


def cmd_plot(args: argparse.Namespace) -> int:
    from models.base import ModelError
    from models.commands.failures import report_failures
    from models.report import ReportError, plot_file
    from models.report.mueller import NOTE as POLARIZATION_NOTE, plot_polarization

    at_least_one(args.subcells, "--subcells", "the number of sub-cells per cell side")
    if Path(args.out).exists() and not Path(args.out).is_dir():
        raise UsageError(f"--out: {args.out} is an existing file; give a directory for the figures")
    # a finished set of figures holds energy.png (the first figure plot_file draws)
    output_path(args.out, inputs=[args.file], overwrite=args.overwrite, directory=True, marker="energy.png")
    incidents = None
    if args.incident is not None:
        thetas, _ = incident_list(args.incident)
        incidents = thetas
    try:
        r = plot_file(args.file, args.out, args.model, incidents, subcells=args.subcells, isotropize=args.isotropize)
        polarization = plot_polarization(args.file, args.out, incidents)   # none for a scalar file
    except (ReportError, ModelError) as e:
        raise UsageError(f"{args.file}: {e}" if not str(e).startswith(str(args.file)) else str(e)) from None
    if polarization:
        r["figures"] += polarization
        r["polarization"] = POLARIZATION_NOTE
    failed = (r.get("evaluation") or {}).get("failed", {})
    if args.json:
        print(json.dumps(r, indent=2))
        return report_failures(failed)
    print(f"wrote {len(r['figures'])} figures into {args.out}:")
    for p in r["figures"]:
        print(f"  {p}")
    if "reference" in r:
        print(f"({r['reference']})")
    if "polarization" in r:
        print(f"({r['polarization']})")
    return report_failures(failed)


