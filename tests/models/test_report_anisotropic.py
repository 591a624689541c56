"""One report ranking Belcour, anisotropic Belcour, the multilayer LUT model and the fitted models on
a simulated anisotropic coated metal (issue: anisotropic layers and the remaining seed models)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from goniometer.database import load_database, simulate_database
from models.base import ModelError
from models.evaluation import evaluate, isotropized
from models.report import build_report
from goniometer.files import slices as store
from goniometer.database import material_path

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def aniso_results(tmp_path_factory):
    out = tmp_path_factory.mktemp("aniso") / "results"
    db = load_database(ROOT / "tests" / "data" / "tiny_anisotropic.toml")
    simulate_database(db, out, "quick")
    return db, out


def test_isotropic_models_skip_anisotropic_stacks_unless_asked(aniso_results):
    db, out = aniso_results
    ref = store.read(material_path(out, db.materials[0]))
    with pytest.raises(ModelError, match="--isotropize mean"):
        evaluate(ref, ["belcour-fwd", "belcour-aniso"])  # asked for explicitly: a clear error
    ev = evaluate(ref, None)
    assert "isotropize" in ev.skipped["belcour-fwd"] and "belcour-aniso" in ev.errors
    ev = evaluate(ref, None, isotropize="mean")
    assert "belcour-fwd" in ev.errors and "mean roughness" in ev.approximations["belcour-fwd"]
    assert "belcour-aniso" not in ev.approximations
    iso = isotropized(ref.stack)
    assert iso.layers[2].roughness == pytest.approx(0.225) and not iso.layers[2].is_anisotropic


def test_one_report_ranks_physical_and_fitted_models(aniso_results, tmp_path):
    db, out = aniso_results
    summary = build_report(out, tmp_path / "report", fits=True, isotropize="mean")
    records = json.loads(summary.errors_json.read_text())
    models = {r["model"] for r in records}
    assert {"belcour-fwd", "belcour-aniso", "multilayer-lut", "hp15-fit", "ggx1-fit", "ggx2-fit"} <= models
    by = {r["model"]: r for r in records}
    # the anisotropic model does better than its isotropic parent fed the mean roughness
    assert by["belcour-aniso"]["internal"]["rmse_mean"] < by["belcour-fwd"]["internal"]["rmse_mean"]
    html = summary.index_html.read_text()
    assert "belcour-aniso" in html and "hp15-fit" in html and "mean roughness" in html
