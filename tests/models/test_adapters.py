"""Adapters without a package (models/adapters.py): --model python:MODULE:NAME (a Model subclass or a
function f(l, v, stack)) and --model mitsuba:FILE.xml|.json, through gonio evaluate, render, plot and
the report; their errors against a direct computation of the same model; bad specs (one line naming
the spec, exit 2); a stochastic model's own noise beside the noise floor."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from goniometer.files import slices as store
from goniometer.cli import main
from goniometer.database import load_database, simulate_database
from goniometer.optics import np_microfacet_reflection, np_microfacet_transmission
from goniometer.grids.slice_grid import light_direction
from goniometer.stack import Interface, Lambertian, Medium, Stack
from models import registry
from models.base import Model, ModelError, ModelValue
from models.compare import errors
from models.compare.integrate import ModelSlices, integrate
from models.evaluation import evaluate, read_slices
from models.report import build_report
from tests.models.harness_helpers import ROOT, tiny_file

TINY = ROOT / "tests" / "data" / "tiny_database.toml"
PLASTIC = Stack("plastic/adapter-test", (Interface(0.2, (1.5,) * 3), Medium((0.05, 0.1, 0.4)),
                                         Lambertian((0.2, 0.5, 0.8))), "plastic")
LAMBERT = Stack("lambert-0.5", (Lambertian((0.5,) * 3),), "other")
#: the stochastic test model's standard error per direction (1/sr)
NOISE = 0.01

MODULE = '''
"""Adapters under test."""
import numpy as np
from models.base import Model, ModelValue


def lambert(l, v, stack):
    """the base's albedo / pi"""
    rho = np.asarray(stack.layers[-1].albedo, dtype=float)
    return np.broadcast_to(rho / np.pi, v.shape[:-1] + (3,))


class Lambert(Model):
    name = "lambert-class"
    description = "the base's albedo / pi"

    def support_reason(self, stack):
        return None

    def _evaluate(self, stack, l, v, side):
        f = np.array(lambert(l, v, stack))
        return ModelValue(np.zeros_like(f), f)


class Noisy(Lambert):
    """lambert with an estimator's standard error of NOISE on the internal part"""
    def _evaluate(self, stack, l, v, side):
        value = super()._evaluate(stack, l, v, side)
        return ModelValue(value.top, value.internal, stderr_internal=np.full(value.internal.shape, NOISE))


def wrong_shape(l, v, stack):
    return np.zeros(v.shape[:-1])


def raises(l, v, stack):
    raise RuntimeError("boom")


