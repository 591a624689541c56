"""``gonio furnace``: the white-furnace / directional-albedo table of one material file, simulated
and per model (:mod:`models.furnace`; ``docs/furnace.md``)."""

from __future__ import annotations

import argparse
import json
import sys

from goniometer.cli.common import (UsageError, add_overwrite, add_spectral, compile_kernels, incident_list, output_path,
                                   progress_bar, sigint_latch, thread_number, usage_errors, whole_number)


def register(sub) -> None:
    """Add ``furnace`` to the ``gonio`` sub-command parser."""
    p = sub.add_parser("furnace", help="directional albedo E(theta) of a material file: simulation (with standard "
                                       "errors and energy terms) and every model that applies (white-furnace tables)")
    p.add_argument("config", metavar="CONFIG.toml")
    p.add_argument("--json", action="store_true", help="print one JSON object (docs/furnace.md)")
    p.add_argument("--plot", metavar="FILE.png", help="also draw albedo vs incident angle into this PNG (default: no figure)")
    p.add_argument("--incident", metavar="LIST",
                   help="incident elevations in degrees, e.g. 0,30,60 (theta:phi for an azimuth); default: the "
                        "file's [simulation] incident_deg, else 0,5,...,85")
    p.add_argument("--rays", type=whole_number,
                   help="rays per incident direction; default: the file's [simulation] rays, else 100000")
    p.add_argument("--seed", type=whole_number, help="random seed; default: the file's [simulation] seed, else 1")
    p.add_argument("--threads", type=thread_number,
                   help="tracing threads; default: the file's [simulation] threads, else all of numba's threads")
    p.add_argument("--multiple-scattering", dest="multiple_scattering", action="store_true",
                   help="every interface scatters multiply on its microsurface (Heitz et al. 2016); "
                        "default: as the file says")
    add_spectral(p)
    add_overwrite(p)
    p.set_defaults(func=cmd_furnace)


def _check_plot_path(path: str, config: str, overwrite: bool) -> None:
    if not path.lower().endswith(".png"):
        raise UsageError(f"--plot: {path!r} must name a .png file")
    output_path(path, inputs=[config], overwrite=overwrite, option="--plot")


def cmd_furnace(args: argparse.Namespace) -> int:
    from goniometer.run.settings import SettingsError
    from goniometer.stack import StackError, load_toml
    from goniometer.kernel.tracer import thread_count
    from goniometer.run.tasks import warm_up
    from models.base import ModelError
    from models.commands.failures import report_failures
    from models.furnace import furnace_settings, model_albedos, run_furnace

    try:
        stack, table = load_toml(args.config)
    except (StackError, OSError) as e:
        raise UsageError(str(e)) from None
    if args.multiple_scattering:
        stack = stack.with_multiple_scattering()
    thetas = phis = None
    if args.incident is not None:
        t, p = incident_list(args.incident)
        thetas, phis = tuple(t), (tuple(p) if p is not None else None)
    try:
        settings = furnace_settings(table, incident_deg=thetas, incident_phi_deg=phis, rays=args.rays,
                                    seed=args.seed, threads=args.threads, spectral=args.spectral,
                                    wavelength_bins=args.wavelength_bins, source=f"{args.config}: simulation")
    except SettingsError as e:
        raise UsageError(str(e) if str(e).startswith(str(args.config)) else _option_error(str(e))) from None
    with usage_errors(StackError, prefix=str(args.config)):
        per = _paths_per_incident(stack, settings)
    if args.plot:
        _check_plot_path(args.plot, args.config, args.overwrite)

    quiet = args.json
    if not quiet:
        spectral = (f", spectral: {settings.wavelength_bins} bins over 360-830 nm in {per // settings.rays} "
                    f"launch(es) of {settings.rays:,} paths" if settings.spectral else "")
        print(f"furnace {stack.name} ({stack.category}, {stack.base} base): {len(settings.incident_deg)} incident "
              f"direction(s) x {settings.rays:,} rays{spectral}, {thread_count(settings.threads)} thread(s)",
              file=sys.stderr)
        if stack.is_spectral and not settings.spectral:
            print(f"note: {stack.name} has spectral data; an RGB run traces their RGB equivalents "
                  f"(docs/spectral.md section 3); --spectral traces the spectra", file=sys.stderr)
    with sigint_latch() as interrupts:
        try:
            # the models first (a model that fails stops the command before any ray is traced), and
            # outside the progress bar, whose rate is the tracing's
            models = model_albedos(stack, settings.incident_deg, settings.incident_phi_deg,
                                   progress=None if quiet else (lambda n: print(f"integrating {n} ...",
                                                                                file=sys.stderr)))
            with interrupts.deferred():
                compile_kernels(lambda: warm_up(stack, settings))
            with progress_bar(per * len(settings.incident_deg), stack.name) as bar:
                def progress(n: int) -> None:
                    interrupts.check()
                    bar.update(n)

                result = run_furnace(stack, settings, progress=progress, models=models)
        except ModelError as e:
            raise UsageError(f"{args.config}: {e}") from None
    if args.plot:
        from models.report.furnace import plot_furnace
        plot_furnace(result, args.plot)
    if args.json:
        print(json.dumps(result.to_json(), indent=2))
    else:
        _print_table(result)
        if args.plot:
            print(f"wrote {args.plot}")
    return report_failures(result.models.failed)


