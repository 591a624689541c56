"""Every compiled function of the simulator states numba's error model (docs/kernel.md, compiled
functions): numba compiles a callee that does not state it with its caller's, and keeps the first
compilation of a signature, so a physics function first compiled from a caller with Python's
error model would later raise ZeroDivisionError inside the kernel (a parallel kernel then fails
with "returned a result with an exception set"), depending on what the process ran before."""

from __future__ import annotations

import importlib
import math
import pkgutil

import numba
import numpy as np
from numba.core.registry import CPUDispatcher

import goniometer
from goniometer import optics


def _simulator_modules():
    """The simulator's modules, its command-line application and the CUDA kernel excepted (the
    latter compiles for the device through numba-cuda, whose dispatchers are not CPU ones)."""
    for info in pkgutil.walk_packages(goniometer.__path__, "goniometer."):
        if info.name.startswith("goniometer.cli") or info.name == "goniometer.kernel.cuda":
            continue
        yield importlib.import_module(info.name)


def test_every_compiled_function_states_the_numpy_error_model():
    found, wrong = 0, []
    for mod in _simulator_modules():
        for name, obj in vars(mod).items():
            if isinstance(obj, CPUDispatcher) and obj.py_func.__module__ == mod.__name__:
                found += 1
                if obj.targetoptions.get("error_model") != "numpy":
                    wrong.append(f"{mod.__name__}.{name}")
    assert found > 100, f"only {found} compiled functions found: the walk missed modules"
    assert not wrong, f"compiled without error_model='numpy': {', '.join(wrong)}"


@numba.njit  # Python's error model, as a user's or a test's own function has
def _mis_from_a_plain_caller(p0, p1, p2):
    return optics.spectral_mis_update(p0, p1, p2, 1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0)


def test_a_zero_density_sum_gives_ieee_values_whoever_compiles_first():
    """A flight whose densities all underflow (a grazing crossing of an absorbing region: the
    kernel then uses Beer-Lambert factors, not these) gives non-finite factors, not an exception,
    from Python and from a caller with Python's error model alike."""
    for r in (_mis_from_a_plain_caller(0.0, 0.0, 0.0), optics.spectral_mis_update(0.0, 0.0, 0.0, 1 / 3, 1 / 3, 1 / 3)):
        assert all(math.isnan(x) for x in r)
    r = _mis_from_a_plain_caller(1.0, 2.0, 3.0)
    np.testing.assert_allclose(r[:3], np.array([1.0, 2.0, 3.0]) / 2.0)
