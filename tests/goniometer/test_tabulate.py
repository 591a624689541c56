"""Tabulated BRDFs on the MERL grid (``docs/tabulated-format.md``): the grid against MERL's own
definition, the cell measure, a Lambertian base (rho / pi in every cell), determinism and resuming,
the MERL ``.binary`` read back by a reader written here from the format's definition and compared
with a classic slice, and the command line.

Tolerances are statistical: z-scores within Z_TOL, chi-square within chi2_limit (false-alarm
probability 1e-6, :mod:`goniometer.testing`, docs/testing.md).
"""

from __future__ import annotations

import hashlib
import json
import math
import struct
from pathlib import Path

import numpy as np
import pytest

import goniometer as g
from goniometer.grids import halfdiff
from goniometer.cli import main
from goniometer.run.tabulation import TabulationCheckpoint, tabulate, tabulation_description
from goniometer.testing import Z_TOL, chi2_limit, energy_total

EXAMPLES = Path(__file__).resolve().parents[2] / "configs" / "examples"
RHO = np.array([0.2, 0.5, 0.8])
#: MERL's scale per channel (stored value x scale = BRDF)
SCALE = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])


# ------------------------------------------------------------------ an independent MERL reader

def _rotate(v: np.ndarray, axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rodrigues' rotation of vectors v (n, 3) about a unit axis by angles (n,)."""
    c = np.cos(angle)[:, None]
    s = np.sin(angle)[:, None]
    a = np.broadcast_to(axis, v.shape)
    return v * c + a * np.sum(a * v, axis=1, keepdims=True) * (1.0 - c) + np.cross(a, v) * s


def merl_index(l: np.ndarray, v: np.ndarray) -> np.ndarray:
    """MERL's index of (light, view) pairs, from the format's definition: half vector angles, the
    difference vector (l rotated by -phi_h about z, then -theta_h about y), square-root mapped
    theta_h, phi_d folded by pi."""
    h = l + v
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    th = np.arccos(np.clip(h[:, 2], -1, 1))
    ph = np.arctan2(h[:, 1], h[:, 0])
    d = _rotate(_rotate(l, np.array([0.0, 0.0, 1.0]), -ph), np.array([0.0, 1.0, 0.0]), -th)
    td = np.arccos(np.clip(d[:, 2], -1, 1))
    pd = np.arctan2(d[:, 1], d[:, 0])
    ih = np.clip(np.sqrt(th / (np.pi / 2)) * 90, 0, 89).astype(int)
    idd = np.clip(td / (np.pi / 2) * 90, 0, 89).astype(int)
    pd = np.where(pd < 0, pd + np.pi, pd)
    ip = np.clip(pd / np.pi * 180, 0, 179).astype(int)
    return ip + 180 * (idd + 90 * ih)


def read_merl_binary(path: Path) -> np.ndarray:
    """(3, 90*90*180) stored values of a MERL .binary file (R, G, B planes)."""
    raw = path.read_bytes()
    dims = struct.unpack("<3i", raw[:12])
    assert dims == (90, 90, 180)
    n = dims[0] * dims[1] * dims[2]
    assert len(raw) == 12 + 3 * n * 8
    return np.frombuffer(raw, dtype="<f8", offset=12).reshape(3, n)


def cosine_directions(rng: np.random.Generator, n: int) -> np.ndarray:
    u1, u2 = rng.random(n), rng.random(n)
    r = np.sqrt(u1)
    return np.stack([r * np.cos(2 * np.pi * u2), r * np.sin(2 * np.pi * u2), np.sqrt(1 - u1)], axis=-1)


# ------------------------------------------------------------------ the grid

def test_cells_follow_merl_definition():
    rng = np.random.default_rng(4)
    l, v = cosine_directions(rng, 200_000), cosine_directions(rng, 200_000)
    ours = halfdiff.cell_indices(l, v)
    theirs = merl_index(l, v)
    # the two differ only within rounding of a cell boundary
    assert np.mean(ours == theirs) > 0.9999
    # reciprocity fold: exchanging l and v keeps the cell (except at boundaries)
    assert np.mean(halfdiff.cell_indices(v, l) == ours) > 0.9999
    assert np.all(halfdiff.cell_indices(l * [1, 1, -1], v) == -1)


def test_cell_measure_sums_to_pi2_and_matches_sampling():
    mu = halfdiff.cell_measure()
    assert mu.sum() == pytest.approx(math.pi ** 2, rel=1e-12)
    # pairs drawn with density cos(l) cos(v) / pi^2 fall in a cell with probability mu / pi^2
    rng = np.random.default_rng(5)
    n = 1_000_000
    cells = halfdiff.cell_indices(cosine_directions(rng, n), cosine_directions(rng, n))
    counts = np.bincount(cells, minlength=halfdiff.N_CELLS).reshape(halfdiff.SHAPE)
    for axes in ((1, 2), (0, 2), (0, 1)):
        expected = n * mu.sum(axis=axes) / math.pi ** 2
        z = (counts.sum(axis=axes) - expected) / np.sqrt(expected)
        assert np.sum(z * z) < chi2_limit(z.size)


# ------------------------------------------------------------------ closed form: Lambertian

def test_lambertian_base_tabulates_rho_over_pi():
    stack = g.stack_from_dict({"name": "lambert", "layers": [{"type": "lambertian", "albedo": RHO.tolist()}]})
    n = 1_000_000
    tab = tabulate(stack, g.TabulationSettings(rays=n, seed=2, threads=2))
    # every path is reflected once with weight rho
    np.testing.assert_allclose(tab.energy["reflected"], RHO, rtol=1e-12)
    assert tab.hits.sum() == n
    # value x measure summed over the grid: pi x reflected (the estimator's normalisation)
    np.testing.assert_allclose(np.einsum("cijk,ijk->c", tab.value, tab.measure), np.pi * RHO, rtol=1e-9)
    # rows of theta_h, theta_d and phi_d: the measure-weighted mean of the cells is rho / pi
    for axes in ((2, 3), (1, 3), (1, 2)):
        w = tab.measure.sum(axis=tuple(a - 1 for a in axes))
        mean = np.sum(tab.value * tab.measure, axis=axes) / w
        se = np.sqrt(np.sum((tab.stderr * tab.measure) ** 2, axis=axes)) / w
        keep = tab.hits.sum(axis=tuple(a - 1 for a in axes)) >= 50
        z = (mean - RHO[:, None] / np.pi)[:, keep] / se[:, keep]
        assert np.all(np.abs(z) < Z_TOL)
        assert np.sum(z[0] ** 2) < chi2_limit(int(keep.sum()))
    # the lookup returns the cell's value, rho / pi within its error where it has many paths
    l = np.array([0.3, 0.1, 0.9]) / np.linalg.norm([0.3, 0.1, 0.9])
    v = np.array([-0.4, 0.2, 0.7]) / np.linalg.norm([-0.4, 0.2, 0.7])
    c = np.unravel_index(halfdiff.cell_indices(l, v), halfdiff.SHAPE)
    np.testing.assert_array_equal(tab.eval(l, v), tab.value[(slice(None),) + c])
    assert np.all(tab.eval(l, v * [1, 1, -1]) == 0.0)


# ------------------------------------------------------------------ determinism, resuming

def _digest(tab) -> str:
    h = hashlib.sha256()
    for a in (tab.value, tab.stderr, tab.hits, *tab.energy.values()):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def test_same_bits_whatever_threads_and_after_resuming(tmp_path):
    stack = g.load_stack(EXAMPLES / "slab.toml")
    base = dict(rays=150_000, seed=9, chunk_rays=8192)
    one = tabulate(stack, g.TabulationSettings(threads=1, **base))
    two = tabulate(stack, g.TabulationSettings(threads=2, **base))
    assert _digest(one) == _digest(two)
    # a slab: its BRDF is tabulated, the transmitted light booked; the energy terms add up to 1
    np.testing.assert_allclose(energy_total(one), 1.0, atol=1e-9)
    assert np.all(one.energy["transmitted"] > 0.3)
    # interrupted after the first batch, then resumed from the checkpoint
    settings = g.TabulationSettings(threads=2, **base)
    cp = TabulationCheckpoint(tmp_path / "cp", tabulation_description(stack, settings))
    calls = []

    def stop(n):
        calls.append(n)
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        tabulate(stack, settings, checkpoint=cp, progress=stop)
    assert (tmp_path / "cp" / "state.npz").exists()
    resumed = []
    again = tabulate(stack, settings, checkpoint=cp, on_resume=resumed.append)
    assert resumed == [calls[0]]
    assert _digest(again) == _digest(one)


# ------------------------------------------------------------------ MERL export vs a classic slice

ROUGH_METAL = {"name": "rough-metal", "category": "metal", "layers": [
    {"type": "interface", "roughness": 0.25, "ior": 1.45, "extinction": [1.0, 0.5, 0.2]}]}


def test_merl_export_reads_back_and_matches_a_classic_slice(tmp_path):
    stack = g.stack_from_dict(ROUGH_METAL)
    n = 1_000_000
    tab = tabulate(stack, g.TabulationSettings(rays=n, seed=11))
    h5 = g.write_tabulated(tmp_path / "t.h5", tab)
    assert main(["export", str(h5), "--format", "merl", "--out", str(tmp_path / "t.binary")]) == 0
    stored = read_merl_binary(tmp_path / "t.binary")
    back = g.read_tabulated(h5)
    data = back.hits.reshape(-1) > 0
    assert np.all(stored[:, ~data] < 0)
    np.testing.assert_allclose(stored[:, data] * SCALE[:, None], back.value.reshape(3, -1)[:, data], rtol=1e-14)
    f_merl = np.where(stored < 0, 0.0, stored) * SCALE[:, None]
    se = back.stderr.reshape(3, -1)

    # the classic slice of the same material at theta_l = 30 deg (its own random streams)
    settings = g.SimulationSettings(incident_deg=(30.0,), rays=n, resolution=(9, 4), seed=12)
    assert_table_matches_slice(f_merl, se, g.simulate(stack, settings).brdf, 30.0)


def assert_table_matches_slice(f_table: np.ndarray, se_table: np.ndarray, sl, theta_deg: float) -> None:
    """A tabulated BRDF ((C, N_CELLS) values and standard errors) against a classic slice of the
    same material at ``theta_deg`` (C channels, its own random streams), in groups of 10 deg of
    theta_v by 90 deg of phi_v (a 9 x 4 slice): the table has ~1 path per cell, so its cells are
    aggregated over each group, weighted by the projected solid angle of the group's
    sub-directions that fall in them; per group within Z_TOL, chi-square per channel, and the
    directional albedo in total."""
    nt, nph = sl.value.shape[2:]
    light = g.light_direction(theta_deg)
    vs, ws = g.SliceGrid("classic", nt, nph).subcells(light, s=12)
    C = f_table.shape[0]
    z_all = []
    total = np.zeros((4, C))  # directional albedo: table, its variance, slice, its variance
    for i in range(nt):
        for j in range(nph):
            v = vs[i, j].reshape(-1, 3)
            w = ws[i, j].reshape(-1)
            a = np.bincount(merl_index(np.broadcast_to(light, v.shape).copy(), v), weights=w,
                            minlength=halfdiff.N_CELLS) / w.sum()
            used = np.flatnonzero(a)
            pred = f_table[:, used] @ a[used]
            pred_se = np.sqrt((se_table[:, used] ** 2) @ (a[used] ** 2))
            ref, ref_se, om = sl.value[0, :, i, j], sl.stderr[0, :, i, j], sl.proj_solid_angle[0, i, j]
            z_all.append((pred - ref) / np.hypot(pred_se, ref_se))
            total += np.array([pred * om, (pred_se * om) ** 2, ref * om, (ref_se * om) ** 2])
    z = np.array(z_all)
    assert np.all(np.abs(z) < Z_TOL)
    for c in range(C):
        assert np.sum(z[:, c] ** 2) < chi2_limit(len(z)), c
    z_total = (total[0] - total[2]) / np.sqrt(total[1] + total[3])
    assert np.all(np.abs(z_total) < Z_TOL)
    assert np.all(total[0] > 0.02)


# ------------------------------------------------------------------ command line

def test_cli_tabulate_export_and_refusals(tmp_path, capsys):
    out = tmp_path / "p.h5"
    assert main(["tabulate", str(EXAMPLES / "plastic.toml"), "--out", str(out), "--rays", "20000",
                 "--seed", "3", "--threads", "1"]) == 0
    tab = g.read_tabulated(out)
    assert tab.settings.rays == 20000 and tab.settings.seed == 3
    assert tab.stack.name == "plastic/P1-a0_0.05"
    assert not (tmp_path / ".p.h5.partial").exists()
    capsys.readouterr()
    assert main(["info", str(out), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["format"] == "goniometer.tabulated" and info["settings"]["rays"] == 20000
    np.testing.assert_allclose(info["energy"]["reflected"], tab.energy["reflected"])
    # xarray: named dimensions, cells without data as NaN
    pytest.importorskip("xarray")
    ds = g.open_dataset(out)
    assert dict(ds["value"].sizes) == {"channel": 3, "theta_h": 90, "theta_d": 90, "phi_d": 180}
    assert int(ds["value"].isnull().sum()) == 3 * int(np.sum(tab.hits == 0))
    assert dict(g.open_datatree(out)["energy"].dataset.sizes) == {"channel": 3}
    # anisotropic stacks are refused with the reason
    assert main(["tabulate", str(EXAMPLES / "aniso-metal.toml"), "--out", str(tmp_path / "a.h5")]) == 2
    err = capsys.readouterr().err
    assert "anisotropic" in err and "isotropic BRDFs only" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "a.h5").exists()
    # export needs a tabulated file, not a slices file
    assert main(["simulate", str(EXAMPLES / "plastic.toml"), "--out", str(tmp_path / "s.h5"), "--rays", "2000",
                 "--incident", "30", "--resolution", "9x18"]) == 0
    capsys.readouterr()
    assert main(["export", str(tmp_path / "s.h5"), "--format", "merl", "--out", str(tmp_path / "s.binary")]) == 2
    assert "gonio tabulate" in capsys.readouterr().err
    assert main(["tabulate", str(EXAMPLES / "plastic.toml"), "--out", str(out), "--rays", "0"]) == 2


# ------------------------------------------------------------------ Ctrl-C anywhere in tabulate

@pytest.fixture
def sigint_default():
    import signal
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def _interrupting(real):
    import os
    import signal

    def wrapper(*a, **k):
        if len(a) > 1 and getattr(a[1], "rays", None) == 8:  # the warm-up's 8 rays: not the run
            return real(*a, **k)
        os.kill(os.getpid(), signal.SIGINT)
        for _ in range(10_000):  # the handler runs at one of these bytecodes
            pass
        return real(*a, **k)
    return wrapper


@pytest.mark.parametrize("where", ["goniometer.run.results:TabulatedBRDF.from_sums",
                                   "goniometer.files.tabulated:write_tabulated", "h5py:File"])
def test_ctrl_c_at_the_end_of_tabulate_is_one_line_130_and_resumable(where, tmp_path, capsys, monkeypatch,
                                                                       sigint_default):
    """Interrupted after the last chunk (while the sums become values, while the file is written, or
    inside h5py where a finalizer may swallow the KeyboardInterrupt): exit 130, one line, no file;
    the rerun finds every ray in the checkpoint and writes the file an uninterrupted run writes."""
    import importlib
    cfg = EXAMPLES / "plastic.toml"
    ref = tmp_path / "ref.h5"
    argv = ["--rays", "20000", "--seed", "5", "--threads", "1"]
    assert main(["tabulate", str(cfg), "--out", str(ref), *argv]) == 0
    out = tmp_path / "p.h5"
    module, attr = where.split(":")
    owner = importlib.import_module(module)
    *path, name = attr.split(".")
    for a in path:
        owner = getattr(owner, a)
    monkeypatch.setattr(owner, name, _interrupting(getattr(owner, name)))
    capsys.readouterr()
    assert main(["tabulate", str(cfg), "--out", str(out), *argv]) == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == f"gonio: interrupted; nothing written to {out}"
    assert not any("Traceback" in line or "Exception ignored" in line for line in err)
    assert not out.exists() and (tmp_path / ".p.h5.partial" / "state.npz").exists()
    monkeypatch.undo()
    assert main(["tabulate", str(cfg), "--out", str(out), *argv]) == 0
    assert "resuming: 20,000 of 20,000 rays" in capsys.readouterr().err
    a, b = g.read_tabulated(out), g.read_tabulated(ref)
    assert np.array_equal(a.hits, b.hits) and np.array_equal(a.value, b.value) and np.array_equal(a.stderr, b.stderr)


# ------------------------------------------------------------------ a rerun with another setting

def test_cli_tabulate_refuses_another_setting_and_keeps_the_checkpoint(tmp_path, capsys, monkeypatch):
    """Issue 31 item 1 for tabulations: a rerun with another seed (or by another code version) is
    one line, exit 2, naming the key and both values; the checkpoint keeps its bytes; an unreadable
    state is refused too (it is all the run's progress); the original command resumes to the bits
    of an uninterrupted run; --restart discards the checkpoint."""
    import goniometer.run.checkpoints
    import goniometer.cli.common
    import goniometer.cli.tabulate
    from tests.conftest import refused
    from tests.goniometer.resume_helpers import assert_same_datasets, bytes_of, stop_after
    cfg = EXAMPLES / "plastic.toml"
    argv = ["--rays", "200000", "--seed", "5", "--threads", "1"]
    ref = tmp_path / "ref.h5"
    assert main(["tabulate", str(cfg), "--out", str(ref), *argv]) == 0
    out, partial = tmp_path / "p.h5", tmp_path / ".p.h5.partial"
    monkeypatch.setattr(goniometer.cli.tabulate, "ResumeAware", stop_after(0))   # Ctrl-C after the first batch
    capsys.readouterr()
    assert main(["tabulate", str(cfg), "--out", str(out), *argv]) == 130
    assert f"gonio: progress kept in {partial}; rerun the same command to resume" in capsys.readouterr().err
    monkeypatch.setattr(goniometer.cli.tabulate, "ResumeAware", goniometer.cli.common.ResumeAware)
    kept = bytes_of(partial)
    assert sorted(kept) == ["meta.json", "state.npz"]
    refused(capsys, ["tabulate", cfg, "--out", out, *argv, "--seed", "7"],
            f"{partial}: holds checkpoints of another run (seed: checkpoints 5, this run 7)",
            "rerun the command that wrote them to resume, or add --restart to discard them")
    monkeypatch.setattr(goniometer.run.checkpoints, "code_key", lambda: "another version")
    refused(capsys, ["tabulate", cfg, "--out", out, *argv], "written by another version of the simulator code",
            "add --restart to discard them")
    monkeypatch.setattr(goniometer.run.checkpoints, "code_key", goniometer.run.checkpoints.cache.simulator_key)
    assert bytes_of(partial) == kept and not out.exists()
    # the original command resumes (two chunks of 65,536 rays were kept) to the uninterrupted run's bits
    assert main(["tabulate", str(cfg), "--out", str(out), *argv]) == 0
    assert "resuming: 131,072 of 200,000 rays" in capsys.readouterr().err and not partial.exists()
    assert_same_datasets(out, ref)
    # an unreadable state is refused, not dropped; --restart discards it (and runs the changed setting)
    out2, partial2 = tmp_path / "q.h5", tmp_path / ".q.h5.partial"
    monkeypatch.setattr(goniometer.cli.tabulate, "ResumeAware", stop_after(0))
    assert main(["tabulate", str(cfg), "--out", str(out2), *argv]) == 130
    monkeypatch.setattr(goniometer.cli.tabulate, "ResumeAware", goniometer.cli.common.ResumeAware)
    (partial2 / "state.npz").write_bytes(b"damaged")
    refused(capsys, ["tabulate", cfg, "--out", out2, *argv],
            f"{partial2}: state.npz cannot be read (not an npz archive: truncated or damaged)",
            "add --restart to discard them and trace from the start")
    assert (partial2 / "state.npz").read_bytes() == b"damaged"
    assert main(["tabulate", str(cfg), "--out", str(out2), *argv, "--seed", "7", "--restart"]) == 0
    assert "resuming" not in capsys.readouterr().err and not partial2.exists()
    assert g.read_tabulated(out2).settings.seed == 7


def test_tabulation_checkpoint_is_compressed(tmp_path):
    """The state is saved with zip deflate (lossless: the resume tests check the bits)."""
    import zipfile
    stack = g.load_stack(EXAMPLES / "plastic.toml")
    settings = g.TabulationSettings(rays=20_000, seed=2, chunk_rays=8192, threads=1)
    cp = TabulationCheckpoint(tmp_path / "cp", tabulation_description(stack, settings))
    tabulate(stack, settings, checkpoint=cp)   # the last state is saved before the caller writes the file
    with zipfile.ZipFile(cp.state_path) as z:
        assert {i.compress_type for i in z.infolist()} == {zipfile.ZIP_DEFLATED}
    assert cp.load().next_chunk == 3
