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

import h5py
import numpy as np
import pytest

from goniometer.files import slices as store
from goniometer.database import load_database, simulate_database
from goniometer.grids.slice_grid import SliceGrid, light_direction
import models.report.build as report_module
from models.evaluation import evaluate
from models.report import ReportError, build_report, model_style, open_results
from models.compare.errors import luminance
from models.evaluation import group_name
from models.report.evaluation import cache_paths, figure_slices, load_slices, round_mantissa, run_evaluation
from models.report.figures import DISK_PX, ORDER_DISK_PX, PANEL_GAP_PX, PAPER_COLOURS
from models.report.geometry import plane_cells
from models.report import hover as hover_mod

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
    # progress once the inputs are read, before each material (done so far, "evaluating ...") and once
    # it is done
    assert calls[0] == (0, 5, "loading the models ...")
    calls = calls[1:]
    assert [c[0] for c in calls] == [0, 1, 1, 2, 2, 3, 3, 4, 4, 5] and all(c[1] == 5 for c in calls)
    assert all(m in c[2] for c, m in zip(calls[::2], summary.materials))
    assert all(m in c[2] for c, m in zip(calls[1::2], summary.materials))
    assert all(c[2].endswith(": evaluating ...") for c in calls[::2])


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
        paths.add(m["hover"])
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


# ---------------------------------------------------------------------- colour bars and hover data

