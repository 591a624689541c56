"""The analytic models whose kernels run their directions in parallel (issue 34: Weidlich-Wilkie,
multilayer-lut, the coat layering of the production models) give the same bits whatever the numba
thread count: a direction's values depend on it alone (docs/architecture.md, determinism)."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from goniometer.grids.slice_grid import light_direction
from models import registry

PARALLEL = ("ww09", "elek10", "ww-bati19", "multilayer-lut", "openpbr-coat", "standard-surface-coat")


def _views(n: int, seed: int) -> np.ndarray:
    v = np.random.default_rng(seed).normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2])
    return v / np.linalg.norm(v, axis=1, keepdims=True)


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="one numba thread: nothing to compare")
@pytest.mark.parametrize("name", PARALLEL)
def test_same_bits_whatever_the_threads(name, plastic, metal):
    model = registry.get(name)
    stacks = [s for s in (plastic, metal) if model.reason(s) is None]
    assert stacks, f"{name} supports neither test stack"
    v = _views(5000, seed=7)
    threads = numba.get_num_threads()
    for stack in stacks:
        for theta in (0.0, 45.0, 80.0):
            l = light_direction(theta, 20.0)
            numba.set_num_threads(2)
            try:
                a = model.evaluate(stack, l, v)
                numba.set_num_threads(1)
                b = model.evaluate(stack, l, v)
            finally:
                numba.set_num_threads(threads)
            assert np.any(a.internal > 0)
            assert a.top.tobytes() == b.top.tobytes() and a.internal.tobytes() == b.internal.tobytes(), (name, theta)
