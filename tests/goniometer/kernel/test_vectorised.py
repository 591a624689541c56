"""The lane kernel's step is vectorised by LLVM (``docs/kernel.md``, section 4), and its bits do
not depend on the CPU's vector width (section 5)."""

from __future__ import annotations

import hashlib
import json
import os
import re
import subprocess
import sys
import textwrap

import llvmlite.binding as llvm
import numba
import numpy as np
import pytest

from goniometer.kernel import event
from goniometer.kernel.layout import LANES, N_FIELDS


def _host_has(feature: str) -> bool:
    return f"+{feature}" in llvm.get_host_cpu_features().flatten().split(",")


def _step_args(walks: bool, film: bool) -> tuple:
    """Arguments selecting a coated metal's specialisation of the step: separable masking, slices,
    no Lambertian base, a conductor whose blue channel shares the green one's index, isotropic;
    with ``walks``: multiple-scattering interfaces, a scattering medium and height-correlated
    masking; with ``film``: filmed interfaces (their Airy terms, docs/kernel.md); scalar light."""
    flag = True if walks else None
    return (np.zeros(N_FIELDS * LANES), np.zeros(400), 16, 2, False, 1, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
            10000, 0.5, 0.0, 0.8, np.uint64(1), 0, 5, flag, None, flag, None, True, None, True, None, flag,
            True if film else None, None)


@pytest.mark.skipif(not _host_has("avx2"), reason="the packed-instruction check is for x86-64 CPUs with AVX2 or AVX-512")
def test_the_step_loop_is_vectorised_on_this_host():
    """The coated metal's specialisation of the step, compiled afresh for this CPU (cached code
    cannot be inspected), holds packed square roots and divisions; on an AVX-512 host also packed
    gathers on 512-bit vectors (on AVX2 hosts such as Zen 3 LLVM's cost model loads the lanes one by
    one: docs/kernel.md section 4)."""
    f = numba.njit(error_model="numpy", boundscheck=False)(event.step.py_func)
    f(*_step_args(False, False))
    asm = f.inspect_asm(f.signatures[0])
    ops = ("vsqrtpd", "vdivpd") + (("vgatherqpd",) if _host_has("avx512f") else ())
    for op in ops:
        assert re.search(rf"\b{op}\b[^\n]*%[yz]mm", asm), f"no packed {op} in the step"
    if _host_has("avx512f"):
        assert re.search(r"\bvsqrtpd\s+%zmm", asm), "AVX-512 host: the step should use 512-bit vectors"


_VARIANTS = textwrap.dedent('''
    import json, re, numba
    from goniometer.kernel import event
    from tests.goniometer.kernel.test_vectorised import _step_args
    out = {}
    for name, walks, film in (("metal", False, False), ("walks-medium-height-correlated", True, False),
                              ("filmed-metal", False, True)):
        f = numba.njit(error_model="numpy", boundscheck=False)(event.step.py_func)
        f.compile(tuple(numba.typeof(a) for a in _step_args(walks, film)))
        asm = f.inspect_asm(f.signatures[0])
        out[name] = {op: len(re.findall(r"\\b" + op + r"\\b[^\\n]*%[yz]mm", asm))
                     for op in ("vsqrtpd", "vdivpd", "vgatherqpd")}
    print(json.dumps(out))
''')


@pytest.mark.slow
def test_every_variant_of_the_step_vectorises_for_avx512(tmp_path):
    """Compiled (not run) for an AVX-512 CPU whatever the host (``NUMBA_CPU_NAME=skylake-avx512``,
    a fresh cache): the coated metal's, the walks' (with a scattering medium and height-correlated
    masking) and the filmed interfaces' specialisations all hold packed square roots, divisions and
    gathers."""
    env = {**os.environ, "NUMBA_CPU_NAME": "skylake-avx512", "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
    run = subprocess.run([sys.executable, "-c", _VARIANTS], env=env, cwd=root, capture_output=True, text=True,
                         timeout=1800)
    assert run.returncode == 0, run.stderr[-2000:]
    counts = json.loads(run.stdout.strip().splitlines()[-1])
    for name, ops in counts.items():
        for op, n in ops.items():
            assert n > 0, f"{name}: no packed {op} ({counts})"


_BITS = textwrap.dedent('''
    import hashlib, numpy as np
    from goniometer.run.settings import SimulationSettings
    from goniometer.run.tasks import n_tasks, trace_tasks
    from goniometer.stack import Interface, Lambertian, Medium, Stack
    stacks = [Stack("m", (Interface(0.05, (1.5,) * 3), Medium((0.1, 0.2, 0.5)),
                          Interface(0.2, (1.45,) * 3, (1.0, 0.01, 0.01))), "metal"),
              Stack("p", (Interface(0.3, (1.5,) * 3, roughness_y=0.1, rotation_deg=20.0), Medium((0.1, 0.2, 0.3)),
                          Lambertian((0.2, 0.5, 0.8))), "plastic"),
              Stack("w", (Interface(0.3, (1.5,) * 3), Medium((0.1, 0.2, 0.5)),
                          Interface(0.4, (1.45,) * 3, (1.0, 0.01, 0.01))), "metal").with_multiple_scattering(),
              Stack("e", (Interface(0.1, (1.5,) * 3), Medium((0.5, 1.0, 2.0), (0.9, 0.6, 0.3), 0.7),
                          Interface(0.2, (1.1,) * 3, (2.0,) * 3)), "metal")]
    h = hashlib.sha256()
    for stack in stacks:
        s = SimulationSettings(incident_deg=(30.0,), rays=200_000, resolution=(18, 72), threads=1, seed=3)
        for part in trace_tasks(stack, s, 0, 0, n_tasks(s)):
            for a in (part.brdf, part.btdf, part.energy, part.energy_sq, part.counts):
                h.update(np.ascontiguousarray(a).tobytes())
    print(h.hexdigest())
''')


@pytest.mark.slow
def test_generic_cpu_and_host_give_the_same_bits(tmp_path):
    """``NUMBA_CPU_NAME=generic`` (SSE2, no FMA) and the host CPU (its widest vectors) trace the
    same bits, walks on multiple-scattering interfaces and free flights in a scattering medium
    included (each compiles afresh, about a minute each)."""
    out = []
    for name, extra in (("generic", {"NUMBA_CPU_NAME": "generic"}), ("host", {})):
        env = dict(os.environ, GONIOMETER_CACHE=str(tmp_path / name), **extra)
        env.pop("NUMBA_CACHE_DIR", None)
        r = subprocess.run([sys.executable, "-c", _BITS], env=env, capture_output=True, text=True, check=True)
        out.append(r.stdout.strip())
    assert out[0] == out[1]
    assert len(out[0]) == len(hashlib.sha256().hexdigest())
