"""docs/models.md section 9.5: the plugin example checked against a simulation with
goniometer.testing runs as it is written, passes, and its wrong-index check fails the model."""

from __future__ import annotations

import contextlib
import io
import re
import sys

from tests.models.harness_helpers import EXAMPLE, ROOT

DOC = ROOT / "docs" / "models.md"


def _block() -> str:
    text = DOC.read_text(encoding="utf-8")
    section = text.split("### 9.5 Checking a model against the simulator", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert len(blocks) == 1, "section 9.5 holds one python block"
    return blocks[0]


def test_the_documented_plugin_check_runs(monkeypatch):
    code = _block()
    assert "from goniometer.testing import" in code and "assert_cells_match" in code
    monkeypatch.syspath_prepend(str(EXAMPLE))
    monkeypatch.delitem(sys.modules, "example_plugin", raising=False)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(code, str(DOC), "exec"), {"__name__": "models_md_9_5"})
    chi2, dof, limit = (float(x) for x in re.fullmatch(
        r"coated-diffuse: chi2 (\S+) over (\S+) cells \(limit (\S+)\)\n", out.getvalue()).groups())
    assert dof > 1000 and 0 < chi2 < limit
