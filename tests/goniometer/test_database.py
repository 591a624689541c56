"""Databases: expansion of the definition, resumable runs, bad input, Dask execution."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from goniometer.files import slices as store
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


@pytest.mark.parametrize("old, new, message", [
    ("quick = 30_000", "quick = true", r"quality\.quick: True is not a positive integer \(rays per slice\)$"),
    ("quick = 30_000", "quick = 3e4", r"quality\.quick: 30000\.0 is not a positive integer"),
    ("quick = 30_000", "quick = 0", r"quality\.quick: 0 is not a positive integer"),
    ('name = "tiny"', 'name = "tiny"\ndescription = 3', r"description: 3 is not a string$"),
])
def test_qualities_and_description_of_the_wrong_type_are_refused(tmp_path, old, new, message):
    """A quality's ray count is a positive integer (a boolean is not one), a description a string:
    one DatabaseError line naming the key, never a conversion."""
    text = TINY.read_text()
    assert old in text
    p = tmp_path / "bad.toml"
    p.write_text(text.replace(old, new, 1))
    with pytest.raises(DatabaseError, match=message) as e:
        load_database(p)
    assert str(e.value).startswith(f"{p}: ") and "\n" not in str(e.value)


_RULE = r'\{ classic_if_alpha0_at_least = a, otherwise = "half" \}'
_NAMES = "classic, half"


@pytest.mark.parametrize("replace, message", [
    # integers and names are SimulationSettings' to check: nothing is converted on the way
    ([("seed = 3", "seed = 1.7")], r"seed: 1\.7 is not an integer in \[0, 9223372036854775807\]$"),
    ([("seed = 3", 'seed = "3"')], r"seed: '3' is not an integer in \[0, 9223372036854775807\]$"),
    ([("seed = 3", "seed = true")], r"seed: True is not an integer in \[0, 9223372036854775807\]$"),
    ([('masking = "separable"', "masking = 1")], r"masking: 1 is not one of separable, height-correlated$"),
    ([("resolution = [9, 18]", "resolution = [9.0, 18]")], r"resolution \(n_theta\): 9\.0 is not an integer in "),
    # the lists and the parametrization rule are the definition's
    ([("incident_deg = [0, 60]", "incident_deg = 45")],
     r"incident_deg: 45 is not a list of elevations \(numbers of degrees, each in \[0, 90\)\)$"),
    ([("incident_deg = [0, 60]", 'incident_deg = "45"')], r"incident_deg: '45' is not a list of elevations"),
    ([("incident_deg = [0, 60]", 'incident_deg = [0, "60"]')],
     r"incident_deg: '60' is not a number \(elevations in degrees, each in \[0, 90\)\)$"),
    ([("incident_deg = [0, 60]", "incident_deg = [true]")], r"incident_deg: True is not a number"),
    ([("resolution = [9, 18]", "resolution = 5")], r"resolution: 5 is not \[n_theta, n_phi\] \(a list of two integers\)$"),
    ([("resolution = [9, 18]", 'resolution = "9x18"')], r"resolution: '9x18' is not \[n_theta, n_phi\]"),
    ([('otherwise = "half"', "otherwise = 4")], rf"parametrization\.otherwise: 4 is not one of {_NAMES}$"),
    # the first material is classic: its settings alone do not show the others' parametrization
    ([("alpha0 = [0.05, 0.2]", "alpha0 = [0.2, 0.05]"), ('otherwise = "half"', 'otherwise = "sphere"')],
     rf"parametrization\.otherwise: 'sphere' is not one of {_NAMES}$"),
    ([("classic_if_alpha0_at_least = 0.2", 'classic_if_alpha0_at_least = "0.2"')],
     r"parametrization\.classic_if_alpha0_at_least: '0\.2' is not a number \(the alpha0 from which materials use "
     r"classic slices\)$"),
    ([('otherwise = "half"', 'otherwise = "half", above = 0.3')],
     rf"parametrization\.above: unknown key of the rule {_RULE}$"),
    ([("classic_if_alpha0_at_least = 0.2, ", "")],
     rf"parametrization\.classic_if_alpha0_at_least: required in the rule {_RULE}$"),
    ([("parametrization = { classic_if_alpha0_at_least = 0.2, otherwise = \"half\" }", 'parametrization = "rgl"')],
     rf"parametrization: 'rgl' is not one of {_NAMES} or the rule {_RULE}$"),
    ([("parametrization = { classic_if_alpha0_at_least = 0.2, otherwise = \"half\" }", "parametrization = 3")],
     rf"parametrization: 3 is not one of {_NAMES} or the rule {_RULE}$"),
    # a definition that expands to no material is still checked
    ([("alpha0 = [0.05, 0.2]", "alpha0 = []"), ("alpha0 = [0.2], alpha1", "alpha0 = [], alpha1"),
      ("seed = 3", "seed = 2.5")], r"seed: 2\.5 is not an integer in "),
])
def test_simulation_values_of_the_wrong_type_are_refused(tmp_path, replace, message):
    """One DatabaseError line naming the [simulation] field and what it takes, never a conversion."""
    text = TINY.read_text()
    for old, new in replace:
        assert old in text, old
        text = text.replace(old, new, 1)
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(DatabaseError, match=message) as e:
        load_database(p)
    assert str(e.value).startswith(f"{p}: simulation") and "\n" not in str(e.value)


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


def test_resume_gives_the_same_bits(tiny_run, tmp_path, monkeypatch):
    """An interrupted material resumes from its checkpointed incident directions: they are loaded,
    not traced again, and the result is bit-identical to an uninterrupted run."""
    import goniometer.run.loop
    db, out, _ = tiny_run
    m = db.materials[0]
    work = tmp_path / "work"
    _interrupt_in_the_second_direction(db, m, work)
    traced: list[int] = []
    trace = goniometer.run.loop.trace_incident

    def counted(stack, settings, k, *args, **kwargs):
        traced.append(k)
        return trace(stack, settings, k, *args, **kwargs)

    monkeypatch.setattr(goniometer.run.loop, "trace_incident", counted)
    s = simulate_database(db, work, "quick", only=m.name)
    assert s.resumed == [m.name] and s.simulated == [m.name]
    assert traced == [1]   # direction 0 came from its checkpoint (a discarded checkpoint traces [0, 1])
    _assert_same_result(store.read(material_path(work, m)), store.read(material_path(out, m)))
    assert material_status(db, work, m, "quick") == "done" and not (work / ".partial").exists()


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


# ----------------------------------------------------------------------------- spectral databases

TINY_SPECTRAL = ROOT / "tests" / "data" / "tiny_spectral_database.toml"

#: the fingerprints of the shipped (RGB) definitions, computed before definitions could be spectral:
#: they pin the fingerprint of existing databases, which their users' results directories record
#: (database.json) and must keep matching (docs/database-format.md section 2.2)
SHIPPED_FINGERPRINTS = {
    "configs/bati2019.toml": "f2442e3041cc11a2",
    "configs/bati2019-ms.toml": "f3d50e3df610a871",
    "configs/anisotropic.toml": "637ad1bb86849be4",
    "configs/appendix-e.toml": "9e92b68acaeb0e96",
    "configs/production.toml": "eff7c052c4da1bb2",
    "configs/production-demo.toml": "236ec79ed5c263e6",
    "tests/data/tiny_database.toml": "49e640ebec4bb3fa",
}


def test_fingerprints_of_existing_databases_are_unchanged():
    for path, fingerprint in SHIPPED_FINGERPRINTS.items():
        db = load_database(ROOT / path)
        assert not db.spectral and db.fingerprint() == fingerprint, path


def test_every_shipped_definition_loads():
    """Every definition under configs/ and tests/data/ passes the [simulation] key check."""
    import tomllib

    def is_definition(p: Path) -> bool:
        data = tomllib.loads(p.read_text())
        return "family" in data or str(data.get("base", "")).endswith(".toml")

    paths = [p for p in sorted((ROOT / "configs").rglob("*.toml")) + sorted((ROOT / "tests" / "data").glob("*.toml"))
             if is_definition(p)]
    assert {ROOT / p for p in SHIPPED_FINGERPRINTS} <= set(paths)
    for p in paths:
        assert load_database(p).materials, p


def test_spectral_keys_enter_the_fingerprint_and_the_settings(tmp_path):
    db = load_database(TINY_SPECTRAL)
    assert db.spectral is True and db.wavelength_bins == 6
    s = db.settings_for(db.materials[0], "quick", threads=1)
    assert s.spectral and s.wavelength_bins == 6 and s.n_channels == 6 and s.rays == 2000
    text = TINY_SPECTRAL.read_text()
    rgb = tmp_path / "rgb.toml"
    rgb.write_text(text.replace("spectral = true\nwavelength_bins = 6\n", ""))
    default_bins = tmp_path / "bins30.toml"
    default_bins.write_text(text.replace("wavelength_bins = 6\n", ""))
    a, b = load_database(rgb), load_database(default_bins)
    assert not a.spectral and not a.settings_for(a.materials[0], "quick").spectral
    assert b.spectral and b.wavelength_bins == 30 == g_default_bins()
    assert len({db.fingerprint(), a.fingerprint(), b.fingerprint()}) == 3
    # an RGB definition's fingerprint is the document without the spectral keys (as before they existed)
    spelled = tmp_path / "spelled.toml"
    spelled.write_text(text.replace("spectral = true\nwavelength_bins = 6\n", "spectral = false\n"))
    assert load_database(spelled).fingerprint() == a.fingerprint()


def g_default_bins() -> int:
    from goniometer.run.settings import SimulationSettings
    return SimulationSettings().wavelength_bins


@pytest.mark.parametrize("replace, message", [
    (("spectral = true", 'spectral = "yes"'), r"simulation: spectral: 'yes' is not a boolean \(true or false\)$"),
    (("wavelength_bins = 6", "wavelength_bins = 0"), r"simulation: wavelength_bins: 0 is outside \[3, 471\]$"),
    (("wavelength_bins = 6", "wavelength_bins = 7"), r"simulation: wavelength_bins: 7 must be a multiple of 3"),
    (("wavelength_bins = 6", "wavelength_bins = 6.0"),
     r"simulation: wavelength_bins: 6.0 is not an integer in \[3, 471\]$"),
    (("spectral = true", "spectral = false"), r"simulation: wavelength_bins: goes with spectral = true"),
    (("spectral = true\n", ""), r"simulation: wavelength_bins: goes with spectral = true"),
    (("seed = 7", "seed = 7\nrays = 5"),
     r"simulation\.rays: unknown key \(allowed: incident_deg, masking, parametrization, polarized, resolution, seed, "
     r"spectral, wavelength_bins\)$"),
    (("conductor = \"Au\"", "ior = { wavelength_nm = [400, 700], value = [0.2, 0.3] }, extinction = 3.0"),
     r": metal/gold-a0_0\.2: layers\[0\]\.ior: the table covers 400-700 nm but the run's wavelength bins need"),
])
def test_bad_spectral_definitions(tmp_path, replace, message):
    p = tmp_path / "bad.toml"
    text = TINY_SPECTRAL.read_text()
    assert replace[0] in text
    p.write_text(text.replace(*replace))
    with pytest.raises(DatabaseError, match=message) as e:
        load_database(p)
    assert str(e.value).startswith(f"{p}: ") and "\n" not in str(e.value)


def test_unknown_simulation_key_of_a_base_names_the_base(tmp_path):
    base = tmp_path / "base.toml"
    base.write_text(TINY.read_text().replace("seed = 3", "seed = 3\nmax_order = 4"))
    twin = tmp_path / "twin.toml"
    twin.write_text('base = "base.toml"\nname = "twin"\n')
    with pytest.raises(DatabaseError, match=rf"^{base}: simulation\.max_order: unknown key"):
        load_database(twin)
    (tmp_path / "x.toml").write_text(TINY.read_text().replace("[simulation]\n", "simulation = 3\n[sim]\n", 1))
    with pytest.raises(DatabaseError, match="unknown key"):
        load_database(tmp_path / "x.toml")


def test_a_thin_film_in_an_rgb_database_is_refused_at_load(tmp_path):
    text = TINY_SPECTRAL.read_text().replace("spectral = true\nwavelength_bins = 6\n", "").replace(
        '{ type = "interface", roughness = "$alpha0", conductor = "Au" },',
        '{ type = "interface", roughness = "$alpha0", ior = 1.5, film = { thickness_nm = 400, ior = 1.33 } },\n'
        '    { type = "lambertian", albedo = 0.02 },').replace('category = "metal"', 'category = "plastic"')
    p = tmp_path / "film.toml"
    p.write_text(text)
    with pytest.raises(DatabaseError, match=r"metal/gold-a0_0\.2: layers\[0\]\.film: a thin film needs a spectral "
                                            r"run \(set spectral = true in \[simulation\]"):
        load_database(p)
    p.write_text(text.replace('parametrization = "classic"', 'parametrization = "classic"\nspectral = true'))
    assert load_database(p).spectral


@pytest.fixture(scope="module")
def spectral_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("db") / "spectral"
    db = load_database(TINY_SPECTRAL)
    summary = simulate_database(db, out, "quick", threads=2)
    return db, out, summary


def _assert_same_result(a, b) -> None:
    """Every array of two SimulationResults is bit-identical."""
    for x, y in [(a.brdf, b.brdf)] + ([(a.btdf, b.btdf)] if a.btdf is not None or b.btdf is not None else []):
        for name in ("value", "stderr", "stderr_internal", "orders", "mask", "proj_solid_angle"):
            assert np.array_equal(getattr(x, name), getattr(y, name)), name
    for x, y in ((a.energy, b.energy), (a.energy_stderr, b.energy_stderr)):
        assert x.keys() == y.keys() and all(np.array_equal(x[k], y[k]) for k in x)
    for name in ("roulette", "capped", "capped_paths", "mean_events", "theta_deg", "phi_deg"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


def test_a_spectral_database_gives_the_bits_of_simulate(spectral_run, tmp_path):
    """Each material's file holds what goniometer.run.loop.simulate gives for its stack and settings
    (written as any slices file is: the bounce orders as float32, docs/slices-format.md)."""
    from goniometer.run.loop import simulate
    db, out, summary = spectral_run
    assert sorted(summary.simulated) == sorted(m.name for m in db.materials)
    for m in db.materials:
        f = store.read(material_path(out, m))
        assert f.settings.spectral and f.settings.wavelength_bins == 6 and f.brdf.value.shape == (2, 6, 6, 12)
        assert (f.btdf is not None) == m.stack.transmits
        ref = simulate(m.stack, db.settings_for(m, "quick"))
        assert np.array_equal(f.brdf.value, ref.brdf.value) and np.array_equal(f.brdf.stderr, ref.brdf.stderr)
        store.write(tmp_path / "ref.h5", ref)
        _assert_same_result(f, store.read(tmp_path / "ref.h5"))
        assert material_status(db, out, m, "quick") == "done"
    manifest = json.loads((out / "database.json").read_text())
    assert manifest["spectral"] is True and manifest["wavelength_bins"] == 6
    assert manifest["fingerprint"] == db.fingerprint()
    assert not (out / ".partial").exists()
    again = simulate_database(db, out, "quick")
    assert again.simulated == [] and sorted(again.skipped) == sorted(m.name for m in db.materials)
    # the RGB twin of the definition is another database: its run refuses the directory
    rgb = dataclasses.replace(db, spectral=False, wavelength_bins=30)
    with pytest.raises(DatabaseError, match="database definition"):
        check_results_dir(rgb, out, "quick")


class _Interrupted(Exception):
    pass


def _interrupt_in_the_second_direction(db, m, work) -> int:
    """Simulate material ``m`` of ``db`` into ``work`` and stop it, from its progress callback, in
    its second incident direction: the first is checkpointed, no file written. Returns the paths of
    one direction."""
    from goniometer.database import checkpointed_incidents, paths_per_incident
    per = paths_per_incident(db, m, "quick")
    done = []

    def interrupt(n: int) -> None:
        done.append(n)
        if sum(done) > per:
            raise _Interrupted()

    with pytest.raises(_Interrupted):
        simulate_database(db, work, "quick", only=m.name, progress=interrupt)
    assert not material_path(work, m).exists() and checkpointed_incidents(work, m) == 1
    assert material_status(db, work, m, "quick") == "partial"
    return per


def test_an_interrupted_spectral_material_resumes_to_the_same_bits(spectral_run, tmp_path):
    db, out, _ = spectral_run
    m = db.select("metal/*")[0]
    work = tmp_path / "work"
    per = _interrupt_in_the_second_direction(db, m, work)
    assert per == 2 * db.qualities["quick"]    # gold: 6 bins in 2 launches of 3 wavelengths
    seen: list[int] = []
    s = simulate_database(db, work, "quick", only=m.name, progress=seen.append)
    assert s.resumed == [m.name] and s.simulated == [m.name]
    assert seen[0] == per and sum(seen) == 2 * per   # the first direction came from its checkpoint
    _assert_same_result(store.read(material_path(work, m)), store.read(material_path(out, m)))
    assert material_status(db, work, m, "quick") == "done" and not (work / ".partial").exists()


def test_cli_runs_and_lists_a_spectral_database(spectral_run, tmp_path, capsys):
    from goniometer.cli import main
    db, out, _ = spectral_run
    work = tmp_path / "cli"
    shutil.copytree(out, work)
    m = db.select("slab/*")[0]
    material_path(work, m).unlink()
    assert main(["database", "simulate", str(TINY_SPECTRAL), "--out", str(work), "--threads", "2"]) == 0
    assert "1 simulated (0 resumed, 0 re-simulated), 1 already done" in capsys.readouterr().out
    _assert_same_result(store.read(material_path(work, m)), store.read(material_path(out, m)))
    assert main(["database", "simulate", str(TINY_SPECTRAL), "--out", str(work)]) == 0
    assert "0 simulated (0 resumed, 0 re-simulated), 2 already done" in capsys.readouterr().out
    assert main(["database", "list", str(TINY_SPECTRAL), "--out", str(work)]) == 0
    text = capsys.readouterr().out
    assert text.count("[done]") == 2 and "in tiny-spectral (spectral, 6 wavelength bins)" in text


def test_dask_cluster_runs_a_spectral_database_with_the_local_bits(spectral_run, tmp_path):
    distributed = pytest.importorskip("distributed", reason="Dask distributed is a test dependency")
    db, out, _ = spectral_run
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cluster:
        remote = tmp_path / "remote"
        simulate_database(db, remote, "quick", scheduler=cluster.scheduler_address)
    for m in db.materials:
        _assert_same_result(store.read(material_path(out, m)), store.read(material_path(remote, m)))
        assert material_status(db, remote, m, "quick") == "done"


def test_cli_interrupt_words_and_checkpoints_of_another_run(tiny_run, tmp_path, capsys, monkeypatch):
    """Ctrl-C in `gonio database simulate` says what is kept and how to resume (issue 31 item 6);
    a rerun whose materials' runs differ from their checkpoints (a quality's rays changed in the
    definition, another code version) is one line, exit 2, naming the key and both values, and the
    checkpoints keep their bytes; the same command resumes them to an uninterrupted run's bits;
    --restart discards them."""
    import goniometer.run.checkpoints
    import goniometer.cli.common
    import goniometer.cli.database
    from goniometer.cli import main
    from tests.conftest import refused
    from tests.goniometer.resume_helpers import assert_same_datasets, bytes_of, stop_after
    db, out, _ = tiny_run
    first, second = db.select("plastic/*")
    work = tmp_path / "work"
    argv = ["database", "simulate", str(TINY), "--out", str(work), "--only", "plastic/*", "--threads", "2"]
    # interrupted in the second material's second direction (30,000 rays a direction)
    monkeypatch.setattr(goniometer.cli.database, "ResumeAware", stop_after(3 * 30_000))
    capsys.readouterr()
    assert main(argv) == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == (f"gonio: interrupted; 1 of 2 material(s) finished in {work} (1 by this run), checkpoints of 1 "
                       f"unfinished material(s) kept in {work / '.partial'} ({second.name}: 1 of 2 incident "
                       f"direction(s)); rerun the same command to resume")
    assert not any("nothing written" in line for line in err)
    monkeypatch.setattr(goniometer.cli.database, "ResumeAware", goniometer.cli.common.ResumeAware)
    kept = bytes_of(work / ".partial")
    assert sorted(kept) == [f"{second.name}/m00.npz", f"{second.name}/meta.json"]
    # the definition's quick quality changed: the checkpoints are of another run
    changed = tmp_path / "changed.toml"
    changed.write_text(TINY.read_text().replace("quick = 30_000", "quick = 35_000"))
    refused(capsys, ["database", "simulate", changed, "--out", work, "--only", second.name],
            f"{work / '.partial' / second.name}: holds checkpoints of another run (rays: checkpoints 30000, "
            f"this run 35000)", "add --restart to discard them")
    monkeypatch.setattr(goniometer.run.checkpoints, "code_key", lambda: "another version")
    refused(capsys, argv, "written by another version of the simulator code", "add --restart to discard them")
    monkeypatch.setattr(goniometer.run.checkpoints, "code_key", goniometer.run.checkpoints.cache.simulator_key)
    assert bytes_of(work / ".partial") == kept
    # the same command resumes: the uninterrupted run's bits
    assert main(argv) == 0
    assert "1 simulated (1 resumed, 0 re-simulated), 1 already done" in capsys.readouterr().out
    for m in (first, second):
        assert_same_datasets(material_path(work, m), material_path(out, m))
    # checkpoints of another code version: refused, then discarded by --restart
    other = tmp_path / "other"
    monkeypatch.setattr(goniometer.run.checkpoints, "code_key", lambda: "another version")
    _interrupt_in_the_second_direction(db, first, other)
    monkeypatch.setattr(goniometer.run.checkpoints, "code_key", goniometer.run.checkpoints.cache.simulator_key)
    again = ["database", "simulate", str(TINY), "--out", str(other), "--only", first.name]
    refused(capsys, again, "another version of the simulator code")
    assert main([*again, "--restart"]) == 0
    assert "1 simulated (0 resumed, 0 re-simulated)" in capsys.readouterr().out
    assert_same_datasets(material_path(other, first), material_path(out, first))
    assert not (other / ".partial" / first.name).exists()
