"""The tensor file container of the RGL material database (Dupuy & Jakob 2018), the file format
Mitsuba 3's and pbrt-v4's ``measured`` materials read (``docs/rgl-format.md``, the container).

Layout, little-endian: the 12 bytes ``tensor_file\\0``, version 1.0 (two u8), a u32 field count,
then per field ``u16`` name length, the name (UTF-8, no terminator), ``u16`` ndim, ``u8`` dtype
code, ``u64`` offset of the data from the start of the file, ``ndim`` x ``u64`` shape; each field's
data is a C-order array at its offset (aligned to 8 bytes by :func:`write_tensor`).
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np

from goniometer.atomic import write_bytes

__all__ = ["MAGIC", "TensorError", "TensorFile", "read_tensor", "tensor_bytes", "write_tensor"]

MAGIC = b"tensor_file\0"
VERSION = (1, 0)
#: dtype codes of the format (Mitsuba's Struct::Type, pbrt's Tensor::Type)
DTYPES = {1: np.uint8, 2: np.int8, 3: np.uint16, 4: np.int16, 5: np.uint32, 6: np.int32, 7: np.uint64,
          8: np.int64, 9: np.float16, 10: np.float32, 11: np.float64}
CODES = {np.dtype(t).newbyteorder("<"): c for c, t in DTYPES.items()}
ALIGN = 8


class TensorError(ValueError):
    """A tensor file that cannot be read, or fields that cannot be written (one line: what and where)."""


@dataclass(frozen=True)
class TensorFile:
    """The fields of a tensor file, by name (numpy arrays, read-only copies)."""

    path: str
    fields: dict[str, np.ndarray]
    version: tuple[int, int] = VERSION

    def __getitem__(self, name: str) -> np.ndarray:
        return self.fields[name]

    def __contains__(self, name: str) -> bool:
        return name in self.fields

    def text(self, name: str = "description") -> str:
        """A uint8 field as UTF-8 text (the ``description``)."""
        return bytes(self.fields[name].tobytes()).decode("utf-8", errors="replace")


def tensor_bytes(fields: Mapping[str, np.ndarray | str | bytes]) -> bytes:
    """The bytes of a tensor file holding ``fields`` in the given order (str and bytes become uint8
    arrays). Every array is written little-endian in C order at an offset aligned to 8 bytes."""
    arrays: list[tuple[bytes, np.ndarray]] = []
    for name, value in fields.items():
        if isinstance(value, str):
            value = np.frombuffer(value.encode("utf-8"), dtype=np.uint8)
        elif isinstance(value, (bytes, bytearray)):
            value = np.frombuffer(bytes(value), dtype=np.uint8)
        a = np.ascontiguousarray(value)
        dt = a.dtype.newbyteorder("<")
        if dt not in CODES:
            raise TensorError(f"field {name!r}: dtype {a.dtype} is not one of the format's")
        key = name.encode("utf-8")
        if not 0 < len(key) < 2**16 or a.ndim >= 2**16:
            raise TensorError(f"field {name!r}: name or rank out of the format's range")
        arrays.append((key, a.astype(dt, copy=False)))
    header = len(MAGIC) + 2 + 4 + sum(2 + len(k) + 2 + 1 + 8 + 8 * a.ndim for k, a in arrays)
    out = bytearray(MAGIC + bytes(VERSION) + struct.pack("<I", len(arrays)))
    offset = -(-header // ALIGN) * ALIGN
    offsets = []
    for key, a in arrays:
        offsets.append(offset)
        offset = -(-(offset + a.nbytes) // ALIGN) * ALIGN
    for (key, a), off in zip(arrays, offsets):
        out += struct.pack("<H", len(key)) + key + struct.pack("<HBQ", a.ndim, CODES[a.dtype], off)
        out += struct.pack(f"<{a.ndim}Q", *a.shape)
    for (key, a), off in zip(arrays, offsets):
        out += b"\0" * (off - len(out)) + a.tobytes(order="C")
    return bytes(out)


def write_tensor(path: str | os.PathLike, fields: Mapping[str, np.ndarray | str | bytes]) -> Path:
    """Write ``fields`` as a tensor file at ``path``, atomically; returns the path."""
    p = Path(path)
    write_bytes(p, tensor_bytes(fields))
    return p


def read_tensor(path: str | os.PathLike) -> TensorFile:
    """Read every field of the tensor file at ``path``. Raises :class:`TensorError` (one line
    naming the file and what is wrong) for anything that is not a whole, well-formed file."""
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as e:
        raise TensorError(f"{p}: cannot be read ({e.strerror or e})") from None
    if not raw.startswith(MAGIC):
        raise TensorError(f"{p}: not a tensor file (it does not start with 'tensor_file\\0')")
    pos = len(MAGIC)

    def take(fmt: str) -> tuple:
        nonlocal pos
        size = struct.calcsize(fmt)
        if pos + size > len(raw):
            raise TensorError(f"{p}: the header is cut short at byte {pos} (file of {len(raw)} bytes)")
        values = struct.unpack_from(fmt, raw, pos)
        pos += size
        return values

    version = take("<BB")
    if version != VERSION:
        raise TensorError(f"{p}: tensor file version {version[0]}.{version[1]}; version 1.0 is read")
    (count,) = take("<I")
    fields: dict[str, np.ndarray] = {}
    for k in range(count):
        (n,) = take("<H")
        name_b = raw[pos:pos + n]
        if len(name_b) != n:
            raise TensorError(f"{p}: the header is cut short in field {k + 1} of {count}")
        pos += n
        try:
            name = name_b.decode("utf-8")
        except UnicodeDecodeError:
            raise TensorError(f"{p}: field {k + 1} has a name that is not UTF-8") from None
        ndim, code, offset = take("<HBQ")
        shape = take(f"<{ndim}Q") if ndim else ()
        if code not in DTYPES:
            raise TensorError(f"{p}: field {name!r} has dtype code {code}, not one of 1..11")
        dt = np.dtype(DTYPES[code]).newbyteorder("<")
        count_items = int(np.prod(shape, dtype=np.int64)) if shape else 1
        end = offset + count_items * dt.itemsize
        if end > len(raw):
            raise TensorError(f"{p}: field {name!r} ({'x'.join(map(str, shape))} {dt.name}) runs past the end "
                              f"of the file ({end} > {len(raw)} bytes)")
        a = np.frombuffer(raw, dtype=dt, count=count_items, offset=offset).reshape(shape).copy()
        a.flags.writeable = False
        fields[name] = a
    return TensorFile(str(p), fields, version)
