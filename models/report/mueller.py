"""``gonio plot``'s figures of a polarized file (``docs/polarization.md``, "Looking at a polarized
file"): per incident direction and side, the 16 Mueller elements normalized by M00 seen from above,
and the degree of polarization for unpolarized incident light.

* ``m_ij = M_ij / M00`` of the white (Rec. 709 luminance-weighted) Mueller matrix of each cell
  (:func:`models.render.stokes.white`), in the file's s/p frames (``docs/polarization.md`` §2),
  on a diverging colour map fixed to [-1, 1];
* ``DOP = sqrt(M10² + M20² + M30²) / M00`` (unpolarized light in, the first column out), [0, 1];
* cells without enough signal are grey (:data:`models.render.stokes.SIGNAL_RULE`), as are the
  cells outside the file's comparison mask.

Views are the report's top views (:mod:`models.report.geometry`: the outgoing hemisphere seen from
above, +x to the right; a BTDF's lower hemisphere seen through the surface), the light marked with
a ring. Files: ``mueller_<side>_theta<θ_l>_phi<φ_l>.png`` and ``dop_<side>_theta<θ_l>_phi<φ_l>.png``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from goniometer.grids.slice_grid import light_direction
from goniometer.run.results import SimulationResult, SliceData
from models.render.stokes import SIGNAL_RULE, dop, enough_signal, white
from models.report.geometry import pixel_map
from models.report.panels import DPI, colormap, diverging_panel, mark_light, save_figure

#: top-view disk diameter of each Mueller element (pixels)
ELEMENT_PX = 110
DOP_PX = 200
DOP_CMAP = "viridis"
FRAMES_TEXT = "s/p frames of each beam's plane of incidence (docs/polarization.md §2)"
#: what ``gonio plot`` says of these figures
NOTE = (f"polarized file: Mueller elements m_ij = M_ij / M00 and the degree of polarization for unpolarized light, "
        f"white light (Rec. 709 luminance of the channels), {FRAMES_TEXT}; {SIGNAL_RULE}")


def normalized(sd: SliceData, m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Of incident direction ``m``: the white Mueller matrices normalized by M00 (n_theta, n_phi, 4, 4),
    the DOP (n_theta, n_phi) and the cells drawn (enough signal and in the mask); NaN elsewhere."""
    mu, se = white(sd.mueller[m], sd.mueller_stderr[m], axis=0)          # (nt, nph, 4, 4)
    ok = np.asarray(sd.mask[m], dtype=bool) & enough_signal(mu[..., 0, 0], se[..., 0, 0])
    with np.errstate(invalid="ignore", divide="ignore"):
        norm = np.where(ok[..., None, None], mu / np.where(ok, mu[..., 0, 0], 1.0)[..., None, None], np.nan)
    return norm, np.where(ok, dop(mu[..., :, 0]), np.nan), ok


def _side_text(side: str) -> str:
    return "BRDF seen from above" if side == "brdf" else "BTDF, lower hemisphere seen from above"


def _wrapped(lines: list[str], width: int) -> str:
    """A figure title: each line wrapped at ``width`` characters (the figure's width at its font)."""
    import textwrap
    return "\n".join(textwrap.fill(line, width) for line in lines)


