"""The report's files: atomic text and JSON writes, reading a JSON file that may be absent or
damaged, safe names for a material's directories, and the datasets of its HDF5 caches, each distinct
array once (:class:`OnceWriter`; the layout is in ``docs/report.md``)."""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from goniometer import atomic

if TYPE_CHECKING:
    import h5py


def write_text(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically, creating the parent directories."""
    atomic.write_bytes(path, text.encode("utf-8"))


def write_json(path: Path, obj: Any, *, indent: int = 1) -> None:
    """Write ``obj`` as JSON (``indent``, no NaN) to ``path`` atomically: every JSON file of
    ``models.report`` is written here."""
    write_text(Path(path), json.dumps(obj, indent=indent, allow_nan=False) + "\n")


def read_json(path: Path) -> dict | None:
    """The JSON object in ``path``, or None if the file is missing, unreadable or not an object."""
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    return doc if isinstance(doc, dict) else None


def safe_part(s: str) -> str:
    """``s`` usable as one file-name component: characters other than ``A-Za-z0-9._-`` become ``_``."""
    return re.sub(r"[^A-Za-z0-9._-]", "_", s) or "_"


def material_dir(name: str) -> Path:
    """Relative directory of a material's figures and cache entry (``plastic/P1-a0_0.05``)."""
    parts = [safe_part(p) for p in name.split("/") if p not in ("", ".", "..")]
    return Path(*parts) if parts else Path("_")


#: the filters of the report's HDF5 caches (lossless: gzip, with the shuffle filter)
H5_FILTERS = {"compression": "gzip", "compression_opts": 6, "shuffle": True}


class OnceWriter:
    """Writes the datasets of an HDF5 file storing each distinct array once: an array equal to one
    already written (same dtype, shape and bytes: e.g. the top lobe several models share) becomes a
    hard link to it, which readers see as an ordinary dataset. Arrays with a leading incident axis
    are chunked one incident direction per chunk, every array compressed by :data:`H5_FILTERS`."""

    def __init__(self, f: "h5py.Group") -> None:
        self.f = f
        self.written: dict[tuple, str] = {}

    def put(self, path: str, data: np.ndarray, per_incident: bool = True) -> None:
        data = np.ascontiguousarray(data)
        key = (data.dtype.str, data.shape, hashlib.sha256(data.tobytes()).digest())
        if key in self.written:
            self.f[path] = self.f[self.written[key]]
            return
        chunks = (1,) + data.shape[1:] if per_incident and data.ndim > 1 and data.shape[0] > 0 else True
        self.f.create_dataset(path, data=data, chunks=chunks, **H5_FILTERS)
        self.written[key] = self.f[path].name