def test_hover_codes_round_trip():
    rng = np.random.default_rng(7)
    v = np.exp(rng.uniform(np.log(hover_mod.F_MIN), np.log(hover_mod.F_MAX), 20_000))
    back = hover_mod.decode(hover_mod.encode(v))
    assert np.max(np.abs(back / v - 1)) <= hover_mod.RELATIVE_PRECISION * (1 + 1e-9)
    assert hover_mod.RELATIVE_PRECISION < 3e-4     # about 4 significant digits
    special = hover_mod.decode(hover_mod.encode(np.array([0.0, 1e-9, 2e7, -1.0, np.nan, hover_mod.F_MIN])))
    assert special[0] == 0 and special[1] == 0 and special[2] == np.inf and special[3] == -np.inf
    assert np.isnan(special[4]) and math.isclose(special[5], hover_mod.F_MIN, rel_tol=1e-12)
    assert DISK_PX % hover_mod.HOVER_PX == 0, "a hover pixel is a block of image pixels"
    S = hover_mod.HOVER_PX
    inside = hover_mod.disk_pixels(S)
    c = (np.arange(S) + 0.5) / S * 2 - 1
    assert np.array_equal(inside, c[None, :] ** 2 + c[:, None] ** 2 < 1)
    assert inside[S // 2, 0] and not inside[0, 0] and 0.75 < inside.mean() < math.pi / 4 + 0.01


def _hover_doc(out: Path, rel: str) -> dict:
    text = (out / rel).read_text()
    m = re.fullmatch(r"//[^\n]*\n\(window\.GONIO_HOVER = window\.GONIO_HOVER \|\| \{\}\)\[(\"[^\"]*\")\] = (.*);\n",
                     text, re.S)
    assert m, text[:200]
    doc = json.loads(m.group(2))
    assert json.loads(m.group(1)) == doc["material"]
    return doc


def test_hover_data_is_the_reference_at_the_pixel_direction(report, results_dir):
    """The hover values of the classic-slice metal, checked against the cells found from each
    coarse pixel's direction by the classic grid's own definition (uniform theta and phi bins)."""
    summary, out, _, _ = report
    data = _html_data(summary.index_html)
    m = next(x for x in data["materials"] if x["category"] == "metal")
    assert m["parametrization"] == "classic"
    doc = _hover_doc(out, m["hover"])
    assert doc["format"] == hover_mod.HOVER_FORMAT and doc["material"] == m["name"] and doc["size"] == hover_mod.HOVER_PX
    assert [i["index"] for i in doc["incidents"]] == [i["index"] for i in m["incidents"]]
    path = next(x.path for x in open_results(results_dir)[1] if x.name == m["name"])
    ref = store.read(path)
    entry = json.loads(cache_paths(out, m["name"])[0].read_text())
    slices = load_slices(cache_paths(out, m["name"])[1], entry["key"], list(m["errors"]))
    S = doc["size"]
    rows, cols = np.nonzero(hover_mod.disk_pixels(S))
    x, y = (2 * cols + 1) / S - 1, 1 - (2 * rows + 1) / S
    theta = np.degrees(np.arccos(np.sqrt(1 - x * x - y * y)))
    phi = np.degrees(np.arctan2(y, x)) % 360
    nt, nph = ref.brdf.grid.n_theta, ref.brdf.grid.n_phi
    ii, jj = (theta / 90 * nt).astype(int), (phi / 360 * nph).astype(int)
    for e in doc["incidents"]:
        k = e["index"]
        assert ref.phi_deg[k] == 0.0   # classic cells are binned in v's own azimuth
        ok = ref.brdf.mask[k][ii, jj]
        lum = luminance(ref.brdf.value[k], axis=0, keepdims=False)[ii, jj]
        se = luminance(ref.brdf.stderr[k], axis=0, keepdims=False)[ii, jj]
        got, got_se = hover_mod.decode(e["reference"]), hover_mod.decode(e["reference_se"])
        assert np.all(np.isnan(got[~ok])) and ok.sum() > 0.8 * ok.size
        pos = ok & (lum >= hover_mod.F_MIN)
        assert np.all(np.abs(got[pos] / lum[pos] - 1) <= hover_mod.RELATIVE_PRECISION * 1.000001)
        assert np.all(got[ok & (lum < hover_mod.F_MIN)] == 0)
        assert np.all(np.abs(got_se[ok & (se > 0)] / se[ok & (se > 0)] - 1) <= hover_mod.RELATIVE_PRECISION * 1.000001)
        assert set(e["models"]) == set(m["errors"])
        for name, (top, internal) in slices.items():
            want = luminance(top[k] + internal[k], axis=0, keepdims=False)[ii, jj]
            got_m = hover_mod.decode(e["models"][name])
            sel = ok & (want > hover_mod.F_MIN)
            # the cache keeps 11 mantissa bits; the hover data was made from the full-precision slices
            assert np.all(np.abs(got_m[sel] / want[sel] - 1) <= hover_mod.RELATIVE_PRECISION + 2.0 ** -11), name


def test_colour_bar_numbers_and_colours_match_the_images(report):
    """The legends the page draws are the images' scales and colours: the band edges are the
    inverse remap of the luminance scale, and every pixel of the band panel of a top view is a
    legend colour (or an edge, masked, outside or light-marker pixel)."""
    from PIL import Image
    summary, out, _, _ = report
    data = _html_data(summary.index_html)
    bands = np.array([[int(h[i:i + 2], 16) for i in (1, 3, 5)] for h in data["colours"]["bands"]])
    assert len(bands) == data["colours"]["iso_levels"] == 10
    assert data["views"]["top"] == {"disk_px": DISK_PX, "gap_px": PANEL_GAP_PX, "panels": 3}
    assert data["views"]["orders"]["disk_px"] == ORDER_DISK_PX
    specials = np.array([[26, 26, 26], [255, 255, 255], [209, 209, 209], [115, 115, 115], [255, 217, 0]])
    allowed = np.concatenate([bands, specials])
    for m in data["materials"]:
        for inc in m["incidents"]:
            lg = inc["legend"]
            edges = np.array(lg["band_edges"])
            assert edges[0] == 0 and np.all(np.diff(edges) > 0) and len(edges) == 11
            assert math.isclose(edges[-1], math.expm1(inc["scale"]) ** 2, rel_tol=1e-3)
            assert math.isclose(edges[5], math.expm1(inc["scale"] / 2) ** 2, rel_tol=1e-3)
            assert lg["rgb_white"] > 0 and len(inc["orders_legend"]) == m["orders_k"]
            assert [o["factor"] for o in inc["orders_legend"]] == [1.0] + [2.0] * (m["orders_k"] - 1)
        img = np.asarray(Image.open(out / m["incidents"][-1]["top"]["reference"]).convert("RGB")).astype(int)
        panel = img[:, DISK_PX + PANEL_GAP_PX:2 * DISK_PX + PANEL_GAP_PX].reshape(-1, 3)
        dist = np.abs(panel[:, None, :] - allowed[None, :, :]).max(axis=2).min(axis=1)
        assert np.all(dist <= 1), f"{m['name']}: colours outside the legend: {np.unique(panel[dist > 1], axis=0)[:5]}"
        present = np.abs(panel[:, None, :] - bands[None, :, :]).max(axis=2).min(axis=0) <= 1
        assert present.sum() >= 2, "the band panel shows the legend's colours"


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
    # raised in a worker process: the same error here, the other workers stopped, no temporary file left
    with pytest.raises(ReportError) as e:
        build_report(broken, tmp_path / "out-jobs", jobs=2)
    assert str(bad) in str(e.value) and list((tmp_path / "out-jobs").rglob(".*.tmp-*")) == []
    with pytest.raises(ReportError, match="jobs = 0: the number of worker processes must be a whole number >= 1"):
        build_report(results_dir, tmp_path / "out", jobs=0)
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


def test_a_spectral_database_is_refused(tmp_path, capsys):
    """The report reads RGB slices: over a spectral database it stops with one line naming the file
    (docs/database-format.md section 5), with or without the definition, and the CLI exits 2."""
    from goniometer.cli import main
    definition = TINY.parent / "tiny_spectral_database.toml"
    results = tmp_path / "spectral"
    simulate_database(load_database(definition), results, "quick", only="metal/*")
    gold = results / "metal" / "gold-a0_0.2.h5"
    for kw in ({}, {"definition": definition}):
        with pytest.raises(ReportError, match=r"gold-a0_0\.2\.h5: a spectral run \(6 wavelength bins\); the report") as e:
            build_report(results, tmp_path / "out", **kw)
        assert str(gold) in str(e.value) and "\n" not in str(e.value)
    mf = json.loads((results / "database.json").read_text())
    mf["definition"] = str(tmp_path / "gone.toml")     # the materials then come from the files
    (results / "database.json").write_text(json.dumps(mf))
    with pytest.raises(ReportError, match="a spectral run"):
        open_results(results)
    assert main(["report", str(results), "--out", str(tmp_path / "cli")]) == 2
    err = capsys.readouterr().err
    assert "a spectral run (6 wavelength bins)" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "cli" / "index.html").exists()


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


