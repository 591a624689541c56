"""goniometer.atomic: a file appears complete under its final name or not at all."""

from __future__ import annotations

import numpy as np
import pytest

from goniometer import atomic


def test_write_bytes_creates_parents_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "a" / "b" / "x.json"
    atomic.write_bytes(target, b"{}")
    assert target.read_bytes() == b"{}"
    atomic.write_bytes(target, b"[1]")  # replaces
    assert target.read_bytes() == b"[1]"
    assert list(target.parent.glob(atomic.TEMP_GLOB)) == []


def test_failed_write_keeps_the_old_file_and_removes_the_temporary(tmp_path):
    target = tmp_path / "x.bin"
    target.write_bytes(b"old")
    with pytest.raises(RuntimeError):
        with atomic.atomic_path(target) as tmp:
            tmp.write_bytes(b"half")
            assert list(tmp_path.glob(atomic.TEMP_GLOB)) == [tmp]  # the pattern matches what is written
            raise RuntimeError("interrupted")
    assert target.read_bytes() == b"old"
    assert list(tmp_path.glob(atomic.TEMP_GLOB)) == []


def test_write_npz_keeps_the_exact_name(tmp_path):
    target = tmp_path / "part.chk"
    atomic.write_npz(target, a=np.arange(3))
    assert [p.name for p in tmp_path.iterdir()] == ["part.chk"]
    with np.load(target) as z:
        np.testing.assert_array_equal(z["a"], np.arange(3))


def test_temporaries_of_concurrent_writers_differ(tmp_path):
    with atomic.atomic_path(tmp_path / "x") as a, atomic.atomic_path(tmp_path / "x") as b:
        assert a != b
        a.write_bytes(b"a")
        b.write_bytes(b"b")
    assert (tmp_path / "x").read_bytes() in (b"a", b"b")
