"""Model plugins (entry-point group goniometer.models, models/plugins.py, models/registry.py):
discovery without pip (a hand-made dist-info on sys.path), the source column of gonio models, the
example plugin through evaluate, render, furnace and the report (whose cache is keyed by the
plugin's code), name clashes (one line, exit 2, both distributions named), a plugin that fails (one
warning line, the rest works), and a real pip install of examples/plugin-model (slow)."""

from __future__ import annotations

import json
import logging
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from goniometer.files import slices as store
from goniometer.cli import main
from goniometer.database import load_database, simulate_database
from goniometer.stack import Interface, Lambertian, Medium, Stack
from models import plugins, registry
from models.evaluation import evaluate
from models.furnace import model_albedos
from models.plugins import PluginError
from models.render import render_file
from models.report import build_report
from tests.models.harness_helpers import EXAMPLE, ROOT, installer, tiny_file  # noqa: F401 -- fixture

TINY = ROOT / "tests" / "data" / "tiny_database.toml"
PLASTIC = Stack("plastic/plugin-test", (Interface(0.2, (1.5,) * 3), Medium((0.05, 0.1, 0.4)),
                                        Lambertian((0.2, 0.5, 0.8))), "plastic")

IMPOSTOR = '''
import numpy as np
from models.base import Model, ModelValue

class Impostor(Model):
    name = "{name}"
    description = "a model that takes a name already taken"

    def support_reason(self, stack):
        return None

    def _evaluate(self, stack, l, v, side):
        z = np.zeros(v.shape[:-1] + (3,))
        return ModelValue(z, z)
'''


@pytest.fixture(scope="module")
def plastic_file(tmp_path_factory) -> Path:
    return tiny_file(tmp_path_factory.mktemp("plugin") / "plastic.h5", PLASTIC, incident=(0.0, 60.0))


def _one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("gonio: error: "), err
    return lines[0]


# ---------------------------------------------------------------------- discovery (a)

def test_without_plugins_the_registry_is_the_built_in_one(installer):
    assert plugins.installed() == ()
    assert set(registry.sources().values()) == {registry.BUILT_IN}
    assert registry.code_key(None) == ""


