"""``gonio tabulate`` (the whole isotropic BRDF of a material file on the MERL grid) and ``gonio
export`` (a tabulated file to another tool's format): ``docs/tabulated-format.md``."""

from __future__ import annotations

import argparse
import sys

import numpy as np

from goniometer.cli.common import (ResumeAware, UsageError, add_device, add_overwrite, add_polarized, add_spectral,
                                   compile_kernels, output_path, progress_bar, sigint_latch, thread_number,
                                   usage_errors, whole_number)


def register(sub) -> None:
    """Add ``tabulate`` and ``export`` to the ``gonio`` sub-command parser."""
    from goniometer.run.settings import TABULATE_RAYS
    p = sub.add_parser("tabulate", help="tabulate a material's whole isotropic BRDF on the MERL grid (HDF5)")
    p.add_argument("config", metavar="CONFIG.toml")
    p.add_argument("--out", required=True, metavar="FILE.h5",
                   help="the tabulated file to write (required; docs/tabulated-format.md)")
    p.add_argument("--rays", type=whole_number, help=f"paths in all, each with its own incident direction; a spectral "
                                                     f"tabulation: per wavelength bin (default {TABULATE_RAYS:,})")
    p.add_argument("--seed", type=whole_number, help="random seed (default: the material file's, else 1)")
    p.add_argument("--threads", type=thread_number,
                   help="numba threads (default: all cores); the file does not depend on it")
    add_device(p)
    add_spectral(p)
    add_polarized(p)
    p.add_argument("--restart", action="store_true",
                   help="discard the checkpoint an interrupted run left (.FILE.h5.partial) and trace from the start "
                        "(default: resume it; a checkpoint of other settings or another code version is refused, "
                        "naming what differs)")
    add_overwrite(p)
    p.set_defaults(func=cmd_tabulate)

    p = sub.add_parser("export", help="export a simulated file to another tool's format: MERL .binary (from a "
                                      "tabulated file), the RGL tensor file of Mitsuba 3's and pbrt-v4's measured "
                                      "material (from a file simulated with --parametrization rgl) or the .pbsdf of "
                                      "Mitsuba 3's measured_polarized (from a polarized tabulated file)")
    p.add_argument("file", metavar="FILE.h5", help="a file written by gonio tabulate (merl), gonio tabulate "
                                                   "--polarized (mitsuba-polarized) or by gonio simulate "
                                                   "--parametrization rgl (rgl)")
    p.add_argument("--format", required=True, choices=("merl", "rgl", "mitsuba-polarized"),
                   help="output format: merl (MERL .binary), rgl (RGL tensor file, docs/rgl-format.md) or "
                        "mitsuba-polarized (Mitsuba 3's measured_polarized tensor file, docs/polarization.md "
                        "section 4)")
    p.add_argument("--out", required=True, metavar="FILE", help="the file to write (required)")
    p.add_argument("--spectral", action="store_true",
                   help="rgl: write the spectral file (spectra + wavelengths: pbrt-v4, Mitsuba's spectral variants) "
                        "instead of the RGB file (Mitsuba's RGB variants) (default: RGB)")
    add_overwrite(p)
    p.set_defaults(func=cmd_export)


def tabulation_settings(table: dict, args: argparse.Namespace):
    """The :class:`~goniometer.run.settings.TabulationSettings` of ``gonio tabulate``: the material
    file's ``[simulation]`` table (``seed``, ``masking``, ``spectral``, ``wavelength_bins``,
    ``device``, ``polarized``; ``table`` as :func:`goniometer.stack.load_toml` returns it), then the
    options given. Raises :class:`~goniometer.run.settings.SettingsError`."""
    from goniometer.run.settings import SimulationSettings, TabulationSettings
    base = SimulationSettings.from_mapping(table, source=f"{args.config}: simulation")
    return TabulationSettings(seed=base.seed, masking=base.masking, spectral=base.spectral,
                              wavelength_bins=base.wavelength_bins, device=base.device,
                              polarized=base.polarized).with_overrides(
        rays=args.rays, seed=args.seed, threads=args.threads, spectral=args.spectral,
        wavelength_bins=args.wavelength_bins, device=args.device, polarized=args.polarized)


