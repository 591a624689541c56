"""``gonio tables``: status, build, rebuild and checks of the models' table files, end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest

from goniometer import atomic
from goniometer.cli import main
from models.tables import multilayer as mt
from models.tables import check as tables_cli
from models.tables import belcour as tables


def _run(capsys, *argv) -> tuple[int, dict]:
    code = main(["tables", *argv, "--json"])
    return code, json.loads(capsys.readouterr().out)


def test_status_builds_nothing(tmp_path, capsys):
    code, out = _run(capsys, "--status", "--cache-dir", str(tmp_path), "--masking", "all")
    assert code == 0
    names = [t["name"] for t in out["tables"]]
    assert names == ["belcour-fgd-separable", "belcour-tir-separable", "belcour-fgd-height-correlated",
                     "belcour-tir-height-correlated", "multilayer-lut"]
    assert {t["status"] for t in out["tables"]} == {"missing"}
    assert not any(t["built"] for t in out["tables"])
    assert list(tmp_path.iterdir()) == []


def test_build_check_and_rebuild(tmp_path, capsys, tiny_multilayer_grid):
    code, out = _run(capsys, "--cache-dir", str(tmp_path), "--check", "6")
    by_name = {t["name"]: t for t in out["tables"]}
    assert set(by_name) == {"belcour-fgd-separable", "belcour-tir-separable", "multilayer-lut"}
    for t in by_name.values():
        assert t["status"] == "current" and t["built"] and t["bytes"] > 0
    # the files are those the models read
    assert tables.read_if_current(tables.table_paths(tmp_path)["fgd"], False, ("fgd",)) is not None
    assert mt.read_if_current(mt.table_path(tmp_path)) is not None
    # the real Belcour tables meet their stated bounds; the 2x2-node multilayer grid cannot
    belcour_checks = by_name["belcour-fgd-separable"]["checks"] + by_name["belcour-tir-separable"]["checks"]
    assert [c["quantity"] for c in belcour_checks] == ["FGD (4D table)", "TIR"]
    assert all(c["ok"] and c["points"] == 6 and 0 <= c["max_error"] <= c["bound"] for c in belcour_checks)
    assert not all(c["ok"] for c in by_name["multilayer-lut"]["checks"])
    assert code == 1 and out["ok"] is False

    # a second run finds everything current and builds nothing
    mtime = tables.table_paths(tmp_path)["fgd"].stat().st_mtime_ns
    code, out = _run(capsys, "--cache-dir", str(tmp_path))
    assert code == 0 and not any(t["built"] for t in out["tables"])
    assert tables.table_paths(tmp_path)["fgd"].stat().st_mtime_ns == mtime

    # a stale file is rebuilt, the current ones are left alone
    path = mt.table_path(tmp_path)
    with np.load(path) as z:
        content = {k: z[k] for k in z.files}
    content["version"] = np.int64(mt.TABLE_VERSION - 1)
    np.savez(path, **content)
    code, out = _run(capsys, "--cache-dir", str(tmp_path), "--status")
    assert {t["name"]: t["status"] for t in out["tables"]}["multilayer-lut"] == "stale"
    code, out = _run(capsys, "--cache-dir", str(tmp_path))
    assert [t["name"] for t in out["tables"] if t["built"]] == ["multilayer-lut"]
    assert mt.read_if_current(path) is not None

    # --rebuild rebuilds current tables too
    code, out = _run(capsys, "--cache-dir", str(tmp_path), "--rebuild")
    assert code == 0 and all(t["built"] for t in out["tables"])
    assert not list(tmp_path.glob(atomic.TEMP_GLOB))


def test_text_output_names_each_table(tmp_path, capsys):
    assert main(["tables", "--status", "--cache-dir", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    assert f"cache directory: {tmp_path}" in text
    for name in ("belcour-fgd-separable", "belcour-tir-separable", "multilayer-lut"):
        assert name in text
    assert "missing" in text


def test_bad_arguments(tmp_path, capsys):
    assert main(["tables", "--check", "-3", "--cache-dir", str(tmp_path)]) == 2
    assert "--check" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        main(["tables", "--masking", "gaussian"])
    assert e.value.code == 2
    with pytest.raises(ValueError, match="masking"):
        tables_cli.check_tables(tmp_path, ("gaussian",))
