"""``gonio invert MEASURED`` (docs/inverse.md, "From a measurement"): lobes fitted to a measured
BRDF at normal incidence, inverted, and the stack simulated against the measurement.

The round trip: a rough gold conductor (alpha 0.2) simulated on a small RGL grid (4 incident
elevations, 16 x 16 nodes, 200,000 rays) and exported as an RGL ``.bsdf`` is the measurement. The
tolerances are docs/inverse.md's, measured over six seeds of that file (largest deviation in
brackets): the fitted energy within :data:`R_RTOL` (0.095 %) of the stack's (Belcour's FGD at normal
incidence), the fitted variance within :data:`SIGMA_RTOL` (0.94 %) of ``f(0.2)``, the retrieved
stack's simulation (1,000,000 rays) within :data:`EXCESS_MAX` (1.2 %) of the measurement's norm
beyond its own noise floor; a gold of alpha 0.22 (+10 %) lies 11 % away. The estimator on the
simulation finds the fitted lobe within ``Z_TOL`` standard errors (0.8).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

import goniometer as g
from goniometer import cli
from goniometer.grids import halfdiff
from goniometer.files.merl import MERL_SCALE
from goniometer.grids.rgl import grid_for
from goniometer.stack import load_toml
from models.belcour import roughness_to_variance
from models.inverse import InverseError, MeasuredRings, fit_measured_lobes, lobe_albedo, lobe_ring_fractions
from models.inverse import invert_measured, simulate_against
from models.inverse.validation import forward_lobes
from goniometer.testing import Z_TOL

ALPHA = 0.2
#: fitted vs the stack's energy, relative (largest of six seeds: 0.095 %)
R_RTOL = 3e-3
#: fitted vs the stack's variance f(alpha), relative (largest of six seeds: 0.94 %)
SIGMA_RTOL = 0.02
#: the retrieved stack's simulation against the measurement, beyond the simulation's noise floor,
#: relative to the measurement's norm (largest of six seeds: 1.2 %; alpha 0.21 gives 6 %)
EXCESS_MAX = 0.025
#: an analytic GGX written as MERL cells, read at normal incidence (largest: 0.08 % in R, 0.06 % in sigma)
MERL_RTOL = 3e-3
SIM_RAYS = "1000000"


def _gold(alpha: float):
    return g.stack_from_dict({"name": "gold", "category": "metal", "layers": [
        {"type": "interface", "roughness": alpha, "ior": [0.2, 0.35, 1.4], "extinction": [3.5, 2.6, 1.9]}]})


@pytest.fixture(scope="module")
def measurement(tmp_path_factory):
    stack = _gold(ALPHA)
    r = g.simulate(stack, g.SimulationSettings.on_rgl_grid(grid_for(stack, 4, 1, 16), rays=200_000, seed=11,
                                                            threads=2))
    return stack, g.export_rgl(r, tmp_path_factory.mktemp("measured") / "gold.bsdf")


@pytest.fixture
def gonio():
    return cli.main


def test_round_trip_of_a_rough_conductor(measurement, gonio, capsys, tmp_path):
    stack, path = measurement
    out = tmp_path / "retrieved.toml"
    assert gonio(["invert", str(path), "--base", "conductor", "--simulate", "--rays", SIM_RAYS, "--threads", "2",
                  "--json", "--out", str(out)]) == 0
    d = json.loads(capsys.readouterr().out)
    R_true, _ = forward_lobes(stack, [[0]])[0]
    fit = d["measurement"]["fit"]
    assert fit["lobes"] == 1 and fit["rings"] == 63
    lobe = fit["fitted"][0]
    np.testing.assert_allclose(lobe["R"], R_true, rtol=R_RTOL)
    np.testing.assert_allclose(lobe["sigma"], roughness_to_variance(ALPHA), rtol=SIGMA_RTOL)
    # the request is the fitted lobe; the retrieved conductor has its roughness
    assert d["achievable"] and d["lobes"][0]["R_forward"] == pytest.approx(lobe["R"], rel=1e-6)
    retrieved, _ = load_toml(out)
    assert retrieved.base == "conductor" and len(retrieved.interfaces) == 1
    assert retrieved.layers[0].alpha_xy[0] == pytest.approx(ALPHA, rel=SIGMA_RTOL)
    sim = d["simulation"]
    assert sim["rays"] == int(SIM_RAYS) and sim["cells"] == 63 * 8 - 8
    assert max(sim["relative_excess"]) < EXCESS_MAX, sim
    for c in range(3):      # E[rmse^2] = noise_floor^2 + excess^2
        assert sim["rmse"][c] ** 2 == pytest.approx(sim["noise_floor"][c] ** 2 + sim["excess_rmse"][c] ** 2, rel=1e-9)
        assert sim["relative_rmse"][c] == pytest.approx(sim["rmse"][c] / sim["reference_norm"][c])
    s = sim["lobes"][0]
    for key in ("R", "sigma"):
        dev = np.abs(np.subtract(s[f"{key}_simulated"], s[f"{key}_fitted"])) / np.array(s[f"{key}_simulated_stderr"])
        assert np.all(dev < Z_TOL), (key, dev)


def test_a_different_stack_shows_a_larger_error(measurement):
    """The same comparison against the measurement, with a gold 10 % rougher than the one measured."""
    _, path = measurement
    mi = invert_measured(path, 1, base="conductor")
    right = simulate_against(mi.reference, mi.inversion.stack(), mi.lobes, rays=int(SIM_RAYS), seed=2, threads=2)
    wrong = simulate_against(mi.reference, _gold(1.1 * ALPHA), mi.lobes, rays=int(SIM_RAYS), seed=2, threads=2)
    assert max(right["relative_excess"]) < EXCESS_MAX < 2 * EXCESS_MAX < min(wrong["relative_excess"])


def test_the_wrong_number_of_lobes_gives_no_stack(measurement, gonio, capsys, tmp_path):
    """Two lobes in a one-lobe measurement: the sharp one takes the coloured energy of the conductor,
    which a top 1-layer lobe in air cannot have (choice 7): exit 1 with the reason, nothing written."""
    _, path = measurement
    out = tmp_path / "s.toml"
    assert gonio(["invert", str(path), "--base", "conductor", "--lobes", "2", "--out", str(out)]) == 1
    assert "not physically achievable" in capsys.readouterr().err and not out.exists()


EDGES = np.radians(90.0 * (np.arange(64) / 90.0) ** 2)         # the 63 rings of 90 x 8 half slices, < 45 deg


def _rings(lobes) -> MeasuredRings:
    e = np.array([sum(R[c] * lobe_ring_fractions(EDGES, a) for R, a in lobes) for c in range(3)])
    return MeasuredRings(EDGES, e, np.ones(63, dtype=bool), np.ones(63))


def test_two_lobes_are_told_apart_and_one_is_not_two():
    """Exact ring energies of two lobes: two GGX lobes recover them (sharpest first), one leaves a
    large misfit; one lobe fitted with two is refused."""
    truth = [((0.04, 0.04, 0.04), 0.05), ((0.5, 0.3, 0.1), 0.4)]
    two = fit_measured_lobes(_rings(truth), 2)
    np.testing.assert_allclose(two.R, [truth[0][0], truth[1][0]], rtol=1e-4)
    np.testing.assert_allclose(two.alpha, [[0.05] * 3, [0.4] * 3], rtol=1e-4)
    assert np.all(two.misfit < 1e-5)
    lobes = two.lobes()
    assert [lb.layers for lb in lobes] == [1, 1] and lobes[0].sigma < lobes[1].sigma
    assert lobes[1].sigma == pytest.approx(roughness_to_variance(0.4), rel=1e-4)
    one = fit_measured_lobes(_rings(truth), 1)
    assert np.all(one.misfit > 0.05)
    with pytest.raises(InverseError, match="lobes"):
        fit_measured_lobes(_rings(truth[1:]), 2)


def _ggx_merl(path, alpha: float, F, missing: float, seed: int = 0):
    """A MERL file of a GGX BRDF with a constant Fresnel factor ``F`` (RGB) and separable Smith
    masking, evaluated at each cell's centre; a fraction ``missing`` of the cells without data."""
    th = np.radians(halfdiff.theta_h_centers_deg())
    td = np.radians(halfdiff.theta_d_centers_deg())
    pd = np.radians(halfdiff.phi_d_centers_deg())
    TH, TD, PD = np.meshgrid(th, td, pd, indexing="ij")
    d = np.stack([np.sin(TD) * np.cos(PD), np.sin(TD) * np.sin(PD), np.cos(TD)], -1)
    c, s = np.cos(TH), np.sin(TH)

    def to_surface(x):          # from the frame of h (polar angle theta_h, azimuth 0), halfdiff's convention
        return np.stack([c * x[..., 0] + s * x[..., 2], x[..., 1], -s * x[..., 0] + c * x[..., 2]], -1)

    lz = to_surface(d)[..., 2]
    vz = to_surface(d * np.array([-1.0, -1.0, 1.0]))[..., 2]
    a2 = alpha * alpha
    D = a2 / (math.pi * c ** 4 * (a2 + np.tan(TH) ** 2) ** 2)

    def g1(z):
        z = np.clip(z, 1e-9, 1.0)
        return 2.0 / (1.0 + np.sqrt(1.0 + a2 * (1.0 - z * z) / (z * z)))

    ok = (lz > 0) & (vz > 0)
    f = np.where(ok, D * g1(lz) * g1(vz) / (4.0 * np.where(ok, lz * vz, 1.0)), 0.0).ravel()
    planes = np.array([Fc * f / sc for Fc, sc in zip(F, MERL_SCALE)])
    planes[:, np.random.default_rng(seed).random(f.size) < missing] = -1.0
    path.write_bytes(np.array(halfdiff.SHAPE, dtype="<i4").tobytes() + planes.astype("<f8").tobytes())
    return path