def cmd_tabulate(args: argparse.Namespace) -> int:
    from goniometer.files import slices as store
    from goniometer.atomic import is_environment_error
    from goniometer.run.checkpoints import checkpoint_dir
    from goniometer.cli.simulate import checkpoint_refusals
    from goniometer.run.settings import SettingsError
    from goniometer.stack import StackError, load_toml
    from goniometer.files.tabulated import write_tabulated
    from goniometer.run.tabulation import (TabulationCheckpoint, TabulationError, check_tabulable,
                                           launches as _launches, tabulate, tabulation_description, warm_up)

    from goniometer.kernel.tracer import DeviceError, check_device, thread_count
    with usage_errors(StackError, SettingsError, TabulationError, store.StoreError):
        stack, table = load_toml(args.config)
        settings = tabulation_settings(table, args)
        check_tabulable(stack, settings)
        paths = settings.rays * len(_launches(stack, settings))
    with usage_errors(DeviceError):
        check_device(settings.device, settings.threads)
    out = output_path(args.out, inputs=[args.config], overwrite=args.overwrite)
    checkpoint = TabulationCheckpoint(checkpoint_dir(out), tabulation_description(stack, settings))
    if args.restart:
        checkpoint.clear()
    with checkpoint_refusals():   # before anything is printed or compiled: a changed setting is refused at once
        checkpoint.check()
    if stack.is_spectral and not settings.spectral:
        print(f"note: {stack.name} has spectral data; an RGB tabulation traces their RGB equivalents "
              f"(docs/spectral.md section 3); --spectral traces the spectra", file=sys.stderr)

    spectral = (f", spectral: {settings.wavelength_bins} bins over 360-830 nm in {paths // settings.rays} launch(es) "
                f"of {settings.rays:,} paths" if settings.spectral else "")
    if settings.polarized:
        spectral += ", polarized (Mueller matrices in the plane frames, docs/polarization.md section 5)"
    print(f"tabulating {stack.name} ({stack.category}): {settings.rays:,} rays over the hemisphere "
          f"(cos-weighted){spectral}, MERL grid 90x90x180, "
          f"{'CUDA' if settings.device == 'cuda' else f'{thread_count(settings.threads)} thread(s)'}",
          file=sys.stderr)
    with sigint_latch() as interrupts:
        with interrupts.deferred():
            compile_s = compile_kernels(lambda: warm_up(stack, settings))
        bar = progress_bar(paths, stack.name)
        progress = ResumeAware(bar, interrupts.check)

        def on_resume(rays: int) -> None:
            progress.resumed(rays)
            bar.write(f"resuming: {rays:,} of {paths:,} rays already traced (checkpoint in "
                      f"{checkpoint.directory}; --restart to discard it)", file=sys.stderr)

        try:
            with bar, checkpoint_refusals():
                tab = tabulate(stack, settings, checkpoint=checkpoint, progress=progress, on_resume=on_resume,
                               compile_s=compile_s)
            interrupts.check()
            with interrupts.writing() as commit:
                write_tabulated(out, tab, commit)  # atomic: interrupted, it leaves nothing under the name
        except KeyboardInterrupt:
            if checkpoint.kept():
                print(f"gonio: {_kept(checkpoint)}", file=sys.stderr)
            raise
        except OSError as e:   # a full disk, say: one line (goniometer.cli.main) saying what is kept
            if checkpoint.kept() and is_environment_error(e):
                e.add_note(_kept(checkpoint))
            raise
        checkpoint.clear()
    print(f"wrote {out}")
    _print_summary(tab)
    return 0


def _kept(checkpoint) -> str:
    return f"progress kept in {checkpoint.directory}; rerun the same command to resume"


