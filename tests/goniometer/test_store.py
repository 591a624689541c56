"""The HDF5 contract of docs/slices-format.md, dimension scales for general tools, atomic writes."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

from goniometer.files import slices as store
from goniometer.run.settings import SimulationSettings
from goniometer.run.loop import simulate


@pytest.fixture(scope="module")
def slab_file(tmp_path_factory):
    from goniometer.stack import Interface, Medium, Stack
    st = Stack("slab/S1", (Interface(0.05, (1.5,) * 3), Medium((0.05, 0.1, 0.4)), Interface(0.2, (1.0,) * 3)), "slab")
    r = simulate(st, SimulationSettings(incident_deg=(0.0, 30.0, 60.0), rays=20_000, resolution=(18, 36),
                                        parametrization="half", max_order=4))
    p = tmp_path_factory.mktemp("h5") / "slab.h5"
    store.write(p, r)
    return p, r


def test_file_has_every_dataset_and_attribute_of_the_contract(slab_file):
    p, r = slab_file
    M, K, nt, nph = 3, 4, 18, 36
    with h5py.File(p, "r") as f:
        assert f.attrs["format"] == "goniometer.slices" and f.attrs["format_version"] == 1
        assert f.attrs["software"].startswith("goniometer") and "T" in f.attrs["created"]
        assert f["material"].attrs["name"] == "slab/S1" and f["material"].attrs["category"] == "slab"
        assert json.loads(f["material/config"][()])["layers"][2]["ior"] == 1.0
        assert f["incident/theta_deg"].shape == (M,) and f["incident/phi_deg"].dtype == np.float64
        sim = f["simulation"].attrs
        for k in ("rays_per_slice", "seed", "masking", "max_order", "elapsed_s", "threads"):
            assert k in sim
        assert sim["max_order"] == K and sim["masking"] == "separable" and sim["rays_per_slice"] == 20_000
        for side in ("brdf", "btdf"):
            g = f[side]
            assert g.attrs["parametrization"] == "half" and g.attrs["n_theta"] == nt and g.attrs["n_phi"] == nph
            assert g["value"].shape == (M, 3, nt, nph) and g["value"].dtype == np.float64
            assert g["stderr"].shape == (M, 3, nt, nph) and g["stderr"].dtype == np.float64
            assert g["orders"].shape == (M, K, 3, nt, nph) and g["orders"].dtype in (np.float32, np.float64)
            assert g["mask"].shape == (M, nt, nph) and g["mask"].dtype == bool
            assert g["proj_solid_angle"].shape == (M, nt, nph) and g["proj_solid_angle"].dtype == np.float64
            assert g["value"].attrs["units"] == "1/sr"
        for k in ("reflected", "transmitted", "absorbed", "masking_loss"):
            assert f["energy"][k].shape == (M, 3)


def test_read_round_trip(slab_file):
    p, r = slab_file
    back = store.read(p)
    assert back.stack == r.stack
    assert back.settings.incident_deg == r.settings.incident_deg
    np.testing.assert_array_equal(back.brdf.value, r.brdf.value)
    np.testing.assert_array_equal(back.btdf.stderr, r.btdf.stderr)
    np.testing.assert_allclose(back.btdf.orders, r.btdf.orders, rtol=1e-6)  # stored as float32
    for k in r.energy:
        np.testing.assert_array_equal(back.energy[k], r.energy[k])


def test_one_chunk_per_incident_direction_and_lossless(slab_file):
    # issue 34: the cell datasets are chunked one incident direction per chunk under gzip + shuffle
    # (lossless: every array reads back bit for bit)
    p, r = slab_file
    with h5py.File(p, "r") as f:
        for side, sd in (("brdf", r.brdf), ("btdf", r.btdf)):
            g = f[side]
            for name in ("value", "stderr", "orders", "mask", "proj_solid_angle"):
                assert g[name].chunks == (1,) + g[name].shape[1:], (side, name)
                assert g[name].compression == "gzip" and g[name].shuffle, (side, name)
            assert g["value"][()].tobytes() == sd.value.tobytes()
            assert g["stderr"][()].tobytes() == sd.stderr.tobytes()
            assert g["proj_solid_angle"][()].tobytes() == sd.proj_solid_angle.tobytes()
            assert g["orders"][()].tobytes() == sd.orders.astype(g["orders"].dtype).tobytes()


def test_xarray_opens_the_groups(slab_file):
    xr = pytest.importorskip("xarray")
    pytest.importorskip("h5netcdf")
    p, r = slab_file
    ds = xr.open_dataset(p, group="btdf", engine="h5netcdf")
    assert ds["value"].dims == ("incident", "channel", "theta", "phi")
    assert ds["orders"].dims == ("incident", "order", "channel", "theta", "phi")
    assert list(ds["channel"].values) == ["R", "G", "B"]
    np.testing.assert_array_equal(ds["incident"].values, [0.0, 30.0, 60.0])
    np.testing.assert_array_equal(ds["value"].values, r.btdf.value)
    assert ds["value"].attrs["units"] == "1/sr" and ds["theta"].attrs["units"] == "deg"
    ds.close()


def test_write_is_atomic(tmp_path, slab_file):
    _, r = slab_file
    target = tmp_path / "out.h5"
    target.write_bytes(b"previous content")
    with pytest.raises(RuntimeError):
        with store.atomic_path(target) as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("interrupted")
    assert target.read_bytes() == b"previous content"
    assert list(tmp_path.iterdir()) == [target]
    store.write(target, r)
    assert store.read(target).stack == r.stack


def test_unreadable_files_raise_store_error(tmp_path):
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"not hdf5 at all")
    with pytest.raises(store.StoreError, match="bad.h5"):
        store.read(bad)
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f.attrs["format"] = "something else"
    with pytest.raises(store.StoreError, match="not a goniometer.slices file"):
        store.read(tmp_path / "other.h5")
    with pytest.raises(store.StoreError, match="no such file"):
        store.read(tmp_path / "missing.h5")


def test_check_writable(tmp_path):
    with pytest.raises(store.StoreError, match="does not exist"):
        store.check_writable(tmp_path / "no" / "x.h5")
    with pytest.raises(store.StoreError, match="directory"):
        store.check_writable(tmp_path)


def test_versions_up_to_ours_read_newer_refused(tmp_path, slab_file):
    # docs/file-identity.md: a reader accepts every format version up to its own and refuses a
    # newer one with a message naming both
    p, _ = slab_file
    newer = tmp_path / "newer.h5"
    newer.write_bytes(p.read_bytes())
    with h5py.File(newer, "r+") as f:
        f.attrs["format_version"] = store.FORMAT_VERSION + 1
    with pytest.raises(store.StoreError, match=rf"format version {store.FORMAT_VERSION + 1} is newer.*"
                                               rf"versions 1 to {store.FORMAT_VERSION}"):
        store.read(newer)
    assert store.read(p).stack.name == "slab/S1"
