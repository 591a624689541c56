"""``gonio lut DEFINITION.toml --out DIR``: a renderer's precomputed table (directional albedo,
its average, coat darkening and roughness) computed by the simulator with a standard error per
cell, checked, and written as ``.npy``, JSON, a C header and a 16-bit PNG (:mod:`models.lut`;
``docs/lut.md``)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from goniometer.cli.common import (THREADS_HELP, ResumeAware, UsageError, add_device, add_overwrite, compile_kernels,
                                   output_path, progress_bar, sigint_latch, thread_number, usage_errors, whole_number)

#: exit status of a table written whose own checks failed (docs/lut.md section 5)
EXIT_CHECKS_FAILED = 1


def register(sub) -> None:
    """Add ``lut`` to the ``gonio`` sub-command parser."""
    p = sub.add_parser("lut", help="compute a renderer's lookup table (albedo, E_avg, coat darkening/roughness) with a "
                                   "standard error per cell: .npy, JSON, C header, PNG (docs/lut.md)")
    p.add_argument("definition", metavar="DEFINITION.toml", help="the table definition (configs/lut/, docs/lut.md)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (NAME.npy, NAME.stderr.npy, "
                                                              "NAME.json, NAME.h, NAME.png)")
    rays = p.add_mutually_exclusive_group()
    rays.add_argument("--rays", type=whole_number, metavar="N",
                      help="rays per cell (per incident direction), replacing the definition's rays or stderr "
                           "(default: the definition's)")
    rays.add_argument("--stderr", type=float, metavar="S",
                      help="target standard error per cell, rays from a pilot run, replacing the definition's rays "
                           "or stderr (default: the definition's)")
    p.add_argument("--seed", type=whole_number, help="random seed (default: the definition's seed, else 1)")
    p.add_argument("--threads", type=thread_number, help=THREADS_HELP)
    add_device(p)
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                   help="trace on this Dask scheduler's workers (same bits; default: local threads)")
    p.add_argument("--published", metavar="FILE",
                   help="a C source holding the renderer's table (the definition's [published] array): report the "
                        "cells where it is off by more than its precision (default: no comparison)")
    p.add_argument("--no-checks", dest="checks", action="store_false",
                   help="skip the checks against the quadratures and closed forms (default: run them)")
    p.add_argument("--restart", action="store_true",
                   help="discard the checkpoints of an interrupted run and start again (default: resume them)")
    p.add_argument("--json", action="store_true", help="print NAME.json's object (default: a text summary)")
    add_overwrite(p)
    p.set_defaults(func=cmd_lut)


def cmd_lut(args: argparse.Namespace) -> int:
    from goniometer.cli.simulate import checkpoint_refusals
    from goniometer.kernel.tracer import DeviceError, check_device
    from models.lut.compute import PARTIAL, Runner, check_checkpoints, clear_checkpoints, kept_cells, plan_table
    from models.lut.definition import LutError, load_definition

    with usage_errors(LutError):
        defn = load_definition(args.definition)
        if args.stderr is not None or args.rays is not None:
            defn = defn.with_rays(args.rays, args.stderr)
        if args.seed is not None:
            from dataclasses import replace
            defn = replace(defn, seed=args.seed)
    inputs = [args.definition] + ([args.published] if args.published else [])
    _refuse_finished(Path(args.out), defn.name, args.overwrite)
    out = output_path(args.out, inputs=inputs, overwrite=args.overwrite, directory=True, marker=f"{defn.name}.json")
    published = _published(args, defn)
    with usage_errors(LutError, prefix=str(args.definition)):
        plan = plan_table(defn)
    device = args.device or "cpu"
    with usage_errors(DeviceError):
        check_device(device)
    root = out / PARTIAL
    if args.restart:
        clear_checkpoints(root)
    with checkpoint_refusals():
        check_checkpoints(root, defn)
    kept = kept_cells(root)
    if kept and not args.json:
        print(f"resuming: {kept} finished cell(s) in {root} (--restart to discard them)", file=sys.stderr)
    client = None
    if args.scheduler:
        from goniometer.run.distributed import ClusterError, dask_client
        with usage_errors(ClusterError, prefix="--scheduler"):
            client = dask_client(args.scheduler)
    runner = Runner(threads=args.threads, device=device, client=client, root=root)
    try:
        result = _compute(args, plan, runner)
        return _finish(args, result, published, out, root)
    except KeyboardInterrupt:
        n = kept_cells(root)
        if n:
            print(f"gonio: {n} finished cell(s) kept in {root}; rerun the same command to resume", file=sys.stderr)
        raise
    except OSError as e:   # a full disk, say: one line (goniometer.cli.main) saying what is kept
        from goniometer.atomic import is_environment_error
        n = kept_cells(root)
        if n and is_environment_error(e):
            e.add_note(f"{n} finished cell(s) kept in {root}; rerun the same command to resume")
        raise
    finally:
        if client is not None:
            client.close()


def _refuse_finished(out: Path, name: str, overwrite: bool) -> None:
    """A finished table (its NAME.json) is not replaced without --overwrite (docs/outputs.md rule 2);
    the refusal says what it holds."""
    from models.lut.writers import describe_table, file_names
    marker = out / file_names(name)["json"]
    if overwrite or not marker.is_file():
        return
    what = describe_table(marker)
    if what is not None:
        raise UsageError(f"--out: {out} already holds a finished output, {marker.name}: {what}; add --overwrite "
                         f"to replace it, or give another directory")


def _published(args: argparse.Namespace, defn):
    """The published table's numbers (``--published``), read before anything is traced."""
    if not args.published:
        return None
    from models.lut.check import read_c_array
    from models.lut.definition import LutError
    if defn.published is None:
        raise UsageError(f"--published: {args.definition} names no [published] array to read from "
                         f"{args.published}")
    with usage_errors(LutError):
        values = read_c_array(args.published, defn.published.array)
    if values.size != defn.cells:
        raise UsageError(f"--published: {args.published}: {defn.published.array} holds {values.size} numbers; the "
                         f"table has {defn.cells} cells ({' x '.join(map(str, defn.shape))})")
    return values