NOT_CALLABLE = 3
'''.replace("NOISE)", f"{NOISE})")


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("adapters")
    (d / "adapter_mod.py").write_text(MODULE)
    return {"dir": d, "module": d / "adapter_mod.py",
            "plastic": tiny_file(d / "plastic.h5", PLASTIC, incident=(0.0, 60.0)),
            "lambert": tiny_file(d / "lambert.h5", LAMBERT, rays=100_000)}


@pytest.fixture
def on_path(files, monkeypatch):
    """adapter_mod importable by its dotted name."""
    monkeypatch.syspath_prepend(str(files["dir"]))
    yield
    sys.modules.pop("adapter_mod", None)


def _one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("gonio: error: "), err
    return lines[0]


def _direct_lambert_errors(path: Path) -> dict:
    """The errors of albedo / pi computed without the adapter: the cell mean of a constant is the
    constant, compared by models.compare.errors as gonio evaluate does."""
    ref = store.read(path)
    sd = ref.brdf
    rho = np.asarray(ref.stack.layers[-1].albedo)
    internal = np.broadcast_to((rho / np.pi)[None, :, None, None], sd.value.shape).copy()
    ms = ModelSlices("lambert", "brdf", sd.grid, np.zeros_like(internal), internal, 5)
    return errors.compare(sd, ms, drop_first_order=True)


def _assert_errors_equal(got: dict, want: dict, rel: float = 1e-9) -> None:
    for part in ("internal", "total"):
        for key in ("rmse", "rmse_mean", "rmse_luminance", "noise_floor_mean"):
            assert got[part][key] == pytest.approx(want[part][key], rel=rel), (part, key)


# ---------------------------------------------------------------------- python:MODULE:NAME

def test_python_adapters_give_the_direct_computation_s_errors(files, on_path, capsys, tmp_path):
    want = _direct_lambert_errors(files["plastic"])
    specs = ["python:adapter_mod:lambert", "python:adapter_mod:Lambert", f"python:{files['module']}:lambert"]
    out = tmp_path / "slices.h5"
    assert main(["evaluate", str(files["plastic"]), "--json", "--save-slices", str(out),
                 *[x for s in specs for x in ("--model", s)]]) == 0
    d = json.loads(capsys.readouterr().out)
    assert list(d["models"]) == specs, "adapters are keyed by the spec the user typed"
    for spec in specs:
        _assert_errors_equal(d["models"][spec], want)
    # a spec holding a path ("/") is one group of the model-slices file
    saved = read_slices(out, specs[2], "brdf")
    rho = np.asarray(PLASTIC.layers[-1].albedo)
    np.testing.assert_allclose(saved["internal"][:, :, 3, 5], np.tile(rho / np.pi, (2, 1)), rtol=1e-12)
    assert np.all(saved["top"] == 0.0)
    # the same through the library, and the text table
    ev = evaluate(store.read(files["plastic"]), [specs[0]])
    _assert_errors_equal(ev.errors[specs[0]], want)
    assert main(["evaluate", str(files["plastic"]), "--model", specs[0]]) == 0
    assert any(line.startswith(specs[0] + " ") for line in capsys.readouterr().out.splitlines())


def test_a_wrong_model_is_not_equal_to_the_direct_computation(files, tmp_path):
    """The comparison above can fail: twice the albedo gives other errors."""
    module = tmp_path / "twice.py"
    module.write_text(MODULE + "\n\ndef twice(l, v, stack):\n    return 2.0 * lambert(l, v, stack)\n")
    spec = f"python:{module}:twice"
    got = evaluate(store.read(files["plastic"]), [spec]).errors[spec]
    with pytest.raises(AssertionError):
        _assert_errors_equal(got, _direct_lambert_errors(files["plastic"]))


@pytest.mark.parametrize("spec, reason", [
    ("python:no_such_module_for_gonio:f", "cannot import module 'no_such_module_for_gonio'"),
    ("python:adapter_mod:nope", "module 'adapter_mod' has no attribute 'nope'"),
    ("python:adapter_mod:NOT_CALLABLE", "is a int, not a Model subclass or a function"),
    ("python:adapter_mod:wrong_shape", "returned shape (2,) for v of shape (2, 3); expected (2, 3)"),
    ("python:adapter_mod:raises", "RuntimeError: boom"),
    ("python:adapter_mod", "expected python:MODULE:NAME"),
    ("python:/no/such/dir/adapter.py:f", "no file /no/such/dir/adapter.py"),
])
def test_bad_python_specs_are_one_line_naming_the_spec(files, on_path, capsys, spec, reason):
    assert main(["evaluate", str(files["plastic"]), "--model", spec]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert spec in line and reason in line, line
    with pytest.raises(ModelError, match="^" + re.escape(spec)):
        registry.get(spec).evaluate(PLASTIC, np.array([0.0, 0.0, 1.0]), np.array([[0.0, 0.0, 1.0]] * 2))


FAILING = '''
import numpy as np
from models.base import Model, ModelValue


def fails_past_the_probe(l, v, stack):
    if v.shape[0] > 2:
        raise ValueError("too many directions")
    return np.zeros(v.shape[:-1] + (3,))


class WrongShape(Model):
    name = "wrong-shape"

    def support_reason(self, stack):
        return None

    def _evaluate(self, stack, l, v, side):
        return ModelValue(np.zeros(3), np.zeros(3))