def test_a_merl_file_with_cells_without_data(gonio, capsys, tmp_path):
    """MERL's nearest cells at normal incidence, 30 % of them without data: rings without data are
    left out, the others filled from their cells with data, and the lobe is found."""
    F = (0.9, 0.7, 0.4)
    path = _ggx_merl(tmp_path / "ggx.binary", ALPHA, F, missing=0.3)
    assert gonio(["invert", str(path), "--base", "conductor", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["measurement"]["kind"] == "merl" and 40 < d["measurement"]["fit"]["rings"] < 63
    lobe = d["measurement"]["fit"]["fitted"][0]
    np.testing.assert_allclose(lobe["R"], np.array(F) * lobe_albedo(ALPHA), rtol=MERL_RTOL)
    np.testing.assert_allclose(lobe["sigma"], roughness_to_variance(ALPHA), rtol=MERL_RTOL)
    assert d["achievable"] and "simulation" not in d


@pytest.mark.parametrize("argv", [
    ["invert", "{bsdf}", "--lobe", "R=0.5"],                   # MEASURED and --lobe
    ["invert", "{other}"],                                    # not a measurement
    ["invert", "{missing}"],
    ["invert", "--lobe", "R=0.5", "--simulate"],              # measured-only options without MEASURED
    ["invert", "--lobe", "R=0.5", "--lobes", "2"],
    ["invert", "{bsdf}", "--lobes", "0"],
    ["invert", "{bsdf}", "--lobes", "4"],
    ["invert", "{bsdf}", "--layers", "1,2"],
    ["invert", "{bsdf}", "--layers", "3"],
    ["invert", "{bsdf}", "--simulate", "--rays", "10"],
    ["invert", "{bsdf}", "--rays", "100000"],                 # --simulate's options without it
    ["invert", "{bsdf}", "--pick", "2.u1=0.3"],
    ["invert", "{bsdf}", "--out", "x.txt"],
])
def test_bad_input_is_one_line_and_status_2(measurement, gonio, capsys, tmp_path, argv):
    other = tmp_path / "notes.bsdf"
    other.write_text("not a tensor file\n")
    names = {"bsdf": str(measurement[1]), "other": str(other), "missing": str(tmp_path / "none.binary")}
    assert gonio([a.format(**names) for a in argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("gonio: error: "), err
