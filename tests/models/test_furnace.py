"""``gonio furnace`` and models.furnace: the OpenPBR white-furnace configurations conserve energy
in the simulation (albedo 1 within its standard error, nothing absorbed, bookkeeping closed),
models' albedo tables have the right shape and come from every registered model, the albedo's
standard error matches the scatter of independent runs, the JSON contract and bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from goniometer import optics
from goniometer.cli import main
from goniometer.run.loop import simulate
from goniometer.run.settings import SimulationSettings
from goniometer.stack import Interface, Medium, Stack, load_toml
from models import registry
from models.compare.albedo import directional_albedo
from models.furnace import ENERGY_TERMS, GRID, INCIDENT_DEG, furnace_settings, run_furnace, simulated_albedo

from goniometer.testing import P_FALSE_ALARM, Z_TOL, chi2_interval

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
    from goniometer.grids.slice_grid import light_direction
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
    lo, hi = chi2_interval(K - 1, 2 * P_FALSE_ALARM)     # P_FALSE_ALARM on each side
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


# ----------------------------------------------------------------------------- spectral runs

EXAMPLES = Path(__file__).resolve().parents[2] / "configs" / "examples"
#: CI-sized spectral runs: two angles, few paths per bin
SPECTRAL_ANGLES = "0,60"
SPECTRAL_RAYS = "2000"


def _spectral_json(capsys, config, *extra: str) -> dict:
    capsys.readouterr()
    assert main(["furnace", str(config), "--json", "--incident", SPECTRAL_ANGLES, "--rays", SPECTRAL_RAYS,
                 "--threads", "1", *extra]) == 0
    return json.loads(capsys.readouterr().out)


def _check_bins(d: dict, bins: int) -> dict:
    """The per-bin table of a spectral --json: its wavelengths, shapes, bookkeeping per bin, and the
    sRGB columns as the colour pipeline's reduction of the bins (returns ``per_bin``)."""
    from goniometer.spectral import combined_stderr, rgb_weights, wavelength_bins
    centres, edges = wavelength_bins(bins)
    sp = d["spectral"]
    assert d["channels"] == f"linear sRGB (D65) of {bins} wavelength bins"
    assert sp["wavelength_bins"] == bins and sp["launches"] == bins // 3
    np.testing.assert_allclose(sp["wavelength_nm"], centres, rtol=0, atol=1e-9)
    per = sp["per_bin"]
    M = len(d["incident_deg"])
    assert set(per["energy"]) == set(ENERGY_TERMS)
    for a in (per["albedo"], per["stderr"], *per["energy"].values(), *per["energy_stderr"].values()):
        assert np.shape(a) == (M, bins)
    e = {k: np.array(v) for k, v in per["energy"].items()}
    np.testing.assert_allclose(sum(e.values()), 1.0, atol=1e-12)           # every bin's bookkeeping closes
    np.testing.assert_allclose(per["albedo"], e["reflected"] + e["transmitted"], rtol=0, atol=0)
    # the table's columns are the bins' linear sRGB: the colour pipeline's weights and its bound
    W = rgb_weights(edges)
    groups = np.arange(bins) % (bins // 3)             # launch k carries bins k, k + B/3, k + 2B/3
    sim = d["simulated"]
    assert np.shape(sim["albedo"]) == np.shape(sim["stderr"]) == (M, 3)
    np.testing.assert_allclose(sim["albedo"], np.array(per["albedo"]) @ W, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(sim["stderr"], combined_stderr(np.array(per["stderr"]), W, groups), rtol=1e-12)
    np.testing.assert_allclose(sim["energy"]["absorbed"], e["absorbed"] @ W, rtol=1e-12, atol=1e-15)
    assert all(np.shape(a) == (M, 3) for a in d["models"].values())
    return per


def test_spectral_gold_json_per_bin_and_in_srgb(capsys):
    """gold-spectral.toml (30 bins) was a broadcast traceback: now sRGB columns, bins in --json, and
    each bin agrees with an independent RGB run of the stack at three of the bins' wavelengths."""
    from goniometer.spectral import wavelength_bins
    d = _spectral_json(capsys, EXAMPLES / "gold-spectral.toml")
    per = _check_bins(d, 30)
    albedo, se = np.array(per["albedo"]), np.array(per["stderr"])
    assert np.all(se > 0) and np.all((albedo > 0.3) & (albedo < 1.0))
    # bins of three different launches, traced again as one RGB run with its own seed: within the
    # combined standard error of the two independent estimates, per bin
    stack, _ = load_toml(EXAMPLES / "gold-spectral.toml")
    picks = (0, 11, 25)
    centres = wavelength_bins(30)[0]
    rgb = run_furnace(stack.at_wavelengths(tuple(float(centres[b]) for b in picks)),
                      furnace_settings(incident_deg=(0.0, 60.0), rays=4000, seed=77, threads=1))
    for c, b in enumerate(picks):
        z = (albedo[:, b] - rgb.albedo[:, c]) / np.hypot(se[:, b], rgb.stderr[:, c])
        assert np.all(np.abs(z) <= Z_TOL), (b, z)
    # gold reflects red, not blue: the sRGB albedo is ordered R > G > B
    sim = np.array(d["simulated"]["albedo"])
    assert np.all((sim[:, 0] > sim[:, 1]) & (sim[:, 1] > sim[:, 2]))


def test_spectral_smooth_gold_is_its_fresnel_reflectance_in_every_bin(tmp_path):
    """Each bin of a smooth gold mirror is the Fresnel reflectance of gold's index at the bin's
    centre, exactly (every path keeps the weight F): the bins are where their wavelengths say."""
    from goniometer.spectral import wavelength_bins
    config = tmp_path / "gold0.toml"
    config.write_text((EXAMPLES / "gold-spectral.toml").read_text().replace("roughness = 0.2", "roughness = 0.0"))
    stack, table = load_toml(config)
    r = run_furnace(stack, furnace_settings(table, incident_deg=(0.0, 60.0), rays=500, wavelength_bins=12,
                                            threads=1))
    centres = wavelength_bins(12)[0]
    eta, kappa = stack.field_values(0, "ior", centres), stack.field_values(0, "extinction", centres)
    for m, t in enumerate((0.0, 60.0)):
        F = optics.np_fresnel_conductor(np.full(12, np.cos(np.radians(t))), eta, kappa)
        np.testing.assert_allclose(r.spectral.albedo[m], F, rtol=1e-12)
    assert np.all(r.spectral.stderr < 1e-7)                 # rounding of the second moment, not noise
    np.testing.assert_allclose(r.spectral.wavelength_nm, centres, rtol=0, atol=0)
    # the figure's panels are the bins' linear sRGB, and say so
    import matplotlib.pyplot as plt
    from models.report.furnace import furnace_figure
    fig = furnace_figure(r)
    try:
        assert [ax.get_title() for ax in fig.axes[:3]] == [f"linear sRGB {c} of 12 wavelength bins" for c in "RGB"]
    finally:
        plt.close(fig)


def test_spectral_soap_film_json_per_bin(capsys):
    d = _spectral_json(capsys, EXAMPLES / "soap-film.toml")
    per = _check_bins(d, 30)
    albedo = np.array(per["albedo"])
    assert np.all((albedo > 0) & (albedo < 0.2))            # a film on varnish over a near-black base
    assert np.ptp(albedo[0]) > 0.01                          # interference: the bins differ
    assert all("thin films" in why or "thin film" in why for n, why in d["skipped"].items() if not n.endswith("-fit"))


def test_spectral_film_white_furnace_conserves_energy_in_every_bin(tmp_path, capsys):
    """The soap film's non-absorbing film and varnish over a white Lambertian, scattering multiply:
    nothing is lost to masking, nothing absorbed in expectation (a clear film's single bookings are
    signed, docs/material-format.md 2.4), so every bin's albedo is 1 within its standard error."""
    config = tmp_path / "film-white.toml"
    text = (EXAMPLES / "soap-film.toml").read_text().replace("albedo = 0.02", "albedo = 1.0")
    config.write_text(text.replace("ior = 1.5\n", "ior = 1.5\nmultiple_scattering = true\n", 1))
    d = _spectral_json(capsys, config, "--wavelength-bins", "9")
    per = _check_bins(d, 9)
    e = {k: np.array(v) for k, v in per["energy"].items()}
    assert np.all(e["masking_loss"] == 0)
    absorbed_se = np.array(per["energy_stderr"]["absorbed"])
    assert np.all(absorbed_se > 0) and np.all(np.abs(e["absorbed"]) <= Z_TOL * absorbed_se)
    albedo, se = np.array(per["albedo"]), np.array(per["stderr"])
    assert np.all(se > 0)                                   # the film's choice varies the weights per bin
    assert np.all(np.abs(albedo - 1.0) <= Z_TOL * se), (albedo, se)


def test_spectral_text_table_says_linear_srgb(capsys):
    assert main(["furnace", str(EXAMPLES / "gold-spectral.toml"), "--incident", SPECTRAL_ANGLES, "--rays",
                 SPECTRAL_RAYS, "--threads", "1"]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert "simulated E (linear sRGB)" in out and "(R G B)" not in out
    assert "columns in linear sRGB (D65) of 30 wavelength bins" in out and "E over the bins [min, max]" in out
    assert "minus the simulation in brackets (linear sRGB; the models read the material's RGB equivalent" in out
    rows = [ln for ln in lines if ln.startswith(("   0.00", "  60.00"))]
    assert len(rows) == 2
    for row in rows:   # theta, 3 x (E, s.e., 4 terms), the bins' [min, max]: not 30 numbers per quantity
        assert len(row.replace("[", " ").replace("]", " ").replace(",", " ").split()) == 1 + 3 * 6 + 2, row


def test_rgb_furnace_table_keeps_its_words(capsys):
    d = _spectral_json(capsys, FURNACE / "metal.toml")
    assert d["channels"] == "R G B" and "spectral" not in d


@pytest.mark.parametrize("edit, extra, expected", [
    (("spectral = true", "spectral = false"), [], "layers[0].film: a thin film needs a spectral run"),
    (None, ["--wavelength-bins", "31"], "--wavelength-bins: 31 must be a multiple of 3"),
])
def test_spectral_bad_input_is_one_line_exit_2(tmp_path, capsys, edit, extra, expected):
    config = tmp_path / "film.toml"
    text = (EXAMPLES / "soap-film.toml").read_text()
    config.write_text(text.replace(*edit) if edit else text)
    assert main(["furnace", str(config), "--rays", "100"] + extra) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("gonio: error: ") and expected in err[-1], err
    assert not any("%" in line for line in err), err   # refused before tracing
