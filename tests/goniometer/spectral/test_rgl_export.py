"""The RGL spectral export of a spectral run carries the traced spectra (docs/spectral.md,
docs/rgl-format.md): Mitsuba 3's scalar_spectral ``measured`` plugin reads them at the bins'
wavelengths within the noise of the file computed exactly from Mitsuba's own spectral
roughconductor, and pbrt-v4's rules take the file."""

from __future__ import annotations

import numpy as np
import pytest

import goniometer as g
from goniometer.files.rgl_export import bsdf_fields, check_readers, fields_from_spectra, stored_values
from goniometer.grids.rgl import grid_for
from goniometer.files.rgl_tensor import write_tensor
from goniometer.stack import stack_from_dict
from goniometer.testing import Z_TOL
from tests.goniometer.rgl.test_export import _expected_estimates, _random_pairs

mi = pytest.importorskip("mitsuba")

GOLD = {"name": "gold", "category": "metal", "layers": [{"type": "interface", "roughness": 0.3, "conductor": "Au"}]}
BINS = 6
RAYS = 300_000


@pytest.fixture(scope="module")
def spectral_gold():
    stack = stack_from_dict(GOLD)
    grid = grid_for(stack, 3, 1, 12)
    s = g.SimulationSettings.on_rgl_grid(grid, rays=RAYS, spectral=True, wavelength_bins=BINS, threads=2,
                                         chunk_rays=1 << 15)
    return stack, grid, g.simulate(stack, s)


def _spectral_bsdf(stack):
    mi.set_variant("scalar_spectral")
    def irregular(sp):
        return {"type": "irregular", "wavelengths": ", ".join(f"{x:.10g}" for x in sp.wavelength_nm),
                "values": ", ".join(f"{x:.10g}" for x in sp.value)}
    return mi.load_dict({"type": "roughconductor", "distribution": "ggx", "alpha": 0.3, "sample_visible": True,
                         "eta": irregular(stack.spectrum(0, "ior")), "k": irregular(stack.spectrum(0, "extinction"))})


def _evaluator(wavelengths):
    """eval (f cos) of a scalar_spectral BSDF at ``wavelengths`` (N, len(wavelengths))."""
    def evaluate(bsdf, wi, wo):
        out = np.empty((len(wi), len(wavelengths)))
        si = mi.SurfaceInteraction3f()
        ctx = mi.BSDFContext()
        for q in range(0, len(wavelengths), 4):
            lam = list(wavelengths[q:q + 4])
            k = len(lam)
            si.wavelengths = mi.UnpolarizedSpectrum(lam + [lam[-1]] * (4 - k))
            for i in range(len(wi)):
                si.wi = mi.Vector3f(*wi[i])
                out[i, q:q + k] = np.array(bsdf.eval(ctx, si, mi.Vector3f(*wo[i])))[:k]
        return out
    return evaluate


def test_spectral_file_holds_the_traced_spectra_and_both_readers_take_it(spectral_gold):
    stack, grid, r = spectral_gold
    f = bsdf_fields(r, spectral=True)
    assert np.array_equal(f["wavelengths"], r.wavelengths_nm.astype(np.float32))
    assert np.array_equal(f["spectra"], stored_values(grid, r.brdf.value).astype(np.float32))
    verdict = check_readers(f)
    assert not verdict["pbrt-v4"] and not verdict["mitsuba-spectral"]
    rgb = bsdf_fields(r)
    assert not check_readers(rgb)["mitsuba-rgb"] and rgb["rgb"].shape[2] == 3 and np.all(rgb["rgb"] >= 0)
    assert "spectra traced at 6 wavelength bins" in bytes(f["description"]).decode()


def test_mitsuba_reads_the_spectra_within_the_noise_of_the_exact_spectral_file(spectral_gold, tmp_path):
    stack, grid, r = spectral_gold
    wl = [float(x) for x in r.wavelengths_nm]
    bsdf = _spectral_bsdf(stack)
    try:
        evaluate = _evaluator(wl)
        exact = _expected_estimates(grid, bsdf, sub=4, evaluate=evaluate, channels=BINS)
        paths = {name: write_tensor(tmp_path / f"{name}.bsdf", fields_from_spectra(grid, v, BINS, name))
                 for name, v in (("sim", r.brdf.value), ("exact", exact), ("se", r.brdf.stderr))}
        loaded = {k: mi.load_dict({"type": "measured", "filename": str(p)}) for k, p in paths.items()}
        wi, wo = _random_pairs(grid, np.random.default_rng(3), count=60)
        a_sim, a_ex, a_se = (evaluate(loaded[k], wi, wo) for k in ("sim", "exact", "se"))
        # interpolation mixes four nodes: their largest standard error bounds the interpolant's
        z = np.abs(a_sim - a_ex) / np.maximum(a_se, 1e-12)
        assert np.all(z[a_se > 0] < Z_TOL), float(z.max())
        # and the check sees a wrong metal: copper's exact file is far outside the noise
        copper = stack_from_dict({**GOLD, "layers": [{"type": "interface", "roughness": 0.3, "conductor": "Cu"}]})
        wrong = _expected_estimates(grid, _spectral_bsdf(copper), sub=4, evaluate=evaluate, channels=BINS)
        w = mi.load_dict({"type": "measured", "filename": str(write_tensor(
            tmp_path / "cu.bsdf", fields_from_spectra(grid, wrong, BINS, "cu")))})
        zw = np.abs(a_sim - evaluate(w, wi, wo)) / np.maximum(a_se, 1e-12)
        assert np.mean(zw[a_se > 0] > Z_TOL) > 0.2
    finally:
        mi.set_variant("scalar_rgb")
