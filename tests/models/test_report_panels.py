"""How the report writes its images (models/report/panels.py, geometry.py; docs/report.md): PNGs with
unfiltered rows that any reader decodes to the very pixels given, matplotlib figures encoded from
Agg's pixels as ``savefig`` would draw them, and top-view maps that sample and mark as the
straightforward indexing does. Synthetic images: no simulation."""

from __future__ import annotations

import io
import zlib

import numpy as np
import pytest
from PIL import Image

from goniometer.grids.slice_grid import SliceGrid, light_direction
from models.report.geometry import pixel_map
from models.png import PNG_SIGNATURE
from models.report.panels import DPI, figure_png, mark_light, png_bytes


def _decode(data: bytes) -> tuple[np.ndarray, dict]:
    img = Image.open(io.BytesIO(data))
    return np.asarray(img), img.info


@pytest.mark.parametrize("channels,mode", [(3, "RGB"), (4, "RGBA")])
def test_png_bytes_decode_to_the_pixels_given(channels, mode):
    rng = np.random.default_rng(3)
    img = rng.integers(0, 256, (17, 23, channels), dtype=np.uint8)
    img[:5] = 255                                   # flat rows, as the report's margins
    data = png_bytes(img, dpi=DPI)
    assert data[:8] == PNG_SIGNATURE
    got, info = _decode(data)
    assert Image.open(io.BytesIO(data)).mode == mode
    np.testing.assert_array_equal(got, img)
    assert info["dpi"] == pytest.approx((DPI, DPI), abs=0.01)
    assert "dpi" not in _decode(png_bytes(img))[1]
    # every row unfiltered: the inflated data is each row's filter byte 0 and then the row
    idat = data[data.index(b"IDAT") + 4:data.index(b"IEND") - 8]
    raw = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(17, 1 + 23 * channels)
    assert not raw[:, 0].any()
    np.testing.assert_array_equal(raw[:, 1:], img.reshape(17, -1))


@pytest.mark.parametrize("bad", [np.zeros((4, 4, 3)), np.zeros((4, 4), np.uint8), np.zeros((4, 4, 2), np.uint8),
                                 np.zeros((0, 4, 3), np.uint8)])
def test_png_bytes_refuses_what_is_not_an_8_bit_image(bad):
    with pytest.raises(ValueError, match=r"png_bytes: the image must be a non-empty \(H, W, 3 or 4\) uint8"):
        png_bytes(bad)


def _figure(facecolor: str = "white"):
    from matplotlib.figure import Figure
    fig = Figure(figsize=(3.2, 2.1), dpi=DPI, facecolor=facecolor)
    ax = fig.add_subplot()
    ax.plot([0, 1, 2], [0.3, 1.7, 0.9], "r-", lw=1.1, label="a model")
    ax.fill_between([0, 1, 2], [0.1, 1.2, 0.5], [0.6, 2.0, 1.1], color="0.8", lw=0)
    ax.set_title("θ_l = 60°, φ_l = 0°", fontsize=9)
    ax.legend(fontsize=7)
    return fig


def test_a_figure_is_the_pixels_savefig_draws():
    fig = _figure()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    want, _ = _decode(buf.getvalue())               # matplotlib's own PNG: RGBA
    got, info = _decode(figure_png(_figure()))
    assert got.shape == want.shape[:2] + (3,), "an opaque figure is written as RGB"
    assert (want[..., 3] == 255).all()
    np.testing.assert_array_equal(got, want[..., :3])
    assert info["dpi"] == pytest.approx((DPI, DPI), abs=0.01)


def test_a_transparent_figure_keeps_its_alpha():
    got, _ = _decode(figure_png(_figure("none")))
    assert got.shape[2] == 4 and (got[..., 3] < 255).any()


def test_a_figure_at_another_resolution_is_drawn_at_the_reports():
    fig = _figure()
    fig.set_dpi(50)
    got, _ = _decode(figure_png(fig))
    np.testing.assert_array_equal(got, _decode(figure_png(_figure()))[0])
    assert fig.dpi == 50, "the figure keeps its own resolution"


@pytest.mark.parametrize("lead", [(), (3,), (2, 3)])
def test_a_pixel_map_samples_the_cells_of_its_valid_pixels(lead):
    grid = SliceGrid("classic", 9, 36)
    rng = np.random.default_rng(5)
    mask = rng.random(grid.shape) > 0.2
    pm = pixel_map(grid, light_direction(60.0, 30.0), mask, 40)
    big = rng.random(lead + (9, 40))
    cells = big[..., :36]                           # not contiguous
    want = np.full(lead + (40, 40), np.nan)
    want[..., pm.ok] = cells[..., pm.ii[pm.ok], pm.jj[pm.ok]]
    for _ in range(2):                              # the second time from what the map kept
        np.testing.assert_array_equal(pm.sample(cells), want)
    assert pm.ok.any() and not pm.ok.all()


def test_the_light_ring_is_around_the_light_and_the_same_every_time():
    s = 80
    light = light_direction(40.0, 0.0)
    a = mark_light(np.ones((s, s, 3)), light)
    b = mark_light(np.ones((s, s, 3)), light)
    np.testing.assert_array_equal(a, b)
    yellow = np.argwhere(np.all(a == (1.0, 0.85, 0.0), axis=-1))
    cx, cy = (light[0] + 1.0) / 2.0 * s - 0.5, (1.0 - light[1]) / 2.0 * s - 0.5
    r = np.hypot(yellow[:, 1] - cx, yellow[:, 0] - cy)
    assert len(r) and r.min() >= 4.0 - 1.2 and r.max() <= 4.0 + 0.2
    assert (a[int(round(cy)), int(round(cx))] == 1.0).all(), "the value under the light stays visible"
    other = mark_light(np.ones((s, s, 3)), light_direction(40.0, 90.0))
    assert not np.array_equal(other, a)


def test_the_bands_are_viridis_and_white_above_the_scale():
    from models.report.geometry import remap
    from models.report.panels import ISO_LEVELS, band_colours, colormap, iso_panel
    np.testing.assert_array_equal(band_colours(ISO_LEVELS), colormap("viridis")(np.linspace(0, 1, ISO_LEVELS))[:, :3])
    grid = SliceGrid("classic", 6, 4)
    pm = pixel_map(grid, light_direction(0.0, 0.0), np.ones(grid.shape, bool), 60)
    scale = float(remap(1.0))
    for level, f in ((0, 0.0), (4, 0.15), (9, 0.97), (None, 5.0)):    # g(f) / g(1) in band `level`; 5: above
        img = iso_panel(np.full(grid.shape, f), scale, pm)
        centre = img[30, 30]
        want = np.ones(3) if level is None else band_colours(ISO_LEVELS)[level]
        assert level is None or int(np.floor(remap(f) / scale * ISO_LEVELS)) == level
        np.testing.assert_array_equal(centre, want)
