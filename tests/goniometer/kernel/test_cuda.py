"""The CUDA kernel (``docs/gpu.md``) without a GPU: the device setting and its refusals, and the
kernel under numba-cuda's simulator against its CPU twin, the per-path kernel (the same transport
and the same paths; in a subprocess, since the simulator must be chosen before ``numba.cuda`` is
first imported). The twin's transport is checked against the lane kernel's by
``test_two_kernels.py``; the kernel compiled for GPUs by ``test_cuda_compile.py``."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

from goniometer.run.settings import EVENT_CAP
from goniometer.kernel import tracer
from goniometer.cli import main
from goniometer.run.settings import SettingsError, SimulationSettings

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


@pytest.mark.skipif(not HAS_NUMBA_CUDA, reason="numba-cuda is not installed")
def test_the_polarized_cuda_kernel_in_the_simulator_traces_its_twins_paths():
    """Polarized light under the simulator (4 x 8 cells, 300 paths): a coated conductor, a rough and
    a smooth dielectric slab; the Mueller histograms (signed, fixed point) equal the per-path
    kernel's float64 sums of the same paths to within rays * 2^-32 (twice the rounding's bound), and
    a polarized tabulation's per-path Mueller matrices equal the twin's."""
    env = dict(os.environ, NUMBA_ENABLE_CUDASIM="1", PYTHONPATH=str(ROOT))
    r = subprocess.run([sys.executable, str(ROOT / "tests/goniometer/kernel/cuda_sim_check.py"), "--polarized", "300"],
                       env=env, capture_output=True, text=True, cwd=ROOT, timeout=900)
    assert r.returncode == 0 and "ALL OK" in r.stdout, r.stdout + r.stderr


def test_a_polarized_cuda_run_without_a_gpu_is_the_device_line(tmp_path, capsys):
    """A polarized run on cuda is no longer refused by its settings: without numba-cuda or a GPU the
    device's own line, exit 2, nothing written."""
    code = main(["simulate", str(ROOT / "configs/examples/metal.toml"), "--out", str(tmp_path / "m.h5"),
                 "--device", "cuda", "--polarized", "--rays", "100"])
    err = capsys.readouterr().err.strip().splitlines()
    if code == 0:
        pytest.skip("a CUDA GPU is visible (or the simulator is on)")
    assert code == 2 and err[-1].startswith("gonio: error: device: cuda"), err
    assert not (tmp_path / "m.h5").exists()
