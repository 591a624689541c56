"""goniometer.run.checkpoints: resumable runs give the file an uninterrupted run gives, never mix in
checkpoints of another run or code version, and never discard them unasked (``docs/outputs.md``
rule 3): a rerun with another setting is refused, naming what differs, and keeps their bytes."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np
import pytest

from goniometer import atomic
from goniometer.run import checkpoints as checkpoint
from goniometer.files import slices as store
from goniometer.run.checkpoints import CheckpointMismatch, Checkpoints, CheckpointWarning, checkpoint_dir, differences
from goniometer.run.results import IncidentPart, run_description
from goniometer.cli import main
from goniometer.run.settings import SimulationSettings
from goniometer.run.loop import simulate, simulate_resumable
from goniometer.run.tasks import trace_incident
from goniometer.stack import Interface, Medium, Stack, load_toml
from tests.conftest import refused
from tests.goniometer.resume_helpers import assert_same_datasets, bytes_of, stop_after

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


def _bytes(d: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(d.iterdir())}


def test_checkpoints_of_another_run_or_code_are_refused_and_kept(tmp_path, monkeypatch):
    """A run never discards checkpoints it cannot use: CheckpointMismatch names each differing key
    with both values, and the directory keeps its bytes (load, check and save alike)."""
    d = tmp_path / "cp"
    Checkpoints(d, run_description(STACK, SETTINGS)).save(0, trace_incident(STACK, SETTINGS, 0))
    before = _bytes(d)
    other = SimulationSettings(**{**SETTINGS.__dict__, "seed": 6, "rays": 30_000})
    cps = Checkpoints(d, run_description(STACK, other))
    for call in (cps.check, lambda: cps.load(3), lambda: cps.save(1, trace_incident(STACK, SETTINGS, 1))):
        with pytest.raises(CheckpointMismatch) as e:
            call()
        assert e.value.differences == [("rays", 20_000, 30_000), ("seed", 5, 6)]
        assert "rays: checkpoints 20000, this run 30000; seed: checkpoints 5, this run 6" in str(e.value)
        assert e.value.other_run and not e.value.other_code and e.value.directory == d
        assert _bytes(d) == before
    thicker = Stack("m", (STACK.layers[0], Medium((0.2, 0.2, 0.3)), STACK.layers[2]))
    with pytest.raises(CheckpointMismatch) as e:
        Checkpoints(d, run_description(thicker, SETTINGS)).load(3)
    assert [k for k, _, _ in e.value.differences] == ["stack.layers[1].optical_depth"]
    integrated = SimulationSettings(**{**SETTINGS.__dict__, "first_order": "integrated"})
    with pytest.raises(CheckpointMismatch, match=r"first_order: checkpoints \(default\), this run integrated"):
        Checkpoints(d, run_description(STACK, integrated)).check()
    monkeypatch.setattr(checkpoint, "code_key", lambda: "other physics")
    with pytest.raises(CheckpointMismatch, match="written by another version of the simulator code") as e:
        Checkpoints(d, run_description(STACK, SETTINGS)).load(3)
    assert e.value.other_code and not e.value.other_run
    assert e.value.differences == [("code", checkpoint.cache.simulator_key(), "other physics")]
    assert _bytes(d) == before
    monkeypatch.undo()
    # the thread count is not part of a run
    more_threads = SimulationSettings(**{**SETTINGS.__dict__, "threads": 2})
    assert list(Checkpoints(d, run_description(STACK, more_threads)).load(3)) == [0]
    # clear() (--restart) is the one way to discard them; then another run's checkpoints start there
    cps.clear()
    assert not d.exists()
    cps.save(1, trace_incident(STACK, other, 1))
    assert list(cps.load(3)) == [1]


def test_differences_name_nested_keys_and_absent_ones():
    kept = {"settings": {"rays": 1_500_000, "resolution": [30, 60]}, "stack": {"layers": [{"roughness": 0.2}]},
            "code": "a"}
    wanted = {"settings": {"rays": 1_400_000, "resolution": [30, 60], "first_order": "integrated"},
              "stack": {"layers": [{"roughness": 0.3}]}, "code": "a"}
    assert differences(kept, wanted) == [("rays", 1_500_000, 1_400_000),
                                         ("first_order", "(default)", "integrated"),
                                         ("stack.layers[0].roughness", 0.2, 0.3)]
    assert differences({"run": {"settings": {"seed": 1}}}, {"run": {"settings": {"seed": 7}}}) == [("seed", 1, 7)]
    assert differences({"settings": {"resolution": [30, 60]}}, {"settings": {"resolution": [30, 90]}}) == [
        ("resolution", [30, 60], [30, 90])]
    assert differences(kept, kept) == []
    many = CheckpointMismatch("d", [(f"k{i}", i, i + 1) for i in range(9)])
    assert str(many).endswith("k5: checkpoints 5, this run 6; and 3 more)")


def test_checkpoints_without_a_readable_description_are_refused(tmp_path):
    """Checkpoint files whose meta.json is missing or unreadable are of an unknown run: refused,
    kept. A description without any checkpoint file beside it holds nothing: replaced."""
    d = tmp_path / "cp"
    cps = Checkpoints(d, run_description(STACK, SETTINGS))
    cps.save(0, trace_incident(STACK, SETTINGS, 0))
    (d / "meta.json").write_text("{not json")
    with pytest.raises(CheckpointMismatch, match="meta.json cannot be read") as e:
        cps.load(3)
    assert e.value.reason is not None and (d / "m00.npz").exists()
    (d / "meta.json").unlink()
    with pytest.raises(CheckpointMismatch, match="holds 1 checkpoint file"):
        cps.check()
    (d / "m00.npz").unlink()
    other = SimulationSettings(**{**SETTINGS.__dict__, "seed": 6})
    (d / "meta.json").write_text(json.dumps(Checkpoints(d, run_description(STACK, other)).meta))
    cps.save(1, trace_incident(STACK, SETTINGS, 1))   # nothing to lose: the description is this run's now
    assert list(cps.load(3)) == [1]


def test_checkpoints_are_compressed_and_read_back_bit_for_bit(tmp_path):
    part = trace_incident(STACK, SETTINGS, 1)
    path = tmp_path / "m01.npz"
    part.save(path)
    with zipfile.ZipFile(path) as z:
        assert {i.compress_type for i in z.infolist()} == {zipfile.ZIP_DEFLATED}
    back = IncidentPart.load(path)
    for name, value in part.__dict__.items():
        if isinstance(value, np.ndarray):
            got = getattr(back, name)
            assert got.dtype == value.dtype and got.tobytes() == value.tobytes(), name
        else:
            assert getattr(back, name) == value, name
    # smaller than the uncompressed archive; an uncompressed checkpoint (written before) still reads
    plain = tmp_path / "plain.npz"
    atomic.write_npz(plain, index=part.index, elapsed_s=part.elapsed_s,
                     **{k: v for k, v in part.__dict__.items() if isinstance(v, np.ndarray)})
    assert path.stat().st_size < 0.6 * plain.stat().st_size
    assert IncidentPart.load(plain).brdf.tobytes() == part.brdf.tobytes()


def test_unreadable_checkpoint_is_reported_and_traced_again(tmp_path, fresh):
    cps = Checkpoints(tmp_path / "cp", run_description(STACK, SETTINGS))
    cps.save(0, trace_incident(STACK, SETTINGS, 0))
    cps.save(1, trace_incident(STACK, SETTINGS, 1))
    (cps.directory / "m01.npz").write_bytes(b"truncated")
    resumed, told = [], []
    cps.on_discard = lambda path, reason: told.append((path, reason))
    r = simulate_resumable(STACK, SETTINGS, cps, on_resume=resumed.append)
    assert resumed == [1]
    assert told == [(cps.directory / "m01.npz", "not an npz archive: truncated or damaged")]
    _same(r, fresh)
    # without a callback: a CheckpointWarning (never silent)
    (cps.directory / "m01.npz").write_bytes(b"truncated")
    with pytest.warns(CheckpointWarning, match="m01.npz: unreadable checkpoint"):
        assert list(Checkpoints(cps.directory, run_description(STACK, SETTINGS)).load(3)) == [0, 2]


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


def test_gonio_simulate_refuses_another_setting_and_keeps_the_checkpoints(tmp_path, capsys, monkeypatch):
    """Issue 31 item 1: a rerun with a changed setting (or by another code version) is one line,
    exit 2, naming each differing key with both values; the checkpoints keep their bytes; the
    original command resumes them to the bits of an uninterrupted run; --restart discards them."""
    import goniometer.cli.simulate
    import goniometer.run.loop
    cfg = EXAMPLES / "metal.toml"
    args = ["--rays", "20000", "--incident", "0,60", "--resolution", "18x36", "--seed", "3", "--threads", "1"]
    ref = tmp_path / "ref.h5"
    assert main(["simulate", str(cfg), "--out", str(ref), *args]) == 0
    out = tmp_path / "m.h5"
    monkeypatch.setattr(goniometer.cli.simulate, "ResumeAware", stop_after(20000))   # Ctrl-C in direction 2
    capsys.readouterr()
    assert main(["simulate", str(cfg), "--out", str(out), *args]) == 130
    assert f"gonio: 1 finished incident direction(s) kept in {checkpoint_dir(out)}" in capsys.readouterr().err
    monkeypatch.undo()
    kept = bytes_of(checkpoint_dir(out))
    assert sorted(kept) == ["m00.npz", "meta.json"]
    line = refused(capsys, ["simulate", cfg, "--out", out, *args, "--rays", "30000", "--seed", "7"],
                   f"{checkpoint_dir(out)}: holds checkpoints of another run",
                   "rays: checkpoints 20000, this run 30000; seed: checkpoints 3, this run 7",
                   "rerun the command that wrote them to resume, or add --restart to discard them")
    assert "code" not in line
    assert bytes_of(checkpoint_dir(out)) == kept and not out.exists()
    monkeypatch.setattr(checkpoint, "code_key", lambda: "another version")
    refused(capsys, ["simulate", cfg, "--out", out, *args], "written by another version of the simulator code",
            "this version of the simulator cannot resume them", "add --restart to discard them")
    monkeypatch.undo()
    assert bytes_of(checkpoint_dir(out)) == kept
    # the original command resumes: only the second direction is traced, the file is the uninterrupted run's
    traced: list[int] = []
    trace = goniometer.run.loop.trace_incident
    monkeypatch.setattr(goniometer.run.loop, "trace_incident",
                        lambda stack, s, k, *a: traced.append(k) or trace(stack, s, k, *a))
    assert main(["simulate", str(cfg), "--out", str(out), *args]) == 0
    assert traced == [1] and not checkpoint_dir(out).exists()
    assert_same_datasets(out, ref)
    # --restart with the changed setting discards them and runs it
    out2 = tmp_path / "m2.h5"
    monkeypatch.setattr(goniometer.cli.simulate, "ResumeAware", stop_after(20000))
    assert main(["simulate", str(cfg), "--out", str(out2), *args]) == 130
    monkeypatch.setattr(goniometer.cli.simulate, "ResumeAware", goniometer.cli.common.ResumeAware)
    traced.clear()
    capsys.readouterr()
    assert main(["simulate", str(cfg), "--out", str(out2), *args, "--rays", "30000", "--restart"]) == 0
    assert traced == [0, 1] and "resuming" not in capsys.readouterr().err
    assert store.read(out2).settings.rays == 30000 and not checkpoint_dir(out2).exists()
