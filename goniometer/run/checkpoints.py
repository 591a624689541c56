"""Checkpoints of a simulation: its finished incident directions, kept until its file is written.

A run (one stack, one :class:`~goniometer.run.settings.SimulationSettings`) traces its incident
directions one after the other (:func:`goniometer.run.loop.run_incidents`). Each finished
direction's raw sums (an :class:`~goniometer.run.results.IncidentPart`) are saved atomically and
compressed (zip deflate, lossless) as ``m<k>.npz`` in a checkpoint directory, beside ``meta.json``
describing the run; a rerun of the same run loads them instead of tracing again, and the directory
is removed once the result is written. Because results are bit-identical whatever the thread count
and however a run is split, a resumed run gives exactly the file an uninterrupted one would.

``meta.json`` holds the caller's description of the run
(:func:`goniometer.run.results.run_description`) plus :func:`code_key` (a hash of the simulator's
sources). Kept checkpoints are never discarded behind the user's back (``docs/outputs.md``, rule
3): a run whose description or code key differs from theirs raises :class:`CheckpointMismatch`,
naming every differing key with both values, and changes nothing; only :meth:`Checkpoints.clear`
(``--restart``) discards them. A single checkpoint file that cannot be read (a disk error, a file
damaged outside the project: writes are atomic) is reported through ``on_discard`` and its
direction traced again; the others are kept.
"""

from __future__ import annotations

import json
import shutil
import warnings
import zipfile
from pathlib import Path
from typing import Any, Callable

from goniometer import atomic, cache
from goniometer.run.results import IncidentPart

__all__ = ["CheckpointMismatch", "CheckpointWarning", "Checkpoints", "checkpoint_dir", "code_key", "differences",
           "check_meta", "unreadable_reason", "write_meta"]

META = "meta.json"
#: how a key absent from a run description is shown: descriptions leave out keys at their defaults
#: (:func:`goniometer.run.results.run_description`, ``docs/file-identity.md``)
ABSENT = "(default)"
#: the differences a :class:`CheckpointMismatch` message lists before "and N more"
SHOWN_DIFFERENCES = 6
#: what an unreadable checkpoint file raises when it is loaded
UNREADABLE = (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile)


def code_key() -> str:
    """Identifies the physics code that wrote a checkpoint: :func:`goniometer.cache.simulator_key`."""
    return cache.simulator_key()


class CheckpointMismatch(ValueError):
    """Kept checkpoints that this run cannot use; nothing was changed.

    ``directory``: where they are. ``differences``: (key, the checkpoints' value, this run's value)
    for every key of the run description that differs (a key like ``rays`` or
    ``stack.layers[1].roughness``; ``code`` when another version of the simulator wrote them).
    ``reason``: set instead when their description cannot be read, or (a tabulation) their one
    state file. ``others``: further directories of the same run with the same problem (a database's
    materials)."""

    def __init__(self, directory: str | Path, differences: list[tuple[str, Any, Any]] | None = None,
                 reason: str | None = None, others: int = 0) -> None:
        self.directory = Path(directory)
        self.differences = list(differences or [])
        self.reason = reason
        self.others = others
        super().__init__(self._message())

    @property
    def other_code(self) -> bool:
        """True if another version of the simulator code wrote the checkpoints."""
        return any(k == "code" for k, _, _ in self.differences)

    @property
    def other_run(self) -> bool:
        """True if the checkpoints are of another run (settings, stack, database...)."""
        return any(k != "code" for k, _, _ in self.differences)

    def _message(self) -> str:
        more = f" (and the checkpoints of {self.others} more material(s))" if self.others else ""
        if self.reason is not None:
            return f"{self.directory}: {self.reason}{more}"
        shown = [f"{k}: checkpoints {_show(a)}, this run {_show(b)}" for k, a, b in self.differences]
        if len(shown) > SHOWN_DIFFERENCES:
            shown = shown[:SHOWN_DIFFERENCES] + [f"and {len(shown) - SHOWN_DIFFERENCES} more"]
        what = " and ".join(w for w, on in (("of another run", self.other_run),
                                            ("written by another version of the simulator code", self.other_code))
                            if on)
        return f"{self.directory}: holds checkpoints {what}{more} ({'; '.join(shown)})"


class CheckpointWarning(UserWarning):
    """A checkpoint file that could not be read: its work is done again (the default ``on_discard``)."""


