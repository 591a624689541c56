"""The appendix E report section (models.report.appendix_e) on hand-made evaluations and energies."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from models.report.appendix_e import appendix_e_markdown, appendix_e_section, is_appendix_e
from models.report.results import MaterialResult, ReportMaterial

THETA = np.array([0.0, 80.0])


def _file(path: Path, refl: np.ndarray) -> Path:
    with h5py.File(path, "w") as f:
        f["incident/theta_deg"] = THETA
        f["energy/reflected"] = refl
        f["energy/reflected_stderr"] = np.full_like(refl, 0.001)
    return path


def _mat(tmp, cat, d, g, refl):
    name = f"{cat}/E-d_{d}-g_{g}"
    p = _file(tmp / f"{cat}-{d}-{g}.h5", refl)
    return ReportMaterial(name, cat, name, {"d": d, "g": g}, "classic", p, 1000, (90, 360))


def _err(x, nf=0.01):
    e = {"rmse_mean": x, "noise_floor_mean": nf}
    return {"internal": e, "total": e}


def test_claims_from_hand_made_numbers(tmp_path):
    # belcour-fwd's errors: at d = 1 lowest at g = 0.9 (holds), at d = 8 lowest at g = 0.3 (does not)
    errs = {(1.0, 0.3): 0.5, (1.0, 0.9): 0.2, (8.0, 0.3): 0.1, (8.0, 0.9): 0.4}
    metal_r = np.array([[0.4, 0.2, 0.5], [0.6, 0.4, 0.8]])
    black_r = np.array([[0.1, 0.05, 0.25], [0.3, 0.2, 0.6]])
    results, black = [], []
    for d in (1.0, 8.0):
        m0 = _mat(tmp_path, "metal", d, 0.0, metal_r)
        results.append(MaterialResult(m0, {"side": "brdf", "models": {}}, "k"))   # g = 0: refused
        black.append(_mat(tmp_path, "other", d, 0.0, black_r))
        for g in (0.3, 0.9):
            m = _mat(tmp_path, "metal", d, g, metal_r)
            results.append(MaterialResult(m, {"side": "brdf", "models": {"belcour-fwd": _err(errs[(d, g)])}}, "k"))
            black.append(_mat(tmp_path, "other", d, g, black_r))
    assert is_appendix_e([r.material for r in results])
    sec = appendix_e_section(results, black)
    c1 = sec["claim_best_g"]
    assert [(c["d"], c["best_g"], c["holds"]) for c in c1["per_depth"]] == [(1.0, 0.9, True), (8.0, 0.3, False)]
    assert (c1["n"], c1["agree"], c1["verdict"]) == (2, 1, "partly")
    assert not any(c["noise_limited"] for c in c1["per_depth"])
    rows = sec["claim_turn_around"]["rows"]
    assert len(rows) == 2 * 3 * 2
    r = rows[0]
    assert r["fraction"] == pytest.approx([0.25, 0.25, 0.5])
    assert r["fraction_mean"] == pytest.approx(0.4 / 1.1)
    # one standard error of a ratio of two independent estimates
    assert r["fraction_stderr"][0] == pytest.approx(0.25 * np.hypot(0.001 / 0.1, 0.001 / 0.4))
    md = appendix_e_markdown(sec)
    assert "Verdict: **partly** (1 of 2 depths)" in md
    assert "| 1 | refused | 5.000e-01 | **2.000e-01** | 0.9 | yes |" in md
    assert "0.500 ± " in md and "larger at 80° than at 0° for 6 of 6" in md
