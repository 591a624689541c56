"""The report's lit spheres (models/report/spheres.py; docs/report.md, docs/render.md): every
material gets its reference and models at 30 and 65 degrees, cached with the evaluation, and the
page reproduces Bati 2019 figure 1 when the results hold its frosted metal."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from goniometer.database import load_database, simulate_database
from models.report import build_report
from models.report.spheres import FIGURE1_FILE, FIGURE1_MODELS, SPHERE_ANGLES_DEG, spheres_cache_path

DEFINITION = Path(__file__).resolve().parents[1] / "data" / "figure1_database.toml"
PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    base = tmp_path_factory.mktemp("figure1")
    simulate_database(load_database(DEFINITION), base / "results", "quick")
    models = list(FIGURE1_MODELS)   # the slab is rendered alone (no BTDF model asked: keeps the test fast)
    summary = build_report(base / "results", base / "report", models=models)
    return base, summary, models


def _data(index: Path) -> dict:
    m = re.search(r'<script type="application/json" id="report-data">(.*?)</script>', index.read_text(), re.S)
    return json.loads(m.group(1))


def test_every_material_has_its_spheres(built):
    base, summary, _ = built
    out = base / "report"
    data = _data(summary.index_html)
    assert len(data["materials"]) == 2
    for m in data["materials"]:
        assert [s["angle"] for s in m["spheres"]] == list(SPHERE_ANGLES_DEG), m["name"]
        for s in m["spheres"]:
            assert (out / s["src"]).read_bytes()[:8] == PNG
            assert set(s["rmse"]) == set(m["errors"]), "every evaluated model is rendered"
        assert spheres_cache_path(out, m["name"]).is_file()
    slab = next(m for m in data["materials"] if m["category"] == "slab")
    assert "BTDF" in slab["spheres"][0]["reference"]


def test_figure1_is_in_the_page(built):
    base, summary, _ = built
    out = base / "report"
    fig = summary.figure1
    assert fig is not None and fig["material"] == "metal/M5-a0_0.05-a1_0.2"
    assert fig["models"] == list(FIGURE1_MODELS) and fig["missing"] == []
    assert (out / FIGURE1_FILE).read_bytes()[:8] == PNG
    html = summary.index_html.read_text()
    assert 'id="figure1"' in html and f'src="{FIGURE1_FILE}"' in html


def test_rerun_reuses_the_cached_spheres(built, monkeypatch):
    base, _, models = built
    import models.render.compare as compare

    def boom(*a, **k):
        raise AssertionError("spheres rendered again although the cache is current")

    monkeypatch.setattr(compare, "shade_views", boom)
    import models.report.spheres as spheres
    monkeypatch.setattr(spheres, "render_views", boom)
    summary = build_report(base / "results", base / "report", models=models)
    assert summary.figure1["src"] == FIGURE1_FILE