def test_the_cache_keeps_each_array_once_and_what_the_figures_were_drawn_from(report, results_dir):
    """issue 34: equal arrays (a top lobe several models share) are one dataset of the cache, each
    chunked per incident direction; what a fresh evaluation hands to the figures is, bit for bit,
    what a rerun reads back from the cache (so a rerun draws the same figures)."""
    _, out, _, _ = report
    name = "metal/M4-a0_0.2-a1_0.2"
    json_path, h5_path = cache_paths(out, name)
    entry = json.loads(json_path.read_text())
    names = list(entry["evaluation"]["models"])
    with h5py.File(h5_path, "r") as f:
        data = {(n, part): f[f"{group_name(n)}/{part}"] for n in names for part in ("top", "internal")}
        address = {k: h5py.h5o.get_info(d.id).addr for k, d in data.items()}
        arrays = {k: d[()] for k, d in data.items()}
        assert all(d.chunks == (1,) + d.shape[1:] and d.compression == "gzip" for d in data.values())
    keys = list(arrays)
    for i, a in enumerate(keys):
        for b in keys[i + 1:]:
            same = arrays[a].tobytes() == arrays[b].tobytes()
            assert (address[a] == address[b]) == same, (a, b)
    assert len(set(address.values())) < len(address), "the models' shared top lobe is stored once"
    ref = store.read(next(p for p in _h5_files(results_dir) if p.stem == "M4-a0_0.2-a1_0.2"))
    _, fresh = run_evaluation(ref, None, 5)
    drawn, back = figure_slices(fresh), load_slices(h5_path, entry["key"], names)
    assert set(drawn) == set(back) == set(names)
    for n in names:
        for k in range(2):
            assert drawn[n][k].dtype == back[n][k].dtype == np.float64
            assert drawn[n][k].tobytes() == back[n][k].tobytes(), n


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


_FIT_JS = """
const tables = Array.from(document.querySelectorAll('table')).map(function (t) {
  const box = t.parentElement;
  return {id: t.id || t.className, table: t.scrollWidth, box: box.clientWidth, box_scroll: box.scrollWidth};
});
return {inner: window.innerWidth, doc: document.documentElement.scrollWidth, tables: tables};
"""


def _assert_fits(driver, what: str) -> None:
    """At the 1 400-pixel window, the page and every table fit without horizontal scrolling."""
    fit = driver.execute_script(_FIT_JS)
    assert fit["inner"] == 1400, fit
    assert fit["doc"] <= fit["inner"], f"{what}: the page scrolls horizontally: {fit}"
    assert any(t["id"] == "material-errors" for t in fit["tables"])
    for t in fit["tables"]:
        assert t["table"] <= t["box"] and t["box_scroll"] <= t["box"], f"{what}: table {t['id']} overflows: {t}"


