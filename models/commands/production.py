"""``gonio production RESULTS --out DIR``: effective darkening and roughening of a production database,
fitted replacements for OpenPBR's formulas, and their report (``docs/production.md``)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from goniometer.cli.common import UsageError, add_overwrite, at_least_one, output_path, whole_number
from models.commands.report import add_jobs


def register(sub) -> None:
    """Add ``production`` to the ``gonio`` sub-command parser."""
    p = sub.add_parser("production", help="measure effective coat darkening/roughening, fit formulas, report "
                                          "(a configs/production.toml results directory)")
    p.add_argument("results", metavar="RESULTS_DIR")
    p.add_argument("--out", required=True, metavar="DIR", help="report directory (summary.json, production.md, PNGs)")
    p.add_argument("--seed", type=whole_number, default=None, help="seed of the held-out coat-index draw (default 13)")
    p.add_argument("--no-belcour", dest="belcour", action="store_false",
                   help="skip belcour-fwd (its columns are then empty)")
    p.add_argument("--json", action="store_true", help="print summary.json")
    add_jobs(p, "measure the materials side by side; the summary is the same whatever N")
    add_overwrite(p)
    p.set_defaults(func=cmd_production)


def cmd_production(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from models.production.study.effective import ProductionError
    from models.production.study.fitting_formulas import SPLIT_SEED
    from models.report.production import write_production_report
    at_least_one(args.jobs, "--jobs", "the number of worker processes")
    results = Path(args.results)
    if not (results / "database.json").is_file():
        raise UsageError(f"RESULTS_DIR: {results} is not a database results directory (no database.json)")
    # a finished production report holds summary.json
    output_path(args.out, inputs=[results], overwrite=args.overwrite, directory=True, marker="summary.json")
    seed = SPLIT_SEED if args.seed is None else args.seed
    if seed < 0:
        raise UsageError(f"--seed: must be >= 0, got {seed}")
    bar = tqdm(total=None, unit="material", file=sys.stderr, dynamic_ncols=True, disable=None, desc="measure")

    def progress(done: int, total: int, message: str) -> None:
        bar.total = total
        bar.n = done
        bar.set_postfix_str(message[:60])
        bar.refresh()

    try:
        with bar:
            summary = write_production_report(results, args.out, with_belcour=args.belcour, seed=seed,
                                              progress=progress, jobs=args.jobs)
    except (ProductionError, ValueError) as e:
        raise UsageError(str(e)) from None
    if args.json:
        print(json.dumps(summary, indent=1))
        return 0
    for q in ("darkening", "roughening"):
        d = summary[q]
        b = "" if d.get("belcour_rmse") is None else f", belcour-fwd {d['belcour_rmse']:.4f} (n = {d['belcour_n']})"
        print(f"{q:10s} held-out RMSE: OpenPBR {d['spec_rmse']:.4f}, fitted {d['fitted_rmse']:.4f}{b}; "
              f"n_train {d['n_train']}, n_heldout {d['n_heldout']}")
    out = Path(args.out)
    print(f"summary: {out / 'summary.json'}")
    print(f"report: {out / 'production.md'}")
    return 0
