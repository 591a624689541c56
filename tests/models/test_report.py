"""The report of a results directory (models/report/): error records, tables, figures, cache,
bad input, reproduction checks, and the static HTML browser driven in a real headless Chromium."""

from __future__ import annotations

import csv
import json
import math
import os
import re
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from goniometer import store
from goniometer.database import load_database, simulate_database
from goniometer.slices import SliceGrid, light_direction
import models.report.build as report_module
from models.evaluation import evaluate
from models.report import ReportError, build_report, model_style, open_results
from models.report.evaluation import round_mantissa
from models.report.figures import PAPER_COLOURS
from models.report.geometry import plane_cells

TINY = Path(__file__).resolve().parents[1] / "data" / "tiny_database.toml"
REQUIRED = ("material", "category", "paper_name", "model", "internal", "total")
CHROMIUM = Path("/usr/bin/chromium")
CHROMEDRIVER = Path("/usr/bin/chromedriver")


@pytest.fixture(scope="module")
def results_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("tiny") / "results"
    simulate_database(load_database(TINY), out, "quick")
    return out


@pytest.fixture(scope="module")
def report(results_dir):
    out = results_dir.parent / "report"
    calls: list[tuple[int, int, str]] = []
    t0 = time.perf_counter()
    summary = build_report(results_dir, out, progress=lambda i, n, msg: calls.append((i, n, msg)))
    return summary, out, calls, time.perf_counter() - t0


def _h5_files(results_dir: Path) -> list[Path]:
    return sorted(p for p in results_dir.rglob("*.h5") if ".partial" not in p.parts)


# ---------------------------------------------------------------------- outputs

def test_errors_json_matches_evaluate(report, results_dir):
    summary, out, calls, _ = report
    records = json.loads((out / "errors.json").read_text())
    assert isinstance(records, list) and len(records) == summary.records
    by_key = {(r["material"], r["model"]): r for r in records}
    assert len(by_key) == len(records), "one record per (material, model)"
    files = _h5_files(results_dir)
    assert len(files) == 5 and len(summary.materials) == 5
    expected_pairs = set()
    for p in files:
        ev = evaluate(store.read(p)).to_json()
        for model, errs in ev["models"].items():
            expected_pairs.add((ev["material"], model))
            rec = by_key[(ev["material"], model)]
            assert rec["internal"] == errs["internal"] and rec["total"] == errs["total"]
            assert rec["category"] == ev["category"] and rec["side"] == ev["side"]
    assert set(by_key) == expected_pairs
    for rec in records:
        assert all(k in rec for k in REQUIRED), rec.keys()
        assert rec["paper_name"] in ("P1", "M4", "S1")
        assert "alpha0" in rec and "tau" in rec
        if rec["category"] == "metal":
            assert rec["alpha1"] == 0.2 and rec["eta1"] == 1.45 and rec["tau_name"] == "A"
        if rec["category"] == "slab":
            assert rec["alpha1"] == 0.2 and "eta1" not in rec
        if rec["category"] == "plastic":
            assert "alpha1" not in rec and rec["rho"] == [0.2, 0.5, 0.8]   # literal in the definition
    assert [c[0] for c in calls] == [1, 2, 3, 4, 5] and all(c[1] == 5 for c in calls)
    assert all(m in c[2] for c, m in zip(calls, summary.materials))


def test_tables_per_category(report):
    summary, out, _, _ = report
    records = json.loads((out / "errors.json").read_text())
    for cat in ("plastic", "metal", "slab"):
        rows = list(csv.DictReader((out / "tables" / f"{cat}.csv").open()))
        mine = [r for r in records if r["category"] == cat]
        assert len(rows) == len(mine) > 0
        for row in rows:
            rec = next(r for r in mine if r["material"] == row["material"] and r["model"] == row["model"])
            assert math.isclose(float(row["internal_rmse_mean"]), rec["internal"]["rmse_mean"], rel_tol=1e-5)
        md = (out / "tables" / f"{cat}.md").read_text()
        assert md.startswith(f"# {cat}")
        for r in mine:
            assert r["model"] in md and r["material"] in md
    for name in ("figures/errors_plastic.png", "figures/errors_metal.png", "figures/errors_slab.png",
                 "figures/errors_overview.png", "reproduction.json", "reproduction.md"):
        assert (out / name).is_file(), name


