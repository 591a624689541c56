"""A failure of the environment (a full disk, a file size limit, a read-only file system) in any
``gonio`` command that writes: one line ``gonio: error: cannot write PATH: <the system's words>``
with what the command kept, exit status 1, the checkpoints intact and no temporary file left; an
OSError that is a bug keeps its traceback (issue 31 item 5, ``docs/outputs.md``)."""

from __future__ import annotations

import contextlib
import errno
import os
import re
import resource
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from goniometer import atomic
from goniometer.run.checkpoints import checkpoint_dir
from goniometer.cli import EXIT_ENVIRONMENT, main
from tests.conftest import PLASTIC_TOML
from tests.goniometer.resume_helpers import assert_same_datasets

EXAMPLES = Path(__file__).resolve().parents[2] / "configs" / "examples"
TINY = Path(__file__).resolve().parents[1] / "data" / "tiny_database.toml"
SMALL = PLASTIC_TOML + """[simulation]
incident_deg = [0, 30, 60]
rays = 2000
resolution = [9, 18]
"""


def _one_error_line(capsys) -> str:
    """stderr's lines starting with 'gonio:': exactly one, an error, and no traceback."""
    err = capsys.readouterr().err
    assert "Traceback" not in err and "During handling" not in err, err
    lines = [line for line in err.splitlines() if line.startswith("gonio:")]
    assert len(lines) == 1 and lines[0].startswith("gonio: error: "), lines
    return lines[0]


def _no_temporaries(root: Path) -> None:
    assert list(root.rglob(atomic.TEMP_GLOB)) == []


def _full_disk_on_call(k: int):
    """np.savez_compressed that fills the disk on its k-th call (counting from 1), after writing a
    little: what numpy's zip writer meets when the file system is full."""
    real = np.savez_compressed
    calls = []

    def save(fh, **arrays):
        calls.append(1)
        if len(calls) == k:
            fh.write(b"x" * 4096)
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(fh, **arrays)
    return save


@pytest.fixture
def config(tmp_path) -> Path:
    cfg = tmp_path / "p.toml"
    cfg.write_text(SMALL)
    return cfg


def test_simulate_full_disk_on_a_checkpoint(tmp_path, config, capsys, monkeypatch):
    out = tmp_path / "p.h5"
    partial = checkpoint_dir(out)
    monkeypatch.setattr(np, "savez_compressed", _full_disk_on_call(2))
    capsys.readouterr()
    assert main(["simulate", str(config), "--out", str(out), "--threads", "1"]) == EXIT_ENVIRONMENT == 1
    assert _one_error_line(capsys) == (f"gonio: error: cannot write {partial / 'm01.npz'}: No space left on device; "
                                       f"1 finished incident direction(s) kept in {partial}; rerun the same command "
                                       f"to resume")
    assert sorted(p.name for p in partial.iterdir()) == ["m00.npz", "meta.json"] and not out.exists()
    _no_temporaries(tmp_path)
    monkeypatch.undo()
    assert main(["simulate", str(config), "--out", str(out), "--threads", "1"]) == 0
    assert "resuming: 1 of 3 incident direction(s) already traced" in capsys.readouterr().err


def _full_disk_for(suffix: str, code: int = errno.ENOSPC):
    """atomic.atomic_path that fails as the file system does with ``code``, after a few bytes, for
    the files whose name ends with ``suffix`` (the others are written)."""
    real = atomic.atomic_path

    @contextlib.contextmanager
    def failing(path, commit=None):
        with real(path, commit) as tmp:
            if str(path).endswith(suffix):
                tmp.write_bytes(b"half")
                raise OSError(code, os.strerror(code))
            yield tmp
    return failing


def test_simulate_full_disk_on_the_final_file(tmp_path, config, capsys, monkeypatch):
    out = tmp_path / "p.h5"
    monkeypatch.setattr(atomic, "atomic_path", _full_disk_for(".h5"))
    capsys.readouterr()
    assert main(["simulate", str(config), "--out", str(out), "--threads", "1"]) == 1
    assert _one_error_line(capsys) == (f"gonio: error: cannot write {out}: No space left on device; 3 finished "
                                       f"incident direction(s) kept in {checkpoint_dir(out)}; rerun the same "
                                       f"command to resume")
    assert not out.exists() and len(list(checkpoint_dir(out).glob("m*.npz"))) == 3
    _no_temporaries(tmp_path)