def _print_summary(t) -> None:
    from goniometer.run.results import ENERGY_TERMS
    n_data = int(np.count_nonzero(t.hits))
    print(f"{t.rays_per_s:,.0f} rays/s with {t.threads} thread(s); compile/load {t.compile_s:.1f} s")
    print(f"cells with data: {n_data:,} of {t.hits.size:,}")
    if t.settings.spectral:
        print(f"spectral: {t.settings.wavelength_bins} wavelength bins ({t.paths:,} paths in {t.launches} launch(es)); "
              f"energy in linear sRGB (D65) of the bins:")
    else:
        print("energy under uniform diffuse light (R G B):")
    rgb = t.rgb()
    for k in ENERGY_TERMS:
        print(f"  {k:13s} " + " ".join(f"{x:8.5f}" for x in rgb.energy[k]))
    if t.capped_paths:
        print(f"warning: {t.capped_paths} path(s) reached the event cap of {t.settings.event_cap}; "
              f"their weight is in /energy/capped")


def cmd_export(args: argparse.Namespace) -> int:
    if args.format == "rgl":
        return _export_rgl(args)
    if args.spectral and args.format == "mitsuba-polarized":
        raise UsageError("--spectral: goes with --format rgl (a mitsuba-polarized file holds the tabulated file's "
                         "channels or bins)")
    if args.format == "mitsuba-polarized":
        return _export_polarized(args)
    if args.spectral:
        raise UsageError("--spectral: goes with --format rgl (a MERL file is RGB)")
    from goniometer.files.merl import write_merl
    from goniometer.files.tabulated import TabulatedError, read_tabulated
    with usage_errors(TabulatedError):
        tab = read_tabulated(args.file)
    out = output_path(args.out, inputs=[args.file], overwrite=args.overwrite)
    if tab.settings.spectral:
        print(f"note: {args.file} is spectral; a MERL file is RGB: writing its linear sRGB (D65, docs/spectral.md "
              f"section 4)", file=sys.stderr)
    write_merl(out, tab.rgb())
    n = int(np.count_nonzero(tab.hits))
    print(f"wrote {out} (MERL .binary, 90x90x180; {n:,} cells with data, {tab.hits.size - n:,} marked negative)")
    return 0


def _export_polarized(args: argparse.Namespace) -> int:
    """``gonio export T.h5 --format mitsuba-polarized --out X.pbsdf`` (``docs/polarization.md`` section 5)."""
    from goniometer.files.mitsuba_polarized import PolarizedExportError, export_pbsdf, wavelengths
    from goniometer.files.tabulated import FORMAT as TAB_FORMAT
    from goniometer.files.tabulated import TabulatedError, read_tabulated
    if _format_of(args.file) == "goniometer.slices":
        raise UsageError(f"{args.file}: a slices file; mitsuba-polarized exports a polarized tabulated file "
                         f"(gonio tabulate CONFIG --polarized --out T.h5)")
    with usage_errors(TabulatedError):
        if _format_of(args.file) == TAB_FORMAT and not _polarized(args.file):
            raise UsageError(f"{args.file}: a scalar tabulation: measured_polarized holds Mueller matrices; tabulate "
                             f"with --polarized (gonio tabulate CONFIG --polarized --out T.h5)")
        tab = read_tabulated(args.file)
    out = output_path(args.out, inputs=[args.file], overwrite=args.overwrite)
    with usage_errors(PolarizedExportError, prefix=str(args.file)):
        wvls, ch = wavelengths(tab)
        export_pbsdf(tab, out)
    s = tab.settings
    if s.spectral and s.wavelength_bins > 3:
        print(f"note: {args.file} has {s.wavelength_bins} wavelength bins; the file holds 5 (Mitsuba's plugin reads "
              f"5): bins {', '.join(str(int(c) + 1) for c in ch)} at {', '.join(str(int(w)) for w in wvls)} nm",
              file=sys.stderr)
    print(f"wrote {out} (Mitsuba 3 measured_polarized tensor file: M [phi_d 360, theta_d 90, theta_h 90, 5 wavelengths "
          f"{'/'.join(str(int(w)) for w in wvls)} nm, 4, 4], plane frames; {int(np.count_nonzero(tab.hits)):,} cells "
          f"with data)")
    print(f"  Mitsuba 3 (*_spectral_polarized variants): {{'type': 'measured_polarized', 'filename': '{out}'}}")
    return 0


