"""The reference a model command judges against: a simulated slices file, or a measured file (a
MERL ``.binary`` or an RGL ``.bsdf``) resampled onto slices with the material it measures
(``--stack CONFIG.toml``; ``docs/measured.md``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from goniometer.cli.common import UsageError, incident_list, resolution, usage_errors



def add_reference_options(p: argparse.ArgumentParser) -> None:
    """``--stack``, ``--incident``, ``--parametrization``, ``--resolution`` for a measured FILE."""
    p.add_argument("--stack", metavar="CONFIG.toml",
                   help="a measured FILE (MERL .binary or RGL .bsdf): the material it measures, which the models "
                        "are given (default: none; required for a measured file)")
    p.add_argument("--incident", dest="measured_incident", metavar="LIST",
                   help="a measured FILE: incident elevations of the reference, e.g. 0,30,60 (default: an RGL "
                        "file's theta_i nodes below 89 deg; for MERL a simulation's default, 0,15,30,45,60,70,80)")
    p.add_argument("--parametrization", dest="measured_parametrization", choices=("classic", "half"),
                   help="a measured FILE: the cells it is resampled onto (default: classic)")
    p.add_argument("--resolution", dest="measured_resolution", metavar="N_THETAxN_PHI",
                   help="a measured FILE: cells per slice (default: 90x360)")


def is_measured(path: str | Path) -> bool:
    """True for a MERL ``.binary`` or an RGL tensor file (by content, whatever its values: reading
    it checks them, :func:`goniometer.files.measured.read_measured`)."""
    from goniometer.files.measured import measured_kind
    return measured_kind(path) is not None


def load_reference(args: argparse.Namespace, subcells: int = 5):
    """The reference of ``args.file``: the simulation it holds, or for a measured file the
    measurement on the slices that ``--incident`` / ``--parametrization`` / ``--resolution`` ask
    for, with ``--stack``'s material. UsageError (one line) for what cannot be."""
    from goniometer.files import slices as store
    from goniometer.files.measured import MeasuredError, measured_reference, read_measured
    from goniometer.run.settings import DEFAULT_INCIDENT, SettingsError, SimulationSettings
    from goniometer.stack import StackError, load_toml
    given = [o for o, v in (("--stack", args.stack), ("--incident", args.measured_incident),
                            ("--parametrization", args.measured_parametrization),
                            ("--resolution", args.measured_resolution)) if v is not None]
    if not is_measured(args.file):
        if given:
            raise UsageError(f"{given[0]}: goes with a measured file (MERL .binary or RGL .bsdf); {args.file} is "
                             f"a simulation, which holds its own stack and grid")
        with usage_errors(store.StoreError, prefix=str(args.file)):
            return store.read(args.file)
    if args.stack is None:
        raise UsageError(f"--stack: {args.file} is a measured file; give the material it measures "
                         f"(--stack CONFIG.toml) so that the models know the stack")
    with usage_errors(MeasuredError):
        measured = read_measured(args.file)
    with usage_errors(StackError):
        stack, _ = load_toml(args.stack)
    if args.measured_incident is not None:
        thetas, phis = incident_list(args.measured_incident)
    else:
        nodes = measured.incident_deg or DEFAULT_INCIDENT   # a MERL file covers them all
        thetas, phis = [t for t in nodes if t < 89.0], None
    res = resolution(args.measured_resolution) if args.measured_resolution else (90, 360)
    with usage_errors(SettingsError):
        settings = SimulationSettings(incident_deg=tuple(thetas),
                                      incident_phi_deg=tuple(phis) if phis is not None else None,
                                      parametrization=args.measured_parametrization or "classic", resolution=res,
                                      rays=1)
    with usage_errors(MeasuredError):
        return measured_reference(measured, stack, settings, subcells=subcells)
