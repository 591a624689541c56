"""The MERL ``.binary`` BRDF file (Matusik et al. 2003), written from a tabulated BRDF
(``docs/tabulated-format.md``, MERL export).

Layout: three little-endian int32 ``(90, 90, 180)`` (theta_h, theta_d, phi_d resolutions), then
three planes R, G, B of ``90 * 90 * 180`` little-endian float64 each; the value of cell
``(i_h, i_d, i_p)`` is at ``i_p + 180 (i_d + 90 i_h)`` of its plane, in the grid of
:mod:`goniometer.grids.halfdiff`. A stored value times the channel's scale (:data:`MERL_SCALE`) is the
BRDF in 1/sr without cosine; negative values mark cells without data.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from goniometer.grids import halfdiff
from goniometer.atomic import write_bytes
from goniometer.run.results import TabulatedBRDF

__all__ = ["MERL_SCALE", "NO_DATA", "merl_bytes", "write_merl"]

#: stored value x scale = BRDF (1/sr), per channel R, G, B
MERL_SCALE = (1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0)
#: the stored value of a cell without data (no path left through it)
NO_DATA = -1.0


def merl_bytes(tab: TabulatedBRDF) -> bytes:
    """The MERL ``.binary`` content of ``tab``: cells no path left through get :data:`NO_DATA`."""
    header = np.array(halfdiff.SHAPE, dtype="<i4").tobytes()
    data = tab.value / np.array(MERL_SCALE)[:, None, None, None]
    data[:, ~tab.has_data] = NO_DATA
    return header + np.ascontiguousarray(data, dtype="<f8").tobytes()


def write_merl(path: str | Path, tab: TabulatedBRDF) -> Path:
    """Write ``tab`` as a MERL ``.binary`` file, atomically; returns the path."""
    p = Path(path)
    write_bytes(p, merl_bytes(tab))
    return p
