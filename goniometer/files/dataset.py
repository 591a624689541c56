"""xarray views of the project's HDF5 files (slices and model-slices files; ``docs/xarray.md``).

xarray and h5netcdf are an optional extra (``pip install 'goniometer[xarray]'``); this module
imports them only when called, and raises ImportError with that instruction when they are missing.

Every group of a file written by this version opens in xarray with named dimensions:
``incident`` (coordinate: theta_l in degrees, with the auxiliary coordinate ``incident_phi``,
phi_l in degrees), ``channel`` (R, G, B), ``order``, ``theta`` and ``phi`` (cell centres in
degrees). The functions below add what a user wants on top of that: cells whose ``mask`` is
False hold meaningless numbers in the file (they are kept there so that the energy sums close,
``docs/slices-format.md`` §5) and come back as NaN in every 1/sr variable.

A polarized run's slice groups add the dimensions ``mueller_row`` (the exit beam's Stokes component,
0..3) and ``mueller_col`` (the incident beam's) and the variables ``mueller`` and ``mueller_stderr``
(``incident, channel, theta, phi, mueller_row, mueller_col``; 1/sr, masked like ``value``), in the
s/p frames of ``docs/polarization.md`` section 2, which the group's attributes ``polarized`` and
``stokes_frames`` say. A scalar file's groups have none of them.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import h5py
import numpy as np

from goniometer.files import slices as store

if TYPE_CHECKING:  # pragma: no cover
    import xarray

__all__ = ["open_dataset", "open_datatree"]

SIDES = ("brdf", "btdf")
#: tabulated BRDFs (``docs/tabulated-format.md``): one ``/brdf`` group on the MERL grid, no incident
#: directions; cells no path left through (``hits`` = 0) are NaN when masked
TABULATED = "goniometer.tabulated"
_FORMATS = (store.FORMAT, "goniometer.model-slices", TABULATED)
#: the note left in the attributes of a group whose masked cells were replaced by NaN
MASKED_NOTE = "cells with mask == False are NaN in every 1/sr variable (they are meaningless in the file)"
#: the attribute ``stokes_frames`` of a polarized slice group: the frames of its Mueller matrices
STOKES_FRAMES = ("sp: each beam's x is the s of its own plane of incidence, x_in = normalize(l x z), "
                 "x_out = normalize(z x v), y = k x x (docs/polarization.md section 2); "
                 "goniometer.grids.stokes.convert_mueller converts them")


def _xarray():
    try:
        import xarray as xr
        import h5netcdf  # noqa: F401  (the engine)
    except ImportError as e:
        raise ImportError(f"goniometer.open_dataset and open_datatree need the optional packages xarray and "
                          f"h5netcdf ({e.name} is missing): pip install 'goniometer[xarray]'") from None
    return xr


def _check_file(p: Path) -> tuple[str, np.ndarray]:
    """The file's format and its incident azimuths; StoreError unless it is one of ours."""
    if not p.is_file():
        raise store.StoreError(f"{p}: no such file")
    try:
        with h5py.File(p, "r") as f:
            fmt = f.attrs.get("format")
            fmt = fmt.decode() if isinstance(fmt, bytes) else fmt
            if fmt not in _FORMATS:
                raise store.StoreError(f"{p}: not a {' or '.join(_FORMATS)} file (format attribute {fmt!r})")
            if fmt == TABULATED:
                return fmt, np.zeros(0)
            return fmt, np.asarray(f["incident/phi_deg"][()], dtype=np.float64)
    except OSError as e:
        raise store.StoreError(f"{p}: not a readable HDF5 file ({e})") from None
    except KeyError:
        raise store.StoreError(f"{p}: missing /incident/phi_deg") from None


