"""Raster panels of the report's figures (numpy images: float RGB in [0, 1], row 0 at the top)
and the PNG writing of images and matplotlib figures (atomic, unfiltered rows, fixed zlib level:
:func:`png_bytes`)."""

from __future__ import annotations

import functools
import io
from pathlib import Path

import numpy as np

from goniometer import atomic
from models.png import encode_png
from models.render.figure import DPI as RENDER_DPI
from models.report.geometry import PixelMap, remap

ISO_LEVELS = 10        # luminance isovalue bands
#: the one resolution of every matplotlib figure of the report: the lit spheres' (one image pixel per
#: figure pixel, models.render.figure)
DPI = RENDER_DPI
#: zlib level of every PNG of the report. The rows are written unfiltered (:func:`png_bytes`): on the
#: report's images (flat bands, masked grey, white margins, antialiased text) deflate finds the repeated
#: pixels themselves, and per-row filters only hide them. Measured on the top views and bounce orders
#: of three Bati 2019 materials (182 images, 60 MB of pixels; 2026-12-06): Pillow's adaptive filters
#: at level 3, 0.79 s and 11.9 MB; unfiltered at level 3, 0.36 s and 9.3 MB (level 6: 1.2 s, 8.4 MB)
PNG_COMPRESSION = 3


def colormap(name: str):
    """The matplotlib colour map ``name`` (matplotlib is imported on first use)."""
    import matplotlib
    return matplotlib.colormaps[name]


def legend_colours(stops: int = 11) -> dict:
    """The colours of the false-colour panels for legends drawn outside the images (the HTML colour
    bars): ``bands``, the :data:`ISO_LEVELS` band colours of :func:`iso_panel` (lowest first), and
    ``diverging``, ``stops`` colours of :func:`diverging_panel` evenly spaced from -lim to +lim."""
    def hexes(rgb: np.ndarray) -> list[str]:
        return ["#%02x%02x%02x" % tuple(int(round(255 * c)) for c in row[:3]) for row in rgb]
    return {"bands": hexes(band_colours(ISO_LEVELS)),
            "diverging": hexes(colormap("RdBu_r")(np.linspace(0.0, 1.0, stops))),
            "masked": hexes(np.full((1, 3), 0.82))[0]}


@functools.lru_cache(maxsize=8)
def band_colours(levels: int) -> np.ndarray:
    """The RGB colours (levels, 3) of :func:`iso_panel`'s bands, lowest first: viridis at ``levels``
    evenly spaced points (read-only)."""
    colours = colormap("viridis")(np.linspace(0.0, 1.0, levels))[:, :3]
    colours.flags.writeable = False
    return colours


def rgb_panel(rgb: np.ndarray, scale: float, pm: PixelMap, factor: float = 1.0) -> np.ndarray:
    """(3, S, S) cell values -> (S, S, 3) image of ``factor * g(f) / scale``."""
    img = np.moveaxis(np.clip(factor * remap(pm.sample(rgb)) / scale, 0.0, 1.0), 0, -1)
    return _frame(img, pm)


def iso_panel(lum: np.ndarray, scale: float, pm: PixelMap, levels: int = ISO_LEVELS) -> np.ndarray:
    """Luminance isovalue bands of ``g(L) / scale`` in false colour (viridis), with black band
    boundaries; values above the scale are white."""
    g = remap(pm.sample(lum)) / scale
    band = np.where(np.isfinite(g), np.floor(np.clip(g, 0.0, None) * levels), -1).astype(int)
    band = np.minimum(band, levels)
    # the band colours, then white: above the scale (band = levels) and no value (band = -1)
    img = np.vstack([band_colours(levels), np.ones((1, 3))])[np.where(band < 0, levels, band)]
    edge = np.zeros(band.shape, bool)
    edge[:, 1:] |= (band[:, 1:] != band[:, :-1]) & (band[:, 1:] >= 0) & (band[:, :-1] >= 0)
    edge[1:, :] |= (band[1:, :] != band[:-1, :]) & (band[1:, :] >= 0) & (band[:-1, :] >= 0)
    img[edge] = 0.1
    return _frame(img, pm)


def diverging_panel(d: np.ndarray, lim: float, pm: PixelMap) -> np.ndarray:
    """(S, S) signed values -> RdBu_r colours over [-lim, lim]."""
    t = np.clip(0.5 + 0.5 * d / lim, 0.0, 1.0)
    img = colormap("RdBu_r")(np.nan_to_num(t, nan=0.5))[..., :3]
    return _frame(img, pm, valid=np.isfinite(d))


def _frame(img: np.ndarray, pm: PixelMap, valid: np.ndarray | None = None) -> np.ndarray:
    ok = pm.ok if valid is None else (pm.ok & valid)
    out = np.where(ok[..., None], np.nan_to_num(img), 0.82)   # masked cells: light grey
    out[~pm.inside] = 1.0
    out[pm.ring] = 0.45
    return out


