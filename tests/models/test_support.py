"""No number without its support (models/compare/errors.py, models/evaluation.py, models/commands/
evaluate.py; docs/models.md section 3, "Support"): every error states the cells it is summed over,
an error over no cell is refused (evaluate, fit: one line, exit 2), one over less than half of the
grid comes with a warning; and the words of gonio evaluate: no skipped lines for fitted models that
were not asked for, one line and exit 2 when no model applies, what "internal" compares for a
spectral simulation.

The measured references are hand-made MERL files of a Lambertian (f = 0.5 / pi) with data only in
the cells whose half-vector angle theta_h lies below a cut: the smaller the cut, the fewer cells of
a coarse slice grid have all of their sub-cells on data."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import goniometer as g
from goniometer.grids import halfdiff
from goniometer.cli import main
from goniometer.files.merl import MERL_SCALE
from goniometer.run.results import SliceData
from goniometer.grids.slice_grid import SliceGrid
from models.compare import errors
from models.compare.errors import LOW_COVERAGE, Coverage, NoCellsError, coverage, require_cells
from models.evaluation import Evaluation

PLASTIC = """name = "plastic/support-test"
category = "plastic"
[[layers]]
type = "interface"
roughness = 0.2
ior = 1.5
[[layers]]
type = "lambertian"
albedo = 0.5
"""
#: the reference grid of the CLI tests: one incident direction, 6 x 12 classic cells of 5 x 5 sub-cells
GRID = ["--incident", "30", "--resolution", "6x12"]


def merl_file(path: Path, theta_h_rows: int) -> Path:
    """A MERL file of a Lambertian of albedo 0.5 with data in the first ``theta_h_rows`` rows of
    theta_h (of 90) and none (stored -1) elsewhere."""
    has = np.zeros(halfdiff.SHAPE, dtype=bool)
    has[:theta_h_rows] = True
    data = np.stack([np.where(has.ravel(), 0.5 / np.pi / s, -1.0) for s in MERL_SCALE])
    path.write_bytes(np.array(halfdiff.SHAPE, dtype="<i4").tobytes() + data.astype("<f8").tobytes())
    return path


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("support")
    (d / "plastic.toml").write_text(PLASTIC)
    # 2 rows (theta_h < 0.02 deg): no 15 x 30 deg cell lies on data; 45 rows (< 22.5 deg): a third of
    # the cells at 30 deg; 90 rows: every cell
    return {"stack": d / "plastic.toml", "none": merl_file(d / "none.binary", 2),
            "part": merl_file(d / "part.binary", 45), "full": merl_file(d / "full.binary", 90)}


def _run(capsys, *argv) -> tuple[int, str, str]:
    capsys.readouterr()
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _error_lines(err: str) -> list[str]:
    return [x for x in err.strip().splitlines() if x.startswith("gonio: error: ")]


# ---------------------------------------------------------------------- the error objects

def _slices(M: int = 2, nt: int = 4, nph: int = 6) -> SliceData:
    rng = np.random.default_rng(1)
    value = rng.uniform(0.1, 1.0, (M, 3, nt, nph))
    orders = np.stack([0.3 * value, 0.7 * value], axis=1)
    mask = np.ones((M, nt, nph), dtype=bool)
    mask[0, :2] = False
    omega = np.full((M, nt, nph), 0.1)
    return SliceData(SliceGrid("classic", nt, nph, "reflection"), value, 0.01 * value, orders, mask, omega,
                     0.01 * value)


def test_every_error_object_counts_its_cells():
    sd = _slices()
    e = errors.error_object(sd.value, sd.stderr, 0.5 * sd.value, sd.proj_solid_angle, sd.mask, cells_total=48)
    assert e["cells"] == 2 * 4 * 6 - 2 * 6 and e["cells_total"] == 48
    # a cell of zero projected solid angle takes no part in the sums: it is not counted either
    omega = sd.proj_solid_angle.copy()
    omega[1, 0, 0] = 0.0
    assert errors.error_object(sd.value, sd.stderr, sd.value, omega, sd.mask)["cells"] == e["cells"] - 1
    # without the grid's count, the arrays' cells
    assert errors.error_object(sd.value, sd.stderr, sd.value, omega, sd.mask)["cells_total"] == sd.mask.size


def test_coverage_and_its_warning_threshold():
    assert Coverage(49, 100).low and not Coverage(50, 100).low
    assert Coverage(49, 100).warning().startswith("the reference has valid data in 49 of 100 cells (49.0 %)")
    assert f"under {100 * LOW_COVERAGE:g} %" in Coverage(1, 100).warning() and Coverage(100, 100).warning() is None


def test_a_simulation_covers_its_grid_and_a_masked_one_is_refused(tmp_path):
    stack = g.stack_from_dict({"name": "p", "category": "plastic", "layers": [
        {"type": "interface", "roughness": 0.3, "ior": 1.5}, {"type": "lambertian", "albedo": 0.5}]})
    for parametrization in ("classic", "half"):
        r = g.simulate(stack, g.SimulationSettings(incident_deg=(0.0, 70.0), rays=2000, resolution=(6, 12),
                                                   parametrization=parametrization, threads=1))
        cov = coverage(r, "brdf")
        # a half grid holds fewer cells than its arrays (those reaching past the horizon): all valid
        assert cov.cells == cov.cells_total == int(np.count_nonzero(r.brdf.mask)), parametrization
        assert (cov.cells_total == r.brdf.mask.size) == (parametrization == "classic")
    r.brdf.mask[:] = False
    with pytest.raises(NoCellsError, match=r"no valid cell on its BRDF \(0 of [\d,]+ cells"):
        require_cells(r, "brdf")


# ---------------------------------------------------------------------- gonio evaluate, gonio fit

def test_evaluate_and_fit_refuse_a_reference_without_a_valid_cell(files, capsys):
    for argv in (["evaluate", files["none"], "--stack", files["stack"], "--model", "ww09", *GRID],
                 ["evaluate", files["none"], "--stack", files["stack"], "--model", "ww09", "--json", *GRID],
                 ["fit", files["none"], "--stack", files["stack"], "--model", "ggx1", "--starts", "1", *GRID]):
        code, out, err = _run(capsys, *argv)
        assert code == 2 and out == "", argv
        (line,) = _error_lines(err)
        assert "none.binary" in line and "no valid cell on its BRDF (0 of 72 cells" in line, line
        assert "5x5 sub-cells" in line and "Traceback" not in err
    # fewer sub-cells reach the data: the reproduction of the issue with --subcells 1 is judged
    code, out, err = _run(capsys, "evaluate", files["part"], "--stack", files["stack"], "--model", "ww09",
                          "--subcells", "1", "--json", *GRID)
    assert code == 0 and json.loads(out)["cells"] > 0


def test_a_partly_covered_reference_is_warned_about_and_its_cells_stated(files, capsys):
    code, out, err = _run(capsys, "evaluate", files["part"], "--stack", files["stack"], "--model", "ww09", "--json",
                          *GRID)
    assert code == 0
    d = json.loads(out)
    cells, total = d["cells"], d["cells_total"]
    assert 0 < cells < LOW_COVERAGE * total and total == 72
    for part in ("internal", "total"):
        assert (d["models"]["ww09"][part]["cells"], d["models"]["ww09"][part]["cells_total"]) == (cells, total)
    warnings = [x for x in err.splitlines() if x.startswith("warning: ")]
    assert len(warnings) == 1 and f"{cells} of 72 cells" in warnings[0] and "part.binary" in warnings[0]
    # the text table states the support in its head line
    code, out, err = _run(capsys, "evaluate", files["part"], "--stack", files["stack"], "--model", "ww09", *GRID)
    assert code == 0 and f"over {cells} of 72 cells" in out.splitlines()[0]
    # a fully covered reference: no warning, every cell
    code, out, err = _run(capsys, "evaluate", files["full"], "--stack", files["stack"], "--model", "ww09", "--json",
                          *GRID)
    assert code == 0 and json.loads(out)["cells"] == 72 and "warning" not in err


def test_fit_says_how_many_cells_it_used(files, capsys):
    code, out, err = _run(capsys, "fit", files["part"], "--stack", files["stack"], "--model", "ggx1", "--starts",
                          "1", "--json", *GRID)
    assert code == 0
    d = json.loads(out)
    assert 0 < d["n_cells"] <= d["cells"] < LOW_COVERAGE * d["cells_total"] and d["cells_total"] == 72
    assert d["errors"]["total"]["cells"] == d["cells"]
    assert sum(x.startswith("warning: ") and "part.binary" in x for x in err.splitlines()) == 1
    code, out, err = _run(capsys, "fit", files["part"], "--stack", files["stack"], "--model", "ggx1", "--starts",
                          "1", *GRID)
    assert code == 0 and f"fitted on {d['n_cells']} cells" in out and f"{d['cells']} of 72 cells" in out


# ---------------------------------------------------------------------- the words of gonio evaluate

def test_evaluate_lists_no_fitted_model_it_was_not_asked_for(files, capsys):
    code, out, _ = _run(capsys, "evaluate", files["full"], "--stack", files["stack"], "--model", "ww09", *GRID)
    assert code == 0 and "skipped" not in out
    code, out, _ = _run(capsys, "evaluate", files["full"], "--stack", files["stack"], "--model", "ww09", "--json",
                        *GRID)
    assert json.loads(out)["skipped"] == {} and json.loads(out)["failed"] == {}


def test_evaluate_where_no_model_applies_is_one_line(files, capsys, monkeypatch):
    from models import registry
    from models.belcour import BelcourBTDF
    from models.weidlich_wilkie import WW09
    # a registry of one BTDF model (no plugin): nothing applies to a plastic, judged on its BRDF
    monkeypatch.setattr(registry, "_plugins", lambda built_in: ())
    monkeypatch.setattr(registry, "_built_in_models", lambda: [BelcourBTDF()])
    code, out, err = _run(capsys, "evaluate", files["full"], "--stack", files["stack"], *GRID)
    assert code == 2 and out == ""
    (line,) = _error_lines(err)
    assert "no model applies to plastic/support-test (judged on its BRDF)" in line and "--model NAME" in line
    monkeypatch.setattr(registry, "_built_in_models", lambda: [WW09(), BelcourBTDF()])
    code, out, err = _run(capsys, "evaluate", files["full"], "--stack", files["stack"], *GRID)
    assert code == 0 and out.splitlines()[2].split()[0] == "ww09"


def test_what_internal_compares_is_said_for_each_reference():
    ev = Evaluation("m", "plastic", "brdf")
    assert ev.internal_compares == "internal paths (order 1 dropped)"
    ev.reference_note = "spectral reference (6 wavelength bins) judged in linear sRGB"
    assert ev.internal_compares == "internal paths (order 1 dropped)"   # a note is not a measurement
    ev.measured = True
    assert "a measurement has no bounce orders" in ev.internal_compares
    assert Evaluation("s", "slab", "btdf").internal_compares == "the whole BTDF"


def test_a_spectral_simulation_is_judged_on_its_internal_paths(tmp_path, capsys):
    cfg = tmp_path / "plastic.toml"
    cfg.write_text(PLASTIC)
    out = tmp_path / "spectral.h5"
    assert main(["simulate", str(cfg), "--out", str(out), "--spectral", "--wavelength-bins", "6", "--rays", "2000",
                 "--incident", "30", "--resolution", "4x8", "--threads", "1"]) == 0
    code, text, _ = _run(capsys, "evaluate", out, "--model", "ww09")
    assert code == 0
    assert "('internal' = internal paths (order 1 dropped);" in text and "a measurement" not in text
    assert "note: spectral reference (6 wavelength bins)" in text