def test_an_oserror_that_is_a_bug_keeps_its_traceback(tmp_path, config, monkeypatch):
    import goniometer.files.slices
    for error in (FileNotFoundError(errno.ENOENT, "No such file or directory", "somewhere"), OSError("a bug")):
        def broken(*args, **kwargs):
            raise error
        monkeypatch.setattr(goniometer.files.slices, "write", broken)
        with pytest.raises(type(error)) as e:
            main(["simulate", str(config), "--out", str(tmp_path / "p.h5"), "--threads", "1"])
        assert e.value is error


def test_tabulate_full_disk_says_the_progress_is_kept(tmp_path, capsys, monkeypatch):
    out = tmp_path / "t.h5"
    monkeypatch.setattr(atomic, "atomic_path", _full_disk_for(".h5", errno.EDQUOT))
    capsys.readouterr()
    assert main(["tabulate", str(EXAMPLES / "plastic.toml"), "--out", str(out), "--rays", "20000", "--threads",
                 "1"]) == 1
    partial = tmp_path / ".t.h5.partial"
    assert _one_error_line(capsys) == (f"gonio: error: cannot write {out}: Disk quota exceeded; progress kept in "
                                       f"{partial}; rerun the same command to resume")
    assert (partial / "state.npz").exists() and not out.exists()
    _no_temporaries(tmp_path)


def test_database_full_disk_says_what_is_kept(tmp_path, capsys, monkeypatch):
    from goniometer.database import load_database
    db = load_database(TINY)
    first, second = db.select("plastic/*")
    work = tmp_path / "db"
    monkeypatch.setattr(np, "savez_compressed", _full_disk_on_call(4))   # the second material's second direction
    capsys.readouterr()
    assert main(["database", "simulate", str(TINY), "--out", str(work), "--only", "plastic/*", "--threads",
                 "2"]) == 1
    partial = work / ".partial"
    assert _one_error_line(capsys) == (
        f"gonio: error: cannot write {partial / second.name / 'm01.npz'}: No space left on device; 1 of 2 "
        f"material(s) finished in {work} (1 by this run), checkpoints of 1 unfinished material(s) kept in {partial} "
        f"({second.name}: 1 of 2 incident direction(s)); rerun the same command to resume")
    _no_temporaries(tmp_path)


def test_a_models_command_full_disk_is_the_same_line(tmp_path, config, capsys, monkeypatch):
    """The models' commands run under the same host: a figure that cannot be written is the same
    one line and exit status."""
    pytest.importorskip("models")
    data = tmp_path / "p.h5"
    assert main(["simulate", str(config), "--out", str(data), "--threads", "1"]) == 0
    real = atomic.write_bytes

    def full(path, payload):
        if Path(path).suffix != ".png":
            return real(path, payload)
        with atomic.atomic_path(path) as tmp:
            tmp.write_bytes(payload[:100])
            raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(atomic, "write_bytes", full)
    figures = tmp_path / "fig"
    capsys.readouterr()
    assert main(["plot", str(data), "--out", str(figures)]) == 1
    line = _one_error_line(capsys)
    assert re.fullmatch(f"gonio: error: cannot write {re.escape(str(figures))}/[a-z0-9_]+\\.png: No space left on "
                        f"device", line), line
    _no_temporaries(tmp_path)


def _file_size_limit(nbytes: int):
    def limit() -> None:   # in the child: writes past nbytes fail with EFBIG instead of a signal
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        resource.setrlimit(resource.RLIMIT_FSIZE, (nbytes, nbytes))
    return limit


def test_a_real_file_size_limit_is_one_line_and_the_run_resumes(tmp_path, config, capsys):
    """A real failure of the operating system (a file size limit: EFBIG from write(2)) while h5py
    writes the slices file: one line, exit 1, the checkpoints (smaller than the limit) intact; the
    rerun without the limit resumes them to the bits of an uninterrupted run."""
    ref = tmp_path / "ref.h5"
    assert main(["simulate", str(config), "--out", str(ref), "--threads", "1"]) == 0   # kernels in the cache
    assert ref.stat().st_size > 60_000
    out = tmp_path / "p.h5"
    proc = subprocess.run([sys.executable, "-m", "goniometer.cli", "simulate", str(config), "--out", str(out),
                           "--threads", "1"], capture_output=True, text=True, timeout=300,
                          preexec_fn=_file_size_limit(40_000))
    assert proc.returncode == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines()[-1] == (
        f"gonio: error: cannot write {out}: File too large; 3 finished incident direction(s) kept in "
        f"{checkpoint_dir(out)}; rerun the same command to resume")
    assert not out.exists()
    _no_temporaries(tmp_path)
    capsys.readouterr()
    assert main(["simulate", str(config), "--out", str(out), "--threads", "1"]) == 0
    assert "resuming: 3 of 3" in capsys.readouterr().err
    assert_same_datasets(out, ref)
