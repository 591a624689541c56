"""Every group of every file opens in xarray with named dimensions (docs/xarray.md), and
goniometer.open_dataset / open_datatree; old files still read (docs/file-identity.md)."""

from __future__ import annotations

import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest

import goniometer
from goniometer.files import slices as store
from goniometer.database import load_database, simulate_database
from goniometer.run.loop import simulate
from goniometer.run.settings import SimulationSettings
from goniometer.stack import Interface, Medium, Stack

xr = pytest.importorskip("xarray")
h5netcdf = pytest.importorskip("h5netcdf")

DATA = Path(__file__).resolve().parents[1] / "data"
#: a slices file written by the writer of commit 836c0c7 (before /energy and /simulation had
#: dimension scales and before incident_phi): slab, incident 30:0 and 30:90, half grid 4 x 6
OLD_FILE = DATA / "slices_v1_before_scales.h5"


@pytest.fixture(scope="module")
def slab_file(tmp_path_factory):
    st = Stack("slab/X", (Interface(0.3, (1.5,) * 3), Medium((0.05, 0.1, 0.4)), Interface(0.3, (1.0,) * 3)), "slab")
    r = simulate(st, SimulationSettings(incident_deg=(0.0, 30.0, 30.0), incident_phi_deg=(0.0, 0.0, 90.0), rays=3000,
                                        resolution=(6, 8), parametrization="half", max_order=3, threads=1))
    p = tmp_path_factory.mktemp("xr") / "slab.h5"
    store.write(p, r)
    return p, r


@pytest.fixture(scope="module")
def database_file(tmp_path_factory):
    db = load_database(DATA / "tiny_database.toml")
    out = tmp_path_factory.mktemp("db")
    simulate_database(db, out, "quick", only="metal/*", threads=1)
    (p,) = list(out.glob("metal/*.h5"))
    return p


def _groups(path: Path) -> list[str]:
    names = ["/"]
    with h5py.File(path, "r") as f:
        f.visititems(lambda n, o: names.append("/" + n) if isinstance(o, h5py.Group) else None)
    return names


def assert_no_phony_dims(path: Path) -> None:
    """h5netcdf without phony dims raises on any unlabeled axis; xarray must not warn about them."""
    with h5netcdf.File(path, "r") as f:  # phony_dims=None: strict
        def walk(g):
            for v in g.variables.values():
                assert all(not d.startswith("phony_dim") for d in v.dimensions), (g.name, v.name)
            for child in g.groups.values():
                walk(child)
        walk(f)
    for group in _groups(path):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            with xr.open_dataset(path, group=group, engine="h5netcdf", phony_dims=None) as ds:
                assert not [d for d in ds.dims if str(d).startswith("phony_dim")], group


def test_every_group_of_a_slices_file_has_named_dims(slab_file):
    p, _ = slab_file
    assert set(_groups(p)) == {"/", "/material", "/incident", "/simulation", "/brdf", "/btdf", "/energy"}
    assert_no_phony_dims(p)


def test_every_group_of_a_database_file_has_named_dims(database_file):
    assert_no_phony_dims(database_file)


def test_coordinates_and_attributes(slab_file):
    p, r = slab_file
    with xr.open_dataset(p, group="brdf", engine="h5netcdf") as ds:
        assert ds["value"].dims == ("incident", "channel", "theta", "phi")
        np.testing.assert_array_equal(ds["incident"].values, [0.0, 30.0, 30.0])
        np.testing.assert_array_equal(ds["incident_phi"].values, [0.0, 0.0, 90.0])
        assert "incident_phi" in ds.coords and ds["incident_phi"].dims == ("incident",)
        # the two azimuths at 30 degrees are told apart, and their data are not the same
        a, b = ds["value"].isel(incident=1).values, ds["value"].isel(incident=2).values
        np.testing.assert_array_equal(a, r.brdf.value[1])
        np.testing.assert_array_equal(b, r.brdf.value[2])
        for name in ("value", "stderr", "mask"):
            assert {"long_name", "units", "description"} <= set(ds[name].attrs), name
        assert "meaningless" in ds["mask"].attrs["description"] and "not NaN" in ds["mask"].attrs["description"]
        assert ds["value"].attrs["units"] == "1/sr" and ds["mask"].dtype == bool
    with xr.open_dataset(p, group="energy", engine="h5netcdf") as en:
        data = [n for n in en.data_vars]
        assert {"reflected", "reflected_stderr", "absorbed", "roulette", "capped"} <= set(data)
        for name in data:  # every energy dataset, whatever its name, gets the dims and the attributes
            assert en[name].dims == ("incident", "channel"), name
            assert {"long_name", "units", "description"} <= set(en[name].attrs), name
        np.testing.assert_array_equal(en["reflected"].values, r.energy["reflected"])
        np.testing.assert_array_equal(en["incident_phi"].values, [0.0, 0.0, 90.0])
        assert list(en["channel"].values) == ["R", "G", "B"]
    with xr.open_dataset(p, group="simulation", engine="h5netcdf") as sim:
        assert sim["mean_events"].dims == ("incident",) and sim.attrs["rays_per_slice"] == 3000
    with xr.open_dataset(p, group="incident", engine="h5netcdf") as inc:
        np.testing.assert_array_equal(inc["phi_deg"].values, [0.0, 0.0, 90.0])
        assert inc["phi_deg"].dims == ("theta_deg",) and "phi_deg" in inc.coords


