"""The overwrite policy (docs/outputs.md) for the simulator's commands: never onto an input, never
over a finished output without --overwrite (which then replaces it), the refusal saying what the file
holds; inputs' and existing outputs' bytes unchanged. The models' commands: tests/models/test_outputs.py."""

from __future__ import annotations

import os

import h5py
import pytest

from goniometer.files import outputs
from goniometer.cli import main
from tests.conftest import PLASTIC_TOML, refused

CONFIG = PLASTIC_TOML + """[simulation]
incident_deg = [30]
rays = 2000
resolution = [9, 18]
"""


@pytest.fixture
def config(tmp_path):
    p = tmp_path / "p.toml"
    p.write_text(CONFIG)
    return p




def test_simulate_never_writes_onto_its_material_file(config, capsys):
    before = config.read_bytes()
    refused(capsys, ["simulate", config, "--out", config], "--out", "input", config)
    assert config.read_bytes() == before
    # the same file by another spelling, and through a link
    refused(capsys, ["simulate", config, "--out", config.parent / "." / config.name], "input")
    link = config.parent / "link.toml"
    os.symlink(config, link)
    refused(capsys, ["simulate", link, "--out", config], "input")
    refused(capsys, ["simulate", config, "--out", link, "--overwrite"], "input")
    assert config.read_bytes() == before


def test_simulate_refuses_a_finished_output_saying_what_it_holds_then_overwrites(config, tmp_path, capsys):
    out = tmp_path / "p.h5"
    assert main(["simulate", str(config), "--out", str(out), "--threads", "1"]) == 0
    before = out.read_bytes()
    with h5py.File(out, "r") as f:
        created = f.attrs["created"]
    line = refused(capsys, ["simulate", config, "--out", out, "--rays", "3000"], out, "exists", "--overwrite",
                   "goniometer.slices", "of p", "2,000 rays x 1 incident", created)
    assert out.read_bytes() == before and "gonio: error: --out:" in line
    assert not (tmp_path / f".{out.name}.partial").exists()  # nothing started
    capsys.readouterr()
    assert main(["simulate", str(config), "--out", str(out), "--rays", "3000", "--threads", "1", "--overwrite"]) == 0
    with h5py.File(out, "r") as f:
        assert int(f["simulation"].attrs["rays_per_slice"]) == 3000


def test_any_existing_file_is_kept_and_described(config, tmp_path, capsys):
    out = tmp_path / "notes.h5"
    out.write_bytes(b"my notes, not a simulation")
    refused(capsys, ["simulate", config, "--out", out], "exists", "26 bytes", "modified")
    assert out.read_bytes() == b"my notes, not a simulation"


def test_tabulate_and_export(config, tmp_path, capsys):
    tab = tmp_path / "t.h5"
    before = config.read_bytes()
    refused(capsys, ["tabulate", config, "--out", config], "input")
    assert config.read_bytes() == before
    assert main(["tabulate", str(config), "--out", str(tab), "--rays", "20000", "--threads", "1"]) == 0
    kept = tab.read_bytes()
    refused(capsys, ["tabulate", config, "--out", tab, "--rays", "30000"], "exists", "goniometer.tabulated",
            "20,000 rays")
    assert tab.read_bytes() == kept
    # export: never onto the tabulated file, never over a finished export without --overwrite
    refused(capsys, ["export", tab, "--format", "merl", "--out", tab], "input", tab)
    assert tab.read_bytes() == kept
    merl = tmp_path / "t.binary"
    assert main(["export", str(tab), "--format", "merl", "--out", str(merl)]) == 0
    exported = merl.read_bytes()
    refused(capsys, ["export", tab, "--format", "merl", "--out", merl], "exists", "MERL .binary")
    assert merl.read_bytes() == exported
    merl.write_bytes(b"x")
    assert main(["export", str(tab), "--format", "merl", "--out", str(merl), "--overwrite"]) == 0
    assert merl.read_bytes() == exported


def test_database_never_writes_onto_its_definition(tmp_path, capsys):
    from pathlib import Path
    definition = Path(__file__).resolve().parents[1] / "data" / "tiny_database.toml"
    copy = tmp_path / "db.toml"
    copy.write_bytes(definition.read_bytes())
    refused(capsys, ["database", "simulate", copy, "--out", copy], "input")
    assert copy.read_bytes() == definition.read_bytes()


def test_describe_existing_names_the_formats():
    import tempfile
    from pathlib import Path
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "x.png"
        p.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 30)
        assert outputs.describe_existing(p).startswith("a PNG image")
        p = Path(d) / "x.bsdf"
        p.write_bytes(outputs.TENSOR_MAGIC + b"\x01\x00")
        assert outputs.describe_existing(p).startswith("an RGL tensor file")
        p = Path(d) / "x.json"
        p.write_text("{}")
        assert outputs.describe_existing(p).startswith("a JSON file of 2 bytes")
        assert outputs.describe_existing(Path(d) / "missing").startswith("unreadable")


def test_check_output_directory_marker(tmp_path):
    d = tmp_path / "report"
    assert outputs.check_output(d, directory=True, marker="index.html") == d   # absent: fine
    d.mkdir()
    (d / "cache").mkdir()
    assert outputs.check_output(d, directory=True, marker="index.html") == d   # unfinished: resumed
    (d / "index.html").write_text("<html></html>")
    with pytest.raises(outputs.OutputError, match="finished output.*HTML page.*--overwrite"):
        outputs.check_output(d, directory=True, marker="index.html")
    assert outputs.check_output(d, directory=True, marker="index.html", overwrite=True) == d
    with pytest.raises(outputs.OutputError, match="is the command's input"):
        outputs.check_output(d, inputs=[tmp_path / "report"], directory=True, overwrite=True)
