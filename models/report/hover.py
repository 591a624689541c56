"""The hover read-out data of the report's top views (``docs/report.md``, hover read-out): per
material one small script file ``hover.js`` that the page loads when the material is shown (a
``<script>`` element works from ``file://``, where ``fetch`` of a local file does not).

Per incident direction it holds the luminance ``L`` (1/sr, no cosine) of the reference, its
standard error (``sum_c w_c stderr_c``, the upper bound the noise floor uses) and every model's
total, sampled on a coarse top-view grid of :data:`HOVER_PX` x :data:`HOVER_PX` pixels: the same
orthographic map as the images (:func:`models.report.geometry.pixel_map`: pixel (r, c) is the
direction ``x = (2c + 1) / S - 1``, ``y = 1 - (2r + 1) / S``, ``+x`` right, ``+y`` up, seen from
above; a BTDF seen through the surface), each coarse pixel a block of the image's pixels. Only the
pixels inside the disk (``(2c + 1 - S)^2 + (2r + 1 - S)^2 < S^2``) are stored, row by row.
The plane-of-incidence figure's panels (``plane``: :func:`hover_plane`) carry the plotted points:
their signed elevation, the reference, its standard error and each model (total, or the internal
paths in the BRDF's second panel), with each panel's axes box in pixels of the PNG.

Values are coded as little-endian uint16, base64: codes 1 .. :data:`N_CODES` are log-spaced from
:data:`F_MIN` to :data:`F_MAX` (relative rounding error <= :data:`RELATIVE_PRECISION`, about
2.5e-4); :data:`BELOW` (0): ``0 <= f < F_MIN``; :data:`ABOVE`: ``f > F_MAX``; :data:`NEGATIVE`:
``f < 0``; :data:`NO_VALUE`: outside the disk or a cell masked for the errors.
"""

from __future__ import annotations

import base64
import json
import math

import numpy as np

from models.report.geometry import PixelMap

HOVER_FORMAT = "goniometer.report-hover"
HOVER_VERSION = 1
#: side of the coarse hover grid (pixels); the top-view disk size must be a multiple of it
HOVER_PX = 36
F_MIN, F_MAX = 1e-7, 1e7            # 1/sr
N_CODES = 65532                     # log-spaced codes 1 .. N_CODES
BELOW, ABOVE, NEGATIVE, NO_VALUE = 0, 65533, 65534, 65535
_STEP = math.log(F_MAX / F_MIN) / (N_CODES - 1)
#: largest relative error of a coded value in [F_MIN, F_MAX]
RELATIVE_PRECISION = math.expm1(_STEP / 2)


def encode(values: np.ndarray) -> str:
    """1-D ``values`` (1/sr; NaN: no value) -> base64 of little-endian uint16 codes."""
    v = np.asarray(values, dtype=np.float64).ravel()
    code = np.full(v.shape, NO_VALUE, dtype=np.int64)
    fin = np.isfinite(v)
    code[fin & (v < 0.0)] = NEGATIVE
    code[fin & (v >= 0.0) & (v < F_MIN)] = BELOW
    code[fin & (v > F_MAX)] = ABOVE
    mid = fin & (v >= F_MIN) & (v <= F_MAX)
    code[mid] = 1 + np.rint(np.log(v[mid] / F_MIN) / _STEP).astype(np.int64)
    return base64.b64encode(code.astype("<u2").tobytes()).decode("ascii")


def decode(text: str) -> np.ndarray:
    """The inverse of :func:`encode`: values, NaN for NO_VALUE, 0 for BELOW, inf for ABOVE,
    -inf for NEGATIVE (the page shows "< F_MIN", "> F_MAX", "negative")."""
    code = np.frombuffer(base64.b64decode(text), dtype="<u2").astype(np.int64)
    out = F_MIN * np.exp((code - 1) * _STEP)
    out[code == BELOW] = 0.0
    out[code == ABOVE] = np.inf
    out[code == NEGATIVE] = -np.inf
    out[code == NO_VALUE] = np.nan
    return out


def disk_pixels(size: int = HOVER_PX) -> np.ndarray:
    """(size, size) bool: the coarse pixels whose centre lies inside the unit disk (exact integer test)."""
    k = 2 * np.arange(size) + 1 - size
    return k[None, :] ** 2 + k[:, None] ** 2 < size * size


def hover_incident(pm: PixelMap, theta: float, phi: float, index: int, reference: np.ndarray,
                   reference_se: np.ndarray, models: dict[str, np.ndarray]) -> dict:
    """One incident direction's entry: ``reference``, ``reference_se`` and ``models[name]`` are
    luminance cells (n_theta, n_phi), sampled through ``pm`` (a :data:`HOVER_PX` pixel map with the
    comparison mask) at the disk pixels and coded."""
    if pm.size != HOVER_PX:
        raise ValueError(f"hover pixel map of {pm.size} pixels, expected {HOVER_PX}")
    inside = disk_pixels(pm.size)

    def pack(cells: np.ndarray) -> str:
        return encode(pm.sample(cells)[inside])

    return {"index": index, "theta": theta, "phi": phi, "reference": pack(reference),
            "reference_se": pack(reference_se), "models": {n: pack(c) for n, c in models.items()}}


def hover_plane(label: str, box: list[float], xlim: tuple[float, float], x: np.ndarray, reference: np.ndarray,
                reference_se: np.ndarray, models: dict[str, np.ndarray]) -> dict:
    """One panel of the plane-of-incidence figure: ``box`` = its axes (left, top, width, height) in
    pixels of the PNG, ``xlim`` its abscissa range (degrees), ``x`` the signed elevations of the
    plotted points (degrees, ``docs/report.md``) and the luminance plotted there (1/sr): the
    reference, its standard error and each model, coded like the top views."""
    return {"label": label, "box": [round(float(b), 2) for b in box], "xlim": [float(v) for v in xlim],
            "x": [round(float(v), 3) for v in x], "reference": encode(reference),
            "reference_se": encode(reference_se), "models": {n: encode(v) for n, v in models.items()}}


def hover_script(material: str, side: str, incidents: list[dict]) -> str:
    """The ``hover.js`` text: registers the material's data in ``window.GONIO_HOVER``."""
    doc = {"format": HOVER_FORMAT, "version": HOVER_VERSION, "material": material, "side": side,
           "size": HOVER_PX, "f_min": F_MIN, "f_max": F_MAX, "n_codes": N_CODES,
           "codes": {"below": BELOW, "above": ABOVE, "negative": NEGATIVE, "no_value": NO_VALUE},
           "quantity": "luminance (Rec. 709) of f in 1/sr, no cosine; reference_se = sum_c w_c stderr_c",
           "incidents": incidents}
    return ("// Hover read-out data of the report (models/report/hover.py, docs/report.md).\n"
            "(window.GONIO_HOVER = window.GONIO_HOVER || {})[" + json.dumps(material) + "] = "
            + json.dumps(doc, separators=(",", ":"), allow_nan=False) + ";\n")