def test_open_dataset_masks_cells_as_nan(slab_file):
    p, r = slab_file
    ds = goniometer.open_dataset(p, side="btdf")
    mask = r.btdf.mask
    assert 0 < mask.sum() < mask.size  # the half grid has masked cells
    v = ds["value"].values
    assert np.isnan(v).sum() == 3 * (~mask).sum()
    np.testing.assert_array_equal(v[np.broadcast_to(mask[:, None], v.shape)],
                                  r.btdf.value[np.broadcast_to(mask[:, None], v.shape)])
    assert np.isnan(ds["orders"].values).sum() == 3 * 3 * (~mask).sum()
    assert not np.isnan(ds["proj_solid_angle"].values).any()  # geometry, not a 1/sr value
    assert ds.attrs["material"] == "slab/X" and ds["value"].attrs["units"] == "1/sr"
    raw = goniometer.open_dataset(p, side="btdf", masked=False)
    np.testing.assert_array_equal(raw["value"].values, r.btdf.value)
    # the file's own sums close only with the masked cells (why they are not NaN in the file)
    e = (raw["value"] * raw["proj_solid_angle"]).sum(("theta", "phi")).values
    np.testing.assert_allclose(e, r.energy["transmitted"], rtol=1e-12)


def test_open_datatree_holds_the_whole_file(slab_file):
    p, r = slab_file
    tree = goniometer.open_datatree(p)
    assert {"material", "incident", "simulation", "brdf", "btdf", "energy"} <= set(tree.children)
    np.testing.assert_array_equal(tree["energy/absorbed"].values, r.energy["absorbed"])
    assert np.isnan(tree["brdf/value"].values).sum() == 3 * (~r.brdf.mask).sum()
    assert tree.attrs["format"] == "goniometer.slices"


def test_bad_side_and_foreign_file(slab_file, tmp_path):
    p, _ = slab_file
    with pytest.raises(ValueError, match="side"):
        goniometer.open_dataset(p, side="bsdf")
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f.attrs["format"] = "something"
    with pytest.raises(store.StoreError, match="not a goniometer.slices"):
        goniometer.open_dataset(other)


def test_old_file_still_reads():
    with h5py.File(OLD_FILE, "r") as f:  # really the old layout
        assert "incident_phi" not in f["brdf"] and "incident" not in f["energy"]
    r = goniometer.read(OLD_FILE)
    assert r.settings.incident_phi_deg == (0.0, 90.0) and r.brdf.value.shape == (2, 3, 4, 6)
    assert goniometer.describe(OLD_FILE)[0].name == "slab/old"
    ds = goniometer.open_dataset(OLD_FILE)  # incident_phi supplied from /incident/phi_deg
    np.testing.assert_array_equal(ds["incident_phi"].values, [0.0, 90.0])
    tree = goniometer.open_datatree(OLD_FILE)
    np.testing.assert_array_equal(tree["energy/reflected"].values, r.energy["reflected"])


def test_missing_xarray_gives_a_clear_import_error(monkeypatch, slab_file):
    import sys
    monkeypatch.setitem(sys.modules, "xarray", None)
    with pytest.raises(ImportError, match=r"goniometer\[xarray\]"):
        goniometer.open_dataset(slab_file[0])
