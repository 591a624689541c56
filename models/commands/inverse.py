"""``gonio invert`` and ``gonio validate-inverse``: the command line of the inverse method
(:mod:`models.inverse`; reports and figures: :mod:`models.report.inverse`). Parsing, calls and
printing only.

Registered through :func:`register` (the ``models`` command plugin). User errors raise
:class:`goniometer.cli.common.UsageError` (one line ``gonio: error: ...``, exit status 2). A well-formed
request that has no physical solution is not a usage error: ``gonio invert`` prints
``not physically achievable: ...`` on stderr and exits with status 1 (:data:`EXIT_NOT_ACHIEVABLE`).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from goniometer.cli.common import THREADS_HELP, UsageError, add_overwrite, thread_number, whole_number

EXIT_NOT_ACHIEVABLE = 1


def _usage(msg: str) -> UsageError:
    return UsageError(msg)


def _check_out(path: str | None, suffix: str, option: str, create_parent: bool = False, overwrite: bool = False,
               inputs=()) -> Path | None:
    if path is None:
        return None
    p = Path(path)
    if p.suffix.lower() != suffix:
        raise _usage(f"{option}: {path!r} should end in {suffix}")
    if p.exists() and p.is_dir():
        raise _usage(f"{option}: {path!r} is a directory")
    from goniometer.files.outputs import OutputError, check_output
    try:
        check_output(p, inputs=inputs, overwrite=overwrite, option=option)
    except OutputError as e:
        raise _usage(str(e)) from None
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.exists():
        if not create_parent:
            raise _usage(f"{option}: directory {str(parent)!r} does not exist")
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise _usage(f"{option}: cannot create {str(parent)!r}: {e.strerror or e}") from None
    return p


# ---------------------------------------------------------------------------- invert

def _options(args: argparse.Namespace):
    from models.inverse import InverseError, InverseOptions
    try:
        return InverseOptions(eta_max=args.eta_max, variance_channel=args.variance_channel,
                              top_variance=args.top_variance)
    except InverseError as e:
        raise _usage(str(e)) from None


def cmd_invert(args: argparse.Namespace) -> int:
    from goniometer import atomic
    from models import inverse
    from models.inverse import InverseError, forward_check
    from models.report.inverse import material_text
    if args.measured is not None:
        if args.lobe:
            raise _usage(f"invert: a MEASURED file ({args.measured}) and --lobe exclude each other: the lobes of a "
                         f"measurement are fitted (--lobes K)")
        return _invert_measured(args)
    extra = _measured_only(args)
    if extra:
        raise _usage(f"{extra[0]}: goes with a MEASURED file (gonio invert FILE.bsdf|FILE.binary {extra[0]} ...)")
    if not args.lobe:
        raise _usage("invert: at least one --lobe is required (e.g. --lobe \"R=0.04 sigma=0 layers=1\")")
    try:
        lobes = [inverse.parse_lobe(t) for t in args.lobe]
        picks = inverse.parse_picks(args.pick, len(lobes))
    except InverseError as e:
        raise _usage(str(e)) from None
    out = _check_out(args.out, ".toml", "--out", overwrite=args.overwrite)
    classes_png = _check_out(args.classes, ".png", "--classes", overwrite=args.overwrite)
    options = _options(args)
    try:
        inv = inverse.solve(lobes, args.base, picks, options, name=args.name)
    except InverseError as e:
        raise _usage(str(e)) from None
    if not inv.achievable:
        print(f"not physically achievable: {inv.reason}", file=sys.stderr)
        if classes_png is not None and inv.classes:
            from models.report.inverse import classes_figure, save_png
            save_png(classes_figure(inv), classes_png)
            print(f"wrote {classes_png} (classes down to the failing lobe)", file=sys.stderr)
        if args.json:
            print(json.dumps(inverse.inversion_json(inv), indent=2))
        return EXIT_NOT_ACHIEVABLE
    stack = inv.stack()
    checks = forward_check(inv)
    if out is not None:
        atomic.write_bytes(out, material_text(inv, stack, checks).encode())
    if classes_png is not None:
        from models.report.inverse import classes_figure, save_png
        save_png(classes_figure(inv), classes_png)
    if args.json:
        print(json.dumps(inverse.inversion_json(inv, stack, checks), indent=2))
        return 0
    _print_stack(inv, stack, checks, lobes)
    if out is not None:
        print(f"wrote {out} (simulate it with: gonio simulate {out} --out FILE.h5 --incident 0 --parametrization half)")
    if classes_png is not None:
        print(f"wrote {classes_png}")
    return 0


def _print_stack(inv, stack, checks, lobes) -> None:
    from models.report.inverse import rgb_text, value_text
    print(f"{stack.name} ({stack.category}), {len(stack.interfaces)} interface(s), solved in "
          f"{1000 * inv.elapsed_s:.1f} ms" + (" (default choices moved by the search)" if inv.searched else ""))
    for layer in json.loads(stack.to_json())["layers"]:
        print("  " + ", ".join(f"{k}={value_text(v) if not isinstance(v, str) else v}" for k, v in layer.items()))
    print(f"{'lobe':>4}  {'R requested':>22} {'R forward':>22}  {'sigma req.':>10} {'sigma forward':>24}")
    for k, (lobe, c) in enumerate(zip(lobes, checks)):
        print(f"{k + 1:>4}  {rgb_text(lobe.rgb):>22} {rgb_text(c.R_forward):>22}  {lobe.sigma:>10.4g} "
              f"{rgb_text(c.sigma_forward):>24}")


# ---------------------------------------------------------------------------- invert MEASURED

#: options of ``gonio invert`` that only a MEASURED file takes, with their "not given" values
_MEASURED_ONLY = (("--lobes", "lobes", None), ("--layers", "layers", None), ("--simulate", "simulate", False),
                  ("--rays", "rays", None), ("--seed", "seed", None), ("--threads", "threads", None))


def _measured_only(args: argparse.Namespace) -> list[str]:
    """The measured-only options given."""
    return [o for o, k, unset in _MEASURED_ONLY if getattr(args, k) != unset]


def _layers(text: str | None, n_lobes: int) -> list[int] | None:
    if text is None:
        return None
    try:
        layers = [int(x) for x in text.split(",")]
    except ValueError:
        raise _usage(f"--layers: {text!r} is not a comma-separated list of 1 or 2 (one per lobe, top first)") from None
    if len(layers) != n_lobes or any(x not in (1, 2) for x in layers):
        raise _usage(f"--layers: {text!r} needs {n_lobes} value(s), each 1 or 2 (one per fitted lobe, top first)")
    return layers


def _invert_measured(args: argparse.Namespace) -> int:
    """``gonio invert MEASURED``: fit lobes to a measurement at normal incidence, invert them,
    optionally simulate the stack against the measurement (docs/inverse.md, "From a measurement")."""
    from goniometer import atomic
    from goniometer.cli.common import usage_errors
    from goniometer.files.measured import MeasuredError, read_measured
    from models import inverse
    from models.inverse import InverseError, forward_check
    from models.inverse import measured as M
    from models.report.inverse import material_text, rgb_text
    n_lobes = M.DEFAULT_LOBES if args.lobes is None else args.lobes
    if not 1 <= n_lobes <= M.MAX_LOBES:
        raise _usage(f"--lobes: {n_lobes} is not in 1..{M.MAX_LOBES}")
    layers = _layers(args.layers, n_lobes)
    if not args.simulate:
        given = [o for o, k in (("--rays", "rays"), ("--seed", "seed"), ("--threads", "threads"))
                 if getattr(args, k) is not None]
        if given:
            raise _usage(f"{given[0]}: goes with --simulate")
    rays = M.SIMULATE_RAYS if args.rays is None else args.rays
    if rays < 1000:
        raise _usage(f"--rays: at least 1000, got {rays}")
    with usage_errors(InverseError):
        picks = inverse.parse_picks(args.pick, n_lobes)
    out = _check_out(args.out, ".toml", "--out", overwrite=args.overwrite, inputs=[args.measured])
    classes_png = _check_out(args.classes, ".png", "--classes", overwrite=args.overwrite, inputs=[args.measured])
    options = _options(args)
    with usage_errors(MeasuredError):
        measured = read_measured(args.measured)
    with usage_errors(InverseError, prefix=str(args.measured)):
        mi = M.invert_measured(measured, n_lobes, layers, args.base, picks, options, name=args.name)
    inv = mi.inversion
    doc = {"measurement": mi.to_json()}
    if not inv.achievable:
        print(f"not physically achievable: {inv.reason}", file=sys.stderr)
        if classes_png is not None and inv.classes:
            from models.report.inverse import classes_figure, save_png
            save_png(classes_figure(inv), classes_png)
            print(f"wrote {classes_png} (classes down to the failing lobe)", file=sys.stderr)
        if args.json:
            print(json.dumps({**doc, **inverse.inversion_json(inv)}, indent=2))
        return EXIT_NOT_ACHIEVABLE
    stack = inv.stack()
    checks = forward_check(inv)
    if out is not None:
        atomic.write_bytes(out, material_text(inv, stack, checks).encode())
    if classes_png is not None:
        from models.report.inverse import classes_figure, save_png
        save_png(classes_figure(inv), classes_png)
    sim = None
    if args.simulate:
        sim = M.simulate_against(mi.reference, stack, mi.lobes, rays, 1 if args.seed is None else args.seed,
                                 args.threads)
        sim.pop("result")
        fit = mi.fit
        for k, lobe in enumerate(sim["lobes"]):
            lobe["R_fitted"], lobe["sigma_fitted"] = fit.R[k], fit.sigma[k]
        doc["simulation"] = inverse.jsonable(sim)
    if args.json:
        print(json.dumps({**doc, **inverse.inversion_json(inv, stack, checks)}, indent=2))
        return 0
    fit = mi.fit
    print(f"{measured.path} ({measured.kind}): {int(fit.rings.valid.sum())} rings at normal incidence, "
          f"{fit.n_lobes} GGX lobe(s) per channel, misfit {rgb_text(fit.misfit)} (relative)")
    for k in range(fit.n_lobes):
        print(f"  lobe {k + 1}: R {rgb_text(fit.R[k])}, alpha {rgb_text(fit.alpha[k])}, sigma {rgb_text(fit.sigma[k])} "
              f"-> {mi.lobes[k].sigma:.4g}")
    _print_stack(inv, stack, checks, mi.lobes)
    if sim is not None:
        print(f"simulated ({rays:,} rays, normal incidence, half {sim['cells']} cells): RMSE {rgb_text(sim['rmse'])}, "
              f"measurement's norm {rgb_text(sim['reference_norm'])}, relative {rgb_text(sim['relative_rmse'])}, "
              f"simulation's noise floor {rgb_text(sim['noise_floor'])}; beyond the noise {rgb_text(sim['excess_rmse'])}, "
              f"relative {rgb_text(sim['relative_excess'])}")
        for k, s in enumerate(sim["lobes"]):
            if s.get("R_simulated") is None:
                print(f"  lobe {k + 1}: simulated together with lobes {s.get('simulated_group')}")
                continue
            print(f"  lobe {k + 1}: R fitted {rgb_text(fit.R[k])} simulated {rgb_text(s['R_simulated'])}; sigma fitted "
                  f"{rgb_text(fit.sigma[k])} simulated {rgb_text(s['sigma_simulated'])}")
    if out is not None:
        print(f"wrote {out}")
    if classes_png is not None:
        print(f"wrote {classes_png}")
    return 0


# ---------------------------------------------------------------------------- validate-inverse

def cmd_validate_inverse(args: argparse.Namespace) -> int:
    from models import inverse as V
    from models.inverse import InverseError
    from models.report import inverse as report
    try:
        cases = V.load_cases(args.cases)
    except InverseError as e:
        raise _usage(str(e)) from None
    json_out = _check_out(args.json, ".json", "--json", create_parent=True, overwrite=args.overwrite,
                          inputs=[args.cases])
    if args.report and Path(args.report).exists() and not Path(args.report).is_dir():
        raise _usage(f"--report: {args.report!r} exists and is not a directory")
    if args.report:
        from goniometer.files.outputs import OutputError, check_output
        try:
            check_output(args.report, inputs=[args.cases], overwrite=args.overwrite, option="--report",
                         directory=True, marker="index.html")
        except OutputError as e:
            raise _usage(str(e)) from None
    if args.rays is not None and args.rays < 1000:
        raise _usage(f"--rays: at least 1000, got {args.rays}")
    resolution = (90, 8)
    if args.resolution:
        try:
            a, b = args.resolution.lower().split("x")
            resolution = (int(a), int(b))
        except ValueError:
            raise _usage(f"--resolution: {args.resolution!r} is not N_THETAxN_PHI (e.g. 90x8)") from None
        if not (8 <= resolution[0] <= 2000 and 1 <= resolution[1] <= 3600):
            raise _usage(f"--resolution: {args.resolution!r} out of range (n_theta 8..2000, n_phi 1..3600)")
    if args.only:
        import fnmatch
        cases = [c for c in cases if fnmatch.fnmatch(c.name, args.only)]
        if not cases:
            raise _usage(f"--only: no case matches {args.only!r}")
    options = _options(args)

    def progress(done: int, total: int, name: str) -> None:
        print(f"[{done}/{total}] {name}", file=sys.stderr)

    results = V.run_validation(cases, simulate=args.simulate, rays=args.rays or V.DEFAULT_RAYS,
                               resolution=resolution, seed=args.seed, options=options, threads=args.threads,
                               progress=progress)
    doc = V.validation_json(results, args.simulate, {"cases_file": str(args.cases), "rays": args.rays or V.DEFAULT_RAYS,
                                                      "resolution": list(resolution), "seed": args.seed})
    if json_out is not None:
        report.write_json(json_out, doc)
    if args.report:
        paths = report.write_report(results, args.report, args.simulate)
    _print_table(results, args.simulate)
    s = doc["summary"]
    print(f"{s['cases']} case(s), {s['achievable']} achievable; largest forward error R "
          f"{_pct(s['max_R_forward_rel_error'])}, sigma {_pct(s['max_sigma_forward_error'])}")
    if s["unexpected"]:
        print(f"unexpected achievability: {', '.join(s['unexpected'])}")
    if json_out is not None:
        print(f"wrote {json_out}")
    if args.report:
        print(f"report: {paths['markdown']} (open {paths['html']})")
    return 1 if s["unexpected"] else 0


def _pct(x: float | None) -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{100 * x:.3f}%"


def _print_table(results, simulate: bool) -> None:
    from models.report.inverse import rgb_text
    for r in results:
        if not r.achievable:
            print(f"{r.case.name}: not physically achievable{'' if not r.case.expect_achievable else ' (UNEXPECTED)'}: "
                  f"{r.inversion.reason}")
            continue
        er, es = r.max_forward_error()
        print(f"{r.case.name}: forward error R {_pct(er)}, sigma {_pct(es)}")
        for k, c in enumerate(r.checks):
            line = (f"    lobe {k + 1}: R {rgb_text(c.R_requested)} -> {rgb_text(c.R_forward)}; "
                    f"sigma {c.sigma_requested:.4g} -> {rgb_text(c.sigma_forward)}")
            if simulate:
                if c.R_simulated is not None:
                    line += f"; simulated R {rgb_text(c.R_simulated)}, sigma {rgb_text(c.sigma_simulated)}"
                elif c.group:
                    line += f"; simulated together with lobes {c.group}"
            print(line)


# ---------------------------------------------------------------------------- registration

def register(subparsers) -> None:
    """Register ``invert`` and ``validate-inverse`` on the ``gonio`` sub-command parser."""
    p = subparsers.add_parser("invert", help="lobes at normal incidence -> a layered material (Bati 2021 inverse); "
                                             "or a measured file's lobes")
    p.add_argument("measured", nargs="?", metavar="MEASURED",
                   help="a measured BRDF (MERL .binary or RGL .bsdf) whose lobes at normal incidence are fitted and "
                        "inverted, instead of --lobe (default: none)")
    p.add_argument("--lobe", action="append", metavar="SPEC",
                   help='a lobe, top first, e.g. "R=0.03,0.06,0.09 sigma=0.05 layers=2" (repeatable; at least one, '
                        'no default)')
    p.add_argument("--base", choices=("dielectric", "conductor"), default="dielectric",
                   help="the last lobe ends on a dielectric (default) or a conductor")
    p.add_argument("--pick", default="center", metavar="center|PARAMS",
                   help="which point of each equivalence class: center (default) or K.NAME=VALUE items, "
                        "NAME in u1, eta1, root, u2, eta2, tau0, tau1 (e.g. \"1.u1=0.2 2.tau1=0,0.3,0\")")
    p.add_argument("--eta-max", dest="eta_max", type=float, default=4.0, help="largest dielectric index (default 4)")
    p.add_argument("--variance-channel", dest="variance_channel", choices=("minimax", "max"), default="minimax",
                   help="achromatic roughness of coloured lobes: minimax over channels (default) or the "
                        "channel of maximal reflectance (the paper)")
    p.add_argument("--top-variance", dest="top_variance", choices=("exact", "paper"), default="exact",
                   help="first interface of a stacked 2-layer lobe: exact variance (default) or alg. 5 as printed")
    p.add_argument("--out", metavar="STACK.toml", help="write the material file (default: not written)")
    p.add_argument("--classes", metavar="OUT.png", help="plot the equivalence classes (default: no plot)")
    p.add_argument("--name", default="inverse", help="material name (default inverse)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--lobes", type=whole_number, metavar="K",
                   help="MEASURED: GGX lobes fitted per channel, 1..3 (default 1)")
    p.add_argument("--layers", metavar="L[,L...]",
                   help="MEASURED: interfaces of each fitted lobe, top first, 1 or 2 (default 1 each)")
    p.add_argument("--simulate", action="store_true",
                   help="MEASURED: simulate the retrieved stack at normal incidence and compare it with the "
                        "measurement (default: no simulation)")
    p.add_argument("--rays", type=whole_number, help="MEASURED --simulate: rays (default 1,000,000)")
    p.add_argument("--seed", type=whole_number, help="MEASURED --simulate: seed (default 1)")
    p.add_argument("--threads", type=thread_number, help="MEASURED --simulate: " + THREADS_HELP)
    add_overwrite(p)
    p.set_defaults(func=cmd_invert)

    p = subparsers.add_parser("validate-inverse", help="run target lobe configurations through the inverse method "
                                                       "and check them (forward model, optional simulation)")
    p.add_argument("cases", metavar="CASES.toml")
    p.add_argument("--json", metavar="OUT.json", help="write the results as JSON (default: not written)")
    p.add_argument("--simulate", action="store_true", help="also simulate every stack at normal incidence")
    p.add_argument("--report", metavar="DIR",
                   help="write report.md, index.html and figures into DIR (default: not written)")
    p.add_argument("--rays", type=whole_number, help="rays per simulation (default 4,000,000)")
    p.add_argument("--resolution", metavar="N_THETAxN_PHI", help="half slices of the simulation (default 90x8)")
    p.add_argument("--seed", type=whole_number, default=1, help="seed of the simulations (default: %(default)s)")
    p.add_argument("--threads", type=thread_number, help=THREADS_HELP)
    p.add_argument("--only", metavar="GLOB", help="cases whose name matches (default: all)")
    p.add_argument("--eta-max", dest="eta_max", type=float, default=4.0,
                   help="largest dielectric index (default: %(default)g)")
    p.add_argument("--variance-channel", dest="variance_channel", choices=("minimax", "max"), default="minimax",
                   help="as for gonio invert (default: %(default)s)")
    p.add_argument("--top-variance", dest="top_variance", choices=("exact", "paper"), default="exact",
                   help="as for gonio invert (default: %(default)s)")
    add_overwrite(p)
    p.set_defaults(func=cmd_validate_inverse)
