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


def ring(img: np.ndarray, x: float, y: float) -> np.ndarray:
    """A copy of the (S, S, 3) image with a hollow yellow ring (dark outline) centred on the image
    point ``(x, y)`` ([-1, 1]², +y up): marks where a peak too narrow to show lies."""
    s = img.shape[0]
    cx, cy = (x + 1.0) / 2.0 * s - 0.5, (1.0 - y) / 2.0 * s - 0.5
    rr, cc = np.mgrid[0:s, 0:s]
    r = np.hypot(cc - cx, rr - cy)
    rad = max(4.0, s / 16.0)
    out = img.copy()
    out[(r >= rad - 2.2) & (r <= rad + 1.2)] = (0.1, 0.1, 0.1)
    out[(r >= rad - 1.2) & (r <= rad + 0.2)] = (1.0, 0.85, 0.0)
    return out


def _wrap(text: str, chars: int) -> list[str]:
    lines: list[str] = []
    for part in text.split("\n"):
        lines += textwrap.wrap(part, max(chars, 12)) or [""]
    return lines


def figure(rows: list[list[tuple[str, np.ndarray | None]]], title: str, caption: str | None = None):
    """A matplotlib Figure of panels: ``rows`` of ``(label, RGB image or None)``; every image has
    the same size, one pixel of the image per pixel of the figure."""
    from matplotlib.figure import Figure
    s = next(img.shape[0] for row in rows for _, img in row if img is not None)
    ncol = max(len(r) for r in rows)
    fs = float(np.clip(s / 38.0, 7.0, 13.0))
    gap, label_h = int(0.06 * s) + 4, int(2.9 * fs * DPI / 72.0) + 4
    # text widths in pixels per character (generous: the layout must not clip what it places)
    title_char, cap_char = 0.62 * 1.05 * fs * DPI / 72.0, 0.58 * 0.85 * fs * DPI / 72.0
    panels_w = ncol * s + (ncol + 1) * gap
    # a narrow figure (one or two spheres) widens for its title, up to four spheres' width, then wraps
    title_w = (max(len(part) for part in title.split("\n")) + 1) * title_char + 2 * gap
    width = int(max(panels_w, min(title_w, 4 * s + 5 * gap)))
    x0 = (width - panels_w) // 2
    title_lines = _wrap(title, int((width - 2 * gap) / title_char))
    title = "\n".join(title_lines)
    title_h = int(1.7 * 1.05 * fs * DPI / 72.0 * len(title_lines)) + 10
    cap_lines = _wrap(caption, int((width - 2 * gap) / cap_char)) if caption else []
    cap_h = int(len(cap_lines) * 1.35 * 0.85 * fs * DPI / 72.0) + (gap if cap_lines else 0)
    height = title_h + len(rows) * (label_h + s) + (len(rows) - 1) * gap // 2 + cap_h + gap // 2
    fig = Figure(figsize=(width / DPI, height / DPI), dpi=DPI, facecolor="white")
    fig.text(0.5, 1.0 - 6 / height, title, ha="center", va="top", fontsize=fs * 1.05)
    y = height - title_h
    for row in rows:
        for c, (label, img) in enumerate(row):
            x = x0 + gap + c * (s + gap)
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
