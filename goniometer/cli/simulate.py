"""``gonio simulate`` and ``gonio info``: one material file in, one slices file out, and its summary."""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from goniometer.cli.common import (FROM_FILE, THREADS_HELP, ResumeAware, UsageError, add_device, add_overwrite,
                                   add_polarized, add_spectral, compile_kernels, incident_list, output_path,
                                   progress_bar, resolution, sigint_latch, thread_number, usage_errors, whole_number)

def settings_defaults() -> dict[str, str]:
    """The defaults of :class:`~goniometer.run.settings.SimulationSettings` as the help prints them."""
    from dataclasses import fields

    from goniometer.run.settings import SimulationSettings
    d = {f.name: f.default for f in fields(SimulationSettings)}
    return {"rays": f"{d['rays']:,}", "incident_deg": ",".join(f"{x:g}" for x in d["incident_deg"]),
            "parametrization": d["parametrization"], "resolution": f"{d['resolution'][0]}x{d['resolution'][1]}",
            "seed": str(d["seed"]), "masking": d["masking"], "max_order": str(d["max_order"]),
            "first_order": d["first_order"]}


def register(sub) -> None:
    """Add ``simulate`` and ``info`` to the ``gonio`` sub-command parser."""
    from goniometer.run.settings import FIRST_ORDER, MASKING, PARAMETRIZATIONS
    d = settings_defaults()
    p = sub.add_parser("simulate", help="simulate a material file into an HDF5 slices file")
    p.add_argument("config", metavar="CONFIG.toml")
    p.add_argument("--out", required=True, metavar="FILE.h5", help="the slices file to write (required)")
    p.add_argument("--rays", type=whole_number, help=f"rays per incident direction (default: {FROM_FILE}{d['rays']})")
    p.add_argument("--incident", metavar="LIST",
                   help="incident elevations in degrees, e.g. 0,30,60 (theta:phi for an azimuth) "
                        f"(default: {FROM_FILE}{d['incident_deg']})")
    p.add_argument("--parametrization", choices=PARAMETRIZATIONS,
                   help="cell grid: theta/phi of v, of the half vector, or the RGL format's sample space (for "
                        f"gonio export --format rgl; docs/rgl-format.md) (default: {FROM_FILE}{d['parametrization']})")
    p.add_argument("--rgl-grid", dest="rgl_grid", metavar="N_THETA_IxN_PHI_IxN",
                   help="the RGL grid of --parametrization rgl: incident elevations (uniform in cos, the last at "
                        "89 deg), azimuths over [-180, 180] (1: isotropic) and sample-space nodes per side "
                        "(default: the file's [simulation] rgl_grid, else 8x1x32, 8x9x32 for an anisotropic stack)")
    p.add_argument("--resolution", metavar="N_THETAxN_PHI",
                   help=f"cells per slice, e.g. 90x360 (default: {FROM_FILE}{d['resolution']})")
    p.add_argument("--seed", type=whole_number, help=f"random seed (default: {FROM_FILE}{d['seed']})")
    p.add_argument("--threads", type=thread_number, help=THREADS_HELP)
    add_device(p)
    p.add_argument("--masking", choices=MASKING,
                   help=f"microfacet masking-shadowing (default: {FROM_FILE}{d['masking']})")
    p.add_argument("--max-order", dest="max_order", type=whole_number,
                   help=f"bounce orders stored separately (K) (default: {FROM_FILE}{d['max_order']})")
    p.add_argument("--first-order", dest="first_order", choices=FIRST_ORDER,
                   help="bounce order 1 (one reflection on the top interface): traced, or integrated over the "
                        "cells in the simulator's optics, which removes its noise (recorded in the file; "
                        f"docs/first-order.md) (default: {FROM_FILE}{d['first_order']})")
    p.add_argument("--multiple-scattering", dest="multiple_scattering", action="store_true",
                   help="every interface scatters multiply on its microsurface (Heitz et al. 2016); "
                        "the file's recorded stack shows it")
    add_spectral(p)
    add_polarized(p)
    p.add_argument("--restart", action="store_true",
                   help="discard the checkpoints an interrupted run left (.FILE.h5.partial) and trace from the "
                        "start (default: resume them; checkpoints of other settings or another code version are "
                        "refused, naming what differs)")
    add_overwrite(p)
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("info", help="describe a simulated file (slices or tabulated) or an RGL tensor file (.bsdf)")
    p.add_argument("file", metavar="FILE")
    p.add_argument("--json", action="store_true", help="print one JSON object (default: a table)")
    p.set_defaults(func=cmd_info)



