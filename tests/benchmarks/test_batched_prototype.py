"""The batched research prototype (``benchmarks/prototypes/batched_kernel.py``, issue 15) traces
the simulator's physics: on the coated metal of issue 15 and a coated transmitting slab, with
independent random streams, its per-cell BRDF weight sums (all bounce orders, and the single
reflection alone) and its reflected energy agree with the simulator's within their Monte Carlo
errors (also for the float32, fast-math variant on the metal); another base roughness is told
apart (the test can fail); its energy bookkeeping closes exactly; and a path's result does not
depend on the lane it ran in (lane counts 16 and 64 give the same sums to rounding)."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import numpy as np
import pytest

from goniometer.settings import SimulationSettings
from goniometer.slices import CLASSIC, light_direction
from goniometer.stack import Interface, Medium, Stack
from goniometer.tasks import n_tasks, trace_tasks
from tests.conftest import Z_TOL, chi2_limit

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks" / "prototypes"))
batched = importlib.import_module("batched_kernel")

RAYS = 200_000
RES = (9, 36)
THETA = 30.0


def _metal(alpha1: float) -> Stack:
    return Stack("metal", (Interface(0.05, (1.5,) * 3), Medium((0.1, 0.2, 0.5)),
                           Interface(alpha1, (1.45,) * 3, (1.0, 0.01, 0.01))), "metal")


SLAB = Stack("slab", (Interface(0.3, (1.5,) * 3), Medium((0.05, 0.1, 0.4)), Interface(0.2, (1.0,) * 3)), "slab")


def _simulator(stack: Stack):
    s = SimulationSettings(incident_deg=(THETA,), rays=RAYS, resolution=RES, parametrization="classic",
                           threads=1, seed=1)
    parts = trace_tasks(stack, s, 0, 0, n_tasks(s))
    acc = parts[0]
    for p in parts[1:]:
        acc.add(p)
    return acc.brdf, acc.energy, acc.energy_sq


def _compare(stack_sim: Stack, stack_proto: Stack, variant: str = "plain"):
    """Chi-square and degrees of freedom of the cell sums (all orders; order 1), and the largest
    z-score of the reflected energy, simulator (seed 1) against the prototype (seed 2)."""
    h_sim, e_sim, q_sim = _simulator(stack_sim)
    h_pro, _, e_pro, q_pro, _ = batched.trace_batched(stack_proto, light_direction(THETA), RAYS, CLASSIC, *RES,
                                                      seed=2, variant=variant)
    K = h_sim.shape[2] - 2
    out = []
    for rows, sq_row in ((slice(0, K), K), (slice(0, 1), None)):
        a = h_sim[:, :, rows, :].sum(axis=2)
        b = h_pro[:, :, rows, :].sum(axis=2)
        if sq_row is None:
            # order 1 alone: its squares are the all-orders squares minus the internal ones
            qa = h_sim[:, :, K, :] - h_sim[:, :, K + 1, :]
            qb = h_pro[:, :, K, :] - h_pro[:, :, K + 1, :]
        else:
            qa = h_sim[:, :, K, :]
            qb = h_pro[:, :, K, :]
        var = (qa / RAYS - (a / RAYS) ** 2 + qb / RAYS - (b / RAYS) ** 2) / RAYS
        hits = (a + b) ** 2 / np.maximum(qa + qb, 1e-300)
        sel = hits >= 100.0
        out.append((float(np.sum(((a - b)[sel] / RAYS) ** 2 / var[sel])), int(sel.sum())))
    e_var = (q_sim[0] / RAYS - (e_sim[0] / RAYS) ** 2 + q_pro[0] / RAYS - (e_pro[0] / RAYS) ** 2) / RAYS
    z = float(np.max(np.abs(e_sim[0] - e_pro[0]) / RAYS / np.sqrt(e_var)))
    return out, z


@pytest.mark.parametrize("stack, variant", [(_metal(0.2), "plain"), (SLAB, "plain"), (_metal(0.2), "f32-arcp-contract")],
                         ids=["metal", "slab", "metal-f32-arcp-contract"])
def test_prototype_agrees_with_simulator(stack, variant):
    (all_orders, single), z = _compare(stack, stack, variant)
    # the single reflection of the metal's alpha0 = 0.05 coat is a peak a few cells wide
    for (chi2, dof), min_dof in ((all_orders, 100), (single, 30)):
        assert dof > min_dof
        assert chi2 < chi2_limit(dof), (chi2, dof)
    assert z < Z_TOL


def test_prototype_tells_another_roughness_apart():
    ((chi2, dof), _), _ = _compare(_metal(0.2), _metal(0.3))
    assert chi2 > chi2_limit(dof), (chi2, dof)


def test_prototype_energy_closes_and_lanes_do_not_matter():
    l = light_direction(THETA)
    runs = [batched.trace_batched(SLAB, l, 50_000, CLASSIC, *RES, seed=3, lanes=lanes, chunk_rays=20_000)
            for lanes in (16, 64)]
    for h, _, e, _, events in runs:
        # reflected + transmitted + absorbed + masking + roulette = rays, per channel
        total = e[batched.E_REFLECTED] + e[batched.E_TRANSMITTED] + e[batched.E_ABSORBED] + e[batched.E_MASKING] \
            + e[batched.E_ROULETTE]
        np.testing.assert_allclose(total, 50_000, rtol=1e-12)
        assert events > 50_000
    (h16, t16, e16, q16, ev16), (h64, t64, e64, q64, ev64) = runs
    assert ev16 == ev64
    np.testing.assert_allclose(h16, h64, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(t16, t64, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(e16, e64, rtol=1e-12)
    np.testing.assert_allclose(q16, q64, rtol=1e-12)