def _mueller_figure(sd: SliceData, side: str, m: int, theta: float, phi: float, title: str):
    from matplotlib import colors
    from matplotlib.cm import ScalarMappable
    from matplotlib.figure import Figure
    norm, _, ok = normalized(sd, m)
    light = light_direction(theta, phi)
    pm = pixel_map(sd.grid, light, ok, ELEMENT_PX)
    fig = Figure(figsize=(7.6, 8.4), dpi=DPI)
    fig.subplots_adjust(left=0.07, right=0.86, bottom=0.04, top=0.87, wspace=0.08, hspace=0.18)
    axes = fig.subplots(4, 4)
    for i in range(4):
        for j in range(4):
            ax = axes[i, j]
            ax.imshow(mark_light(diverging_panel(pm.sample(norm[..., i, j]), 1.0, pm), light), interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(f"m{i}{j}", fontsize=8, pad=2)
    for i in range(4):
        axes[i, 0].set_ylabel(f"row {i} (exit S{i})", fontsize=7)
        axes[3, i].set_xlabel(f"column {i} (incident S{i})", fontsize=7)
    cax = fig.add_axes((0.89, 0.25, 0.022, 0.45))
    bar = fig.colorbar(ScalarMappable(norm=colors.Normalize(-1.0, 1.0), cmap=colormap("RdBu_r")), cax=cax,
                       ticks=[-1, -0.5, 0, 0.5, 1])
    bar.set_label("m_ij = M_ij / M00 (1: M_ij and M00 in sr⁻¹)", fontsize=7)
    bar.ax.tick_params(labelsize=7)
    fig.suptitle(_wrapped([f"{title}: Mueller matrix normalized by M00, {_side_text(side)}, "
                           f"θ_l = {theta:g}°, φ_l = {phi:g}°",
                           f"white light; {FRAMES_TEXT}; +x (φ = 0°) right, +y up; ring: the light l",
                           f"{SIGNAL_RULE}, or outside the comparison mask"], 120), fontsize=7.5)
    return fig


def _dop_figure(sd: SliceData, side: str, m: int, theta: float, phi: float, title: str):
    from matplotlib import colors
    from matplotlib.cm import ScalarMappable
    from matplotlib.figure import Figure
    _, d, ok = normalized(sd, m)
    light = light_direction(theta, phi)
    pm = pixel_map(sd.grid, light, ok, DOP_PX)
    values = pm.sample(d)
    img = colormap(DOP_CMAP)(np.clip(np.nan_to_num(values), 0.0, 1.0))[..., :3]
    img[~(pm.ok & np.isfinite(values))] = 0.82          # grey: not drawn (the panels' masked grey)
    img[~pm.inside] = 1.0
    fig = Figure(figsize=(4.6, 4.4), dpi=DPI)
    fig.subplots_adjust(left=0.1, right=0.8, bottom=0.1, top=0.78)
    ax = fig.subplots()
    ax.imshow(mark_light(img, light), interpolation="nearest")
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_xlabel("+x (φ = 0°) →", fontsize=7)
    ax.set_ylabel("+y (φ = 90°) →", fontsize=7)
    cax = fig.add_axes((0.84, 0.15, 0.035, 0.58))
    bar = fig.colorbar(ScalarMappable(norm=colors.Normalize(0.0, 1.0), cmap=colormap(DOP_CMAP)), cax=cax)
    bar.set_label("DOP (1)", fontsize=7)
    bar.ax.tick_params(labelsize=7)
    fig.suptitle(_wrapped([f"{title}: degree of polarization for unpolarized light",
                           f"DOP = √(M10² + M20² + M30²) / M00, {_side_text(side)}, θ_l = {theta:g}°, "
                           f"φ_l = {phi:g}°",
                           f"white light; ring: the light l; {SIGNAL_RULE}, or outside the comparison mask"], 80),
                 fontsize=6.5)
    return fig


def draw_polarization_figures(result: SimulationResult, out_dir: Path, incidents: Sequence[float] | None = None,
                              title: str | None = None) -> list[Path]:
    """The Mueller and DOP figures of every side of a polarized ``result`` (linear sRGB: call
    :meth:`SimulationResult.rgb` first on a spectral one), for its incident directions whose polar
    angle is in ``incidents`` (degrees; None: all), written into ``out_dir``; their paths. A scalar
    result has none (empty list)."""
    title = title or result.stack.name
    paths: list[Path] = []
    for side in ("brdf", "btdf"):
        sd = getattr(result, side)
        if sd is None or sd.mueller is None:
            continue
        for m, (theta, phi) in enumerate(zip(result.theta_deg, result.phi_deg)):
            theta, phi = float(theta), float(phi)
            if incidents is not None and not any(abs(theta - float(w)) < 1e-6 for w in incidents):
                continue
            tag = f"{side}_theta{theta:g}_phi{phi:g}"
            for name, draw in (("mueller", _mueller_figure), ("dop", _dop_figure)):
                p = Path(out_dir) / f"{name}_{tag}.png"
                save_figure(draw(sd, side, m, theta, phi, title), p)
                paths.append(p)
    return paths


def plot_polarization(path: str | Path, out_dir: str | Path, incidents: Sequence[float] | None = None) -> list[str]:
    """``gonio plot``'s polarization figures of the file ``path`` (:func:`draw_polarization_figures`,
    a spectral file in linear sRGB): their absolute paths, none for a scalar file."""
    from models.report.evaluation import read_reference
    ref = read_reference(Path(path))
    if not ref.settings.polarized:
        return []
    title = ref.stack.name
    if ref.settings.spectral:
        title = f"{title} (linear sRGB of {ref.settings.wavelength_bins} wavelength bins)"
    return [str(p.resolve()) for p in draw_polarization_figures(ref.rgb(), Path(out_dir), incidents, title)]
