"""Polarization of a lit sphere (``gonio render --stokes``) and the polarimetric quantities that
``gonio plot`` draws too (``docs/polarization.md``, "Looking at a polarized file"; ``docs/render.md``).

* **White light, one number per quantity.** A file's channels (R, G, B, or a spectral run's
  linear sRGB) are combined with the Rec. 709 luminance weights ``w`` (:data:`models.compare.errors.LUMINANCE`):
  Stokes vectors of incoherent light add, so ``sum_c w_c S_c`` is the Stokes vector a
  luminance-response polarimeter sees under white light (and ``sum_c w_c M_c`` its Mueller matrix).
  Its standard error is bounded by ``sum_c w_c se_c`` (the channels share their paths; the bound
  holds whatever their correlation).
* **Enough signal** (:data:`SIGNAL_RULE`): a cell or pixel is drawn where the standard error of its
  intensity (``M00``, or ``S0``) is at most :data:`MAX_RELATIVE_STDERR` of it; the others are grey.
  An angle of linear polarization is drawn only where the degree of linear polarization exceeds
  twice its standard-error bound (:data:`AOLP_RULE`).
* **Unpolarized incident light**: ``S_out = M[:, 0]`` (the first column), the degree of polarization
  ``DOP = sqrt(S1² + S2² + S3²) / S0``, of linear polarization ``DOLP = sqrt(S1² + S2²) / S0``, the angle
  ``AOLP = ½ atan2(S2, S1)`` (degrees in (-90, 90], from the frame's x towards its y).
* **The camera's frame** (:data:`CAMERA_FRAME`): the sphere of ``models.render.sphere`` is seen by
  an orthographic camera on +z; the exit beam travels along ``k = +z``. Each pixel's Stokes vector,
  in the s/p frame of its exit beam (``x = normalize(n × v)`` in the pixel's local frame,
  ``docs/polarization.md`` §2), is turned about ``k`` into ``x = the image's horizontal axis (+x, to
  the right) projected perpendicular to k`` (here +x itself), ``y = k × x`` = the image's up:
  AOLP = 0° is horizontal polarization, +90° vertical, positive angles counter-clockwise as the
  image is seen (:func:`goniometer.grids.stokes.rotator`).
"""

from __future__ import annotations

import textwrap
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from goniometer.files import slices as store
from goniometer.grids.stokes import frame_x, rotator
from goniometer.run.results import SimulationResult
from models.compare.errors import LUMINANCE
from models.render.figure import fill, write_png
from models.render.reference import SLICES_FORMAT, SlicesBSDF, file_format, slices_reference
from models.render.sphere import BTDF, IRRADIANCE, RenderError, SphereView
from models.render.tonemap import EXPOSURE_RULE, display, exposure

#: a cell or pixel is drawn where se(intensity) <= this fraction of the intensity
MAX_RELATIVE_STDERR = 0.2
SIGNAL_RULE = (f"grey where the standard error of the intensity (M00, luminance-weighted; bounded by the sum of "
               f"the channels' weighted standard errors) exceeds {MAX_RELATIVE_STDERR:g} of it, or where no "
               f"light arrives")
AOLP_RULE = "AOLP drawn where DOLP exceeds twice its standard-error bound (elsewhere the angle is noise)"
CAMERA_FRAME = ("camera frame: x = the image's horizontal axis (+x, right) projected perpendicular to the line of "
                "sight, y = k × x (image up), k towards the camera; AOLP 0° = horizontal, counter-clockwise positive")
#: the colour maps: DOLP (sequential, [0, 1]) and AOLP (cyclic, degrees in [-90, 90])
DOLP_CMAP, AOLP_CMAP = "viridis", "twilight_shifted"
#: display value of sphere pixels without enough signal (or unlit) in the DOLP and AOLP panels
LOW_SIGNAL = 0.5


class NotPolarized(RenderError):
    """``--stokes`` on a file without Mueller matrices."""


