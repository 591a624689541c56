"""The report's matplotlib figures are readable (models/report/tables.py, figures.py, furnace.py;
docs/report.md, figures): a log axis always has labelled ticks, the tallest energy bar stays inside
its axes, the furnace legend hides no curve, ``gonio plot``'s bounce orders are a labelled
figure, and the plane-of-incidence figure a material redraws for each incident direction is the one
drawn anew for it. Synthetic numbers: no simulation."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest


def _axes():
    from matplotlib.figure import Figure
    fig = Figure(figsize=(4, 3), dpi=100)
    return fig, fig.add_subplot()


@pytest.mark.parametrize("lo,hi", [(6.4e-3, 1.08e-2), (1.1e-2, 1.25e-2), (1.3e-3, 1.5e-2), (1e-5, 3.0)])
def test_a_log_axis_has_at_least_three_labelled_ticks(lo, hi):
    from models.report.tables import MIN_TICKS, log_ticks
    fig, ax = _axes()
    ax.plot([0, 1], [lo, hi], "o")
    ax.set_yscale("log")
    log_ticks(ax)
    y0, y1 = ax.get_ylim()
    ticks = [t for t in ax.get_yticks() if y0 <= t <= y1]
    labels = [ax.yaxis.get_major_formatter()(t) for t in ticks]
    assert len(ticks) >= MIN_TICKS and all(labels), (lo, hi, ticks)
    assert y0 <= lo and y1 >= hi, "the data stay inside the axis"


def test_the_tallest_energy_bar_is_inside_its_axes():
    from models.report.figures import _energy_figure, order_energy
    rng = np.random.default_rng(1)
    m, k, nt, nph = 7, 5, 3, 4
    orders = rng.uniform(0.0, 1.0, (m, k, 3, nt, nph))
    orders[-1] *= 4.0                    # the grazing incidence carries the most energy
    sd = SimpleNamespace(orders=orders, proj_solid_angle=np.full((m, nt, nph), 0.1))
    ref = SimpleNamespace(theta_deg=np.array([0, 15, 30, 45, 60, 70, 80.0]), stack=SimpleNamespace(name="x"))
    fig = _energy_figure(ref, sd, "brdf")
    ax = fig.axes[0]
    assert ax.get_ylim()[1] > 1.02 * order_energy(sd).sum(axis=1).max()


def test_the_furnace_legend_is_beside_the_curves():
    from models.report.furnace import furnace_figure
    import matplotlib.pyplot as plt
    t = np.arange(0.0, 90.0, 5.0)
    albedo = np.ones((len(t), 3))
    res = SimpleNamespace(material="m", incident_deg=t, albedo=albedo, stderr=0.01 * albedo, rays=1000, spectral=None,
                          models=SimpleNamespace(albedo={f"model{i}": albedo * (0.5 + 0.1 * i) for i in range(8)}))
    fig = furnace_figure(res)
    try:
        fig.canvas.draw()
        assert fig.legends and not any(a.get_legend() for a in fig.axes)
        box = fig.legends[0].get_window_extent()
        for ax in fig.axes:
            assert not box.overlaps(ax.get_window_extent()), "the legend covers a panel"
    finally:
        plt.close(fig)


def test_plot_orders_is_a_labelled_figure():
    from models.report.figures import _labelled_orders
    k, s = 3, 20
    panels = [np.full((s, s, 3), 0.3) for _ in range(k)]
    legends = [{"order": i + 1, "factor": 1.0 if i == 0 else 2.0, "rgb_white": 0.5, "g_top": 1.0,
                "band_edges": list(np.linspace(0.0, 2.0, 11))} for i in range(k)]
    inc = SimpleNamespace(theta=60.0, phi=0.0)
    fig = _labelled_orders(panels, panels, legends, inc, "metal/M1", "brdf")
    disks = [a for a in fig.axes if a.images]
    bars = [a for a in fig.axes if not a.images]
    assert "metal/M1" in fig.get_suptitle() and "θ_l = 60°" in fig.get_suptitle()
    assert len(disks) == 2 * k and len(bars) == k, "one colour bar per order"
    assert all("sr⁻¹" in a.get_xlabel() for a in bars)
    assert all(a.get_title().startswith(f"order {i + 1}") for i, a in enumerate(disks[:k]))
    assert disks[k].get_ylabel() and disks[-1].get_xlabel()


def _incident(m: int, theta: float, phi: float, scale: float, grid, models: tuple[str, ...], seed: int):
    """A synthetic incident direction of ``grid`` (values ``scale`` times a random field, some cells
    masked, one never reached) for :class:`models.report.figures.PlaneFigure`."""
    from goniometer.grids.slice_grid import light_direction
    from models.report.figures import _Incident
    rng = np.random.default_rng(seed)
    shape = (3,) + grid.shape

    def field():
        return scale * rng.uniform(0.1, 1.0, shape)

    ref, internal = field(), 0.5 * field()
    ref[:, 2, :] = 0.0                              # a ring of cells no path reached: the 95 % bound
    mask = rng.random(grid.shape) > 0.1
    return _Incident(m, theta, phi, light_direction(theta, phi), ref, 0.05 * ref, internal, 0.05 * internal,
                     np.stack([ref, internal]), mask, np.full(grid.shape, 1e-3 / scale),
                     {n: (0.8 * field(), 0.3 * field()) for n in models})


@pytest.mark.parametrize("side", ["brdf", "btdf"])
def test_a_plane_figure_drawn_again_is_the_figure_drawn_anew(side):
    """One PlaneFigure per material, redrawn for each incident direction: every PNG is, pixel for
    pixel, the figure made for that direction alone (curves, band, y range, light, title), and so
    are the values handed to the hover read-out."""
    from goniometer.grids.slice_grid import SliceGrid
    from models.report.figures import PlaneFigure, model_style
    from models.report.panels import figure_pixels
    grid = SliceGrid("classic", 18, 36, "reflection" if side == "brdf" else "transmission")
    models = ("ww09", "elek10", "my-model")
    styles = model_style(models)
    incs = [_incident(0, 0.0, 0.0, 1.0, grid, models, 1), _incident(1, 60.0, 90.0, 40.0, grid, models, 2),
            _incident(2, 30.0, 0.0, 0.01, grid, models, 3)]
    again = PlaneFigure(side, models, styles, "metal/M1", 1000)
    ylims = []
    for inc in incs:
        values = again.draw(inc, grid)
        got = figure_pixels(again.fig)
        ylims.append(again.axes[0].get_ylim())
        anew = PlaneFigure(side, models, styles, "metal/M1", 1000)
        assert values == anew.draw(inc, grid)
        np.testing.assert_array_equal(got, figure_pixels(anew.fig), err_msg=f"theta_l = {inc.theta}")
    assert len(set(ylims)) == 3, "the y range follows each direction"
    texts = [t.get_text() for t in again.legend.get_texts()]
    assert texts == ["reference ±2σ\n(no hit: 95% bound)", "reference", *models], "the band first, as before"
    assert "θ_l = 30°" in again.fig.get_suptitle() and len(again.axes) == (2 if side == "brdf" else 1)
    with pytest.raises(ValueError, match="plane figure of"):
        again.draw(_incident(3, 0.0, 0.0, 1.0, grid, models[:2], 4), grid)
