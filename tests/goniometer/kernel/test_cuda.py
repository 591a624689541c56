"""The CUDA kernel (``docs/gpu.md``) without a GPU: the device setting and its refusals, the kernel
under numba-cuda's simulator against its CPU twin (the same paths; in a subprocess, since the
simulator must be chosen before ``numba.cuda`` is first imported), and the twin's transport
against the lane kernel's, cell by cell and in every energy term within standard errors."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from goniometer.kernel import tracer
from goniometer.cli import main
from goniometer.run.settings import EVENT_CAP, SettingsError, SimulationSettings
from goniometer.grids.slice_grid import boundary_tables, light_direction
from goniometer.kernel.packing import pack
from goniometer.testing import Z_TOL, chi2_limit
from tests.goniometer.kernel import test_two_kernels as two

ROOT = Path(__file__).resolve().parents[3]
HAS_NUMBA_CUDA = importlib.util.find_spec("numba_cuda") is not None


def test_the_device_setting():
    assert SimulationSettings().device == "cpu"
    assert "device" not in SimulationSettings().to_dict()   # a CPU run's identity predates the field
    s = SimulationSettings(device="cuda")
    assert s.to_dict()["device"] == "cuda" and SimulationSettings.from_dict(s.to_dict()) == s
    with pytest.raises(SettingsError, match="device: 'gpu' is not one of cpu, cuda"):
        SimulationSettings(device="gpu")


def test_cuda_without_numba_cuda_is_one_line(monkeypatch, tmp_path, capsys):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda n, *a: None if n == "numba_cuda" else real(n, *a))
    with pytest.raises(tracer.DeviceError, match=r"needs numba-cuda \(pip install 'goniometer\[cuda\]'\)"):
        tracer.check_device("cuda")
    code = main(["simulate", str(ROOT / "configs/examples/metal.toml"), "--out", str(tmp_path / "m.h5"),
                 "--device", "cuda", "--rays", "100"])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == "gonio: error: device: cuda needs numba-cuda (pip install 'goniometer[cuda]')"


@pytest.mark.skipif(not HAS_NUMBA_CUDA, reason="numba-cuda is not installed")
def test_cuda_without_a_gpu_is_one_line(tmp_path):
    """Outside the simulator, without a GPU (this test's premise: skipped where one is visible)."""
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_ENABLE_CUDASIM"}
    code = ("import sys; from numba import cuda; sys.exit(0 if cuda.is_available() else 1)")
    if subprocess.run([sys.executable, "-c", code], env=env, capture_output=True).returncode == 0:
        pytest.skip("a CUDA GPU is visible")
    r = subprocess.run([sys.executable, "-m", "goniometer.cli", "simulate", str(ROOT / "configs/examples/metal.toml"),
                        "--out", str(tmp_path / "m.h5"), "--device", "cuda", "--rays", "100"],
                       env=env, capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip().splitlines()[-1] == ("gonio: error: device: cuda: no CUDA GPU is visible "
                                                 "(numba.cuda.is_available() is False)")
    assert not (tmp_path / "m.h5").exists()


@pytest.mark.skipif(not HAS_NUMBA_CUDA, reason="numba-cuda is not installed")
def test_the_cuda_kernel_in_the_simulator_traces_its_twins_paths():
    """Under the simulator (tiny grids, a few thousand paths): the kernel's integer sums are its CPU
    twin's float64 sums of the same paths to the fixed point's rounding, counters exactly, and
    every ray's unit weight is accounted for; a metal (height-correlated masking), a scattering
    medium under walks over a Lambertian base, filmed walks over a transmitting base."""
    env = dict(os.environ, NUMBA_ENABLE_CUDASIM="1", PYTHONPATH=str(ROOT))
    r = subprocess.run([sys.executable, str(ROOT / "tests/goniometer/kernel/cuda_sim_check.py"), "1000"],
                       env=env, capture_output=True, text=True, cwd=ROOT, timeout=900)
    assert r.returncode == 0 and "ALL OK" in r.stdout, r.stdout + r.stderr


def _twin(stack, seed, height_correlated=False):
    """The CUDA kernel's paths on the CPU (goniometer.kernel.onepath.trace_keyed_chunk), summed as
    test_two_kernels sums the lane kernel's."""
    from goniometer.kernel.onepath import trace_keyed_chunk
    p = pack(stack)
    f = tracer.prepare(p, (0, 0, 1), 1, 1, 0, 0, 0, 1, 1, boundary_tables("classic", 1, 1), 1, 1).facts
    l = light_direction(40.0, 10.0)
    cr = 1 << 14
    nb = -(-two.RAYS // cr)
    bt = two.RES if stack.transmits else (1, 1)
    out = (np.zeros(two.RES + (two.K + 2, 3)), np.zeros(bt + (two.K + 2, 3)), np.zeros((tracer.N_ENERGY, 3)),
           np.zeros((tracer.N_ENERGY_SQ, 3)), np.zeros(tracer.N_COUNTS, dtype=np.int64))
    for b in range(nb):
        trace_keyed_chunk(*(getattr(p, k) for k in ("if_alpha", "if_rot", "if_ms", "if_film", "region_tau",
                                                    "region_albedo", "region_g", "cond", "rho", "base_kind")),
                          f.tau_mode, f.eta_dn, f.eta_up, *l, min(cr, two.RAYS - b * cr), seed, 0, b, 0, *two.RES,
                          *boundary_tables("classic", *two.RES), two.K, EVENT_CAP, False, height_correlated,
                          *out, np.empty(0, dtype=np.int64), np.empty((0, 3)))
    return out


@pytest.mark.parametrize("name", [n if n == "metal" else pytest.param(n, marks=pytest.mark.slow)
                                  for n in sorted(two.STACKS)])
def test_the_cuda_transport_agrees_with_the_lane_kernel(name):
    """The CUDA kernel's transport (its CPU twin, 240 000 paths) against the lane kernel on every
    two-kernel test stack: chi-square per cell and every energy term within standard errors."""
    stack = two.STACKS[name]
    hc = name == "metal"
    lanes = two._trace(stack, tracer.KERNEL_LANES, 1, hc)
    twin = _twin(stack, 2, hc)
    for part in (0, 1) if stack.transmits else (0,):
        chi2, dof = two._cells_chi2(lanes[part], twin[part])
        assert dof >= 40, f"only {dof} cells hit well enough"
        assert chi2 < chi2_limit(dof), f"{name} part {part}: chi2 {chi2:.1f} over {dof} cells"
    n = two.RAYS
    for row in range(tracer.N_ENERGY_SQ):
        var = (lanes[3][row] - lanes[2][row] ** 2 / n) + (twin[3][row] - twin[2][row] ** 2 / n)
        assert np.all(np.abs(lanes[2][row] - twin[2][row]) <= Z_TOL * np.sqrt(var) + 1e-12 * n), (name, row)
    total = twin[2][:tracer.N_ENERGY].sum(0) - twin[2][tracer.E_REFLECTED_WITHOUT_BASE]
    np.testing.assert_allclose(total, n, rtol=1e-12)
