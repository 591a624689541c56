"""gonio render --stokes (models/render/stokes.py; docs/polarization.md, "Looking at a polarized
file"): a rough glass over a black base reflects, at every pixel of the sphere, the light of one
Fresnel event at the angle half the one between light and camera, so its degree of linear
polarization is Fresnel's and its angle is perpendicular to the plane of light and camera
(horizontal in the image) once each pixel's s/p frame is turned into the camera's; a wrong turn
fails the check. The command refuses a scalar file in one line."""

from __future__ import annotations

import json
import math

import h5py
import numpy as np
import pytest

import goniometer as g
from goniometer import optics
from goniometer.cli import main as gonio
from goniometer.files import slices as store
from goniometer.grids import stokes as frames
from goniometer.stack import Interface, Lambertian, Stack
from goniometer.testing import Z_TOL
from models.render import stokes
from models.render.stokes import render_stokes

GLASS = Stack("glass", (Interface(0.15, (1.5,) * 3), Lambertian((0.0,) * 3)), "other")
#: light and camera 90 degrees apart: every single reflection has its microfacet at 45 degrees
LIGHT_DEG = 90.0


@pytest.fixture(scope="module")
def glass():
    return g.simulate(GLASS, g.SimulationSettings(incident_deg=(40.0, 45.0, 50.0), rays=1_000_000, resolution=(12, 24),
                                                  parametrization="half", polarized=True, seed=3, threads=2))


def _closed_dolp() -> float:
    ra, rb = optics.fresnel_dielectric_mueller(math.cos(math.radians(0.5 * LIGHT_DEG)), 1.5)[:2]
    return abs(rb) / ra


def _aolp_outliers(sphere) -> tuple[int, int]:
    """``(failing, shown)``: pixels whose AOLP (camera frame) is further from 0 (s-polarized:
    perpendicular to the plane of light and camera, the image's horizontal) than Z_TOL times its
    first-order standard-error bound, among the pixels with an AOLP."""
    s, se = sphere.stokes, sphere.stderr
    a = sphere.aolp_deg
    ok = np.isfinite(a)
    with np.errstate(invalid="ignore", divide="ignore"):
        se_a = np.degrees(0.5 * np.hypot(se[:, 1], se[:, 2]) / np.hypot(s[:, 1], s[:, 2]))
    dev = np.abs((a + 90.0) % 180.0 - 90.0)
    return int(np.sum(ok & (dev > Z_TOL * se_a))), int(np.sum(ok))


def test_dolp_is_fresnels_and_aolp_is_horizontal_in_the_camera_frame(glass):
    sphere = render_stokes(glass, 64, LIGHT_DEG)
    d, se = sphere.dolp, sphere.dolp_stderr
    shown = np.isfinite(d)
    assert shown.sum() >= 50
    closed = _closed_dolp()
    assert np.all(np.abs(d[shown] - closed) <= Z_TOL * se[shown]), np.max(np.abs(d[shown] - closed) / se[shown])
    # the check can fail: unpolarized light (DOLP 0, what a scalar run would draw) lies outside on most
    # pixels (the bound of the standard error ignores the correlation of S0 and S1, which share their paths)
    assert np.mean(closed > Z_TOL * se[shown]) > 0.5
    failing, with_angle = _aolp_outliers(sphere)
    assert with_angle >= 50 and failing == 0
    # the pixels' s/p frames are far from the camera's: the angle of x_out = normalize(n x V) from +x
    n = sphere.view.normals
    psi = np.degrees(np.arctan2(-n[:, 0], n[:, 1]))
    assert np.sum(np.isfinite(sphere.aolp_deg) & (np.abs(psi) > 20.0)) >= 20


@pytest.mark.parametrize("wrong", ["none", "inverse"])
def test_a_wrong_frame_rotation_fails_the_check(glass, monkeypatch, wrong):
    """The same check with the Stokes frames left in s/p, or turned the wrong way, fails."""
    right = frames.rotator
    if wrong == "none":
        monkeypatch.setattr(stokes, "rotator", lambda k, a, b: right(k, a, a))
    else:
        monkeypatch.setattr(stokes, "rotator", lambda k, a, b: right(k, b, a))
    failing, _ = _aolp_outliers(render_stokes(glass, 64, LIGHT_DEG))
    assert failing >= 10


