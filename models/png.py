"""PNG files of numpy images, by zlib alone (PNG 1.2, every row unfiltered: filter type 0): the
report's 8-bit colour figures (:func:`models.report.panels.png_bytes`) and a renderer table's 16-bit
grey image (:func:`models.lut.writers.png16`) share this one encoder."""

from __future__ import annotations

import struct
import zlib

import numpy as np

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def encode_png(img: np.ndarray, level: int, dpi: float | None = None) -> bytes:
    """PNG bytes of ``img``, row 0 at the top: (H, W, 3) or (H, W, 4) uint8 (RGB, RGBA), or (H, W)
    uint16 (16-bit grey); deflated at zlib ``level``; ``dpi``: the resolution stated in a ``pHYs``
    chunk (none without it). Lossless: any PNG reader gives ``img`` back."""
    img = np.asarray(img)
    if img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] in (3, 4) and 0 not in img.shape:
        h, w, c = img.shape
        header = struct.pack(">IIBBBBB", w, h, 8, 2 if c == 3 else 6, 0, 0, 0)
        pixels = img.reshape(h, w * c)
    elif img.dtype == np.uint16 and img.ndim == 2 and 0 not in img.shape:
        h, w = img.shape
        header = struct.pack(">IIBBBBB", w, h, 16, 0, 0, 0, 0)
        pixels = img.astype(">u2").view(np.uint8).reshape(h, 2 * w)   # PNG's samples are big-endian
    else:
        raise ValueError(f"encode_png: the image must be a non-empty (H, W, 3 or 4) uint8 or (H, W) uint16 "
                         f"array, not {img.dtype} {img.shape}")
    rows = np.zeros((h, 1 + pixels.shape[1]), np.uint8)   # column 0: each row's filter type, 0 (none)
    rows[:, 1:] = pixels
    chunks = [(b"IHDR", header)]
    if dpi is not None:
        per_metre = int(round(dpi / 0.0254))
        chunks.append((b"pHYs", struct.pack(">IIB", per_metre, per_metre, 1)))
    chunks += [(b"IDAT", zlib.compress(rows.tobytes(), level)), (b"IEND", b"")]
    return PNG_SIGNATURE + b"".join(struct.pack(">I", len(data)) + kind + data
                                    + struct.pack(">I", zlib.crc32(kind + data)) for kind, data in chunks)
