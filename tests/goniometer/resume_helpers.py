"""Helpers of the tests of interrupted, resumed and refused runs (simulate, tabulate, database)."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np


class StopAfter:
    """Stands for ``ResumeAware`` in a command module (monkeypatched): the bar moves as usual, and
    once more than :attr:`limit` rays (paths) are reported done a KeyboardInterrupt is raised, as
    the command's latch does on Ctrl-C. Subclass it with a limit: :func:`stop_after`."""

    limit = 0

    def __init__(self, bar, check=None) -> None:
        self.bar, self.done = bar, 0

    def resumed(self, n: int) -> None:
        pass

    def __call__(self, n: int) -> None:
        self.done += n
        self.bar.update(n)
        if self.done > self.limit:
            raise KeyboardInterrupt


def stop_after(limit: int) -> type[StopAfter]:
    """A :class:`StopAfter` that interrupts once more than ``limit`` rays are done."""
    return type("Stop", (StopAfter,), {"limit": limit})


def bytes_of(directory: Path) -> dict[str, bytes]:
    """Every file under ``directory`` (relative path -> bytes)."""
    return {str(p.relative_to(directory)): p.read_bytes() for p in sorted(Path(directory).rglob("*")) if p.is_file()}


def assert_same_datasets(a: Path, b: Path) -> None:
    """Two HDF5 files hold the same datasets with the same bits (timings aside: ``elapsed``)."""
    def datasets(path: Path) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {}
        with h5py.File(path, "r") as f:
            f.visititems(lambda name, obj: out.__setitem__(name, obj[()]) if isinstance(obj, h5py.Dataset) else None)
        return {k: v for k, v in out.items() if "elapsed" not in k}
    x, y = datasets(a), datasets(b)
    assert x.keys() == y.keys()
    for k in x:
        assert np.asarray(x[k]).tobytes() == np.asarray(y[k]).tobytes(), k
