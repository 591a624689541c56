"""goniometer.atomic: a file appears complete under its final name or not at all."""

from __future__ import annotations

import errno

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


def _full_disk_after(nbytes: int):
    """A numpy saver that writes ``nbytes`` and then fails as a full disk does (no file name: the
    error of a write on an open file)."""
    def save(fh, **arrays):
        fh.write(b"x" * nbytes)
        raise OSError(errno.ENOSPC, "No space left on device")
    return save


def test_a_full_disk_is_a_write_error_naming_the_final_path(tmp_path, monkeypatch):
    """ENOSPC inside a write: WriteError with the final name and the system's words; the old file
    and the directory are as they were (no temporary left)."""
    target = tmp_path / "m00.npz"
    target.write_bytes(b"old")
    monkeypatch.setattr(np, "savez_compressed", _full_disk_after(1000))
    with pytest.raises(atomic.WriteError) as e:
        atomic.write_npz_compressed(target, a=np.arange(3))
    assert (e.value.errno, e.value.strerror, e.value.filename) == (errno.ENOSPC, "No space left on device", str(target))
    assert atomic.is_environment_error(e.value) and isinstance(e.value.__cause__, OSError)
    assert target.read_bytes() == b"old" and [p.name for p in tmp_path.iterdir()] == ["m00.npz"]


def test_h5py_s_errors_take_the_system_s_words_and_other_errors_pass(tmp_path):
    """h5py reports a full disk as errno 28 with a long message of its own: the WriteError says
    'No space left on device'. An OSError that is not the file system's (a missing directory, a
    bug) is raised as it is."""
    with pytest.raises(atomic.WriteError) as e:
        with atomic.atomic_path(tmp_path / "r.h5") as tmp:
            tmp.write_bytes(b"half")
            raise OSError(errno.ENOSPC, "Can't synchronously write data (file write failed: errno = 28, ...)")
    assert e.value.strerror == "No space left on device" and e.value.filename == str(tmp_path / "r.h5")
    for error in (FileNotFoundError(errno.ENOENT, "No such file or directory", "x"), OSError("no errno")):
        with pytest.raises(type(error)) as e:
            with atomic.atomic_path(tmp_path / "r.h5"):
                raise error
        assert e.value is error and not atomic.is_environment_error(e.value)
    assert list(tmp_path.iterdir()) == []
