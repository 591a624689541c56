"""gonio report --compare-to a polarized database's scalar twin: polarization.md/.json say how far
the scalar intensity is from the polarized one (docs/polarization.md section 6), with what the
tables of the tiny database's slab show."""

from __future__ import annotations

import json
from pathlib import Path

from goniometer.cli import main
from goniometer.database import load_database, simulate_database

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