'''


def test_adapters_that_fail_past_their_probe_are_one_line_each(files, tmp_path, capsys):
    module = tmp_path / "failing_adapters.py"
    module.write_text(FAILING)
    function, cls = f"python:{module}:fails_past_the_probe", f"python:{module}:WrongShape"
    capsys.readouterr()
    assert main(["evaluate", str(files["plastic"]), "--model", "ww09", "--model", function, "--model", cls]) == 1
    out, err = capsys.readouterr()
    assert out.splitlines()[2].split()[0] == "ww09" and "Traceback" not in err
    failed = sorted(x for x in err.splitlines() if x.startswith("failed "))
    assert failed == sorted([f"failed {function}: the function raised ValueError: too many directions",
                             f"failed {cls}: _evaluate returned top of shape (3,); expected ({9 * 18 * 25}, 3) (RGB last)"]), err


def test_specs_work_wherever_model_names_do(files, on_path, tmp_path, capsys):
    spec = "python:adapter_mod:lambert"
    assert main(["render", str(files["plastic"]), "--out", str(tmp_path / "s.png"), "--model", spec,
                 "--size", "32", "--json"]) == 0
    assert spec in json.loads(capsys.readouterr().out)["models"]
    assert main(["plot", str(files["plastic"]), "--out", str(tmp_path / "fig"), "--model", spec,
                 "--incident", "60", "--json"]) == 0
    assert spec in json.loads(capsys.readouterr().out)["evaluation"]["models"]
    assert main(["render", str(files["plastic"]), "--out", str(tmp_path / "t.png"), "--model",
                 "python:adapter_mod:nope"]) == 2
    assert "has no attribute 'nope'" in _one_error_line(capsys.readouterr().err)


def test_a_file_adapter_in_the_report_is_keyed_by_the_file(files, tmp_path):
    module = tmp_path / "my_model.py"
    module.write_text(MODULE)
    spec = f"python:{module}:lambert"
    results = tmp_path / "results"
    simulate_database(load_database(TINY), results, "quick", only="plastic/P1-a0_0.2")
    out = tmp_path / "report"
    first = build_report(results, out, models=[spec], incidents_for_figures=[60])
    assert {r["model"] for r in json.loads((out / "errors.json").read_text())} == {spec}
    assert len(first.evaluated) == 1 and not first.failed
    again = build_report(results, out, models=[spec], incidents_for_figures=[60])
    assert again.evaluated == []
    module.write_text(MODULE + "\n# edited\n")
    assert len(build_report(results, out, models=[spec], incidents_for_figures=[60]).evaluated) == 1
    with pytest.raises(Exception, match="cannot import module"):
        build_report(results, out, models=["python:no_such_module_for_gonio:f"])


# ---------------------------------------------------------------------- a stochastic model's noise

def test_a_stochastic_model_reports_its_noise_beside_the_floor(files, on_path, capsys):
    spec = "python:adapter_mod:Noisy"
    ref = store.read(files["plastic"])
    sd = ref.brdf
    # the cell mean of independent sub-cell estimates: NOISE sqrt(sum w^2) / sum w
    se = np.zeros_like(sd.value)
    for m, (t, p) in enumerate(zip(ref.theta_deg, ref.phi_deg)):
        _, w = sd.grid.subcells(light_direction(t, p), 5)
        se[m] = NOISE * np.sqrt((w**2).sum(axis=(2, 3))) / w.sum(axis=(2, 3))
    want = errors.noise_floor(se, sd.proj_solid_angle, sd.mask)
    assert main(["evaluate", str(files["plastic"]), "--model", spec, "--model", "ww-bati19", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)["models"]
    for part in ("internal", "total"):
        np.testing.assert_allclose(d[spec][part]["model_noise"], want, rtol=1e-10)
        assert d[spec][part]["model_noise_mean"] == pytest.approx(float(np.mean(want)), rel=1e-10)
        assert "model_noise" not in d["ww-bati19"][part], "an exact model's error object is unchanged"
    _assert_errors_equal(d[spec], _direct_lambert_errors(files["plastic"]))
    assert main(["evaluate", str(files["plastic"]), "--model", spec, "--model", "ww-bati19"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[1].split()[-3:] == ["model", "noise", "(total)"]
    row = next(x for x in lines if x.startswith(spec))
    assert row.split()[-2:] == [f"{np.mean(want):.2e}"] * 2
    assert next(x for x in lines if x.startswith("ww-bati19")).split()[-2:] == ["-", "-"]


def test_integration_of_the_model_noise_is_the_standard_error_of_the_cell_mean(files):
    """Direct check of the formula on one cell: the mean of K independent estimates of weights w_k."""

    class Sub(Model):
        name = "sub"
        scattering = anisotropic = True

        def support_reason(self, stack):
            return None

        def _evaluate(self, stack, l, v, side):
            z = np.zeros(v.shape[:-1] + (3,))
            return ModelValue(z, z + 1.0, stderr_top=z + 2.0, stderr_internal=None)
    ref = store.read(files["lambert"])
    ms = integrate(Sub(), ref, "brdf", s=3)
    _, w = ref.brdf.grid.subcells(light_direction(ref.theta_deg[0], ref.phi_deg[0]), 3)
    w = w[4, 7]
    assert ms.top_stderr[0, 1, 4, 7] == pytest.approx(2.0 * np.sqrt((w**2).sum()) / w.sum(), rel=1e-12)
    assert ms.internal_stderr is None and np.all(ms.stderr("internal") == 0.0)
    np.testing.assert_allclose(ms.stderr("total"), ms.top_stderr)


# ---------------------------------------------------------------------- mitsuba:FILE

DIFFUSE = '<bsdf version="3.0.0" type="diffuse"><rgb name="reflectance" value="{r}"/></bsdf>\n'
CONDUCTOR = {"type": "roughconductor", "distribution": "ggx", "alpha": 0.3, "sample_visible": True,
             "eta": {"type": "rgb", "value": [0.2, 0.5, 1.0]}, "k": {"type": "rgb", "value": [3.0, 2.5, 2.0]}}


@pytest.fixture
def mitsuba():
    return pytest.importorskip("mitsuba", reason="Mitsuba 3 is a test dependency: pip install mitsuba")


def test_mitsuba_diffuse_matches_a_lambertian_within_the_noise_floor(files, mitsuba, tmp_path, capsys):
    for r in ("0.5", "0.6"):
        (tmp_path / f"diffuse-{r}.xml").write_text(DIFFUSE.format(r=r))
    spec = f"mitsuba:{tmp_path / 'diffuse-0.5.xml'}"
    wrong = f"mitsuba:{tmp_path / 'diffuse-0.6.xml'}"
    assert main(["evaluate", str(files["lambert"]), "--model", spec, "--model", wrong, "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    e = d["models"][spec]["total"]
    assert e["rmse_mean"] <= 1.25 * e["noise_floor_mean"], e
    w = d["models"][wrong]["total"]
    assert w["rmse_mean"] > 3.0 * w["noise_floor_mean"], "the test can fail: reflectance 0.6 is far outside"
    assert "does not read the stack" in d["approximations"][spec]
    assert registry.get(spec).description.endswith("a fixed Mitsuba BSDF; it does not read the stack")
    assert main(["evaluate", str(files["lambert"]), "--model", spec]) == 0
    assert f"note {spec}: a fixed Mitsuba BSDF" in capsys.readouterr().out


class _Conductor(Model):
    """The roughconductor of CONDUCTOR written with goniometer.optics (separable Smith, exact Fresnel)."""

    name = "optics-conductor"
    scattering = anisotropic = True

    def support_reason(self, stack):
        return None

    def _evaluate(self, stack, l, v, side):
        eta, k = (np.array(CONDUCTOR[x]["value"]) for x in ("eta", "k"))
        f = np_microfacet_reflection(l[0], l[1], l[2], v[..., 0:1], v[..., 1:2], v[..., 2:3], 0.3, 0.3, eta, k, False)
        return ModelValue(np.zeros_like(f), f)


def test_mitsuba_json_roughconductor_is_the_microfacet_brdf(files, mitsuba, tmp_path):
    path = tmp_path / "conductor.json"
    path.write_text(json.dumps(CONDUCTOR))
    spec = f"mitsuba:{path}"
    ref = store.read(files["plastic"])
    got = evaluate(ref, [spec]).errors[spec]
    want = errors.compare(ref.brdf, integrate(_Conductor(), ref, "brdf"), drop_first_order=True)
    _assert_errors_equal(got, want, rel=1e-4)      # Mitsuba's rgb variants compute in single precision
    model = registry.get(spec)
    rng = np.random.default_rng(3)
    v = rng.normal(size=(50, 3))
    v[:, 2] = np.abs(v[:, 2]) + 0.05
    v /= np.linalg.norm(v, axis=1)[:, None]
    l = np.array([0.3, 0.1, 0.9]) / np.linalg.norm([0.3, 0.1, 0.9])
    np.testing.assert_allclose(model.evaluate(PLASTIC, l, v).internal, _Conductor().evaluate(PLASTIC, l, v).internal,
                               rtol=2e-5, atol=1e-7)


def test_mitsuba_btdf_side_is_the_flux_based_transmission(mitsuba, tmp_path):
    path = tmp_path / "glass.xml"
    path.write_text('<bsdf version="3.0.0" type="roughdielectric"><string name="distribution" value="ggx"/>'
                    '<float name="alpha" value="0.3"/><float name="int_ior" value="1.5"/>'
                    '<float name="ext_ior" value="1.0"/></bsdf>')
    model = registry.get(f"mitsuba:{path}")
    assert model.sides == ("brdf", "btdf")
    rng = np.random.default_rng(4)
    v = np.column_stack([rng.uniform(-0.3, 0.3, 40), rng.uniform(-0.3, 0.3, 40), -rng.uniform(0.6, 1.0, 40)])
    v /= np.linalg.norm(v, axis=1)[:, None]
    l = np.array([0.3, 0.1, 0.9]) / np.linalg.norm([0.3, 0.1, 0.9])
    got = model.evaluate(PLASTIC, l, v, "btdf").internal[:, 0]
    want = np_microfacet_transmission(l[0], l[1], l[2], v[:, 0], v[:, 1], v[:, 2], 0.3, 0.3, 1.5, False)
    assert np.count_nonzero(want) > 20
    np.testing.assert_allclose(got, want, rtol=2e-5, atol=1e-7)
    assert np.all(model.evaluate(PLASTIC, l, -v, "btdf").internal == 0.0), "the BTDF side is the lower hemisphere"


@pytest.mark.parametrize("name, text, reason", [
    ("broken.xml", '<bsdf version="3.0.0" type="diffuse">\n  <rgb name="reflectance" value="0.5"\n</bsdf>\n',
     "Mitsuba refused the file: Parsing of XML file"),
    ("shape.xml", '<shape version="3.0.0" type="sphere"/>\n', "the file holds a Shape, not a BSDF"),
    ("unknown.xml", '<bsdf version="3.0.0" type="no_such_bsdf"/>\n', 'Plugin "no_such_bsdf" not found'),
    ("list.json", "[1, 2]\n", "holds a JSON list, not a plugin dictionary"),
    ("bad.json", "{not json\n", "is not JSON"),
    ("typo.json", '{"type": "roughconductor", "alphaa": 0.2}\n', "unreferenced property"),
    ("diffuse.txt", DIFFUSE.format(r=0.5), "expected mitsuba:FILE.xml or mitsuba:FILE.json"),
    (None, None, "no file"),
])
def test_bad_mitsuba_files_are_one_line_naming_the_spec(files, mitsuba, tmp_path, capsys, name, text, reason):
    path = tmp_path / (name or "missing.xml")
    if text is not None:
        path.write_text(text)
    spec = f"mitsuba:{path}"
    assert main(["evaluate", str(files["lambert"]), "--model", spec]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert spec in line and reason in line, line
