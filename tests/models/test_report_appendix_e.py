"""The appendix E report section (models.report.appendix_e) on hand-made evaluations and energies."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from models.report.appendix_e import appendix_e_markdown, appendix_e_section, fraction_stderr, is_appendix_e
from models.report.results import MaterialResult, ReportMaterial

THETA = np.array([0.0, 80.0])


def _file(path: Path, refl: np.ndarray, unbased: np.ndarray | None) -> Path:
    with h5py.File(path, "w") as f:
        f["incident/theta_deg"] = THETA
        f["energy/reflected"] = refl
        f["energy/reflected_stderr"] = np.full_like(refl, 0.001)
        if unbased is not None:
            f["energy/reflected_without_base"] = unbased
            f["energy/reflected_without_base_stderr"] = np.full_like(refl, 0.0005)
    return path


def _mat(tmp, cat, d, g, refl, unbased=None):
    name = f"{cat}/E-d_{d}-g_{g}"
    p = _file(tmp / f"{cat}-{d}-{g}.h5", refl, unbased)
    return ReportMaterial(name, cat, name, {"d": d, "g": g}, "classic", p, 1000, (90, 360))


def _err(x, nf=0.01):
    e = {"rmse_mean": x, "noise_floor_mean": nf}
    return {"internal": e, "total": e}


def test_claims_from_hand_made_numbers(tmp_path):
    # belcour-fwd's errors: at d = 1 lowest at g = 0.9 (holds), at d = 8 lowest at g = 0.3 (does not)
    errs = {(1.0, 0.3): 0.5, (1.0, 0.9): 0.2, (8.0, 0.3): 0.1, (8.0, 0.9): 0.4}
    metal_r = np.array([[0.4, 0.2, 0.5], [0.6, 0.4, 0.8]])
    unbased_r = np.array([[0.1, 0.05, 0.25], [0.3, 0.2, 0.6]])
    results = []
    for d in (1.0, 8.0):
        m0 = _mat(tmp_path, "metal", d, 0.0, metal_r, unbased_r)
        results.append(MaterialResult(m0, {"side": "brdf", "models": {}}, "k"))   # g = 0: refused
        for g in (0.3, 0.9):
            m = _mat(tmp_path, "metal", d, g, metal_r, unbased_r)
            results.append(MaterialResult(m, {"side": "brdf", "models": {"belcour-fwd": _err(errs[(d, g)])}}, "k"))
    # a file written before the per-path record: named, not counted
    old = _mat(tmp_path, "metal", 1.0, 0.6, metal_r)
    results.append(MaterialResult(old, {"side": "brdf", "models": {"belcour-fwd": _err(0.3)}}, "k"))
    assert is_appendix_e([r.material for r in results])
    sec = appendix_e_section(results)
    c1 = sec["claim_best_g"]
    assert [(c["d"], c["best_g"], c["holds"]) for c in c1["per_depth"]] == [(1.0, 0.9, True), (8.0, 0.3, False)]
    assert (c1["n"], c1["agree"], c1["verdict"]) == (2, 1, "partly")
    assert not any(c["noise_limited"] for c in c1["per_depth"])
    assert sec["claim_turn_around"]["unrecorded"] == ["metal/E-d_1.0-g_0.6"]
    rows = sec["claim_turn_around"]["rows"]
    assert len(rows) == 2 * 3 * 2
    r = rows[0]
    assert r["fraction"] == pytest.approx([0.25, 0.25, 0.5])
    assert r["fraction_mean"] == pytest.approx(0.4 / 1.1)
    # one standard error of the ratio of a part to its whole on the same paths
    assert r["fraction_stderr"][0] == pytest.approx(np.sqrt(0.5 * 0.0005**2 + 0.25**2 * 0.001**2) / 0.4)
    md = appendix_e_markdown(sec)
    assert "Verdict: **partly** (1 of 2 depths)" in md
    assert "1 file(s) predate the per-path record" in md
    assert "| 1 | refused | 5.000e-01 | 3.000e-01 | **2.000e-01** | 0.9 | yes |" in md
    assert "0.500 ± " in md and "larger at 80° than at 0° for 6 of 6" in md


def test_fraction_stderr_matches_replicates():
    """The delta-method error of U / R (U a part of R on the same paths) against the spread of the
    ratio over 400 independent replicate experiments of 2000 paths each."""
    rng = np.random.default_rng(3)
    n, reps = 2000, 400
    fracs, ses, naive = [], [], []
    for _ in range(reps):
        w = rng.exponential(0.5, n) * (rng.random(n) < 0.7)       # per-path reflected weight
        u = w * (rng.random(n) < 0.3)                               # the part that never reached the base
        r_, u_ = w.mean(), u.mean()
        sr, su = w.std(ddof=1) / np.sqrt(n), u.std(ddof=1) / np.sqrt(n)
        fracs.append(u_ / r_)
        ses.append(float(fraction_stderr(np.array(u_), np.array(su), np.array(r_), np.array(sr))))
        naive.append(u_ / r_ * np.hypot(su / u_, sr / r_))
    spread = np.std(fracs, ddof=1)
    # the spread of a standard deviation over 400 replicates is ~3.5 %; 5 sigma
    assert abs(np.mean(ses) / spread - 1.0) < 0.18
    # the test can fail: the independent-ratio formula (no covariance) is clearly off here
    assert abs(np.mean(naive) / spread - 1.0) > 0.18