def _show(value: Any) -> str:
    text = value if isinstance(value, str) else json.dumps(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _display(key: str) -> str:
    """A description's key as the user knows it: ``rays``, not ``settings.rays`` (nor, in a
    database, ``run.settings.rays``)."""
    for prefix in ("run.settings.", "settings.", "run."):
        if key.startswith(prefix):
            return key[len(prefix):]
    return key


def differences(kept: Any, wanted: Any, key: str = "") -> list[tuple[str, Any, Any]]:
    """(key, kept value, wanted value) of every leaf where two run descriptions (JSON data) differ;
    keys are dotted (``settings.rays``, ``stack.layers[1].roughness``) and shown without their
    ``settings.`` or ``run.`` prefix; a key one side lacks has the value :data:`ABSENT`."""
    if isinstance(kept, dict) and isinstance(wanted, dict):
        out = []
        for k in list(wanted) + [k for k in kept if k not in wanted]:
            sub = f"{key}.{k}" if key else str(k)
            if k not in kept or k not in wanted:
                out.append((_display(sub), kept.get(k, ABSENT), wanted.get(k, ABSENT)))
            else:
                out.extend(differences(kept[k], wanted[k], sub))
        return out
    if isinstance(kept, list) and isinstance(wanted, list) and len(kept) == len(wanted) \
            and any(isinstance(x, (dict, list)) for x in kept + wanted):
        return [d for i, (a, b) in enumerate(zip(kept, wanted)) for d in differences(a, b, f"{key}[{i}]")]
    return [] if kept == wanted else [(_display(key), kept, wanted)]


def check_meta(directory: Path, meta: dict[str, Any], kept: list[Path]) -> None:
    """Raise :class:`CheckpointMismatch` if ``directory`` holds checkpoint files (``kept``) that
    ``meta`` (a run description with its code key) cannot use: their ``meta.json`` differs from it
    or cannot be read. Nothing is changed."""
    if not kept:
        return
    try:
        have = json.loads((directory / META).read_text())
    except FileNotFoundError:
        raise CheckpointMismatch(directory, reason=f"holds {len(kept)} checkpoint file(s) but no {META} saying "
                                                   f"which run they are of") from None
    except (OSError, ValueError) as e:
        raise CheckpointMismatch(directory, reason=f"{META} cannot be read ({e}); it says which run the "
                                                   f"{len(kept)} checkpoint file(s) are of") from None
    found = differences(have, json.loads(json.dumps(meta)))
    if found:
        raise CheckpointMismatch(directory, found)


def unreadable_reason(path: Path, e: BaseException) -> str:
    """Why a checkpoint file could not be read, in a few words."""
    try:
        if not zipfile.is_zipfile(path):
            return "not an npz archive: truncated or damaged"
    except OSError:
        pass
    return f"{type(e).__name__}: {e}"


def _warn(path: Path, reason: str) -> None:
    warnings.warn(f"{path}: unreadable checkpoint ({reason}); its work is done again", CheckpointWarning,
                  stacklevel=3)


class Checkpoints:
    """The checkpoint directory of one run (created on the first :meth:`save`).

    ``on_discard(path, reason)`` is told of an unreadable checkpoint file before it is deleted and
    its direction traced again (default: a :class:`CheckpointWarning`)."""

    def __init__(self, directory: str | Path, meta: dict[str, Any],
                 on_discard: Callable[[Path, str], None] | None = None) -> None:
        self.directory = Path(directory)
        self.meta = dict(meta, code=code_key())
        self.on_discard = on_discard if on_discard is not None else _warn

    def _path(self, k: int) -> Path:
        return self.directory / f"m{k:02d}.npz"

    def kept(self) -> list[Path]:
        """The checkpoint files in the directory (finished directions, readable or not)."""
        return sorted(self.directory.glob("m*.npz")) if self.directory.is_dir() else []

    def check(self) -> None:
        """Raise :class:`CheckpointMismatch` if the directory holds checkpoints of another run or
        code version (or whose ``meta.json`` cannot be read); changes nothing."""
        check_meta(self.directory, self.meta, self.kept())

    def load(self, n_incident: int) -> dict[int, IncidentPart]:
        """The finished directions of this run (index -> part). Checkpoints this run cannot use
        raise :class:`CheckpointMismatch`; an unreadable file is reported (``on_discard``) and
        deleted, and its direction is traced again."""
        self.check()
        parts: dict[int, IncidentPart] = {}
        for k in range(n_incident):
            p = self._path(k)
            if not p.exists():
                continue
            try:
                part = IncidentPart.load(p)
                if part.index != k:
                    raise ValueError(f"holds incident direction {part.index}")
                parts[k] = part
            except UNREADABLE as e:
                self.on_discard(p, unreadable_reason(p, e))
                p.unlink(missing_ok=True)
        return parts

    def save(self, k: int, part: IncidentPart) -> None:
        """Keep a finished direction (atomically, compressed). The first save writes ``meta.json``;
        a directory holding checkpoints of another run raises :class:`CheckpointMismatch`."""
        write_meta(self.directory, self.meta, self.kept())
        part.save(self._path(k))

    def clear(self) -> None:
        """Discard the checkpoints (``--restart``; after the result is written)."""
        shutil.rmtree(self.directory, ignore_errors=True)


def write_meta(directory: Path, meta: dict[str, Any], kept: list[Path]) -> None:
    """Before a checkpoint file is written: ``meta.json`` describes ``meta``'s run (written if the
    directory holds no checkpoint file yet; else it must already: :func:`check_meta`)."""
    check_meta(directory, meta, kept)
    if kept:
        return
    try:
        if json.loads((directory / META).read_text()) == json.loads(json.dumps(meta)):
            return
    except (OSError, ValueError):
        pass
    atomic.write_bytes(directory / META, json.dumps(meta, indent=1).encode())


def checkpoint_dir(out: str | Path) -> Path:
    """Where ``gonio simulate --out OUT`` keeps its checkpoints: ``.OUT.partial`` beside ``OUT``."""
    p = Path(out)
    return p.with_name(f".{p.name}.partial")
