"""Spectral transport (docs/spectral.md): launches of three wavelengths, files with a wavelength
axis, the colour pipeline -- checked against Mitsuba 3's scalar_spectral roughconductor cell by
cell, against the RGB run of a constant-index dielectric, and against energy conservation."""

from __future__ import annotations

import math

import numpy as np
import pytest

import goniometer as g
from goniometer.run import results
from goniometer.files import slices as store
from goniometer.run.settings import SettingsError
from goniometer.spectral import wavelength_bins
from goniometer.run.launches import bin_groups, launch_seed, launches
from goniometer.stack import StackError, stack_from_dict
from goniometer.testing import Z_TOL, assert_cells_match, cell_chi2, chi2_limit, energy_total

GOLD = {"name": "gold", "category": "metal", "layers": [{"type": "interface", "roughness": 0.3, "conductor": "Au"}]}
#: a rough dielectric slab of constant index with an achromatic medium: every bin has the RGB run's expectation
SLAB = {"name": "slab", "category": "slab", "layers": [
    {"type": "interface", "roughness": 0.3, "ior": 1.5}, {"type": "medium", "optical_depth": 0.2},
    {"type": "interface", "roughness": 0.2, "ior": 1.0}]}


def _settings(**kw) -> g.SimulationSettings:
    base = dict(incident_deg=(0.0, 50.0), rays=60_000, resolution=(12, 24), spectral=True, wavelength_bins=6,
                threads=2, chunk_rays=1 << 14)
    base.update(kw)
    return g.SimulationSettings(**base)


@pytest.fixture(scope="module")
def gold_run():
    stack = stack_from_dict(GOLD)
    return stack, g.simulate(stack, _settings(rays=150_000))


def test_launches_spread_the_bins_and_cover_each_once():
    stack = stack_from_dict(GOLD)
    s = _settings(wavelength_bins=9)
    assert launches(stack, s) == [(0, 3, 6), (1, 4, 7), (2, 5, 8)]
    assert list(bin_groups(stack, s)) == [0, 1, 2, 0, 1, 2, 0, 1, 2]
    assert len({launch_seed(1, k) for k in range(100)}) == 100 and launch_seed(1, 0) != launch_seed(2, 0)
    # a dispersive dielectric: one wavelength per launch
    disp = stack_from_dict({"name": "glass", "category": "slab", "layers": [
        {"type": "interface", "roughness": 0.2, "ior": {"cauchy": [1.5, 0.0042]}},
        {"type": "interface", "roughness": 0.2, "ior": 1.0}]})
    assert launches(disp, s) == [(b,) for b in range(9)]


def test_a_spectral_file_round_trips_with_its_wavelength_axis(gold_run, tmp_path):
    stack, r = gold_run
    B = r.settings.wavelength_bins
    assert r.brdf.value.shape == (2, B, 12, 24) and r.energy["reflected"].shape == (2, B)
    assert np.allclose(r.wavelengths_nm, wavelength_bins(B)[0])
    p = store.write(tmp_path / "gold.h5", r)
    back = store.read(p)
    assert results.same_run(back.settings, r.settings)
    assert back.settings.spectral and back.stack == stack
    assert np.array_equal(back.brdf.value, r.brdf.value) and np.array_equal(back.brdf.stderr, r.brdf.stderr)
    assert back.paths_per_incident == r.settings.rays * B // 3
    xr = pytest.importorskip("xarray")
    ds = g.open_dataset(p, "brdf")
    assert "wavelength_nm" in ds["value"].dims and np.allclose(ds["wavelength_nm"], r.wavelengths_nm)


def test_same_seed_same_bits_whatever_the_threads():
    stack = stack_from_dict(GOLD)
    a = g.simulate(stack, _settings(rays=20_000, threads=1, incident_deg=(30.0,)))
    b = g.simulate(stack, _settings(rays=20_000, threads=2, incident_deg=(30.0,)))
    assert np.array_equal(a.brdf.value, b.brdf.value) and np.array_equal(a.brdf.stderr, b.brdf.stderr)


