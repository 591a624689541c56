"""gonio evaluate on a polarized file (issue 33 item 5; docs/polarization.md, "Models on polarized
files"): polarized models judged element by element against the file's Mueller matrices with a noise floor per element,
every model's intensity against M00 unchanged, scalar files as before."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

import goniometer as g
from goniometer.cli import main
from goniometer.files import slices as store
from goniometer.stack import Interface, Stack
from models import registry
from models.base import Model, ModelError, ModelValue
from goniometer.testing import P_FALSE_ALARM, noise_floor_ratio_limit
from models.compare import integrate_mueller, mueller_errors

mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is a test dependency: pip install mitsuba")

#: a grey rough conductor: a fixed Mitsuba file can give it in its RGB and its spectral variants alike
METAL = Stack("metal", (Interface(0.3, (0.9,) * 3, (2.5,) * 3),), "metal")


def _conductor(alpha: float) -> dict:
    return {"type": "roughconductor", "distribution": "ggx", "alpha": alpha, "eta": 0.9, "k": 2.5}


PLUGIN = '''
import numpy as np
from models.base import Model, ModelValue

F = 0.1


class Depolarizer(Model):
    """f = 0.1 / sr, fully depolarizing: M00 = f, every other element 0."""
    polarized = True

    def support_reason(self, stack):
        return None

    def _evaluate(self, stack, l, v, side):
        f = np.full(v.shape[:-1] + (3,), F)
        return ModelValue(np.zeros_like(f), f)

    def _evaluate_mueller(self, stack, l, v, side):
        m = np.zeros(v.shape[:-1] + (3, 4, 4))
        m[..., 0, 0] = F
        return m


class WrongShape(Depolarizer):
    def _evaluate_mueller(self, stack, l, v, side):
        return np.zeros(v.shape[:-1] + (4, 4))


class WrongFrames(Depolarizer):
    mueller_frames = "xyz"


def scalar(l, v, stack):
    return np.full(v.shape[:-1] + (3,), F)


def lambertian(l, v, stack):
    return np.full(v.shape[:-1] + (3,), 0.3 / np.pi)
'''


@pytest.fixture(scope="module")
def polarized(tmp_path_factory):
    """A polarized rough conductor at 8 x 16 cells lit out of the xz plane, its file, Mitsuba files
    of the same roughconductor and of a wrong one (alpha 0.2), a diffuse one, and a plugin module."""
    d = tmp_path_factory.mktemp("pol")
    r = g.simulate(METAL, g.SimulationSettings(rays=120_000, resolution=(8, 16), polarized=True, seed=7, threads=2,
                                               incident_deg=(40.0,), incident_phi_deg=(30.0,)))
    files = {"run": r, "file": store.write(d / "metal.h5", r)}
    for name, alpha in (("right", 0.3), ("wrong", 0.2)):
        (d / f"{name}.json").write_text(json.dumps(_conductor(alpha)))
        files[name] = f"mitsuba:{d / f'{name}.json'}"
    (d / "diffuse.json").write_text(json.dumps({"type": "diffuse"}))
    files["diffuse"] = f"mitsuba:{d / 'diffuse.json'}"
    (d / "plug.py").write_text(PLUGIN)
    files["plugin"] = str(d / "plug.py")
    # the same file without its Mueller matrices: a scalar file of the same intensities
    scalar = replace(r, settings=replace(r.settings, polarized=False),
                     brdf=replace(r.brdf, mueller=None, mueller_stderr=None))
    files["scalar"] = store.write(d / "scalar.h5", scalar)
    return files


def _evaluate(capsys, file, *models, json_out=True, status=0) -> dict | str:
    capsys.readouterr()
    argv = ["evaluate", str(file), *[x for m in models for x in ("--model", m)]] + (["--json"] if json_out else [])
    assert main(argv) == status
    out = capsys.readouterr().out
    return json.loads(out) if json_out else out


def test_mitsubas_roughconductor_is_within_the_noise_floor_of_every_element(polarized, capsys):
    """Mitsuba's polarized roughconductor, taken to the file's s/p frames, is the same physics: each
    of the 16 elements' RMSE within the ratio to its noise floor a perfect model stays under
    (:func:`goniometer.testing.noise_floor_ratio_limit`), per channel; the same BSDF with alpha 0.2
    is above it in every element that is not 0; M00's error is the intensity error."""
    right, wrong = polarized["right"], polarized["wrong"]
    d = _evaluate(capsys, polarized["file"], right, wrong)
    assert d["polarized"] is True and d["intensity_only"] == {} and d["failed"] == {}
    ok, bad = d["mueller"][right], d["mueller"][wrong]
    assert "roughconductor in scalar_spectral_polarized" in ok["note"] or "llvm_ad_spectral_polarized" in ok["note"]
    rmse, noise, norm = (np.array(ok[k]) for k in ("mueller_rmse", "mueller_noise", "mueller_norm"))
    assert rmse.shape == (4, 4, 3) and np.array(ok["mueller_rmse_mean"]).shape == (4, 4)
    zero = noise == 0.0                      # M03, M30: a conductor's Fresnel matrix has none
    assert np.count_nonzero(~zero) == 14 * 3
    assert np.all(rmse[zero] <= 1e-6 * norm.max())
    # the ratio a perfect model stays under (every element and channel: 42 checks at P_FALSE_ALARM / 42 each)
    sd = store.read(polarized["file"]).brdf
    stderr = np.moveaxis(sd.mueller_stderr, (1, 4, 5), (3, 1, 2))     # (M, 4, 4, C, n_theta, n_phi)
    weight = (sd.proj_solid_angle * sd.mask)[:, None, None, None]
    limit = noise_floor_ratio_limit(stderr, weight, axis=(0, 4, 5), p=P_FALSE_ALARM / 42)
    assert limit.shape == (4, 4, 3) and np.all(np.isnan(limit) == zero)
    assert np.all(rmse[~zero] <= limit[~zero] * noise[~zero]), rmse / np.where(zero, 1.0, noise) / limit
    assert np.all(np.array(bad["mueller_rmse"])[~zero] > limit[~zero] * noise[~zero])
    # M00 is the intensity: the same error as the intensity's total (Mitsuba's two variants, single precision)
    assert np.allclose(rmse[0, 0], d["models"][right]["total"]["rmse"], rtol=1e-4)
    assert ok["cells"] == d["cells"] and ok["cells_total"] == d["cells_total"]


