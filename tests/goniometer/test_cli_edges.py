"""Rough edges of the gonio command line (issue 14 §4): --version, defaults in every option's help,
progress lines without a terminal, a broken pipe, one-line errors, Ctrl-C in the final assembly,
and the noise floors of gonio evaluate's table."""

from __future__ import annotations

import argparse
import io
import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

import goniometer
from goniometer.cli import build_parser, main
from goniometer.cli.common import LineProgress
from tests.conftest import PLASTIC_TOML

ROOT = Path(__file__).resolve().parents[2]
PLASTIC = PLASTIC_TOML + """[simulation]
incident_deg = [0, 45]
rays = 3000
resolution = [9, 18]
"""


def _env() -> dict:
    return {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}


def _one_line_error(capsys, argv, expected: str) -> str:
    capsys.readouterr()
    assert main(argv) == 2, argv
    err = capsys.readouterr().err.strip()
    assert err.startswith("gonio: error: ") and "\n" not in err and expected in err, err
    return err


# ----------------------------------------------------------------------------- --version, help

def test_version(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.strip() == f"gonio (goniometer) {goniometer.__version__}"


def _options(parser: argparse.ArgumentParser, path: str):
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            for name, sub in a.choices.items():
                yield from _options(sub, f"{path} {name}")
        elif a.option_strings and not isinstance(a, (argparse._HelpAction, argparse._VersionAction)):
            yield path, a


def test_every_option_states_its_default():
    """Every optional argument of every sub-command (the models plugin's included): its help
    says what happens when it is not given; when it has a value default, the help shows it."""
    seen = set()
    bad = []
    for path, a in _options(build_parser(), "gonio"):
        seen.add(path)
        if a.required or isinstance(a, (argparse._StoreTrueAction, argparse._StoreFalseAction)):
            continue  # nothing to default, or off unless given
        text = (a.help or "") % {"default": a.default}
        if "default" not in text:
            bad.append(f"{path} {a.option_strings[-1]}: {a.help!r}")
        elif a.default is not None:
            shown = {str(a.default), f"{a.default:g}" if isinstance(a.default, float) else str(a.default)}
            if not any(s in text for s in shown):
                bad.append(f"{path} {a.option_strings[-1]}: default {a.default!r} not in {text!r}")
    assert {"gonio simulate", "gonio database simulate", "gonio evaluate", "gonio report"} <= seen
    assert not bad, "\n".join(bad)


def test_simulate_help_shows_the_settings_defaults_and_vocabularies(capsys):
    """The help takes its defaults and choices from SimulationSettings (one home: goniometer.run.settings)."""
    from goniometer.run.settings import FIRST_ORDER, MASKING, PARAMETRIZATIONS, SimulationSettings
    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    d = SimulationSettings()
    for shown in (f"{d.rays:,}", ",".join(f"{x:g}" for x in d.incident_deg), f"{d.resolution[0]}x{d.resolution[1]}",
                  f"(default: the file's [simulation] table, else {d.masking})", *PARAMETRIZATIONS, *MASKING,
                  *FIRST_ORDER):
        assert shown in text, shown


def test_first_order_integrated_from_the_command_line(tmp_path, capsys):
    """--first-order integrated is recorded in the file and shown by info; a stack without an
    interface on top is refused in one line with status 2 before anything is traced."""
    cfg = tmp_path / "p.toml"
    cfg.write_text(PLASTIC)
    out = tmp_path / "p.h5"
    assert main(["simulate", str(cfg), "--out", str(out), "--threads", "1", "--first-order", "integrated"]) == 0
    capsys.readouterr()
    assert main(["info", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["settings"]["first_order"] == "integrated"
    assert main(["info", str(out)]) == 0
    assert "order 1 integrated" in capsys.readouterr().out
    lamb = tmp_path / "l.toml"
    lamb.write_text('name = "l"\ncategory = "plastic"\n[[layers]]\ntype = "lambertian"\nalbedo = 0.5\n')
    _one_line_error(capsys, ["simulate", str(lamb), "--out", str(tmp_path / "l.h5"), "--first-order", "integrated"],
                    "first_order: integrated needs an interface on top")
    assert not (tmp_path / "l.h5").exists()


# ----------------------------------------------------------------------------- progress and pipes

def test_line_progress_prints_every_tenth_with_rate_and_eta():
    now = [0.0]
    out = io.StringIO()
    with LineProgress(1000, "metal", file=out, clock=lambda: now[0]) as bar:
        for _ in range(40):
            now[0] += 1.0
            bar.update(25)  # 25 rays a second
    lines = out.getvalue().splitlines()
    assert len(lines) == 10
    assert lines[0].startswith("metal:  10% (100/1.00k ray)") and "25.0 ray/s" in lines[0]
    assert "ETA 00:36" in lines[0]  # 900 rays left at 25 per second
    assert lines[-1].startswith("metal: 100%") and lines[-1].endswith("ETA 00:00")


def test_simulate_prints_progress_lines_when_stderr_is_a_file(tmp_path):
    cfg = tmp_path / "p.toml"
    cfg.write_text(PLASTIC)
    p = subprocess.run([sys.executable, "-m", "goniometer.cli", "simulate", str(cfg), "--out", str(tmp_path / "p.h5"),
                        "--rays", "300000", "--incident", "0", "--threads", "1"],
                       capture_output=True, text=True, env=_env(), timeout=300)
    assert p.returncode == 0, p.stderr
    lines = [ln for ln in p.stderr.splitlines() if ln.startswith("p: ")]
    # one task of 8 chunks of 131 072 rays covers the run: at least the last line, at 100 %
    assert lines and lines[-1].startswith("p: 100% (300k/300k ray)") and "ray/s" in lines[-1], p.stderr
    assert all(re.search(r"ETA \S+", ln) for ln in lines)


def test_no_traceback_when_the_reader_goes_away():
    r, w = os.pipe()
    os.close(r)  # like `| head` that has already exited
    try:
        p = subprocess.run([sys.executable, "-m", "goniometer.cli", "database", "list",
                            str(ROOT / "configs" / "bati2019.toml")], stdout=w, stderr=subprocess.PIPE, env=_env(),
                           timeout=120)
    finally:
        os.close(w)
    assert p.returncode == 141
    assert p.stderr == b""


# ----------------------------------------------------------------------------- one-line errors

def test_material_file_not_utf8(tmp_path, capsys):
    cfg = tmp_path / "latin1.toml"
    cfg.write_bytes(PLASTIC.replace('name = "p"', 'name = "caf\u00e9"').encode("latin-1"))
    err = _one_line_error(capsys, ["simulate", str(cfg), "--out", str(tmp_path / "x.h5")], "not UTF-8")
    assert str(cfg) in err and "0xe9" in err
    assert not (tmp_path / "x.h5").exists()


@pytest.mark.parametrize("category, expected", [("metal", "'metal' needs the last layer to be a conductor"),
                                                ("slab", "'slab' needs the last layer to be a dielectric")])
def test_category_that_contradicts_the_stack(tmp_path, capsys, category, expected):
    cfg = tmp_path / "m.toml"
    cfg.write_text(PLASTIC.replace('category = "plastic"', f'category = "{category}"'))
    err = _one_line_error(capsys, ["simulate", str(cfg), "--out", str(tmp_path / "x.h5")], expected)
    assert "Lambertian base" in err and "'plastic' or 'other'" in err


def test_category_other_goes_with_any_stack_and_old_files_keep_their_category():
    from goniometer.stack import Stack, StackError, stack_from_dict
    layers = [{"type": "interface", "roughness": 0.2, "ior": 1.5}, {"type": "lambertian", "albedo": 0.5}]
    assert stack_from_dict({"name": "x", "category": "other", "layers": layers}).base == "lambertian"
    with pytest.raises(StackError, match="category"):
        stack_from_dict({"name": "x", "category": "metal", "layers": layers})
    # a file written before the rule holds its stack as JSON: it still reads
    old = Stack.from_json(json.dumps({"name": "x", "category": "metal", "layers": layers}))
    assert old.category == "metal"


@pytest.fixture(scope="module")
def plastic_file(tmp_path_factory):
    d = tmp_path_factory.mktemp("edges")
    cfg = d / "p.toml"
    cfg.write_text(PLASTIC)
    assert main(["simulate", str(cfg), "--out", str(d / "p.h5"), "--threads", "1"]) == 0
    return d / "p.h5"


def test_subcells_zero(plastic_file, tmp_path, capsys):
    for argv in (["evaluate", str(plastic_file), "--model", "ww09", "--subcells", "0"],
                 ["plot", str(plastic_file), "--out", str(tmp_path / "figs"), "--subcells", "0"],
                 ["report", str(tmp_path), "--out", str(tmp_path / "rep"), "--subcells", "0"]):
        _one_line_error(capsys, argv, "--subcells: 0 is not allowed")
    assert not (tmp_path / "figs").exists() and not (tmp_path / "rep").exists()


def test_jobs_zero(tmp_path, capsys):
    for argv in (["report", str(tmp_path), "--out", str(tmp_path / "rep"), "--jobs", "0"],
                 ["production", str(tmp_path), "--out", str(tmp_path / "prod"), "--jobs", "0"]):
        _one_line_error(capsys, argv, "--jobs: 0 is not allowed")
    assert not (tmp_path / "rep").exists() and not (tmp_path / "prod").exists()


def test_plot_out_naming_an_existing_file(plastic_file, tmp_path, capsys):
    f = tmp_path / "figures.png"
    f.write_bytes(b"keep")
    _one_line_error(capsys, ["plot", str(plastic_file), "--out", str(f)], "is an existing file")
    assert f.read_bytes() == b"keep"
    from models.report import ReportError, plot_file
    with pytest.raises(ReportError, match="existing file"):
        plot_file(plastic_file, f)


# ----------------------------------------------------------------------------- evaluate's floors

def test_evaluate_table_puts_each_floor_beside_its_own_error(plastic_file, capsys):
    capsys.readouterr()
    assert main(["evaluate", str(plastic_file), "--model", "ww09", "--json"]) == 0
    e = json.loads(capsys.readouterr().out)["models"]["ww09"]
    assert main(["evaluate", str(plastic_file), "--model", "ww09"]) == 0
    out = capsys.readouterr().out.splitlines()
    header = next(ln for ln in out if ln.startswith("model"))
    row = next(ln for ln in out if ln.startswith("ww09")).split()
    assert header.count("its floor") == 2 and header.index("total mean") < header.rindex("its floor")
    internal_floor, total_mean, total_floor = (float(x) for x in row[-3:])
    i, t = e["internal"], e["total"]
    assert internal_floor == pytest.approx(i["noise_floor_mean"], rel=6e-3)
    assert total_mean == pytest.approx(t["rmse_mean"], rel=1e-4)
    assert total_floor == pytest.approx(t["noise_floor_mean"], rel=6e-3)
    # the two floors differ (the total holds the first order too), so the placement matters
    assert abs(t["noise_floor_mean"] - i["noise_floor_mean"]) > 0.02 * t["noise_floor_mean"]


# ----------------------------------------------------------------------------- Ctrl-C

@pytest.fixture
def sigint_default():
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def _interrupting(real, reached: list):
    def wrapper(*a, **k):
        os.kill(os.getpid(), signal.SIGINT)
        for _ in range(10_000):  # the handler runs at one of these bytecodes
            pass
        reached.append(True)
        return real(*a, **k)
    return wrapper


def test_ctrl_c_in_the_final_assembly_is_130_and_resumable(tmp_path, capsys, monkeypatch, sigint_default):
    import goniometer.run.loop
    cfg = tmp_path / "p.toml"
    cfg.write_text(PLASTIC)
    out = tmp_path / "p.h5"
    reached: list = []
    monkeypatch.setattr(goniometer.run.loop, "assemble", _interrupting(goniometer.run.loop.assemble, reached))
    capsys.readouterr()
    assert main(["simulate", str(cfg), "--out", str(out), "--threads", "1"]) == 130
    err = capsys.readouterr().err
    assert not reached and not out.exists()
    assert "gonio: 2 finished incident direction(s) kept in" in err and "rerun the same command to resume" in err
    assert err.strip().splitlines()[-1] == f"gonio: interrupted; nothing written to {out}"
    monkeypatch.undo()
    assert main(["simulate", str(cfg), "--out", str(out), "--threads", "1"]) == 0
    assert "resuming: 2 of 2" in capsys.readouterr().err and out.exists()


def test_ctrl_c_while_the_assembly_kernels_run_waits_for_them(tmp_path, capsys, monkeypatch, sigint_default):
    """The numba kernels of the assembly (cell geometry) run before tracing, inside the deferred
    block: an interrupt there lets them finish (a KeyboardInterrupt inside numba's compiler can
    break it), then stops with 130."""
    import goniometer.run.results
    cfg = tmp_path / "p.toml"
    cfg.write_text(PLASTIC.replace("resolution = [9, 18]", "resolution = [7, 18]\nparametrization = \"half\""))
    out = tmp_path / "p.h5"
    reached: list = []
    monkeypatch.setattr(goniometer.run.results, "cell_geometries",
                        _interrupting(goniometer.run.results.cell_geometries, reached))
    capsys.readouterr()
    assert main(["simulate", str(cfg), "--out", str(out), "--threads", "1"]) == 130
    err = capsys.readouterr().err
    assert reached and not out.exists()  # every interrupted call ran to its end (warm-up and the real grid)
    assert "interrupt received" in err and err.strip().splitlines()[-1].startswith("gonio: interrupted")


# ----------------------------------------------------------------------------- smaller items of the edges issue

def test_g_without_scattering_albedo_names_the_other_key(tmp_path, capsys):
    cfg = tmp_path / "g.toml"
    cfg.write_text(PLASTIC.replace('type = "lambertian"', 'type = "medium"\noptical_depth = 0.5\ng = 0.3\n'
                                   '[[layers]]\ntype = "lambertian"', 1))
    err = _one_line_error(capsys, ["simulate", str(cfg), "--out", str(tmp_path / "g.h5")], "layers[1].g")
    assert "scattering_albedo" in err and not (tmp_path / "g.h5").exists()


def test_duplicate_incident_directions_and_whole_number_counts(tmp_path, capsys):
    cfg = tmp_path / "p.toml"
    cfg.write_text(PLASTIC)
    out = tmp_path / "p.h5"
    err = _one_line_error(capsys, ["simulate", str(cfg), "--out", str(out), "--incident", "30,30"], "incident_deg")
    assert "given twice" in err and not out.exists()
    assert main(["simulate", str(cfg), "--out", str(out), "--incident", "30,30:90", "--rays", "2e3",
                 "--threads", "1"]) == 0  # another azimuth is another direction; 2e3 is a whole number
    capsys.readouterr()
    with pytest.raises(SystemExit) as e:
        main(["simulate", str(cfg), "--out", str(tmp_path / "q.h5"), "--rays", "2.5"])
    assert e.value.code == 2 and "is not a whole number" in capsys.readouterr().err


def test_models_table_has_a_header_and_the_anisotropy_column(capsys):
    assert main(["models"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split()[:6] == ["model", "sides", "kind", "aniso", "scatter", "description"]
    assert any(" yes " in line for line in lines[1:]) and any("belcour-aniso" in line for line in lines)


# ----------------------------------------------------------------------------- issue 31: the words

def _parser_paths(parser: argparse.ArgumentParser, path: str = "gonio"):
    """Every (sub-)command of gonio, the plugins' included: ("gonio database list", ...)."""
    yield path
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            for name, sub in a.choices.items():
                yield from _parser_paths(sub, f"{path} {name}")


def _parser_error(capsys, argv) -> str:
    capsys.readouterr()
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2, argv
    return capsys.readouterr().err


def test_every_command_refuses_an_argument_in_one_line_with_a_hint(capsys):
    """argparse printed its 12-line usage before the line that matters: now one line naming the
    command and where its help is, for every command (plugins share the parser class)."""
    paths = list(_parser_paths(build_parser()))
    assert {"gonio simulate", "gonio database list", "gonio furnace", "gonio evaluate", "gonio report"} <= set(paths)
    for path in paths:
        err = _parser_error(capsys, path.split()[1:] + ["--no-such-option"])
        assert err.count("\n") == 1 and err.startswith(f"{path}: error: "), err
        assert err.rstrip().endswith(f"; see {path} --help"), err
        assert "usage:" not in err


@pytest.mark.parametrize("argv, expected", [
    (["simulate", "x.toml", "--out", "x.h5", "--rays", "abc"],
     "gonio simulate: error: --rays: 'abc' is not a whole number (e.g. 100000 or 1e5); see gonio simulate --help"),
    (["furnace", "x.toml", "--rays", "1.5"],
     "gonio furnace: error: --rays: '1.5' is not a whole number (e.g. 100000 or 1e5); see gonio furnace --help"),
    (["simulate", "x.toml", "--out", "x.h5", "--masking", "smith"],
     "gonio simulate: error: --masking: invalid choice: 'smith'"),
    (["database", "list", "x.toml", "--bogus"],
     "gonio database list: error: unrecognized arguments: --bogus; see gonio database list --help"),
])
def test_argument_errors_name_the_option_and_the_command(capsys, argv, expected):
    err = _parser_error(capsys, argv)
    assert err.startswith(expected) and err.count("\n") == 1, err


def test_info_of_a_directory_or_of_a_file_it_does_not_read(tmp_path, capsys):
    """'gonio info DIR' said 'no such file'; 'gonio info m.binary' said 'not a readable
    goniometer.slices file': now what the path is and what info reads."""
    err = _one_line_error(capsys, ["info", str(tmp_path)], f"{tmp_path}: a directory, not a file")
    assert "gonio info reads a goniometer.slices file" in err and "RGL tensor file (.bsdf" in err
    merl = tmp_path / "m.binary"
    import numpy as np
    merl.write_bytes(np.array([90, 90, 180], "<i4").tobytes() + bytes(64))
    err = _one_line_error(capsys, ["info", str(merl)], "a MERL .binary BRDF (90x90x180)")
    assert "gonio info reads a goniometer.slices file" in err and "not a readable" not in err
    cfg = tmp_path / "p.toml"
    cfg.write_text(PLASTIC)
    _one_line_error(capsys, ["info", str(cfg)], "a TOML file of")
    _one_line_error(capsys, ["info", str(tmp_path / "none.h5")], "no such file")
    # a slices file that is damaged keeps the reader's own word
    broken = tmp_path / "b.h5"
    import h5py
    with h5py.File(broken, "w") as f:
        f.attrs["format"] = "goniometer.slices"
    _one_line_error(capsys, ["info", str(broken)], "goniometer.slices")


def test_out_under_an_existing_file_names_the_file(tmp_path, capsys):
    """'--out existing_file/x.h5' said the directory does not exist."""
    cfg = tmp_path / "p.toml"
    cfg.write_text(PLASTIC)
    blocker = tmp_path / "m.h5"
    blocker.write_bytes(b"keep")
    for argv in (["simulate", str(cfg), "--out", str(blocker / "x.h5")],
                 ["simulate", str(cfg), "--out", str(blocker / "deeper" / "x.h5")],
                 ["furnace", str(cfg), "--plot", str(blocker / "e.png")],
                 ["report", str(tmp_path), "--out", str(blocker / "rep")]):
        err = _one_line_error(capsys, argv, f"{blocker} is a file")
        assert "not a directory" in err and "does not exist" not in err
    assert blocker.read_bytes() == b"keep"
    _one_line_error(capsys, ["simulate", str(cfg), "--out", str(tmp_path / "none" / "x.h5")],
                    f"output directory {tmp_path / 'none'} does not exist")


def test_database_list_of_a_material_file(tmp_path, capsys):
    """It said 'category: unknown key (allowed: ...)'."""
    cfg = tmp_path / "p.toml"
    cfg.write_text(PLASTIC)
    for verb in (["list"], ["simulate", "--out", str(tmp_path / "out")]):
        err = _one_line_error(capsys, ["database", verb[0], str(cfg), *verb[1:]], f"{cfg}: a material file")
        assert "not a database definition" in err and "unknown key" not in err
    assert not (tmp_path / "out").exists()
    # a definition with a mistake keeps its own word
    (tmp_path / "db.toml").write_text('name = "d"\ncategory = "x"\n')
    _one_line_error(capsys, ["database", "list", str(tmp_path / "db.toml")], "category: unknown key")


# ----------------------------------------------------------------------------- threads beyond the machine

def test_more_threads_than_the_machine_has_are_one_line(tmp_path, capsys):
    """The settings do not know the machine (they import neither numba nor the kernel): --threads is
    checked against numba's threads where it is parsed, the library checks it at launch."""
    import numba

    from goniometer.kernel.tracer import DeviceError
    from goniometer.run.settings import SimulationSettings
    from goniometer.stack import stack_from_dict
    import tomllib
    top = numba.config.NUMBA_NUM_THREADS
    cfg = tmp_path / "p.toml"
    cfg.write_text(PLASTIC)
    for argv in (["simulate", str(cfg), "--out", str(tmp_path / "x.h5")], ["furnace", str(cfg)],
                 ["tabulate", str(cfg), "--out", str(tmp_path / "t.h5")]):
        capsys.readouterr()
        with pytest.raises(SystemExit) as e:   # the parser refuses it (argparse exits)
            main([*argv, "--threads", str(top + 1)])
        assert e.value.code == 2
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and f"--threads: {top + 1} is outside [1, {top}]" in err, err
    assert not list(tmp_path.glob("*.h5"))
    settings = SimulationSettings(incident_deg=(0.0,), rays=10, threads=top + 1)   # a valid setting ...
    stack = stack_from_dict(tomllib.loads(PLASTIC_TOML))
    with pytest.raises(DeviceError, match=rf"threads: {top + 1} is outside \[1, {top}\]"):
        goniometer.simulate(stack, settings)                                      # ... this machine cannot run
