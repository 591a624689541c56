"""HDF5 files of simulated materials (format "goniometer.slices", version 1; ``docs/slices-format.md``).

Writes are atomic: the file is written under a temporary name in the destination directory
and renamed over the final name only once complete, so an interrupted run never leaves a
half-written file under the final name. Groups carry HDF5 dimension scales (incident,
order, channel, theta, phi) so that general tools (``xarray`` with ``engine="h5netcdf"``)
can open them.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
from pathlib import Path
from typing import Callable

import h5py
import numpy as np

import goniometer
from goniometer.atomic import atomic_path, hdf5_file  # noqa: F401  (public here too: store.atomic_path)
from goniometer.run.results import ENERGY_TERMS, SimulationResult, SliceData
from goniometer.run.settings import SimulationSettings
from goniometer.grids.slice_grid import SliceGrid
from goniometer.stack import Stack, StackError

FORMAT = "goniometer.slices"
FORMAT_VERSION = 1
CHANNELS = ("R", "G", "B")
_COMPRESSION = {"compression": "gzip", "compression_opts": 4, "shuffle": True}


class StoreError(ValueError):
    """A file that is not a readable goniometer slices file (message names the file and why)."""


def check_writable(path: str | Path) -> Path:
    """Raise :class:`StoreError` unless ``path`` could be created or replaced; creates nothing."""
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    if p.exists() and p.is_dir():
        raise StoreError(f"{p}: output path is a directory")
    if not parent.is_dir():
        raise StoreError(f"{p}: output directory {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise StoreError(f"{p}: output directory {parent} is not writable")
    if p.exists() and not os.access(p, os.W_OK):
        raise StoreError(f"{p}: existing file is not writable")
    return p


def write(path: str | Path, result: SimulationResult, commit: Callable[[], None] | None = None) -> Path:
    """Write ``result`` to ``path`` atomically; returns the path. ``commit``: see
    :func:`goniometer.atomic.atomic_path`."""
    p = check_writable(path)
    with hdf5_file(p, commit) as f:
        _write(f, result)
    return p


def _write(f: h5py.File, r: SimulationResult) -> None:
    s = r.settings
    write_header(f, FORMAT, r.stack, r.theta_deg, r.phi_deg)

    sim = f.create_group("simulation")
    sim.attrs["rays_per_slice"] = s.rays
    sim.attrs["seed"] = s.seed
    sim.attrs["masking"] = s.masking
    sim.attrs["max_order"] = s.max_order
    sim.attrs["elapsed_s"] = float(np.sum(r.elapsed_s))
    sim.attrs["threads"] = r.threads
    sim.attrs["chunk_rays"] = s.chunk_rays
    sim.attrs["chunks_per_task"] = s.chunks_per_task
    sim.attrs["event_cap"] = s.event_cap
    sim.attrs["first_order"] = s.first_order
    sim.attrs["compile_s"] = r.compile_s
    sim.attrs["rays_per_s"] = r.rays_per_s
    sim.attrs["parametrization"] = s.parametrization
    sim.attrs["resolution"] = np.array(s.resolution, dtype=np.int64)
    if s.device != "cpu":   # docs/gpu.md: absent on a CPU run's file (whose bytes predate the field)
        sim.attrs["device"] = s.device
    wl = r.wavelengths_nm
    if s.polarized:   # docs/slices-format.md: /brdf/mueller, /btdf/mueller (absent on a scalar run's file)
        sim.attrs["polarized"] = True
    if s.spectral:   # docs/slices-format.md: the channel axis holds wavelength bins
        sim.attrs["spectral"] = True
        sim.attrs["wavelength_bins"] = s.wavelength_bins
        sim.attrs["paths_per_incident"] = r.paths_per_incident
    sim.create_dataset("elapsed_per_incident_s", data=r.elapsed_s)
    sim.create_dataset("capped_paths", data=r.capped_paths)
    sim.create_dataset("mean_events", data=r.mean_events)

    _write_slices(f, "brdf", r.brdf, r.theta_deg, r.phi_deg, wl)
    if s.rgl is not None:
        write_rgl_warp(f, s.rgl)
    if r.btdf is not None:
        _write_slices(f, "btdf", r.btdf, r.theta_deg, r.phi_deg, wl)

    en = f.create_group("energy")
    en.attrs["description"] = (f"fractions of the incident flux per channel ({'wavelength bin' if wl is not None else 'R, G, B'}); "
                               "reflected + transmitted + absorbed + masking_loss + roulette + capped = 1")
    for name in ENERGY_TERMS:
        en.create_dataset(name, data=r.energy[name])
        en.create_dataset(f"{name}_stderr", data=r.energy_stderr[name])
    en.create_dataset("roulette", data=r.roulette)
    en.create_dataset("capped", data=r.capped)
    if r.reflected_without_base is not None:
        en.create_dataset("reflected_without_base", data=r.reflected_without_base)
        en.create_dataset("reflected_without_base_stderr", data=r.reflected_without_base_stderr)

    # last: named dimensions for every dataset of the two per-incident groups (xarray without phony dims)
    attach_incident_dims(sim, r.theta_deg, r.phi_deg, describe=SIMULATION_ATTRS.get, wavelengths_nm=wl)
    attach_incident_dims(en, r.theta_deg, r.phi_deg, describe=energy_attrs, wavelengths_nm=wl)


#: what /rgl holds: the warp's tables as the exported tensor file holds them (float32)
RGL_TABLES = {"theta_i": ("rad", "incident elevations theta_i (the format's nodes)"),
              "phi_i": ("rad", "incident azimuths phi_i (one: isotropic, relative azimuths)"),
              "ndf": ("1/sr", "the warp's NDF D on (rows phi_m, columns sqrt(theta_m / (pi / 2)))"),
              "sigma": ("1", "projected area of the warp's NDF on the same grid"),
              "vndf": ("1", "visible-normal density on the square per (phi_i, theta_i), the warp's table")}


def write_rgl_warp(f: h5py.File, grid) -> None:
    """``/rgl``: the RGL grid (attribute ``grid``, JSON) and its warp tables (``docs/rgl-format.md``)."""
    g = f.create_group("rgl")
    g.attrs["grid"] = json.dumps(grid.to_dict())
    g.attrs["description"] = ("the warp of the RGL format (Dupuy & Jakob 2018) this file's /brdf is recorded "
                              "on: /brdf/value[m, c, k, j] is the stored value S at sample-space node "
                              "(u_x, u_y) = (j, k) / (n - 1) of incident direction m; docs/rgl-format.md")
    for name, a in grid.tables().items():
        d = g.create_dataset(name, data=a, **(_COMPRESSION if a.ndim > 1 else {}))
        d.attrs["units"], d.attrs["description"] = RGL_TABLES[name]


#: the channel scale of a spectral file: the wavelength-bin centres (``docs/spectral.md``)
WAVELENGTH = "wavelength_nm"


def _channel_scale(g: h5py.Group, wavelengths_nm: np.ndarray | None):
    """The scale of the channel axis: ``channel`` (R, G, B) or ``wavelength_nm`` (bin centres)."""
    if wavelengths_nm is None:
        return _scaled(g, "channel", np.array(CHANNELS, dtype=h5py.string_dtype()), None, "colour channel")
    return _scaled(g, WAVELENGTH, np.asarray(wavelengths_nm, dtype=np.float64), "nm", "wavelength-bin centre")


def _scaled(g: h5py.Group, name: str, data, units: str | None = None, long_name: str | None = None):
    d = g.create_dataset(name, data=data)
    d.make_scale(name)
    if units:
        d.attrs["units"] = units
    if long_name:
        d.attrs["long_name"] = long_name
    return d


#: name of the auxiliary coordinate holding phi_l along the ``incident`` dimension (§2 of the format page)
INCIDENT_PHI = "incident_phi"
_INCIDENT_LONG = "incident elevation theta_l"
_INCIDENT_PHI_LONG = "incident azimuth phi_l"


def _incident_phi(g: h5py.Group, incident: h5py.Dataset, phi_deg: np.ndarray) -> h5py.Dataset:
    """The 1-D dataset ``incident_phi`` along the ``incident`` scale: phi_l of each incident direction."""
    d = g.create_dataset(INCIDENT_PHI, data=np.asarray(phi_deg, dtype=np.float64))
    d.dims[0].attach_scale(incident)
    d.attrs["units"] = "deg"
    d.attrs["long_name"] = _INCIDENT_PHI_LONG
    d.attrs["description"] = ("azimuth phi_l of each incident direction, measured from +x towards +y; "
                              "the incident dimension's coordinate holds theta_l only, so several "
                              "azimuths at one elevation are told apart by this coordinate")
    return d


#: attributes of the energy terms: name -> (long_name, description); units are "1" (fractions)
ENERGY_ATTRS = {
    "reflected": ("reflected fraction", "fraction of the incident flux that leaves the stack upward"),
    "transmitted": ("transmitted fraction", "fraction of the incident flux that leaves the stack downward "
                    "(0 for opaque stacks)"),
    "absorbed": ("absorbed fraction", "fraction of the incident flux absorbed by media, conductors (1 - F) "
                 "and Lambertian bases (1 - rho)"),
    "masking_loss": ("masking loss", "fraction of the incident flux lost to single-scattering microfacet "
                     "masking and to wrong-side outgoing directions"),
    "roulette": ("Russian roulette balance", "net weight booked by Russian roulette divided by the rays; "
                 "zero in expectation"),
    "capped": ("capped fraction", "weight of the paths stopped by the event cap divided by the rays"),
    "reflected_without_base": ("reflected fraction that never reached the base",
                               "part of `reflected` carried by paths that never had an event at the base "
                               "(the bottom layer: conductor, Lambertian, or last interface of a transmitting "
                               "stack); not a further term of the energy sum"),
}


#: attributes of the datasets of ``/simulation``
SIMULATION_ATTRS = {
    "elapsed_per_incident_s": {"long_name": "wall time per incident direction", "units": "s",
                               "description": "wall time of the tracing of each incident direction"},
    "capped_paths": {"long_name": "paths stopped by the event cap", "units": "1",
                     "description": "number of paths of each incident direction stopped by the event cap"},
    "mean_events": {"long_name": "mean events per path", "units": "1",
                    "description": "mean number of scattering events per path"},
}


def energy_attrs(name: str) -> dict[str, str]:
    """``long_name``, ``units`` and ``description`` of the energy dataset ``name`` (``<term>_stderr``
    is the standard error of ``<term>``); an empty dict for a name without an entry in ENERGY_ATTRS."""
    base = name[:-len("_stderr")] if name.endswith("_stderr") else name
    if base not in ENERGY_ATTRS:
        return {}
    long_name, description = ENERGY_ATTRS[base]
    if base != name:
        return {"long_name": f"standard error of the {long_name}", "units": "1",
                "description": f"Monte Carlo standard error of /energy/{base} ({description})"}
    return {"long_name": long_name, "units": "1", "description": description}


def attach_incident_dims(g: h5py.Group, theta_deg: np.ndarray, phi_deg: np.ndarray,
                         describe: Callable[[str], dict | None] | None = None,
                         wavelengths_nm: np.ndarray | None = None) -> None:
    """Give every dataset of a per-incident group (``/energy``, ``/simulation``) named dimensions:
    shape (M,) gets ``incident``, shape (M, 3) gets ``incident, channel``; ``incident`` holds theta_l
    and the auxiliary coordinate ``incident_phi`` phi_l. Call it once every dataset is written; any
    dataset of another shape raises ValueError. ``describe(name)`` returns attributes to set."""
    data = [(name, d) for name, d in g.items() if isinstance(d, h5py.Dataset)]
    M = len(theta_deg)
    C = len(CHANNELS) if wavelengths_nm is None else len(wavelengths_nm)
    for name, d in data:
        if d.shape not in ((M,), (M, C)):
            raise ValueError(f"{g.name}/{name}: shape {d.shape} is neither (M,) nor (M, {C}) with M = {M}")
    incident = _scaled(g, "incident", np.asarray(theta_deg, dtype=np.float64), "deg", _INCIDENT_LONG)
    _incident_phi(g, incident, phi_deg)
    channel = None
    for name, d in data:
        if d.ndim == 2 and channel is None:
            channel = _channel_scale(g, wavelengths_nm)
        d.dims[0].attach_scale(incident)
        if d.ndim == 2:
            d.dims[1].attach_scale(channel)
        d.attrs["coordinates"] = INCIDENT_PHI
        for k, v in ((describe(name) or {}) if describe else {}).items():
            d.attrs[k] = v


class SliceGroupWriter:
    """Writes one group of slices (``/brdf``, ``/btdf``, or a model's group) with its dimension
    scales: ``incident``, ``order`` (if K is given), ``channel``, ``theta``, ``phi`` and cell edges."""

    def __init__(self, parent: h5py.Group, name: str, grid: SliceGrid, theta_deg: np.ndarray, K: int | None = None,
                 phi_deg: np.ndarray | None = None, wavelengths_nm: np.ndarray | None = None):
        g = parent.create_group(name)
        self.group = g
        g.attrs["parametrization"] = grid.parametrization
        g.attrs["n_theta"] = grid.n_theta
        g.attrs["n_phi"] = grid.n_phi
        g.attrs["side"] = grid.side
        th_name = "theta_v" if grid.parametrization == "classic" else "theta_h"
        ph_name = "phi_v" if grid.parametrization == "classic" else "phi_h"
        self.scales = {
            "incident": _scaled(g, "incident", theta_deg, "deg", _INCIDENT_LONG),
            "channel": _channel_scale(g, wavelengths_nm),
        }
        if grid.parametrization == "rgl":
            # rows u_y, columns u_x: the nodes of the RGL format's stored values (docs/rgl-format.md)
            nodes = np.linspace(0.0, 1.0, grid.n_theta)
            edges = np.clip((np.arange(grid.n_theta + 1) - 0.5) / (grid.n_theta - 1), 0.0, 1.0)
            self.scales["theta"] = _scaled(g, "theta", nodes, "1", "sample-space node u_y (rows)")
            self.scales["phi"] = _scaled(g, "phi", nodes, "1", "sample-space node u_x (columns)")
            _scaled(g, "theta_edges_deg", edges, "1", "dual-cell edges in u_y (the name is the other grids')")
            _scaled(g, "phi_edges_deg", edges, "1", "dual-cell edges in u_x (the name is the other grids')")
        else:
            self.scales["theta"] = _scaled(g, "theta", grid.theta_centers_deg(), "deg",
                                           f"cell centre {th_name}" + (" (square-root mapped rows)"
                                                                       if grid.parametrization == "half" else ""))
            self.scales["phi"] = _scaled(g, "phi", grid.phi_centers_deg(), "deg", f"cell centre {ph_name}")
            _scaled(g, "theta_edges_deg", grid.theta_edges_deg(), "deg", f"cell edges in {th_name}")
            _scaled(g, "phi_edges_deg", grid.phi_edges_deg(), "deg", f"cell edges in {ph_name}")
        if K is not None:
            self.scales["order"] = _scaled(g, "order", np.arange(1, K + 1, dtype=np.int64), None,
                                           f"bounce order (events at the top layer); {K} means {K} or more")
        self.has_phi = phi_deg is not None
        if self.has_phi:
            _incident_phi(g, self.scales["incident"], phi_deg)

    def mueller_scales(self) -> None:
        """The dimension scales of a Mueller matrix's rows and columns (a polarized run's slices)."""
        for dim, what in (("mueller_row", "row (the exit beam's Stokes component)"),
                          ("mueller_col", "column (the incident beam's Stokes component)")):
            self.scales[dim] = _scaled(self.group, dim, np.arange(4, dtype=np.int64), None, f"Mueller matrix {what}")

    def put(self, name: str, data: np.ndarray, dims: tuple[str, ...], units: str | None = None,
            dtype=None, description: str | None = None, long_name: str | None = None) -> h5py.Dataset:
        # one chunk per incident direction: what a reader takes at once, and 0.4-0.65 of the size of
        # HDF5's own small chunks under the same filters (docs/slices-format.md)
        shape = np.shape(data)
        chunks = (1,) + shape[1:] if dims and dims[0] == "incident" and len(shape) > 1 and shape[0] > 0 else True
        d = self.group.create_dataset(name, data=data, dtype=dtype, chunks=chunks, **_COMPRESSION)
        for axis, dim in enumerate(dims):
            d.dims[axis].attach_scale(self.scales[dim])
        if units:
            d.attrs["units"] = units
        if long_name:
            d.attrs["long_name"] = long_name
        if description:
            d.attrs["description"] = description
        if self.has_phi and "incident" in dims:
            d.attrs["coordinates"] = INCIDENT_PHI
        return d


CELLS = ("incident", "channel", "theta", "phi")
MAPS = ("incident", "theta", "phi")


#: the ``description`` of ``mask`` (slices and model-slices files): masked cells hold meaningless values
MASK_DESCRIPTION = (
    "True where a cell may be used: comparisons sum only over these cells. Where False (half grid: "
    "cells reaching past the horizon, and row 0), value, stderr and the other 1/sr data of the cell are "
    "meaningless (they can reach thousands of 1/sr) and must be ignored; they are stored as numbers, "
    "not NaN, so that summing value * proj_solid_angle over all cells gives the energy. "
    "goniometer.open_dataset returns them as NaN. See docs/slices-format.md section 5.")
_MASKED = " Meaningless where mask is False (see mask)."


def _write_slices(f: h5py.File, name: str, sd: SliceData, theta_deg: np.ndarray, phi_deg: np.ndarray,
                  wavelengths_nm: np.ndarray | None = None) -> None:
    w = SliceGroupWriter(f, name, sd.grid, theta_deg, K=sd.orders.shape[1], phi_deg=phi_deg,
                         wavelengths_nm=wavelengths_nm)
    what = "BRDF" if name == "brdf" else "BTDF"
    rgl = sd.grid.parametrization == "rgl"
    unit = "1" if rgl else "1/sr"
    if rgl:
        v = w.put("value", sd.value, CELLS, unit, long_name="RGL stored value S",
                  description="the RGL format's stored value S = f cos(theta_o) 4 sigma(l) / D(h) at the node: "
                              "the reflected energy per unit sample-space area of the node's dual cell "
                              "(docs/rgl-format.md), all bounce orders." + _MASKED)
    else:
        v = w.put("value", sd.value, CELLS, "1/sr", long_name=f"{what} cell mean",
                  description=f"cosine-weighted mean of the {what} over the cell, Int f |cos theta_v| dw / "
                              "proj_solid_angle, all bounce orders, without the cosine factor." + _MASKED)
    v.attrs["ancillary_variables"] = "stderr mask"
    w.put("stderr", sd.stderr, CELLS, unit, long_name=f"standard error of the {what} cell mean",
          description="Monte Carlo standard error of value." + _MASKED)
    if sd.stderr_internal is not None:
        w.put("stderr_internal", sd.stderr_internal, CELLS, unit, long_name="standard error of the internal part",
              description="standard error of the internal part (bounce orders >= 2)." + _MASKED)
    w.put("orders", sd.orders, ("incident", "order", "channel", "theta", "phi"), unit, dtype=np.float32,
          long_name=f"{what} cell mean per bounce order",
          description="value of each bounce order (events at the top layer); the last order holds "
                      "that order or more; float32." + _MASKED)
    if sd.mueller is not None:
        w.mueller_scales()
        dims = CELLS + ("mueller_row", "mueller_col")
        w.put("mueller", sd.mueller, dims, unit, long_name=f"{what} Mueller matrix cell mean",
              description="the cell mean of the Mueller matrix (the incident beam's Stokes vector to the exit "
                          "beam's, each in the s/p frame of its plane of incidence, docs/polarization.md section 2), "
                          "all bounce orders, without the cosine; [..., 0, 0] is value." + _MASKED)
        w.put("mueller_stderr", sd.mueller_stderr, dims, unit, long_name="standard error of the Mueller matrix",
              description="Monte Carlo standard error of each element of mueller." + _MASKED)
    w.put("mask", sd.mask, MAPS, "1", long_name="cell valid for comparisons", description=MASK_DESCRIPTION)
    if rgl:
        w.put("proj_solid_angle", sd.proj_solid_angle, MAPS, "1", long_name="sample-space area of the dual cell",
              description="area in u of the part of the node's dual cell whose outgoing directions lie above the "
                          "horizon (the estimator's measure; the name is the other grids')")
    else:
        w.put("proj_solid_angle", sd.proj_solid_angle, MAPS, "sr", long_name="projected solid angle of the cell",
              description="Int over the part of the cell on this side of |cos theta_v| dw_v")


def write_header(f: h5py.File, fmt: str, stack: Stack, theta_deg: np.ndarray, phi_deg: np.ndarray) -> None:
    """Root attributes, ``/material`` and ``/incident`` shared by every file of slices the project writes."""
    write_material(f, fmt, FORMAT_VERSION, stack)
    inc = f.create_group("incident")
    theta = _scaled(inc, "theta_deg", theta_deg, units="deg", long_name=_INCIDENT_LONG)
    phi = inc.create_dataset("phi_deg", data=phi_deg)  # along theta_deg (it was a scale of its own before)
    phi.dims[0].attach_scale(theta)
    phi.attrs["units"] = "deg"
    phi.attrs["long_name"] = _INCIDENT_PHI_LONG
    inc.attrs["coordinates"] = "phi_deg"


def write_material(f: h5py.File, fmt: str, version: int, stack: Stack) -> None:
    """Root attributes (format, version, software, date) and ``/material`` (the stack), shared by
    every file the project writes."""
    f.attrs["format"] = fmt
    f.attrs["format_version"] = version
    f.attrs["software"] = f"goniometer {goniometer.__version__}"
    f.attrs["created"] = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    mat = f.create_group("material")
    mat.attrs["name"] = stack.name
    mat.attrs["category"] = stack.category
    mat.create_dataset("config", data=stack.to_json())


# ---------------------------------------------------------------------- reading

def read(path: str | Path) -> SimulationResult:
    """Read a slices file into a :class:`SimulationResult` (raises :class:`StoreError`)."""
    p = Path(path)
    if not p.is_file():
        raise StoreError(f"{p}: no such file")
    try:
        with h5py.File(p, "r") as f:
            return _read(f, p)
    except StoreError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as e:
        raise StoreError(f"{p}: not a readable {FORMAT} file ({e})") from None


def describe(path: str | Path) -> tuple[Stack, SimulationSettings]:
    """The stack and settings of a file without loading its slices; checks that the datasets of
    the contract are present with consistent shapes (raises :class:`StoreError`)."""
    p = Path(path)
    try:
        with h5py.File(p, "r") as f:
            stack, settings = _header(f, p)
            M = len(settings.incident_deg)
            nt, nph = settings.resolution
            sides = ["brdf"] + (["btdf"] if stack.transmits else [])
            C = settings.n_channels
            for side in sides:
                checked = [("value", (M, C, nt, nph)), ("stderr", (M, C, nt, nph)),
                           ("orders", (M, settings.max_order, C, nt, nph)), ("mask", (M, nt, nph)),
                           ("proj_solid_angle", (M, nt, nph))]
                if settings.polarized:
                    checked += [("mueller", (M, C, nt, nph, 4, 4)), ("mueller_stderr", (M, C, nt, nph, 4, 4))]
                for name, shape in checked:
                    key = f"{side}/{name}"
                    if key not in f or f[key].shape != shape:
                        raise StoreError(f"{p}: /{key} is missing or not of shape {shape}")
            for k in ENERGY_TERMS:
                if f"energy/{k}" not in f:
                    raise StoreError(f"{p}: missing /energy/{k}")
            return stack, settings
    except StoreError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as e:
        raise StoreError(f"{p}: not a readable {FORMAT} file ({e})") from None


def _header(f: h5py.File, p: Path) -> tuple[Stack, SimulationSettings]:
    if f.attrs.get("format") != FORMAT:
        raise StoreError(f"{p}: not a {FORMAT} file (format attribute {f.attrs.get('format')!r})")
    version = int(f.attrs.get("format_version", -1))
    if version > FORMAT_VERSION:
        raise StoreError(f"{p}: format version {version} is newer than this software reads "
                         f"(versions 1 to {FORMAT_VERSION}); update goniometer")
    if version < 1:
        raise StoreError(f"{p}: format version {version} is not a version of {FORMAT}")
    for need in ("material/config", "incident/theta_deg", "incident/phi_deg", "simulation", "brdf/value", "energy/reflected"):
        if need not in f:
            raise StoreError(f"{p}: missing /{need}")
    config = f["material/config"][()]
    config = config.decode() if isinstance(config, bytes) else str(config)
    try:
        stack = Stack.from_json(config)
    except (StackError, json.JSONDecodeError) as e:
        raise StoreError(f"{p}: /material/config is not a valid stack ({e})") from None
    sim = f["simulation"].attrs
    brdf = f["brdf"].attrs
    d = {"incident_deg": [float(x) for x in f["incident/theta_deg"][()]],
         "incident_phi_deg": [float(x) for x in f["incident/phi_deg"][()]],
         "rays": int(sim["rays_per_slice"]), "parametrization": str(brdf["parametrization"]),
         "resolution": [int(brdf["n_theta"]), int(brdf["n_phi"])], "seed": int(sim["seed"]),
         "masking": str(sim["masking"]), "max_order": int(sim["max_order"])}
    # attributes added in later versions of the format: absent, the field's default
    for key in ("chunk_rays", "chunks_per_task", "event_cap"):
        if key in sim:
            d[key] = int(sim[key])
    if "first_order" in sim:
        d["first_order"] = str(sim["first_order"])
    if "device" in sim:
        d["device"] = str(sim["device"])
    if bool(sim.get("spectral", False)):
        d["spectral"] = True
        d["wavelength_bins"] = int(sim["wavelength_bins"])
    if bool(sim.get("polarized", False)):
        d["polarized"] = True
    if d["parametrization"] == "rgl":
        if "rgl" not in f or "grid" not in f["rgl"].attrs:
            raise StoreError(f"{p}: an RGL-grid file without /rgl (its warp)")
        try:
            d["rgl"] = json.loads(f["rgl"].attrs["grid"])
        except ValueError as e:
            raise StoreError(f"{p}: /rgl@grid is not valid JSON ({e})") from None
    settings = SimulationSettings.from_dict(d)
    return stack, settings


def _read(f: h5py.File, p: Path) -> SimulationResult:
    stack, settings = _header(f, p)
    sim = f["simulation"].attrs
    theta = f["incident/theta_deg"][()]
    phi = f["incident/phi_deg"][()]
    brdf = _read_slices(f["brdf"])
    btdf = _read_slices(f["btdf"]) if "btdf" in f else None
    en = f["energy"]
    M = len(theta)
    energy = {k: en[k][()] for k in ENERGY_TERMS}
    C = settings.n_channels
    energy_se = {k: en[f"{k}_stderr"][()] if f"{k}_stderr" in en else np.full((M, C), np.nan) for k in ENERGY_TERMS}
    elapsed = f["simulation/elapsed_per_incident_s"][()] if "simulation/elapsed_per_incident_s" in f \
        else np.full(M, float(sim["elapsed_s"]) / M)
    return SimulationResult(
        stack=stack, settings=settings, theta_deg=theta, phi_deg=phi, brdf=brdf, btdf=btdf,
        energy=energy, energy_stderr=energy_se,
        roulette=en["roulette"][()] if "roulette" in en else np.zeros((M, C)),
        capped=en["capped"][()] if "capped" in en else np.zeros((M, C)),
        capped_paths=f["simulation/capped_paths"][()] if "simulation/capped_paths" in f else np.zeros(M, np.int64),
        mean_events=f["simulation/mean_events"][()] if "simulation/mean_events" in f else np.full(M, np.nan),
        elapsed_s=elapsed, threads=int(sim["threads"]), compile_s=float(sim.get("compile_s", 0.0)),
        reflected_without_base=en["reflected_without_base"][()] if "reflected_without_base" in en else None,
        reflected_without_base_stderr=(en["reflected_without_base_stderr"][()]
                                       if "reflected_without_base_stderr" in en else None),
    )


def _read_slices(g: h5py.Group) -> SliceData:
    side = g.attrs.get("side")
    if side is None:
        side = "transmission" if g.name.endswith("btdf") else "reflection"
    grid = SliceGrid(str(g.attrs["parametrization"]), int(g.attrs["n_theta"]), int(g.attrs["n_phi"]), str(side))
    return SliceData(grid=grid, value=g["value"][()], stderr=g["stderr"][()], orders=g["orders"][()],
                     mask=g["mask"][()].astype(bool), proj_solid_angle=g["proj_solid_angle"][()],
                     stderr_internal=g["stderr_internal"][()] if "stderr_internal" in g else None,
                     mueller=g["mueller"][()] if "mueller" in g else None,
                     mueller_stderr=g["mueller_stderr"][()] if "mueller_stderr" in g else None)
