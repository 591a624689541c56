"""The report's numbers do not move when its evaluation gets faster (issue 34): the error table of the
tiny database, every default built-in model, equals the one recorded before (tests/models/pinned_report.py),
and a report written by worker processes (--jobs 2) holds the same files as a serial one."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from tests.models.pinned_report import PINNED, build, differences, report_view


@pytest.fixture(scope="module")
def serial(tmp_path_factory):
    base = tmp_path_factory.mktemp("pinned")
    return base, build(base, jobs=1)


def test_the_error_table_is_the_pinned_one(serial):
    _, out = serial
    got, want = report_view(out), json.loads(PINNED.read_text())
    assert len(want["errors"]) == 27 and set(want["tables"]) == {f"{c}.{x}" for c in ("metal", "plastic", "slab")
                                                                  for x in ("csv", "md")}
    diffs = differences(got["errors"], want["errors"], "errors")
    assert not diffs, "\n".join(diffs[:20])
    # the tables to their last printed digit
    for name, text in want["tables"].items():
        assert got["tables"][name] == text, name


def test_the_comparison_sees_a_change():
    want = {"a": {"rmse": [0.25, 1e-3], "cells": 7}}
    assert differences({"a": {"rmse": [0.25, 1e-3 * (1 + 1e-12)], "cells": 7}}, want) == []
    assert differences({"a": {"rmse": [0.25, 1e-3 * (1 + 1e-8)], "cells": 7}}, want) == \
        [f"/a/rmse[1]: {1e-3 * (1 + 1e-8)!r}, pinned 0.001"]
    assert differences({"a": {"rmse": [0.25], "cells": 7}}, want) == ["/a/rmse: 1 items, pinned 2"]
    assert differences({"a": {"rmse": [0.25, 1e-3], "cells": 8}}, want) == ["/a/cells: 8, pinned 7"]


def _files(out: Path) -> dict[str, bytes]:
    return {p.relative_to(out).as_posix(): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}


def _without_times(name: str, data: bytes) -> object:
    """A file's content without what records when or how long: the page's generation time, a cache
    entry's ``elapsed_s`` and ``model_elapsed_s``."""
    if name == "index.html":
        return re.sub(rb"generated \d{4}-\d\d-\d\d \d\d:\d\d:\d\d \w+", b"generated T",
                      re.sub(rb'"generated":"[^"]*"', b'"generated":"T"', data))
    if name.startswith("cache/") and name.endswith(".json"):
        entry = json.loads(data)
        entry.pop("elapsed_s", None)
        entry.pop("model_elapsed_s", None)
        return entry
    return data


def test_a_parallel_report_writes_the_same_files(serial):
    base, out = serial
    par = build(base, jobs=2, name="report-jobs2")
    a, b = _files(out), _files(par)
    assert set(a) == set(b)
    assert any(n.endswith(".png") for n in a) and any(n.startswith("cache/") and n.endswith(".h5") for n in a)
    # byte for byte, but for the times: the page's generation time and each cache entry's seconds
    different = [n for n in a if a[n] != b[n]]
    assert all(n == "index.html" or (n.startswith("cache/") and n.endswith(".json")) for n in different), different
    assert [n for n in a if _without_times(n, a[n]) != _without_times(n, b[n])] == []
