"""Comparison figures of sphere images: labelled panels, hatching where the reference has no
value, split spheres (left half reference, right half model, as Bati 2019 figures 16-17), a title
and a caption; PNG written atomically (``docs/render.md``)."""

from __future__ import annotations

import io
import textwrap
from pathlib import Path

import numpy as np

from goniometer import atomic

#: display value of the background (outside the sphere): dark grey, so that the unlit side shows
BACKGROUND = 0.16
#: the two greys of the hatching that marks sphere pixels without a value
HATCH = (0.42, 0.58)
DPI = 100


def fill(disp: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """(S, S, 3) display values with NaN -> an RGB image: background outside the disk, diagonal
    hatching on disk pixels without a value."""
    s = disp.shape[0]
    rr, cc = np.mgrid[0:s, 0:s]
    stripe = np.where(((rr + cc) // max(2, s // 64)) % 2 == 0, HATCH[0], HATCH[1])
    out = np.where(np.isfinite(disp), disp, stripe[..., None])
    out[~inside] = BACKGROUND
    return np.clip(out, 0.0, 1.0)


def split(ref: np.ndarray, model: np.ndarray) -> np.ndarray:
    """Left half from ``ref``, right half from ``model`` (both (S, S, 3) images), a thin light line
    between them."""
    s = ref.shape[1]
    out = model.copy()
    out[:, : s // 2] = ref[:, : s // 2]
    w = max(1, s // 256)
    out[:, s // 2 - w // 2 - (w % 2): s // 2 + w // 2] = 0.85
    return out


def figure(rows: list[list[tuple[str, np.ndarray | None]]], title: str, caption: str | None = None):
    """A matplotlib Figure of panels: ``rows`` of ``(label, RGB image or None)``; every image has
    the same size, one pixel of the image per pixel of the figure."""
    from matplotlib.figure import Figure
    s = next(img.shape[0] for row in rows for _, img in row if img is not None)
    ncol = max(len(r) for r in rows)
    fs = float(np.clip(s / 38.0, 7.0, 13.0))
    gap, label_h = int(0.06 * s) + 4, int(2.9 * fs * DPI / 72.0) + 4
    title_h = int(1.7 * fs * DPI / 72.0 * max(1, title.count("\n") + 1)) + 10
    width = ncol * s + (ncol + 1) * gap
    cap_lines = []
    if caption:
        chars = max(40, int(width / (0.55 * fs * DPI / 72.0)))
        for part in caption.split("\n"):
            cap_lines += textwrap.wrap(part, chars) or [""]
    cap_h = int(len(cap_lines) * 1.35 * 0.85 * fs * DPI / 72.0) + (gap if cap_lines else 0)
    height = title_h + len(rows) * (label_h + s) + (len(rows) - 1) * gap // 2 + cap_h + gap // 2
    fig = Figure(figsize=(width / DPI, height / DPI), dpi=DPI, facecolor="white")
    fig.text(0.5, 1.0 - 6 / height, title, ha="center", va="top", fontsize=fs * 1.05)
    y = height - title_h
    for row in rows:
        for c, (label, img) in enumerate(row):
            x = gap + c * (s + gap)
            if label:
                fig.text((x + s / 2) / width, (y - 2) / height, label, ha="center", va="top", fontsize=fs,
                         linespacing=1.15)
            if img is not None:
                ax = fig.add_axes((x / width, (y - label_h - s) / height, s / width, s / height))
                ax.imshow(img, interpolation="nearest")
                ax.set_axis_off()
        y -= label_h + s + gap // 2
    if cap_lines:
        fig.text(gap / width, (y - gap // 2 + 6) / height, "\n".join(cap_lines), ha="left", va="top",
                 fontsize=fs * 0.85, color="0.25")
    return fig


def write_png(path: str | Path, fig) -> None:
    """The figure as a PNG (8-bit sRGB) at :data:`DPI`, written atomically."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, facecolor="white")
    atomic.write_bytes(path, buf.getvalue())
