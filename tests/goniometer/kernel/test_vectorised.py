"""The lane kernel's step is vectorised by LLVM (``docs/kernel.md``, section 4), and its bits do
not depend on the CPU's vector width (section 5)."""

from __future__ import annotations

import hashlib
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


@pytest.mark.skipif(not _host_has("avx2"), reason="the packed-instruction check is for x86-64 CPUs with AVX2 or AVX-512")
@pytest.mark.parametrize("walks", [False, True], ids=["metal", "multiple-scattering-medium-height-correlated"])
def test_the_step_loop_is_vectorised(walks):
    """The coated metal's specialisation of the step, compiled afresh (cached code cannot be
    inspected), holds packed square roots, divisions and gathers; so does the one whose interfaces
    scatter multiply (the walks' first bounces, their heights from table-driven logarithms), whose
    medium scatters (free flights, Henyey-Greenstein directions) and whose masking is
    height-correlated (the Beta function from a series)."""
    f = numba.njit(error_model="numpy", boundscheck=False)(event.step.py_func)
    S = np.zeros(N_FIELDS * LANES)
    # a coated metal's variant: separable masking, slices, no Lambertian base, a conductor whose
    # blue channel shares the green one's index, isotropic; with walks: multiple-scattering
    # interfaces, a scattering medium and height-correlated masking
    flag = True if walks else None
    f(S, np.zeros(60), 16, 2, False, 1, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 10000, 0.5, 0.0, 0.8,
      np.uint64(1), 0, 5, flag, None, flag, None, True, None, True, None, flag)
    asm = f.inspect_asm(f.signatures[0])
    for op in ("vsqrtpd", "vdivpd", "vgatherqpd"):
        assert re.search(rf"\b{op}\b[^\n]*%[yz]mm", asm), f"no packed {op} in the step"
    if _host_has("avx512f"):
        assert re.search(r"\bvsqrtpd\s+%zmm", asm), "AVX-512 host: the step should use 512-bit vectors"


_BITS = textwrap.dedent('''
    import hashlib, numpy as np
    from goniometer.settings import SimulationSettings
    from goniometer.tasks import n_tasks, trace_tasks
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