def _paths_per_incident(stack, settings) -> int:
    """Paths per incident direction: ``rays``, times a spectral run's launches. Raises StackError
    for what the run cannot trace: a spectral table that does not cover the bins, a film in an RGB
    run (``docs/spectral.md``)."""
    if not settings.spectral:
        from goniometer.kernel.packing import check_films
        check_films(stack)
        return settings.rays
    from goniometer.run.launches import launch_stacks
    return settings.rays * len(launch_stacks(stack, settings))


#: the option that sets each settings field
OPTIONS = {"incident_deg": "--incident", "incident_phi_deg": "--incident", "rays": "--rays", "seed": "--seed",
           "threads": "--threads", "wavelength_bins": "--wavelength-bins"}


def _option_error(message: str) -> str:
    """A settings error about a command-line value, named by its option
    (``rays: 0 is outside [1, ...]`` -> ``--rays: 0 is outside [1, ...]``)."""
    field, _, rest = message.partition(":")
    return f"{OPTIONS[field]}:{rest}" if field in OPTIONS else message


def _rgb(a) -> str:
    return " ".join(f"{x:7.4f}" for x in a)


def _print_table(r) -> None:
    """The text table (``docs/furnace.md`` section 4): RGB columns, or for a spectral run the
    bins' linear sRGB with each albedo's smallest and largest bin."""
    from goniometer.run.results import ENERGY_TERMS
    sp = r.spectral
    print(f"{r.material} ({r.category}, {r.base} base): directional albedo E = reflected + transmitted, "
          f"{r.rays:,} rays per angle{' and wavelength bin' if sp is not None else ''}, seed {r.seed}")
    if sp is not None:
        print(f"spectral: {sp.bins} wavelength bins, {sp.wavelength_nm[0]:.1f}-{sp.wavelength_nm[-1]:.1f} nm "
              f"(centres), {sp.launches} launch(es); columns in {r.channels} (docs/spectral.md section 4)")
        print("  (standard errors are upper bounds; components leave [0, 1] for colours outside the sRGB gamut; "
              "per bin: --json, spectral.per_bin)")
    label = "linear sRGB" if sp is not None else "R G B"
    extra = f"  {'E over the bins [min, max]':>26}" if sp is not None else ""
    print(f"{'theta_l':>7}  {f'simulated E ({label})':>23}  {'std. error':>23}  {'reflected':>23}  "
          f"{'transmitted':>23}  {'absorbed':>23}  {'masking_loss':>23}{extra}")
    for m, t in enumerate(r.incident_deg):
        cols = [_rgb(r.albedo[m]), " ".join(f"{x:7.1e}" for x in r.stderr[m])]
        cols += [_rgb(r.energy[k][m]) for k in ENERGY_TERMS]
        if sp is not None:
            cols.append(f"{'':8s}[{sp.albedo[m].min():7.4f}, {sp.albedo[m].max():7.4f}]")
        print(f"{t:7.2f}  " + "  ".join(cols))
    if any(abs(x) > 0 for k in ("roulette", "capped") for x in r.energy[k].ravel()):
        worst = {k: float(abs(r.energy[k]).max()) for k in ("roulette", "capped")}
        print(f"(roulette and capped weight, at most {worst['roulette']:.1e} and {worst['capped']:.1e}, "
              f"close the bookkeeping; {r.capped_paths} path(s) reached the event cap)")
    if r.models.albedo:
        names = list(r.models.albedo)
        print()
        reads = "; the models read the material's RGB equivalent, docs/spectral.md" if sp is not None else ""
        print(f"models' directional albedo ({' + '.join(s.upper() for s in r.sides)}; quadrature, docs/furnace.md), "
              f"minus the simulation in brackets ({label}{reads}):")
        for name in names:
            print(f"  {name}")
            for m, t in enumerate(r.incident_deg):
                a = r.models.albedo[name][m]
                print(f"    {t:7.2f}  {_rgb(a)}   [{' '.join(f'{x:+8.4f}' for x in a - r.albedo[m])}]")
    for name, reason in r.models.skipped.items():
        print(f"skipped {name}: {reason}")
