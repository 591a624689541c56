"""The README's Python API example runs verbatim and prints what it promises."""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def _python_api_block() -> str:
    text = README.read_text(encoding="utf-8")
    section = text.split("## Python API", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert len(blocks) == 1, "the Python API section holds one python block"
    return blocks[0]


def test_readme_python_api_block_runs():
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(_python_api_block(), str(README), "exec"), {"__name__": "readme"})
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("reflected R, G, B:")
    reflected = [float(x) for x in re.findall(r"[0-9.]+(?:e-?\d+)?", lines[0].split(":", 1)[1])]
    assert len(reflected) == 3 and all(0.0 < r < 1.0 for r in reflected)
    names = [ln.split()[0] for ln in lines[1:]]
    assert sorted(names) == ["belcour-fwd", "ww09"]
    for ln in lines[1:]:
        rmse, floor = (float(x) for x in re.findall(r"RMSE (\S+)  noise floor (\S+)", ln)[0])
        assert rmse > 0 and floor > 0