def _html_data(index: Path) -> dict:
    text = index.read_text()
    m = re.search(r'<script type="application/json" id="report-data">(.*?)</script>', text, re.S)
    assert m, "embedded data"
    return json.loads(m.group(1))


def test_html_is_static_and_every_image_exists(report):
    summary, out, _, _ = report
    text = summary.index_html.read_text()
    assert not re.search(r'(src|href)="(https?:)?//', text), "no network resources"
    assert "<script src" not in text and "<link rel=\"stylesheet\"" not in text
    data = _html_data(summary.index_html)
    paths = set(re.findall(r'<img[^>]+src="([^"]+)"', text))
    assert paths, "the figure-4 plots are in the static page"
    for m in data["materials"]:
        assert m["incidents"] and len(m["incidents"]) == 2
        paths.add(m["energy"])
        for inc in m["incidents"]:
            paths |= {inc["plane"], inc["orders"], *inc["top"].values()}
            assert set(inc["top"]) == {"reference", *m["errors"]}
    paths |= set(data["overview"].values())
    missing = [p for p in paths if not (out / p).is_file()]
    assert not missing, missing
    for href in re.findall(r'<a href="([^"#]+)"', text):
        assert (out / href).is_file(), href


def test_reproduction_checks_are_computed(report):
    summary, out, _, _ = report
    checks = json.loads((out / "reproduction.json").read_text())
    assert checks == json.loads(json.dumps(summary.reproduction))
    verdicts = {c["id"]: c for c in checks}
    assert {c["verdict"] for c in checks} <= {"holds", "partly", "does not hold", "not testable"}
    for c in checks:
        assert c["paper"] and c["test"] and c["source"]
        assert (c["verdict"] == "not testable") == (c["n"] == 0)
    # the tiny database has 2 plastics: ww09 vs elek10 is compared on both
    assert verdicts["plastic-ww09-vs-elek"]["n"] == 2
    # no metal with alpha1 = 0.001 in it
    assert verdicts["metal-a1-0.001-a0-0.2-elek-same"]["verdict"] == "not testable"
    html = summary.index_html.read_text()
    assert all(f'data-check="{c["id"]}"' in html for c in checks)


def test_missing_model_is_reported_as_not_evaluated(results_dir, tmp_path):
    summary = build_report(results_dir, tmp_path / "r", models=["ww09"], incidents_for_figures=[60])
    c = {x["id"]: x for x in summary.reproduction}["plastic-ww09-vs-elek"]
    assert c["verdict"] == "not testable" and "elek10" in c["note"]
    records = json.loads(summary.errors_json.read_text())
    assert {r["model"] for r in records} == {"ww09"}
    data = _html_data(summary.index_html)
    assert all([i["theta"] for i in m["incidents"]] == [60.0] for m in data["materials"])


# ---------------------------------------------------------------------- cache

def test_rerun_uses_the_cache_and_redoes_only_what_changed(report, results_dir, monkeypatch):
    summary, out, _, _ = report
    # pin the model-code key: in a shared working tree other files may change during the test
    monkeypatch.setattr(report_module, "model_code_key", lambda: "pinned-for-the-test")
    t0 = time.perf_counter()
    first = build_report(results_dir, out)
    first_s = time.perf_counter() - t0
    assert first.evaluated == summary.materials, "a new model-code key re-evaluates everything"
    assert first.figures_drawn == summary.materials
    t0 = time.perf_counter()
    again = build_report(results_dir, out)
    rerun_s = time.perf_counter() - t0
    assert again.evaluated == [] and again.reused == summary.materials
    assert again.figures_drawn == [] and again.figures_reused == summary.materials
    assert rerun_s < first_s
    assert json.loads(again.errors_json.read_text()) == json.loads(summary.errors_json.read_text())
    # rewrite one reference (new file content, same data): only that material is redone
    p = _h5_files(results_dir)[0]
    store.write(p, store.read(p))
    third = build_report(results_dir, out)
    assert len(third.evaluated) == 1 and len(third.reused) == 4 and len(third.figures_drawn) == 1
    assert json.loads(third.errors_json.read_text()) == json.loads(summary.errors_json.read_text())


# ---------------------------------------------------------------------- bad input

