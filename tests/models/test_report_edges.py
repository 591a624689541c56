"""A report never dies for one figure (models/report/build.py, spheres.py; docs/report.md): over one
material of each category, the near-Dirac slabs of configs/bati2019.toml included (alpha0 = alpha1 =
0.001, black on the backlit spheres), the report finishes, every sphere PNG says why its reference
cannot be shown, ``errors.json`` lists what was not drawn, and a figure that raises costs only itself."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from goniometer.atomic import TEMP_GLOB
from goniometer.cli import main as gonio
from goniometer.database import load_database, simulate_database
import models.report.build as build_module
from models.report import build_report
from models.report.spheres import SPHERE_ANGLES_DEG
from tests.conftest import child_sigint_default

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


# ---------------------------------------------------------------------- a reference without a valid cell

TINY = Path(__file__).resolve().parents[1] / "data" / "tiny_database.toml"
PLASTICS = ("plastic/P1-a0_0.05", "plastic/P1-a0_0.2")


def _mask_out(path: Path) -> None:
    """Mark every cell of a simulated file's BRDF as invalid (a reference without a valid cell)."""
    import h5py
    with h5py.File(path, "r+") as f:
        f["brdf/mask"][...] = 0


@pytest.fixture
def plastics(tmp_path):
    results = tmp_path / "results"
    db = load_database(TINY)
    for name in PLASTICS:
        simulate_database(db, results, "quick", only=name)
    return results


def test_a_material_without_a_valid_cell_is_its_records_failure(plastics, tmp_path, capsys):
    empty = plastics / "plastic" / "P1-a0_0.05.h5"
    _mask_out(empty)
    out = tmp_path / "report"
    capsys.readouterr()
    assert gonio(["report", str(plastics), "--out", str(out), "--model", "ww09", "--model", "elek10",
                  "--incidents", "60"]) == 1
    _, err = capsys.readouterr()
    # one warning for the material (both models fail for one reason; its spheres, without a value,
    # are warnings of their own), the other material judged
    warnings = [x for x in err.splitlines() if x.startswith("warning: ") and " failed: " in x]
    assert len(warnings) == 1, warnings
    assert warnings[0].startswith("warning: plastic/P1-a0_0.05: ww09, elek10 failed: the reference has no valid cell")
    records = json.loads((out / "errors.json").read_text())
    assert {r["material"] for r in records} == {"plastic/P1-a0_0.2"} and len(records) == 2
    assert all(r[p]["cells"] == r[p]["cells_total"] == 2 * 9 * 18 for r in records for p in ("internal", "total"))
    table = (out / "tables" / "plastic.md").read_text()
    row = next(x for x in table.splitlines() if x.startswith("| plastic/P1-a0_0.05 "))
    assert row.count("| failed ") == 2 and "| 0 of " in row, row
    assert "cells" in (out / "tables" / "plastic.csv").read_text().splitlines()[0].split(",")


def test_a_report_that_judges_nothing_is_refused(plastics, tmp_path, capsys):
    for name in PLASTICS:
        _mask_out(plastics / f"{name}.h5")
    out = tmp_path / "report"
    capsys.readouterr()
    assert gonio(["report", str(plastics), "--out", str(out), "--model", "ww09"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines[-1].startswith("gonio: error: ") and "nothing to report" in lines[-1] and "no valid cell" in lines[-1]
    assert not any(x.startswith("gonio: error") for x in lines[:-1])
    assert not (out / "index.html").exists() and len(list((out / "cache").rglob("*.json"))) == 2


def test_an_interrupted_report_says_what_it_cached(plastics, tmp_path, capsys, monkeypatch):
    out = tmp_path / "report"
    real = build_module.evaluate_material
    calls = []

    def second_interrupts(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*args, **kwargs)
    monkeypatch.setattr(build_module, "evaluate_material", second_interrupts)
    capsys.readouterr()
    assert gonio(["report", str(plastics), "--out", str(out), "--model", "ww09", "--incidents", "60",
                  "--jobs", "1"]) == 130   # one job: here, where the monkeypatch is
    err = capsys.readouterr().err
    assert err.splitlines()[0] == "report: 2 material(s); loading the models ..."
    line = err.strip().splitlines()[-1]
    assert line.startswith("gonio: interrupted; ") and "cached evaluations of 1 material(s)" in line
    assert "rerun the same command to resume" in line and "nothing written" not in err
    monkeypatch.setattr(build_module, "evaluate_material", real)
    summary = build_report(plastics, out, models=["ww09"], incidents_for_figures=[60.0])
    assert summary.reused == ["plastic/P1-a0_0.05"] and summary.evaluated == ["plastic/P1-a0_0.2"]


def test_the_report_progress_keeps_its_last_words(plastics, tmp_path, capsys):
    assert gonio(["report", str(plastics), "--out", str(tmp_path / "report"), "--model", "ww09",
                  "--incidents", "60"]) == 0
    lines = capsys.readouterr().err.splitlines()
    # at once: the models load, then the first material (a first run compiles the models there)
    assert lines[:2] == ["report: 2 material(s); loading the models ...",
                         "report: 2 material(s); plastic/P1-a0_0.05: evaluating ..."]
    last = [x for x in lines if x.startswith("report: 100%")][-1]
    assert last.endswith(" s]") and "figures drawn in" in last, last


@pytest.fixture(scope="module")
def tiny_results(tmp_path_factory) -> Path:
    results = tmp_path_factory.mktemp("tiny") / "results"
    simulate_database(load_database(TINY), results, "quick")
    return results


@pytest.mark.parametrize("who", ["group", "report"])
def test_ctrl_c_stops_the_workers_and_a_rerun_resumes(tiny_results, tmp_path, who):
    """gonio report --jobs 2 interrupted once a material is cached: Ctrl-C at a terminal (the whole
    process group) or a SIGINT to the report alone (which passes it on to its workers): exit status
    130 and its one line, no traceback, no temporary file, no page; the rerun reuses what was cached."""
    results, out = tiny_results, tmp_path / "report"
    proc = subprocess.Popen([sys.executable, "-m", "goniometer.cli", "report", str(results), "--out", str(out),
                             "--jobs", "2"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=child_sigint_default)
    deadline = time.monotonic() + 600
    while not list((out / "cache").rglob("*.json")) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.1)
    assert proc.poll() is None, "the report ended before it could be interrupted"
    if who == "group":
        os.killpg(proc.pid, signal.SIGINT)
    else:
        proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=600)
    assert proc.returncode == 130, err
    lines = err.replace("\r", "\n").strip().splitlines()
    assert lines[-1].startswith("gonio: interrupted; ") and "rerun the same command to resume" in lines[-1]
    assert "Traceback" not in err and "Error" not in err, err
    assert list(out.rglob(TEMP_GLOB)) == [] and not (out / "index.html").exists()
    cached = len(list((out / "cache").rglob("*.json")))
    assert 1 <= cached < 5
    summary = build_report(results, out, jobs=1)
    assert len(summary.reused) == cached and len(summary.evaluated) == 5 - cached
