"""The pinned error table of the tiny database: ``tests/data/tiny_database.toml`` at quick quality
(5 materials: plastic, metal, slab; classic and half grids), every default built-in model (the
installed model plugins left out, so that the pin holds with or without ``examples/plugin-model``),
as the report wrote it on main e901683, before the harness was made faster (issue 34). The report's numbers
must not change when its evaluation does (``tests/models/test_report_pinned.py``).

Recorded with ``python -m tests.models.pinned_report --write`` (simulates the database into a
temporary directory, builds the report serially, writes ``tests/data/tiny_report_pinned.json``).

What is pinned: every error object of ``errors.json`` (``rmse``, noise floors, ``reference_norm``,
``cells``) at full precision, and the tables (``tables/<category>.csv`` and ``.md``) as text, i.e.
to their last printed digit. The full-precision numbers are compared to :data:`REL` relative: the
sums over a cell's sub-cells may be taken in another order than the recorded code took them
(``numpy.einsum`` picks its own order; a faster integration another one), which moves the last
bits of a double (relative 1e-16 per cell), and no printed digit.
"""

from __future__ import annotations

import contextlib
import json
import math
import sys
import tempfile
from pathlib import Path
from typing import Iterator

DATA = Path(__file__).resolve().parents[1] / "data"
TINY = DATA / "tiny_database.toml"
PINNED = DATA / "tiny_report_pinned.json"
QUALITY = "quick"
#: relative tolerance of the full-precision numbers (the reassociation of a cell's sum, see above)
REL = 1e-9


def report_view(out: Path) -> dict:
    """What is pinned of the report directory ``out``: the error objects per (material, model) and
    the tables' text."""
    records = json.loads((out / "errors.json").read_text())
    errors = {f"{r['material']} | {r['model']}": {"side": r["side"], "internal": r["internal"],
                                                    "total": r["total"]} for r in records}
    tables = {p.name: p.read_text() for p in sorted((out / "tables").iterdir())}
    return {"errors": errors, "tables": tables}


def differences(got: object, want: object, where: str = "", rel: float = REL) -> list[str]:
    """Where ``got`` differs from ``want``: numbers beyond ``rel`` relative, anything else exactly."""
    if isinstance(want, dict) and isinstance(got, dict):
        out = [f"{where}/{k}: missing" for k in want if k not in got]
        out += [f"{where}/{k}: not pinned" for k in got if k not in want]
        for k in want:
            if k in got:
                out += differences(got[k], want[k], f"{where}/{k}", rel)
        return out
    if isinstance(want, list) and isinstance(got, list):
        if len(got) != len(want):
            return [f"{where}: {len(got)} items, pinned {len(want)}"]
        return [d for i, (g, w) in enumerate(zip(got, want)) for d in differences(g, w, f"{where}[{i}]", rel)]
    if isinstance(want, float) and isinstance(got, (int, float)) and not isinstance(got, bool):
        if math.isclose(got, want, rel_tol=rel, abs_tol=0.0):
            return []
        return [f"{where}: {got!r}, pinned {want!r}"]
    return [] if got == want else [f"{where}: {got!r}, pinned {want!r}"]


@contextlib.contextmanager
def built_in_models_only() -> Iterator[None]:
    """Within the block the registry of this process lists the built-in models only (no entry-point
    scan)."""
    from models import plugins
    real = plugins.entry_points
    plugins.entry_points = lambda group: []
    plugins.clear_cache()
    try:
        yield
    finally:
        plugins.entry_points = real
        plugins.clear_cache()


def build(tmp: Path, jobs: int | None = None, name: str = "report") -> Path:
    """Simulate the tiny database into ``tmp / "results"`` (if not there) and build its report into
    ``tmp / name``; returns the report directory."""
    from goniometer.database import load_database, simulate_database
    from models.report import build_report
    results = tmp / "results"
    if not results.exists():
        simulate_database(load_database(TINY), results, QUALITY)
    out = tmp / name
    kwargs = {} if jobs is None else {"jobs": jobs}
    build_report(results, out, models=default_built_in_models(), **kwargs)
    return out


def default_built_in_models() -> list[str]:
    """The models a report evaluates by default, the installed plugins' left out, in registry order:
    named explicitly, so that worker processes (which scan the installed plugins afresh) evaluate
    the same ones."""
    from models import registry
    with built_in_models_only():
        return [n for n, m in registry.all_models().items() if not m.on_request]


def main(argv: list[str]) -> int:
    if argv != ["--write"]:
        print("usage: python -m tests.models.pinned_report --write", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        view = report_view(build(Path(tmp)))
    PINNED.write_text(json.dumps(view, indent=1, sort_keys=True) + "\n")
    print(f"{PINNED}: {len(view['errors'])} error records, {len(view['tables'])} tables")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