def _hours(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def _compute(args: argparse.Namespace, plan, runner):
    """Compile, (pilot,) estimate, trace with checkpoints and progress (docs/lut.md section 5)."""
    from goniometer.run.checkpoints import CheckpointMismatch
    from models.lut.compute import calibrate, pilot, run_table, start_checkpoints, warm_up
    defn = plan.definition
    quiet = args.json
    say = (lambda text: None) if quiet else (lambda text: print(text, file=sys.stderr))
    incidents = {len(s.incident_deg) for s in plan.specs.values()}
    target = (f"{defn.rays:,} rays per cell" if defn.rays is not None
              else f"target standard error {defn.stderr:g} per cell (rays from a pilot run)")
    say(f"lut {defn.name} ({defn.quantity}): {defn.cells} cell(s) {' x '.join(map(str, defn.shape)) or '1'}, "
        f"{len(plan.specs)} run(s) x {max(incidents)} incident direction(s); {target}; "
        f"{runner.threads or 'all'} thread(s), {runner.device}")
    try:
        with sigint_latch() as interrupts:
            with interrupts.deferred():
                compile_kernels(lambda: warm_up(plan, runner))
            rate = calibrate(plan, runner)
            start_checkpoints(runner.root, defn)
            if plan.pilot_rays:
                total = plan.pilot_total()
                say(f"pilot: {plan.pilot_rays:,} rays per cell, {total:,} rays, about {_hours(total / rate)} "
                    f"at {rate / 1e6:.1f} M rays/s")
                _traced(runner, interrupts, total, f"{defn.name} pilot", lambda: pilot(plan, runner))
                lo, hi = min(plan.rays.values()), max(plan.rays.values())
                say(f"rays per cell for a standard error of {defn.stderr:g}: {lo:,} to {hi:,} "
                    f"(the pilot's standard errors, times {_safety()})")
            total = plan.total_rays()
            say(f"cost: {total:,} rays, about {_hours(total / rate)} at {rate / 1e6:.1f} M rays/s (measured here "
                f"on {runner.threads or 'all'} thread(s))")
            result = _traced(runner, interrupts, total, defn.name, lambda: run_table(plan, runner))
    except CheckpointMismatch as e:   # a run's own checkpoints (the table's were checked before)
        from goniometer.cli.simulate import checkpoint_refusal
        raise UsageError(checkpoint_refusal(e)) from None
    return result


def _safety() -> str:
    from models.lut.compute import SAFETY
    return f"{SAFETY:g}"


def _traced(runner, interrupts, total: int, desc: str, work):
    """Run ``work`` under a progress bar of ``total`` rays that Ctrl-C stops."""
    bar = progress_bar(total, desc)
    progress = ResumeAware(bar, interrupts.check)
    runner.progress = progress
    runner.on_resume = progress.resumed
    try:
        with bar:
            return work()
    finally:
        runner.progress = runner.on_resume = None


def _finish(args: argparse.Namespace, result, published, out: Path, root: Path) -> int:
    """Checks, comparison, scores; the files (NAME.json last); the summary; the checkpoints cleared."""
    from models.lut.check import check_table, compare_published, reference_values, score_darkening, score_roughness
    from models.lut.compute import clear_checkpoints
    from models.lut.writers import png_why_not, write_table
    defn = result.definition
    say = (lambda text: None) if args.json else (lambda text: print(text, file=sys.stderr))
    document = result.to_json()
    checks, ref = [], None
    if args.checks:
        say("checking the table against the quadratures and closed forms ...")
        ref = reference_values(defn)
        checks = check_table(result, ref)
    document["checks"] = [c.to_json() for c in checks]
    if published is not None:
        document["published"] = dict(source=defn.published.source, array=defn.published.array, file=str(args.published),
                                     **compare_published(result, published, defn.published.decimals, ref))
    if defn.quantity == "coat-darkening":
        document["score"] = score_darkening(result)
    elif defn.quantity == "coat-roughness":
        document["score"] = score_roughness(result)
    paths = write_table(out, result, document, source=str(args.definition))
    clear_checkpoints(root)
    if args.json:
        print(json.dumps(document, indent=1))
    else:
        _summary(result, document, paths)
        if "png" not in paths:
            print(f"no PNG: {png_why_not(result.values)}")
    failed = [c for c in checks if not c.passed]
    return EXIT_CHECKS_FAILED if failed else 0


def _summary(result, document: dict, paths: dict) -> None:
    import numpy as np
    defn = result.definition
    se = result.stderr
    print(f"{defn.name}: {defn.quantity}, {' x '.join(map(str, defn.shape)) or '1'} cell(s); values "
          f"{float(np.min(result.values)):.6g} to {float(np.max(result.values)):.6g}; standard error at most "
          f"{float(np.max(se)):.3g} (median {float(np.median(se)):.3g}); {result.total_rays:,} rays in "
          f"{_hours(result.elapsed_s)}")
    for c in document["checks"]:
        from models.lut.check import CellCheck
        print(CellCheck(**c).line())
    pub = document.get("published")
    if pub is not None:
        print(f"published {pub['array']} ({pub['source'] or pub['file']}): largest difference "
              f"{pub['max_abs_difference']:.2g}; {len(pub['beyond_ours'])} cell(s) off by more than its precision "
              f"({pub['precision']:g}) and our standard error" + (
                  f"; {len(pub['beyond_quadrature'])} cell(s) off from the quadrature by more than its precision "
                  f"and the quadrature's error" if "beyond_quadrature" in pub else ""))
        for c in (pub.get("beyond_quadrature") or pub["beyond_ours"])[:10]:
            print(f"  cell {tuple(c['cell'])}: published {c['published']:.6f}, ours {c['value']:.6f} "
                  f"+- {c['stderr']:.1e}" + (f", quadrature {c['quadrature']:.6f}" if "quadrature" in c else ""))
    score = document.get("score")
    if score is not None:
        print(f"formulas scored (a cell fails where off by more than {score['tolerance']:g} and "
              f"{_z():.1f} standard errors):")
        for name, s in score["formulas"].items():
            print(f"  {name:24s} RMSE {s['rmse']:.4f}, largest error {s['max_abs_error']:.4f} at "
                  f"{tuple(s['worst_cell'])}, fails {s['failing_cells']} of {s['cells']} cell(s)")
    for kind, p in paths.items():
        print(f"wrote {p}")


def _z() -> float:
    from models.lut.check import Z_TOL
    return Z_TOL
