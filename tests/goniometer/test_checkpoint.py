"""goniometer.checkpoint: resumable runs give the file an uninterrupted run gives, and never mix
in checkpoints of another run or code version."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from goniometer import checkpoint, store
from goniometer.checkpoint import Checkpoints, checkpoint_dir
from goniometer.results import run_description
from goniometer.cli import main
from goniometer.settings import SimulationSettings
from goniometer.run import simulate, simulate_resumable
from goniometer.tasks import trace_incident
from goniometer.stack import Interface, Medium, Stack, load_toml

EXAMPLES = Path(__file__).resolve().parents[2] / "configs" / "examples"
STACK = Stack("m", (Interface(0.2, (1.5,) * 3), Medium((0.1, 0.2, 0.3)), Interface(0.3, (1.2,) * 3, (3.0,) * 3)))
SETTINGS = SimulationSettings(incident_deg=(0.0, 40.0, 70.0), rays=20_000, resolution=(18, 36), seed=5,
                              chunk_rays=4096, chunks_per_task=2)


def _same(a, b) -> None:
    np.testing.assert_array_equal(a.brdf.value, b.brdf.value)
    np.testing.assert_array_equal(a.brdf.stderr, b.brdf.stderr)
    np.testing.assert_array_equal(a.brdf.orders, b.brdf.orders)
    for k in a.energy:
        np.testing.assert_array_equal(a.energy[k], b.energy[k])


@pytest.fixture(scope="module")
def fresh():
    return simulate(STACK, SETTINGS)


def test_resumed_run_is_bit_identical(tmp_path, fresh):
    cps = Checkpoints(tmp_path / "cp", run_description(STACK, SETTINGS))
    assert not cps.directory.exists()  # created on the first save only
    cps.save(0, trace_incident(STACK, SETTINGS, 0))
    cps.save(2, trace_incident(STACK, SETTINGS, 2))
    resumed, rays = [], []
    r = simulate_resumable(STACK, SETTINGS, cps, progress=rays.append, on_resume=resumed.append)
    assert resumed == [2]
    assert sum(rays) == 3 * SETTINGS.rays
    _same(r, fresh)
    assert sorted(p.name for p in cps.directory.iterdir()) == ["m00.npz", "m01.npz", "m02.npz", "meta.json"]
    cps.clear()
    assert not cps.directory.exists()


def test_checkpoints_of_another_run_or_code_are_discarded(tmp_path, monkeypatch):
    d = tmp_path / "cp"
    Checkpoints(d, run_description(STACK, SETTINGS)).save(0, trace_incident(STACK, SETTINGS, 0))
    other = SimulationSettings(**{**SETTINGS.__dict__, "seed": 6})
    assert Checkpoints(d, run_description(STACK, other)).load(3) == {}
    assert not d.exists()
    thicker = Stack("m", (STACK.layers[0], Medium((0.2, 0.2, 0.3)), STACK.layers[2]))
    Checkpoints(d, run_description(STACK, SETTINGS)).save(0, trace_incident(STACK, SETTINGS, 0))
    assert Checkpoints(d, run_description(thicker, SETTINGS)).load(3) == {}
    Checkpoints(d, run_description(STACK, SETTINGS)).save(0, trace_incident(STACK, SETTINGS, 0))
    monkeypatch.setattr(checkpoint, "code_key", lambda: "other physics")
    assert Checkpoints(d, run_description(STACK, SETTINGS)).load(3) == {}
    # the thread count is not part of a run
    monkeypatch.undo()
    Checkpoints(d, run_description(STACK, SETTINGS)).save(1, trace_incident(STACK, SETTINGS, 1))
    more_threads = SimulationSettings(**{**SETTINGS.__dict__, "threads": 2})
    assert list(Checkpoints(d, run_description(STACK, more_threads)).load(3)) == [1]


def test_unreadable_checkpoint_is_traced_again(tmp_path, fresh):
    cps = Checkpoints(tmp_path / "cp", run_description(STACK, SETTINGS))
    cps.save(0, trace_incident(STACK, SETTINGS, 0))
    cps.save(1, trace_incident(STACK, SETTINGS, 1))
    (cps.directory / "m01.npz").write_bytes(b"truncated")
    resumed = []
    r = simulate_resumable(STACK, SETTINGS, cps, on_resume=resumed.append)
    assert resumed == [1]
    _same(r, fresh)


def test_gonio_simulate_resumes_and_restarts(tmp_path, capsys):
    cfg = EXAMPLES / "metal.toml"
    args = ["--rays", "20000", "--incident", "0,60", "--resolution", "18x36", "--seed", "3"]
    ref = tmp_path / "ref.h5"
    assert main(["simulate", str(cfg), "--out", str(ref), *args]) == 0
    capsys.readouterr()
    # what an interrupted run leaves: the first direction checkpointed
    out = tmp_path / "m.h5"
    stack, table = load_toml(cfg)
    settings = SimulationSettings.from_mapping(table).with_overrides(
        rays=20000, incident_deg=(0.0, 60.0), incident_phi_deg=(0.0, 0.0), resolution=(18, 36), seed=3)
    Checkpoints(checkpoint_dir(out), run_description(stack, settings)).save(0, trace_incident(stack, settings, 0))
    assert main(["simulate", str(cfg), "--out", str(out), *args]) == 0
    assert "resuming: 1 of 2 incident direction(s) already traced" in capsys.readouterr().err
    assert not checkpoint_dir(out).exists()
    _same(store.read(out), store.read(ref))
    # --restart discards them
    out2 = tmp_path / "m2.h5"
    Checkpoints(checkpoint_dir(out2), run_description(stack, settings)).save(0, trace_incident(stack, settings, 0))
    assert main(["simulate", str(cfg), "--out", str(out2), "--restart", *args]) == 0
    assert "resuming" not in capsys.readouterr().err
    _same(store.read(out2), store.read(ref))