def mark_light(img: np.ndarray, light: np.ndarray) -> np.ndarray:
    """Hollow yellow ring (dark outline) at the top-view position of the light direction; the
    values under its centre stay visible."""
    outline, ring = _light_ring(img.shape[0], float(light[0]), float(light[1]))
    img[outline] = (0.1, 0.1, 0.1)
    img[ring] = (1.0, 0.85, 0.0)
    return img


@functools.lru_cache(maxsize=64)
def _light_ring(s: int, lx: float, ly: float) -> tuple[np.ndarray, np.ndarray]:
    """The pixels of :func:`mark_light`'s dark outline and yellow ring in an ``s`` x ``s`` view, light
    ``(lx, ly, .)`` (every panel of an incident direction marks the same light: worked out once)."""
    cx = (lx + 1.0) / 2.0 * s - 0.5
    cy = (1.0 - ly) / 2.0 * s - 0.5
    yy, xx = np.mgrid[0:s, 0:s]
    r = np.sqrt((xx - cx) ** 2 + (yy - cy) ** 2)
    rad = max(4.0, s / 40)
    outline, ring = (r >= rad - 2.2) & (r <= rad + 1.2), (r >= rad - 1.2) & (r <= rad + 0.2)
    outline.flags.writeable = ring.flags.writeable = False
    return outline, ring


def compose(rows: list[list[np.ndarray]], gap: int = 8) -> np.ndarray:
    """Panels (float RGB in [0, 1]) on a white canvas, row by row."""
    h = max(p.shape[0] for row in rows for p in row)
    w = max(sum(p.shape[1] for p in row) + gap * (len(row) - 1) for row in rows)
    canvas = np.ones((len(rows) * h + gap * (len(rows) - 1), w, 3))
    for r, row in enumerate(rows):
        x = 0
        for p in row:
            y = r * (h + gap)
            canvas[y:y + p.shape[0], x:x + p.shape[1]] = p
            x += p.shape[1] + gap
    return canvas


def png_bytes(img: np.ndarray, dpi: float | None = None) -> bytes:
    """An 8-bit image (H, W, 3) RGB or (H, W, 4) RGBA, row 0 at the top, as PNG bytes: every row
    unfiltered, deflated at :data:`PNG_COMPRESSION` (:func:`models.png.encode_png`); ``dpi``: the
    resolution stated in a ``pHYs`` chunk (none without it). Lossless: any PNG reader gives ``img`` back."""
    img = np.asarray(img)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] not in (3, 4) or 0 in img.shape:
        raise ValueError(f"png_bytes: the image must be a non-empty (H, W, 3 or 4) uint8 array, "
                         f"not {img.dtype} {img.shape}")
    return encode_png(img, PNG_COMPRESSION, dpi)


def write_png(path: Path, img: np.ndarray) -> None:
    """``img`` (float RGB, clipped to [0, 1]) as an 8-bit PNG (:func:`png_bytes`), written atomically."""
    atomic.write_bytes(path, png_bytes((np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)))


def figure_pixels(fig) -> np.ndarray:
    """The pixels of the matplotlib figure ``fig`` drawn by Agg at :data:`DPI`, (H, W, 4) uint8 RGBA:
    what ``fig.savefig(..., format="png", dpi=DPI)`` encodes. The figure keeps its Agg canvas, so
    that a figure drawn again (:class:`models.report.figures.PlaneFigure`) reuses its renderer."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    canvas = fig.canvas if isinstance(fig.canvas, FigureCanvasAgg) else FigureCanvasAgg(fig)
    dpi = fig.dpi
    if dpi != DPI:   # the report's figures are made at DPI: only a foreign one is set to it, for this drawing
        fig.dpi = DPI
    try:
        canvas.draw()
        return np.array(canvas.buffer_rgba())
    finally:
        if dpi != DPI:
            fig.dpi = dpi


def figure_png(fig, tight: bool = False) -> bytes:
    """The matplotlib figure ``fig`` as PNG bytes at :data:`DPI`: its pixels (:func:`figure_pixels`)
    through :func:`png_bytes`, RGB when the figure is opaque (the report's are: white background);
    ``tight``: cropped to its drawn extent (for figures laid out without a layout engine), by
    matplotlib's ``savefig``."""
    if tight:
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=DPI, pil_kwargs={"compress_level": PNG_COMPRESSION}, bbox_inches="tight")
        return buf.getvalue()
    rgba = figure_pixels(fig)
    return png_bytes(rgba[..., :3] if np.all(rgba[..., 3] == 255) else rgba, dpi=DPI)


def save_figure(fig, path: Path, tight: bool = False) -> None:
    """The matplotlib figure ``fig`` as a PNG at :data:`DPI` (:func:`figure_png`), written atomically:
    every matplotlib PNG of ``models.report`` is written here."""
    atomic.write_bytes(Path(path), figure_png(fig, tight))
