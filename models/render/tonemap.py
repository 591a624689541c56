"""Tone mapping of sphere images (``docs/render.md``): one exposure for every panel of a
comparison, set on the reference, then the sRGB transfer function.

Colour space: the simulator's and the models' R, G, B channels are taken as **linear sRGB**
(Rec. 709 primaries, D65 white); images are encoded with the sRGB OETF (IEC 61966-2-1) and
written as 8-bit sRGB PNGs.
"""

from __future__ import annotations

import numpy as np

from models.render.sphere import RenderError

#: the reference's pixel values (max over R, G, B, sphere pixels with a value) at this percentile ...
EXPOSURE_PERCENTILE = 99.0
#: ... are displayed at this linear value (before the OETF); brighter pixels clip at 1
EXPOSURE_WHITE = 0.9

EXPOSURE_RULE = (f"one exposure for all panels: the reference's {EXPOSURE_PERCENTILE:g}th percentile "
                 f"(max of R, G, B over the sphere) maps to {EXPOSURE_WHITE:g}, then the sRGB OETF; "
                 f"linear sRGB primaries")


def exposure(reference: np.ndarray, inside: np.ndarray) -> float:
    """The factor ``k`` that maps the reference's radiance (size, size, 3) to display values: its
    :data:`EXPOSURE_PERCENTILE` percentile (of the per-pixel maximum channel over the sphere pixels
    with a value, unlit ones included) maps to :data:`EXPOSURE_WHITE`; if that percentile is 0
    (a tiny highlight on black), its maximum does. RenderError if the reference is black or has no
    value on the sphere."""
    return pixel_exposure(reference[inside])


def pixel_exposure(px: np.ndarray) -> float:
    """:func:`exposure` of sphere pixels ``px`` (P, 3) (NaN: no value)."""
    m = np.max(px, axis=-1)
    m = m[np.isfinite(m)]
    if not m.size:
        raise RenderError("the reference has no value on this sphere (light outside the recorded incident range?)")
    p = float(np.percentile(m, EXPOSURE_PERCENTILE))
    if not p > 0.0:
        p = float(np.max(m))
    if not p > 0.0:
        raise RenderError("the reference is black on this sphere; no exposure can be set")
    return EXPOSURE_WHITE / p


def srgb_oetf(x: np.ndarray) -> np.ndarray:
    """The sRGB transfer function of linear values in [0, 1] (IEC 61966-2-1: linear below 0.0031308)."""
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def display(img: np.ndarray, k: float) -> np.ndarray:
    """Display values in [0, 1] (sRGB-encoded) of linear radiance ``img`` at exposure ``k``; NaN
    stays NaN (no value)."""
    out = srgb_oetf(np.nan_to_num(k * img, nan=0.0))
    return np.where(np.isfinite(img), out, np.nan)
