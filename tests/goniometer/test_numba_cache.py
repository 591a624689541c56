"""goniometer.cache: source-keyed cache directories and pruning of old ones."""

from __future__ import annotations

import os
import time

from goniometer import cache as _numba_cache


def _key_dir(base, i: int, age_s: float):
    d = base / f"{i:016x}"
    d.mkdir(parents=True)
    (d / "kernel.nbi").write_bytes(b"x")
    t = time.time() - age_s
    os.utime(d / "kernel.nbi", (t, t))
    os.utime(d, (t, t))
    return d


def test_prune_keeps_the_recent_and_removes_old_unused(tmp_path):
    base = tmp_path / "numba"
    day = 86400.0
    old = [_key_dir(base, i, (10 + i) * day) for i in range(12)]        # unused for 10..21 days
    fresh = [_key_dir(base, 100 + i, 3600.0) for i in range(3)]        # used an hour ago
    other = base / "not-a-key"
    other.mkdir()
    current = base / ("f" * 16)
    removed = _numba_cache.prune(base, current, keep=8, stale_s=day)
    left = {d.name for d in base.iterdir()}
    # current + 7 most recent siblings kept: the 3 fresh ones and the 4 youngest old ones
    assert current.name in left and other.name in left
    assert {d.name for d in fresh} <= left
    assert {d.name for d in old[:4]} <= left
    assert set(removed) == set(old[4:]) and not any(d.name in left for d in old[4:])
    assert (current / ".last-used").exists()


def test_prune_never_removes_recently_used_directories(tmp_path):
    base = tmp_path / "numba"
    recent = [_key_dir(base, i, 60.0) for i in range(20)]
    assert _numba_cache.prune(base, base / ("e" * 16), keep=2, stale_s=86400.0) == []
    assert all(d.exists() for d in recent)


def test_configure_uses_a_source_keyed_directory(tmp_path, monkeypatch):
    monkeypatch.setenv("GONIOMETER_CACHE", str(tmp_path))
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    import numba
    before = numba.config.CACHE_DIR
    try:
        path = _numba_cache.configure()
        assert path == str(tmp_path / "numba" / _numba_cache.simulator_key())
        assert (tmp_path / "numba" / _numba_cache.simulator_key() / ".last-used").exists()
    finally:
        numba.config.CACHE_DIR = before