def _polarized(path: str) -> bool:
    import h5py
    with h5py.File(path, "r") as f:
        return bool(f["simulation"].attrs.get("polarized", False)) if "simulation" in f else False


def _export_rgl(args: argparse.Namespace) -> int:
    """``gonio export F.h5 --format rgl --out NAME.bsdf [--spectral]`` (``docs/rgl-format.md``)."""
    import time

    from goniometer.files import slices as store
    from goniometer.files.rgl_export import ExportError, bsdf_fields, check_readers
    from goniometer.files.rgl_tensor import write_tensor
    from goniometer.files.tabulated import FORMAT as TAB_FORMAT
    if _format_of(args.file) == TAB_FORMAT:
        raise UsageError(f"{args.file}: a tabulated file (MERL grid) exports as --format merl; for rgl simulate the "
                         f"material with --parametrization rgl")
    with usage_errors(store.StoreError):
        result = store.read(args.file)
    out = output_path(args.out, inputs=[args.file], overwrite=args.overwrite)
    t0 = time.perf_counter()
    with usage_errors(ExportError, prefix=str(args.file)):
        fields = bsdf_fields(result, spectral=args.spectral)
    if args.spectral and not result.settings.spectral:
        print(f"note: {args.file} is an RGB run: the file's spectra are its RGB upsampled (B 465, G 550, R 610 nm; "
              f"docs/rgl-format.md section 5); a spectral run (gonio simulate --spectral) exports traced spectra",
              file=sys.stderr)
    readers = check_readers(fields)
    wanted = ("mitsuba-spectral", "pbrt-v4") if args.spectral else ("mitsuba-rgb",)
    problems = [f"{r}: {'; '.join(readers[r])}" for r in wanted if readers[r]]
    if problems:
        raise UsageError(f"{args.file}: the exported file would be refused ({' | '.join(problems)}); nothing written")
    write_tensor(out, fields)
    g = result.settings.rgl
    kind = "spectral (spectra + wavelengths: pbrt-v4, Mitsuba's spectral variants)" if args.spectral \
        else "RGB (Mitsuba's RGB variants)"
    print(f"wrote {out} (RGL tensor file, {kind}; {len(g.theta_i_deg)} theta_i x {len(g.phi_i_deg)} phi_i, "
          f"{g.n}x{g.n} nodes; {time.perf_counter() - t0:.1f} s)")
    for line in _reader_lines(str(out), readers):
        print(f"  {line}")
    return 0


def _reader_lines(out: str, readers: dict[str, list[str]]) -> list[str]:
    """How each reader loads the written file, for the readers that take it (``check_readers``:
    pbrt-v4 never takes an RGB file), and what to export for the ones that do not."""
    lines = []
    if not readers["mitsuba-rgb"]:
        lines.append(f"Mitsuba 3 (RGB variants): {{'type': 'measured', 'filename': '{out}'}}")
    if not readers["mitsuba-spectral"]:
        lines.append(f"Mitsuba 3 (spectral variants): {{'type': 'measured', 'filename': '{out}'}}")
    if not readers["pbrt-v4"]:
        lines.append(f'pbrt-v4: Material "measured" "string filename" "{out}"')
    else:   # an RGB file (a spectral file pbrt-v4 refuses is not written): the spectral export is pbrt-v4's
        lines.append(f"pbrt-v4 does not read this file ({'; '.join(readers['pbrt-v4'])}): export again with "
                     f"--spectral for pbrt-v4")
    return lines


def _format_of(path: str) -> str | None:
    import h5py
    try:
        with h5py.File(path, "r") as f:
            fmt = f.attrs.get("format")
            return fmt.decode() if isinstance(fmt, bytes) else fmt
    except OSError:
        return None