def white(x: np.ndarray, se: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """The luminance-weighted sum over the channel axis ``axis`` of ``x`` and the bound
    ``sum_c w_c se_c`` of its standard error (module docstring); the axis is dropped."""
    w = np.asarray(LUMINANCE, dtype=np.float64)
    return np.moveaxis(x, axis, -1) @ w, np.abs(np.moveaxis(se, axis, -1)) @ w


def enough_signal(s0: np.ndarray, se0: np.ndarray) -> np.ndarray:
    """Where the intensity ``s0`` is positive with a standard error ``se0`` of at most
    :data:`MAX_RELATIVE_STDERR` of it (:data:`SIGNAL_RULE`); NaN is False."""
    with np.errstate(invalid="ignore"):
        return np.isfinite(s0) & np.isfinite(se0) & (s0 > 0.0) & (se0 <= MAX_RELATIVE_STDERR * s0)


def _ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0.0, num / np.where(den > 0.0, den, 1.0), np.nan)


def dop(s: np.ndarray) -> np.ndarray:
    """``sqrt(S1² + S2² + S3²) / S0`` of Stokes vectors ``s`` (..., 4); NaN where ``S0 <= 0``."""
    return _ratio(np.sqrt(np.sum(s[..., 1:] ** 2, axis=-1)), s[..., 0])


def dolp(s: np.ndarray) -> np.ndarray:
    """``sqrt(S1² + S2²) / S0`` of Stokes vectors ``s`` (..., 4); NaN where ``S0 <= 0``."""
    return _ratio(np.hypot(s[..., 1], s[..., 2]), s[..., 0])


def dolp_stderr(s: np.ndarray, se: np.ndarray) -> np.ndarray:
    """A first-order bound of the standard error of :func:`dolp`: ``(hypot(se1, se2) + DOLP se0) / S0``
    (``sqrt(S1² + S2²)`` moves by at most ``|(δS1, δS2)|``)."""
    return _ratio(np.hypot(se[..., 1], se[..., 2]) + np.nan_to_num(dolp(s)) * se[..., 0], s[..., 0])


def aolp_deg(s: np.ndarray) -> np.ndarray:
    """``½ atan2(S2, S1)`` in degrees, in (-90, 90], of Stokes vectors ``s`` (..., 4)."""
    return 0.5 * np.degrees(np.arctan2(s[..., 2], s[..., 1]))


def to_camera(s: np.ndarray, view: SphereView, l: np.ndarray, v: np.ndarray, lit: np.ndarray) -> np.ndarray:
    """Stokes vectors ``s`` (Q, 4) of the lit pixels (``lit`` among the disk's pixels; ``l``, ``v``
    their local directions), from the s/p frame of each exit beam to the camera's frame
    (:data:`CAMERA_FRAME`)."""
    t, b, n = (a[lit] for a in view.frames)
    phi_v = np.degrees(np.arctan2(v[:, 1], v[:, 0]))
    phi_l = np.degrees(np.arctan2(l[:, 1], l[:, 0]))
    x_local = frame_x("sp", l, v, phi_l, phi_v)[1]
    x_world = x_local[:, :1] * t + x_local[:, 1:2] * b + x_local[:, 2:] * n
    k = np.array([0.0, 0.0, 1.0])
    cam = np.array([1.0, 0.0, 0.0])
    cam = cam - (cam @ k) * k
    cam = np.broadcast_to(cam / np.linalg.norm(cam), x_world.shape)
    return (rotator(np.broadcast_to(k, x_world.shape), x_world, cam) @ s[..., None])[..., 0]