def _paths_per_incident(stack, settings) -> int:
    """Paths per incident direction: ``rays``, times a spectral run's launches (StackError for a
    spectral table that does not cover the run's bins)."""
    if not settings.spectral:
        return settings.rays
    from goniometer.run.launches import launch_stacks
    return settings.rays * len(launch_stacks(stack, settings))


def cmd_simulate(args: argparse.Namespace) -> int:
    from goniometer.files import slices as store
    from goniometer.atomic import is_environment_error
    from goniometer.run.checkpoints import Checkpoints, checkpoint_dir
    from goniometer.run.first_order import check_supported
    from goniometer.run.results import cell_geometries, run_description
    from goniometer.run.settings import SettingsError, SimulationSettings
    from goniometer.run.loop import run_incidents
    from goniometer.stack import StackError, load_toml
    from goniometer.run.tasks import warm_up
    from goniometer.grids.rgl import RGLGridError

    with usage_errors(StackError, SettingsError):
        stack, table = load_toml(args.config)
        if args.multiple_scattering:
            stack = stack.with_multiple_scattering()
        base = SimulationSettings.from_mapping(_without_rgl(table) if args.parametrization in ("classic", "half")
                                               else table, source=f"{args.config}: simulation", stack=stack)
    over: dict[str, Any] = {}
    if args.incident is not None:
        thetas, phis = incident_list(args.incident)
        over["incident_deg"] = tuple(thetas)
        over["incident_phi_deg"] = tuple(phis) if phis is not None else tuple(0.0 for _ in thetas)
    if args.resolution is not None:
        over["resolution"] = resolution(args.resolution)
    for key in ("rays", "parametrization", "seed", "threads", "masking", "max_order", "first_order", "spectral",
                "wavelength_bins", "device", "polarized"):
        value = getattr(args, key)
        if value is not None:
            over[key] = value
    with usage_errors(SettingsError, RGLGridError):
        if over.get("parametrization", base.parametrization) == "rgl":
            settings = _on_rgl_grid(args, stack, base, over)
        else:
            if args.rgl_grid is not None:
                raise UsageError("--rgl-grid: goes with --parametrization rgl")
            settings = base.with_overrides(**over)
        if settings.first_order == "integrated":
            check_supported(stack)
    from goniometer.kernel.tracer import DeviceError, check_device, thread_count
    with usage_errors(DeviceError):
        check_device(settings.device, settings.threads)
    with usage_errors(StackError):
        per = _paths_per_incident(stack, settings)
        if not settings.spectral:
            from goniometer.kernel.packing import check_films
            check_films(stack)
            if stack.is_spectral:
                print(f"note: {stack.name} has spectral data; an RGB run traces their RGB equivalents "
                      f"(docs/spectral.md section 3); --spectral traces the spectra", file=sys.stderr)
    out = output_path(args.out, inputs=[args.config], overwrite=args.overwrite)
    checkpoints = Checkpoints(checkpoint_dir(out), run_description(stack, settings))
    if args.restart:
        checkpoints.clear()
    with checkpoint_refusals():   # before anything is printed or compiled: a changed setting is refused at once
        checkpoints.check()

    total = per * len(settings.incident_deg)
    spectral = (f", spectral: {settings.wavelength_bins} bins over 360-830 nm in {per // settings.rays} launch(es) "
                f"of {settings.rays:,} paths" if settings.spectral else "")
    spectral += ", polarized (Mueller matrices, docs/polarization.md)" if settings.polarized else ""
    print(f"simulating {stack.name} ({stack.category}): {len(settings.incident_deg)} incident direction(s) x "
          f"{settings.rays:,} rays{spectral}, {settings.parametrization} {settings.resolution[0]}x"
          f"{settings.resolution[1]}, {thread_count(settings.threads)} thread(s)", file=sys.stderr)
    with sigint_latch() as interrupts:
        with interrupts.deferred():
            compile_s = compile_kernels(lambda: warm_up(stack, settings))
            cell_geometries(settings)  # the final assembly's numba kernels: compiled and run here
        bar = progress_bar(total, stack.name)
        progress = ResumeAware(bar, interrupts.check)
        checkpoints.on_discard = lambda path, reason: bar.write(
            f"warning: {path}: unreadable checkpoint ({reason}); its incident direction is traced again",
            file=sys.stderr)

        def on_resume(n: int) -> None:
            progress.resumed(n * per)
            bar.write(f"resuming: {n} of {len(settings.incident_deg)} incident direction(s) already traced "
                      f"(checkpoints in {checkpoints.directory}; --restart to discard them)", file=sys.stderr)

        try:
            with bar, checkpoint_refusals():
                result = run_incidents(stack, settings, checkpoints=checkpoints, progress=progress,
                                       on_resume=on_resume)
            result.compile_s = compile_s
            interrupts.check()
            with interrupts.writing() as commit:
                store.write(out, result, commit)  # atomic: interrupted, it leaves nothing under the name
        except KeyboardInterrupt:
            kept = _kept(checkpoints)
            if kept:
                print(f"gonio: {kept}", file=sys.stderr)
            raise
        except OSError as e:   # a full disk, say: one line (goniometer.cli.main) saying what is kept
            kept = _kept(checkpoints)
            if kept and is_environment_error(e):
                e.add_note(kept)
            raise
        checkpoints.clear()
    print(f"wrote {out}")
    _print_summary(result)
    return 0


