"""Atomic file writes: a file appears under its final name complete or not at all.

Everything the project writes to a user's disk (HDF5 results, checkpoints, manifests, reports,
cached tables) goes through :func:`atomic_path` (HDF5 files through :func:`hdf5_file`, which builds
them in memory first): the content is written to a temporary file in the
same directory (``.<name>.tmp-<pid>-<random>``, see :data:`TEMP_GLOB`), then renamed over the
final name, which is atomic on POSIX file systems. On any exception (KeyboardInterrupt included)
the temporary file is removed and the final name is left untouched.

A write that fails for a reason of the file system (a full disk, a quota, a read-only mount:
:data:`ENVIRONMENT_ERRNOS`) raises :class:`WriteError`, an :class:`OSError` that names the final
path and says the error in the system's words (``No space left on device``), whatever the writer
(numpy's zip writer, h5py) made of it; ``gonio`` prints it as one line and exits with status 1
(``docs/outputs.md``, "When the disk is full").
"""

from __future__ import annotations

import contextlib
import errno
import io
import os
import uuid
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterator

import numpy as np

if TYPE_CHECKING:
    import h5py

#: glob pattern of the temporary files (none should survive a write, finished or failed)
TEMP_GLOB = ".*.tmp-*"

#: the errors of the environment, not of the program: the file system is full, over quota, read-only,
#: failing, forbids the file, or the process has too many files open. An OSError with one of these
#: numbers and a file name is what ``gonio`` reports as one line (exit status 1); any other OSError
#: is a bug and keeps its traceback.
ENVIRONMENT_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EACCES, errno.EPERM,
                                errno.EIO, errno.EMFILE, errno.ENFILE})


class WriteError(OSError):
    """A write of :func:`atomic_path` that failed for a reason of the file system
    (:data:`ENVIRONMENT_ERRNOS`): ``filename`` is the final path, ``strerror`` the system's words."""


def is_environment_error(e: BaseException) -> bool:
    """True for an OSError of the file system (:data:`ENVIRONMENT_ERRNOS`) that names its file."""
    return isinstance(e, OSError) and e.errno in ENVIRONMENT_ERRNOS and e.filename is not None


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, commit: Callable[[], None] | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it to ``path`` if the block succeeds.

    ``commit``, if given, is called between the block and the rename: an exception it raises
    (a Ctrl-C recorded while the file was written, say) removes the temporary file and leaves
    ``path`` as it was. An OSError of the file system (:data:`ENVIRONMENT_ERRNOS`) is raised again
    as a :class:`WriteError` naming ``path``."""
    p = Path(path)
    tmp = p.with_name(f".{p.name}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}")
    try:
        yield tmp
        if commit is not None:
            commit()
        os.replace(tmp, p)
    except BaseException as e:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        if isinstance(e, OSError) and not isinstance(e, WriteError) and e.errno in ENVIRONMENT_ERRNOS:
            raise WriteError(e.errno, os.strerror(e.errno), str(p)) from e
        raise


@contextlib.contextmanager
def hdf5_file(path: str | os.PathLike, commit: Callable[[], None] | None = None) -> Iterator["h5py.File"]:
    """Yield a new HDF5 file that appears at ``path`` when the block ends (``commit`` as in
    :func:`atomic_path`). The file is built in memory and written out in one go: the HDF5 library
    never writes to the disk itself, because when a write of its own fails (a full disk) it cannot
    close the file, reports errors of objects it cannot free, and may crash the process at exit.
    The memory is the file's size (a spectral tabulation's 94 MB, ``docs/tabulated-format.md``)."""
    import h5py
    buffer = io.BytesIO()
    with h5py.File(buffer, "w") as f:
        yield f
    with atomic_path(path, commit) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(buffer.getbuffer())


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically, creating the parent directories."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(p) as tmp:
        tmp.write_bytes(data)


def write_npz(path: str | os.PathLike, **arrays) -> None:
    """``np.savez`` of ``arrays`` to exactly ``path`` (no ``.npz`` appended), atomically, creating
    the parent directories."""
    _write_npz(path, np.savez, arrays)


def write_npz_compressed(path: str | os.PathLike, **arrays) -> None:
    """:func:`write_npz` with ``np.savez_compressed`` (zip deflate: lossless, the arrays read back
    bit for bit)."""
    _write_npz(path, np.savez_compressed, arrays)


def _write_npz(path: str | os.PathLike, save: Callable[..., None], arrays: dict) -> None:
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(p) as tmp:
        with open(tmp, "wb") as fh:
            save(fh, **arrays)