@dataclass
class StokesSphere:
    """A polarized file's reference on one sphere view: per disk pixel (row-major, ``view.inside``)
    the radiance RGB for unpolarized light, the white Stokes vector in the camera's frame, its
    standard-error bound; NaN where the reference has no value, 0 (and ``lit`` False) where unlit."""

    view: SphereView
    material: str
    description: str
    rgb: np.ndarray        # (P, 3) radiance f cos(theta_l) E of each channel
    stokes: np.ndarray     # (P, 4) white (luminance-weighted) Stokes radiance, camera frame
    stderr: np.ndarray     # (P, 4) its standard-error bound
    lit: np.ndarray        # (P,) bool

    @property
    def shown(self) -> np.ndarray:
        """Pixels with enough signal (:data:`SIGNAL_RULE`)."""
        return self.lit & enough_signal(self.stokes[:, 0], self.stderr[:, 0])

    @property
    def dolp(self) -> np.ndarray:
        """(P,) DOLP, NaN where not :attr:`shown`."""
        return np.where(self.shown, dolp(self.stokes), np.nan)

    @property
    def dolp_stderr(self) -> np.ndarray:
        """(P,) the bound of :attr:`dolp`'s standard error (:func:`dolp_stderr`), NaN where not shown."""
        return np.where(self.shown, dolp_stderr(self.stokes, self.stderr), np.nan)

    @property
    def aolp_deg(self) -> np.ndarray:
        """(P,) AOLP in degrees (camera frame), NaN where not shown (:data:`AOLP_RULE`)."""
        with np.errstate(invalid="ignore"):
            ok = self.shown & (self.dolp > 2.0 * self.dolp_stderr)
        return np.where(ok, aolp_deg(self.stokes), np.nan)

    def image(self, values: np.ndarray) -> np.ndarray:
        """(size, size, ...) image of per-disk-pixel ``values``, NaN outside the disk."""
        out = np.full((self.view.size, self.view.size) + values.shape[1:], np.nan)
        out[self.view.inside] = values
        return out

    def to_json(self) -> dict:
        """What ``gonio render --stokes --json`` prints."""
        no_value = ~np.isfinite(self.stokes[:, 0])
        d = self.dolp[np.isfinite(self.dolp)]
        return {"material": self.material, "reference": self.description, "side": self.view.side,
                "size": self.view.size, "light_angle_deg": self.view.light_angle_deg, "frame": CAMERA_FRAME,
                "signal_rule": SIGNAL_RULE, "aolp_rule": AOLP_RULE,
                "no_value_fraction": float(np.mean(no_value)), "shown_fraction": float(np.mean(self.shown)),
                "dolp_median": float(np.median(d)) if d.size else None,
                "dolp_max": float(np.max(d)) if d.size else None}


def polarized_result(path: str | Path) -> SimulationResult:
    """The polarized slices file ``path`` in linear sRGB; :class:`NotPolarized` for a scalar slices
    file or a tabulated one, RenderError for anything else unreadable."""
    fmt = file_format(path)
    if fmt != SLICES_FORMAT:
        raise NotPolarized(f"{path}: format {fmt or 'missing'!r} holds no Mueller matrices; polarization is drawn "
                           f"from a polarized slices file (gonio simulate --polarized)")
    try:
        result = store.read(path)
    except store.StoreError as e:
        raise RenderError(str(e)) from None
    if not result.settings.polarized:
        raise NotPolarized(f"{path}: a scalar file (no Mueller matrices); simulate it with --polarized to draw "
                           f"its polarization")
    return result.rgb()


def render_stokes(result: SimulationResult, view_size: int, light_angle_deg: float, where: str | None = None
                  ) -> StokesSphere:
    """The Stokes sphere of a polarized result: its compared side (as ``gonio render``) lit by
    unpolarized light, each pixel's first Mueller column interpolated like the intensity
    (:class:`models.render.reference.SlicesBSDF`) and turned into the camera's frame."""
    where = where or result.stack.name
    if not result.settings.polarized:
        raise NotPolarized(f"{where}: a scalar result (no Mueller matrices)")
    ref = slices_reference(result, where)
    sd = result.brdf if ref.side == "brdf" else result.btdf
    M, C = sd.mueller.shape[:2]
    nt, nph = sd.mueller.shape[2:4]
    column = np.moveaxis(sd.mueller[..., :, 0], -1, 2).reshape(M, C * 4, nt, nph)        # (M, C*4, ...)
    column_se = np.moveaxis(sd.mueller_stderr[..., :, 0], -1, 2).reshape(M, C * 4, nt, nph)
    lookup = SlicesBSDF(result, ref.side, np.concatenate([column, column_se], axis=1))
    view = SphereView(view_size, light_angle_deg, ref.side)
    lit, l, v = view.local
    got = lookup(l, v) if len(l) else np.zeros((0, 8 * C))
    cos_l = (l[:, 2] * IRRADIANCE)[:, None, None]
    s = got[:, :4 * C].reshape(-1, C, 4) * cos_l
    se = got[:, 4 * C:].reshape(-1, C, 4) * cos_l
    ws, wse = white(s, se, axis=1)
    P = len(lit)
    rgb, stokes, stderr = np.zeros((P, C)), np.zeros((P, 4)), np.zeros((P, 4))
    rgb[lit] = s[:, :, 0]
    stokes[lit] = to_camera(ws, view, l, v, lit)
    stderr[lit] = wse
    return StokesSphere(view, result.stack.name, ref.description, rgb, stokes, stderr, lit)


