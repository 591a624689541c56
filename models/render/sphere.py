"""The lit sphere: pixels, normals, local frames and the shading of one directional light
(``docs/render.md``).

Conventions:

* Orthographic camera on the +z axis looking at a unit sphere centred at the origin; the image
  has ``size x size`` pixels over the square [-1, 1]^2, +x to the right, +y up. A pixel centre
  ``(x, y)`` inside the unit disk sees the sphere point with outward normal
  ``n = (x, y, sqrt(1 - x^2 - y^2))``; the view direction (towards the camera) is ``V = +z``.
* One directional light at ``light_angle_deg`` from the view direction, in the plane that holds the
  view direction and the sphere's vertical (+y): ``L = (0, sin a, cos a)`` (light above the
  camera). Slabs are shown in transmission (:data:`BTDF` view): the light is behind the sphere,
  ``L = (0, sin a, -cos a)``.
* Local frame of a pixel: tangent ``t = normalize(y x n)`` (along the sphere's parallels, +x at
  the centre of the image), bitangent ``b = n x t`` (along the meridians, upwards), normal ``n``.
  Isotropic BSDFs only depend on the normal; the tangent is stated for completeness.
* BRDF view: local ``l = (L.t, L.b, L.n)``, ``v = (V.t, V.b, V.n)``. BTDF view: each surface point
  is a sheet of the material whose top (first layer) faces into the sphere: the local frame is
  ``(t, -b, -n)``, so the light (behind the sphere) is on the top side and the viewer below.
* Radiance of a lit pixel: ``f(l, v) cos(theta_l) E`` with ``E`` = :data:`IRRADIANCE` (irradiance
  on a plane facing the light), no cosine in ``f`` (1/sr), RGB. Pixels whose light is below the
  local horizon are black; pixels outside the disk are not part of the sphere.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Callable

import numpy as np

#: the two views: reflection (BRDF, light on the camera's side) and transmission (BTDF, backlit)
BRDF, BTDF = "brdf", "btdf"
#: irradiance of the directional light on a plane facing it (arbitrary units: the exposure scales it)
IRRADIANCE = 1.0
#: allowed image sizes (pixels per side) and light angles (degrees from the view direction)
SIZE_RANGE = (16, 4096)
LIGHT_ANGLE_RANGE = (0.0, 90.0)

#: ``f(l, v)``: local light and view directions (N, 3) -> BSDF values (N, 3), 1/sr, no cosine;
#: NaN where the BSDF has no value (e.g. outside the recorded incident range of a file)
BSDF = Callable[[np.ndarray, np.ndarray], np.ndarray]


class RenderError(ValueError):
    """A rendering request that cannot be met (the message names the field and the allowed range)."""


@dataclass(frozen=True)
class SphereView:
    """A sphere image: ``size`` pixels per side, light at ``light_angle_deg`` from the view direction,
    ``side`` :data:`BRDF` (reflection) or :data:`BTDF` (backlit, transmission)."""

    size: int = 512
    light_angle_deg: float = 30.0
    side: str = BRDF

    def __post_init__(self) -> None:
        lo, hi = SIZE_RANGE
        if isinstance(self.size, bool) or not isinstance(self.size, (int, np.integer)) or not lo <= self.size <= hi:
            raise RenderError(f"size: {self.size!r} must be an integer in [{lo}, {hi}] pixels")
        a0, a1 = LIGHT_ANGLE_RANGE
        a = self.light_angle_deg
        if not isinstance(a, (int, float, np.floating)) or not np.isfinite(a) or not a0 <= a <= a1:
            raise RenderError(f"light angle: {a!r} must be in [{a0:g}, {a1:g}] degrees from the view direction")
        if self.side not in (BRDF, BTDF):
            raise RenderError(f"side: {self.side!r} is not one of {BRDF}, {BTDF}")

    # ------------------------------------------------------------------ geometry
    @cached_property
    def _pixels(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        c = (np.arange(self.size) + 0.5) / self.size * 2.0 - 1.0
        x = np.broadcast_to(c[None, :], (self.size, self.size))
        y = np.broadcast_to(-c[:, None], (self.size, self.size))
        return x, y, x * x + y * y < 1.0

    @property
    def inside(self) -> np.ndarray:
        """(size, size) bool: pixel centres on the sphere."""
        return self._pixels[2]

    @property
    def light(self) -> np.ndarray:
        """The light direction (towards the light) in camera space."""
        a = np.radians(self.light_angle_deg)
        return np.array([0.0, np.sin(a), np.cos(a) if self.side == BRDF else -np.cos(a)])

    @property
    def mirror_point(self) -> tuple[float, float] | None:
        """Image coordinates ``(x, y)`` (in [-1, 1], +y up) of the sphere point whose normal is halfway
        between the light and the view, ``normalize(L + V) = (0, sin(a/2), cos(a/2))``: where a
        reflected peak narrower than any grid is a point highlight. None for a :data:`BTDF` view (its
        straight-through peak ``v = -l`` reaches the camera only at ``a = 0``, and then everywhere)."""
        if self.side == BTDF:
            return None
        return 0.0, float(np.sin(0.5 * np.radians(self.light_angle_deg)))

    @cached_property
    def normals(self) -> np.ndarray:
        """(P, 3) outward normals of the pixels inside the disk (row-major order)."""
        x, y, inside = self._pixels
        xi, yi = x[inside], y[inside]
        return np.stack([xi, yi, np.sqrt(np.maximum(1.0 - xi * xi - yi * yi, 0.0))], axis=-1)

    @cached_property
    def frames(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(t, b, n), each (P, 3): the local frame of every pixel inside the disk, BTDF flip included."""
        n = self.normals
        t = np.stack([n[:, 2], np.zeros(len(n)), -n[:, 0]], axis=-1)   # y x n
        t /= np.linalg.norm(t, axis=-1, keepdims=True)                # |y x n| = sqrt(1 - n_y^2) > 0 inside
        b = np.cross(n, t)
        if self.side == BTDF:
            return t, -b, -n
        return t, b, n

    @cached_property
    def local(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(lit, l, v)``: which disk pixels the light reaches (P,) and their local light and view
        directions (lit pixels only, (Q, 3))."""
        t, b, n = self.frames
        L, V = self.light, np.array([0.0, 0.0, 1.0])
        l = np.stack([t @ L, b @ L, n @ L], axis=-1)
        v = np.stack([t @ V, b @ V, n @ V], axis=-1)
        lit = l[:, 2] > 0.0
        return lit, l[lit], v[lit]

    # ------------------------------------------------------------------ shading
    def shade(self, f: BSDF) -> np.ndarray:
        """(size, size, 3) linear radiance ``f(l, v) cos(theta_l) E`` of every pixel: 0 on unlit sphere
        pixels, NaN where ``f`` has no value and outside the disk."""
        return shade_views([self], f)[0]


def shade_views(views: list[SphereView], f: BSDF) -> list[np.ndarray]:
    """:meth:`SphereView.shade` of several views with one call of ``f`` on all their pixels (a model
    is then evaluated once per light node for every view)."""
    parts = [v.local for v in views]
    l = np.concatenate([p[1] for p in parts]) if parts else np.zeros((0, 3))
    v = np.concatenate([p[2] for p in parts]) if parts else np.zeros((0, 3))
    fv = np.asarray(f(l, v), dtype=np.float64).reshape(len(l), 3) if len(l) else np.zeros((0, 3))
    images, start = [], 0
    for view, (lit, lv, _) in zip(views, parts):
        values = np.zeros((len(lit), 3))
        values[lit] = fv[start:start + len(lv)] * (lv[:, 2] * IRRADIANCE)[:, None]
        start += len(lv)
        img = np.full((view.size, view.size, 3), np.nan)
        img[view.inside] = values
        images.append(img)
    return images
