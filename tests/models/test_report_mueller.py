"""gonio plot on a polarized file (models/report/mueller.py; docs/polarization.md, "Looking at a
polarized file"): the Mueller elements normalized by M00 and the degree of polarization per
incident direction and side, listed by --json; none for a scalar file; the normalization, the
degree of polarization and the signal rule against their definitions."""

from __future__ import annotations

import json

import numpy as np
import pytest

import goniometer as g
from goniometer.cli import main as gonio
from goniometer.files import slices as store
from goniometer.stack import Interface, Medium, Stack
from models.compare.errors import LUMINANCE
from models.render.stokes import MAX_RELATIVE_STDERR
from models.report.mueller import normalized

COATED = Stack("coated", (Interface(0.2, (1.5,) * 3), Medium((0.05,) * 3),
                          Interface(0.3, (0.2, 0.9, 1.3), (3.5, 2.5, 2.0))), "metal")
SLAB = Stack("slab", (Interface(0.3, (1.5,) * 3), Medium((0.1,) * 3), Interface(0.3, (1.0,) * 3)), "slab")


def _run(stack: Stack, polarized: bool) -> g.SimulationResult:
    return g.simulate(stack, g.SimulationSettings(incident_deg=(0.0, 30.0), rays=20_000, resolution=(6, 12),
                                                  polarized=polarized, seed=4, threads=1))


@pytest.fixture(scope="module")
def coated():
    return _run(COATED, True)


def _plot(capsys, path, out, *flags) -> dict:
    assert gonio(["plot", str(path), "--out", str(out), "--json", *flags]) == 0
    return json.loads(capsys.readouterr().out)


def test_plot_draws_the_mueller_and_dop_figures_of_a_polarized_file(coated, tmp_path, capsys):
    path = store.write(tmp_path / "coated.h5", coated)
    doc = _plot(capsys, path, tmp_path / "all")
    names = [p.split("/")[-1] for p in doc["figures"]]
    for theta in (0, 30):
        for kind in ("mueller", "dop"):
            assert f"{kind}_brdf_theta{theta}_phi0.png" in names
    assert not any("btdf" in n for n in names)          # opaque: no BTDF
    for p in doc["figures"]:
        with open(p, "rb") as f:
            assert f.read(8) == b"\x89PNG\r\n\x1a\n"
    assert "M00" in doc["polarization"] and "0.2" in doc["polarization"]
    doc = _plot(capsys, path, tmp_path / "one", "--incident", "30")
    names = [p.split("/")[-1] for p in doc["figures"]]
    assert "mueller_brdf_theta30_phi0.png" in names and "mueller_brdf_theta0_phi0.png" not in names


def test_plot_draws_both_sides_of_a_polarized_slab(tmp_path, capsys):
    path = store.write(tmp_path / "slab.h5", _run(SLAB, True))
    names = [p.split("/")[-1] for p in _plot(capsys, path, tmp_path / "f", "--incident", "0")["figures"]]
    assert {"mueller_brdf_theta0_phi0.png", "mueller_btdf_theta0_phi0.png", "dop_btdf_theta0_phi0.png"} <= set(names)


def test_plot_of_a_scalar_file_draws_no_polarization(tmp_path, capsys):
    path = store.write(tmp_path / "scalar.h5", _run(COATED, False))
    doc = _plot(capsys, path, tmp_path / "f")
    assert "polarization" not in doc
    assert not any(k in p for p in doc["figures"] for k in ("mueller_", "dop_"))
    assert not list((tmp_path / "f").glob("mueller_*")) and not list((tmp_path / "f").glob("dop_*"))


def test_normalized_elements_dop_and_the_signal_rule(coated):
    sd = coated.brdf
    m = 1
    norm, dop, ok = normalized(sd, m)
    w = np.asarray(LUMINANCE)
    mu = np.einsum("c,cijkl->ijkl", w, sd.mueller[m])
    se00 = np.einsum("c,cij->ij", w, sd.mueller_stderr[m, :, :, :, 0, 0])
    want = sd.mask[m] & (mu[..., 0, 0] > 0) & (se00 <= MAX_RELATIVE_STDERR * mu[..., 0, 0])
    np.testing.assert_array_equal(ok, want)
    assert 0 < ok.sum() < ok.size                 # some cells drawn, some greyed by the rule
    np.testing.assert_allclose(norm[ok], mu[ok] / mu[ok][:, :1, :1], rtol=1e-12)
    np.testing.assert_allclose(norm[ok][:, 0, 0], 1.0)
    assert np.isnan(norm[~ok]).all() and np.isnan(dop[~ok]).all()
    col = mu[ok][:, :, 0]
    np.testing.assert_allclose(dop[ok], np.sqrt((col[:, 1:] ** 2).sum(-1)) / col[:, 0], rtol=1e-12)
    assert np.all((dop[ok] >= 0) & np.isfinite(dop[ok])) and dop[ok].max() > 0.01   # the coat polarizes
