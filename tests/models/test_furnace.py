"""``gonio furnace`` and models.furnace: the OpenPBR white-furnace configurations conserve energy
in the simulation (albedo 1 within its standard error, nothing absorbed, bookkeeping closed),
models' albedo tables have the right shape and come from every registered model, the albedo's
standard error matches the scatter of independent runs, the JSON contract and bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from goniometer import optics
from goniometer.cli import main
from goniometer.run import simulate
from goniometer.settings import SimulationSettings
from goniometer.stack import Interface, Medium, Stack, load_toml
from models import registry
from models.compare.albedo import directional_albedo
from models.furnace import ENERGY_TERMS, GRID, INCIDENT_DEG, furnace_settings, run_furnace, simulated_albedo

from tests.conftest import P_FALSE_ALARM, Z_TOL

FURNACE = Path(__file__).resolve().parents[2] / "configs" / "furnace"
CONFIGS = sorted(FURNACE.glob("*.toml"))
#: CI-sized runs: few angles, few rays (the configurations conserve energy path by path)
ANGLES = (0.0, 60.0, 85.0)
RAYS = 2000


def test_the_openpbr_configurations_are_shipped():
    names = {p.stem for p in CONFIGS}
    assert {"metal", "metal-coated", "diffuse", "diffuse-coated", "dielectric", "dielectric-coated"} <= names


def test_white_metal_index_reflects_everything():
    # ior 1e-9 + i 1 (and relative to a coat of 1.6) has F = 1 to double precision at every angle
    cos = np.linspace(0.0, 1.0, 2001)
    for eta0 in (1.0, 1.6):
        F = optics.np_fresnel_conductor(cos, 1e-9 / eta0, 1.0 / eta0)
        assert np.all(F == 1.0)


@pytest.fixture(scope="module")
def runs():
    out = {}
    for p in CONFIGS:
        stack, table = load_toml(p)
        out[p.stem] = (stack, run_furnace(stack, furnace_settings(table, incident_deg=ANGLES, rays=RAYS, threads=1)))
    return out


@pytest.mark.parametrize("name", [p.stem for p in CONFIGS])
def test_white_furnace_conserves_energy(runs, name):
    stack, r = runs[name]
    assert r.albedo.shape == r.stderr.shape == (len(ANGLES), 3)
    # bookkeeping: every unit of incident flux is reflected, transmitted, absorbed, lost to
    # masking, booked by roulette or stopped by the cap
    total = sum(r.energy[k] for k in ENERGY_TERMS)
    np.testing.assert_allclose(total, 1.0, atol=1e-12)
    # nothing absorbs and the interfaces scatter multiply: albedo 1 within its standard error
    assert np.all(r.energy["absorbed"] == 0.0)
    assert np.all(r.energy["masking_loss"] == 0.0)
    assert np.all(np.abs(r.albedo - 1.0) <= Z_TOL * r.stderr + 1e-12), (r.albedo, r.stderr)
    np.testing.assert_allclose(r.albedo, r.energy["reflected"] + r.energy["transmitted"], rtol=0, atol=0)
    if stack.transmits:
        assert np.all(r.energy["transmitted"] > 0)
    else:
        assert np.all(r.energy["transmitted"] == 0)


@pytest.mark.parametrize("name", [p.stem for p in CONFIGS])
def test_every_registered_model_is_evaluated_or_skipped(runs, name):
    stack, r = runs[name]
    assert set(r.models.albedo) | set(r.models.skipped) == set(registry.catalogue())
    assert not set(r.models.albedo) & set(r.models.skipped)
    for model, a in r.models.albedo.items():
        assert a.shape == (len(ANGLES), 3) and np.all(np.isfinite(a)) and np.all(a >= 0), model
        sides = r.models.sides[model]
        assert tuple(sides) == (("brdf", "btdf") if stack.transmits else ("brdf",))
        np.testing.assert_allclose(sum(sides.values()), a, rtol=0, atol=0)
    for model, reason in r.models.skipped.items():
        assert isinstance(reason, str) and reason, model


def test_models_are_taken_up_on_the_shipped_configurations(runs):
    # the metal and the glossy-diffuse configurations are what the harness's models represent
    assert {"ww09", "belcour-fwd", "multilayer-lut"} <= set(runs["metal-coated"][1].models.albedo)
    assert "multilayer-lut" in runs["diffuse"][1].models.albedo
    assert "belcour-aniso" in runs["metal-anisotropic"][1].models.albedo


@pytest.mark.parametrize("name", ["metal-coated", "metal-anisotropic", "diffuse"])
def test_model_quadrature_has_converged(runs, name):
    # doubling the Gauss-Legendre order changes no model's albedo by more than 1e-5: 100 times
    # below the standard error of a default run (1e5 rays: ~1e-3 for an albedo that varies per
    # path); table-driven models (multilayer-lut: linear interpolation) converge slowest
    from goniometer.slices import light_direction
    stack, r = runs[name]
    for model in r.models.albedo:
        m = registry.get(model)
        for t in (0.0, 85.0):
            a8 = directional_albedo(m, stack, light_direction(t), "brdf", order=8)
            a16 = directional_albedo(m, stack, light_direction(t), "brdf", order=16)
            np.testing.assert_allclose(a8, a16, atol=1e-5, err_msg=f"{model} at {t}")


def test_a_smooth_interface_skips_every_model():
    # a smooth coat over the white metal: the coated-base models would represent it, but its
    # Dirac lobe is no integrable function
    stack = Stack("smooth", (Interface(0.0, (1.5,) * 3), Interface(0.3, (1e-9,) * 3, (1.0,) * 3, multiple_scattering=True)))
    r = run_furnace(stack, furnace_settings(incident_deg=(30.0,), rays=500, threads=1))
    assert not r.models.albedo
    assert "perfectly smooth" in r.models.skipped["ww09"] and "layers[0]" in r.models.skipped["ww09"]
    np.testing.assert_allclose(r.albedo, 1.0, atol=1e-12)    # nothing is absorbed or lost


def test_albedo_standard_error_matches_the_scatter_of_independent_runs():
    # an absorbing slab: reflected and transmitted both vary; K independent seeds scatter about
    # their mean as the standard error says (chi-square with K - 1 degrees of freedom, both tails)
    stack = Stack("slab", (Interface(0.3, (1.5,) * 3), Medium((0.3, 0.6, 1.2)), Interface(0.2, (1.2,) * 3)))
    K, n = 24, 4000
    albedo, stderr = [], []
    for seed in range(K):
        s = SimulationSettings(incident_deg=(40.0,), rays=n, resolution=GRID[1], parametrization=GRID[0],
                               seed=seed + 1, threads=1)
        a, se = simulated_albedo(simulate(stack, s))
        albedo.append(a[0])
        stderr.append(se[0])
    albedo, stderr = np.array(albedo), np.array(stderr)
    assert np.all(stderr > 0)
    sigma = np.sqrt(np.mean(stderr ** 2, axis=0))
    chi2 = np.sum(((albedo - albedo.mean(axis=0)) / sigma) ** 2, axis=0)
    lo, hi = stats.chi2.ppf(P_FALSE_ALARM, K - 1), stats.chi2.isf(P_FALSE_ALARM, K - 1)
    assert np.all((chi2 > lo) & (chi2 < hi)), (chi2, lo, hi)


def test_settings_layering():
    s = furnace_settings()
    assert s.incident_deg == INCIDENT_DEG and s.rays == 100_000 and s.resolution == GRID[1]
    s = furnace_settings({"rays": 500, "incident_deg": [10, 20], "resolution": [90, 360]}, seed=3)
    assert s.rays == 500 and s.incident_deg == (10.0, 20.0) and s.seed == 3 and s.resolution == GRID[1]
    s = furnace_settings({"rays": 500}, incident_deg=(5.0,), rays=7)
    assert s.rays == 7 and s.incident_deg == (5.0,) and s.incident_phi_deg == (0.0,)


# ----------------------------------------------------------------------------- the command

def test_cli_json_contract(tmp_path, capsys):
    png = tmp_path / "e.png"
    assert main(["furnace", str(FURNACE / "dielectric.toml"), "--json", "--incident", "0,45:90", "--rays", "600",
                 "--seed", "5", "--threads", "1", "--plot", str(png)]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["incident_deg"] == [0.0, 45.0] and d["incident_phi_deg"] == [0.0, 90.0]
    sim = d["simulated"]
    assert np.shape(sim["albedo"]) == np.shape(sim["stderr"]) == (2, 3)
    assert set(sim["energy"]) == set(ENERGY_TERMS)
    assert all(np.shape(v) == (2, 3) for v in sim["energy"].values())
    assert sim["rays"] == 600 and sim["seed"] == 5
    np.testing.assert_allclose(sim["albedo"], 1.0, atol=1e-12)
    assert set(d["models"]) | set(d["skipped"]) == set(registry.catalogue())
    assert all(np.shape(a) == (2, 3) for a in d["models"].values())
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_cli_text_table(capsys):
    assert main(["furnace", str(FURNACE / "metal-coated.toml"), "--incident", "30", "--rays", "500",
                 "--threads", "1"]) == 0
    out = capsys.readouterr().out
    assert "furnace/metal-coated" in out and "simulated E" in out
    assert "ww09" in out and "skipped belcour-btdf:" in out


@pytest.mark.parametrize("extra, expected", [
    (["--incident", "90"], "--incident: 90 is outside [0, 90)"),
    (["--incident", "a"], "--incident: 'a' is not a number"),
    (["--rays", "0"], "--rays: 0 is outside"),
    (["--plot", "x.pdf"], "--plot: 'x.pdf' must name a .png file"),
    (["--plot", "/no/such/dir/e.png"], "does not exist"),
])
def test_cli_bad_input_is_one_line_exit_2(extra, expected, capsys):
    assert main(["furnace", str(FURNACE / "metal.toml")] + extra) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("gonio: error: ") and expected in err and "\n" not in err, err


def test_cli_missing_or_invalid_file(tmp_path, capsys):
    assert main(["furnace", str(tmp_path / "missing.toml")]) == 2
    assert "missing.toml" in capsys.readouterr().err
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "b"\n[[layers]]\ntype = "interface"\nroughness = 2\nior = 1.5\n')
    assert main(["furnace", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert "layers[0].roughness" in err and "\n" not in err
