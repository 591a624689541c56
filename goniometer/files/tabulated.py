"""The HDF5 file of a tabulated isotropic BRDF on the MERL grid (format "goniometer.tabulated",
version 1; ``docs/tabulated-format.md``): :func:`write_tabulated`, :func:`read_tabulated` of a
:class:`goniometer.run.results.TabulatedBRDF` (what ``gonio tabulate`` produces).

    tab = read_tabulated("metal-tab.h5")
    f = tab.eval(l, v)      # (..., 3) RGB, 1/sr, no cosine; l, v unit, pointing away from the surface
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import h5py
import numpy as np

from goniometer.grids import halfdiff
from goniometer.atomic import hdf5_file
from goniometer.run.results import TAB_ENERGY_TERMS, TabulatedBRDF
from goniometer.run.settings import SettingsError, TabulationSettings
from goniometer.stack import Stack, StackError

__all__ = ["FORMAT", "FORMAT_VERSION", "TabulatedError", "read_tabulated", "write_tabulated"]

FORMAT = "goniometer.tabulated"
FORMAT_VERSION = 1
CHANNELS = ("R", "G", "B")
#: the channel scale of a spectral tabulation (as in a slices file, ``docs/spectral.md``)
WAVELENGTH = "wavelength_nm"
_COMPRESSION = {"compression": "gzip", "compression_opts": 4, "shuffle": True}
_DESCRIPTION = {
    "value": "mean BRDF over the cell, weighted by cos(theta_l) cos(theta_v) (no cosine in the value); "
             "0 where no path left through the cell",
    "stderr": "standard error of value (0 where no path left through the cell)",
    "hits": "number of paths that left through the cell (a cell has data when hits > 0)",
    "measure": "integral of cos(theta_l) cos(theta_v) dw_l dw_v over the cell (folds included); sums to pi^2",
    "mueller": "a polarized tabulation's only: mean Mueller matrix over the cell (no cosine), the incident beam's "
               "Stokes vector (along -l) to the exit beam's (along v), both in the plane frames x = normalize(l x v) "
               "of the cell's pair with phi_d in [0, 180) deg (docs/polarization.md section 5); [..., 0, 0] is value",
    "mueller_stderr": "a polarized tabulation's only: standard error of each element of mueller",
}
#: the Stokes frames of a polarized tabulation's Mueller matrices (goniometer.grids.stokes.FRAMES)
FRAMES = "plane"


class TabulatedError(ValueError):
    """A file that is not a readable tabulated BRDF (the message names the file and why)."""


# ---------------------------------------------------------------------- writing

def write_tabulated(path: str | Path, tab: TabulatedBRDF, commit: Callable[[], None] | None = None) -> Path:
    """Write ``tab`` to ``path`` atomically (the layout of ``docs/tabulated-format.md``); ``commit``:
    see :func:`goniometer.atomic.atomic_path`."""
    from goniometer.files import slices as store
    p = store.check_writable(path)
    with hdf5_file(p, commit) as f:
        store.write_material(f, FORMAT, FORMAT_VERSION, tab.stack)
        _write(f, tab)
    return p


def _scale(g: h5py.Group, name: str, data, units: str | None, long_name: str) -> h5py.Dataset:
    d = g.create_dataset(name, data=data)
    d.make_scale(name)
    if units:
        d.attrs["units"] = units
    d.attrs["long_name"] = long_name
    return d


def _channel_scale(g: h5py.Group, t: TabulatedBRDF) -> h5py.Dataset:
    """The scale of the channel axis: ``channel`` (R, G, B) or ``wavelength_nm`` (bin centres, nm)."""
    if t.settings.spectral:
        return _scale(g, WAVELENGTH, np.asarray(t.wavelengths_nm, dtype=np.float64), "nm", "wavelength-bin centre")
    return _scale(g, "channel", np.array(CHANNELS, dtype=h5py.string_dtype()), None, "colour channel")


def _write(f: h5py.File, t: TabulatedBRDF) -> None:
    s = t.settings
    sim = f.create_group("simulation")
    sim.attrs["rays"] = s.rays
    sim.attrs["seed"] = s.seed
    sim.attrs["masking"] = s.masking
    sim.attrs["chunk_rays"] = s.chunk_rays
    sim.attrs["event_cap"] = s.event_cap
    sim.attrs["threads"] = t.threads
    sim.attrs["elapsed_s"] = t.elapsed_s
    sim.attrs["compile_s"] = t.compile_s
    sim.attrs["rays_per_s"] = t.rays_per_s
    sim.attrs["capped_paths"] = t.capped_paths
    sim.attrs["mean_events"] = t.mean_events
    sim.attrs["incident_density"] = "cos(theta_l) / pi over the upper hemisphere, one direction per path"
    if s.spectral:   # docs/tabulated-format.md: the channel axis holds wavelength bins
        sim.attrs["spectral"] = True
        sim.attrs["wavelength_bins"] = s.wavelength_bins
        sim.attrs["launches"] = t.launches
        sim.attrs["paths"] = t.paths
    if s.device != "cpu":
        sim.attrs["device"] = s.device
    if s.polarized:   # docs/tabulated-format.md: /brdf/mueller, /brdf/mueller_stderr
        sim.attrs["polarized"] = True

    g = f.create_group("brdf")
    g.attrs["grid"] = "merl"
    g.attrs["shape"] = np.array(halfdiff.SHAPE, dtype=np.int64)
    g.attrs["folds"] = "isotropy (phi_h dropped); reciprocity (phi_d and phi_d + 180 deg share a cell)"
    g.attrs["estimator"] = "value = pi * (sum of exit weights in the cell) / (rays * measure)"
    scales = {
        "channel": _channel_scale(g, t),
        "theta_h": _scale(g, "theta_h", halfdiff.theta_h_centers_deg(), "deg",
                          "cell centre theta_h (square-root mapped rows)"),
        "theta_d": _scale(g, "theta_d", halfdiff.theta_d_centers_deg(), "deg", "cell centre theta_d"),
        "phi_d": _scale(g, "phi_d", halfdiff.phi_d_centers_deg(), "deg", "cell centre phi_d (folded to [0, 180))"),
    }
    _scale(g, "theta_h_edges_deg", halfdiff.theta_h_edges_deg(), "deg", "cell edges in theta_h")
    _scale(g, "theta_d_edges_deg", halfdiff.theta_d_edges_deg(), "deg", "cell edges in theta_d")
    _scale(g, "phi_d_edges_deg", halfdiff.phi_d_edges_deg(), "deg", "cell edges in phi_d")
    arrays = [("value", t.value, ("channel", "theta_h", "theta_d", "phi_d"), "1/sr"),
              ("stderr", t.stderr, ("channel", "theta_h", "theta_d", "phi_d"), "1/sr"),
              ("hits", t.hits, ("theta_h", "theta_d", "phi_d"), None),
              ("measure", t.measure, ("theta_h", "theta_d", "phi_d"), "sr^2")]
    if t.mueller is not None:
        g.attrs["stokes_frames"] = FRAMES
        for dim, what in (("mueller_row", "row (the exit beam's Stokes component)"),
                          ("mueller_col", "column (the incident beam's Stokes component)")):
            scales[dim] = _scale(g, dim, np.arange(4, dtype=np.int64), None, f"Mueller matrix {what}")
        dims = ("channel", "theta_h", "theta_d", "phi_d", "mueller_row", "mueller_col")
        arrays += [("mueller", t.mueller, dims, "1/sr"), ("mueller_stderr", t.mueller_stderr, dims, "1/sr")]
    for name, data, dims, units in arrays:
        d = g.create_dataset(name, data=data, chunks=True, **_COMPRESSION)
        for axis, dim in enumerate(dims):
            d.dims[axis].attach_scale(scales[dim])
        if units:
            d.attrs["units"] = units
        d.attrs["description"] = _DESCRIPTION[name]

    en = f.create_group("energy")
    en.attrs["description"] = ("fractions of the flux of uniform diffuse illumination per channel "
                               f"({'wavelength bin' if s.spectral else 'R, G, B'}); "
                               "reflected + transmitted + absorbed + masking_loss + roulette + capped = 1; "
                               "reflected_without_base is a part of reflected")
    channel = _channel_scale(en, t)
    for name, data, long_name in (
            *((k, t.energy[k], f"{k.replace('_', ' ')} fraction") for k in TAB_ENERGY_TERMS),
            *((f"{k}_stderr", t.energy_stderr[k], f"standard error of {k}") for k in TAB_ENERGY_TERMS),
            ("roulette", t.roulette, "net weight booked by Russian roulette, per path"),
            ("capped", t.capped, "weight of paths stopped by the event cap, per path")):
        d = en.create_dataset(name, data=data)
        d.dims[0].attach_scale(channel)
        d.attrs["long_name"] = long_name


# ---------------------------------------------------------------------- reading

def read_tabulated(path: str | Path, mueller: bool = True) -> TabulatedBRDF:
    """Read a tabulated file (raises :class:`TabulatedError` naming the file and the reason).
    ``mueller``: read a polarized file's Mueller matrices (False: leave them out, 1.1 GB for RGB;
    ``settings.polarized`` still says what the file holds)."""
    p = Path(path)
    if not p.is_file():
        raise TabulatedError(f"{p}: no such file")
    try:
        with h5py.File(p, "r") as f:
            return _read(f, p, mueller)
    except TabulatedError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as e:
        raise TabulatedError(f"{p}: not a readable {FORMAT} file ({e})") from None


def _read(f: h5py.File, p: Path, mueller: bool = True) -> TabulatedBRDF:
    fmt = f.attrs.get("format")
    if fmt != FORMAT:
        hint = " (a slices file: gonio tabulate writes tabulated files)" if fmt == "goniometer.slices" else ""
        raise TabulatedError(f"{p}: not a {FORMAT} file (format attribute {fmt!r}){hint}")
    version = int(f.attrs.get("format_version", -1))
    if version > FORMAT_VERSION:
        raise TabulatedError(f"{p}: format version {version} is newer than this software reads "
                             f"(versions 1 to {FORMAT_VERSION}); update goniometer")
    if version < 1:
        raise TabulatedError(f"{p}: format version {version} is not a version of {FORMAT}")
    config = f["material/config"][()]
    config = config.decode() if isinstance(config, bytes) else str(config)
    try:
        stack = Stack.from_json(config)
    except (StackError, json.JSONDecodeError) as e:
        raise TabulatedError(f"{p}: /material/config is not a valid stack ({e})") from None
    sim = f["simulation"].attrs
    spectral = bool(sim.get("spectral", False))
    try:
        settings = TabulationSettings(rays=int(sim["rays"]), seed=int(sim["seed"]), masking=str(sim["masking"]),
                                      chunk_rays=int(sim["chunk_rays"]), event_cap=int(sim["event_cap"]),
                                      spectral=spectral, wavelength_bins=int(sim.get("wavelength_bins", 30)),
                                      device=str(sim.get("device", "cpu")),
                                      polarized=bool(sim.get("polarized", False)))
    except SettingsError as e:
        raise TabulatedError(f"{p}: /simulation: {e}") from None
    g = f["brdf"]
    cells = halfdiff.SHAPE
    C = settings.n_channels
    checked = [("value", (C,) + cells), ("stderr", (C,) + cells), ("hits", cells), ("measure", cells)]
    if settings.polarized:
        checked += [("mueller", (C,) + cells + (4, 4)), ("mueller_stderr", (C,) + cells + (4, 4))]
    for name, shape in checked:
        if name not in g or g[name].shape != shape:
            raise TabulatedError(f"{p}: /brdf/{name} is missing or not of shape {shape}")
    en = f["energy"]
    return TabulatedBRDF(
        stack=stack, settings=settings, value=g["value"][()], stderr=g["stderr"][()], hits=g["hits"][()],
        measure=g["measure"][()],
        energy={k: en[k][()] for k in TAB_ENERGY_TERMS}, energy_stderr={k: en[f"{k}_stderr"][()] for k in TAB_ENERGY_TERMS},
        roulette=en["roulette"][()], capped=en["capped"][()], capped_paths=int(sim["capped_paths"]),
        mean_events=float(sim["mean_events"]), elapsed_s=float(sim["elapsed_s"]), threads=int(sim["threads"]),
        compile_s=float(sim.get("compile_s", 0.0)), launches=int(sim.get("launches", 1)),
        mueller=g["mueller"][()] if settings.polarized and mueller else None,
        mueller_stderr=g["mueller_stderr"][()] if settings.polarized and mueller else None)