def test_bad_input_raises_report_error(results_dir, tmp_path):
    with pytest.raises(ReportError, match="no such directory"):
        build_report(tmp_path / "nope", tmp_path / "out")
    plain = tmp_path / "plain"
    plain.mkdir()
    with pytest.raises(ReportError, match="not a results directory"):
        build_report(plain, tmp_path / "out")
    empty = tmp_path / "empty"
    empty.mkdir()
    shutil.copy(results_dir / "database.json", empty / "database.json")
    with pytest.raises(ReportError, match="no finished materials"):
        build_report(empty, tmp_path / "out")
    broken = tmp_path / "broken"
    shutil.copytree(results_dir, broken)
    bad = sorted(broken.rglob("*.h5"))[0]
    bad.write_bytes(b"not an hdf5 file")
    with pytest.raises(ReportError) as e:
        build_report(broken, tmp_path / "out")
    assert str(bad) in str(e.value)
    bad_manifest = tmp_path / "badmf"
    bad_manifest.mkdir()
    (bad_manifest / "database.json").write_text("{ not json")
    with pytest.raises(ReportError, match="database.json"):
        build_report(bad_manifest, tmp_path / "out")
    with pytest.raises(ReportError, match="unknown model"):
        build_report(results_dir, tmp_path / "out", models=["no-such-model"])
    with pytest.raises(ReportError, match="own directory"):
        build_report(results_dir, results_dir)
    with pytest.raises(ReportError, match="is a file"):
        build_report(_h5_files(results_dir)[0], tmp_path / "out")


def test_without_its_definition_parameters_come_from_the_files(results_dir, tmp_path):
    moved = tmp_path / "moved"
    shutil.copytree(results_dir, moved)
    mf = json.loads((moved / "database.json").read_text())
    mf["definition"] = "no/such/definition.toml"
    (moved / "database.json").write_text(json.dumps(mf))
    _, materials, missing, warnings = open_results(moved)
    assert len(materials) == 5 and not missing
    assert any("not found" in w for w in warnings)
    metal = next(m for m in materials if m.category == "metal")
    assert metal.paper_name == "M4" and metal.params["alpha1"] == 0.2 and metal.params["eta1"] == 1.45
    # given explicitly, the definition is used again
    _, materials, _, warnings = open_results(moved, definition=TINY)
    assert not warnings and next(m for m in materials if m.category == "metal").params["tau_name"] == "A"


# ---------------------------------------------------------------------- helpers

def test_model_style_is_fixed_for_paper_models_and_distinct_for_others():
    st = model_style(["ww09", "elek10", "belcour-fwd", "belcour-sym", "multilayer-lut", "zz-new"])
    assert st["ww09"]["colour"] == PAPER_COLOURS["ww09"] and st["belcour-sym"]["colour"] == PAPER_COLOURS["belcour-sym"]
    assert st["multilayer-lut"]["colour"] != st["zz-new"]["colour"]
    assert set(st["multilayer-lut"]["colour"]) and st["multilayer-lut"]["colour"] not in PAPER_COLOURS.values()


def test_plane_cells_classic_and_half():
    grid = SliceGrid("classic", 9, 18)
    x, rows, cols = plane_cells(grid, light_direction(30.0), 0.0, np.ones(grid.shape, bool))
    assert np.allclose(x, np.r_[-np.arange(85, 0, -10), np.arange(5, 90, 10)])
    assert set(map(tuple, cols[x > 0])) == {(8, 9)} and set(map(tuple, cols[x < 0])) == {(0, 17)}
    half = SliceGrid("half", 9, 18)
    x, rows, _ = plane_cells(half, light_direction(0.0), 0.0, np.ones(half.shape, bool))
    th_h = half.theta_centers_deg()
    inside = 2 * th_h < 90
    assert np.allclose(np.sort(np.abs(x)), np.sort(np.r_[2 * th_h[inside], 2 * th_h[inside]]))


def test_round_mantissa_precision():
    a = np.random.default_rng(1).lognormal(0, 5, 1000)
    r = round_mantissa(a)
    assert r.dtype == np.float32 and np.max(np.abs(r / a - 1)) <= 2.0 ** -12 + 1e-7


# ---------------------------------------------------------------------- headless Chromium