def test_a_coat_over_a_diffuse_base_sends_out_radial_polarization():
    """Light leaving a smooth coat from a depolarizing base is p-polarized (the refraction passes more
    p than s), along the plane of the normal and the camera: in the image, the radial direction
    from the sphere's centre. This checks the camera frame's handedness (y = k x x, k towards the
    camera, angles counter-clockwise), which the horizontal AOLP of the glass cannot: the mirrored
    angles fail."""
    plastic = Stack("plastic", (Interface(0.0, (1.5,) * 3), Lambertian((0.8,) * 3)), "plastic")
    r = g.simulate(plastic, g.SimulationSettings(incident_deg=tuple(range(0, 90, 10)), rays=50_000, resolution=(9, 36),
                                                 polarized=True, seed=3, threads=2))
    sphere = render_stokes(r, 48, 0.0)          # light along the line of sight
    a = sphere.aolp_deg
    ok = np.isfinite(a)
    assert ok.sum() >= 500
    s, se = sphere.stokes, sphere.stderr
    with np.errstate(invalid="ignore", divide="ignore"):
        se_a = np.degrees(0.5 * np.hypot(se[:, 1], se[:, 2]) / np.hypot(s[:, 1], s[:, 2]))
    n = sphere.view.normals
    radial = np.degrees(np.arctan2(n[:, 1], n[:, 0]))

    def off(angle: np.ndarray) -> np.ndarray:
        return np.abs((angle - radial + 90.0) % 180.0 - 90.0)
    assert np.all(off(a)[ok] <= Z_TOL * se_a[ok] + 1e-9)
    assert np.sum(off(-a)[ok] > Z_TOL * se_a[ok] + 1e-9) > 0.5 * ok.sum()


def _run(capsys, *argv) -> tuple[int, str, str]:
    code = gonio(["render", *map(str, argv)])
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_stokes_writes_the_png_and_its_summary(glass, tmp_path, capsys):
    path = store.write(tmp_path / "glass.h5", glass)
    code, out, err = _run(capsys, path, "--out", tmp_path / "s.png", "--stokes", "--size", "48", "--light-angle",
                          "90", "--json")
    assert code == 0, err
    assert (tmp_path / "s.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    doc = json.loads(out)
    assert doc["material"] == "glass" and doc["side"] == "brdf" and doc["frame"] == stokes.CAMERA_FRAME
    assert abs(doc["dolp_median"] - _closed_dolp()) < 0.1 and doc["shown_fraction"] > 0


def test_cli_stokes_is_refused_on_a_scalar_file_and_with_models(tmp_path, capsys):
    r = g.simulate(GLASS, g.SimulationSettings(incident_deg=(30.0, 60.0), rays=2000, resolution=(3, 6), threads=1))
    path = store.write(tmp_path / "scalar.h5", r)
    with pytest.raises(stokes.NotPolarized, match="a scalar result"):
        render_stokes(r, 32, 30.0)
    for extra, start in (((), "gonio: error: --stokes: "), (("--model", "ww09"), "gonio: error: --stokes: ")):
        code, out, err = _run(capsys, path, "--out", tmp_path / "s.png", "--stokes", *extra)
        lines = err.strip().splitlines()
        assert code == 2 and out == "" and len(lines) == 1 and lines[0].startswith(start), err
    assert "scalar file" in err or "--model" in err
    assert not (tmp_path / "s.png").exists()
    code, _, err = _run(capsys, path, "--out", tmp_path / "s.png", "--stokes")
    assert "a scalar file (no Mueller matrices)" in err
    tab = tmp_path / "t.h5"                       # a tabulated file holds no Mueller matrices either
    with h5py.File(tab, "w") as f:
        f.attrs["format"] = "goniometer.tabulated"
    code, out, err = _run(capsys, tab, "--out", tmp_path / "s.png", "--stokes")
    assert code == 2 and err.startswith("gonio: error: --stokes: ") and "holds no Mueller matrices" in err, err
    assert not (tmp_path / "s.png").exists()