def _finish(ds: "xarray.Dataset", phi_deg: np.ndarray, masked: bool) -> "xarray.Dataset":
    """Add ``incident_phi`` where an older file lacks it, and turn masked cells into NaN."""
    ds = ds.copy()
    if "mueller" in ds.data_vars:
        ds.attrs.update({"polarized": 1, "stokes_frames": STOKES_FRAMES})
    if "incident" in ds.dims and store.INCIDENT_PHI not in ds.variables:
        # files written before the auxiliary coordinate existed: take it from /incident/phi_deg
        ds = ds.assign_coords({store.INCIDENT_PHI: ("incident", phi_deg,
                                                     {"units": "deg", "long_name": "incident azimuth phi_l"})})
    if masked and ("mask" in ds.data_vars or "hits" in ds.data_vars):
        valid = ds["mask"].astype(bool) if "mask" in ds.data_vars else ds["hits"] > 0
        for name, var in ds.data_vars.items():
            if var.attrs.get("units") == "1/sr" and set(valid.dims) <= set(var.dims):
                ds[name] = var.where(valid).assign_attrs(var.attrs)
        ds.attrs["masked_cells"] = MASKED_NOTE if "mask" in ds.data_vars else \
            "cells no path left through (hits == 0) are NaN in every 1/sr variable"
    return ds


def open_dataset(path: str | Path, side: str = "brdf", model: str | None = None,
                 masked: bool = True) -> "xarray.Dataset":
    """One side of a slices file as an in-memory :class:`xarray.Dataset`.

    ``side`` is ``"brdf"`` or ``"btdf"``; for a model-slices file (``gonio evaluate --save-slices``)
    give ``model`` too. Variables in 1/sr (``value``, ``stderr``, ``orders``, ...) are NaN where
    ``mask`` is False unless ``masked=False``. Values are BSDF values without the cosine factor,
    angles in degrees, ``l`` and ``v`` pointing away from the surface (``docs/slices-format.md``).
    The dataset's attributes add the file's ``format``, ``material`` name and ``category``. A
    polarized file's group holds ``mueller`` and ``mueller_stderr`` (dimensions ``incident, channel,
    theta, phi, mueller_row, mueller_col``) and the attributes ``polarized`` = 1 and
    ``stokes_frames`` (module docstring); a scalar file's holds neither.
    Raises StoreError for a file that is not ours or lacks the side, ValueError for a bad ``side``.
    """
    xr = _xarray()
    if side not in SIDES:
        raise ValueError(f"side: {side!r} is not one of {', '.join(SIDES)}")
    p = Path(path)
    fmt, phi = _check_file(p)
    if (model is None) != (fmt in (store.FORMAT, TABULATED)):
        raise ValueError(f"{p}: model: " + ("give the model's name for a model-slices file" if model is None
                                            else f"a {fmt} file holds no models"))
    group = side if model is None else f"{model}/{side}"
    with h5py.File(p, "r") as f:
        if group not in f:
            have = ("a tabulated file holds the BRDF only" if fmt == TABULATED else
                    "the stack is opaque" if model is None else f"groups: {', '.join(f)}")
            raise store.StoreError(f"{p}: no /{group} ({have})")
        mat = f["material"].attrs
        info = {"format": fmt, "material": str(mat.get("name", "")), "category": str(mat.get("category", ""))}
    with xr.open_dataset(p, group=group, engine="h5netcdf", phony_dims="sort") as ds:
        ds = ds.load()
    ds.attrs.update(info)
    return _finish(ds, phi, masked)


def open_datatree(path: str | Path, masked: bool = True) -> "xarray.DataTree":
    """The whole file as an in-memory :class:`xarray.DataTree`, one node per HDF5 group.

    Slice groups get the same treatment as in :func:`open_dataset` (masked cells as NaN unless
    ``masked=False``, ``incident_phi`` added for older files). Files written before the groups
    ``/energy`` and ``/simulation`` had dimension scales show phony dimensions there.
    """
    xr = _xarray()
    p = Path(path)
    _, phi = _check_file(p)
    with xr.open_datatree(p, engine="h5netcdf", phony_dims="sort") as tree:
        tree = tree.load()
    return tree.map_over_datasets(lambda ds: _finish(ds, phi, masked) if "incident" in ds.dims else ds)
