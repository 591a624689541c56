"""The overwrite policy of every command that writes (``docs/outputs.md``).

Two rules, checked before any work starts:

1. A command never writes onto one of its own inputs: an output path that is an input (the same
   file or directory, through any spelling or link) is refused, naming both.
2. An existing finished output is never replaced unless the caller says ``overwrite``. The refusal
   says what the existing output holds (format, material, rays, date) so that the user can judge
   what ``--overwrite`` would lose. A directory output counts as finished when it holds its
   command's completion marker (a report's ``index.html``, say); a directory without it is work in
   progress that the command resumes.

Writes themselves stay atomic (:mod:`goniometer.atomic`), so a refused or interrupted command leaves
every file as it was. Library functions that write (``goniometer.write`` and the like) replace what
is at their path: the policy is the commands' contract with a user's disk, and a script that calls
the library decides for itself.
"""

from __future__ import annotations

import datetime as _dt
import os
from pathlib import Path
from typing import Iterable

__all__ = ["OutputError", "check_output", "describe_existing", "same_path"]

#: the first bytes of the tensor files of the RGL material database (Dupuy & Jakob 2018)
TENSOR_MAGIC = b"tensor_file\0"
_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
_HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"


class OutputError(ValueError):
    """An output the policy refuses; the message names the path, the reason and the way out."""


def same_path(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """True if ``a`` and ``b`` name the same file or directory (links and spellings resolved)."""
    pa, pb = Path(a), Path(b)
    try:
        if pa.exists() and pb.exists():
            return os.path.samefile(pa, pb)
    except OSError:
        pass
    return pa.resolve() == pb.resolve()


def check_output(path: str | os.PathLike, *, inputs: Iterable[str | os.PathLike] = (), overwrite: bool = False,
                 option: str = "--out", directory: bool = False, marker: str | None = None) -> Path:
    """Apply the policy to one output; returns its path. Creates nothing.

    ``inputs``: the command's input files or directories. ``directory``: the output is a directory
    whose finished form holds ``marker`` (a file name inside it); without a marker a directory
    output is never "finished" (the command merges into it file by file and checks those itself).
    Raises :class:`OutputError` naming ``option``.
    """
    out = Path(path)
    for given in inputs:
        inp = Path(given)
        if same_path(out, inp):
            raise OutputError(f"{option}: {out} is the command's input {inp}; it would be overwritten. "
                              f"Give another output path")
    if directory:
        if out.exists() and not out.is_dir():
            raise OutputError(f"{option}: {out} is an existing file, not a directory ({describe_existing(out)})")
        if marker is not None and (out / marker).is_file() and not overwrite:
            raise OutputError(f"{option}: {out} already holds a finished output ({describe_existing(out / marker)}); "
                              f"add --overwrite to replace it, or give another directory")
        return out
    if out.is_dir():
        raise OutputError(f"{option}: {out} is a directory; give a file name")
    if out.exists() and not overwrite:
        raise OutputError(f"{option}: {out} exists ({describe_existing(out)}); add --overwrite to replace it, "
                          f"or give another name")
    return out


def _mtime(p: Path) -> str:
    t = _dt.datetime.fromtimestamp(p.stat().st_mtime, _dt.timezone.utc)
    return t.strftime("%Y-%m-%d %H:%M UTC")


def describe_existing(path: str | os.PathLike) -> str:
    """One phrase saying what the file at ``path`` holds: its format, material, rays and date where
    the file records them, else its size and modification time. Never raises for an unreadable file."""
    p = Path(path)
    try:
        with open(p, "rb") as fh:
            head = fh.read(16)
        size = p.stat().st_size
        date = _mtime(p)
    except OSError as e:
        return f"unreadable: {e.strerror or e}"
    if head.startswith(_HDF5_MAGIC):
        return _describe_hdf5(p, size, date)
    if head.startswith(TENSOR_MAGIC):
        return f"an RGL tensor file (.bsdf), {size:,} bytes, modified {date}"
    if head.startswith(_PNG_MAGIC):
        return f"a PNG image, {size:,} bytes, modified {date}"
    if p.suffix == ".binary" and size >= 12:
        import numpy as np
        dims = np.frombuffer(head[:12], dtype="<i4")
        if tuple(int(x) for x in dims) == (90, 90, 180):
            return f"a MERL .binary BRDF (90x90x180), modified {date}"
    kinds = {".json": "a JSON file", ".toml": "a TOML file", ".md": "a Markdown file", ".html": "an HTML page",
             ".csv": "a CSV table", ".txt": "a text file"}
    return f"{kinds.get(p.suffix.lower(), 'a file')} of {size:,} bytes, modified {date}"


def _describe_hdf5(p: Path, size: int, date: str) -> str:
    try:
        import h5py
        with h5py.File(p, "r") as f:
            fmt = f.attrs.get("format")
            if fmt is None:
                return f"an HDF5 file of {size:,} bytes, modified {date}"
            fmt = fmt.decode() if isinstance(fmt, bytes) else str(fmt)
            parts = [f"a {fmt} file"]
            if "material" in f and "name" in f["material"].attrs:
                parts.append(f"of {f['material'].attrs['name']}")
            sim = f["simulation"].attrs if "simulation" in f else {}
            if "rays_per_slice" in sim:
                n_inc = f["incident"]["theta_deg"].shape[0] if "incident" in f else 0
                parts.append(f"({int(sim['rays_per_slice']):,} rays x {n_inc} incident direction(s))")
            elif "rays" in sim:
                parts.append(f"({int(sim['rays']):,} rays)")
            created = f.attrs.get("created")
            parts.append(f"written {created}" if created is not None else f"modified {date}")
            return " ".join(parts)
    except (OSError, KeyError, ValueError):
        return f"an HDF5 file of {size:,} bytes that cannot be read, modified {date}"
