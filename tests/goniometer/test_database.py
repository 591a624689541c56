"""Databases: expansion of the definition, resumable runs, bad input, Dask execution."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from goniometer import store
from goniometer.database import (DatabaseError, check_results_dir, load_database, material_path, material_status,
                                 simulate_database)

ROOT = Path(__file__).resolve().parents[2]
TINY = ROOT / "tests" / "data" / "tiny_database.toml"


def test_bati2019_expands_to_the_60_materials_of_the_paper():
    db = load_database(ROOT / "configs" / "bati2019.toml")
    names = [m.name for m in db.materials]
    assert len(names) == 60 == len(set(names))
    cats = [m.category for m in db.materials]
    assert cats.count("plastic") == 12 and cats.count("metal") == 36 and cats.count("slab") == 12
    m = {x.name: x for x in db.materials}["metal/M2-a0_0.05-a1_0.2"]
    assert m.paper_name == "M2" and m.parametrization == "half"
    assert m.params == {"alpha0": 0.05, "alpha1": 0.2, "tau_name": "C", "tau": [0.05, 0.1, 0.4], "eta1": 1.45}
    layers = m.stack.layers
    assert layers[0].roughness == 0.05 and layers[0].ior == (1.5,) * 3
    assert layers[1].optical_depth == (0.05, 0.1, 0.4)
    assert layers[2].ior == (1.45,) * 3 and layers[2].extinction == (1.0, 0.01, 0.01) and layers[2].roughness == 0.2
    assert {x.parametrization for x in db.materials if x.params["alpha0"] == 0.2} == {"classic"}
    assert {x.parametrization for x in db.materials if x.params["alpha0"] != 0.2} == {"half"}
    slab = {x.name: x for x in db.materials}["slab/S3-a0_0.001-a1_0.001"]
    assert slab.stack.transmits and slab.stack.layers[2].ior == (1.0,) * 3
    assert db.qualities["paper"] == 160_000_000
    assert db.incident_deg == (0.0, 15.0, 30.0, 45.0, 60.0, 70.0, 80.0)


def test_bad_definitions(tmp_path):
    text = TINY.read_text()
    cases = {
        "dup": text.replace('grid = { alpha0 = [0.05, 0.2] }\nvariants = [{ variant = "S1"', 'grid = { alpha0 = [0.05, 0.05] }\nvariants = [{ variant = "S1"'),
        "stack": text.replace('albedo = [0.2, 0.5, 0.8]', 'albedo = [0.2, 1.5, 0.8]'),
        "symbol": text.replace('variants = [{ variant = "P1", tau = "C" }]', 'variants = [{ variant = "P1", tau = "Z" }]'),
    }
    expected = {"dup": "produced twice", "stack": r"P1-a0_0.05: layers\[2\].albedo", "symbol": "not a symbol"}
    for key, t in cases.items():
        p = tmp_path / f"{key}.toml"
        p.write_text(t)
        with pytest.raises(DatabaseError, match=expected[key]):
            load_database(p)


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("db") / "tiny"
    db = load_database(TINY)
    summary = simulate_database(db, out, "quick", threads=2)
    return db, out, summary


def test_run_writes_one_file_per_material_and_skips_them_on_rerun(tiny_run):
    db, out, summary = tiny_run
    assert sorted(summary.simulated) == sorted(m.name for m in db.materials)
    for m in db.materials:
        p = material_path(out, m)
        r = store.read(p)
        assert r.stack == m.stack and r.settings.rays == 30_000 and r.settings.parametrization == m.parametrization
        assert material_status(db, out, m, "quick") == "done"
    assert not (out / ".partial").exists()   # checkpoints and their empty folders are gone
    again = simulate_database(db, out, "quick")
    assert again.simulated == [] and len(again.skipped) == len(db.materials)
    manifest = json.loads((out / "database.json").read_text())
    assert manifest["database"] == "tiny" and manifest["quality"] == "quick"


def test_resume_gives_the_same_bits(tiny_run, tmp_path):
    """An interrupted material resumes from its finished incident directions; the result is
    bit-identical to an uninterrupted run."""
    db, out, _ = tiny_run
    m = db.materials[0]
    fresh = tmp_path / "fresh"
    simulate_database(db, fresh, "quick", only=m.name)
    # simulate an interruption after the first incident direction: keep only its checkpoint
    from goniometer.database import _partial_dir
    from goniometer.tasks import trace_incident
    settings = db.settings_for(m, "quick")
    pdir = _partial_dir(fresh, m)
    pdir.mkdir(parents=True)
    (pdir / "meta.json").write_text(json.dumps({"fingerprint": db.fingerprint(), "quality": "quick", "material": m.name,
                                                "settings": [settings.rays, settings.seed, settings.chunk_rays,
                                                             settings.chunks_per_task]}))
    trace_incident(m.stack, settings, 0).save(pdir / "m00.npz")
    material_path(fresh, m).unlink()
    assert material_status(db, fresh, m, "quick") == "partial"
    s = simulate_database(db, fresh, "quick", only=m.name)
    assert s.resumed == [m.name]
    a, b = store.read(material_path(out, m)), store.read(material_path(fresh, m))
    assert np.array_equal(a.brdf.value, b.brdf.value) and np.array_equal(a.brdf.orders, b.brdf.orders)


def test_results_dir_of_another_database_or_quality_is_refused(tiny_run, tmp_path):
    db, out, _ = tiny_run
    with pytest.raises(DatabaseError, match="quality"):
        check_results_dir(db, out, "other")
    bati = load_database(ROOT / "configs" / "bati2019.toml")
    with pytest.raises(DatabaseError, match="database"):
        check_results_dir(bati, out, "quick")
    stray = tmp_path / "stray"
    stray.mkdir()
    (stray / "x.h5").write_bytes(b"")
    with pytest.raises(DatabaseError, match="not a results directory"):
        simulate_database(db, stray, "quick")
    assert (stray / "x.h5").read_bytes() == b""


def test_corrupted_file_is_reported_and_resimulated_on_request(tiny_run, tmp_path):
    db, out, _ = tiny_run
    work = tmp_path / "work"
    shutil.copytree(out, work)
    m = db.materials[1]
    p = material_path(work, m)
    good = p.read_bytes()
    p.write_bytes(good[: len(good) // 2])
    with pytest.raises(DatabaseError, match="resimulate-corrupted"):
        simulate_database(db, work, "quick")
    assert p.stat().st_size == len(good) // 2  # nothing touched
    s = simulate_database(db, work, "quick", resimulate_corrupted=True)
    assert s.resimulated == [m.name] and s.simulated == [m.name]
    assert np.array_equal(store.read(p).brdf.value, store.read(material_path(out, m)).brdf.value)
    assert list(p.parent.glob(p.name + ".corrupt-*"))  # the damaged file was kept aside


def test_dask_cluster_gives_bit_identical_results(tiny_run, tmp_path):
    distributed = pytest.importorskip("distributed", reason="Dask distributed is a test dependency")
    db, out, _ = tiny_run
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cluster:
        remote = tmp_path / "remote"
        simulate_database(db, remote, "quick", only="slab/*", scheduler=cluster.scheduler_address)
    for m in db.select("slab/*"):
        a, b = store.read(material_path(out, m)), store.read(material_path(remote, m))
        for x, y in ((a.brdf.value, b.brdf.value), (a.btdf.value, b.btdf.value), (a.btdf.stderr, b.btdf.stderr),
                     (a.brdf.orders, b.brdf.orders), (a.energy["absorbed"], b.energy["absorbed"])):
            assert np.array_equal(x, y)


def test_appendix_e_definition_expands_with_d_and_g():
    from pathlib import Path
    from goniometer.database import load_database
    db = load_database(Path(__file__).resolve().parents[2] / "configs" / "appendix-e.toml")
    metals = [m for m in db.materials if m.category == "metal"]
    assert len(metals) == 25 == len(db.materials)
    assert {(m.params["d"], m.params["g"]) for m in metals} == {
        (d, g) for d in (0.5, 1.0, 2.0, 4.0, 8.0) for g in (0.0, 0.3, 0.6, 0.8, 0.9)}
    m = next(x for x in metals if x.params["d"] == 2.0 and x.params["g"] == 0.6)
    top, med, base = m.stack.layers
    assert (top.roughness, top.ior) == (0.0, (1.0, 1.0, 1.0))
    # sigma_t d = (0.2, 0.2, 1.1) d, albedo sigma_s / sigma_t
    assert med.optical_depth == (0.4, 0.4, 2.2) and med.g == 0.6
    assert med.scattering_albedo == pytest.approx((0.5, 0.5, 1 / 1.1), rel=1e-15)
    assert (base.roughness, base.ior, base.extinction) == (0.2, (1.5,) * 3, (3.0, 0.0, 0.0))
    assert db.qualities["demo"] < db.qualities["quick"] < db.qualities["full"]


def test_bati2019_ms_is_the_2019_database_with_multiple_scattering_on_every_interface():
    ss = load_database(ROOT / "configs" / "bati2019.toml")
    ms = load_database(ROOT / "configs" / "bati2019-ms.toml")
    assert ms.name == "bati2019-ms" and len(ms.materials) == 60
    assert [(m.name, m.category, m.params, m.parametrization) for m in ms.materials] == \
           [(m.name, m.category, m.params, m.parametrization) for m in ss.materials]
    assert (ms.incident_deg, ms.resolution, ms.seed, ms.masking, ms.qualities) == \
           (ss.incident_deg, ss.resolution, ss.seed, ss.masking, ss.qualities)
    for a, b in zip(ss.materials, ms.materials):
        assert b.stack == a.stack.with_multiple_scattering()
        assert b.stack.to_json() == a.stack.with_multiple_scattering().to_json() != a.stack.to_json()
    assert ms.fingerprint() != ss.fingerprint()


def test_base_and_multiple_scattering_keys(tmp_path):
    (tmp_path / "sub").mkdir()
    shutil.copy(TINY, tmp_path / "tiny.toml")
    twin = tmp_path / "sub" / "twin.toml"
    twin.write_text('base = "../tiny.toml"\nname = "tiny-ms"\nmultiple_scattering = true\n')
    ss, ms = load_database(TINY), load_database(twin)
    assert ms.name == "tiny-ms" and [m.name for m in ms.materials] == [m.name for m in ss.materials]
    assert all(x.multiple_scattering for m in ms.materials for x in m.stack.layers if hasattr(x, "multiple_scattering"))
    # a table of the derived file replaces the base's; false leaves the stacks as they are
    twin.write_text('base = "../tiny.toml"\nname = "t2"\nmultiple_scattering = false\n[quality]\nq = 7\n')
    t2 = load_database(twin)
    assert t2.qualities == {"q": 7} and t2.materials == ss.materials
    bad = {'base = "../tiny.toml"\n': "name: required",
           'base = "../nope.toml"\nname = "x"\n': "cannot read",
           'base = 3\nname = "x"\n': "base: 3 is not a path",
           'base = "twin2.toml"\nname = "x"\n': "one level of base only",
           'base = "../tiny.toml"\nname = "x"\nmultiple_scattering = "yes"\n': "not a boolean"}
    (tmp_path / "sub" / "twin2.toml").write_text('base = "../tiny.toml"\nname = "y"\n')
    for text, message in bad.items():
        twin.write_text(text)
        with pytest.raises(DatabaseError, match=message):
            load_database(twin)
