"""Reading the project's TOML files (materials, databases, inverse cases) with one-line errors."""

from __future__ import annotations

import os
import tomllib
from pathlib import Path
from typing import Any


def read_toml(path: str | os.PathLike, error: type[Exception]) -> dict[str, Any]:
    """The parsed UTF-8 TOML file at ``path``; ``error("<path>: cannot read: ...")`` or
    ``error("<path>: invalid TOML: ...")`` if it cannot be read or parsed."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as e:
        raise error(f"{p}: cannot read: {e.strerror or e}") from None
    except UnicodeDecodeError as e:
        raise error(f"{p}: cannot read: not UTF-8 text (byte 0x{e.object[e.start]:02x} at offset {e.start}); "
                    f"save the file as UTF-8") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise error(f"{p}: invalid TOML: {e}") from None
