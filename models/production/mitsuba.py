"""``mitsuba-roughplastic`` and ``mitsuba-principled``: Mitsuba 3's own BSDFs, evaluated through
Mitsuba's Python API, with our stack mapped to their parameters (:class:`MitsubaRoughPlastic`,
:class:`MitsubaPrincipled`), so that the verdict is on the renderer's code.

Sources: the Mitsuba 3 plugin documentation and sources, ``src/bsdfs/roughplastic.cpp`` (class
``RoughPlastic``: GGX specular lobe + diffuse term ``diffuse / (1 - internal reflectance)`` scaled
by the rough transmittances in and out and ``1 / eta^2``) and ``src/bsdfs/principled.cpp``
(Burley 2012/2015 principled BSDF; its clearcoat lobe: GTR1 distribution of roughness
``lerp(0.1, 0.001, clearcoat_gloss)``, Schlick Fresnel with ``R0 = 0.04`` (index 1.5), separable
Smith GGX masking of roughness 0.25, weight ``clearcoat / 4``; helpers in ``principledhelpers.h``).
Mapping, refusals and findings: ``docs/production-models.md`` ("mitsuba-roughplastic,
mitsuba-principled").

Mitsuba is an optional dependency (``pip install mitsuba``): without it both models refuse every
stack with the reason "mitsuba not installed". The vectorised ``llvm_ad_rgb`` variant is used when
it evaluates a BSDF in a probe subprocess (its JIT can abort the process on some machines), the
``scalar_rgb`` variant otherwise (:func:`mitsuba_variant`); both compute in single precision.

Conventions (as :mod:`models.base`): ``l`` towards the light (``l_z > 0``), ``v`` towards the
viewer. Mitsuba's ``BSDF.eval(ctx, si, wo)`` returns the BSDF value **times the cosine of the
outgoing direction** ``wo``; it is called in importance mode with ``si.wi = l`` and ``wo = v``
(our flux-based convention) and divided by ``v_z`` here (:meth:`MitsubaBSDF.eval`), so the models
return values without the cosine, in 1/sr, RGB last. ``top`` is the lobe of the coat (roughplastic's
specular component, principled's clearcoat), ``internal`` the rest.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, Callable

import numpy as np

from goniometer import optics
from goniometer.stack import Stack
from models.base import CoatedBase, Model, ModelValue, coated_base

VECTORISED = "llvm_ad_rgb"
SCALAR = "scalar_rgb"
NOT_INSTALLED = "mitsuba not installed"
#: principled's clearcoat: Schlick R0 = 0.04 is the index 1.5, and the GTR1 roughness range
PRINCIPLED_COAT_IOR = 1.5
PRINCIPLED_ALPHA_GLOSSY = 0.001
PRINCIPLED_ALPHA_ROUGH = 0.1
#: principled clamps its main lobe's alpha = roughness^2 to at least this
PRINCIPLED_ALPHA_MIN = 0.001
#: how far a coat index may be from 1.5 and still count as principled's clearcoat
IOR_TOLERANCE = 1e-9

_PROBE = """
import mitsuba as mi, drjit as dr
mi.set_variant('llvm_ad_rgb')
b = mi.load_dict({'type': 'roughplastic', 'distribution': 'ggx'})
si = dr.zeros(mi.SurfaceInteraction3f, 2)
si.wi = mi.Vector3f([0.0, 0.6], [0.0, 0.0], [1.0, 0.8])
v = b.eval(mi.BSDFContext(), si, mi.Vector3f([0.0, 0.0], [0.0, 0.0], [1.0, 1.0]))
dr.eval(v)
print('ok', float(v[0][0]))
"""


@lru_cache(maxsize=1)
def mitsuba_module() -> Any | None:
    try:
        import mitsuba
    except ImportError:
        return None
    return mitsuba


@lru_cache(maxsize=1)
def vectorised_variant_works() -> bool:
    """Whether ``llvm_ad_rgb`` evaluates a BSDF, tried in a subprocess (a failing LLVM JIT aborts
    its process instead of raising); memoised per process."""
    mi = mitsuba_module()
    if mi is None or VECTORISED not in mi.variants():
        return False
    try:
        run = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=300)
    except (OSError, subprocess.TimeoutExpired):
        return False
    return run.returncode == 0 and run.stdout.startswith("ok")


def mitsuba_variant() -> str | None:
    """The Mitsuba variant the models use: ``llvm_ad_rgb`` where it works, else ``scalar_rgb``;
    None when Mitsuba (or both variants) is missing."""
    mi = mitsuba_module()
    if mi is None:
        return None
    if vectorised_variant_works():
        return VECTORISED
    return SCALAR if SCALAR in mi.variants() else None


#: Mitsuba's polarized variants, vectorised first (``docs/polarization.md``, "Models on polarized
#: files")
VECTORISED_POLARIZED = "llvm_ad_spectral_polarized"
SCALAR_POLARIZED = "scalar_spectral_polarized"
#: Mitsuba 3's BSDF plugins whose polarized ``eval`` carries polarization (the others depolarize:
#: mitsuba3#1512, #1625; mitsuba2#435); ``conductor`` and ``dielectric`` are smooth, so ``eval``
#: gives them no value off their delta directions
POLARIZING_PLUGINS = ("conductor", "roughconductor", "dielectric", "pplastic")
#: the C++ classes of those plugins (what a loaded BSDF's ``class_name()`` says)
POLARIZING_CLASSES = {"SmoothConductor": "conductor", "RoughConductor": "roughconductor",
                      "SmoothDielectric": "dielectric", "PolarizedPlastic": "pplastic"}

_PROBE_POLARIZED = """
import mitsuba as mi, drjit as dr
mi.set_variant('llvm_ad_spectral_polarized')
b = mi.load_dict({'type': 'roughconductor', 'distribution': 'ggx'})
si = dr.zeros(mi.SurfaceInteraction3f, 2)
si.wi = mi.Vector3f([0.0, 0.6], [0.0, 0.0], [1.0, 0.8])
si.wavelengths = mi.UnpolarizedSpectrum(610.0, 550.0, 465.0, 465.0)
v = b.eval(mi.BSDFContext(mi.TransportMode.Importance), si, mi.Vector3f([0.0, 0.0], [0.0, 0.0], [1.0, 1.0]))
dr.eval(v)
print('ok', float(v[0, 0][0][0]))
"""


@lru_cache(maxsize=1)
def vectorised_polarized_works() -> bool:
    """Whether ``llvm_ad_spectral_polarized`` evaluates a BSDF, tried in a subprocess as
    :func:`vectorised_variant_works`; memoised per process."""
    mi = mitsuba_module()
    if mi is None or VECTORISED_POLARIZED not in mi.variants():
        return False
    try:
        run = subprocess.run([sys.executable, "-c", _PROBE_POLARIZED], capture_output=True, text=True, timeout=300)
    except (OSError, subprocess.TimeoutExpired):
        return False
    return run.returncode == 0 and run.stdout.startswith("ok")


def mitsuba_polarized_variant() -> str | None:
    """The polarized Mitsuba variant polarized models use: ``llvm_ad_spectral_polarized`` where it
    works, else ``scalar_spectral_polarized``; None when Mitsuba or both variants are missing."""
    mi = mitsuba_module()
    if mi is None:
        return None
    if vectorised_polarized_works():
        return VECTORISED_POLARIZED
    return SCALAR_POLARIZED if SCALAR_POLARIZED in mi.variants() else None


def channel_wavelengths(stack: Stack) -> tuple[float, float, float]:
    """The wavelengths (nm) a spectral Mitsuba variant evaluates the three channels of ``stack``
    at: the stack's own (a wavelength triple of a spectral run), else where the RGB channels sit on
    the wavelength axis of the project's stated upsampling (R 610, G 550, B 465 nm,
    ``docs/rgl-format.md``)."""
    if stack.wavelengths_nm is not None:
        return tuple(float(x) for x in stack.wavelengths_nm)
    from goniometer.files.rgl_export import CHANNEL_NM
    return CHANNEL_NM


def plugin_name(bsdf: Any) -> str:
    """The plugin a loaded Mitsuba BSDF is: one of :data:`POLARIZING_PLUGINS` for their classes
    (:data:`POLARIZING_CLASSES`), else its C++ class name (``SmoothDiffuse`` for ``diffuse``)."""
    name = (bsdf.class_name() if hasattr(bsdf, "class_name") else str(bsdf).split("[", 1)[0]).strip()
    return POLARIZING_CLASSES.get(name, name)


class MitsubaBSDF:
    """One Mitsuba BSDF loaded from a plugin dictionary in ``variant`` (or from a file,
    :meth:`from_file`), evaluated without cosine."""

    def __init__(self, spec: dict, variant: str, *, _load: Callable[[Any], Any] | None = None) -> None:
        mi = mitsuba_module()
        if mi is None:
            raise ImportError(NOT_INSTALLED)
        self.variant = variant
        self.spec = spec
        previous = mi.variant()
        mi.set_variant(variant)
        try:
            self.bsdf = mi.load_dict(spec) if _load is None else _load(mi)
            if not isinstance(self.bsdf, getattr(mi, variant).BSDF):
                raise ValueError(f"the file holds a {type(self.bsdf).__name__}, not a BSDF")
        finally:
            if previous is not None:
                mi.set_variant(previous)
        self._types = getattr(mi, variant)

    @classmethod
    def from_file(cls, path: str | Path, variant: str) -> "MitsubaBSDF":
        """The BSDF of a Mitsuba 3 file: XML through ``mi.load_file``, JSON (a plugin dictionary)
        through ``mi.load_dict(json.load(...))``. Mitsuba's own errors are RuntimeError; a file
        that holds something else than a BSDF, or JSON that is not an object, is a ValueError."""
        path = Path(path)
        if path.suffix.lower() == ".json":
            try:
                spec = json.loads(path.read_text(encoding="utf-8"))
            except json.JSONDecodeError as e:
                raise ValueError(f"{path} is not JSON: {e}") from None
            if not isinstance(spec, dict):
                raise ValueError(f"{path} holds a JSON {type(spec).__name__}, not a plugin dictionary")
            return cls(spec, variant)
        return cls({"file": str(path)}, variant, _load=lambda mi: mi.load_file(str(path)))

    def eval(self, l: np.ndarray, v: np.ndarray, component: int | None = None, side: str = "brdf") -> np.ndarray:
        """``f(l, v)`` without cosine, shape ``v.shape[:-1] + (3,)``: Mitsuba's ``eval`` in importance
        mode with ``si.wi = l``, ``wo = v`` (all components, or only ``component``), divided by
        ``|v_z|``; 0 where ``l_z <= 0`` and for ``v`` outside the side's hemisphere (``v_z > 0`` for
        ``side="brdf"``, ``v_z < 0`` for ``"btdf"``, whose values are then flux based: importance mode)."""
        mi = mitsuba_module()
        shape = v.shape[:-1]
        vv = np.asarray(v, dtype=np.float64).reshape(-1, 3)
        out = np.zeros((vv.shape[0], 3))
        up = np.flatnonzero(vv[:, 2] > 0.0) if side == "brdf" else np.flatnonzero(vv[:, 2] < 0.0)
        if l[2] <= 0.0 or up.size == 0:
            return out.reshape(shape + (3,))
        if component is None:
            ctx = mi.BSDFContext(mi.TransportMode.Importance)
        else:
            ctx = mi.BSDFContext(mi.TransportMode.Importance, mi.BSDFFlags.All, component)
        t = self._types
        w = vv[up]
        if self.variant == VECTORISED:
            import drjit as dr
            n = w.shape[0]
            si = dr.zeros(t.SurfaceInteraction3f, n)
            si.wi = t.Vector3f(np.full(n, l[0]), np.full(n, l[1]), np.full(n, l[2]))
            value = self.bsdf.eval(ctx, si, t.Vector3f(w[:, 0], w[:, 1], w[:, 2]))
            vals = np.column_stack([np.asarray(value[i], dtype=np.float64) for i in range(3)])
        else:
            si = t.SurfaceInteraction3f()
            si.wi = t.Vector3f(float(l[0]), float(l[1]), float(l[2]))
            vals = np.empty((w.shape[0], 3))
            for k in range(w.shape[0]):
                vals[k] = self.bsdf.eval(ctx, si, t.Vector3f(w[k, 0], w[k, 1], w[k, 2]))
        out[up] = vals / np.abs(w[:, 2:3])
        return out.reshape(shape + (3,))

    def eval_mueller(self, l: np.ndarray, v: np.ndarray, wavelengths_nm: tuple[float, float, float],
                     side: str = "brdf") -> np.ndarray:
        """The Mueller matrices ``v.shape[:-1] + (3, 4, 4)`` of a BSDF loaded in a polarized
        variant, without cosine, in Mitsuba 3's ``stokes_basis`` frames (``"mitsuba"`` of
        :mod:`goniometer.grids.stokes`): ``eval`` in importance mode with ``si.wi = l``, ``wo = v``
        (the light arriving along ``-l``, leaving along ``v``), divided by ``|v_z|``; channel ``c``
        is the spectral entry evaluated at ``wavelengths_nm[c]`` (one call for the three). 0 where
        :meth:`eval` gives 0 (``l_z <= 0``, ``v`` off the side's hemisphere)."""
        mi = mitsuba_module()
        shape = v.shape[:-1]
        vv = np.asarray(v, dtype=np.float64).reshape(-1, 3)
        out = np.zeros((vv.shape[0], 3, 4, 4))
        up = np.flatnonzero(vv[:, 2] > 0.0) if side == "brdf" else np.flatnonzero(vv[:, 2] < 0.0)
        if l[2] <= 0.0 or up.size == 0:
            return out.reshape(shape + (3, 4, 4))
        ctx = mi.BSDFContext(mi.TransportMode.Importance)
        t = self._types
        w = vv[up]
        lam = [float(x) for x in wavelengths_nm]
        lam4 = t.UnpolarizedSpectrum(lam[0], lam[1], lam[2], lam[2])
        if self.variant == VECTORISED_POLARIZED:
            import drjit as dr
            n = w.shape[0]
            si = dr.zeros(t.SurfaceInteraction3f, n)
            si.wi = t.Vector3f(np.full(n, l[0]), np.full(n, l[1]), np.full(n, l[2]))
            si.wavelengths = lam4
            value = self.bsdf.eval(ctx, si, t.Vector3f(w[:, 0], w[:, 1], w[:, 2]))
            vals = np.empty((n, 3, 4, 4))
            for i in range(4):
                for j in range(4):
                    for c in range(3):
                        vals[:, c, i, j] = np.asarray(value[i, j][c], dtype=np.float64)
        else:
            si = t.SurfaceInteraction3f()
            si.wi = t.Vector3f(float(l[0]), float(l[1]), float(l[2]))
            si.wavelengths = lam4
            vals = np.empty((w.shape[0], 3, 4, 4))
            for k in range(w.shape[0]):
                a = np.asarray(self.bsdf.eval(ctx, si, t.Vector3f(w[k, 0], w[k, 1], w[k, 2])), dtype=np.float64)
                vals[k] = np.moveaxis(a[:, :, :3], -1, 0)          # (row, col, wavelength) -> (c, row, col)
        out[up] = vals / np.abs(w[:, 2])[:, None, None, None]
        return out.reshape(shape + (3, 4, 4))


    def delta_components(self, side: str = "brdf") -> list[int]:
        """The components of the BSDF that are Dirac lobes on ``side``: those whose flags hold
        ``DeltaReflection`` (``"brdf"``), or ``DeltaTransmission`` or ``Null`` (``"btdf"``: light
        that passes straight through, ``thindielectric``'s transmission); ``eval`` gives them no
        value (:meth:`delta_lobes`)."""
        mi = mitsuba_module()
        flag = (int(mi.BSDFFlags.DeltaReflection) if side == "brdf"
                else int(mi.BSDFFlags.DeltaTransmission) | int(mi.BSDFFlags.Null))
        return [c for c in range(self.bsdf.component_count()) if int(self.bsdf.flags(c)) & flag]

    def delta_lobes(self, l: np.ndarray, side: str = "brdf") -> list[tuple[np.ndarray, np.ndarray]]:
        """The Dirac lobes leaving on ``side`` for the light ``l``: ``(v, weight)`` per delta
        component (:meth:`delta_components`), ``v`` its unit direction (:func:`exact_direction`),
        ``weight`` (3,) RGB the fraction of the incident flux it carries: Mitsuba's ``sample`` in
        importance mode with ``si.wi = l``, restricted to that component (its ``pdf`` is then 1 and
        its weight ``f |cos theta_v| / pdf`` the lobe's reflectance or flux-based transmittance).
        Components that sample nothing (``pdf = 0``, e.g. ``l_z <= 0``) or off the side give none."""
        return [(v, w.reshape(3)) for v, w in self._sample_deltas(l, side, None)]

    def delta_lobes_mueller(self, l: np.ndarray, wavelengths_nm: tuple[float, float, float],
                            side: str = "brdf") -> list[tuple[np.ndarray, np.ndarray]]:
        """:meth:`delta_lobes` of a BSDF loaded in a polarized variant: ``(v, M)``, ``M`` (3, 4, 4)
        the Mueller matrix of the lobe's weight in Mitsuba's ``stokes_basis`` frames (those of
        :meth:`eval_mueller`), channel ``c`` at ``wavelengths_nm[c]``."""
        return self._sample_deltas(l, side, wavelengths_nm)

    def _sample_deltas(self, l: np.ndarray, side: str, wavelengths_nm) -> list[tuple[np.ndarray, np.ndarray]]:
        mi = mitsuba_module()
        l = np.asarray(l, dtype=np.float64).reshape(3)
        if l[2] <= 0.0:
            return []
        t = self._types
        vectorised = self.variant in (VECTORISED, VECTORISED_POLARIZED)
        polarized = wavelengths_nm is not None
        out = []
        for c in self.delta_components(side):
            ctx = mi.BSDFContext(mi.TransportMode.Importance, mi.BSDFFlags.All, c)
            if vectorised:
                import drjit as dr
                si = dr.zeros(t.SurfaceInteraction3f, 1)
                si.wi = t.Vector3f([float(l[0])], [float(l[1])], [float(l[2])])
                if polarized:
                    lam = [float(x) for x in wavelengths_nm]
                    si.wavelengths = t.UnpolarizedSpectrum(lam[0], lam[1], lam[2], lam[2])
                bs, weight = self.bsdf.sample(ctx, si, t.Float([0.5]), t.Point2f([0.5], [0.5]))
                wo = np.array([np.asarray(bs.wo[k], dtype=np.float64)[0] for k in range(3)])
                pdf = float(np.asarray(bs.pdf, dtype=np.float64)[0])
                if polarized:
                    w = np.array([[[np.asarray(weight[i, j][ch], dtype=np.float64)[0] for j in range(4)]
                                   for i in range(4)] for ch in range(3)])
                else:
                    w = np.array([np.asarray(weight[k], dtype=np.float64)[0] for k in range(3)])
            else:
                si = t.SurfaceInteraction3f()
                si.wi = t.Vector3f(float(l[0]), float(l[1]), float(l[2]))
                if polarized:
                    lam = [float(x) for x in wavelengths_nm]
                    si.wavelengths = t.UnpolarizedSpectrum(lam[0], lam[1], lam[2], lam[2])
                bs, weight = self.bsdf.sample(ctx, si, 0.5, t.Point2f(0.5, 0.5))
                wo = np.asarray(bs.wo, dtype=np.float64).reshape(3)
                pdf = float(bs.pdf)
                a = np.asarray(weight, dtype=np.float64)
                w = np.moveaxis(a[:, :, :3], -1, 0) if polarized else a.reshape(3)
            on_side = wo[2] > 0.0 if side == "brdf" else wo[2] < 0.0
            if pdf > 0.0 and on_side and np.all(np.isfinite(w)) and np.any(w != 0.0):
                out.append((exact_direction(l, wo), w))
        return out


#: how far a direction Mitsuba computes in single precision may lie from the double-precision
#: direction it stands for (:func:`exact_direction`)
SINGLE_PRECISION = 1e-5


def exact_direction(l: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """The double-precision direction a smooth interface's lobe ``wo`` (single precision, from
    Mitsuba) stands for, for the light ``l``: the mirror ``(-l_x, -l_y, l_z)`` when ``wo`` is it to
    :data:`SINGLE_PRECISION` (the direction our tracer gives a smooth reflection, bit for bit), ``-l``
    when ``wo`` is that (light passing straight through, ``thindielectric``'s transmission); a
    lobe in the plane of incidence on the far side of the normal (a refraction) gets the azimuth
    opposite ``l``'s exactly, ``v_xy = -l_xy |wo_xy| / |l_xy|``, and its own ``|v_z|``; a lobe along
    the normal is ``(0, 0, +-1)``; any other is ``wo`` normalised. On a cell border, the double-
    precision direction is binned where the tracer bins it (``docs/models.md`` §3, "Delta lobes")."""
    l = np.asarray(l, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    wo = wo / np.linalg.norm(wo)
    mirror = np.array([-l[0], -l[1], l[2]])
    if np.max(np.abs(wo - mirror)) <= SINGLE_PRECISION:
        return mirror + 0.0
    if np.max(np.abs(wo + l)) <= SINGLE_PRECISION:
        return -l + 0.0
    q, r = math.hypot(wo[0], wo[1]), math.hypot(l[0], l[1])
    if q <= SINGLE_PRECISION:
        return np.array([0.0, 0.0, math.copysign(1.0, wo[2])])
    if r > 0.0 and abs(l[0] * wo[1] - l[1] * wo[0]) <= SINGLE_PRECISION * r * q and l[0] * wo[0] + l[1] * wo[1] < 0.0:
        k = q / r
        return np.array([-l[0] * k, -l[1] * k, math.copysign(math.sqrt(max(0.0, 1.0 - q * q)), wo[2])]) + 0.0
    return wo + 0.0


def _rgb(values) -> dict:
    return {"type": "rgb", "value": [float(x) for x in values]}


class _MitsubaModel(Model):
    """What both Mitsuba models share: the variant, the per-stack memo of loaded BSDFs, the
    "mitsuba not installed" refusal and the checks of the coated-base structure."""

    sides = ("brdf",)
    #: isotropic roughplastic / principled (anisotropic 0): GGX and Fresnel of l, v and h only
    #: (Model.mirror_symmetric)
    mirror_symmetric = True

    def __init__(self) -> None:
        self._loaded: dict[Stack, tuple[MitsubaBSDF, ...]] = {}

    @property
    def variant(self) -> str | None:
        """The Mitsuba variant in use (:func:`mitsuba_variant`)."""
        return mitsuba_variant()

    def support_reason(self, stack: Stack) -> str | None:
        if self.variant is None:
            return NOT_INSTALLED
        cb = coated_base(stack)
        if cb is None:
            return "exactly [dielectric coat interface, optional medium, base] (a coat over a base)"
        if np.any(cb.tau > 0.0):
            return (f"no coat absorption (this stack's coat medium has optical_depth "
                    f"{[float(x) for x in cb.tau]})")
        top = stack.layers[0]
        if len(set(top.ior)) != 1:
            return f"one coat index for all channels (this coat has ior {list(top.ior)})"
        return self.coat_reason(cb)

    def coat_reason(self, cb: CoatedBase) -> str | None:
        """The model's own refusals, given the coated-base description."""
        raise NotImplementedError

    def bsdfs(self, stack: Stack) -> tuple[MitsubaBSDF, ...]:
        """The Mitsuba BSDFs of ``stack`` (memoised per model instance)."""
        got = self._loaded.get(stack)
        if got is None:
            got = tuple(MitsubaBSDF(spec, self.variant) for spec in self.specs(stack))
            self._loaded[stack] = got
        return got

    def specs(self, stack: Stack) -> list[dict]:
        """The Mitsuba plugin dictionaries of ``stack``."""
        raise NotImplementedError


class MitsubaRoughPlastic(_MitsubaModel):
    """Mitsuba 3's ``roughplastic`` (``src/bsdfs/roughplastic.cpp``) on a Lambertian base under a
    rough dielectric coat without absorption.

    Mapping: ``distribution = "ggx"``, ``alpha`` = coat roughness, ``int_ior`` = coat index,
    ``ext_ior = 1`` (the stack starts in air), ``diffuse_reflectance`` = the Lambertian albedo,
    ``nonlinear`` (default True: the base albedo enters the inter-reflection series
    ``rho / (1 - rho F_dr)`` as it does in the stack; False is Mitsuba's default
    ``rho / (1 - F_dr)``). ``top`` = component 0 (the specular lobe), ``internal`` = component 1
    (the diffuse term)."""

    name = "mitsuba-roughplastic"
    description = "Mitsuba 3 roughplastic (GGX coat over a diffuse base), evaluated by Mitsuba itself"

    def __init__(self, nonlinear: bool = True) -> None:
        super().__init__()
        self.nonlinear = bool(nonlinear)

    def coat_reason(self, cb: CoatedBase) -> str | None:
        if cb.base != "lambertian":
            return f"a Lambertian base only (roughplastic's diffuse term; this stack's base is a {cb.base})"
        if cb.alpha0 <= 0.0:
            return "a rough coat only (alpha = 0 is Mitsuba's smooth plastic, not roughplastic)"
        return None

    def specs(self, stack: Stack) -> list[dict]:
        cb = coated_base(stack)
        return [{"type": "roughplastic", "distribution": "ggx", "alpha": float(cb.alpha0),
                 "int_ior": float(cb.eta0), "ext_ior": 1.0, "diffuse_reflectance": _rgb(cb.rho),
                 "nonlinear": self.nonlinear, "sample_visible": True}]

    def _evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> ModelValue:
        (bsdf,) = self.bsdfs(stack)
        return ModelValue(bsdf.eval(l, v, component=0), bsdf.eval(l, v, component=1))


class MitsubaPrincipled(_MitsubaModel):
    """Mitsuba 3's ``principled`` (``src/bsdfs/principled.cpp``): base lobes + clearcoat.

    Coat: ``clearcoat = 1`` and ``clearcoat_gloss = (0.1 - alpha0) / 0.099`` (Mitsuba's GTR1
    roughness is ``lerp(0.1, 0.001, clearcoat_gloss)``; our coat roughness is taken as that
    roughness), coat index 1.5 only, ``alpha0`` in [0.001, 0.1]. Base:

    * conductor: ``metallic = 1``, ``roughness = sqrt(alpha1)`` (principled's alpha is
      roughness^2, at least 0.001), ``base_color`` = the conductor's Fresnel reflectance at normal
      incidence, relative to the coat (``base_color="coat"``, default: index
      ``(n1 + i k1) / 1.5``) or to air (``"air"``);
    * Lambertian: ``metallic = 0``, ``specular = 0`` (no dielectric lobe of its own: the coat is
      the clearcoat), ``roughness = 0`` (no retro-reflection), ``base_color`` = the albedo;
      principled's diffuse is then ``albedo / pi (1 - F_l / 2) (1 - F_v / 2)``,
      ``F = (1 - cos)^5``, not Lambertian.

    The base lobes are not attenuated by the clearcoat (principled adds the two).
    ``top`` = the clearcoat lobe (the full BSDF minus the same BSDF without clearcoat),
    ``internal`` = the base lobes."""

    name = "mitsuba-principled"
    description = "Mitsuba 3 principled BSDF (clearcoat over a metallic or diffuse base), evaluated by Mitsuba itself"

    def __init__(self, base_color: str = "coat") -> None:
        super().__init__()
        if base_color not in ("coat", "air"):
            raise ValueError(f"base_color must be 'coat' or 'air', got {base_color!r}")
        self.base_color = base_color

    def coat_reason(self, cb: CoatedBase) -> str | None:
        if abs(cb.eta0 - PRINCIPLED_COAT_IOR) > IOR_TOLERANCE:
            return f"coat index 1.5 only (principled's clearcoat has R0 = 0.04; this coat has ior {cb.eta0})"
        if not PRINCIPLED_ALPHA_GLOSSY <= cb.alpha0 <= PRINCIPLED_ALPHA_ROUGH:
            return (f"coat roughness in [{PRINCIPLED_ALPHA_GLOSSY}, {PRINCIPLED_ALPHA_ROUGH}] only (the range of "
                    f"clearcoat_gloss; this coat has alpha {cb.alpha0})")
        if cb.base == "conductor":
            if cb.alpha1 < PRINCIPLED_ALPHA_MIN:
                return f"base roughness >= {PRINCIPLED_ALPHA_MIN} only (principled clamps alpha; this base has {cb.alpha1})"
            return None
        if cb.base == "lambertian":
            return None
        return f"a conductor or Lambertian base only (this stack's base is a {cb.base})"

    @staticmethod
    def clearcoat_gloss(alpha0: float) -> float:
        """The ``clearcoat_gloss`` whose GTR1 roughness ``lerp(0.1, 0.001, gloss)`` is ``alpha0``."""
        return (PRINCIPLED_ALPHA_ROUGH - alpha0) / (PRINCIPLED_ALPHA_ROUGH - PRINCIPLED_ALPHA_GLOSSY)

    def base_parameters(self, cb: CoatedBase) -> dict:
        """Principled's base parameters for the base of ``cb`` (class docstring)."""
        if cb.base == "lambertian":
            return {"metallic": 0.0, "specular": 0.0, "roughness": 0.0, "base_color": _rgb(cb.rho)}
        outside = cb.eta0 if self.base_color == "coat" else 1.0
        f0 = [optics.fresnel_conductor(1.0, float(n) / outside, float(k) / outside)
              for n, k in zip(cb.eta1, cb.kappa1)]
        return {"metallic": 1.0, "roughness": math.sqrt(float(cb.alpha1)), "base_color": _rgb(f0)}

    def specs(self, stack: Stack) -> list[dict]:
        cb = coated_base(stack)
        base = {"type": "principled", **self.base_parameters(cb)}
        coat = {**base, "clearcoat": 1.0, "clearcoat_gloss": self.clearcoat_gloss(float(cb.alpha0))}
        return [coat, base]

    def _evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> ModelValue:
        coat, base = self.bsdfs(stack)
        internal = base.eval(l, v)
        return ModelValue(coat.eval(l, v) - internal, internal)