def _kept(checkpoints) -> str | None:
    """What an interrupted or failed run keeps, and how to go on; None if it keeps nothing."""
    n = len(checkpoints.kept())
    if not n:
        return None
    return f"{n} finished incident direction(s) kept in {checkpoints.directory}; rerun the same command to resume"


@contextlib.contextmanager
def checkpoint_refusals():
    """Kept checkpoints the run cannot use (:class:`goniometer.run.checkpoints.CheckpointMismatch`):
    one line naming every differing key with both values and the way on, exit status 2. Shared by
    ``simulate``, ``tabulate`` and ``database simulate`` (each has ``--restart``)."""
    from goniometer.run.checkpoints import CheckpointMismatch
    try:
        yield
    except CheckpointMismatch as e:
        raise UsageError(checkpoint_refusal(e)) from None


def checkpoint_refusal(e) -> str:
    """The line of a :class:`goniometer.run.checkpoints.CheckpointMismatch`: what they are, and how to
    go on (``docs/outputs.md`` rule 3)."""
    if e.reason is None and e.other_code:
        way = ("this version of the simulator cannot resume them (the version that wrote them can); "
               "add --restart to discard them")
    elif e.reason is None:
        way = "rerun the command that wrote them to resume, or add --restart to discard them"
    else:
        way = "add --restart to discard them and trace from the start"
    return f"{e}; {way} (nothing was changed)"


def _without_rgl(table: dict) -> dict:
    """A ``[simulation]`` table without its RGL keys (a classic or half run asked on the command line)."""
    return {k: v for k, v in table.items() if k not in ("parametrization", "rgl_grid")
            and not (k in ("incident_deg", "resolution") and table.get("parametrization") == "rgl")}