def _chromium_or_skip() -> None:
    """Make sure Chromium and its driver are present: install them with apt-get when running as
    root, otherwise skip with the reason."""
    if CHROMIUM.exists() and CHROMEDRIVER.exists():
        return
    why = "not root or no apt-get"
    if hasattr(os, "geteuid") and os.geteuid() == 0 and shutil.which("apt-get"):
        try:
            r = subprocess.run(["apt-get", "install", "-y", "--no-install-recommends", "chromium", "chromium-driver"],
                               env={**os.environ, "DEBIAN_FRONTEND": "noninteractive"}, capture_output=True,
                               text=True, timeout=900)
            why = f"apt-get install failed: {r.stderr.strip()[-300:]}" if r.returncode else why
        except subprocess.TimeoutExpired:
            why = "apt-get install timed out"
    if not (CHROMIUM.exists() and CHROMEDRIVER.exists()):
        pytest.skip(f"headless browser test needs {CHROMIUM} and {CHROMEDRIVER} (Debian packages chromium, "
                    f"chromium-driver): {why}")


@pytest.fixture
def browser():
    _chromium_or_skip()
    webdriver = pytest.importorskip("selenium.webdriver", reason="needs selenium (pip install selenium)")
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service
    opts = Options()
    opts.binary_location = str(CHROMIUM)
    profile = tempfile.mkdtemp(prefix="gonio-chromium-")
    for arg in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--no-first-run",
                "--disable-background-networking", "--disable-component-update", "--disable-sync",
                "--window-size=1400,1000", f"--user-data-dir={profile}"):
        opts.add_argument(arg)
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(str(CHROMEDRIVER)), options=opts)
    try:
        yield driver
    finally:
        driver.quit()
        shutil.rmtree(profile, ignore_errors=True)


def _wait(driver, condition, what: str, timeout: float = 15.0):
    from selenium.webdriver.support.ui import WebDriverWait
    return WebDriverWait(driver, timeout).until(lambda d: condition(d), message=what)


def _image_loaded(driver, element_id: str, src: str) -> bool:
    return bool(driver.execute_script(
        "const i = document.getElementById(arguments[0]);"
        "return !!i && i.getAttribute('src') === arguments[1] && i.complete && i.naturalWidth > 0 "
        "&& i.offsetWidth > 0;", element_id, src))


def test_html_browser_in_headless_chromium(report, browser):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select
    summary, out, _, _ = report
    data = _html_data(summary.index_html)
    browser.get(summary.index_html.resolve().as_uri())
    _wait(browser, lambda d: d.execute_script("return document.body.dataset.material || ''"), "page initialised")
    first = data["materials"][0]
    _wait(browser, lambda d: _image_loaded(d, "img-plane", first["incidents"][0]["plane"]), "first plane image")

    # pick the metal category, then the second incident direction
    Select(browser.find_element(By.ID, "sel-category")).select_by_value("metal")
    metal = next(m for m in data["materials"] if m["category"] == "metal")
    _wait(browser, lambda d: d.execute_script("return document.body.dataset.material") == metal["name"],
          "metal selected")
    Select(browser.find_element(By.ID, "sel-incident")).select_by_value("1")
    inc = metal["incidents"][1]
    _wait(browser, lambda d: _image_loaded(d, "img-plane", inc["plane"]), "plane image of incident 1")
    for name in ("reference", *metal["errors"]):
        _wait(browser, lambda d, n=name: _image_loaded(d, f"img-top-{n}", inc["top"][n]), f"top view of {name}")
    rows = browser.find_elements(By.CSS_SELECTOR, "#material-errors tbody tr[data-model]")
    assert {r.get_attribute("data-model") for r in rows} == set(metal["errors"])

    # hide a model: its top view goes away
    hidden = next(iter(metal["errors"]))
    browser.find_element(By.ID, f"chk-model-{hidden}").click()
    _wait(browser, lambda d: not d.find_elements(By.ID, f"img-top-{hidden}"), "hidden model's top view removed")

    # change a material parameter: slab alpha0 0.2 -> 0.05, keeping the incident angle
    Select(browser.find_element(By.ID, "sel-category")).select_by_value("slab")
    Select(browser.find_element(By.ID, "sel-param-alpha0")).select_by_value("0.05")
    slab = next(m for m in data["materials"] if m["category"] == "slab" and m["params"]["alpha0"] == "0.05")
    _wait(browser, lambda d: d.execute_script("return document.body.dataset.material") == slab["name"], "slab a0=0.05")
    theta = inc["theta"]
    want = next(i for i in slab["incidents"] if i["theta"] == theta)
    _wait(browser, lambda d: _image_loaded(d, "img-plane", want["plane"]), "slab plane image at the same incidence")
    _wait(browser, lambda d: _image_loaded(d, "img-orders", want["orders"]), "slab bounce orders image")

    severe = [e for e in browser.get_log("browser") if e.get("level") == "SEVERE"]
    assert not severe, severe