def _panel(sphere: StokesSphere, values: np.ndarray, lo: float, hi: float, cmap: str) -> np.ndarray:
    """An RGB image of per-pixel ``values`` in ``cmap`` over [lo, hi]: grey where not drawn, hatched
    where the reference has no value, the background outside the disk."""
    import matplotlib
    colours = matplotlib.colormaps[cmap](np.clip((np.nan_to_num(values) - lo) / (hi - lo), 0.0, 1.0))[:, :3]
    colours[~np.isfinite(values)] = LOW_SIGNAL
    colours[~np.isfinite(sphere.stokes[:, 0])] = np.nan
    return fill(sphere.image(colours), sphere.view.inside)


def stokes_figure(sphere: StokesSphere):
    """The figure: the radiance for unpolarized light (sRGB, exposed as ``gonio render``), the DOLP
    (colour bar [0, 1]) and the AOLP (cyclic colour bar, degrees, camera frame); title and caption."""
    from matplotlib import colors
    from matplotlib.cm import ScalarMappable
    from matplotlib.figure import Figure
    from matplotlib import colormaps as colormap
    view = sphere.view
    rgb_img = sphere.image(sphere.rgb)
    k = exposure(rgb_img, view.inside)
    panels = [(fill(display(rgb_img, k), view.inside), "radiance for unpolarized light (sRGB)"),
              (_panel(sphere, sphere.dolp, 0.0, 1.0, DOLP_CMAP), "DOLP = √(S1² + S2²) / S0"),
              (_panel(sphere, sphere.aolp_deg, -90.0, 90.0, AOLP_CMAP), "AOLP = ½ atan2(S2, S1)")]
    fig = Figure(figsize=(11.0, 5.0), dpi=100, facecolor="white")
    fig.subplots_adjust(left=0.02, right=0.98, bottom=0.27, top=0.78, wspace=0.12)
    axes = fig.subplots(1, 3)
    for ax, (img, title) in zip(axes, panels):
        ax.imshow(img, interpolation="nearest")
        ax.set_title(title, fontsize=9)
        ax.set_axis_off()
    bar = fig.colorbar(ScalarMappable(norm=colors.Normalize(0.0, 1.0), cmap=colormap[DOLP_CMAP]), ax=axes[1],
                       orientation="horizontal", fraction=0.05, pad=0.04)
    bar.set_label("degree of linear polarization (1)", fontsize=8)
    bar = fig.colorbar(ScalarMappable(norm=colors.Normalize(-90.0, 90.0), cmap=colormap[AOLP_CMAP]), ax=axes[2],
                       orientation="horizontal", fraction=0.05, pad=0.04, ticks=[-90, -45, 0, 45, 90])
    bar.set_label("angle of linear polarization (degrees, camera frame)", fontsize=8)
    what = ("BTDF, sphere backlit" if view.side == BTDF else "BRDF, light") + \
        f" at {view.light_angle_deg:g}° from the view"
    fig.suptitle("\n".join([f"{sphere.material}: polarization for unpolarized light, {what}",
                            "white light (Rec. 709 luminance of the channels); AOLP in the camera frame:",
                            *textwrap.wrap(CAMERA_FRAME[len("camera frame: "):], 110)]), fontsize=9)
    fig.text(0.02, 0.03, "\n".join([f"Reference: {sphere.description}; Stokes vectors from the s/p frames of "
                                    f"docs/polarization.md §2 turned into the camera frame.",
                                    f"DOLP and AOLP {SIGNAL_RULE}; {AOLP_RULE}.",
                                    f"Hatched: no value. Radiance: {EXPOSURE_RULE}."]),
             fontsize=7, color="0.25", va="bottom", wrap=True)
    return fig


def render_stokes_file(path: str | Path, out: str | Path, light_angle_deg: float = 30.0, size: int = 512
                       ) -> StokesSphere:
    """``gonio render --stokes``: the polarization of a polarized file's sphere, written as a PNG."""
    sphere = render_stokes(polarized_result(path), size, light_angle_deg, str(path))
    write_png(out, stokes_figure(sphere))
    return sphere


__all__ = ["AOLP_RULE", "CAMERA_FRAME", "MAX_RELATIVE_STDERR", "NotPolarized", "SIGNAL_RULE", "StokesSphere",
           "aolp_deg", "dolp", "dolp_stderr", "dop", "enough_signal", "polarized_result", "render_stokes",
           "render_stokes_file", "stokes_figure", "to_camera", "white"]
