"""``gonio lut`` (docs/lut.md): its files, the cost line and the checks it prints; a finished
table refused without --overwrite; Ctrl-C keeps the finished cells (exit 130) and a rerun resumes
them bit for bit; checkpoints of another definition refused naming the key; bad input in one line;
a published table compared; a failing check exits 1 with the files written."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from goniometer.cli import main
from tests.conftest import refused
from tests.goniometer.resume_helpers import bytes_of, stop_after

DEFINITION = """name = "small_E"
quantity = "albedo"
masking = "height-correlated"
rays = {rays}
seed = 3
[interface]
fresnel = "white"
[[axes]]
parameter = "mu"
nodes = 3
clamp = [1e-4, 1.0]
[[axes]]
parameter = "roughness"
nodes = 3
clamp = [1e-4, 1.0]
map = "alpha=r^2"
[published]
source = "a test"
array = "small_E"
"""
RAYS = 20_000


def write(tmp_path: Path, rays: int = RAYS) -> Path:
    p = tmp_path / "small.toml"
    p.write_text(DEFINITION.format(rays=rays))
    return p


def run(argv, capsys) -> tuple[int, str, str]:
    capsys.readouterr()
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_writes_the_files_and_refuses_to_replace_them(tmp_path, capsys):
    d, out = write(tmp_path), tmp_path / "out"
    code, text, err = run(["lut", d, "--out", out, "--threads", "1"], capsys)
    assert code == 0, err
    assert "cost: 180,000 rays, about" in err and "M rays/s" in err
    assert "check quadrature: passes" in text and "check fresnel: passes" in text
    names = sorted(p.name for p in out.iterdir())
    assert names == ["small_E.h", "small_E.json", "small_E.npy", "small_E.png", "small_E.stderr.npy"]
    doc = json.loads((out / "small_E.json").read_text())
    assert doc["format"] == "goniometer.lut" and all(c["passed"] for c in doc["checks"])
    np.testing.assert_array_equal(np.load(out / "small_E.npy"), np.array(doc["values"]))
    before = bytes_of(out)
    line = refused(capsys, ["lut", d, "--out", out], "--out", "small_E.json", "--overwrite")
    assert "already holds a finished output" in line and bytes_of(out) == before
    code, _, _ = run(["lut", d, "--out", out, "--overwrite", "--threads", "1"], capsys)
    assert code == 0
    np.testing.assert_array_equal(np.load(out / "small_E.npy"), np.array(doc["values"]))   # same seed, same bits


def test_ctrl_c_keeps_the_cells_and_a_rerun_resumes_them_bit_for_bit(tmp_path, capsys, monkeypatch):
    d = write(tmp_path)
    whole = tmp_path / "whole"
    assert run(["lut", d, "--out", whole, "--threads", "1"], capsys)[0] == 0
    out = tmp_path / "cut"
    import models.commands.lut as command
    with monkeypatch.context() as m:
        m.setattr(command, "ResumeAware", stop_after(4 * RAYS))
        code, _, err = run(["lut", d, "--out", out, "--threads", "1"], capsys)
    assert code == 130
    assert "finished cell(s) kept in" in err and "rerun the same command to resume" in err
    assert not (out / "small_E.json").exists()
    kept = sorted((out / ".partial").rglob("m*.npz"))
    assert 4 <= len(kept) < 9
    # another definition is refused, naming the key, and the checkpoints keep their bytes
    before = bytes_of(out / ".partial")
    line = refused(capsys, ["lut", write(tmp_path, rays=RAYS + 1), "--out", out], "rays: checkpoints 20000, this run 20001",
                   "--restart")
    assert bytes_of(out / ".partial") == before and "nothing was changed" in line
    d = write(tmp_path)
    code, _, err = run(["lut", d, "--out", out, "--threads", "2"], capsys)
    assert code == 0, err
    assert "resuming: " in err and "finished cell(s)" in err
    for name in ("small_E.npy", "small_E.stderr.npy", "small_E.h"):
        assert (out / name).read_bytes() == (whole / name).read_bytes(), name
    assert not (out / ".partial").exists()


def test_restart_discards_the_checkpoints(tmp_path, capsys, monkeypatch):
    d, out = write(tmp_path), tmp_path / "out"
    import models.commands.lut as command
    with monkeypatch.context() as m:
        m.setattr(command, "ResumeAware", stop_after(2 * RAYS))
        assert run(["lut", d, "--out", out, "--threads", "1"], capsys)[0] == 130
    d2 = write(tmp_path, rays=RAYS // 2)
    code, _, err = run(["lut", d2, "--out", out, "--threads", "1", "--restart"], capsys)
    assert code == 0, err
    assert json.loads((out / "small_E.json").read_text())["rays"][0] == [RAYS // 2] * 3


def test_the_output_is_never_the_definition(tmp_path, capsys):
    d = write(tmp_path)
    before = d.read_bytes()
    refused(capsys, ["lut", d, "--out", d], "--out", "input")
    refused(capsys, ["lut", d, "--out", d, "--overwrite"], "input")
    assert d.read_bytes() == before


@pytest.mark.parametrize("argv, needles", [
    (["--rays", "0"], ["--rays: 0 is outside [1,"]),
    (["--stderr", "0.7"], ["--stderr: 0.7 is outside (0, 0.5)"]),
    (["--published", "missing.c"], ["--published: missing.c: cannot read"]),
])
def test_bad_options_are_one_line(tmp_path, capsys, argv, needles):
    d = write(tmp_path)
    refused(capsys, ["lut", d, "--out", tmp_path / "out", *argv], *needles)
    assert not (tmp_path / "out").exists()


def test_more_threads_than_the_machine_are_refused_by_the_parser(tmp_path, capsys):
    from goniometer.cli import main
    d = write(tmp_path)
    capsys.readouterr()
    with pytest.raises(SystemExit) as e:
        main(["lut", str(d), "--out", str(tmp_path / "out"), "--threads", "100000"])
    err = capsys.readouterr().err.strip().splitlines()
    assert e.value.code == 2 and len(err) == 1 and "gonio lut: error: --threads: 100000 is outside [1," in err[0], err
    assert not (tmp_path / "out").exists()


def test_a_bad_definition_is_one_line_naming_the_file_and_field(tmp_path, capsys):
    p = tmp_path / "bad.toml"
    p.write_text(DEFINITION.format(rays=RAYS).replace('clamp = [1e-4, 1.0]\n', '', 1))
    refused(capsys, ["lut", p, "--out", tmp_path / "out"], str(p), "axes[0]: a node gives mu 0, outside (0, 1]")
    refused(capsys, ["lut", tmp_path / "none.toml", "--out", tmp_path / "out"], "none.toml: cannot read")


def test_published_comparison_and_a_failing_check(tmp_path, capsys, monkeypatch):
    d, out = write(tmp_path), tmp_path / "out"
    src = tmp_path / "tables.c"
    src.write_text("static const float small_E[4] = {1.0f, 0.5f, 0.5f, 0.5f};\n")
    refused(capsys, ["lut", d, "--out", out, "--published", src], "small_E holds 4 numbers; the table has 9 cells")
    src.write_text("static const float small_E[9] = {" + ", ".join(["0.5f"] * 9) + "};\n")
    import models.lut.check as check
    real = check.reference_values

    def shifted(defn):   # a quadrature that disagrees: the check fails, the files are still written
        ref, err, words = real(defn)
        return ref + 0.05, err, words
    monkeypatch.setattr(check, "reference_values", shifted)
    code, text, _ = run(["lut", d, "--out", out, "--published", src, "--threads", "1"], capsys)
    assert code == 1
    assert "check quadrature: FAILS" in text and "published small_E (a test)" in text
    doc = json.loads((out / "small_E.json").read_text())
    assert doc["published"]["file"] == str(src) and len(doc["published"]["beyond_ours"]) == 9
    assert not doc["checks"][0]["passed"]