def test_example_plugin_is_listed_with_its_source(installer, capsys):
    root = installer.example()
    names = list(registry.all_models())
    assert names[-1] == "coated-diffuse", "plugins come after the built-in models"
    assert registry.sources()["coated-diffuse"] == "example-plugin 0.1"
    assert main(["models", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["coated-diffuse"]["source"] == "example-plugin 0.1" and d["ww09"]["source"] == "built-in"
    assert d["coated-diffuse"]["sides"] == ["brdf"] and set(d["ww09"]) >= {"description", "fitted", "anisotropic"}
    assert main(["models"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split()[:7] == ["model", "sides", "kind", "aniso", "scatter", "description", "source"]
    row = next(x for x in lines if x.startswith("coated-diffuse "))
    assert row.endswith("example-plugin 0.1")
    assert next(x for x in lines if x.startswith("ww09 ")).endswith("built-in")
    # the scan is cached; clearing it forgets the plugin once it is off the path
    sys.path.remove(str(root))
    installer.roots.clear()
    assert "coated-diffuse" in registry.all_models()
    plugins.clear_cache()
    assert "coated-diffuse" not in registry.all_models()


def test_example_plugin_runs_through_gonio_evaluate(installer, plastic_file, capsys):
    installer.example()
    assert main(["evaluate", str(plastic_file), "--model", "coated-diffuse", "--model", "ww-bati19", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    e = d["models"]["coated-diffuse"]
    assert set(d["models"]) == {"coated-diffuse", "ww-bati19"}
    # a fair model of this plastic: well below the reference's own size, near the built-in ones
    for part in ("internal", "total"):
        assert 0 < e[part]["rmse_mean"] < 0.2 * np.mean(e[part]["reference_norm"])
        assert e[part]["rmse_mean"] < 3 * d["models"]["ww-bati19"][part]["rmse_mean"]
    # without --model the plugin is one of "every model that applies", like a built-in (the built-ins cut
    # down to one, for speed)
    from models.weidlich_wilkie import WW09
    installer.monkeypatch.setattr(registry, "_built_in_models", lambda: [WW09()])
    every = evaluate(store.read(plastic_file))
    assert list(every.errors) == ["ww09", "coated-diffuse"] and every.errors["coated-diffuse"] == e
    assert main(["evaluate", str(plastic_file)]) == 0
    rows = [line.split()[0] for line in capsys.readouterr().out.splitlines()[2:4]]
    assert rows == ["ww09", "coated-diffuse"]


def test_example_plugin_renders_and_has_a_directional_albedo(installer, plastic_file, tmp_path):
    installer.example()
    spheres = render_file(plastic_file, tmp_path / "s.png", ["coated-diffuse"], 30.0, 32)
    assert "coated-diffuse" in spheres.images and (tmp_path / "s.png").exists()
    albedos = model_albedos(PLASTIC, (0.0, 60.0))
    a = albedos.albedo["coated-diffuse"]
    assert a.shape == (2, 3) and np.all((a > 0.05) & (a < 0.9))


def test_example_plugin_in_the_report_keyed_by_its_code(installer, tmp_path):
    root = installer.example()
    results = tmp_path / "results"
    simulate_database(load_database(TINY), results, "quick", only="plastic/P1-a0_0.2")
    out = tmp_path / "report"
    first = build_report(results, out, models=["coated-diffuse"], incidents_for_figures=[60])
    records = json.loads((out / "errors.json").read_text())
    assert {r["model"] for r in records} == {"coated-diffuse"} and len(records) == 1
    assert all(r["internal"]["rmse_mean"] > 0 for r in records)
    assert "coated-diffuse" in (out / "index.html").read_text()
    assert len(first.evaluated) == 1
    again = build_report(results, out, models=["coated-diffuse"], incidents_for_figures=[60])
    assert again.evaluated == [] and len(again.reused) == 1
    # an updated plugin (new sources, new version) is evaluated again
    module = root / "example_plugin.py"
    module.write_text(module.read_text() + "\n# updated\n")
    plugins.clear_cache()
    updated = build_report(results, out, models=["coated-diffuse"], incidents_for_figures=[60])
    assert len(updated.evaluated) == 1


# ---------------------------------------------------------------------- clashes (b)

def test_a_clash_with_a_built_in_name_is_one_line_naming_both(installer, plastic_file, capsys):
    installer.install("clash-plugin", "0.2", {"ww09": "clash_mod:Impostor"},
                      {"clash_mod": IMPOSTOR.format(name="ww09")})
    with pytest.raises(PluginError, match="clash-plugin 0.2") as e:
        registry.all_models()
    assert "goniometer" in str(e.value) and "'ww09'" in str(e.value)
    for argv in (["models"], ["models", "--json"], ["evaluate", str(plastic_file)],
                 ["evaluate", str(plastic_file), "--model", "ww09"]):
        capsys.readouterr()
        assert main(argv) == 2, argv
        line = _one_error_line(capsys.readouterr().err)
        assert "clash-plugin 0.2" in line and "built-in models (goniometer" in line


def test_a_clash_with_a_fitted_name_is_refused_too(installer):
    installer.install("fit-clash", "1.0", {"hp15-fit": "fit_clash_mod:Impostor"},
                      {"fit_clash_mod": IMPOSTOR.format(name="hp15-fit")})
    with pytest.raises(PluginError, match="fit-clash 1.0"):
        registry.catalogue()


def test_a_clash_between_two_plugins_names_both(installer, capsys):
    installer.install("first-plugin", "1.0", {"twin-a": "twin_a:Impostor"}, {"twin_a": IMPOSTOR.format(name="twin")})
    installer.install("second-plugin", "2.0", {"twin-b": "twin_b:Impostor"}, {"twin_b": IMPOSTOR.format(name="twin")})
    assert main(["models"]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "first-plugin 1.0" in line and "second-plugin 2.0" in line and "'twin'" in line


# ---------------------------------------------------------------------- failing plugins (c)

def test_a_plugin_that_fails_is_one_warning_and_the_rest_works(installer, plastic_file, caplog, capsys):
    installer.example()
    installer.install("broken-plugin", "0.3", {"broken": "no_such_module_for_gonio:Model"}, {})
    installer.install("bad-init", "0.4", {"bad-init": "bad_init_mod:Impostor"},
                      {"bad_init_mod": IMPOSTOR.format(name="bad-init")
                       + "\n    def __init__(self):\n        raise RuntimeError('no licence')\n"})
    installer.install("not-a-model", "0.5", {"not-a-model": "not_model_mod:thing"}, {"not_model_mod": "thing = 3\n"})
    with caplog.at_level(logging.WARNING, logger="models.plugins"):
        models = registry.all_models()
        registry.all_models()      # the scan is cached: the warnings are not repeated
        assert main(["evaluate", str(plastic_file), "--model", "coated-diffuse", "--json"]) == 0
    assert "coated-diffuse" in models and "ww09" in models
    messages = [r.getMessage() for r in caplog.records if r.name == "models.plugins"]
    assert len(messages) == 3, messages
    assert all("\n" not in m and "left out" in m for m in messages)
    by = {m.split("'")[1]: m for m in messages}
    assert "broken-plugin 0.3" in by["broken"] and "No module named 'no_such_module_for_gonio'" in by["broken"]
    assert "no licence" in by["bad-init"] and "not a models.base.Model subclass" in by["not-a-model"]
    assert json.loads(capsys.readouterr().out)["models"]["coated-diffuse"]["total"]["rmse_mean"] > 0


def test_the_failure_is_one_line_on_the_cli_stderr(installer):
    root = installer.install("broken-plugin", "0.3", {"broken": "no_such_module_for_gonio:Model"}, {})
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), str(ROOT)])}
    run = subprocess.run([sys.executable, "-c", "import sys; from goniometer.cli import main; "
                          "sys.exit(main(['models', '--json']))"], capture_output=True, text=True, env=env,
                         timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stderr.strip().splitlines() == [run.stderr.strip()], run.stderr
    assert "model plugin 'broken' (broken-plugin 0.3" in run.stderr and "left out" in run.stderr
    assert "ww09" in json.loads(run.stdout)


# ---------------------------------------------------------------------- models that fail (d)

FAILING = '''
import numpy as np
from models.base import Model, ModelValue

class BadEvaluate(Model):
    name = "bad-evaluate"
    description = "a model whose _evaluate raises"

    def support_reason(self, stack):
        return None

    def _evaluate(self, stack, l, v, side):
        raise ZeroDivisionError("boom in _evaluate")


class BadSupport(Model):
    name = "bad-support"
    description = "a model whose support_reason raises"

    def support_reason(self, stack):
        raise KeyError("boom in support_reason")

    def _evaluate(self, stack, l, v, side):
        z = np.zeros(v.shape[:-1] + (3,))
        return ModelValue(z, z)
'''
FAILED = {"bad-evaluate": "_evaluate raised ZeroDivisionError: boom in _evaluate",
          "bad-support": "support_reason raised KeyError: 'boom in support_reason'"}


@pytest.fixture
def failing(installer, monkeypatch):
    """Two failing plugins beside the built-in ww09 alone (for speed)."""
    from models.weidlich_wilkie import WW09
    installer.install("failing-plugin", "0.6", {"bad-evaluate": "failing_mod:BadEvaluate",
                                                "bad-support": "failing_mod:BadSupport"}, {"failing_mod": FAILING})
    monkeypatch.setattr(registry, "_built_in_models", lambda: [WW09()])
    return installer


def _failed_lines(err: str) -> dict[str, str]:
    lines = [x for x in err.strip().splitlines() if x.startswith("failed ")]
    assert "Traceback" not in err and len(lines) == len({x.split(":")[0] for x in lines}), err
    return {x.split(":")[0][len("failed "):]: x.split(": ", 1)[1] for x in lines}


def test_a_failing_model_is_one_line_in_evaluate_and_the_others_stand(failing, plastic_file, capsys):
    for argv in (["evaluate", str(plastic_file)],
                 ["evaluate", str(plastic_file), "--model", "ww09", "--model", "bad-evaluate", "--model", "bad-support"]):
        capsys.readouterr()
        assert main(argv) == 1, argv
        out, err = capsys.readouterr()
        assert [x.split()[0] for x in out.splitlines()[2:3]] == ["ww09"], out
        assert "bad-" not in out.split("(\'internal\'")[0]
        assert _failed_lines(err) == FAILED
    assert main(["evaluate", str(plastic_file), "--json"]) == 1
    out, err = capsys.readouterr()
    d = json.loads(out)
    assert list(d["models"]) == ["ww09"] and d["failed"] == FAILED and d["models"]["ww09"]["total"]["rmse_mean"] > 0
    assert _failed_lines(err) == FAILED
    # the library records the failures and goes on
    ev = evaluate(store.read(plastic_file))
    assert list(ev.errors) == ["ww09"] and ev.failed == FAILED


def test_a_failing_model_is_one_line_in_render_and_the_others_stand(failing, plastic_file, tmp_path, capsys):
    png = tmp_path / "s.png"
    assert main(["render", str(plastic_file), "--out", str(png), "--size", "32", "--model", "ww09",
                 "--model", "bad-evaluate", "--model", "bad-support"]) == 1
    out, err = capsys.readouterr()
    assert png.is_file() and "ww09" in out and "image RMSE" in out and "bad-" not in out
    assert _failed_lines(err) == FAILED
    assert main(["render", str(plastic_file), "--out", str(tmp_path / "j.png"), "--size", "32", "--model", "all",
                 "--json"]) == 1
    out, err = capsys.readouterr()
    d = json.loads(out)
    assert list(d["models"]) == ["ww09"] and d["failed"] == FAILED and _failed_lines(err) == FAILED


def test_a_failing_model_is_a_warning_of_the_report_and_its_status_is_1(failing, tmp_path, capsys):
    results = tmp_path / "results"
    simulate_database(load_database(TINY), results, "quick", only="plastic/P1-a0_0.2")
    out = tmp_path / "report"
    capsys.readouterr()
    assert main(["report", str(results), "--out", str(out), "--incidents", "60"]) == 1
    _, err = capsys.readouterr()
    warnings = [x for x in err.splitlines() if x.startswith("warning: ")]
    assert sorted(w.split(": ")[2] for w in warnings) == ["bad-evaluate failed", "bad-support failed"], warnings
    records = json.loads((out / "errors.json").read_text())
    assert [r["model"] for r in records] == ["ww09"] and (out / "index.html").is_file()
    table = (out / "tables" / "plastic.md").read_text()
    assert "| failed |" in table and "bad-evaluate" in table


def test_a_failing_model_is_one_line_in_furnace_and_the_others_stand(failing, tmp_path, capsys):
    """It stopped the furnace with one line (exit 2) and lost the other models' albedos."""
    cfg = tmp_path / "p.toml"
    cfg.write_text(PLASTIC.to_toml())
    capsys.readouterr()
    assert main(["furnace", str(cfg), "--rays", "2000", "--incident", "30", "--json"]) == 1
    out, err = capsys.readouterr()
    d = json.loads(out)
    assert list(d["models"]) == ["ww09"] and d["failed"] == FAILED and _failed_lines(err) == FAILED
    assert main(["furnace", str(cfg), "--rays", "2000", "--incident", "30"]) == 1
    out, err = capsys.readouterr()
    assert "ww09" in out and "bad-" not in out and _failed_lines(err) == FAILED


# ---------------------------------------------------------------------- the documented example

def test_the_documented_example_is_the_example_package():
    """docs/models.md section 9 shows the example's module and pyproject.toml as they are."""
    doc = (ROOT / "docs" / "models.md").read_text()
    section = doc[doc.index("## 9. Writing a model (plugins)"):]
    blocks = {lang: [b.split("\n", 1)[1] for b in section.split("```")[1::2] if b.startswith(lang + "\n")]
              for lang in ("python", "toml")}
    assert (EXAMPLE / "example_plugin.py").read_text() in blocks["python"]
    assert (EXAMPLE / "pyproject.toml").read_text() in blocks["toml"]


# ---------------------------------------------------------------------- a real install (d)

@pytest.mark.slow
def test_pip_installs_the_example_and_gonio_lists_it(tmp_path):
    target = tmp_path / "site"
    source = tmp_path / "plugin-model"   # a copy: the build leaves build/ and *.egg-info beside the sources
    shutil.copytree(EXAMPLE, source, ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
    pip = subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--target", str(target),
                          str(source)], capture_output=True, text=True, timeout=600)
    assert pip.returncode == 0, pip.stderr
    assert list(target.glob("example_plugin-0.1*.dist-info")), sorted(p.name for p in target.iterdir())
    env = {**os.environ, "PYTHONPATH": str(target)}
    gonio = Path(sys.executable).with_name("gonio")
    run = subprocess.run([str(gonio), "models", "--json"], capture_output=True, text=True, env=env, timeout=120)
    assert run.returncode == 0 and run.stderr == "", run.stderr
    d = json.loads(run.stdout)
    assert d["coated-diffuse"]["source"] == "example-plugin 0.1"
    run = subprocess.run([str(gonio), "models"], capture_output=True, text=True, env=env, timeout=120)
    assert any(x.startswith("coated-diffuse ") and x.endswith("example-plugin 0.1") for x in run.stdout.splitlines())
