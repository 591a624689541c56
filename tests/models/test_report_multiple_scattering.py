"""The multiple-scattering table (models.report.multiple_scattering) on hand-made files and evaluations."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from models.report.multiple_scattering import multiple_scattering_markdown, multiple_scattering_section
from models.report.results import MaterialResult, ReportError, ReportMaterial

THETA = np.array([0.0, 45.0, 80.0])


def _file(path: Path, loss, refl, trans, theta=THETA) -> Path:
    with h5py.File(path, "w") as f:
        f["incident/theta_deg"] = theta
        f["energy/masking_loss"] = np.asarray(loss, float)
        f["energy/reflected"] = np.asarray(refl, float)
        f["energy/transmitted"] = np.asarray(trans, float)
    return path


def _res(tmp, tag, name, cat, errors, **energies):
    p = _file(tmp / f"{tag}-{name.replace('/', '_')}.h5", **energies)
    mat = ReportMaterial(name, cat, name.split("/")[1], {"alpha0": 0.2, "tau": [0.2] * 3}, "classic", p, 1000, (9, 18))
    models = {m: {"internal": {"rmse_mean": i, "noise_floor_mean": 0.001},
                  "total": {"rmse_mean": t, "noise_floor_mean": 0.002}} for m, (i, t) in errors.items()}
    return MaterialResult(mat, {"models": models}, "k")


def test_loss_gain_and_errors_from_hand_made_numbers(tmp_path):
    loss = np.array([[0.01, 0.02, 0.03], [0.02, 0.02, 0.02], [0.10, 0.20, 0.30]])
    refl = np.full((3, 3), 0.5)
    zero = np.zeros((3, 3))
    ss = [_res(tmp_path, "ss", "metal/M1-a0_0.2", "metal", {"a": (0.1, 0.2), "b": (0.3, 0.4)},
               loss=loss, refl=refl, trans=zero),
          _res(tmp_path, "ss", "metal/only-ss", "metal", {"a": (0.1, 0.2)}, loss=zero, refl=refl, trans=zero)]
    ms = [_res(tmp_path, "ms", "metal/M1-a0_0.2", "metal", {"a": (0.15, 0.1), "c": (0.0, 0.0)},
               loss=zero, refl=refl + 0.5 * loss, trans=zero),
          _res(tmp_path, "ms", "slab/only-ms", "slab", {}, loss=zero, refl=refl, trans=zero)]
    sec = multiple_scattering_section(ss, ms)
    assert sec["only_single"] == ["metal/only-ss"] and sec["only_multiple"] == ["slab/only-ms"]
    (row,) = sec["materials"]
    assert row["material"] == "metal/M1-a0_0.2" and row["category"] == "metal" and row["params"] == {"alpha0": 0.2}
    l = row["ss_masking_loss"]
    assert l["mean"] == pytest.approx([0.13 / 3, 0.24 / 3, 0.35 / 3])
    assert l["mean_channels"] == pytest.approx(0.72 / 9)
    assert l["at_0"]["theta"] == 0.0 and l["at_0"]["mean_channels"] == pytest.approx(0.02)
    assert l["at_80"]["theta"] == 80.0 and l["at_80"]["value"] == pytest.approx([0.1, 0.2, 0.3])
    assert row["reflected_gain"]["mean_channels"] == pytest.approx(0.5 * 0.72 / 9)
    assert row["transmitted_gain"]["mean_channels"] == 0.0 and row["ms_masking_loss"]["mean_channels"] == 0.0
    # only the models evaluated on both twins
    assert list(row["models"]) == ["a"]
    a = row["models"]["a"]
    assert (a["internal"]["ss"], a["internal"]["ms"]) == (0.1, 0.15) and a["internal"]["change"] == pytest.approx(0.05)
    assert a["total"]["change"] == pytest.approx(-0.1) and a["total"]["ms_noise_floor"] == 0.002
    cat = sec["by_category"]["metal"]
    assert cat["materials"] == 1 and cat["ss_masking_loss_max"] == pytest.approx(0.08)
    assert cat["models"]["a"]["total"] == pytest.approx({"ss": 0.2, "ms": 0.1, "change": -0.1, "materials": 1})
    md = multiple_scattering_markdown(sec)
    assert "| metal/M1-a0_0.2 | 0.0433, 0.0800, 0.1167 | 0.0800 | 0.0200 | 0.2000 | 0.0400 |" in md
    assert "| metal/M1-a0_0.2 | a | 0.1000 | 0.1500 | +0.0500 | 0.2000 | 0.1000 | -0.1000 |" in md
    assert "only-ss" in md and "only-ms" in md


def test_twins_with_other_incidents_are_refused(tmp_path):
    z = np.zeros((3, 3))
    ss = [_res(tmp_path, "ss", "plastic/P1", "plastic", {}, loss=z, refl=z, trans=z)]
    ms = [_res(tmp_path, "ms", "plastic/P1", "plastic", {}, loss=z, refl=z, trans=z, theta=np.array([0.0, 30.0, 80.0]))]
    with pytest.raises(ReportError, match="other incident directions"):
        multiple_scattering_section(ss, ms)


def test_report_compare_to_on_a_tiny_twin_database(tmp_path):
    import json
    import shutil

    from goniometer.database import load_database, simulate_database
    from models.report import build_report
    root = Path(__file__).resolve().parents[2]
    shutil.copy(root / "tests" / "data" / "tiny_database.toml", tmp_path / "tiny.toml")
    (tmp_path / "tiny-ms.toml").write_text('base = "tiny.toml"\nname = "tiny-ms"\nmultiple_scattering = true\n')
    only = "plastic/P1-a0_0.2"
    simulate_database(load_database(tmp_path / "tiny.toml"), tmp_path / "ss", "quick", only=only, threads=1)
    simulate_database(load_database(tmp_path / "tiny-ms.toml"), tmp_path / "ms", "quick", only=only, threads=1)
    s = build_report(tmp_path / "ms", tmp_path / "rep", models=["ww09"], compare_to=tmp_path / "ss",
                     incidents_for_figures=[])
    sec = json.loads((tmp_path / "rep" / "multiple-scattering.json").read_text())
    assert s.multiple_scattering["materials"][0]["material"] == only == sec["materials"][0]["material"]
    row = sec["materials"][0]
    assert row["ss_masking_loss"]["mean_channels"] > 0.01 and row["ms_masking_loss"]["mean_channels"] == 0.0
    assert row["reflected_gain"]["mean_channels"] > 0 and set(row["models"]) == {"ww09"}
    assert (tmp_path / "rep" / "multiple-scattering" / "cache").is_dir()
    assert "| plastic/P1-a0_0.2 | ww09 |" in (tmp_path / "rep" / "multiple-scattering.md").read_text()
    with pytest.raises(ReportError):   # not a results directory
        build_report(tmp_path / "ms", tmp_path / "rep2", models=["ww09"], compare_to=tmp_path / "rep" / "x",
                     incidents_for_figures=[])
