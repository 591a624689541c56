"""The files of a table (``docs/lut.md`` section 6): ``NAME.npy`` (values) and
``NAME.stderr.npy`` (standard errors) in the table's own layout, ``NAME.json`` (both arrays, the
grid, the definition, the rays, the checks), ``NAME.h`` (a C/C++ header of two ``static const
float`` arrays, values and standard errors, row-major as the ``.npy`` holds them) and, where the
values fit an image, ``NAME.png`` (16-bit greyscale). Every file is written atomically
(:mod:`goniometer.atomic`); ``NAME.json`` is written last and marks a finished table.
"""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any, Callable

import numpy as np

from goniometer import atomic
from models.lut.compute import LutResult
from models.png import encode_png

#: the largest image side written (a 3-D table lays its slices side by side)
MAX_IMAGE_SIDE = 16384


def file_names(name: str) -> dict[str, str]:
    """The output files of table ``name`` by kind."""
    return {"values": f"{name}.npy", "stderr": f"{name}.stderr.npy", "json": f"{name}.json", "header": f"{name}.h",
            "png": f"{name}.png"}


def c_float(x: float) -> str:
    """A C float literal holding the single-precision value of ``x`` exactly (9 significant
    digits), always with a point or an exponent before the ``f`` suffix."""
    text = f"{float(np.float32(x)):.9g}"
    if not any(c in text for c in ".en"):
        text += ".0"
    return text + "f"


def c_array(name: str, data: np.ndarray) -> str:
    """``static const float NAME[N] = {...};`` with one printed line per innermost row and a blank
    line between the 2-D slices of a 3-D or 4-D table (as Cycles prints its tables)."""
    a = np.asarray(data, dtype=np.float64)
    rows = a.reshape(-1, a.shape[-1]) if a.ndim else a.reshape(1, 1)
    per_slice = int(np.prod(a.shape[-2:-1])) if a.ndim >= 3 else rows.shape[0] + 1
    lines = []
    for i, row in enumerate(rows):
        if i and i % per_slice == 0:
            lines.append("")
        lines.append("  " + " ".join(c_float(x) + "," for x in row))
    return f"static const float {name}[{a.size}] = {{\n" + "\n".join(lines) + "\n};\n"


def header_text(result: LutResult, source: str = "") -> str:
    """The C/C++ header of a table: a comment saying what it holds, then, inside an include guard,
    the values and the standard errors (``NAME_stderr``)."""
    d = result.definition
    axes = "".join(f"[{a.parameter} {a.nodes}]" for a in d.axes) or "[1]"
    lines = [f"/* {d.name}: {d.quantity} table computed by gonio lut (goniometer; docs/lut.md)",
             f" * {d.description}" if d.description else None,
             f" * definition: {source}" if source else None,
             f" * layout: {axes}, row-major (the last axis fastest); each printed line is one row of the last axis",
             f" * standard errors: {d.name}_stderr[], same layout (largest {float(np.max(result.stderr)):.3g})",
             f" * rays per cell: {int(np.min(result.rays)):,} to {int(np.max(result.rays)):,}; seed {result.seed}",
             " */", ""]
    for a, v in zip(d.axes, result.axis_values):
        nodes = ", ".join(f"{x:.6g}" for x in v[:8]) + (", ..." if v.size > 8 else "")
        what = {"alpha=r^2": " (GGX alpha = r^2)", "alpha=r": " (GGX alpha)",
                "ior=ior_from_F0(z^4)": " (index from F0 = z^4)"}.get(a.map, "")
        lines.insert(-2, f" * axis {a.parameter}{what}: {a.nodes} nodes ({a.placement}), values {nodes}")
    text = "\n".join(x for x in lines if x is not None)
    guard = f"GONIOMETER_LUT_{d.c_name.upper()}_H"
    return (text + f"\n#ifndef {guard}\n#define {guard}\n\n" + c_array(d.c_name, result.values) + "\n"
            + c_array(f"{d.c_name}_stderr", result.stderr) + f"\n#endif /* {guard} */\n")


def image_layout(values: np.ndarray) -> np.ndarray | None:
    """The table as a 2-D image (rows = the first axis of a 2-D table; a 3-D table's slices along
    its first axis side by side), or None for a 4-D table or one too large."""
    a = np.asarray(values, dtype=np.float64)
    if a.ndim == 0:
        a = a.reshape(1, 1)
    if a.ndim == 1:
        img = a.reshape(1, -1)
    elif a.ndim == 2:
        img = a
    elif a.ndim == 3:
        img = np.concatenate(list(a), axis=1)
    else:
        return None
    return img if max(img.shape) <= MAX_IMAGE_SIDE else None


def png_why_not(values: np.ndarray) -> str | None:
    """Why a table gets no PNG (None if it gets one)."""
    if image_layout(values) is None:
        return "a 4-D table (or one wider than 16384 pixels) is no image"
    v = np.asarray(values)
    if np.min(v) < 0.0 or np.max(v) > 1.0:
        return f"its values leave [0, 1] ({float(np.min(v)):.4g} to {float(np.max(v)):.4g}); the PNG stores 0..1"
    return None


def png16(image: np.ndarray) -> bytes:
    """A 16-bit greyscale PNG of ``image`` (values in [0, 1], rounded to ``/65535``), every row
    unfiltered, deflated at zlib level 9 (:func:`models.png.encode_png`)."""
    return encode_png(np.round(np.clip(image, 0.0, 1.0) * 65535.0).astype(np.uint16), 9)


def describe_table(path: str | Path) -> str | None:
    """What a finished table's ``NAME.json`` holds, in one phrase (None if it is not one)."""
    try:
        d = json.loads(Path(path).read_text(encoding="utf-8"))
        if d.get("format") != "goniometer.lut":
            return None
        shape = " x ".join(str(n) for n in d["shape"]) or "1"
        return (f"the {d['quantity']} table {d['name']}, {shape} cell(s), standard error at most "
                f"{float(d['stderr_max']):.3g}, {int(d['total_rays']):,} rays, written {d.get('created', '?')}")
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _npy(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(a, dtype=np.float64))
    return buf.getvalue()


def write_table(out: str | Path, result: LutResult, document: dict[str, Any], source: str = "",
                commit: Callable[[], None] | None = None) -> dict[str, Path]:
    """Write the table's files into the directory ``out`` (created if needed); ``document`` is the
    JSON object (:meth:`LutResult.to_json` with the checks), written last. ``commit`` as in
    :func:`goniometer.atomic.atomic_path` for the last file. Returns the paths by kind (no
    ``png`` where :func:`png_why_not` says why)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    names = file_names(result.definition.name)
    paths = {k: out / v for k, v in names.items()}
    atomic.write_bytes(paths["values"], _npy(result.values))
    atomic.write_bytes(paths["stderr"], _npy(result.stderr))
    atomic.write_bytes(paths["header"], header_text(result, source).encode())
    if png_why_not(result.values) is None:
        atomic.write_bytes(paths["png"], png16(image_layout(result.values)))
    else:
        paths.pop("png")
    with atomic.atomic_path(paths["json"], commit) as tmp:
        tmp.write_text(json.dumps(document, indent=1))
    return paths


__all__ = ["file_names", "c_float", "c_array", "header_text", "image_layout", "png_why_not", "png16", "describe_table",
           "write_table"]
