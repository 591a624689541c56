"""Spectral tabulations on the MERL grid (docs/spectral.md, docs/tabulated-format.md): a Lambertian
base of a spectral albedo against its closed form per bin, a spectral gold against its own spectral
classic slice per bin, the same bits whatever the threads and after resuming, the file and the
command line (MERL export of the sRGB, refusals)."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

import goniometer as g
from goniometer.cli import main
from goniometer.spectral import from_toml, wavelength_bins
from goniometer.run.tabulation import TabulationCheckpoint, tabulate, tabulation_description
from goniometer.testing import Z_TOL, chi2_limit, energy_total
from tests.goniometer.test_tabulate import EXAMPLES, assert_table_matches_slice, read_merl_binary

ALBEDO = {"wavelength_nm": [360.0, 500.0, 830.0], "value": [0.1, 0.7, 0.3]}
LAMBERT = {"name": "lambert", "category": "plastic", "layers": [{"type": "lambertian", "albedo": ALBEDO}]}
GOLD = {"name": "gold", "category": "metal", "layers": [{"type": "interface", "roughness": 0.3, "conductor": "Au"}]}


def _settings(**kw) -> g.TabulationSettings:
    base = dict(rays=200_000, seed=3, threads=2, spectral=True, wavelength_bins=6, chunk_rays=1 << 14)
    base.update(kw)
    return g.TabulationSettings(**base)


def test_a_spectral_lambertian_tabulates_its_albedo_over_pi_per_bin():
    tab = tabulate(g.stack_from_dict(LAMBERT), _settings())
    rho = from_toml(ALBEDO, "albedo").at(wavelength_bins(6)[0])
    assert tab.value.shape == (6, 90, 90, 180) and tab.launches == 2 and tab.paths == 400_000
    # every path is reflected once with the albedo of its bin: exact
    np.testing.assert_allclose(tab.energy["reflected"], rho, rtol=1e-12)
    np.testing.assert_allclose(np.einsum("cijk,ijk->c", tab.value, tab.measure), np.pi * rho, rtol=1e-9)
    # rows of theta_h: the measure-weighted mean of the cells is rho / pi in every bin
    w = tab.measure.sum(axis=(1, 2))
    mean = np.sum(tab.value * tab.measure, axis=(2, 3)) / w
    se = np.sqrt(np.sum((tab.stderr * tab.measure) ** 2, axis=(2, 3))) / w
    keep = tab.hits.sum(axis=(1, 2)) >= 50
    z = (mean - rho[:, None] / np.pi)[:, keep] / se[:, keep]
    assert np.all(np.abs(z) < Z_TOL)
    for b in range(6):
        assert np.sum(z[b] ** 2) < chi2_limit(int(keep.sum()))
    # the sRGB of the table is the colour pipeline's sRGB of the albedo spectrum
    rgb = tab.rgb()
    assert rgb.value.shape == (3, 90, 90, 180) and not rgb.settings.spectral and rgb.paths == tab.paths
    np.testing.assert_allclose(rgb.energy["reflected"], g.spectral.spectral_to_rgb(rho, wavelength_bins(6)[1]),
                               rtol=1e-12)


def test_spectral_gold_matches_its_spectral_classic_slice_per_bin():
    """Two estimators of the same spectral transport: the tabulation (a direction per path, MERL
    cells) against a classic slice at 30 deg (each bin checked against Mitsuba 3 in
    test_transport.py), per bin; bins given other bins' wavelengths would fail (gold's
    reflectance doubles over the range)."""
    stack = g.stack_from_dict(GOLD)
    n = 1_000_000
    tab = tabulate(stack, _settings(rays=n, seed=11))
    sl = g.simulate(stack, g.SimulationSettings(incident_deg=(30.0,), rays=n, resolution=(9, 4), seed=12,
                                                spectral=True, wavelength_bins=6)).brdf
    f = tab.value.reshape(6, -1)
    se = tab.stderr.reshape(6, -1)
    assert_table_matches_slice(f, se, sl, 30.0)
    with pytest.raises(AssertionError):
        assert_table_matches_slice(f[::-1], se[::-1], sl, 30.0)


def _digest(tab) -> str:
    h = hashlib.sha256()
    for a in (tab.value, tab.stderr, tab.hits, *tab.energy.values()):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def test_same_bits_whatever_threads_and_after_resuming_within_a_later_launch(tmp_path):
    stack = g.load_stack(EXAMPLES / "soap-film.toml")        # a thin film: a spectral tabulation takes it
    base = dict(rays=40_000, seed=9, chunk_rays=8192)
    one = tabulate(stack, _settings(threads=1, **base))
    two = tabulate(stack, _settings(threads=2, **base))
    assert _digest(one) == _digest(two)
    np.testing.assert_allclose(energy_total(one), 1.0, atol=1e-9)
    # interrupted in the second launch, then resumed from the checkpoint
    settings = _settings(threads=2, **base)
    cp = TabulationCheckpoint(tmp_path / "cp", tabulation_description(stack, settings))
    seen = []

    def stop(n):
        seen.append(n)
        if sum(seen) > base["rays"]:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        tabulate(stack, settings, checkpoint=cp, progress=stop)
    resumed = []
    again = tabulate(stack, settings, checkpoint=cp, on_resume=resumed.append)
    assert resumed == [sum(seen)] and base["rays"] < resumed[0] < 2 * base["rays"]
    assert _digest(again) == _digest(one)
    # a spectral tabulation is another run than the RGB one: its own checkpoint key
    assert tabulation_description(stack, settings) != tabulation_description(
        stack, g.TabulationSettings(threads=2, **base))


def test_cli_spectral_tabulate_info_export_and_refusals(tmp_path, capsys):
    cfg = EXAMPLES / "gold-spectral.toml"
    out = tmp_path / "gold.h5"
    assert main(["tabulate", str(cfg), "--out", str(out), "--rays", "20000", "--spectral", "--wavelength-bins", "6",
                 "--threads", "1"]) == 0
    cap = capsys.readouterr()
    assert "spectral: 6 bins over 360-830 nm in 2 launch(es)" in cap.err
    tab = g.read_tabulated(out)
    assert tab.settings.spectral and tab.value.shape[0] == 6 and tab.launches == 2
    np.testing.assert_allclose(tab.wavelengths_nm, wavelength_bins(6)[0])
    assert main(["info", str(out), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["settings"]["spectral"] and info["spectral"]["wavelength_bins"] == 6
    np.testing.assert_allclose(info["spectral"]["energy_per_bin"]["reflected"], tab.energy["reflected"])
    np.testing.assert_allclose(info["energy"]["reflected"], tab.rgb().energy["reflected"])
    pytest.importorskip("xarray")
    ds = g.open_dataset(out)
    assert dict(ds["value"].sizes) == {"wavelength_nm": 6, "theta_h": 90, "theta_d": 90, "phi_d": 180}
    # a MERL file is RGB: the export writes the table's sRGB, and says so
    assert main(["export", str(out), "--format", "merl", "--out", str(tmp_path / "g.binary")]) == 0
    assert "is spectral; a MERL file is RGB" in capsys.readouterr().err
    stored = read_merl_binary(tmp_path / "g.binary")
    data = tab.hits.reshape(-1) > 0
    scale = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])
    np.testing.assert_allclose(stored[:, data] * scale[:, None], tab.rgb().value.reshape(3, -1)[:, data], rtol=1e-14)
    # a thin film in an RGB tabulation, and bad bins: one line, exit 2, nothing written
    rgb_film = tmp_path / "film-rgb.toml"
    rgb_film.write_text((EXAMPLES / "soap-film.toml").read_text().replace("spectral = true", "spectral = false"))
    for argv, needle in (([str(rgb_film)], "tabulate with --spectral"),
                         ([str(cfg), "--spectral", "--wavelength-bins", "7"], "wavelength_bins: 7 must be a multiple")):
        bad = tmp_path / "bad.h5"
        assert main(["tabulate", *argv, "--out", str(bad), "--rays", "100"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert needle in err[-1] and len(err) == 1, err
        assert not bad.exists()