def _on_rgl_grid(args: argparse.Namespace, stack, base, over: dict):
    """The settings of a run on the RGL grid: the grid from --rgl-grid, else the file's, else the
    default for the stack; the other settings from the file and the command line."""
    from goniometer.grids.rgl import grid_for, parse_grid
    from goniometer.run.settings import SimulationSettings
    for option, key in (("--incident", "incident_deg"), ("--resolution", "resolution")):
        if key in over:
            raise UsageError(f"{option}: the RGL grid sets it (its theta_i, phi_i nodes and n x n); "
                             f"use --rgl-grid N_THETA_IxN_PHI_IxN")
    grid = base.rgl
    if args.rgl_grid is not None or grid is None:
        grid = grid_for(stack, *(parse_grid(args.rgl_grid) if args.rgl_grid is not None else (None, None, None)))
    fields = {k: getattr(base, k) for k in ("rays", "seed", "masking", "max_order", "threads", "first_order",
                                            "spectral", "wavelength_bins", "device", "polarized")}
    fields.update({k: v for k, v in over.items() if k != "parametrization"})
    if grid.isotropic and stack.is_anisotropic:   # refused before tracing
        source = "--rgl-grid" if args.rgl_grid is not None else f"{args.config}: simulation.rgl_grid"
        raise UsageError(f"{source}: {stack.name} is anisotropic but the RGL grid has one incident azimuth "
                         f"(N_PHI_I = 1): the readers would take the file as isotropic and gonio export refuses it; "
                         f"give N_PHI_I >= 3, e.g. --rgl-grid {len(grid.theta_i_deg)}x9x{grid.n}")
    return SimulationSettings.on_rgl_grid(grid, **fields)


def _print_summary(r) -> None:
    from goniometer.run.results import ENERGY_TERMS
    print(f"{r.rays_per_s:,.0f} rays/s with {r.threads} thread(s) ({r.rays_per_s / r.threads:,.0f} per thread); "
          f"compile/load {r.compile_s:.1f} s")
    if r.settings.spectral:
        print(f"spectral: {r.settings.wavelength_bins} wavelength bins ({r.paths_per_incident:,} paths per incident "
              f"direction); energies as the CIE Y (D65) of the bins and their range over the bins (per bin: "
              f"gonio info --json)")
        _print_spectral_energies(r)
        return
    print(f"{'theta_l':>8} {'phi_l':>6}  {'reflected (R G B)':>26}  {'transmitted':>26}  {'absorbed':>26}  {'masking_loss':>26}")
    for m in range(len(r.theta_deg)):
        row = [f"{r.theta_deg[m]:8.2f}", f"{r.phi_deg[m]:6.1f}"]
        for k in ENERGY_TERMS:
            row.append(" ".join(f"{x:8.5f}" for x in r.energy[k][m]))
        print("  ".join(row))
    if np.any(r.capped_paths):
        print(f"warning: {int(np.sum(r.capped_paths))} path(s) reached the event cap of {r.settings.event_cap}; "
              f"their weight is in /energy/capped")


def _print_spectral_energies(r) -> None:
    """Per incident direction and energy term: the fraction's CIE Y (D65 weights of the bins, a
    luminance: within [0, 1] as every bin is) and its smallest and largest bin."""
    from goniometer.run.results import ENERGY_TERMS
    from goniometer.spectral import wavelength_bins, xyz_weights
    y = xyz_weights(wavelength_bins(r.settings.wavelength_bins)[1])[:, 1]
    y = y / y.sum()
    print(f"{'theta_l':>8} {'phi_l':>6}  " + "  ".join(f"{k + ' Y [min, max]':>26}" for k in ENERGY_TERMS))
    for m in range(len(r.theta_deg)):
        row = [f"{r.theta_deg[m]:8.2f}", f"{r.phi_deg[m]:6.1f}"]
        for k in ENERGY_TERMS:
            e = r.energy[k][m]
            row.append(f"{float(e @ y):8.5f} [{e.min():7.5f}, {e.max():7.5f}]")
        print("  ".join(row))
    if np.any(r.capped_paths):
        print(f"warning: {int(np.sum(r.capped_paths))} path(s) reached the event cap of {r.settings.event_cap}; "
              f"their weight is in /energy/capped")


# ---------------------------------------------------------------------- info