def _mitsuba_cells(stack, r, wavelengths: np.ndarray, sub: int = 4) -> np.ndarray:
    """Cell means (M, B, nt, nph) of Mitsuba 3's scalar_spectral roughconductor given the same
    spectral eta and k (irregular spectra of our table's nodes), evaluated at the bin centres:
    ``sub x sub`` midpoint sub-cells per cell, weighted by |cos| dw."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_spectral")
    eta, k = stack.spectrum(0, "ior"), stack.spectrum(0, "extinction")

    def irregular(sp):
        return {"type": "irregular", "wavelengths": ", ".join(f"{x:.10g}" for x in sp.wavelength_nm),
                "values": ", ".join(f"{x:.10g}" for x in sp.value)}

    bsdf = mi.load_dict({"type": "roughconductor", "distribution": "ggx", "alpha": 0.3, "sample_visible": True,
                         "eta": irregular(eta), "k": irregular(k)})
    grid = r.brdf.grid
    te, pe = np.radians(grid.theta_edges_deg()), np.radians(grid.phi_edges_deg())
    nt, nph = len(te) - 1, len(pe) - 1
    f = (np.arange(sub) + 0.5) / sub
    out = np.zeros((len(r.theta_deg), len(wavelengths), nt, nph))
    ctx = mi.BSDFContext()
    for m, th in enumerate(r.theta_deg):
        t = math.radians(th)
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(math.sin(t), 0.0, math.cos(t))
        for i in range(nt):
            ts = te[i] + (te[i + 1] - te[i]) * f
            for j in range(nph):
                ps = pe[j] + (pe[j + 1] - pe[j]) * f
                num = np.zeros(len(wavelengths))
                den = 0.0
                for a in ts:
                    w = math.sin(a) * math.cos(a)
                    for b in ps:
                        wo = mi.Vector3f(math.sin(a) * math.cos(b), math.sin(a) * math.sin(b), math.cos(a))
                        for q in range(0, len(wavelengths), 4):
                            lam = list(wavelengths[q:q + 4]) + [wavelengths[-1]] * (4 - len(wavelengths[q:q + 4]))
                            si.wavelengths = mi.Spectrum(lam)
                            val = np.array(bsdf.eval(ctx, si, wo))[: len(wavelengths[q:q + 4])]
                            num[q:q + 4] += val * math.sin(a)
                        den += w
                out[m, :, i, j] = num / den   # eval is f cos; the cell mean weights f by cos dw
    return out


def test_spectral_gold_matches_mitsuba_scalar_spectral_cell_by_cell(gold_run):
    stack, r = gold_run
    model = _mitsuba_cells(stack, r, r.wavelengths_nm)
    omega = r.brdf.proj_solid_angle[:, None]
    assert_cells_match(r.brdf.value, r.brdf.stderr, model, omega, r.settings.rays, min_cells=300)
    # the check has teeth: silver's data in place of gold's is seen
    silver = stack_from_dict({**GOLD, "layers": [{"type": "interface", "roughness": 0.3, "conductor": "Ag"}]})
    wrong = _mitsuba_cells(silver, r, r.wavelengths_nm)
    chi2, dof = cell_chi2(r.brdf.value, r.brdf.stderr, wrong, omega, r.settings.rays)
    assert chi2 > 3 * chi2_limit(dof)


def test_rgb_of_a_constant_index_dielectric_equals_the_rgb_run():
    stack = stack_from_dict(SLAB)
    kw = dict(incident_deg=(20.0, 60.0), rays=80_000, resolution=(8, 16), threads=2, chunk_rays=1 << 14)
    spec = g.simulate(stack, g.SimulationSettings(spectral=True, wavelength_bins=6, **kw)).rgb()
    rgb = g.simulate(stack, g.SimulationSettings(seed=7, **kw))
    for side in ("brdf", "btdf"):
        a, b = getattr(spec, side), getattr(rgb, side)
        se = np.hypot(a.stderr, b.stderr)
        ok = (a.value > 5 * a.stderr) & (b.value > 5 * b.stderr)   # cells with about 25 paths or more
        z = (a.value - b.value)[ok] / se[ok]
        assert ok.sum() > 100 and np.mean(z * z) < 1.0 + 4.0 * math.sqrt(2.0 / ok.sum()), (side, ok.sum(), np.mean(z * z))
    for k in ("reflected", "transmitted"):
        d = spec.energy[k] - rgb.energy[k]
        # beside both noises, the colour pipeline's white residual: a constant spectrum c maps to c
        # within 1.7e-4 c (docs/spectral.md section 4)
        slack = 1.7e-4 * np.abs(rgb.energy[k])
        assert np.all(np.abs(d) < Z_TOL * np.hypot(spec.energy_stderr[k], rgb.energy_stderr[k]) + slack), (k, d)


def test_energy_is_conserved_per_bin(gold_run):
    _, r = gold_run
    assert np.allclose(energy_total(r), 1.0, atol=1e-9)


def test_integrated_first_order_per_bin_matches_the_traced_run(gold_run):
    """Each bin's integral (the cubature of docs/first-order.md on the bin's launch stack) against
    the traced spectral run, cell by cell: a bin given another bin's wavelength fails it (gold's
    reflectance grows from 0.4 to 0.97 over the range)."""
    stack, traced = gold_run
    s = traced.settings
    integ = g.simulate(stack, _settings(rays=1_000, first_order="integrated"))
    # a single-scattering interface is all order 1: nothing traced is deposited
    assert np.array_equal(integ.brdf.orders[:, 1:], np.zeros_like(integ.brdf.orders[:, 1:]))
    for m in range(len(s.incident_deg)):
        omega = traced.brdf.proj_solid_angle[m]
        for b in range(s.wavelength_bins):
            assert_cells_match(traced.brdf.value[m, b], traced.brdf.stderr[m, b], integ.brdf.value[m, b], omega,
                               s.rays, min_expected=20.0, where=traced.brdf.mask[m], min_cells=40)
    # the same run's bins swapped would not pass: the check can fail
    chi2, dof = cell_chi2(traced.brdf.value[1, 0], traced.brdf.stderr[1, 0], integ.brdf.value[1, -1],
                          traced.brdf.proj_solid_angle[1], s.rays, 20.0, traced.brdf.mask[1])
    assert chi2 > chi2_limit(dof)


@pytest.mark.parametrize("kw, needle", [
    (dict(wavelength_bins=31), "wavelength_bins: 31 must be a multiple of 3"),
    (dict(wavelength_bins=0), "wavelength_bins: 0 is outside"),
])
def test_bad_spectral_settings_are_refused(kw, needle):
    with pytest.raises(SettingsError, match=needle):
        _settings(**kw)


def test_a_table_that_does_not_cover_the_bins_is_refused():
    stack = stack_from_dict({"name": "x", "category": "plastic", "layers": [
        {"type": "interface", "roughness": 0.2, "ior": 1.5},
        {"type": "lambertian", "albedo": {"wavelength_nm": [400, 700], "value": [0.2, 0.8]}}]})
    with pytest.raises(StackError, match=r"layers\[1\].albedo: the table covers 400-700 nm"):
        g.simulate(stack, _settings(rays=100))


def test_a_resumed_spectral_run_has_the_bits_of_an_uninterrupted_one(tmp_path):
    """Checkpoints hold a spectral incident direction's bins (docs/spectral.md, docs/outputs.md):
    a run that finds one direction checkpointed traces only the other and ends with the same bits."""
    from goniometer.run.checkpoints import Checkpoints
    from goniometer.run.results import run_description
    from goniometer.run.loop import run_incidents
    stack = stack_from_dict(GOLD)
    s = _settings(rays=4000, resolution=(4, 8))
    whole = run_incidents(stack, s)
    ck = Checkpoints(tmp_path / "ck", run_description(stack, s))
    run_incidents(stack, s, checkpoints=ck)              # saves both directions
    (tmp_path / "ck" / "m01.npz").unlink()               # as if interrupted after the first
    resumed = []
    again = run_incidents(stack, s, checkpoints=ck, on_resume=resumed.append)
    assert resumed == [1]
    for a, b in ((whole.brdf.value, again.brdf.value), (whole.brdf.stderr, again.brdf.stderr),
                 (whole.energy["reflected"], again.energy["reflected"])):
        assert np.array_equal(a, b)
