"""Named conductors (goniometer.spectral.conductors, data/*.csv): coverage, provenance, and normal-
incidence reflectance against the published table and an independent data set (Mitsuba 3's)."""

from __future__ import annotations

import tomllib
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from goniometer.spectral import NAMED_CONDUCTORS, Spectrum, SpectrumError, named_conductor

DOIS = {"Au": "10.1103/PhysRevB.6.4370", "Ag": "10.1103/PhysRevB.6.4370", "Cu": "10.1103/PhysRevB.6.4370",
        "Al": "10.1364/AO.34.004755"}


def reflectance(n, k):
    return ((n - 1) ** 2 + k**2) / ((n + 1) ** 2 + k**2)


def test_the_four_conductors_are_named():
    assert {"Ag", "Al", "Au", "Cu"} <= set(NAMED_CONDUCTORS)


@pytest.mark.parametrize("name", NAMED_CONDUCTORS)
def test_each_file_covers_the_range_and_states_its_source(name):
    eta, k = named_conductor(name)
    assert isinstance(eta, Spectrum) and isinstance(k, Spectrum)
    assert eta.covers(360.0, 830.0) and k.covers(360.0, 830.0)
    assert eta.wavelength_nm == k.wavelength_nm
    assert DOIS[name] in eta.source and DOIS[name] in k.source
    text = resources.files("goniometer.spectral").joinpath("data", f"{name}.csv").read_text()
    header = "\n".join(line for line in text.splitlines() if line.startswith("#"))
    for needed in (DOIS[name], "refractiveindex.info", "CC0", "Range:"):
        assert needed in header, needed
    lam = np.linspace(360.0, 830.0, 471)
    assert np.all(eta.at(lam) > 0) and np.all(k.at(lam) > 0)


def test_au_nodes_are_johnson_christy_rows():
    # Johnson & Christy 1972, gold (their table, as refractiveindex.info gives it): 2.75 eV (450.9 nm) n = 1.38, k = 1.914;
    # 2.26 eV (548.6 nm) n = 0.43, k = 2.455; 1.88 eV (659.5 nm) n = 0.14, k = 3.697
    eta, k = named_conductor("Au")
    np.testing.assert_array_equal(eta.at([450.9, 548.6, 659.5]), [1.38, 0.43, 0.14])
    np.testing.assert_array_equal(k.at([450.9, 548.6, 659.5]), [1.914, 2.455, 3.697])


def test_au_reflectance_the_familiar_gold_edge():
    eta, k = named_conductor("Au")
    r = reflectance(eta.at([450.0, 550.0, 650.0]), k.at([450.0, 550.0, 650.0]))
    # hand, from the rows above: R(450.9) = 0.408, R(548.6) = 0.787, R(659.5) = 0.963
    np.testing.assert_allclose(r, [0.408, 0.79, 0.957], atol=0.01)
    assert r[0] < 0.45 < 0.75 < r[1] < r[2]


MITSUBA_IOR = None
try:
    import mitsuba  # noqa: F401  (only its data files are read: mitsuba/data/ior/*.spd)

    MITSUBA_IOR = Path(mitsuba.__file__).parent / "data" / "ior"
except ImportError:
    pass


def _mitsuba(name):
    eta = np.loadtxt(MITSUBA_IOR / f"{name}.eta.spd", comments="#")
    k = np.loadtxt(MITSUBA_IOR / f"{name}.k.spd", comments="#")
    return lambda lam: reflectance(np.interp(lam, *eta.T), np.interp(lam, *k.T))


# |R(ours) - R(Mitsuba 3's data)|: independent measurements (Mitsuba's files are luxpop's tables)
# differ by up to 0.06 on gold's absorption edge (550 nm) and by a few 1e-2 elsewhere
@pytest.mark.skipif(MITSUBA_IOR is None, reason="mitsuba (extra 'test') not installed")
@pytest.mark.parametrize("name, lams, atol", [
    ("Au", [450.0, 650.0, 700.0, 800.0], 0.03),
    ("Au", [550.0], 0.07),
    ("Cu", [400.0, 450.0, 500.0, 550.0, 650.0, 700.0, 800.0], 0.03),
    ("Cu", [600.0], 0.04),
    ("Al", list(np.arange(360.0, 831.0, 10.0)), 0.01),
    ("Ag", [500.0, 550.0, 600.0, 650.0, 700.0, 800.0], 0.04),
])
def test_reflectance_agrees_with_mitsubas_data(name, lams, atol):
    eta, k = named_conductor(name)
    ours = reflectance(eta.at(lams), k.at(lams))
    np.testing.assert_allclose(ours, _mitsuba(name)(np.array(lams)), atol=atol)


def test_ag_reflects_above_450nm():
    eta, k = named_conductor("Ag")
    lam = np.linspace(450.0, 830.0, 381)
    assert np.all(reflectance(eta.at(lam), k.at(lam)) > 0.9)


def test_lookup_is_case_insensitive_and_unknown_names_list_the_known():
    assert named_conductor("au") == named_conductor("Au")
    with pytest.raises(SpectrumError, match=r"^layers\[0\]: unknown conductor 'Pt' \(known: Ag, Al, Au, Cu"):
        named_conductor("Pt", "layers[0]")


def test_pyproject_packages_the_csv_files():
    root = Path(__file__).resolve().parents[3]
    config = tomllib.loads((root / "pyproject.toml").read_text())
    assert "data/*.csv" in config["tool"]["setuptools"]["package-data"]["goniometer.spectral"]