def info_dict(path: Path) -> dict[str, Any]:
    """The JSON summary printed by ``gonio info --json``."""
    from goniometer.run.results import ENERGY_TERMS
    from goniometer.files import slices as store
    spectral = store.read(path)
    r = spectral.rgb()   # a spectral file's energies are shown in linear sRGB; "spectral" lists the bins
    s = spectral.settings
    d: dict[str, Any] = {
        "file": str(path),
        "material": {"name": r.stack.name, "category": r.stack.category, "base": r.stack.base,
                     "config": json.loads(r.stack.to_json())},
        "settings": {
            "incident_deg": list(s.incident_deg), "incident_phi_deg": list(s.incident_phi_deg),
            "rays": s.rays, "parametrization": s.parametrization, "resolution": list(s.resolution),
            "seed": s.seed, "masking": s.masking, "max_order": s.max_order, "chunk_rays": s.chunk_rays,
            "first_order": s.first_order, "spectral": s.spectral, "polarized": s.polarized,
        },
        "sides": ["brdf"] + (["btdf"] if r.btdf is not None else []),
        "energy": [],
        "performance": {"threads": r.threads, "elapsed_s": float(np.sum(r.elapsed_s)),
                        "rays_per_s": spectral.rays_per_s, "rays_per_s_per_thread": spectral.rays_per_s / r.threads,
                        "compile_s": r.compile_s},
        "capped_paths": int(np.sum(r.capped_paths)),
    }
    if s.spectral:
        wl = spectral.wavelengths_nm
        d["spectral"] = {"wavelength_bins": s.wavelength_bins, "wavelength_nm": [float(x) for x in wl],
                         "paths_per_incident": spectral.paths_per_incident,
                         "energy_per_bin": [{k: [float(x) for x in spectral.energy[k][m]] for k in ENERGY_TERMS}
                                            for m in range(len(spectral.theta_deg))],
                         "energy_channels": "linear sRGB (D65) of the bins, docs/spectral.md section 4"}
    for m in range(len(r.theta_deg)):
        e = {"theta_deg": float(r.theta_deg[m]), "phi_deg": float(r.phi_deg[m])}
        for k in ENERGY_TERMS:
            e[k] = [float(x) for x in r.energy[k][m]]
        if r.reflected_without_base is not None:
            e["reflected_without_base"] = [float(x) for x in r.reflected_without_base[m]]
        e["mean_events"] = float(r.mean_events[m])
        d["energy"].append(e)
    return d


#: what ``gonio info`` reads, as its refusals say
INFO_READS = ("gonio info reads a goniometer.slices file (gonio simulate), a goniometer.tabulated file (gonio "
              "tabulate) or an RGL tensor file (.bsdf, gonio export --format rgl)")


def cmd_info(args: argparse.Namespace) -> int:
    from goniometer.run.results import ENERGY_TERMS
    from goniometer.files import slices as store
    from goniometer.files.outputs import describe_existing
    path = Path(args.file)
    if path.is_dir():
        raise UsageError(f"{path}: a directory, not a file; {INFO_READS}")
    if _is_tensor(path):
        return _info_tensor(args)
    if _is_tabulated(path):
        return _info_tabulated(args)
    try:
        d = info_dict(path)
    except store.StoreError as e:
        if path.is_file() and _hdf5_format(path) != store.FORMAT:   # another kind of file: say what it is
            raise UsageError(f"{path}: {describe_existing(path)}; {INFO_READS}") from None
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
    if s["first_order"] == "integrated":
        print("  bounce order 1 integrated over the cells, not traced (its standard error is 0)")
    if s["polarized"]:
        print("  polarized: each cell holds its Mueller matrix (mueller, mueller_stderr; s/p frames of each beam's "
              "plane of incidence, docs/polarization.md); value is its [0, 0]")
    if "spectral" in d:
        sp = d["spectral"]
        print(f"  spectral: {sp['wavelength_bins']} wavelength bins, {sp['wavelength_nm'][0]:.1f}-"
              f"{sp['wavelength_nm'][-1]:.1f} nm (centres), {sp['paths_per_incident']:,} paths per incident "
              f"direction; energies below in linear sRGB (D65), whose components fall below 0 or above 1 for "
              f"colours outside the sRGB gamut (per bin: --json, spectral.energy_per_bin)")
    print(f"  {p['rays_per_s']:,.0f} rays/s on {p['threads']} thread(s) ({p['elapsed_s']:.1f} s)")
    print(f"  {'theta_l':>7} {'phi_l':>6}  {'reflected (R G B)':>24}  {'transmitted':>24}  {'absorbed':>24}  {'masking_loss':>24}")
    for e in d["energy"]:
        cols = [" ".join(f"{x:7.4f}" for x in e[k]) for k in ENERGY_TERMS]
        print(f"  {e['theta_deg']:7.2f} {e['phi_deg']:6.1f}  " + "  ".join(cols))
    if d["capped_paths"]:
        print(f"  warning: {d['capped_paths']} path(s) reached the event cap")
    return 0




