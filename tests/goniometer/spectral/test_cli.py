"""``gonio simulate --spectral`` and ``gonio info`` on a spectral file; bad spectral input is one
line and exit 2 (docs/spectral.md)."""

from __future__ import annotations

import json

import pytest

from goniometer.cli import main
from tests.conftest import refused

GOLD = """name = "gold"
category = "metal"
[[layers]]
type = "interface"
roughness = 0.3
conductor = "Au"
"""


def _write(tmp_path, text: str, name: str = "m.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_a_spectral_simulate_and_its_info(tmp_path, capsys):
    cfg = _write(tmp_path, GOLD)
    out = tmp_path / "gold.h5"
    assert main(["simulate", str(cfg), "--out", str(out), "--spectral", "--wavelength-bins", "6", "--rays", "2000",
                 "--incident", "30", "--resolution", "4x8", "--threads", "1"]) == 0
    err = capsys.readouterr().err
    assert "spectral: 6 bins over 360-830 nm in 2 launch(es) of 2,000 paths" in err
    assert main(["info", str(out), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["settings"]["spectral"] and d["spectral"]["wavelength_bins"] == 6
    assert len(d["spectral"]["wavelength_nm"]) == 6 and d["spectral"]["paths_per_incident"] == 4000
    assert len(d["energy"][0]["reflected"]) == 3 and len(d["spectral"]["energy_per_bin"][0]["reflected"]) == 6


def test_an_rgb_run_of_spectral_data_says_what_it_traces(tmp_path, capsys):
    cfg = _write(tmp_path, GOLD)
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "g.h5"), "--rays", "500", "--incident", "30",
                 "--resolution", "2x4", "--threads", "1"]) == 0
    assert "an RGB run traces their RGB equivalents" in capsys.readouterr().err


@pytest.mark.parametrize("text, argv, needles", [
    (GOLD, ["--spectral", "--wavelength-bins", "31"], ["wavelength_bins: 31 must be a multiple of 3"]),
    (GOLD.replace('"Au"', '"Xy"'), ["--spectral"], ["layers[0].conductor", "'Xy' is not a named conductor",
                                                     "Ag, Al, Au, Cu"]),
    ('name = "p"\ncategory = "plastic"\n[[layers]]\ntype = "interface"\nroughness = 0.2\nior = 1.5\n'
     '[[layers]]\ntype = "lambertian"\nalbedo = {wavelength_nm = [400, 700], value = [0.2, 0.8]}\n',
     ["--spectral"], ["layers[1].albedo: the table covers 400-700 nm", "367.8-822.2 nm"]),
    ('name = "p"\ncategory = "plastic"\n[[layers]]\ntype = "interface"\nroughness = 0.2\nior = 1.5\n'
     '[[layers]]\ntype = "lambertian"\nalbedo = {wavelength_nm = [700, 400], value = [0.2, 0.8]}\n',
     ["--spectral"], ["layers[1].albedo.wavelength_nm", "strictly increasing"]),
    ('name = "p"\ncategory = "plastic"\n[[layers]]\ntype = "interface"\nroughness = 0.2\nior = 1.5\n'
     'film = {thickness_nm = 300, ior = 1.33}\n[[layers]]\ntype = "lambertian"\nalbedo = 0.5\n',
     [], ["layers[0].film: a thin film needs a spectral run"]),
    ('name = "p"\ncategory = "plastic"\n[[layers]]\ntype = "interface"\nroughness = 0.2\nior = 1.5\n'
     'film = {thickness_nm = -3, ior = 1.33}\n[[layers]]\ntype = "lambertian"\nalbedo = 0.5\n',
     ["--spectral"], ["layers[0].film.thickness_nm", "outside [0, inf)"]),
], ids=["bins", "unknown-conductor", "table-short", "table-unsorted", "film-in-rgb-run", "negative-thickness"])
def test_bad_spectral_input_is_one_line_and_exit_2(tmp_path, capsys, text, argv, needles):
    cfg = _write(tmp_path, text)
    out = tmp_path / "x.h5"
    refused(capsys, ["simulate", cfg, "--out", out, "--rays", "100", "--incident", "30", "--resolution", "2x4",
                     *argv], *needles)
    assert not out.exists()
