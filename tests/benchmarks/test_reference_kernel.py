"""The benchmarks' yardstick kernel (``benchmarks/reference_kernel.py``) traces the same physics as
the simulator: on the coated metal and the coated Lambertian, with independent random streams,
its per-cell BRDF weight sums and its reflected energy agree with the simulator's within their
Monte Carlo errors (chi-square over cells at the suite's false-alarm probability), and a stack
with another base roughness is told apart (the test can fail)."""

from __future__ import annotations

import importlib
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from goniometer.run.settings import SimulationSettings
from goniometer.grids.slice_grid import CLASSIC, light_direction
from goniometer.stack import Interface, Lambertian, Medium, Stack
from goniometer.run.tasks import n_tasks, trace_tasks
from goniometer.testing import Z_TOL, chi2_limit, effective_exits, mean_stderr, two_sample_chi2

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
reference_kernel = importlib.import_module("reference_kernel")

RAYS = 200_000
RES = (9, 36)
THETA = 30.0


def _metal(alpha1: float) -> Stack:
    return Stack("metal", (Interface(0.05, (1.5,) * 3), Medium((0.1, 0.2, 0.5)),
                           Interface(alpha1, (1.45,) * 3, (1.0, 0.01, 0.01))), "metal")


PLASTIC = Stack("plastic", (Interface(0.3, (1.5,) * 3), Medium((0.05, 0.1, 0.4)), Lambertian((0.2, 0.5, 0.8))),
                "plastic")


def _simulator(stack: Stack):
    s = SimulationSettings(incident_deg=(THETA,), rays=RAYS, resolution=RES, parametrization="classic",
                           threads=1, seed=1)
    parts = trace_tasks(stack, s, 0, 0, n_tasks(s))
    acc = parts[0]
    for p in parts[1:]:
        acc.add(p)
    K = s.max_order
    return acc.brdf[:, :, :K, :].sum(axis=2), acc.brdf[:, :, K, :], acc.energy[0], acc.energy_sq[0]


def _chi2(stack_sim: Stack, stack_ref: Stack) -> tuple[float, int, float]:
    """Chi-square of the cell sums (cells with >= 100 expected exits) and the z-score of the
    reflected energy, simulator (seed 1) against the yardstick (seed 2)."""
    sim, sim_sq, e_sim, e_sq = _simulator(stack_sim)
    ref, _, e_ref, ref_sq = reference_kernel.trace_reference(stack_ref, light_direction(THETA), RAYS, CLASSIC, *RES,
                                                             seed=2, squares=True)
    # each sample's cell means and standard errors from its own sums of squares (a cell mixes many
    # small weights with rare large ones: one sample alone may have missed those), cells selected
    # by the effective number of exits of both samples together
    a, sa = mean_stderr(sim, sim_sq, RAYS)
    b, sb = mean_stderr(ref, ref_sq, RAYS)
    chi2, dof = two_sample_chi2(a, sa, b, sb, effective_exits(sim + ref, sim_sq + ref_sq) >= 100.0)
    # the reflected energy: the yardstick's error taken as the simulator's (same physics, same rays)
    e_a, e_sa = mean_stderr(e_sim, e_sq, RAYS)
    z = float(np.max(np.abs(e_a - e_ref[0] / RAYS) / (math.sqrt(2.0) * e_sa)))
    return chi2, dof, z


@pytest.mark.parametrize("stack", [_metal(0.2), PLASTIC], ids=["metal", "plastic"])
def test_reference_kernel_agrees_with_simulator(stack):
    chi2, dof, z = _chi2(stack, stack)
    assert dof > 100
    assert chi2 < chi2_limit(dof), (chi2, dof)
    assert z < Z_TOL


def test_reference_kernel_tells_another_roughness_apart():
    chi2, dof, _ = _chi2(_metal(0.2), _metal(0.3))
    assert chi2 > chi2_limit(dof), (chi2, dof)