def _is_tensor(path: Path) -> bool:
    from goniometer.files.outputs import TENSOR_MAGIC
    try:
        with open(path, "rb") as fh:
            return fh.read(len(TENSOR_MAGIC)) == TENSOR_MAGIC
    except OSError:
        return False


def tensor_info(path: Path) -> dict[str, Any]:
    """The JSON summary ``gonio info FILE.bsdf --json`` prints: fields, grids, which readers take it."""
    from goniometer.files.rgl_export import check_readers
    from goniometer.files.rgl_tensor import read_tensor
    t = read_tensor(path)
    f = t.fields
    d: dict[str, Any] = {"file": str(path), "format": "rgl-tensor", "version": list(t.version),
                         "fields": {k: {"dtype": v.dtype.name, "shape": list(v.shape)} for k, v in f.items()}}
    if "description" in f:
        d["description"] = t.text("description")
    if "theta_i" in f:
        d["theta_i_deg"] = [round(float(x), 4) for x in np.degrees(f["theta_i"])]
    if "phi_i" in f:
        d["phi_i_deg"] = [round(float(x), 4) for x in np.degrees(f["phi_i"])]
        d["isotropic"] = int(f["phi_i"].shape[0]) <= 2
    if "wavelengths" in f:
        d["wavelengths_nm"] = [float(f["wavelengths"][0]), float(f["wavelengths"][-1]), int(f["wavelengths"].size)]
    if "jacobian" in f:
        d["jacobian"] = bool(f["jacobian"].reshape(-1)[0])
    d["readers"] = {k: {"takes_it": not v, "why_not": v} for k, v in check_readers(t).items()}
    from goniometer.files.measured import MeasuredError, read_measured
    try:   # as a reference of gonio evaluate/fit (docs/measured.md): its values checked
        read_measured(path)
        d["as_measurement"] = {"reads": True, "why_not": None}
    except MeasuredError as e:
        d["as_measurement"] = {"reads": False, "why_not": str(e)}
    return d


def _info_tensor(args: argparse.Namespace) -> int:
    """``gonio info`` of an RGL tensor file (``docs/rgl-format.md``)."""
    from goniometer.files.rgl_tensor import TensorError
    with usage_errors(TensorError):
        d = tensor_info(Path(args.file))
    if args.json:
        print(json.dumps(d, indent=2))
        return 0
    print(f"{d['file']}: RGL tensor file, version {d['version'][0]}.{d['version'][1]}")
    if "description" in d:
        print(f"  description: {d['description'][:300]}")
    for name, fd in d["fields"].items():
        print(f"  {name:12s} {fd['dtype']:8s} {'x'.join(str(n) for n in fd['shape']) or 'scalar'}")
    if "theta_i_deg" in d:
        print(f"  theta_i (deg): {', '.join(f'{x:g}' for x in d['theta_i_deg'])}")
    if "phi_i_deg" in d:
        print(f"  phi_i (deg): {', '.join(f'{x:g}' for x in d['phi_i_deg'])} "
              f"({'isotropic' if d['isotropic'] else 'anisotropic'})")
    if "wavelengths_nm" in d:
        lo, hi, n = d["wavelengths_nm"]
        print(f"  wavelengths: {n} from {lo:g} to {hi:g} nm")
    for reader, r in d["readers"].items():
        print(f"  {reader:17s} " + ("takes it" if r["takes_it"] else "refuses it: " + "; ".join(r["why_not"])))
    m = d["as_measurement"]
    print(f"  {'as a measurement':17s} " + ("reads it" if m["reads"] else f"refuses it: {m['why_not']}"))
    return 0


