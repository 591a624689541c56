"""The xarray view of a polarized file (docs/xarray.md, docs/slices-format.md): ``mueller`` and
``mueller_stderr`` on the dimensions ``mueller_row``/``mueller_col``, equal to the file's arrays,
masked like ``value``; a scalar file's view has none of them."""

from __future__ import annotations

import numpy as np
import pytest

import goniometer
from goniometer.files import slices as store
from goniometer.files.dataset import STOKES_FRAMES
from goniometer.run.loop import simulate
from goniometer.run.settings import SimulationSettings
from goniometer.stack import Interface, Medium, Stack
from tests.goniometer.test_dataset import assert_no_phony_dims

xr = pytest.importorskip("xarray")
pytest.importorskip("h5netcdf")

SLAB = Stack("slab/P", (Interface(0.3, (1.5,) * 3), Medium((0.05, 0.1, 0.4)), Interface(0.3, (1.0,) * 3)), "slab")
DIMS = ("incident", "channel", "theta", "phi", "mueller_row", "mueller_col")


def _file(tmp_path_factory, polarized: bool):
    r = simulate(SLAB, SimulationSettings(incident_deg=(0.0, 30.0), rays=3000, resolution=(6, 8),
                                          parametrization="half", max_order=3, threads=1, polarized=polarized))
    p = tmp_path_factory.mktemp("xrp") / ("pol.h5" if polarized else "scalar.h5")
    store.write(p, r)
    return p, r


@pytest.fixture(scope="module")
def polarized_file(tmp_path_factory):
    return _file(tmp_path_factory, True)


@pytest.fixture(scope="module")
def scalar_file(tmp_path_factory):
    return _file(tmp_path_factory, False)


@pytest.mark.parametrize("side", ["brdf", "btdf"])
def test_mueller_variables_are_the_files_arrays(polarized_file, side):
    p, r = polarized_file
    sd = getattr(r, side)
    raw = goniometer.open_dataset(p, side=side, masked=False)
    for name in ("mueller", "mueller_stderr"):
        assert raw[name].dims == DIMS, name
        assert raw[name].attrs["units"] == "1/sr" and {"long_name", "description"} <= set(raw[name].attrs)
        np.testing.assert_array_equal(raw[name].values, getattr(sd, name))
    np.testing.assert_array_equal(raw["mueller_row"].values, [0, 1, 2, 3])
    np.testing.assert_array_equal(raw["mueller_col"].values, [0, 1, 2, 3])
    np.testing.assert_allclose(raw["mueller"].sel(mueller_row=0, mueller_col=0).values, sd.value, rtol=1e-12, atol=0)
    assert raw.attrs["polarized"] == 1 and raw.attrs["stokes_frames"] == STOKES_FRAMES
    # masked like value: NaN exactly where mask is False, the file's numbers elsewhere
    ds = goniometer.open_dataset(p, side=side)
    m = ds["mueller"].values
    where = np.broadcast_to(sd.mask[:, None, :, :, None, None], m.shape)
    assert 0 < sd.mask.sum() < sd.mask.size
    assert np.isnan(m[~where]).all() and not np.isnan(m[where]).any()
    np.testing.assert_array_equal(m[where], sd.mueller[where])
    assert np.isnan(ds["mueller_stderr"].values[~where]).all()


def test_the_datatree_and_plain_xarray_see_the_dimensions(polarized_file):
    p, r = polarized_file
    assert_no_phony_dims(p)
    tree = goniometer.open_datatree(p)
    assert tree["btdf/mueller"].dims == DIMS and tree["btdf"].attrs["polarized"] == 1
    with xr.open_dataset(p, group="brdf", engine="h5netcdf") as ds:
        np.testing.assert_array_equal(ds["mueller_stderr"].values, r.brdf.mueller_stderr)


def test_a_scalar_files_view_is_unchanged(scalar_file):
    p, _ = scalar_file
    ds = goniometer.open_dataset(p)
    assert "mueller" not in ds.variables and "mueller_stderr" not in ds.variables
    assert "mueller_row" not in ds.dims and "mueller_col" not in ds.dims
    assert "polarized" not in ds.attrs and "stokes_frames" not in ds.attrs
