"""The house's floors (docs/architecture.md): the simulator imports nothing above it, nothing
below the application imports the application, no import circles, and ``gonio --help`` stays light.

Imports are read from the sources (every ``import`` statement, function-level ones included), so
a lazy import cannot hide an upward dependency; the simulator is also imported for real in a fresh
interpreter to catch what the sources do not show.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("goniometer", "models")
#: the application floor: CLI commands, reports, HTML, figures
APPLICATION = ("goniometer.cli", "models.commands", "models.report")


def _modules() -> dict[str, Path]:
    found = {}
    for pkg in PACKAGES:
        for p in sorted((ROOT / pkg).rglob("*.py")):
            parts = list(p.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            found[".".join(parts)] = p
    return found


MODULES = _modules()


def _resolve(name: str) -> str | None:
    """The project module an imported dotted name refers to (longest known prefix)."""
    parts = name.split(".")
    while parts:
        cand = ".".join(parts)
        if cand in MODULES:
            return cand
        parts.pop()
    return None


def _imports(module: str) -> set[str]:
    """Project modules imported anywhere in ``module`` (TYPE_CHECKING blocks included)."""
    tree = ast.parse(MODULES[module].read_text(encoding="utf-8"))
    is_pkg = MODULES[module].name == "__init__.py"
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = module.split(".")
                anchor = anchor if is_pkg else anchor[:-1]
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join(anchor + ([base] if base else []))
            names = [f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base for a in node.names]
        else:
            continue
        for n in names:
            target = _resolve(n)
            if target is not None and target != module:
                out.add(target)
    return out


GRAPH = {m: _imports(m) for m in MODULES}


def _in(module: str, prefixes: tuple[str, ...]) -> bool:
    return any(module == p or module.startswith(p + ".") for p in prefixes)


def test_the_module_list_is_read():
    # guards the tests below against an empty or mis-rooted scan
    assert "goniometer.kernel.tracer" in MODULES and "models.base" in MODULES
    assert "goniometer.optics" in GRAPH["goniometer.kernel.event"]


def test_simulator_imports_nothing_from_models():
    upward = sorted(f"{m} -> {t}" for m, ts in GRAPH.items() if _in(m, ("goniometer",))
                    for t in ts if _in(t, ("models",)))
    assert not upward, "the simulator imports the models: " + ", ".join(upward)


def test_nothing_below_the_application_imports_it():
    upward = sorted(f"{m} -> {t}" for m, ts in GRAPH.items() if not _in(m, APPLICATION)
                    for t in ts if _in(t, APPLICATION))
    assert not upward, "lower floors import the application: " + ", ".join(upward)


#: the simulator's rooms from the ground up (docs/architecture.md, "Rooms of the simulator"): a
#: module imports only modules of its own room or of a room below it
SIMULATOR_ROOMS = (
    ("goniometer._lazy", "goniometer.cache", "goniometer.bits", "goniometer.atomic", "goniometer.tomlfile"),
    ("goniometer.spectral",),
    ("goniometer.stack",),
    ("goniometer.optics",),
    ("goniometer.grids",),
    ("goniometer.kernel",),
    ("goniometer.run",),
    ("goniometer.files",),
    ("goniometer.database",),
    ("goniometer.testing",),
    ("goniometer.cli",),
)


def _room(module: str) -> int:
    """The floor of ``module`` among :data:`SIMULATOR_ROOMS` (the package face ``goniometer`` is on the ground)."""
    if module == "goniometer":     # the face: the version and the cache's configuration; its names load lazily
        return 0
    for k, room in enumerate(SIMULATOR_ROOMS):
        if _in(module, room):
            return k
    raise AssertionError(f"{module} is in no room of SIMULATOR_ROOMS: give it one")


def test_every_simulator_module_has_a_room():
    for m in MODULES:
        if _in(m, ("goniometer",)):
            _room(m)


def test_nothing_in_the_simulator_imports_a_room_above_its_own():
    upward = sorted(f"{m} -> {t}" for m, ts in GRAPH.items() if _in(m, ("goniometer",))
                    for t in ts if _in(t, ("goniometer",)) and _room(t) > _room(m))
    assert not upward, "imports that run back up inside the simulator: " + ", ".join(upward)


def test_the_settings_stand_without_numba_and_the_kernel():
    """The data contract (docs/architecture.md): the settings import neither numba nor the kernel, so
    the command line takes its vocabularies and defaults from them without loading the kernel."""
    imported = GRAPH["goniometer.run.settings"]
    assert not [m for m in imported if _in(m, ("goniometer.kernel",))], imported
    tree = ast.parse(MODULES["goniometer.run.settings"].read_text(encoding="utf-8"))
    names = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    names |= {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
    assert not [n for n in names if n == "numba" or n.startswith("numba.")], names


def test_the_rooms_test_can_fail():
    # guards the test above: a real upward pair is seen as one
    assert _room("goniometer.run.settings") > _room("goniometer.kernel.tracer")
    assert "goniometer.kernel.tracer" in GRAPH["goniometer.run.tasks"]


def _cycles() -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in GRAPH[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(GRAPH):
        if v not in index:
            visit(v)
    return out


def test_no_import_circles():
    cycles = _cycles()
    assert not cycles, f"import circles: {cycles}"


def _fresh(code: str) -> str:
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.strip()


def test_importing_every_simulator_module_loads_no_model():
    sim = sorted(m for m in MODULES if _in(m, ("goniometer",)) and not m.endswith("__main__"))
    code = ("import importlib, sys\n"
            f"for m in {sim!r}: importlib.import_module(m)\n"
            "print(sorted(m for m in sys.modules if m == 'models' or m.startswith('models.')))")
    assert _fresh(code) == "[]"


@pytest.mark.parametrize("package", ["goniometer", "models"])
def test_the_public_face_is_light(package):
    # importing a package loads no submodule beyond what its face needs (names load on use)
    code = (f"import sys; import {package}\n"
            f"print(sorted(m for m in sys.modules if m.startswith('{package}.')))")
    loaded = eval(_fresh(code))
    assert set(loaded) <= {"goniometer.cache", "goniometer._lazy"}, loaded


def test_gonio_help_imports_no_model():
    code = ("import sys, contextlib, io\n"
            "from goniometer.cli import build_parser\n"
            "p = build_parser()\n"
            "with contextlib.redirect_stdout(io.StringIO()): p.format_help()\n"
            "print(sorted(m for m in sys.modules if m.startswith('models.') and not m.startswith('models.commands')))")
    assert _fresh(code) == "[]"


def test_start_up_compiles_nothing():
    # gonio --help and gonio models (which builds every model) neither compile nor load a numba
    # function: each is compiled (or loaded from its cache) on first use, the np_* ufuncs of
    # goniometer.optics included (goniometer.optics.LazyUfunc; issue 34: 1.5 s per process start)
    code = ("import sys, contextlib, io\n"
            "from numba.core.dispatcher import Dispatcher\n"
            "from goniometer.cli import main\n"
            "from goniometer.optics import LazyUfunc\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n"
            "    for argv in (['--help'], ['models']):\n"
            "        try:\n"
            "            main(argv)\n"
            "        except SystemExit:\n"
            "            pass\n"
            "built, lazy = [], 0\n"
            "for name, mod in list(sys.modules.items()):\n"
            "    if name.split('.')[0] not in ('goniometer', 'models'):\n"
            "        continue\n"
            "    for attr, obj in list(vars(mod).items()):\n"
            "        if isinstance(obj, Dispatcher) and obj.overloads:\n"
            "            built.append(f'{name}.{attr}')\n"
            "        if isinstance(obj, LazyUfunc):\n"
            "            lazy += 1\n"
            "            if obj._ufunc is not None:\n"
            "                built.append(f'{name}.{attr}')\n"
            "print(sorted(set(built)), lazy > 0, 'models.weidlich_wilkie' in sys.modules)")
    assert _fresh(code) == "[] True True"
