"""``gonio simulate --parametrization rgl``, ``gonio export --format rgl`` and ``gonio info FILE.bsdf``:
what they write, and their refusals (one line, exit 2, nothing written)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import goniometer as g
from goniometer.cli import main
from tests.conftest import refused

EXAMPLES = Path(__file__).resolve().parents[3] / "configs" / "examples"
GOLD = """name = "gold"
category = "metal"
[[layers]]
type = "interface"
roughness = 0.3
ior = [0.2, 0.35, 1.4]
extinction = [3.5, 2.6, 1.9]
[simulation]
rays = 20000
parametrization = "rgl"
rgl_grid = [3, 1, 8]
"""




@pytest.fixture(scope="module")
def gold(tmp_path_factory):
    d = tmp_path_factory.mktemp("rgl")
    cfg = d / "gold.toml"
    cfg.write_text(GOLD)
    out = d / "gold.h5"
    assert main(["simulate", str(cfg), "--out", str(out), "--threads", "1"]) == 0
    return cfg, out


def test_the_file_table_sets_the_grid_and_the_file_records_it(gold, capsys):
    cfg, out = gold
    r = g.read(out)
    grid = r.settings.rgl
    assert r.settings.parametrization == "rgl" and len(grid.theta_i_deg) == 3 and grid.n == 8
    assert r.brdf.value.shape == (3, 3, 8, 8) and r.btdf is None
    capsys.readouterr()
    assert main(["info", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["settings"]["parametrization"] == "rgl"


def test_export_both_files_and_info_says_who_reads_them(gold, tmp_path, capsys):
    cfg, out = gold
    rgb, spec = tmp_path / "gold_rgb.bsdf", tmp_path / "gold_spec.bsdf"
    capsys.readouterr()
    assert main(["export", str(out), "--format", "rgl", "--out", str(rgb)]) == 0
    said, err = capsys.readouterr()
    # pbrt-v4 refuses RGB files: no pbrt-v4 line for one, but the export that pbrt-v4 reads
    assert f"Mitsuba 3 (RGB variants): {{'type': 'measured', 'filename': '{rgb}'}}" in said
    assert 'Material "measured"' not in said and "pbrt-v4 does not read this file" in said and "--spectral" in said
    assert "is an RGB run" not in err
    assert main(["export", str(out), "--format", "rgl", "--out", str(spec), "--spectral"]) == 0
    said, err = capsys.readouterr()
    assert "is an RGB run: the file's spectra are its RGB upsampled" in err   # a stand-in, said so
    assert f'pbrt-v4: Material "measured" "string filename" "{spec}"' in said
    assert "Mitsuba 3 (spectral variants)" in said and "RGB variants" not in said.split("\n", 1)[1]
    assert main(["info", str(spec), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["readers"]["pbrt-v4"]["takes_it"] and d["readers"]["mitsuba-spectral"]["takes_it"]
    assert not d["readers"]["mitsuba-rgb"]["takes_it"] and d["isotropic"] and d["jacobian"]
    assert main(["info", str(rgb)]) == 0
    text = capsys.readouterr().out
    assert "mitsuba-rgb       takes it" in text and "pbrt-v4           refuses it" in text
    # the policy: never onto the input, never over a finished export without --overwrite
    kept = rgb.read_bytes()
    refused(capsys, ["export", out, "--format", "rgl", "--out", rgb], "exists", "RGL tensor file")
    assert rgb.read_bytes() == kept
    refused(capsys, ["export", out, "--format", "rgl", "--out", out], "input")


def test_export_refuses_what_the_readers_cannot_take(gold, tmp_path, capsys):
    cfg, out = gold
    classic = tmp_path / "c.h5"
    assert main(["simulate", str(EXAMPLES / "metal.toml"), "--out", str(classic), "--rays", "2000", "--incident",
                 "30", "--resolution", "9x18", "--threads", "1"]) == 0
    refused(capsys, ["export", classic, "--format", "rgl", "--out", tmp_path / "c.bsdf"], "not recorded on the RGL grid",
             "--parametrization rgl")
    assert not (tmp_path / "c.bsdf").exists()
    # an anisotropic stack on a grid of one incident azimuth: refused before tracing (it was traced
    # with a warning, and then its export refused)
    aniso = tmp_path / "a.h5"
    refused(capsys, ["simulate", EXAMPLES / "aniso-metal.toml", "--out", aniso, "--parametrization", "rgl",
                     "--rgl-grid", "3x1x8", "--rays", "2000", "--threads", "1"],
            "--rgl-grid: ", "anisotropic but the RGL grid has one incident azimuth", "N_PHI_I >= 3", "3x9x8")
    assert not aniso.exists() and not (tmp_path / ".a.h5.partial").exists()
    # the file table's grid says where it comes from
    cfg_aniso = tmp_path / "aniso.toml"
    cfg_aniso.write_text((EXAMPLES / "aniso-metal.toml").read_text().split("[simulation]")[0]
                         + '[simulation]\nparametrization = "rgl"\nrgl_grid = [3, 1, 8]\n')
    refused(capsys, ["simulate", cfg_aniso, "--out", aniso], f"{cfg_aniso}: simulation.rgl_grid: ", "anisotropic")
    # such a file written through the library: its export is refused too
    from goniometer.grids.rgl import grid_for
    from goniometer.stack import load_toml
    stack, _ = load_toml(EXAMPLES / "aniso-metal.toml")
    g.write(aniso, g.simulate(stack, g.SimulationSettings.on_rgl_grid(grid_for(stack, 3, 1, 8), rays=500, threads=1)))
    refused(capsys, ["export", aniso, "--format", "rgl", "--out", tmp_path / "a.bsdf"], "anisotropic", "N_PHI_I >= 3")
    assert not (tmp_path / "a.bsdf").exists()
    refused(capsys, ["export", out, "--format", "merl", "--out", tmp_path / "x.binary", "--spectral"], "--spectral")


@pytest.mark.parametrize("argv, needle", [
    (["--rgl-grid", "8x2x32"], "N_PHI_I = 2"),
    (["--rgl-grid", "8x1"], "N_THETA_IxN_PHI_IxN"),
    (["--rgl-grid", "8x1x2"], "N = 2 is outside [4, 512]"),
    (["--incident", "30"], "--incident: the RGL grid sets it"),
    (["--resolution", "9x18"], "--resolution: the RGL grid sets it"),
    (["--first-order", "integrated"], "first_order"),
])
def test_bad_rgl_options(gold, tmp_path, capsys, argv, needle):
    cfg, _ = gold
    refused(capsys, ["simulate", cfg, "--out", tmp_path / "x.h5", *argv], needle)
    assert not (tmp_path / "x.h5").exists()


def test_rgl_grid_without_the_parametrization(tmp_path, capsys):
    refused(capsys, ["simulate", EXAMPLES / "metal.toml", "--out", tmp_path / "x.h5", "--rgl-grid", "8x1x32"],
             "--rgl-grid: goes with --parametrization rgl")
