"""``gonio tables``: show, build and check the models' precomputed tables (:mod:`models.tables.check`).

Exit status: 0, or 1 if a check exceeds its stated bound.
"""

from __future__ import annotations

import argparse
import json

from goniometer.cli.common import UsageError, progress_bar, whole_number


def _bar(name: str):
    bar = progress_bar(1000, f"building {name}", unit="step", unit_scale=False,
                       bar_format="{l_bar}{bar}| {elapsed}<{remaining} {postfix}")

    def update(stage: str, frac: float) -> None:
        bar.set_postfix_str(stage, refresh=False)
        bar.update(max(0, int(round(1000 * frac)) - bar.n))
        if frac >= 1.0:
            bar.close()

    return update


def cmd_tables(args: argparse.Namespace) -> int:
    from models.tables import MASKINGS, cache_directory, check_tables
    if args.check < 0:
        raise UsageError(f"--check: must be >= 0 random points, got {args.check}")
    maskings = MASKINGS if args.masking == "all" else (args.masking,)
    cache_dir = cache_directory(args.cache_dir)
    entries = check_tables(cache_dir, maskings, build=not args.status, rebuild=args.rebuild, check_points=args.check,
                           seed=args.seed, progress=None if args.json else _bar)
    ok = all(c.ok for e in entries for c in e.checks)
    if args.json:
        print(json.dumps({"cache_dir": str(cache_dir), "tables": [e.to_dict() for e in entries], "ok": ok},
                         indent=2))
    else:
        print(f"cache directory: {cache_dir}")
        for e in entries:
            size = f"{e.bytes / 1e6:.1f} MB" if e.bytes else "-"
            print(f"  {e.name:32s} {e.status:8s}{' (built now)' if e.built else '':12s} {size:>9s}  {e.path}")
            for c in e.checks:
                verdict = "ok" if c.ok else "EXCEEDS THE BOUND"
                print(f"      check {c.quantity} [{c.region}]: max |error| {c.max_error:.2e} over {c.points} "
                      f"points, stated bound {c.bound:.0e}: {verdict}")
    return 0 if ok else 1


def register(sub) -> None:
    """Add ``tables`` to the ``gonio`` sub-command parser."""
    p = sub.add_parser("tables", help="show, build (--rebuild) and check the models' precomputed tables")
    p.add_argument("--rebuild", action="store_true", help="rebuild every table, even current ones")
    p.add_argument("--status", action="store_true", help="only report what is there; build nothing")
    p.add_argument("--masking", choices=("separable", "height-correlated", "all"), default="separable",
                   help="which Belcour tables: separable (default, what the models use), height-correlated, all")
    p.add_argument("--cache-dir", dest="cache_dir", metavar="DIR",
                   help="table directory (default $GONIOMETER_CACHE or ~/.cache/goniometer)")
    p.add_argument("--check", type=whole_number, default=0, metavar="N",
                   help="compare N random off-grid lookups per table with direct quadrature (exit 1 above bound) "
                        "(default: %(default)s, no check)")
    p.add_argument("--seed", type=whole_number, default=1, help="seed of the --check points (default 1)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=cmd_tables)