def _hdf5_format(path: Path) -> str | None:
    """The ``format`` attribute of an HDF5 file (None: no such attribute, or not an HDF5 file)."""
    import h5py
    try:
        with h5py.File(path, "r") as f:
            fmt = f.attrs.get("format")
    except OSError:
        return None
    return fmt.decode() if isinstance(fmt, bytes) else fmt


def _is_tabulated(path: Path) -> bool:
    from goniometer.files.tabulated import FORMAT
    return _hdf5_format(path) == FORMAT


def _info_tabulated(args: argparse.Namespace) -> int:
    """``gonio info`` of a tabulated file (``docs/tabulated-format.md``)."""
    from goniometer.run.results import ENERGY_TERMS
    from goniometer.files.tabulated import TabulatedError, read_tabulated
    with usage_errors(TabulatedError):
        spectral = read_tabulated(args.file, mueller=False)   # (what info says needs no Mueller matrices)
    t = spectral.rgb()   # a spectral file's energies are shown in linear sRGB; "spectral" lists the bins
    s = spectral.settings
    n_data = int(np.count_nonzero(t.hits))
    d: dict[str, Any] = {
        "file": str(args.file), "format": "goniometer.tabulated",
        "material": {"name": t.stack.name, "category": t.stack.category, "base": t.stack.base,
                     "config": json.loads(t.stack.to_json())},
        "settings": {"rays": s.rays, "seed": s.seed, "masking": s.masking, "chunk_rays": s.chunk_rays,
                     "spectral": s.spectral, "device": s.device, "polarized": s.polarized},
        "grid": {"name": "merl", "shape": list(t.hits.shape), "cells_with_data": n_data},
        "energy": {k: [float(x) for x in v] for k, v in t.energy.items()},
        "performance": {"threads": t.threads, "elapsed_s": t.elapsed_s, "rays_per_s": t.rays_per_s,
                        "compile_s": t.compile_s},
        "capped_paths": t.capped_paths, "mean_events": t.mean_events,
    }
    if s.spectral:
        d["spectral"] = {"wavelength_bins": s.wavelength_bins,
                         "wavelength_nm": [float(x) for x in spectral.wavelengths_nm],
                         "paths": spectral.paths, "launches": spectral.launches,
                         "energy_per_bin": {k: [float(x) for x in v] for k, v in spectral.energy.items()},
                         "energy_channels": "linear sRGB (D65) of the bins, docs/spectral.md section 4"}
    if args.json:
        print(json.dumps(d, indent=2))
        return 0
    m = d["material"]
    print(f"{d['file']}: {m['name']} ({m['category']}, {m['base']} base), tabulated BRDF on the MERL grid")
    print(f"  stack: {json.dumps(m['config']['layers'])}")
    print(f"  {s.rays:,} rays (cosine-weighted incident directions), seed {s.seed}, {s.masking} masking; "
          f"cells with data: {n_data:,} of {t.hits.size:,}")
    print(f"  {t.rays_per_s:,.0f} rays/s on {t.threads} thread(s) ({t.elapsed_s:.1f} s)")
    if s.spectral:
        wl = spectral.wavelengths_nm
        print(f"  spectral: {s.wavelength_bins} wavelength bins, {wl[0]:.1f}-{wl[-1]:.1f} nm (centres), "
              f"{spectral.paths:,} paths in {spectral.launches} launch(es)")
    if s.polarized:
        print("  polarized: each cell holds its Mueller matrix (mueller, mueller_stderr; plane frames x = "
              "normalize(l x v) of the cell's pair, docs/polarization.md section 5)")
    print(f"  energy under uniform diffuse light ({'linear sRGB of the bins' if s.spectral else 'R G B'}):")
    for k in ENERGY_TERMS:
        print(f"    {k:13s} " + " ".join(f"{x:7.4f}" for x in t.energy[k]))
    if t.capped_paths:
        print(f"  warning: {t.capped_paths} path(s) reached the event cap")
    return 0