def test_the_frames_conversion_is_needed(polarized):
    """Mitsuba's matrices read as if they were in the s/p frames (no conversion) are refused: the
    elements that mix linear polarizations leave the noise floor."""
    r = polarized["run"]
    model = registry.models_for([polarized["right"]])[polarized["right"]]
    model.mueller_frames = "sp"
    e = mueller_errors(r.brdf, integrate_mueller(model, r, "brdf", 5))
    rmse, noise = np.array(e["mueller_rmse"]), np.array(e["mueller_noise"])
    mixing = np.zeros((4, 4), dtype=bool)
    mixing[1:3, :] = mixing[:, 1:3] = True       # every element with a row or a column of S1, S2
    assert np.all(rmse[mixing] > 3.0 * noise[mixing]), rmse / np.maximum(noise, 1e-300)


def test_a_plugin_model_gives_mueller_matrices(polarized, capsys):
    """A plugin Model with polarized = True: its matrices integrated as its intensities are (M00's
    error is its total intensity error, to rounding), a depolarizer's other elements miss the whole
    reference (their error is the reference's norm); the text output has the 4 x 4 block."""
    spec = f"python:{polarized['plugin']}:Depolarizer"
    d = _evaluate(capsys, polarized["file"], spec)
    e = d["mueller"][spec]
    assert np.allclose(e["mueller_rmse"][0][0], d["models"][spec]["total"]["rmse"], rtol=1e-12, atol=0.0)
    rmse, norm = np.array(e["mueller_rmse"]), np.array(e["mueller_norm"])
    off = np.ones((4, 4), dtype=bool)
    off[0, 0] = False
    assert np.allclose(rmse[off], norm[off], rtol=1e-12, atol=0.0)
    assert np.all(norm[1:3, 1:3] > 0.0)
    out = _evaluate(capsys, polarized["file"], spec, json_out=False)
    assert f"{spec}: RMSE of M_ij / its noise floor" in out
    assert len([x for x in out.splitlines() if x.startswith("  M") and x[4] == "j"]) == 4


