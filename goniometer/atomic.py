"""Atomic file writes: a file appears under its final name complete or not at all.

Everything the project writes to a user's disk (HDF5 results, checkpoints, manifests, reports,
cached tables) goes through :func:`atomic_path`: the content is written to a temporary file in the
same directory (``.<name>.tmp-<pid>-<random>``, see :data:`TEMP_GLOB`), then renamed over the
final name, which is atomic on POSIX file systems. On any exception (KeyboardInterrupt included)
the temporary file is removed and the final name is left untouched.
"""

from __future__ import annotations

import contextlib
import os
import uuid
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

#: glob pattern of the temporary files (none should survive a write, finished or failed)
TEMP_GLOB = ".*.tmp-*"


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, commit: Callable[[], None] | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it to ``path`` if the block succeeds.

    ``commit``, if given, is called between the block and the rename: an exception it raises
    (a Ctrl-C recorded while the file was written, say) removes the temporary file and leaves
    ``path`` as it was."""
    p = Path(path)
    tmp = p.with_name(f".{p.name}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}")
    try:
        yield tmp
        if commit is not None:
            commit()
        os.replace(tmp, p)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        raise


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically, creating the parent directories."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(p) as tmp:
        tmp.write_bytes(data)


def write_npz(path: str | os.PathLike, **arrays) -> None:
    """``np.savez`` of ``arrays`` to exactly ``path`` (no ``.npz`` appended), atomically, creating
    the parent directories."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(p) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
