"""A report never dies for one figure (models/report/build.py, spheres.py; docs/report.md): over one
material of each category, the near-Dirac slabs of configs/bati2019.toml included (alpha0 = alpha1 =
0.001, black on the backlit spheres), the report finishes, every sphere PNG says why its reference
cannot be shown, ``errors.json`` lists what was not drawn, and a figure that raises costs only itself."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from goniometer.cli import main as gonio
from goniometer.database import load_database, simulate_database
import models.report.build as build_module
from models.report import build_report
from models.report.spheres import SPHERE_ANGLES_DEG

DEFINITION = Path(__file__).resolve().parents[1] / "data" / "edge_database.toml"
PNG = b"\x89PNG\r\n\x1a\n"
#: one model per side keeps the test to seconds (the figures, not the models, are under test)
MODELS = ["ww09", "belcour-btdf"]
FIGURES_AT = [60.0]
SLABS = {"slab/S3-a0_0.001-a1_0.001", "slab/S4-a0_0.001-a1_0.001"}


@pytest.fixture(scope="module")
def edges(tmp_path_factory):
    base = tmp_path_factory.mktemp("edges")
    simulate_database(load_database(DEFINITION), base / "results", "quick")
    summary = build_report(base / "results", base / "report", models=MODELS, incidents_for_figures=FIGURES_AT)
    return base, summary


def _records(summary) -> list[dict]:
    return json.loads(summary.errors_json.read_text())


def test_near_dirac_slabs_do_not_stop_the_report(edges):
    base, summary = edges
    out = base / "report"
    assert len(summary.materials) == 4 and {"plastic", "metal", "slab"} <= {m.split("/")[0] for m in summary.materials}
    records = _records(summary)
    assert {r["material"] for r in records} == set(summary.materials)
    for name in ("reproduction.json", "tables/slab.csv", "figures/errors_overview.png", "index.html"):
        assert (out / name).is_file(), name
    # the 65 degree backlit sphere of each smooth slab is black: drawn with the reason, listed in errors.json
    for slab in SLABS:
        listed = {x["figure"]: x["reason"] for r in records if r["material"] == slab for x in r["not_drawn"]}
        assert "sphere_65.png" in listed, listed
        assert "black" in listed["sphere_65.png"] and "straight-through" in listed["sphere_65.png"]
        for angle in SPHERE_ANGLES_DEG:
            png = out / "figures" / Path(*slab.split("/")) / f"sphere_{angle:g}.png"
            assert png.read_bytes()[:8] == PNG
    # what is listed is exactly what the summary and the page say; nothing else was lost
    assert all(x["material"] in SLABS and x["figure"].startswith("sphere_") for x in summary.not_drawn), \
        summary.not_drawn
    assert sum(len(r["not_drawn"]) for r in records if r["material"] not in SLABS) == 0
    assert sum("not drawn" in w for w in summary.warnings) == len(summary.not_drawn)


def test_a_figure_that_raises_costs_only_itself(edges, monkeypatch):
    base, summary = edges
    plastic = next(m for m in summary.materials if m.startswith("plastic/"))
    real = build_module.material_figures

    def flaky(res, *a, **k):
        if res.material.name == plastic:
            raise RuntimeError("drawing failed on purpose")
        return real(res, *a, **k)

    def no_plots(*a, **k):
        raise RuntimeError("no figure-4 plot today")

    monkeypatch.setattr(build_module, "material_figures", flaky)
    monkeypatch.setattr(build_module, "errors_figure", no_plots)
    again = build_report(base / "results", base / "report", models=MODELS, incidents_for_figures=FIGURES_AT)
    records = _records(again)
    assert {r["material"] for r in records} == set(summary.materials), "every error record is still written"
    mine = [x for r in records if r["material"] == plastic for x in r["not_drawn"]]
    assert mine and all(x["figure"] == "figures" and "on purpose" in x["reason"] for x in mine)
    reported = {x["figure"] for x in again.not_drawn if x["material"] is None}
    assert reported == {"figures/errors_plastic.png", "figures/errors_metal.png", "figures/errors_slab.png"}
    assert (base / "report" / "reproduction.json").is_file() and (base / "report" / "tables" / "plastic.md").is_file()
    page = again.index_html.read_text()
    assert "drawing failed on purpose" in page


def test_gonio_render_explains_a_black_reference(edges, tmp_path, capsys):
    base, _ = edges
    path = base / "results" / "slab" / "S3-a0_0.001-a1_0.001.h5"
    code = gonio(["render", str(path), "--out", str(tmp_path / "s.png"), "--light-angle", "65", "--size", "32",
                  "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert (tmp_path / "s.png").read_bytes()[:8] == PNG
    doc = json.loads(out)
    assert "black" in doc["reference_note"] and doc["models"] == {}