def test_save_slices_keeps_the_mueller_matrices(polarized, capsys, tmp_path):
    """--save-slices writes a polarized model's integrated matrices beside its intensities (and none
    for a scalar model)."""
    from models.evaluation import read_slices
    spec, fn = f"python:{polarized['plugin']}:Depolarizer", f"python:{polarized['plugin']}:scalar"
    out = tmp_path / "m.h5"
    assert main(["evaluate", str(polarized["file"]), "--model", spec, "--model", fn, "--save-slices", str(out)]) == 0
    got = read_slices(out, spec, "brdf")
    assert got["mueller"].shape == got["value"].shape + (4, 4)
    assert np.allclose(got["mueller"][..., 0, 0], got["value"], rtol=1e-12, atol=0.0)
    assert np.all(got["mueller"][..., 1:, :] == 0.0)
    assert "mueller" not in read_slices(out, fn, "brdf")


def test_plugins_whose_mueller_matrices_fail_keep_their_intensity_errors(polarized, capsys):
    """A polarized plugin that returns another shape, or names frames that do not exist, is that
    model's failure (exit 1, one line each), its intensity errors kept."""
    shape = f"python:{polarized['plugin']}:WrongShape"
    frames = f"python:{polarized['plugin']}:WrongFrames"
    d = _evaluate(capsys, polarized["file"], shape, frames, status=1)
    assert "its Mueller matrices: _evaluate_mueller returned shape" in d["failed"][shape]
    assert "mueller_frames: 'xyz' is not one of sp, mitsuba, plane" in d["failed"][frames]
    assert set(d["models"]) == {shape, frames} and d["mueller"] == {}


def test_a_model_without_mueller_matrices_is_judged_on_the_intensity_only(polarized, capsys):
    """A scalar function and a Mitsuba plugin that depolarizes (diffuse): intensity errors as on any
    file, listed as intensity only with why, in the JSON and the text."""
    fn, diffuse = f"python:{polarized['plugin']}:scalar", polarized["diffuse"]
    d = _evaluate(capsys, polarized["file"], fn, diffuse)
    assert d["mueller"] == {} and set(d["models"]) == {fn, diffuse}
    assert d["intensity_only"][fn] == "a scalar model: it gives intensities, not Mueller matrices"
    assert "Mitsuba's SmoothDiffuse is judged on the intensity only" in d["intensity_only"][diffuse]
    out = _evaluate(capsys, polarized["file"], fn, json_out=False)
    assert f"intensity only {fn}: a scalar model" in out
    out = _evaluate(capsys, polarized["file"], fn, f"python:{polarized['plugin']}:lambertian", json_out=False)
    assert f"intensity only {fn}, python:{polarized['plugin']}:lambertian: a scalar model" in out
    assert "(no evaluated model gives Mueller matrices)" in out


def test_a_scalar_file_is_evaluated_as_before_and_m00_gives_the_same_numbers(polarized, capsys):
    """The same intensities without Mueller matrices: no polarized key, no Mueller line, and the
    intensity errors of every model (scalar or polarized) equal on both files."""
    models = (polarized["right"], f"python:{polarized['plugin']}:scalar", f"python:{polarized['plugin']}:Depolarizer")
    pol = _evaluate(capsys, polarized["file"], *models)
    sca = _evaluate(capsys, polarized["scalar"], *models)
    assert not {"polarized", "mueller", "intensity_only"} & set(sca)
    assert set(pol) - set(sca) == {"polarized", "mueller", "intensity_only"}
    assert sca["models"] == pol["models"]
    text = _evaluate(capsys, polarized["scalar"], *models, json_out=False)
    assert "polarized" not in text and "M_ij" not in text and "intensity only" not in text


def test_evaluate_mueller_of_a_scalar_model_is_refused():
    class Scalar(Model):
        name = "scalar"

        def support_reason(self, stack):
            return None

        def _evaluate(self, stack, l, v, side):
            return ModelValue(np.zeros(v.shape[:-1] + (3,)), np.zeros(v.shape[:-1] + (3,)))

    with pytest.raises(ModelError, match="scalar: a scalar model: it gives intensities, not Mueller matrices"):
        Scalar().evaluate_mueller(METAL, np.array([0.0, 0.0, 1.0]), np.array([[0.0, 0.0, 1.0]]))


