"""The report's figures of one material (``docs/report.md``, figures): plane-of-incidence curves,
top views (RGB, luminance isovalues, difference to the reference), the bounce-order decomposition
(Bati 2019, figure 13) and the energy per bounce order; the models' colours and markers; the
figure stamp that lets a rerun skip current figures; :func:`plot_file` for ``gonio plot``.

Values are drawn through the paper's remap ``g(f) = log(1 + sqrt(f))``; the view and curve
geometry is in :mod:`models.report.geometry`.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from goniometer.run.results import SimulationResult, SliceData
from goniometer.grids.slice_grid import SliceGrid, light_direction
from models.compare.errors import luminance
from models.evaluation import comparison_side, evaluate
from models.report.evaluation import cache_paths, judged_side, load_slices, read_reference
from models.report.files import material_dir, read_json, safe_part, write_json, write_text
from models.report.geometry import exposure, pixel_map, plane_cells, remap, unremap
from models.report.hover import HOVER_PX, hover_incident, hover_plane, hover_script
from models.report.panels import (DPI, ISO_LEVELS, colormap, compose, diverging_panel, iso_panel, mark_light,
                                  rgb_panel, save_figure, write_png)
from models.report.results import MaterialResult, ReportError

#: the paper's colours (figures 5-10) for its models; others get FALLBACK_COLOURS in name order
PAPER_COLOURS = {
    "ww09": "#e41a1c",            # red
    "elek10": "#ff8c00",          # orange
    "belcour-fwd": "#00bcd4",     # cyan
    "belcour-sym": "#1f4fd8",     # blue
    "ww-bati19": "#e377c2",       # pink (figure 10, eq. 5)
    "belcour-bati19": "#2ca02c",  # green (figure 10, eq. 6)
    "belcour-btdf": "#009aa8",    # teal: Belcour forward on slabs (cyan in figure 9)
}
FALLBACK_COLOURS = ("#8c564b", "#9467bd", "#7f7f7f", "#bcbd22", "#393b79", "#637939", "#8c6d31",
                    "#843c39", "#7b4173", "#17becf")
PAPER_MARKERS = {"ww09": "o", "elek10": "s", "ww-bati19": "D", "belcour-fwd": "^", "belcour-sym": "v",
                 "belcour-bati19": "P", "belcour-btdf": "^"}
FALLBACK_MARKERS = ("X", "*", "h", "<", ">", "p", "d", "8")
DISK_PX = 180          # top-view disk diameter (pixels)
ORDER_DISK_PX = 130    # bounce-order disk diameter
PANEL_GAP_PX = 8       # gap between the disks of a composed image (panels.compose)
#: significant digits of the colour-bar numbers handed to the page
LEGEND_DIGITS = 4


def model_style(names: Iterable[str]) -> dict[str, dict[str, str]]:
    """Colour and marker of every model: the paper's for its models, a fixed fallback palette
    (assigned in name order) for the others."""
    out: dict[str, dict[str, str]] = {}
    names = list(dict.fromkeys(names))   # given order, not a set's (the page would depend on the hash seed)
    others = sorted(n for n in names if n not in PAPER_COLOURS)
    for n in names:
        if n in PAPER_COLOURS:
            out[n] = {"colour": PAPER_COLOURS[n], "marker": PAPER_MARKERS.get(n, "o")}
    for i, n in enumerate(others):
        out[n] = {"colour": FALLBACK_COLOURS[i % len(FALLBACK_COLOURS)],
                  "marker": FALLBACK_MARKERS[i % len(FALLBACK_MARKERS)]}
    return out


@dataclass
class _Incident:
    """Everything the figures of one incident direction need."""

    m: int
    theta: float
    phi: float
    light: np.ndarray
    ref: np.ndarray            # (3, nt, nph) total reference
    ref_se: np.ndarray
    ref_internal: np.ndarray
    ref_internal_se: np.ndarray
    orders: np.ndarray         # (K, 3, nt, nph)
    mask: np.ndarray
    omega: np.ndarray
    models: dict[str, tuple[np.ndarray, np.ndarray]]   # (top, internal), each (3, nt, nph)


def _incidents(ref: SimulationResult, sd: SliceData, slices: dict, which: list[int]) -> Iterable[_Incident]:
    internal = sd.orders[:, 1:].astype(np.float64).sum(axis=1)
    se_int = sd.stderr_internal if sd.stderr_internal is not None else sd.stderr
    for m in which:
        th, ph = float(ref.theta_deg[m]), float(ref.phi_deg[m])
        yield _Incident(m, th, ph, light_direction(th, ph), sd.value[m], sd.stderr[m], internal[m], se_int[m],
                        sd.orders[m].astype(np.float64), sd.mask[m], sd.proj_solid_angle[m],
                        {n: (t[m], i[m]) for n, (t, i) in slices.items()})


def _figure_incidents(ref: SimulationResult, wanted: Sequence[float] | None) -> list[int]:
    if wanted is None:
        return list(range(len(ref.theta_deg)))
    return [m for m, t in enumerate(ref.theta_deg) if any(abs(float(t) - float(w)) < 1e-6 for w in wanted)]


def draw_material_figures(ref: SimulationResult, slices: dict[str, tuple[np.ndarray, np.ndarray]],
                          fig_dir: Path, rel: str, styles: dict, incidents: Sequence[float] | None,
                          standalone: bool = False, name: str | None = None, title: str | None = None) -> dict:
    """Draw every figure of one material into ``fig_dir``; returns their paths relative to the
    report (``rel`` is ``fig_dir`` relative to it) for the HTML: ``{"incidents": [...], "energy": ...}``.
    Files of incident direction m are named ``*_m<m>.png``. ``standalone`` (``gonio plot``, where
    no HTML page explains the images): files named ``*_theta<θ_l>_phi<φ_l>.png`` (degrees), and
    top views drawn as labelled figures (titles, colour bars, orientation; :func:`_labelled_top`).
    Otherwise the page draws the colour bars from each entry's ``legend`` / ``orders_legend`` and
    reads the hover values from ``hover.js`` (:mod:`models.report.hover`), registered under ``name``
    (default: the stack's name). ``title``: what the figure titles call the material (default: the
    stack's name)."""
    title = title or ref.stack.name
    side = comparison_side(ref.stack)
    sd = ref.brdf if side == "brdf" else ref.btdf
    entries, hover = [], []
    plane_fig = PlaneFigure(side, list(slices), styles, title, ref.settings.rays)
    for inc in _incidents(ref, sd, slices, _figure_incidents(ref, incidents)):
        tag = f"theta{inc.theta:g}_phi{inc.phi:g}" if standalone else f"m{inc.m}"
        plane = f"plane_{tag}.png"
        plane_values = plane_fig.draw(inc, sd.grid)
        save_figure(plane_fig.fig, fig_dir / plane)
        labels = (title, side) if standalone else None
        tops, diff_scale, lum_scale, rgb_scale = _top_views(inc, sd.grid, fig_dir, tag, labels)
        orders = f"orders_{tag}.png"
        top, bottom, orders_legend = _orders_panels(inc, sd.grid, rgb_scale)
        if standalone:
            save_figure(_labelled_orders(top, bottom, orders_legend, inc, title, side), fig_dir / orders)
        else:
            write_png(fig_dir / orders, compose([top, bottom], gap=PANEL_GAP_PX))
        entries.append({"index": inc.m, "theta": inc.theta, "phi": inc.phi, "plane": f"{rel}/{plane}",
                        "orders": f"{rel}/{orders}", "top": {k: f"{rel}/{v}" for k, v in tops.items()},
                        "diff_scale": diff_scale, "scale": lum_scale,
                        "legend": _legend(rgb_scale, lum_scale), "orders_legend": orders_legend})
        if not standalone:
            hover.append({**_hover_entry(inc, sd.grid), "plane": plane_values})
    save_figure(_energy_figure(ref, sd, side, title), fig_dir / "energy.png")
    out = {"incidents": entries, "energy": f"{rel}/energy.png", "orders_k": int(sd.orders.shape[1])}
    if not standalone:
        write_text(fig_dir / "hover.js", hover_script(name or ref.stack.name, side, hover))
        out["hover"] = f"{rel}/hover.js"
    return out


def _sig(x: float) -> float:
    """``x`` rounded to :data:`LEGEND_DIGITS` significant digits (colour-bar numbers)."""
    return float(f"{float(x):.{LEGEND_DIGITS - 1}e}")


def _legend(rgb_scale: float, lum_scale: float, factor: float = 1.0) -> dict:
    """The numbers of a view's colour bars: ``rgb_white``, the f (1/sr) at which an RGB channel
    saturates (``factor * g(f) = rgb_scale``); ``band_edges``, the luminance (1/sr) at the
    :data:`ISO_LEVELS` + 1 band edges (evenly spaced in g from 0 to ``lum_scale``), and ``g_top`` =
    ``lum_scale``."""
    edges = unremap(np.linspace(0.0, lum_scale, ISO_LEVELS + 1))
    return {"rgb_white": _sig(unremap(rgb_scale / factor)), "g_top": _sig(lum_scale),
            "band_edges": [_sig(e) for e in edges]}


def _hover_entry(inc: _Incident, grid: SliceGrid) -> dict:
    """The hover read-out data of one incident direction (:func:`models.report.hover.hover_incident`):
    the luminance of the reference, its standard error and each model's total, as the top views show."""
    pm = pixel_map(grid, inc.light, inc.mask, HOVER_PX)
    return hover_incident(pm, inc.theta, inc.phi, inc.m, _lum(inc.ref), _lum(inc.ref_se),
                          {n: _lum(t + i) for n, (t, i) in inc.models.items()})


def plot_file(path: str | Path, out_dir: str | Path, models: Sequence[str] | None = None,
              incidents: Sequence[float] | None = None, subcells: int = 5,
              isotropize: str | None = None) -> dict:
    """The per-material figures of the report for one simulated file, written into ``out_dir``.

    ``models``: names to draw beside the reference (``["all"]``: every model that supports the
    stack; None or empty: the reference alone), integrated onto the file's cells exactly as
    ``gonio evaluate`` does (``subcells``, ``isotropize``). ``incidents``: polar angles (degrees)
    of the file's incident directions to draw (None: all). A spectral file is drawn in linear sRGB
    (:meth:`SimulationResult.rgb`, ``docs/spectral.md`` section 4), which every figure title says.
    Returns ``{"figures": [paths], "evaluation": the gonio evaluate --json object or None}``, plus
    ``"reference"``, a note of what was drawn, for a spectral file. Raises ReportError for a bad
    file or an incident angle the file does not hold, ModelError for an unknown or unsupported model.
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ReportError(f"{out}: the output directory names an existing file (give a directory)")
    ref = read_reference(Path(path))
    if incidents is not None:
        have = [float(t) for t in ref.theta_deg]
        missing = [w for w in incidents if not any(abs(t - float(w)) < 1e-6 for t in have)]
        if missing:
            raise ReportError(f"{path}: no incident direction at theta = {', '.join(f'{w:g}' for w in missing)} deg "
                              f"(the file has {', '.join(f'{t:g}' for t in have)})")
    judged_side(ref, str(path))
    slices: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    doc = None
    if models:
        names = None if list(models) == ["all"] else list(models)
        ev = evaluate(ref, names, s=subcells, isotropize=isotropize)
        slices = {n: (ms.top, ms.internal) for n, ms in ev.slices.items()}
        doc = ev.to_json()   # evaluate judges a spectral reference in linear sRGB itself
    title, note = ref.stack.name, None
    if ref.settings.spectral:
        bins = ref.settings.wavelength_bins
        title = f"{ref.stack.name} (linear sRGB of {bins} wavelength bins)"
        note = (f"spectral file ({bins} wavelength bins) drawn in linear sRGB (D65, CIE 1931; docs/spectral.md "
                f"section 4); its standard errors are upper bounds")
        ref = ref.rgb()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ReportError(f"{out}: cannot create the output directory ({e.strerror or e})") from None
    figs = draw_material_figures(ref, slices, out, ".", model_style(list(slices)), incidents, standalone=True,
                                 title=title)
    paths = [out / "energy.png"]
    for e in figs["incidents"]:
        paths += [out / e["plane"], out / e["orders"]] + [out / t for t in e["top"].values()]
    r = {"figures": [str(p.resolve()) for p in paths], "evaluation": doc}
    if note is not None:
        r["reference"] = note
    return r


def _lum(cells: np.ndarray) -> np.ndarray:
    """Luminance of (3, ...) cell values (channel axis first, dropped)."""
    return luminance(cells, axis=0, keepdims=False)


#: upper bound drawn for a cell no path reached: 3 / (N Omega) is the 95 % upper limit of its value
#: (no hit among N rays of weight <= 1: the expected count N f Omega is below 3 at 95 %)
ZERO_HIT_BOUND = 3.0


class PlaneFigure:
    """The plane-of-incidence figure of one material, drawn for one incident direction after the
    other (:meth:`draw`): the figure, its axes, ticks, labels and legend are made once (they are the
    same for every incident direction of a material, and making them costs about as much as
    drawing the figure), each direction sets the curves, the band, the light's line, the y range
    and the title. What each direction's PNG shows is what a figure made for it alone would show
    (``tests/models/test_report_figures.py`` compares the pixels).

    The grey band is the reference +- 2 standard errors; where no path reached a cell (value 0,
    standard error 0: tiny cells near the pole of half slices at low ray counts) it spans
    [0, 3 / (N Omega)] instead, the 95 % upper limit, so an empty cell does not look like a
    confident zero. ``models``: the names drawn (every incident direction gives each a slice,
    :class:`_Incident`), coloured by ``styles``; ``rays``: N, the rays of a slice."""

    def __init__(self, side: str, models: Sequence[str], styles: dict, title: str, rays: int) -> None:
        from matplotlib.figure import Figure
        # (title, reference cells, their standard error, the model part drawn from (top, internal))
        if side == "brdf":
            self.parts = [("total", "ref", "ref_se", lambda t, i: t + i),
                          ("internal paths (order 1 / top lobe dropped)", "ref_internal", "ref_internal_se",
                           lambda t, i: i)]
        else:
            self.parts = [("BTDF", "ref", "ref_se", lambda t, i: t + i)]
        self.side, self.models, self.title, self.rays = side, list(models), title, rays
        width = 4.0 * len(self.parts) + 1.6
        fig = Figure(figsize=(width, 2.9), dpi=DPI)   # fixed layout: constrained layout costs ~0.3 s a figure
        fig.subplots_adjust(left=0.6 / width, right=1.0 - 1.55 / width, bottom=0.17, top=0.84, wspace=0.22)
        self.fig = fig
        self.axes = fig.subplots(1, len(self.parts), squeeze=False)[0]
        size = fig.get_size_inches() * DPI
        self.boxes, self.bands, self.curves, self.lights = [], [], [], []
        for ax, (label, _, _, _) in zip(self.axes, self.parts):
            self.bands.append(None)
            ref_line, = ax.plot([], [], "k--", lw=1.3, label="reference")
            model_lines = [ax.plot([], [], "-", color=styles.get(n, {"colour": "k"})["colour"], lw=1.1, label=n)[0]
                           for n in self.models]
            self.curves.append([ref_line, *model_lines])
            self.lights.append(ax.axvline(0.0, color="0.5", lw=0.6, ls=":"))
            ax.set_xlim(-90, 90)
            ax.set_xticks([-90, -60, -30, 0, 30, 60, 90])
            ax.set_xlabel("signed θ_v (deg), > 0 on the " + ("mirror" if side == "brdf" else "straight-through")
                          + " side", fontsize=8)
            ax.set_title(label, fontsize=9)
            ax.tick_params(labelsize=8)
            box = ax.get_position()
            self.boxes.append([box.x0 * size[0], (1.0 - box.y1) * size[1], box.width * size[0], box.height * size[1]])
        self.axes[0].set_ylabel("log(1 + √f), luminance", fontsize=8)
        self.legend = None
        self.suptitle = fig.suptitle("", fontsize=9)

    def draw(self, inc: _Incident, grid: SliceGrid) -> list[dict]:
        """Set the figure (:attr:`fig`) to the incident direction ``inc``; returns the values it
        plots, one entry per panel (for the hover read-out, :func:`models.report.hover.hover_plane`)."""
        if list(inc.models) != self.models:
            raise ValueError(f"plane figure of {self.models}: the incident direction has {list(inc.models)}")
        x, rows, cols = plane_cells(grid, inc.light, inc.phi, inc.mask)

        def along(cells: np.ndarray) -> np.ndarray:
            return 0.5 * (cells[rows, cols[:, 0]] + cells[rows, cols[:, 1]])

        bound = along(ZERO_HIT_BOUND / (max(self.rays, 1) * np.where(inc.omega > 0, inc.omega, np.inf)))
        values = []
        for k, (ax, (label, ref_name, se_name, pick)) in enumerate(zip(self.axes, self.parts)):
            lum = along(_lum(getattr(inc, ref_name)))
            se = along(_lum(getattr(inc, se_name)))
            upper = np.where(lum > 0, lum + 2 * se, bound)
            models = {n: along(_lum(pick(t, i))) for n, (t, i) in inc.models.items()}
            for line, y in zip(self.curves[k], [lum, *models.values()]):
                line.set_data(x, remap(y))
            self.lights[k].set_xdata([inc.theta, inc.theta])
            if self.bands[k] is not None:
                self.bands[k].remove()
            ax.relim()   # the curves' limits; the band adds its own (a Collection: not in relim before 3.9)
            self.bands[k] = ax.fill_between(x, remap(lum - 2 * se), remap(upper), color="0.8", lw=0,
                                            label="reference ±2σ\n(no hit: 95% bound)")
            values.append(hover_plane(label, self.boxes[k], ax.get_xlim(), x, lum, se, models))
        if self.legend is None:   # the band first, as when it was added first
            handles, labels = self.axes[0].get_legend_handles_labels()
            order = [len(handles) - 1, *range(len(handles) - 1)]
            self.legend = self.fig.legend([handles[j] for j in order], [labels[j] for j in order],
                                          loc="center right", fontsize=7, frameon=False)
        self.suptitle.set_text(f"{self.title}: plane of incidence, θ_l = {inc.theta:g}°, φ_l = {inc.phi:g}°")
        return values


def _top_views(inc: _Incident, grid: SliceGrid, fig_dir: Path, tag: str,
               labels: tuple[str, str] | None = None) -> tuple[dict[str, str], float, float, float]:
    """Reference and model top views, one PNG each with three disks: RGB, luminance isovalues and
    the signed difference of g(L) to the reference (for the reference: its 2-sigma noise), all
    on scales shared by the reference and the models. Returns file names, the difference scale,
    the luminance scale and the RGB scale (g units). ``labels`` = (material name, side): labelled
    figures instead of the bare disks the HTML report frames."""
    pm = pixel_map(grid, inc.light, inc.mask, DISK_PX)
    scale = exposure(np.max(remap(inc.ref), axis=0), inc.omega, inc.mask)
    lum_ref = _lum(inc.ref)
    lum_scale = exposure(remap(lum_ref), inc.omega, inc.mask)
    g_lum_ref = remap(pm.sample(lum_ref))
    totals = {n: t + i for n, (t, i) in inc.models.items()}
    lums = {"reference": lum_ref, **{n: _lum(cells) for n, cells in totals.items()}}
    diffs = {n: remap(pm.sample(lums[n])) - g_lum_ref for n in totals}
    allabs = np.concatenate([np.abs(d[np.isfinite(d)]) for d in diffs.values()]) if diffs else np.zeros(0)
    lim = float(np.percentile(allabs, 99)) if allabs.size else 0.0
    lim = max(lim, 1e-3 * lum_scale, 1e-12)
    noise = remap(pm.sample(lum_ref + 2.0 * _lum(inc.ref_se))) - g_lum_ref
    out = {}
    panels = {"reference": (inc.ref, noise), **{n: (cells, diffs[n]) for n, cells in totals.items()}}
    for name, (cells, third) in panels.items():
        a = mark_light(rgb_panel(cells, scale, pm), inc.light)
        b = mark_light(iso_panel(lums[name], lum_scale, pm), inc.light)
        c = mark_light(diverging_panel(third, lim, pm), inc.light)
        fname = f"top_{tag}_{safe_part(name)}.png"
        if labels is None:
            write_png(fig_dir / fname, compose([[a, b, c]], gap=PANEL_GAP_PX))
        else:
            save_figure(_labelled_top((a, b, c), name, inc, labels, lum_scale, lim), fig_dir / fname)
        out[name] = fname
    return out, lim, lum_scale, scale


def _labelled_top(panels: tuple[np.ndarray, np.ndarray, np.ndarray], name: str, inc: _Incident,
                  labels: tuple[str, str], lum_scale: float, lim: float):
    """The three top-view disks of one panel set as a matplotlib figure: titles, the colour bars
    of the luminance bands (g(L) = log(1 + sqrt L), 0 to the exposure ``lum_scale``) and of the
    difference (-lim to lim), and the orientation (+x, phi = 0, to the right; +y up; the ring marks
    the light direction l)."""
    from matplotlib import colors
    from matplotlib.cm import ScalarMappable
    from matplotlib.figure import Figure
    material, side = labels
    fig = Figure(figsize=(8.4, 3.3), dpi=DPI)
    fig.subplots_adjust(left=0.02, right=0.98, bottom=0.2, top=0.8, wspace=0.25)
    axes = fig.subplots(1, 3)
    third = "2σ noise of the reference: g(L + 2σ) − g(L)" if name == "reference" else "g(L) − g(L reference)"
    titles = ("RGB, g(f) = log(1 + √f), one exposure", "luminance g(L), bands", third)
    for ax, img, title in zip(axes, panels, titles):
        ax.imshow(img, interpolation="nearest")
        ax.set_title(title, fontsize=7.5)
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_xlabel("+x (φ = 0°) →", fontsize=7)
        ax.set_ylabel("+y (φ = 90°) →", fontsize=7)
    bands = colors.BoundaryNorm(np.linspace(0.0, lum_scale, ISO_LEVELS + 1), ISO_LEVELS)
    fig.colorbar(ScalarMappable(norm=bands, cmap=colormap("viridis").resampled(ISO_LEVELS)), ax=axes[1],
                 orientation="horizontal", fraction=0.06, pad=0.12, format="%.3g").ax.tick_params(labelsize=6)
    fig.colorbar(ScalarMappable(norm=colors.Normalize(-lim, lim), cmap=colormap("RdBu_r")), ax=axes[2],
                 orientation="horizontal", fraction=0.06, pad=0.12, format="%.3g",
                 ticks=[-lim, 0.0, lim]).ax.tick_params(labelsize=6)
    what = "BRDF seen from above" if side == "brdf" else "BTDF, lower hemisphere seen from above"
    fig.suptitle(f"{material} — {name}: {what}, θ_l = {inc.theta:g}°, φ_l = {inc.phi:g}°\n"
                 f"yellow ring: the light direction l; grey: cells outside the comparison mask; "
                 f"white in the bands: above the exposure", fontsize=8)
    return fig


def _orders_panels(inc: _Incident, grid: SliceGrid, scale: float) -> tuple[list[np.ndarray], list[np.ndarray],
                                                                          list[dict]]:
    """Figure 13: per bounce order (columns), RGB (orders >= 2 doubled, on the top views' RGB
    exposure ``scale``, :func:`_top_views`) over isovalues (each order exposed on its own range,
    see :func:`exposure`): the top and bottom rows of disks, and each column's colour-bar numbers
    (:func:`_legend`)."""
    pm = pixel_map(grid, inc.light, inc.mask, ORDER_DISK_PX)
    top, bottom, legends = [], [], []
    for k in range(inc.orders.shape[0]):
        cells = inc.orders[k]
        factor = 1.0 if k == 0 else 2.0
        top.append(mark_light(rgb_panel(cells, scale, pm, factor=factor), inc.light))
        lum = _lum(cells)
        lum_scale = exposure(remap(lum), inc.omega, inc.mask)
        bottom.append(mark_light(iso_panel(lum, lum_scale, pm), inc.light))
        legends.append({"order": k + 1, "factor": factor, **_legend(scale, lum_scale, factor)})
    return top, bottom, legends


def _labelled_orders(top: list[np.ndarray], bottom: list[np.ndarray], legends: list[dict], inc: _Incident,
                     material: str, side: str):
    """The bounce-order disks as a matplotlib figure (``gonio plot``): a title, one column per order
    (its RGB white point in 1/sr), the orientation of the views, and under each column the colour
    bar of its luminance bands in 1/sr (band edges evenly spaced in g(L) = log(1 + sqrt L))."""
    from matplotlib import colors
    from matplotlib.cm import ScalarMappable
    from matplotlib.figure import Figure
    k = len(top)
    fig = Figure(figsize=(1.75 * k + 1.2, 5.0), dpi=DPI, layout="constrained")
    axes = fig.subplots(2, k, squeeze=False)
    cmap = colormap("viridis").resampled(ISO_LEVELS)
    for c in range(k):
        lg = legends[c]
        last = "+" if c == k - 1 and k > 1 else ""
        doubled = " (RGB ×2)" if lg["factor"] != 1.0 else ""
        axes[0, c].set_title(f"order {lg['order']}{last}{doubled}\nRGB white at f = {lg['rgb_white']:.3g} sr⁻¹",
                             fontsize=7.5)
        for r, img in ((0, top[c]), (1, bottom[c])):
            ax = axes[r, c]
            ax.imshow(img, interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
        axes[1, c].set_xlabel("+x (φ = 0°) →", fontsize=7)
        edges = np.asarray(lg["band_edges"], dtype=float)
        if np.all(np.diff(edges) > 0):
            bar = fig.colorbar(ScalarMappable(norm=colors.BoundaryNorm(edges, ISO_LEVELS), cmap=cmap), ax=axes[1, c],
                               orientation="horizontal", fraction=0.08, pad=0.06, spacing="uniform",
                               ticks=[edges[0], edges[len(edges) // 2], edges[-1]], format="%.3g")
            bar.ax.tick_params(labelsize=6)
            bar.set_label("luminance L (sr⁻¹)", fontsize=6.5)
    axes[0, 0].set_ylabel("RGB, g(f) = log(1 + √f)\n+y (φ = 90°) →", fontsize=7)
    axes[1, 0].set_ylabel("luminance bands\n+y (φ = 90°) →", fontsize=7)
    what = "BRDF seen from above" if side == "brdf" else "BTDF, lower hemisphere seen from above"
    fig.suptitle(f"{material}: bounce orders of the reference, {what}, θ_l = {inc.theta:g}°, φ_l = {inc.phi:g}°\n"
                 f"each order on its own band scale; yellow ring: the light direction l; grey: cells outside the "
                 f"comparison mask; white in the bands: above the scale", fontsize=8, wrap=True)
    return fig


def order_energy(sd: SliceData) -> np.ndarray:
    """Luminance of the energy ``sum_cells f Omega`` per incident and bounce order, (M, K)."""
    lum = luminance(sd.orders.astype(np.float64), axis=2, keepdims=False)   # (M, K, nt, nph)
    return np.einsum("mkij,mij->mk", lum, sd.proj_solid_angle)


def _energy_figure(ref: SimulationResult, sd: SliceData, side: str, title: str | None = None):
    from matplotlib.figure import Figure
    e = order_energy(sd)
    K = e.shape[1]
    fig = Figure(figsize=(5.0, 2.6), dpi=DPI)
    fig.subplots_adjust(left=0.13, right=0.78, bottom=0.17, top=0.89)
    ax = fig.add_subplot()
    xs = np.arange(e.shape[0])
    bottom = np.zeros(e.shape[0])
    colours = colormap("viridis")(np.linspace(0.0, 0.9, K))
    for k in range(K):
        label = f"order {k + 1}" + ("+" if k == K - 1 else "")
        ax.bar(xs, e[:, k], bottom=bottom, color=colours[k], label=label, width=0.7)
        bottom += e[:, k]
    top = float(np.max(bottom)) if bottom.size else 0.0
    if np.isfinite(top) and top > 0:
        ax.set_ylim(0.0, 1.08 * top)   # the tallest stacked bar stays inside the axes
    ax.set_xticks(xs, [f"{t:g}°" for t in ref.theta_deg])
    ax.set_xlabel("θ_l", fontsize=8)
    ax.set_ylabel(("reflected" if side == "brdf" else "transmitted") + " energy (luminance)", fontsize=8)
    ax.tick_params(labelsize=8)
    ax.legend(fontsize=7, frameon=False, loc="center left", bbox_to_anchor=(1.0, 0.5))
    ax.set_title(f"{title or ref.stack.name}: energy per bounce order", fontsize=9)
    return fig


def material_figures(res: MaterialResult, ref: SimulationResult | None, out: Path, styles: dict,
                     incidents: Sequence[float] | None, report_key: str) -> bool:
    """Draw the material's figures unless its stamp says they are current; True if drawn."""
    rel_dir = Path("figures") / material_dir(res.material.name)
    fig_dir = out / rel_dir
    style_key = {n: styles[n] for n in res.evaluation["models"]}
    fkey = hashlib.sha256(json.dumps([res.key, report_key, None if incidents is None else sorted(incidents),
                                      style_key], sort_keys=True).encode()).hexdigest()[:20]
    stamp_path = fig_dir / "stamp.json"
    stamp = read_json(stamp_path)
    if stamp and stamp.get("key") == fkey and _files_exist(out, stamp.get("figures", {})):
        res.figures = stamp["figures"]
        return False
    if ref is None:
        ref = read_reference(res.material.path)
    if res.slices is None:
        res.slices = load_slices(cache_paths(out, res.material.name)[1], res.key, res.evaluation["models"])
        if res.slices is None:
            raise ReportError(f"{cache_paths(out, res.material.name)[1]}: unreadable cache; delete it and rerun")
    fig_dir.mkdir(parents=True, exist_ok=True)
    res.figures = draw_material_figures(ref, res.slices, fig_dir, rel_dir.as_posix(), styles, incidents,
                                        name=res.material.name)
    write_json(stamp_path, {"key": fkey, "figures": res.figures})
    return True


def _files_exist(out: Path, figures: dict) -> bool:
    paths = [figures.get("energy"), figures.get("hover", figures.get("energy"))]
    for inc in figures.get("incidents", []):
        paths += [inc.get("plane"), inc.get("orders"), *inc.get("top", {}).values()]
    return all(p and (out / p).is_file() for p in paths)
