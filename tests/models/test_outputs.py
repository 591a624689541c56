"""The overwrite policy (docs/outputs.md) for the models' commands: evaluate --save-slices, render,
plot, furnace --plot, report, production, invert, validate-inverse. Each refusal is one line, exit 2,
and leaves the input and any existing output byte for byte as they were."""

from __future__ import annotations

from pathlib import Path

import pytest

from goniometer.cli import main
from tests.conftest import PLASTIC_TOML, refused

ROOT = Path(__file__).resolve().parents[2]
CONFIG = PLASTIC_TOML + """[simulation]
incident_deg = [0, 45]
rays = 4000
resolution = [9, 18]
"""


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    d = tmp_path_factory.mktemp("outputs")
    cfg = d / "p.toml"
    cfg.write_text(CONFIG)
    out = d / "p.h5"
    assert main(["simulate", str(cfg), "--out", str(out), "--threads", "1"]) == 0
    return cfg, out




def test_evaluate_save_slices(sim, tmp_path, capsys):
    cfg, h5 = sim
    before = h5.read_bytes()
    refused(capsys, ["evaluate", h5, "--model", "ww09", "--save-slices", h5], "--save-slices", "input", h5)
    refused(capsys, ["evaluate", h5, "--model", "ww09", "--save-slices", h5, "--overwrite"], "input")
    assert h5.read_bytes() == before
    out = tmp_path / "s.h5"
    assert main(["evaluate", str(h5), "--model", "ww09", "--save-slices", str(out)]) == 0
    saved = out.read_bytes()
    refused(capsys, ["evaluate", h5, "--model", "ww09", "--save-slices", out], "exists", "goniometer.model-slices",
            "of p")
    assert out.read_bytes() == saved
    assert main(["evaluate", str(h5), "--model", "ww09", "--save-slices", str(out), "--overwrite"]) == 0


def test_render(sim, tmp_path, capsys):
    cfg, h5 = sim
    before = h5.read_bytes()
    refused(capsys, ["render", h5, "--out", h5], "input")
    assert h5.read_bytes() == before
    png = tmp_path / "s.png"
    png.write_bytes(b"\x89PNG\r\n\x1a\nmine")
    refused(capsys, ["render", h5, "--out", png, "--size", "32"], "exists", "a PNG image")
    assert png.read_bytes() == b"\x89PNG\r\n\x1a\nmine"
    assert main(["render", str(h5), "--out", str(png), "--size", "32", "--overwrite"]) == 0
    assert png.read_bytes() != b"\x89PNG\r\n\x1a\nmine"


def test_plot_directory(sim, tmp_path, capsys):
    cfg, h5 = sim
    d = tmp_path / "figs"
    d.mkdir()
    (d / "energy.png").write_bytes(b"old figure")
    refused(capsys, ["plot", h5, "--out", d], "finished output", "--overwrite")
    assert (d / "energy.png").read_bytes() == b"old figure"


def test_furnace_plot(sim, tmp_path, capsys):
    cfg, _ = sim
    before = cfg.read_bytes()
    png = tmp_path / "f.png"
    png.write_bytes(b"keep")
    refused(capsys, ["furnace", cfg, "--plot", png, "--rays", "1000"], "--plot", "exists")
    assert png.read_bytes() == b"keep" and cfg.read_bytes() == before


def test_report_and_production_directories(tmp_path, capsys):
    db = tmp_path / "db"
    db.mkdir()
    (db / "database.json").write_text("{}")
    refused(capsys, ["report", db, "--out", db], "input")
    refused(capsys, ["production", db, "--out", db], "input")
    rep = tmp_path / "rep"
    rep.mkdir()
    (rep / "index.html").write_text("<html>mine</html>")
    refused(capsys, ["report", db, "--out", rep], "finished output", "HTML page", "--overwrite")
    assert (rep / "index.html").read_text() == "<html>mine</html>"
    prod = tmp_path / "prod"
    prod.mkdir()
    (prod / "summary.json").write_text("{}")
    refused(capsys, ["production", db, "--out", prod], "finished output", "JSON file")
    assert (prod / "summary.json").read_text() == "{}"


def test_invert_and_validate_inverse(tmp_path, capsys):
    toml = tmp_path / "s.toml"
    toml.write_text("mine")
    refused(capsys, ["invert", "--lobe", "R=0.04 sigma=0.01 layers=1", "--out", toml], "exists", "TOML file")
    assert toml.read_text() == "mine"
    assert main(["invert", "--lobe", "R=0.04 sigma=0.01 layers=1", "--out", str(toml), "--overwrite"]) == 0
    assert toml.read_text() != "mine"
    cases = ROOT / "configs" / "inverse" / "cases.toml"
    js = tmp_path / "v.json"
    js.write_text("[]")
    refused(capsys, ["validate-inverse", cases, "--json", js], "--json", "exists")
    assert js.read_text() == "[]"
    rep = tmp_path / "vr"
    rep.mkdir()
    (rep / "index.html").write_text("x")
    refused(capsys, ["validate-inverse", cases, "--report", rep], "--report", "finished output")
