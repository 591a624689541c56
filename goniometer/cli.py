"""The ``gonio`` command line: thin wrappers that parse, call the library and print.

Every user error prints one line ``gonio: error: ...`` on stderr and exits with status 2;
an interrupted run (Ctrl-C) exits with 130 and leaves no file under the output name.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import signal
import sys
import threading
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

EXIT_USAGE = 2
EXIT_INTERRUPTED = 130


class UsageError(Exception):
    """A user error the CLI reports as one line with exit status 2."""


# ---------------------------------------------------------------------- helpers

class _Interrupts:
    """Ctrl-C handling of the long commands (:func:`_sigint_latch`)."""

    def __init__(self) -> None:
        self.hit = False
        self.deferring = False

    def handler(self, signum, frame) -> None:
        self.hit = True
        if not self.deferring:
            raise KeyboardInterrupt
        print("gonio: interrupt received; stopping once the kernel is compiled", file=sys.stderr)

    def check(self) -> None:
        """Raise KeyboardInterrupt if Ctrl-C was pressed since entry."""
        if self.hit:
            raise KeyboardInterrupt

    @contextlib.contextmanager
    def deferred(self):
        """Within the block Ctrl-C is only recorded; it is raised when the block ends."""
        self.deferring = True
        try:
            yield
        finally:
            self.deferring = False
        self.check()


@contextlib.contextmanager
def _sigint_latch():
    """Yield an :class:`_Interrupts`: SIGINT raises KeyboardInterrupt at once and is also latched.

    Python drops a KeyboardInterrupt raised while a finalizer runs, and one raised inside numba's
    compiler can leave it broken (a RuntimeError instead of a clean exit), so long commands compile
    inside ``deferred()`` and call ``check()`` at every progress report. Outside the main thread
    (no signal handlers there), or where SIGINT is ignored (a background job of a script), nothing
    is installed and ``check()`` never raises.
    """
    state = _Interrupts()
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGINT) is signal.SIG_IGN):
        yield state
        return
    previous = signal.signal(signal.SIGINT, state.handler)
    try:
        yield state
    finally:
        signal.signal(signal.SIGINT, previous)


def _incident_list(text: str) -> tuple[list[float], list[float] | None]:
    thetas: list[float] = []
    phis: list[float] = []
    any_phi = False
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        try:
            if ":" in part:
                t, p = part.split(":", 1)
                thetas.append(float(t))
                phis.append(float(p))
                any_phi = True
            else:
                thetas.append(float(part))
                phis.append(0.0)
        except ValueError:
            raise UsageError(f"--incident: {part!r} is not a number (expected e.g. 0,30,60 or 30:45)") from None
    if not thetas:
        raise UsageError("--incident: no incident angle given")
    return thetas, (phis if any_phi else None)


def _resolution(text: str) -> tuple[int, int]:
    try:
        a, b = text.lower().split("x")
        return int(a), int(b)
    except ValueError:
        raise UsageError(f"--resolution: {text!r} is not of the form N_THETAxN_PHI (e.g. 90x360)") from None


def _progress_bar(total: int, desc: str):
    from tqdm import tqdm
    return tqdm(total=total, desc=desc, unit="ray", unit_scale=True, file=sys.stderr,
                dynamic_ncols=True, disable=None, smoothing=0.1)


# ---------------------------------------------------------------------- simulate

def cmd_simulate(args: argparse.Namespace) -> int:
    from goniometer import store
    from goniometer.checkpoint import Checkpoints, checkpoint_dir, run_description, simulate_resumable
    from goniometer.simulate import SettingsError, SimulationSettings, warm_up
    from goniometer.stack import StackError, load_toml

    try:
        stack, table = load_toml(args.config)
        base = SimulationSettings.from_mapping(table, source=f"{args.config}: simulation")
    except (StackError, SettingsError) as e:
        raise UsageError(str(e)) from None
    over: dict[str, Any] = {}
    if args.incident is not None:
        thetas, phis = _incident_list(args.incident)
        over["incident_deg"] = tuple(thetas)
        over["incident_phi_deg"] = tuple(phis) if phis is not None else tuple(0.0 for _ in thetas)
    if args.resolution is not None:
        over["resolution"] = _resolution(args.resolution)
    for key in ("rays", "parametrization", "seed", "threads", "masking", "max_order"):
        value = getattr(args, key)
        if value is not None:
            over[key] = value
    try:
        settings = base.with_overrides(**over)
    except SettingsError as e:
        raise UsageError(str(e)) from None
    try:
        out = store.check_writable(args.out)
    except store.StoreError as e:
        raise UsageError(str(e)) from None

    total = settings.rays * len(settings.incident_deg)
    print(f"simulating {stack.name} ({stack.category}): {len(settings.incident_deg)} incident direction(s) x "
          f"{settings.rays:,} rays, {settings.parametrization} {settings.resolution[0]}x{settings.resolution[1]}, "
          f"{settings.n_threads} thread(s)", file=sys.stderr)
    with _sigint_latch() as interrupts, _progress_bar(total, stack.name) as bar:
        def progress(n: int) -> None:
            interrupts.check()
            bar.update(n)

        with interrupts.deferred():
            compile_s = warm_up()
        checkpoints = Checkpoints(checkpoint_dir(out), run_description(stack, settings))
        if args.restart:
            checkpoints.clear()

        def on_resume(n: int) -> None:
            bar.write(f"resuming: {n} of {len(settings.incident_deg)} incident direction(s) already traced "
                      f"(checkpoints in {checkpoints.directory}; --restart to discard them)", file=sys.stderr)

        try:
            result = simulate_resumable(stack, settings, checkpoints, progress=progress, on_resume=on_resume)
            interrupts.check()
        except KeyboardInterrupt:
            kept = len(list(checkpoints.directory.glob("m*.npz"))) if checkpoints.directory.is_dir() else 0
            if kept:
                print(f"gonio: {kept} finished incident direction(s) kept in {checkpoints.directory}; "
                      f"rerun the same command to resume", file=sys.stderr)
            raise
    result.compile_s = compile_s
    store.write(out, result)
    checkpoints.clear()
    print(f"wrote {out}")
    _print_summary(result)
    return 0


def _print_summary(r) -> None:
    print(f"{r.rays_per_s:,.0f} rays/s with {r.threads} thread(s) ({r.rays_per_s / r.threads:,.0f} per thread); "
          f"compile/load {r.compile_s:.1f} s")
    print(f"{'theta_l':>8} {'phi_l':>6}  {'reflected (R G B)':>26}  {'transmitted':>26}  {'absorbed':>26}  {'masking_loss':>26}")
    for m in range(len(r.theta_deg)):
        row = [f"{r.theta_deg[m]:8.2f}", f"{r.phi_deg[m]:6.1f}"]
        for k in ("reflected", "transmitted", "absorbed", "masking_loss"):
            row.append(" ".join(f"{x:8.5f}" for x in r.energy[k][m]))
        print("  ".join(row))
    if np.any(r.capped_paths):
        print(f"warning: {int(np.sum(r.capped_paths))} path(s) reached the event cap of {r.settings.event_cap}; "
              f"their weight is in /energy/capped")


# ---------------------------------------------------------------------- info

def info_dict(path: Path) -> dict[str, Any]:
    """The JSON summary printed by ``gonio info --json``."""
    from goniometer import store
    r = store.read(path)
    s = r.settings
    d: dict[str, Any] = {
        "file": str(path),
        "material": {"name": r.stack.name, "category": r.stack.category, "base": r.stack.base,
                     "config": json.loads(r.stack.to_json())},
        "settings": {
            "incident_deg": list(s.incident_deg), "incident_phi_deg": list(s.incident_phi_deg),
            "rays": s.rays, "parametrization": s.parametrization, "resolution": list(s.resolution),
            "seed": s.seed, "masking": s.masking, "max_order": s.max_order, "chunk_rays": s.chunk_rays,
        },
        "sides": ["brdf"] + (["btdf"] if r.btdf is not None else []),
        "energy": [],
        "performance": {"threads": r.threads, "elapsed_s": float(np.sum(r.elapsed_s)),
                        "rays_per_s": r.rays_per_s, "rays_per_s_per_thread": r.rays_per_s / r.threads,
                        "compile_s": r.compile_s},
        "capped_paths": int(np.sum(r.capped_paths)),
    }
    for m in range(len(r.theta_deg)):
        e = {"theta_deg": float(r.theta_deg[m]), "phi_deg": float(r.phi_deg[m])}
        for k in ("reflected", "transmitted", "absorbed", "masking_loss"):
            e[k] = [float(x) for x in r.energy[k][m]]
        e["mean_events"] = float(r.mean_events[m])
        d["energy"].append(e)
    return d


def cmd_info(args: argparse.Namespace) -> int:
    from goniometer import store
    try:
        d = info_dict(Path(args.file))
    except store.StoreError as e:
        raise UsageError(str(e)) from None
    if args.json:
        print(json.dumps(d, indent=2))
        return 0
    m = d["material"]
    s = d["settings"]
    p = d["performance"]
    print(f"{d['file']}: {m['name']} ({m['category']}, {m['base']} base)")
    print(f"  stack: {json.dumps(m['config']['layers'])}")
    print(f"  {len(s['incident_deg'])} incident direction(s), {s['rays']:,} rays each, {s['parametrization']} "
          f"{s['resolution'][0]}x{s['resolution'][1]}, seed {s['seed']}, {s['masking']} masking, K = {s['max_order']}; "
          f"slices: {', '.join(d['sides'])}")
    print(f"  {p['rays_per_s']:,.0f} rays/s on {p['threads']} thread(s) ({p['elapsed_s']:.1f} s)")
    print(f"  {'theta_l':>7} {'phi_l':>6}  {'reflected (R G B)':>24}  {'transmitted':>24}  {'absorbed':>24}  {'masking_loss':>24}")
    for e in d["energy"]:
        cols = [" ".join(f"{x:7.4f}" for x in e[k]) for k in ("reflected", "transmitted", "absorbed", "masking_loss")]
        print(f"  {e['theta_deg']:7.2f} {e['phi_deg']:6.1f}  " + "  ".join(cols))
    if d["capped_paths"]:
        print(f"  warning: {d['capped_paths']} path(s) reached the event cap")
    return 0


# ---------------------------------------------------------------------- models / evaluate

def cmd_models(args: argparse.Namespace) -> int:
    from models.registry import FITTED, catalogue
    models = catalogue()
    if args.json:
        print(json.dumps({n: {"description": m.description, "sides": list(m.sides), "fitted": n in FITTED,
                              "anisotropic": bool(m.anisotropic)} for n, m in models.items()}, indent=2))
        return 0
    width = max(len(n) for n in models)
    for name, m in models.items():
        kind = "fitted" if name in FITTED else "analytic"
        print(f"{name:<{width}}  {'/'.join(x.upper() for x in m.sides):9s} {kind:8s}  {m.description}")
    print("(fitted models are fitted to a file on request: gonio fit FILE.h5 --model hp15|ggx1|ggx2, "
          "or gonio evaluate FILE.h5 --model hp15-fit)")
    return 0


def cmd_fit(args: argparse.Namespace) -> int:
    from goniometer import store
    from models.base import ModelError
    from models.fit import fit
    try:
        reference = store.read(args.file)
        if reference.brdf is None:
            raise ModelError(f"{args.model}: the file has no BRDF slices to fit")

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
    print(("converged: " if result.converged else "NOT converged: ") + result.message)
    for k, v in result.params.items():
        print(f"  {k:8s} = {v}")
    if result.errors:
        e = result.errors["total"]
        print(f"RMSE (eq. 4) mean {e['rmse_mean']:.4e}  (R G B) {' '.join(f'{x:.3e}' for x in e['rmse'])}  "
              f"luminance {e['rmse_luminance']:.3e}  noise floor {e['noise_floor_mean']:.2e}")
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    from goniometer import store
    from models.base import ModelError
    from models.evaluate import evaluate, save_slices

    try:
        if args.save_slices:
            store.check_writable(args.save_slices)
        reference = store.read(args.file)
        ev = evaluate(reference, args.model or None, s=args.subcells, isotropize=args.isotropize,
                      progress=None if args.json else (lambda n: print(f"integrating {n} ...", file=sys.stderr)))
    except (store.StoreError, ModelError) as e:
        raise UsageError(f"{args.file}: {e}" if not str(e).startswith(str(args.file)) else str(e)) from None
    if args.save_slices:
        save_slices(args.save_slices, reference, ev)
    if args.json:
        print(json.dumps(ev.to_json(), indent=2))
        return 0
    what = "internal paths (order 1 dropped)" if ev.side == "brdf" else "BTDF"
    print(f"{ev.material} ({ev.category}): RMSE of eq. 4 on the {ev.side.upper()}, "
          f"{len(reference.theta_deg)} incident direction(s), {args.subcells}x{args.subcells} sub-cells")
    print(f"{'model':16s} {'internal mean':>13s} {'(R G B)':>30s} {'luminance':>10s} {'total mean':>11s}  noise floor")
    for name, e in ev.errors.items():
        i, t = e["internal"], e["total"]
        rgb = " ".join(f"{x:9.3e}" for x in i["rmse"])
        print(f"{name:16s} {i['rmse_mean']:13.4e} {rgb:>30s} {i['rmse_luminance']:10.3e} {t['rmse_mean']:11.4e}"
              f"  {i['noise_floor_mean']:.2e}")
    print(f"('internal' = {what}; noise floor = the error a perfect model would show against this reference)")
    for name, note in ev.approximations.items():
        print(f"note {name}: {note}")
    for name, reason in ev.skipped.items():
        print(f"skipped {name}: {reason}")
    if args.save_slices:
        print(f"wrote {args.save_slices}")
    return 0


def cmd_plot(args: argparse.Namespace) -> int:
    from models.base import ModelError
    from models.report import ReportError, plot_file

    incidents = None
    if args.incident is not None:
        thetas, _ = _incident_list(args.incident)
        incidents = thetas
    try:
        r = plot_file(args.file, args.out, args.model, incidents, subcells=args.subcells, isotropize=args.isotropize)
    except (ReportError, ModelError) as e:
        raise UsageError(f"{args.file}: {e}" if not str(e).startswith(str(args.file)) else str(e)) from None
    if args.json:
        print(json.dumps(r, indent=2))
        return 0
    print(f"wrote {len(r['figures'])} figures into {args.out}:")
    for p in r["figures"]:
        print(f"  {p}")
    return 0


# ---------------------------------------------------------------------- database

def cmd_database_list(args: argparse.Namespace) -> int:
    from goniometer.database import DatabaseError, list_rows, load_database
    try:
        db = load_database(args.config)
        rows = list_rows(db, args.out, args.quality) if args.out else list_rows(db)
    except DatabaseError as e:
        raise UsageError(str(e)) from None
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    for r in rows:
        params = " ".join(f"{k}={r[k]}" for k in ("alpha0", "alpha1", "tau_name", "rho_name", "eta1") if k in r)
        status = f"  [{r['status']}]" if "status" in r else ""
        print(f"{r['name']:32s} {r['paper_name']:4s} {r['parametrization']:8s} {params}{status}")
    counts = {}
    for r in rows:
        counts[r["category"]] = counts.get(r["category"], 0) + 1
    print(f"{len(rows)} materials ({', '.join(f'{n} {c}' for c, n in counts.items())}) in {db.name}")
    return 0


def cmd_database_simulate(args: argparse.Namespace) -> int:
    from goniometer.database import DatabaseError, load_database, simulate_database
    from goniometer.simulate import SettingsError, warm_up
    try:
        db = load_database(args.config)
        materials = db.select(args.only)
        if args.quality not in db.qualities:
            raise DatabaseError(f"--quality: {args.quality!r} is not one of {', '.join(db.qualities)}")
        rays = db.qualities[args.quality] * len(db.incident_deg)
    except DatabaseError as e:
        raise UsageError(str(e)) from None
    print(f"{db.name}: {len(materials)} material(s), quality {args.quality} "
          f"({db.qualities[args.quality]:,} rays per slice), into {args.out}", file=sys.stderr)
    from tqdm import tqdm
    bar = tqdm(total=rays * len(materials), unit="ray", unit_scale=True, file=sys.stderr, dynamic_ncols=True,
               disable=None, smoothing=0.05, desc=db.name)

    try:
        with _sigint_latch() as interrupts, bar:
            def on_material(m, status):
                interrupts.check()
                bar.set_postfix_str(f"{m.name} ({status})")

            def progress(n: int) -> None:
                interrupts.check()
                bar.update(n)

            if args.scheduler is None:
                with interrupts.deferred():
                    warm_up()
            summary = simulate_database(db, args.out, args.quality, args.only, threads=args.threads,
                                        scheduler=args.scheduler, resimulate_corrupted=args.resimulate_corrupted,
                                        progress=progress, on_material=on_material)
            bar.update(bar.total - bar.n) if bar.total else None
    except (DatabaseError, SettingsError) as e:
        raise UsageError(str(e)) from None
    print(f"{len(summary.simulated)} simulated ({len(summary.resumed)} resumed, {len(summary.resimulated)} "
          f"re-simulated), {len(summary.skipped)} already done, in {summary.elapsed_s:.0f} s; files in {args.out}")
    return 0


# ---------------------------------------------------------------------- report

def cmd_report(args: argparse.Namespace) -> int:
    from models.report import ReportError, build_report
    from tqdm import tqdm
    incidents = None
    if args.incidents:
        incidents, _ = _incident_list(args.incidents)
    bar = tqdm(total=None, unit="material", file=sys.stderr, dynamic_ncols=True, disable=None, desc="report")

    def progress(done: int, total: int, message: str) -> None:
        bar.total = total
        bar.n = done
        bar.set_postfix_str(message[:80])
        bar.refresh()

    try:
        with bar:
            summary = build_report(args.results, args.out, models=args.model or None, subcells=args.subcells,
                                   progress=progress, incidents_for_figures=incidents, definition=args.definition,
                                   fits=args.fits, isotropize=args.isotropize)
    except ReportError as e:
        raise UsageError(str(e)) from None
    for w in summary.warnings:
        print(f"warning: {w}", file=sys.stderr)
    print(f"{len(summary.materials)} material(s), {summary.records} (material, model) record(s); "
          f"{len(summary.evaluated)} evaluated, {len(summary.reused)} reused from the cache")
    print(f"errors: {summary.errors_json}")
    print(f"open: {summary.index_html}")
    return 0


# ---------------------------------------------------------------------- parser

def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="gonio", description="Monte Carlo virtual goniometer for layered materials.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("simulate", help="simulate a material file into an HDF5 slices file")
    p.add_argument("config", metavar="CONFIG.toml")
    p.add_argument("--out", required=True, metavar="FILE.h5")
    p.add_argument("--rays", type=int, help="rays per incident direction")
    p.add_argument("--incident", metavar="LIST", help="incident elevations in degrees, e.g. 0,30,60 (theta:phi for an azimuth)")
    p.add_argument("--parametrization", choices=("classic", "half"))
    p.add_argument("--resolution", metavar="N_THETAxN_PHI", help="e.g. 90x360")
    p.add_argument("--seed", type=int)
    p.add_argument("--threads", type=int)
    p.add_argument("--masking", choices=("separable", "height-correlated"))
    p.add_argument("--max-order", dest="max_order", type=int, help="bounce orders stored separately (K)")
    p.add_argument("--restart", action="store_true",
                   help="discard the checkpoints an interrupted run of the same command left (.FILE.h5.partial)")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("info", help="describe a simulated file")
    p.add_argument("file", metavar="FILE.h5")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_info)

    p = sub.add_parser("database", help="material databases: list, simulate")
    dsub = p.add_subparsers(dest="database_command", required=True, metavar="ACTION")
    q = dsub.add_parser("list", help="list the materials a database definition expands to")
    q.add_argument("config", metavar="CONFIG.toml")
    q.add_argument("--out", help="also show each material's status in this results directory")
    q.add_argument("--quality", default="quick")
    q.add_argument("--json", action="store_true")
    q.set_defaults(func=cmd_database_list)
    q = dsub.add_parser("simulate", help="simulate every material (resumable) into one HDF5 file each")
    q.add_argument("config", metavar="CONFIG.toml")
    q.add_argument("--out", required=True, metavar="DIR")
    q.add_argument("--quality", default="quick", help="a quality of the definition's [quality] table (quick, paper)")
    q.add_argument("--only", metavar="GLOB", help="materials whose name matches, e.g. 'metal/M2-*'")
    q.add_argument("--threads", type=int)
    q.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="run the tasks on a Dask distributed cluster")
    q.add_argument("--resimulate-corrupted", action="store_true",
                   help="move unreadable finished files aside and simulate them again")
    q.set_defaults(func=cmd_database_simulate)

    p = sub.add_parser("report", help="error tables, figures and an HTML browser for a simulated database")
    p.add_argument("results", metavar="RESULTS_DIR")
    p.add_argument("--out", required=True, metavar="DIR")
    p.add_argument("--model", action="append", metavar="NAME", help="models to evaluate (default: all that apply)")
    p.add_argument("--subcells", type=int, default=5)
    p.add_argument("--incidents", metavar="LIST", help="incident elevations to draw figures for (default: all)")
    p.add_argument("--definition", metavar="CONFIG.toml", help="the database definition, if it has moved")
    p.add_argument("--fits", action="store_true", help="also fit hp15, ggx1 and ggx2 to every BRDF (slow)")
    p.add_argument("--isotropize", choices=("mean",),
                   help="let isotropic models evaluate anisotropic stacks with the mean roughness")
    p.set_defaults(func=cmd_report)

    p = sub.add_parser("fit", help="fit a compact model (hp15, ggx1, ggx2) to the BRDF slices of a file")
    p.add_argument("file", metavar="FILE.h5")
    p.add_argument("--model", required=True, choices=("hp15", "ggx1", "ggx2"))
    p.add_argument("--json", action="store_true")
    p.add_argument("--starts", type=int, default=4, help="optimiser starts (default 4)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--weighting", choices=("paper", "eq4"), default="paper",
                   help="the paper's eq. 29 weighting (default) or eq. 4 directly")
    p.set_defaults(func=cmd_fit)

    p = sub.add_parser("models", help="list the analytic models and what they support")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_models)

    p = sub.add_parser("evaluate", help="integrate models onto a simulated file and print their errors")
    p.add_argument("file", metavar="FILE.h5")
    p.add_argument("--model", action="append", metavar="NAME", help="a model to evaluate (repeatable; default: all that apply)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--save-slices", dest="save_slices", metavar="OUT.h5", help="write the integrated model slices")
    p.add_argument("--subcells", type=int, default=5, help="sub-cells per cell axis (default 5)")
    p.add_argument("--isotropize", choices=("mean",),
                   help="let isotropic models evaluate an anisotropic stack with the mean roughness (noted in the output)")
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser("plot", help="figures of one simulated file (incident plane, top views, bounce orders), "
                                    "optionally with models")
    p.add_argument("file", metavar="FILE.h5")
    p.add_argument("--out", required=True, metavar="DIR", help="directory for the PNG figures")
    p.add_argument("--model", action="append", metavar="NAME",
                   help="draw this model too (repeatable; 'all': every model that supports the stack)")
    p.add_argument("--incident", metavar="THETAS", help="only these incident angles of the file, e.g. 0,60")
    p.add_argument("--subcells", type=int, default=5, help="sub-cells per cell side when integrating models")
    p.add_argument("--isotropize", choices=("mean",), help="feed isotropic models the mean roughness")
    p.add_argument("--json", action="store_true", help="print the figure paths (and the model errors) as JSON")
    p.set_defaults(func=cmd_plot)

    from models.inverse_cli import add_parsers as add_inverse_parsers
    add_inverse_parsers(sub)
    from models.tables_cli import add_parsers as add_tables_parsers
    add_tables_parsers(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    func: Callable[[argparse.Namespace], int] = args.func
    try:
        return func(args)
    except UsageError as e:
        print(f"gonio: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        out = getattr(args, "out", None)
        note = f"; nothing written to {out}" if out else ""
        print(f"gonio: interrupted{note}", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
