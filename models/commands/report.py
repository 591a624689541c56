"""``gonio report``: error tables, figures and an HTML browser for a simulated database."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from goniometer.cli.common import (EXIT_INTERRUPTED, UsageError, add_overwrite, at_least_one, incident_list,
                                   output_path, progress_bar, whole_number)


def register(sub) -> None:
    """Add ``report`` to the ``gonio`` sub-command parser."""
    p = sub.add_parser("report", help="error tables, figures and an HTML browser for a simulated database")
    p.add_argument("results", metavar="RESULTS_DIR")
    p.add_argument("--out", required=True, metavar="DIR", help="the report directory (required)")
    p.add_argument("--model", action="append", metavar="NAME", help="models to evaluate (default: all that apply)")
    p.add_argument("--subcells", type=whole_number, default=5,
                   help="sub-cells per cell side when integrating models (default: %(default)s)")
    p.add_argument("--incidents", metavar="LIST", help="incident elevations to draw figures for (default: all)")
    p.add_argument("--definition", metavar="CONFIG.toml", help="the database definition, if it has moved "
                        "(default: the path recorded in the results' database.json)")
    p.add_argument("--fits", action="store_true", help="also fit hp15, ggx1 and ggx2 to every BRDF (slow)")
    p.add_argument("--isotropize", choices=("mean",),
                   help="let isotropic models evaluate anisotropic stacks with the mean roughness "
                        "(default: isotropic models skip anisotropic stacks)")
    p.add_argument("--compare-to", metavar="TWIN_RESULTS_DIR",
                   help="results of the twin of this database: the single-scattering twin of a multiple-scattering "
                        "database (adds multiple-scattering.md/.json), or the scalar twin of a polarized one (adds "
                        "polarization.md/.json, docs/polarization.md) (default: no comparison)")
    add_jobs(p, "evaluate the materials and draw their figures side by side; the report's files are the same "
                "whatever N")
    add_overwrite(p)
    p.set_defaults(func=cmd_report)


def add_jobs(p, what: str) -> None:
    """``--jobs N``: worker processes (``models.workers``), default :func:`default_jobs`."""
    p.add_argument("--jobs", type=whole_number, default=default_jobs(), metavar="N",
                   help=f"worker processes that {what} (default: the cores, %(default)s)")


def default_jobs() -> int:
    """The cores this process may run on (``os.sched_getaffinity``), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:   # not on Linux
        return max(1, os.cpu_count() or 1)



def cmd_report(args: argparse.Namespace) -> int:
    at_least_one(args.subcells, "--subcells", "the number of sub-cells per cell side")
    at_least_one(args.jobs, "--jobs", "the number of worker processes")
    # a finished report holds index.html (written last); an unfinished one is resumed from its cache
    inputs = [args.results] + [x for x in (args.definition, args.compare_to) if x]
    output_path(args.out, inputs=inputs, overwrite=args.overwrite, directory=True, marker="index.html")
    incidents = None
    if args.incidents:
        incidents, _ = incident_list(args.incidents)
    from models.commands.failures import EXIT_MODEL_FAILED
    from models.report import ReportError, build_report
    bar = progress_bar(None, "report", unit="material", unit_scale=False)

    def progress(done: int, total: int, message: str) -> None:
        if done == 0:   # loading the models, then the first material (a first run compiles the models'
            # functions there): said at once, not at the first tenth
            bar.write(f"report: {total} material(s); {message}", file=sys.stderr)
        bar.total = total
        bar.n = done
        bar.set_postfix_str(message)
        bar.refresh()

    try:
        with bar:
            summary = build_report(args.results, args.out, models=args.model or None, subcells=args.subcells,
                                   progress=progress, incidents_for_figures=incidents, definition=args.definition,
                                   fits=args.fits, isotropize=args.isotropize,
                                   compare_to=args.compare_to, jobs=args.jobs)
    except ReportError as e:
        raise UsageError(str(e)) from None
    except KeyboardInterrupt:
        print(f"gonio: interrupted; {interrupted_note(Path(args.out))}", file=sys.stderr)
        return EXIT_INTERRUPTED
    for w in summary.warnings:
        print(f"warning: {w}", file=sys.stderr)
    print(f"{len(summary.materials)} material(s), {summary.records} (material, model) record(s); "
          f"{len(summary.evaluated)} evaluated, {len(summary.reused)} reused from the cache")
    print(f"errors: {summary.errors_json}")
    if summary.multiple_scattering is not None:
        print(f"multiple scattering: {summary.out_dir / 'multiple-scattering.md'}")
    print(f"open: {summary.index_html}")
    if summary.failed:
        n = sum(len(v) for v in summary.failed.values())
        print(f"{n} (material, model) pair(s) failed (the warnings above; marked in the report)", file=sys.stderr)
        return EXIT_MODEL_FAILED
    return 0


def interrupted_note(out: Path) -> str:
    """What an interrupted report leaves in ``out`` and how it goes on: the cached evaluations
    (written whole, one file per material) and figures; a rerun resumes from them."""
    from models.report.evaluation import cached_evaluations
    n = cached_evaluations(out)
    held = (f"{out / 'cache'} holds the cached evaluations of {n} material(s) and the figures drawn so far"
            if n else f"no material evaluation was cached in {out / 'cache'} yet")
    return f"{held}; index.html is not (re)written; rerun the same command to resume from the cache"