def test_mitsuba_mueller_channels_are_their_wavelengths():
    """eval_mueller reads channel c at the c-th wavelength (one call): a roughconductor whose index
    is a spectrum gives, per channel, the BSDF of that wavelength's index; an RGB stack's channels
    sit at 610, 550 and 465 nm, a wavelength triple's at its own."""
    from models.production.mitsuba import (MitsubaBSDF, SCALAR_POLARIZED, VECTORISED_POLARIZED, channel_wavelengths,
                                           mitsuba_polarized_variant, plugin_name)
    variant = mitsuba_polarized_variant()
    assert variant in (SCALAR_POLARIZED, VECTORISED_POLARIZED)
    assert channel_wavelengths(METAL) == (610.0, 550.0, 465.0)
    assert channel_wavelengths(replace(METAL, wavelengths_nm=(450.0, 500.0, 700.0))) == (450.0, 500.0, 700.0)
    eta, k = (0.2, 0.9, 1.3), (3.5, 2.5, 2.0)
    spectral = {**_conductor(0.3),
                "eta": {"type": "irregular", "wavelengths": "465, 550, 610", "values": ", ".join(map(str, eta[::-1]))},
                "k": {"type": "irregular", "wavelengths": "465, 550, 610", "values": ", ".join(map(str, k[::-1]))}}
    b = MitsubaBSDF(spectral, variant)
    assert plugin_name(b.bsdf) == "roughconductor"
    l = np.array([0.5, 0.1, np.sqrt(0.74)])
    v = np.array([[0.1, 0.2, np.sqrt(0.95)], [-0.3, 0.4, np.sqrt(0.75)]])
    got = b.eval_mueller(l, v, (610.0, 550.0, 465.0))
    assert got.shape == (2, 3, 4, 4)
    for c in range(3):
        one = MitsubaBSDF({**_conductor(0.3), "eta": eta[c], "k": k[c]}, variant).eval_mueller(l, v, (550.0,) * 3)
        assert np.allclose(got[:, c], one[:, 0], rtol=1e-5, atol=1e-7)
    assert not np.allclose(got[:, 0], got[:, 2])


@pytest.mark.parametrize("l", [(0.0, 0.0, 1.0), (0.3, -0.4, np.sqrt(0.75))])
def test_a_models_frames_are_taken_to_the_files(l):
    """to_file_frames gives, from any frame family a model states, what convert_mueller gives into the
    file's s/p frames of the incident azimuth (30 degrees); at l = z a model's "sp" frame is the limit
    along the azimuth 0, which that azimuth then turns."""
    from goniometer.grids.stokes import convert_mueller
    from models.compare.integrate import to_file_frames
    rng = np.random.default_rng(3)
    v = rng.normal(size=(5, 3))      # v[0] at the normal ("plane" frames are undefined there for l = z)
    v[:, 2] = np.abs(v[:, 2])
    v[0] = (0.0, 0.0, 1.0)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    L = np.broadcast_to(np.array(l), v.shape)
    phi_v = np.degrees(np.arctan2(v[:, 1], v[:, 0]))
    file_sp = np.full(5, 30.0)
    model_sp = np.zeros(5)
    want = rng.normal(size=(5, 3, 4, 4))              # in the file's frames
    for frames, phi in (("mitsuba", file_sp), ("plane", file_sp), ("sp", model_sp)):
        with np.errstate(invalid="ignore"):
            given = np.stack([convert_mueller(convert_mueller(want[:, c], L, v, "sp", "mitsuba", file_sp, phi_v),
                                              L, v, "mitsuba", frames, phi, phi_v) for c in range(3)], axis=1)
        with np.errstate(invalid="ignore"):        # (the undefined "plane" frames: NaN)
            got = to_file_frames(given, frames, np.array(l), v, 30.0)
        defined = np.linalg.norm(np.cross(L, v), axis=1) > 0 if frames == "plane" else np.ones(5, dtype=bool)
        assert np.allclose(got[defined], want[defined], atol=1e-12), frames
    if l[2] == 1.0:   # the model's "sp" frame at the normal is not the file's: the azimuth matters
        assert not np.allclose(to_file_frames(want, "sp", np.array(l), v, 30.0), want, atol=1e-6)
    with pytest.raises(ModelError, match="mueller_frames: 'xy' is not one of sp, mitsuba, plane"):
        to_file_frames(want, "xy", np.array(l), v, 30.0)
