"""``gonio database list|simulate``: expand a database definition, simulate all its materials."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

from goniometer.cli.common import (EXIT_INTERRUPTED, THREADS_HELP, ResumeAware, UsageError, compile_kernels,
                                   output_path, progress_bar, sigint_latch, skip_progress, thread_number, usage_errors)


def register(sub) -> None:
    """Add ``database`` (``list``, ``simulate``) to the ``gonio`` sub-command parser."""
    p = sub.add_parser("database", help="material databases: list, simulate")
    dsub = p.add_subparsers(dest="database_command", required=True, metavar="ACTION")
    q = dsub.add_parser("list", help="list the materials a database definition expands to")
    q.add_argument("config", metavar="CONFIG.toml")
    q.add_argument("--out", metavar="DIR",
                   help="also show each material's status in this results directory (default: no status)")
    q.add_argument("--quality", default="quick",
                   help="the quality whose results --out holds (default: %(default)s)")
    q.add_argument("--json", action="store_true")
    q.set_defaults(func=cmd_database_list)
    q = dsub.add_parser("simulate", help="simulate every material (resumable) into one HDF5 file each")
    q.add_argument("config", metavar="CONFIG.toml")
    q.add_argument("--out", required=True, metavar="DIR", help="the results directory (required)")
    q.add_argument("--quality", default="quick",
                   help="a quality of the definition's [quality] table (e.g. demo, quick, paper: "
                        "`gonio database list` does not need it) (default: %(default)s)")
    q.add_argument("--only", metavar="GLOB", help="materials whose name matches, e.g. 'metal/M2-*' (default: all)")
    q.add_argument("--threads", type=thread_number, help=THREADS_HELP)
    q.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                   help="run the tasks on a Dask distributed cluster (default: this machine)")
    q.add_argument("--resimulate-corrupted", action="store_true",
                   help="move unreadable finished files aside and simulate them again")
    q.add_argument("--overwrite", action="store_true",
                   help="simulate the selected finished materials again and replace their files (default: "
                        "finished materials are skipped; docs/outputs.md)")
    q.add_argument("--polarized", action="store_true",
                   help="trace every material with polarized light, the same rays per slice: the definition's "
                        "polarized twin, into its own results directory (docs/polarization.md) (default: the "
                        "definition's [simulation] polarized, else scalar light)")
    q.add_argument("--restart", action="store_true",
                   help="discard the checkpoints of the selected unfinished materials (DIR/.partial) and trace them "
                        "from the start (default: resume them; checkpoints of another run or code version are "
                        "refused, naming what differs)")
    q.set_defaults(func=cmd_database_simulate)



def cmd_database_list(args: argparse.Namespace) -> int:
    from goniometer.database import DatabaseError, list_rows
    db = _load_definition(args.config)
    with usage_errors(DatabaseError):
        rows = list_rows(db, args.out, args.quality) if args.out else list_rows(db)
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    for r in rows:
        params = " ".join(f"{k}={r[k]}" for k in ("alpha0", "alpha1", "tau_name", "rho_name", "eta1", "d", "g") if k in r)
        status = f"  [{r['status']}]" if "status" in r else ""
        print(f"{r['name']:32s} {r['paper_name']:4s} {r['parametrization']:8s} {params}{status}")
    counts = {}
    for r in rows:
        counts[r["category"]] = counts.get(r["category"], 0) + 1
    spectral = f" (spectral, {db.wavelength_bins} wavelength bins)" if db.spectral else ""
    print(f"{len(rows)} materials ({', '.join(f'{n} {c}' for c, n in counts.items())}) in {db.name}{spectral}")
    return 0


def _load_definition(path: str):
    """The database definition at ``path``; a refusal is one line, which for a material file says
    that it is one."""
    from goniometer.database import DatabaseError, load_database
    try:
        return load_database(path)
    except DatabaseError as e:
        if _is_material_file(path):
            raise UsageError(f"{path}: a material file (its [[layers]] are one stack: gonio simulate and gonio "
                             f"furnace take it), not a database definition (docs/database-format.md)") from None
        raise UsageError(str(e)) from None


def _is_material_file(path: str) -> bool:
    """True when ``path`` is a TOML file with ``[[layers]]``: a material file (docs/material-format.md),
    which no database definition has."""
    from goniometer.tomlfile import read_toml
    try:
        return "layers" in read_toml(path, ValueError)
    except ValueError:   # unreadable: the definition's own error says so
        return False


def cmd_database_simulate(args: argparse.Namespace) -> int:
    from goniometer.atomic import is_environment_error
    from goniometer.cli.simulate import checkpoint_refusals
    from goniometer.database import (DatabaseError, check_checkpoints, check_results_dir, material_status,
                                     paths_per_incident, runs, simulate_database)
    from goniometer.run.results import cell_geometries
    from goniometer.run.settings import SettingsError
    from goniometer.run.tasks import run_variant, warm_up_runs
    started = time.time()   # files written after it are this run's (an interrupt says how many)
    db = _load_definition(args.config)
    if args.polarized:
        db = dataclasses.replace(db, polarized=True)
    with usage_errors(DatabaseError):
        materials = db.select(args.only)
        if args.quality not in db.qualities:
            raise DatabaseError(f"--quality: {args.quality!r} is not one of {', '.join(db.qualities)}")
        # paths per material: a spectral run traces its launches' paths (docs/spectral.md section 1)
        rays = {m.name: paths_per_incident(db, m, args.quality) * len(db.incident_deg) for m in materials}
    output_path(args.out, inputs=[args.config], directory=True)
    # before compiling: another database's directory, or checkpoints this run cannot use, are refused at once
    with usage_errors(DatabaseError), checkpoint_refusals():
        check_results_dir(db, Path(args.out), args.quality)
        if not args.restart:
            check_checkpoints(db, args.out, args.quality, [m for m in materials if args.overwrite or material_status(
                db, Path(args.out), m, args.quality) != "done"])
    spectral = (f", spectral: {db.wavelength_bins} wavelength bins ({db.qualities[args.quality]:,} paths per bin "
                f"and slice)" if db.spectral else f" ({db.qualities[args.quality]:,} rays per slice)")
    spectral += ", polarized light" if db.polarized else ""
    print(f"{db.name}: {len(materials)} material(s), quality {args.quality}{spectral}, into {args.out}",
          file=sys.stderr)

    try:
        with sigint_latch() as interrupts, checkpoint_refusals():
            todo = [m for m in materials
                    if args.overwrite or material_status(db, Path(args.out), m, args.quality) != "done"]
            if args.scheduler is None and todo:
                pairs = runs(db, todo, args.quality)
                with interrupts.deferred():
                    variants = len({run_variant(s, st) for s, st in pairs})
                    compile_kernels(lambda: warm_up_runs(pairs), variants=variants)
                    # the final assembly's numba kernels, for each grid of the run: compiled and run here
                    grids = {m.parametrization: m for m in todo}
                    for m in grids.values():
                        cell_geometries(db.settings_for(m, args.quality))
            bar = progress_bar(sum(rays.values()), db.name, smoothing=0.05)
            progress = ResumeAware(bar, interrupts.check)

            def on_discard(path, reason):
                bar.write(f"warning: {path}: unreadable checkpoint ({reason}); its incident direction is traced "
                          f"again", file=sys.stderr)

            def on_material(m, status):
                interrupts.check()
                if status == "partial":
                    progress.resumed(_checkpointed_rays(db, args.out, m, args.quality))
                bar.set_postfix_str(f"{m.name} ({status})")

            with bar:
                if len(todo) < len(materials):  # finished materials: done before this run, not in its rate
                    skip_progress(bar, sum(rays.values()) - sum(rays[m.name] for m in todo))
                summary = simulate_database(db, args.out, args.quality, args.only, threads=args.threads,
                                            scheduler=args.scheduler, resimulate_corrupted=args.resimulate_corrupted,
                                            progress=progress, on_material=on_material, overwrite=args.overwrite,
                                            restart=args.restart, on_discard=on_discard)
                if bar.total and bar.n < bar.total:
                    bar.update(bar.total - bar.n)
    except (DatabaseError, SettingsError) as e:
        raise UsageError(str(e)) from None
    except KeyboardInterrupt:
        # what is on disk is kept: say so, and how to go on (the host's "nothing written" would be wrong)
        print(f"gonio: interrupted; {_kept(db, Path(args.out), materials, started)}", file=sys.stderr)
        return EXIT_INTERRUPTED
    except OSError as e:   # a full disk, say: one line (goniometer.cli.main) saying what is kept
        if is_environment_error(e):
            e.add_note(_kept(db, Path(args.out), materials, started))
        raise
    print(f"{len(summary.simulated)} simulated ({len(summary.resumed)} resumed, {len(summary.resimulated)} "
          f"re-simulated), {len(summary.skipped)} already done, in {summary.elapsed_s:.0f} s; files in {args.out}")
    return 0


def _kept(db, out: Path, materials: list, since: float) -> str:
    """What an interrupted or failed ``database simulate`` leaves in ``out``: the materials finished
    (and how many of them were written after ``since``, by this run), the unfinished ones with
    checkpoints, and how to go on."""
    from goniometer.database import checkpointed_incidents, material_path
    files = [material_path(out, m) for m in materials]
    done = [p for p in files if p.exists()]
    now = sum(1 for p in done if p.stat().st_mtime >= since)
    partial = {m.name: n for m, p in zip(materials, files) if not p.exists() and (n := checkpointed_incidents(out, m))}
    words = [f"{len(done)} of {len(materials)} material(s) finished in {out} ({now} by this run)"]
    if partial:
        name, n = next(iter(partial.items()))
        more = f" and {len(partial) - 1} more" if len(partial) > 1 else ""
        words.append(f"checkpoints of {len(partial)} unfinished material(s) kept in {out / '.partial'} ({name}: {n} "
                     f"of {len(db.incident_deg)} incident direction(s){more})")
    return ", ".join(words) + "; rerun the same command to resume"


def _checkpointed_rays(db, out: str, material, quality: str) -> int:
    """Rays (paths) of the incident directions an unfinished material has in its checkpoints."""
    from goniometer.database import checkpointed_incidents, paths_per_incident
    return paths_per_incident(db, material, quality) * checkpointed_incidents(Path(out), material)