def _hover(driver, img_id: str, panel: int, row: int, col: int) -> dict:
    """Move the pointer over coarse hover pixel (row, col) of disk ``panel`` of a top view; returns
    the read-out's text and data attributes once it shows a value."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By
    img = driver.find_element(By.ID, img_id)
    driver.execute_script("arguments[0].scrollIntoView({block: 'center'});", img)
    rect = driver.execute_script("const r = arguments[0].getBoundingClientRect();"
                                 "return [r.width, r.height, arguments[0].naturalWidth];", img)
    block = DISK_PX / hover_mod.HOVER_PX
    k = rect[0] / rect[2]     # CSS pixels per image pixel
    x = (panel * (DISK_PX + PANEL_GAP_PX) + (col + 0.5) * block) * k - rect[0] / 2
    y = (row + 0.5) * block * k - rect[1] / 2
    ActionChains(driver).move_to_element_with_offset(img, round(x), round(y)).perform()
    _wait(driver, lambda d: re.search(r"reference L = \S*\d", d.find_element(By.ID, "hover-readout").text),
          "hover read-out with the reference value")
    return driver.execute_script("const b = document.getElementById('hover-readout');"
                                 "return {text: b.innerText, hidden: b.hidden, row: +b.dataset.row, "
                                 "col: +b.dataset.col, panel: +b.dataset.panel};")


def test_html_browser_in_headless_chromium(report, browser, results_dir):
    from selenium.webdriver.common.action_chains import ActionChains
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
    assert len(metal["errors"]) >= 10, "the metal shows the most models: the widest error table"
    _assert_fits(browser, "metal")

    # colour bars under every top view and every bounce-order column, with the legend's numbers
    for name in ("reference", *metal["errors"]):
        fig = browser.find_element(By.CSS_SELECTOR, f'#topviews figure[data-model="{name}"]')
        kinds = {e.get_attribute("data-colorbar") for e in fig.find_elements(By.CSS_SELECTOR, "[data-colorbar]")}
        assert kinds == {"rgb", "bands", "diverging"}, (name, kinds)
        bands = fig.find_element(By.CSS_SELECTOR, '[data-colorbar="bands"]')
        assert len(bands.find_elements(By.CSS_SELECTOR, ".cbar-strip span")) == 10
        assert "1/sr" in bands.text and "1/sr" in fig.find_element(By.CSS_SELECTOR, '[data-colorbar="rgb"]').text
        top_edge = float(bands.find_elements(By.CSS_SELECTOR, ".cbar-ticks span")[-1].text)
        assert math.isclose(top_edge, inc["legend"]["band_edges"][-1], rel_tol=5e-3)
        diverging = fig.find_element(By.CSS_SELECTOR, '[data-colorbar="diverging"]').text
        lim = float(re.search(r"\+(\S+)", diverging).group(1))
        assert math.isclose(lim, inc["diff_scale"], rel_tol=5e-3), (diverging, inc["diff_scale"])
    order_bars = browser.find_elements(By.CSS_SELECTOR, '#orders-legend [data-colorbar="bands"]')
    assert len(order_bars) == metal["orders_k"]

    # hover read-out: aim at a coarse pixel whose 3 x 3 neighbourhood is valid; the page must name a
    # pixel within one of it, and show that pixel's direction and the reference luminance of its cell
    from models.report.geometry import pixel_map
    ref = store.read(next(x.path for x in open_results(results_dir)[1] if x.name == metal["name"]))
    k = inc["index"]
    S = hover_mod.HOVER_PX
    pm = pixel_map(ref.brdf.grid, light_direction(ref.theta_deg[k], ref.phi_deg[k]), ref.brdf.mask[k], S)
    lum = luminance(ref.brdf.value[k], axis=0, keepdims=False)
    cand = [(r, c) for r in range(2, S - 2) for c in range(2, S - 2)
            if pm.ok[r - 1:r + 2, c - 1:c + 2].all() and (lum[pm.ii[r - 1:r + 2, c - 1:c + 2],
                                                               pm.jj[r - 1:r + 2, c - 1:c + 2]] > 0).all()]
    assert cand
    row, col = cand[len(cand) // 3]
    for panel in (0, 2):
        ro = _hover(browser, "img-top-reference", panel, row, col)
        assert ro["panel"] == panel and abs(ro["row"] - row) <= 1 and abs(ro["col"] - col) <= 1, (ro, row, col)
        r, c = ro["row"], ro["col"]
        x, y = (2 * c + 1) / S - 1, 1 - (2 * r + 1) / S
        th, ph = math.degrees(math.acos(math.sqrt(1 - x * x - y * y))), math.degrees(math.atan2(y, x)) % 360
        got = re.search(r"θv = ([\d.]+)°, φv = ([\d.]+)°", ro["text"])
        assert got and abs(float(got.group(1)) - th) <= 0.051 and abs(float(got.group(2)) - ph) <= 0.051, ro["text"]
        value = float(re.search(r"reference L = (\S+) ± (\S+) 1/sr", ro["text"]).group(1))
        want = lum[pm.ii[r, c], pm.jj[r, c]]
        assert math.isclose(value, want, rel_tol=5e-3 + hover_mod.RELATIVE_PRECISION), (value, want)
        for name in metal["errors"]:
            assert re.search(re.escape(name) + r"\s+\d", ro["text"]), (name, ro["text"])
    # the plane-of-incidence plot: the plotted point nearest the pointer, with the plotted value
    grid, light = ref.brdf.grid, light_direction(ref.theta_deg[k], ref.phi_deg[k])
    xs, prow, pcol = plane_cells(grid, light, float(ref.phi_deg[k]), ref.brdf.mask[k])
    plotted = 0.5 * (lum[prow, pcol[:, 0]] + lum[prow, pcol[:, 1]])
    part = next(e for e in _hover_doc(out, metal["hover"])["incidents"] if e["index"] == k)["plane"][0]
    assert np.allclose(part["x"], xs, atol=1e-3)
    j = int(np.argmax(np.where(xs > 0, plotted, -1)))    # the brightest point on the mirror side
    box, (x0, x1) = part["box"], part["xlim"]
    img = browser.find_element(By.ID, "img-plane")
    browser.execute_script("arguments[0].scrollIntoView({block: 'center'});", img)
    w, h, nat = browser.execute_script("const r = arguments[0].getBoundingClientRect();"
                                       "return [r.width, r.height, arguments[0].naturalWidth];", img)
    px = box[0] + (xs[j] - x0) / (x1 - x0) * box[2]
    py = box[1] + box[3] / 2
    ActionChains(browser).move_to_element_with_offset(img, round(px * w / nat - w / 2),
                                                      round(py * w / nat - h / 2)).perform()
    _wait(browser, lambda d: d.execute_script("return document.getElementById('hover-readout').dataset.sample")
          == str(j), "plane read-out at the aimed point")
    text = browser.find_element(By.ID, "hover-readout").text
    assert f"signed θv = {xs[j]:.1f}°" in text and "φv = 180°" in text, text
    value = float(re.search(r"reference L = (\S+) ±", text).group(1))
    assert math.isclose(value, plotted[j], rel_tol=5e-3 + hover_mod.RELATIVE_PRECISION), (value, plotted[j])
    ActionChains(browser).move_to_element(browser.find_element(By.ID, "material-title")).perform()
    _wait(browser, lambda d: d.execute_script("return document.getElementById('hover-readout').hidden"),
          "read-out hidden when the pointer leaves the image")

    # hide a model: its top view goes away
    hidden = next(iter(metal["errors"]))
    browser.find_element(By.ID, f"chk-model-{hidden}").click()
    _wait(browser, lambda d: not d.find_elements(By.ID, f"img-top-{hidden}"), "hidden model's top view removed")
    ro = _hover(browser, "img-top-reference", 1, row, col)
    assert not re.search(re.escape(hidden) + r"\s+\d", ro["text"]), "a hidden model is not read out"

    # change a material parameter: slab alpha0 0.2 -> 0.05, keeping the incident angle
    Select(browser.find_element(By.ID, "sel-category")).select_by_value("slab")
    Select(browser.find_element(By.ID, "sel-param-alpha0")).select_by_value("0.05")
    slab = next(m for m in data["materials"] if m["category"] == "slab" and m["params"]["alpha0"] == "0.05")
    _wait(browser, lambda d: d.execute_script("return document.body.dataset.material") == slab["name"], "slab a0=0.05")
    theta = inc["theta"]
    want = next(i for i in slab["incidents"] if i["theta"] == theta)
    _wait(browser, lambda d: _image_loaded(d, "img-plane", want["plane"]), "slab plane image at the same incidence")
    _wait(browser, lambda d: _image_loaded(d, "img-orders", want["orders"]), "slab bounce orders image")
    _assert_fits(browser, "slab")
    Select(browser.find_element(By.ID, "sel-category")).select_by_value("plastic")
    _wait(browser, lambda d: d.execute_script("return document.body.dataset.material").startswith("plastic/"),
          "plastic selected")
    _assert_fits(browser, "plastic")

    severe = [e for e in browser.get_log("browser") if e.get("level") == "SEVERE"]
    assert not severe, severe
