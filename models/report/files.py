"""The report's files: atomic text and JSON writes, reading a JSON file that may be absent or
damaged, and safe names for a material's directories (the layout is in ``docs/report.md``)."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from goniometer import atomic


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
