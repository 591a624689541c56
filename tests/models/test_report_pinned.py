"""The report's numbers do not move when its evaluation gets faster (issue 34): the error table of the
tiny database, every default built-in model, equals the one recorded before (tests/models/pinned_report.py)."""

from __future__ import annotations

import json

import pytest

from tests.models.pinned_report import PINNED, build, differences, report_view


@pytest.fixture(scope="module")
def serial(tmp_path_factory):
    base = tmp_path_factory.mktemp("pinned")
    return base, build(base)


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
