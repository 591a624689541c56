"""Directional albedo of an analytic model: the hemispherical integral of ``f * |cos theta_v|``
(``docs/furnace.md``, "Directional albedo of a model").

For one light direction ``l`` and one side (``"brdf"``: ``v`` in the upper hemisphere,
``"btdf"``: ``v`` in the lower one),

    E_side(l) = Int_{hemisphere} f(l, v) |cos theta_v| d omega_v ,

``f`` without the cosine, in 1/sr (the :class:`models.base.Model` convention), so ``E`` is a
fraction of the incident flux. The integral is a product rule in the polar angle ``theta``
(measured from +z on the BRDF side, from -z on the BTDF side) and the azimuth ``phi``: composite
Gauss-Legendre on panels whose breakpoints are graded geometrically (ratio 2) about the direction
every lobe of a plane-parallel stack points at -- the mirror direction for the BRDF, the Snell
direction into the medium below for the BTDF -- down to a scale set by the smallest interface
roughness (:func:`lobe_scale`), with a panel end on the circle where a microfacet BTDF jumps
(:func:`transmission_horizon`), and no panel wider than ``max_panel`` elsewhere. The integrand
``f cos theta sin theta`` vanishes smoothly at the pole and the horizon, so the rule needs no
horizon clipping.

A perfectly smooth interface (roughness 0) has a Dirac lobe that models return as 0
(``docs/models.md`` section 1): it is not an integrable function, and :func:`smooth_interface`
names such an interface so that callers can refuse the stack.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from goniometer.stack import Interface, Stack
from models.base import Model, ModelFailure

#: Gauss-Legendre points per panel (default)
ORDER = 8
#: the widest panel anywhere (radians)
MAX_PANEL = math.pi / 16
#: the finest graded panel is this fraction of the smallest interface roughness (alpha)
SCALE_FRACTION = 1.0 / 16.0


@dataclass(frozen=True)
class HemisphereRule:
    """Quadrature nodes on one hemisphere: ``directions`` (N, 3) unit vectors (z > 0 for the
    BRDF side, z < 0 for the BTDF side) and ``weights`` (N,) in sr that include ``|cos theta|``:
    ``sum(weights * g(directions))`` approximates ``Int g |cos theta| d omega``."""

    directions: np.ndarray
    weights: np.ndarray


@lru_cache(maxsize=8)
def _gauss_legendre(order: int) -> tuple[np.ndarray, np.ndarray]:
    x, w = np.polynomial.legendre.leggauss(order)
    return x, w


def graded_breakpoints(lo: float, hi: float, centre: float, scale: float, max_panel: float,
                       extra: tuple[float, ...] = ()) -> np.ndarray:
    """Panel ends on ``[lo, hi]``: ``centre`` and ``centre +- scale * 2**k`` (k = 0, 1, ...) inside
    the interval and the ``extra`` points (known kinks or jumps of the integrand), then every panel
    wider than ``max_panel`` split evenly."""
    if not hi > lo:
        raise ValueError(f"graded_breakpoints: empty interval [{lo}, {hi}]")
    pts = {lo, hi} | {x for x in extra if lo < x < hi}
    if lo < centre < hi:
        pts.add(centre)
    d = scale
    while d < hi - lo:
        for x in (centre - d, centre + d):
            if lo < x < hi:
                pts.add(x)
        d *= 2.0
    ends = np.array(sorted(pts))
    out = [ends[0]]
    for a, b in zip(ends[:-1], ends[1:]):
        n = max(1, int(math.ceil((b - a) / max_panel - 1e-12)))
        out.extend(a + (b - a) * np.arange(1, n + 1) / n)
    return np.array(out)


def composite_gauss(breaks: np.ndarray, order: int) -> tuple[np.ndarray, np.ndarray]:
    """Nodes and weights of composite Gauss-Legendre with ``order`` points on every panel."""
    x, w = _gauss_legendre(order)
    a, b = breaks[:-1, None], breaks[1:, None]
    half = 0.5 * (b - a)
    return (0.5 * (a + b) + half * x).ravel(), (half * w).ravel()


def hemisphere_rule(centre_theta: float, centre_phi: float, scale: float, side: str = "brdf",
                    order: int = ORDER, max_panel: float = MAX_PANEL,
                    theta_breaks: tuple[float, ...] = ()) -> HemisphereRule:
    """A product rule on one hemisphere, graded about the direction (``centre_theta``,
    ``centre_phi``) (radians; theta from the side's pole) down to ``scale`` radians in theta and
    ``scale / sin(centre_theta)`` in phi, with panel ends at the polar angles ``theta_breaks``
    too (circles where the integrand jumps)."""
    if side not in ("brdf", "btdf"):
        raise ValueError(f"hemisphere_rule: side {side!r} is not brdf or btdf")
    half_pi = 0.5 * math.pi
    tb = graded_breakpoints(0.0, half_pi, min(max(centre_theta, 0.0), half_pi), scale, max_panel, theta_breaks)
    s_phi = scale / max(math.sin(centre_theta), 1e-300)
    pb = graded_breakpoints(centre_phi - math.pi, centre_phi + math.pi, centre_phi, min(s_phi, math.pi), max_panel)
    t, wt = composite_gauss(tb, order)
    p, wp = composite_gauss(pb, order)
    st, ct = np.sin(t), np.cos(t)
    sign = 1.0 if side == "brdf" else -1.0
    d = np.empty((t.size, p.size, 3))
    d[..., 0] = st[:, None] * np.cos(p)[None, :]
    d[..., 1] = st[:, None] * np.sin(p)[None, :]
    d[..., 2] = sign * ct[:, None]
    w = (wt * st * ct)[:, None] * wp[None, :]
    return HemisphereRule(d.reshape(-1, 3), w.ravel())


def smooth_interface(stack: Stack) -> int | None:
    """Index in ``stack.layers`` of the first perfectly smooth interface that scatters (a Dirac
    lobe), or None. An index-matched dielectric interface (relative index 1) is absent and does
    not count."""
    above = 1.0
    for i, x in enumerate(stack.layers):
        if not isinstance(x, Interface):
            continue
        matched = not x.is_conductor and x.ior[0] == above
        if min(x.alpha_xy) == 0.0 and not matched:
            return i
        above = x.ior[0]
    return None


def lobe_scale(stack: Stack) -> float:
    """The finest graded panel (radians): :data:`SCALE_FRACTION` of the smallest non-zero
    interface roughness; pi / 2 (no grading) for a stack without a rough interface."""
    alphas = [a for x in stack.interfaces for a in x.alpha_xy if a > 0.0]
    return SCALE_FRACTION * min(alphas) if alphas else 0.5 * math.pi


def lobe_centre(stack: Stack, light: np.ndarray, side: str) -> tuple[float, float]:
    """(theta, phi) in radians of the direction the lobes of ``side`` point at: the mirror
    direction (BRDF) or the Snell direction into the medium below the last interface (BTDF),
    theta from the side's pole; phi = phi_l + pi for both."""
    lz = float(np.clip(light[2], -1.0, 1.0))
    theta_l = math.acos(lz)
    phi = math.atan2(float(light[1]), float(light[0])) + math.pi
    if side == "brdf":
        return theta_l, phi
    last = stack.layers[-1]
    n = float(last.ior[0]) if isinstance(last, Interface) else 1.0
    return math.asin(min(1.0, math.sin(theta_l) / n)), phi


def transmission_horizon(stack: Stack, light: np.ndarray) -> tuple[float, ...]:
    """Polar angle (from -z, radians) of the circle where a single-interface microfacet BTDF
    jumps: its generalized half vector ``-(l + eta v)`` reaches the horizon when
    ``|cos theta_v| = cos theta_l / eta`` (``eta`` = index below the last interface, light from
    air). Empty when that circle does not exist (``eta <= cos theta_l``) or for an opaque stack."""
    last = stack.layers[-1]
    if not stack.transmits or not isinstance(last, Interface):
        return ()
    c = float(light[2]) / float(last.ior[0])
    return (math.acos(c),) if 0.0 < c < 1.0 else ()


def directional_albedo(model: Model, stack: Stack, light: np.ndarray, side: str, order: int = ORDER,
                       max_panel: float = MAX_PANEL) -> np.ndarray:
    """``E_side(l)`` of ``model`` for ``stack`` (RGB, shape (3,)): the integral of the model's
    total (top + internal) value times ``|cos theta_v|`` over the side's hemisphere. Raises
    :class:`ModelError` if the model refuses the stack or side, :class:`ModelFailure` if it fails or
    returns non-finite values."""
    light = np.asarray(light, dtype=np.float64).reshape(3)
    theta, phi = lobe_centre(stack, light, side)
    breaks = transmission_horizon(stack, light) if side == "btdf" else ()
    rule = hemisphere_rule(theta, phi, lobe_scale(stack), side, order, max_panel, breaks)
    value = model.evaluate(stack, light, rule.directions, side).total
    if not np.all(np.isfinite(value)):
        raise ModelFailure(model.name, f"produced non-finite values for {side} at l = {np.round(light, 6).tolist()}")
    return rule.weights @ value
