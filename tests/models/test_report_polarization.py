"""gonio report --compare-to a polarized database's scalar twin: polarization.md/.json say how far
the scalar intensity is from the polarized one (docs/polarization.md section 6), with what the
tables of the tiny database's slab show."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from goniometer.cli import main
from goniometer.database import load_database, simulate_database
from models.report.polarization import RESOLVED_Z, _cells

ROOT = Path(__file__).resolve().parents[2]
TINY = ROOT / "tests" / "data" / "tiny_database.toml"


def test_report_compares_a_polarized_database_with_its_scalar_twin(tmp_path, capsys):
    db = load_database(TINY)
    only = "slab/*"
    simulate_database(db, tmp_path / "scalar", "quick", only=only)
    assert main(["database", "simulate", str(TINY), "--out", str(tmp_path / "pol"), "--quality", "quick",
                 "--only", only, "--polarized", "--threads", "2"]) == 0
    manifest = json.loads((tmp_path / "pol" / "database.json").read_text())
    assert manifest["polarized"] is True and "polarized" not in json.loads((tmp_path / "scalar" / "database.json")
                                                                          .read_text())
    capsys.readouterr()
    out = tmp_path / "report"
    assert main(["report", str(tmp_path / "pol"), "--out", str(out), "--compare-to", str(tmp_path / "scalar"),
                 "--model", "ww09"]) in (0, 1)
    sec = json.loads((out / "polarization.json").read_text())
    assert sec["materials"] and not sec["only_scalar"] and not sec["only_polarized"]
    inc = sec["materials"][0]["incidents"]
    assert all(row["brdf"]["cells"] > 0 for row in inc)
    text = (out / "polarization.md").read_text()
    assert "# Polarized light" in text and "largest relative difference" in text and "| slab" in text
    assert not (out / "multiple-scattering.json").exists()


def _run(value, stderr, rays=10**6):
    n = value.shape[-1]
    return {"rays": rays, "brdf": {"value": value[None, :, None], "stderr": stderr[None, :, None],
                                   "proj_solid_angle": np.full((1, 1, n), 1e-3), "mask": np.ones((1, 1, n), bool)}}


def test_the_cells_comparison_resolves_a_difference_and_not_noise():
    """Two runs of the same intensity differ by noise only: no cell resolves a difference at
    RESOLVED_Z and the rms z is 1; a 10 % difference with 1 % standard errors is resolved as
    10 % - 5 x 1.4 %, and the single cell's largest difference exceeds it."""
    rng = np.random.default_rng(3)
    shape = (3, 20000)
    truth = np.full(shape, 2.0)
    se = 0.01 * truth
    a = _run(truth + se * rng.standard_normal(shape), se)
    same = _cells(a, _run(truth + se * rng.standard_normal(shape), se), "brdf", 0)
    assert same["cells"] == truth.size and same["resolved_rel_diff"] == 0.0 and same["resolved_cells"] == 0
    assert abs(same["rms_z"] - 1.0) < 0.02
    differs = _cells(a, _run(1.1 * truth + se * rng.standard_normal(shape), se), "brdf", 0)
    assert differs["resolved_cells"] > 0.9 * truth.size
    assert 0.1 - RESOLVED_Z * 0.01 * 2 ** 0.5 < differs["resolved_rel_diff"] < 0.1
    assert differs["max_rel_diff"] > differs["resolved_rel_diff"]
