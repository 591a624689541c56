"""Checkpoints of a simulation: its finished incident directions, kept until its file is written.

A run (one stack, one :class:`~goniometer.settings.SimulationSettings`) traces its incident
directions one after the other (:func:`goniometer.run.run_incidents`). Each finished
direction's raw sums (an :class:`~goniometer.results.IncidentPart`) are saved atomically as ``m<k>.npz`` in a checkpoint
directory, beside ``meta.json`` describing the run; a rerun of the same run loads them instead of
tracing again, and the directory is removed once the result is written. Because results are
bit-identical whatever the thread count and however a run is split, a resumed run gives exactly
the file an uninterrupted one would.

``meta.json`` holds the caller's description of the run
(:func:`goniometer.results.run_description`) plus :func:`code_key` (a hash of the simulator's
numba sources): checkpoints of another run, or written by other physics code, are
discarded, never mixed in. Unreadable checkpoint files are discarded too.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

from goniometer import atomic, cache
from goniometer.results import IncidentPart

META = "meta.json"


def code_key() -> str:
    """Identifies the physics code that wrote a checkpoint: :func:`goniometer.cache.simulator_key`."""
    return cache.simulator_key()


class Checkpoints:
    """The checkpoint directory of one run (created on the first :meth:`save`)."""

    def __init__(self, directory: str | Path, meta: dict[str, Any]) -> None:
        self.directory = Path(directory)
        self.meta = dict(meta, code=code_key())

    def _path(self, k: int) -> Path:
        return self.directory / f"m{k:02d}.npz"

    def _current(self) -> bool:
        try:
            return json.loads((self.directory / META).read_text()) == self.meta
        except (OSError, ValueError):
            return False

    def load(self, n_incident: int) -> dict[int, IncidentPart]:
        """The finished directions of this run (index -> part); checkpoints of another run or code
        version and unreadable files are deleted."""
        if not self.directory.is_dir():
            return {}
        if not self._current():
            self.clear()
            return {}
        parts: dict[int, IncidentPart] = {}
        for k in range(n_incident):
            p = self._path(k)
            if not p.exists():
                continue
            try:
                part = IncidentPart.load(p)
                if part.index != k:
                    raise ValueError(f"{p}: holds incident direction {part.index}")
                parts[k] = part
            except (OSError, ValueError, KeyError):
                p.unlink(missing_ok=True)
        return parts

    def save(self, k: int, part: IncidentPart) -> None:
        """Keep a finished direction (atomically)."""
        if not self._current():
            self.clear()
            self.directory.mkdir(parents=True, exist_ok=True)
            atomic.write_bytes(self.directory / META, json.dumps(self.meta, indent=1).encode())
        part.save(self._path(k))

    def clear(self) -> None:
        shutil.rmtree(self.directory, ignore_errors=True)


def checkpoint_dir(out: str | Path) -> Path:
    """Where ``gonio simulate --out OUT`` keeps its checkpoints: ``.OUT.partial`` beside ``OUT``."""
    p = Path(out)
    return p.with_name(f".{p.name}.partial")
