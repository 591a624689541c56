"""Layer stacks: the TOML material contract of ``docs/material-format.md``, validation, canonical JSON.

A stack is listed top first and starts in air (index 1). Layer kinds:

* :class:`Interface` -- a GGX rough boundary; ``ior``/``extinction`` give the absolute complex
  index of the medium **below** it. ``extinction > 0`` in any channel makes a conductor
  (opaque, last layer). A dielectric's index is one real value for all channels.
* :class:`Medium` -- a homogeneous layer between two interfaces (or above a Lambertian base):
  ``optical_depth`` tau, the extinction optical depth at normal incidence (RGB);
  ``scattering_albedo`` (RGB, default 0) and the Henyey-Greenstein asymmetry ``g`` (default 0).
  Without scattering it absorbs by Beer-Lambert, factor ``exp(-tau / |cos theta|)`` per traversal.
* :class:`Lambertian` -- an opaque diffuse base of albedo ``rho`` (RGB), last layer.

An interface may carry a :class:`Film`: a thin film on every microfacet (Airy-summed reflection and
transmission, ``docs/material-format.md``, thin films); it needs a spectral stack
(``Stack.wavelengths_nm``).

Every error is a :class:`StackError` whose message names the file, the layer index and the field.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Union

import numpy as np

from goniometer.tomlfile import read_toml

RGB = tuple[float, float, float]
CATEGORIES = ("plastic", "metal", "slab", "other")
#: the base (``Stack.base``) each category requires; ``other`` goes with any stack
CATEGORY_BASE = {"plastic": "lambertian", "metal": "conductor", "slab": "transmit"}
_BASE_WORDS = {"lambertian": "a Lambertian base", "conductor": "a conductor interface",
               "transmit": "a dielectric interface (light leaves below)"}

#: most interfaces a stack may have (the tracer keeps the stack's tables in a fixed-size block on
#: the stack of its lane loop, ``docs/kernel.md``)
MAX_INTERFACES = 64


class StackError(ValueError):
    """An invalid material definition; the message names the file, layer and field."""


@dataclass(frozen=True)
class Film:
    """A thin film on an interface (``docs/material-format.md``, thin films): thickness
    ``thickness_nm`` >= 0 (nm) and the film's **absolute** complex index ``ior + i extinction`` per
    channel (``ior`` > 0, ``extinction`` >= 0). Every microfacet of the interface reflects and
    transmits with the film's Airy-summed amplitudes (:func:`goniometer.optics.film_rt`) between
    the region above and the medium below (a dielectric, or the conductor of a conductor
    interface). A film of thickness 0 is optically absent (:func:`pack` drops it)."""

    thickness_nm: float
    ior: RGB
    extinction: RGB = (0.0, 0.0, 0.0)

    def to_dict(self) -> dict[str, Any]:
        return {"thickness_nm": self.thickness_nm, "ior": list(self.ior), "extinction": list(self.extinction)}


@dataclass(frozen=True)
class Interface:
    """GGX rough interface. ``roughness`` is alpha in [0, 1] (0 = perfectly smooth) along the
    interface's tangent x axis; ``roughness_y`` (None = isotropic) along its y axis, the tangent
    frame being rotated by ``rotation_deg`` about z from the macro frame (x towards phi = 0).

    ``ior`` and ``extinction`` are the absolute index ``eta + i kappa`` of the medium below (RGB).
    ``multiple_scattering``: every event on the interface is a random walk on the GGX
    microsurface (Heitz et al. 2016; ``docs/material-format.md`` 2.1) instead of one microfacet
    reflection or refraction with a masking loss.
    """

    roughness: float
    ior: RGB
    extinction: RGB = (0.0, 0.0, 0.0)
    roughness_y: float | None = None
    rotation_deg: float = 0.0
    #: every event on the interface is a random walk on the microsurface (Heitz et al. 2016)
    multiple_scattering: bool = False
    #: a thin film on every microfacet (None: the bare interface)
    film: Film | None = None

    @property
    def is_conductor(self) -> bool:
        return max(self.extinction) > 0.0

    @property
    def is_anisotropic(self) -> bool:
        return self.roughness_y is not None and self.roughness_y != self.roughness

    @property
    def alpha_xy(self) -> tuple[float, float]:
        """GGX roughness along the interface's tangent x and y axes."""
        return (self.roughness, self.roughness if self.roughness_y is None else self.roughness_y)


@dataclass(frozen=True)
class Medium:
    """Homogeneous medium: ``optical_depth`` tau >= 0, the extinction (absorption + scattering)
    optical depth at normal incidence (RGB); ``scattering_albedo`` in [0, 1] (RGB), the fraction of
    extinction that scatters; ``g`` in (-1, 1), the Henyey-Greenstein asymmetry of the phase
    function. The defaults (no scattering) make a purely absorbing (Beer-Lambert) medium."""

    optical_depth: RGB
    scattering_albedo: RGB = (0.0, 0.0, 0.0)
    g: float = 0.0

    @property
    def scatters(self) -> bool:
        """True when light scatters in some channel (albedo > 0 where the optical depth is > 0)."""
        return any(a > 0.0 and t > 0.0 for a, t in zip(self.scattering_albedo, self.optical_depth))


@dataclass(frozen=True)
class Lambertian:
    """Opaque Lambertian base of albedo ``albedo`` in [0, 1] (RGB)."""

    albedo: RGB


Layer = Union[Interface, Medium, Lambertian]


@dataclass(frozen=True)
class Stack:
    """A validated layer stack (top first).

    ``wavelengths_nm``: the wavelengths (nm) of the three channels when the stack is one
    wavelength triple of a spectral run (``docs/spectral.md``); None for an RGB stack, whose
    channels are colours, not wavelengths."""

    name: str
    layers: tuple[Layer, ...]
    category: str = "other"
    wavelengths_nm: tuple[float, float, float] | None = None
    #: spectral definitions of the layers' per-channel fields, ``(layer index, field, spectrum)``
    #: with field one of :data:`SPECTRAL_FIELDS` and spectrum a ``goniometer.spectral`` object
    #: (``at(wavelength_nm)``); the field itself then holds the RGB equivalent of the spectrum
    #: (what an RGB run traces and the RGB models read, ``docs/spectral.md`` section 3)
    spectra: tuple[tuple[int, str, Any], ...] = ()

    def __post_init__(self) -> None:
        _validate_structure(self.layers, source="stack")

    @property
    def is_spectral(self) -> bool:
        """True when some layer field is defined by a spectrum (not only by an RGB triple)."""
        return bool(self.spectra)

    def spectrum(self, layer: int, field: str) -> Any:
        """The spectral definition of ``layers[layer].field``, or None (an RGB value)."""
        for i, f, sp in self.spectra:
            if i == layer and f == field:
                return sp
        return None

    def field_values(self, layer: int, field: str, wavelength_nm: np.ndarray) -> np.ndarray:
        """``layers[layer].field`` at ``wavelength_nm``: its spectrum, or its RGB value upsampled
        (:func:`goniometer.spectral.upsample_rgb`, ``docs/spectral.md`` section 3)."""
        from goniometer.spectral import upsample_rgb
        sp = self.spectrum(layer, field)
        if sp is not None:
            return np.asarray(sp.at(wavelength_nm), dtype=np.float64)
        x = self.layers[layer]
        for part in field.split("."):
            x = getattr(x, part)
        return np.asarray(upsample_rgb(tuple(x), wavelength_nm), dtype=np.float64)

    def dispersive(self, wavelength_nm: np.ndarray) -> bool:
        """True when a dielectric interface's index differs between the wavelengths
        ``wavelength_nm`` (such a stack is traced one wavelength per path, ``docs/spectral.md``)."""
        for i, x in enumerate(self.layers):
            if isinstance(x, Interface) and not x.is_conductor and self.spectrum(i, "ior") is not None:
                v = self.field_values(i, "ior", wavelength_nm)
                if np.any(v != v[0]):
                    return True
        return False

    def at_wavelengths(self, wavelength_nm: tuple[float, float, float]) -> "Stack":
        """The RGB-shaped stack whose three channels are the wavelengths ``wavelength_nm`` (nm):
        every per-channel field evaluated there (spectra interpolated, RGB values upsampled), and
        ``wavelengths_nm`` set. A dielectric interface needs one index for its three channels
        (StackError otherwise: trace a dispersive stack one wavelength at a time)."""
        w = np.asarray(wavelength_nm, dtype=np.float64)
        if w.shape != (3,):
            raise StackError(f"{self.name}: at_wavelengths needs three wavelengths, got {w.shape}")

        def val(i: int, field: str) -> RGB:
            v = self.field_values(i, field, w)
            return (float(v[0]), float(v[1]), float(v[2]))

        layers: list[Layer] = []
        for i, x in enumerate(self.layers):
            if isinstance(x, Interface):
                ior, ext = val(i, "ior"), val(i, "extinction")
                if not x.is_conductor and len(set(ior)) != 1:
                    raise StackError(f"{self.name}: layers[{i}].ior: a dielectric interface takes one index for "
                                     f"all channels; the wavelengths {list(w)} nm have {list(ior)}")
                changes: dict[str, Any] = {"ior": ior, "extinction": ext}
                film = getattr(x, "film", None)
                if film is not None:
                    changes["film"] = dataclasses.replace(film, ior=val(i, "film.ior"),
                                                          extinction=val(i, "film.extinction"))
                layers.append(dataclasses.replace(x, **changes))
            elif isinstance(x, Medium):
                layers.append(dataclasses.replace(x, optical_depth=val(i, "optical_depth"),
                                                  scattering_albedo=val(i, "scattering_albedo")))
            else:
                layers.append(Lambertian(val(i, "albedo")))
        return Stack(self.name, tuple(layers), self.category, (float(w[0]), float(w[1]), float(w[2])))

    def check_covers(self, lo_nm: float, hi_nm: float) -> None:
        """Raise StackError naming the first spectrum that does not cover [lo_nm, hi_nm]."""
        for i, f, sp in self.spectra:
            if not sp.covers(lo_nm, hi_nm):
                raise StackError(f"{self.name}: layers[{i}].{f}: the table covers {sp.wavelength_nm[0]:g}-"
                                 f"{sp.wavelength_nm[-1]:g} nm but the run's wavelength bins need {lo_nm:.1f}-"
                                 f"{hi_nm:.1f} nm (extend the table or use fewer, wider bins)")

    # ------------------------------------------------------------------ derived
    @property
    def interfaces(self) -> list[Interface]:
        return [x for x in self.layers if isinstance(x, Interface)]

    @property
    def is_anisotropic(self) -> bool:
        """Whether any interface has an anisotropic roughness (``alpha_x != alpha_y``)."""
        return any(x.is_anisotropic for x in self.interfaces)

    @property
    def transmits(self) -> bool:
        """True when the last layer is a dielectric interface (light can leave downward)."""
        last = self.layers[-1]
        return isinstance(last, Interface) and not last.is_conductor

    @property
    def base(self) -> str:
        """``"transmit"``, ``"conductor"`` or ``"lambertian"``."""
        last = self.layers[-1]
        if isinstance(last, Lambertian):
            return "lambertian"
        return "conductor" if last.is_conductor else "transmit"

    # ------------------------------------------------------------------ JSON
    def to_dict(self) -> dict[str, Any]:
        layers = []
        for x in self.layers:
            if isinstance(x, Interface):
                d: dict[str, Any] = {"type": "interface", "roughness": x.roughness}
                if x.is_anisotropic:
                    d["roughness"] = list(x.alpha_xy)
                    d["rotation_deg"] = x.rotation_deg
                if x.is_conductor:
                    d["ior"] = list(x.ior)
                    d["extinction"] = list(x.extinction)
                else:
                    d["ior"] = x.ior[0]
                # omitted at its default: a single-scattering interface keeps its old identity
                if x.multiple_scattering:
                    d["multiple_scattering"] = True
                # omitted without a film: a bare interface keeps its old identity
                if x.film is not None:
                    d["film"] = x.film.to_dict()
                layers.append(d)
            elif isinstance(x, Medium):
                d = {"type": "medium", "optical_depth": list(x.optical_depth)}
                # keys at their defaults are omitted: a non-scattering medium keeps its old identity
                if max(x.scattering_albedo) > 0.0:
                    d["scattering_albedo"] = list(x.scattering_albedo)
                if x.g != 0.0:
                    d["g"] = x.g
                layers.append(d)
            else:
                layers.append({"type": "lambertian", "albedo": list(x.albedo)})
        for i, f, sp in self.spectra:   # a spectral definition replaces the RGB equivalent it implies
            head, _, sub = f.partition(".")
            if sub:
                layers[i][head][sub] = sp.to_dict()
            else:
                layers[i][head] = sp.to_dict()
        return {"name": self.name, "category": self.category, "layers": layers}

    def with_multiple_scattering(self, on: bool = True) -> "Stack":
        """The same stack with ``multiple_scattering = on`` on every interface (``gonio simulate
        --multiple-scattering``); the canonical JSON, hence the recorded stack, shows it."""
        layers = tuple(dataclasses.replace(x, multiple_scattering=on) if isinstance(x, Interface) else x
                       for x in self.layers)
        return Stack(self.name, layers, self.category, self.wavelengths_nm, self.spectra)

    def to_json(self) -> str:
        """Canonical JSON: sorted keys, no whitespace, RGB lists, shortest float repr."""
        return json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))

    @classmethod
    def from_json(cls, text: str) -> "Stack":
        # files written before the category rule keep reading: no category check here
        return stack_from_dict(json.loads(text), source="json", check_category=False)

    def to_toml(self) -> str:
        """The material as a TOML file (``docs/material-format.md``)."""
        out = [f"name = {json.dumps(self.name)}", f"category = {json.dumps(self.category)}", ""]
        for d in self.to_dict()["layers"]:
            out.append("[[layers]]")
            for k, v in d.items():
                if isinstance(v, dict):
                    v = "{" + ", ".join(f"{a} = {json.dumps(b)}" for a, b in v.items()) + "}"
                    out.append(f"{k} = {v}")
                else:
                    out.append(f"{k} = {json.dumps(v)}")
            out.append("")
        return "\n".join(out)


# ---------------------------------------------------------------------- loading

_LAYER_KEYS = {
    "interface": {"type", "roughness", "ior", "extinction", "rotation_deg", "multiple_scattering", "conductor",
                  "film"},
    "medium": {"type", "optical_depth", "scattering_albedo", "g"},
    "lambertian": {"type", "albedo"},
}
_FILM_KEYS = {"thickness_nm", "ior", "extinction"}
_TOP_KEYS = {"name", "category", "layers", "simulation"}
SIMULATION_KEYS = {"incident_deg", "rays", "parametrization", "resolution", "seed", "masking",
                   "max_order", "threads", "first_order", "rgl_grid", "spectral", "wavelength_bins", "polarized"}


def load_toml(path: str | Path) -> tuple[Stack, dict[str, Any]]:
    """Load a material file. Returns the stack and its ``[simulation]`` table (possibly empty).

    Raises :class:`StackError` (with the file name) on any problem, including invalid TOML.
    """
    p = Path(path)
    data = read_toml(p, StackError)
    stack = stack_from_dict(data, source=str(p))
    sim = data.get("simulation", {})
    if not isinstance(sim, dict):
        raise StackError(f"{p}: simulation: must be a table")
    unknown = sorted(set(sim) - SIMULATION_KEYS)
    if unknown:
        raise StackError(f"{p}: simulation.{unknown[0]}: unknown key "
                         f"(allowed: {', '.join(sorted(SIMULATION_KEYS))})")
    return stack, dict(sim)


def load_stack(path: str | Path) -> Stack:
    """The stack of a material file (:func:`load_toml` without its ``[simulation]`` table)."""
    return load_toml(path)[0]


def validate_category(stack: Stack, source: str = "stack") -> None:
    """Raise :class:`StackError` if ``stack.category`` contradicts its last layer
    (:data:`CATEGORY_BASE`: a plastic ends on a Lambertian base, a metal on a conductor, a slab on
    a dielectric interface; ``docs/material-format.md``)."""
    want = CATEGORY_BASE.get(stack.category)
    if want is not None and stack.base != want:
        fits = [c for c, b in CATEGORY_BASE.items() if b == stack.base]
        raise StackError(f"{source}: category: {stack.category!r} needs the last layer to be {_BASE_WORDS[want]}, "
                         f"but this stack ends on {_BASE_WORDS[stack.base]} (use category "
                         f"{' or '.join(repr(c) for c in fits + ['other'])})")


def stack_from_dict(data: dict[str, Any], source: str = "stack", check_category: bool = True) -> Stack:
    """Build and validate a :class:`Stack` from the TOML/JSON structure (``check_category``:
    also refuse a category that contradicts the stack, see :func:`validate_category`, and a ``g``
    given to a medium that does not scatter, which would be recorded and do nothing; both are
    checks of what a user writes: a stack's canonical JSON, read back, skips them)."""
    if not isinstance(data, dict):
        raise StackError(f"{source}: the material must be a table")
    unknown = sorted(set(data) - _TOP_KEYS)
    if unknown:
        raise StackError(f"{source}: {unknown[0]}: unknown key (allowed: {', '.join(sorted(_TOP_KEYS))})")
    name = data.get("name")
    if not isinstance(name, str) or not name.strip():
        raise StackError(f"{source}: name: required, a non-empty string")
    category = data.get("category", "other")
    if category not in CATEGORIES:
        raise StackError(f"{source}: category: {category!r} is not one of {', '.join(CATEGORIES)}")
    raw_layers = data.get("layers")
    if not isinstance(raw_layers, list) or not raw_layers:
        raise StackError(f"{source}: layers: required, a non-empty array of tables ([[layers]])")
    spectra: list[tuple[int, str, Any]] = []
    layers = tuple(_layer_from_dict(d, i, source, spectra) for i, d in enumerate(raw_layers))
    _validate_structure(layers, source)
    stack = Stack(name=name, layers=layers, category=category, spectra=tuple(spectra))
    if check_category:
        validate_category(stack, source)
        for i, (d, x) in enumerate(zip(raw_layers, layers)):
            if isinstance(x, Medium) and x.g != 0.0 and max(x.scattering_albedo) == 0.0:
                raise StackError(f"{source}: layers[{i}].g: only a scattering medium takes g; add "
                                 f"scattering_albedo in (0, 1] (or remove g: a medium without scattering_albedo "
                                 f"only absorbs)")
    return stack


def _layer_from_dict(d: Any, i: int, source: str, spectra: list | None = None) -> Layer:
    """One layer; the spectral definitions of its fields are appended to ``spectra`` as
    ``(i, field, spectrum)``."""
    where = f"{source}: layers[{i}]"
    found: list[tuple[str, Any]] = []
    if not isinstance(d, dict):
        raise StackError(f"{where}: must be a table")
    kind = d.get("type")
    if kind not in _LAYER_KEYS:
        raise StackError(f"{where}.type: {kind!r} is not one of interface, medium, lambertian")
    unknown = sorted(set(d) - _LAYER_KEYS[kind])
    misplaced = [x for x in unknown if x in _LAYER_KEYS["medium"]]
    if "multiple_scattering" in unknown:
        raise StackError(f"{where}.multiple_scattering: only an interface layer takes multiple_scattering "
                         f"(this layer is a {kind})")
    if misplaced:
        raise StackError(f"{where}.{misplaced[0]}: only a medium layer takes {misplaced[0]} "
                         f"(this layer is {'an' if kind == 'interface' else 'a'} {kind})")
    if unknown:
        raise StackError(f"{where}.{unknown[0]}: unknown key for a {kind} layer "
                         f"(allowed: {', '.join(sorted(_LAYER_KEYS[kind]))})")
    if kind == "interface":
        rough, rough_y, rotation = _roughness(d, where)
        if "conductor" in d:
            d = _named_conductor(d, where)
        ext = _rgb(d, "extinction", where, lo=0.0, default=0.0, spectra=found)
        dielectric = max(ext) <= 0.0
        ior = _rgb(d, "ior", where, positive=True, spectra=found, index=dielectric)
        if spectra is not None:
            spectra.extend((i, f, sp) for f, sp in found)
        if dielectric and len(set(ior)) != 1:
            raise StackError(f"{where}.ior: a dielectric interface takes one index for all channels "
                             f"(got {list(ior)}); an RGB index needs extinction > 0 (a conductor)")
        ms = d.get("multiple_scattering", False)
        if not isinstance(ms, bool):
            raise StackError(f"{where}.multiple_scattering: {ms!r} is not a boolean (true or false)")
        film = _film(d["film"], f"{where}.film", spectra, i) if "film" in d else None
        return Interface(roughness=rough, ior=ior, extinction=ext, roughness_y=rough_y, rotation_deg=rotation,
                         multiple_scattering=ms, film=film)
    if kind == "medium":
        albedo = _rgb(d, "scattering_albedo", where, lo=0.0, hi=1.0, default=0.0, spectra=found)
        g = _number(d["g"], f"{where}.g") if "g" in d else 0.0
        _check_g(g, f"{where}.g")
        tau = _rgb(d, "optical_depth", where, lo=0.0, spectra=found)
        if spectra is not None:
            spectra.extend((i, f, sp) for f, sp in found)
        return Medium(optical_depth=tau, scattering_albedo=albedo, g=g)
    albedo = _rgb(d, "albedo", where, lo=0.0, hi=1.0, spectra=found)
    if spectra is not None:
        spectra.extend((i, f, sp) for f, sp in found)
    return Lambertian(albedo=albedo)


def _named_conductor(d: dict, where: str) -> dict:
    """``conductor = "Au"``: the interface table with the named measured ``ior`` and
    ``extinction`` spectra (``goniometer.spectral.named_conductor``)."""
    from goniometer.spectral import NAMED_CONDUCTORS, SpectrumError, named_conductor
    name = d["conductor"]
    clash = [k for k in ("ior", "extinction") if k in d]
    if clash:
        raise StackError(f"{where}.conductor: gives ior and extinction itself; remove {clash[0]}")
    if not isinstance(name, str) or name not in NAMED_CONDUCTORS:
        raise StackError(f"{where}.conductor: {name!r} is not a named conductor (known: {', '.join(NAMED_CONDUCTORS)})")
    try:
        eta, k = named_conductor(name, f"{where}.conductor")
    except SpectrumError as e:
        raise StackError(str(e)) from None
    out = {key: v for key, v in d.items() if key != "conductor"}
    out["ior"], out["extinction"] = eta, k
    return out


def _film(d: Any, where: str, spectra: list | None = None, layer: int = 0) -> Film:
    """The ``film`` table of an interface: ``thickness_nm`` (>= 0), ``ior`` (RGB, > 0) and
    ``extinction`` (RGB, >= 0, default 0), the film's absolute index; ``ior`` and ``extinction``
    may be spectral tables (appended to ``spectra`` as ``film.ior``, ``film.extinction`` of
    ``layer``)."""
    if not isinstance(d, dict):
        raise StackError(f"{where}: must be a table, e.g. {{thickness_nm = 350, ior = 1.33}}")
    unknown = sorted(set(d) - _FILM_KEYS)
    if unknown:
        raise StackError(f"{where}.{unknown[0]}: unknown key for a film (allowed: {', '.join(sorted(_FILM_KEYS))})")
    if "thickness_nm" not in d:
        raise StackError(f"{where}.thickness_nm: required")
    raw = d["thickness_nm"]
    if isinstance(raw, float) and not math.isfinite(raw):
        _check_film_thickness(raw, f"{where}.thickness_nm")
    thickness = _number(raw, f"{where}.thickness_nm")
    _check_film_thickness(thickness, f"{where}.thickness_nm")
    found: list[tuple[str, Any]] = []
    film = Film(thickness_nm=thickness, ior=_rgb(d, "ior", where, positive=True, spectra=found, field="film.ior"),
                extinction=_rgb(d, "extinction", where, lo=0.0, default=0.0, spectra=found, field="film.extinction"))
    if spectra is not None:
        spectra.extend((layer, f, sp) for f, sp in found)
    return film


def _check_film_thickness(v: float, where: str) -> None:
    if not (math.isfinite(v) and v >= 0.0):
        raise StackError(f"{where}: {v!r} is outside [0, inf) (the film's thickness in nm)")


def _check_film(f: Any, where: str) -> None:
    """A :class:`Film` built in Python: the rules of :func:`_film`."""
    if not isinstance(f, Film):
        raise StackError(f"{where}: {f!r} is not a Film")
    if isinstance(f.thickness_nm, bool) or not isinstance(f.thickness_nm, (int, float, np.floating)):
        raise StackError(f"{where}.thickness_nm: {f.thickness_nm!r} is not a number")
    _check_film_thickness(float(f.thickness_nm), f"{where}.thickness_nm")
    for key, positive, lo in (("ior", True, None), ("extinction", False, 0.0)):
        vals = getattr(f, key)
        if len(vals) != 3:
            raise StackError(f"{where}.{key}: an RGB value needs 3 numbers, got {len(vals)}")
        for v in vals:
            if not math.isfinite(v):
                raise StackError(f"{where}.{key}: {v!r} is not finite")
            _check_range(v, f"{where}.{key}", lo, None, positive)


def _roughness(d: dict, where: str) -> tuple[float, float | None, float]:
    """``roughness`` (alpha, or [alpha_x, alpha_y]) and ``rotation_deg`` of an interface table."""
    if "roughness" not in d:
        raise StackError(f"{where}.roughness: required")
    r = d["roughness"]
    w = f"{where}.roughness"
    if isinstance(r, list):
        if len(r) != 2:
            raise StackError(f"{w}: an anisotropic roughness is [alpha_x, alpha_y], got {len(r)} value(s)")
        ax, ay = (_number(x, w) for x in r)
        for v in (ax, ay):
            _check_range(v, w, 0.0, 1.0, False)
    else:
        ax = _number(r, w)
        _check_range(ax, w, 0.0, 1.0, False)
        ay = ax
    rotation = 0.0
    if "rotation_deg" in d:
        rotation = _number(d["rotation_deg"], f"{where}.rotation_deg")
        if ax == ay:
            raise StackError(f"{where}.rotation_deg: a rotation needs an anisotropic roughness "
                             f"[alpha_x, alpha_y] with alpha_x != alpha_y")
        if not 0.0 <= rotation < 360.0:
            raise StackError(f"{where}.rotation_deg: {rotation:g} is outside [0, 360)")
    return ax, (ay if ay != ax else None), rotation


def _number(x: Any, where: str) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise StackError(f"{where}: {x!r} is not a number")
    v = float(x)
    if not math.isfinite(v):
        raise StackError(f"{where}: {x!r} is not finite")
    return v


def _check_range(v: float, where: str, lo, hi, positive: bool) -> None:
    if positive and not v > 0.0:
        raise StackError(f"{where}: {v!r} must be > 0")
    if lo is not None and v < lo:
        raise StackError(f"{where}: {v!r} is outside [{lo}, {hi if hi is not None else 'inf'})"
                         if hi is None else f"{where}: {v!r} is outside [{lo}, {hi}]")
    if hi is not None and v > hi:
        raise StackError(f"{where}: {v!r} is outside [{lo}, {hi}]")


def _check_g(g: float, where: str) -> None:
    if not -1.0 < g < 1.0:
        raise StackError(f"{where}: {g!r} is outside (-1, 1) (the Henyey-Greenstein asymmetry)")


def _rgb(d: dict, key: str, where: str, lo=None, hi=None, positive=False, default=None,
         spectra: list | None = None, index: bool = False, field: str | None = None) -> RGB:
    """An RGB value (a number or three), or, where ``spectra`` is given, also a spectral table
    (``docs/spectral.md``): then ``(field or key, spectrum)`` is appended to ``spectra`` and the
    spectrum's RGB equivalent returned (``index``: one value for the three channels, the
    luminance-weighted mean, for a dielectric's index)."""
    if key not in d:
        if default is None:
            raise StackError(f"{where}.{key}: required")
        return (float(default),) * 3
    x = d[key]
    w = f"{where}.{key}"
    if spectra is not None and (isinstance(x, dict) or _is_spectral_object(x)):
        return _spectral_value(x, w, lo, hi, positive, spectra, field or key, index)
    if isinstance(x, list):
        if len(x) != 3:
            raise StackError(f"{w}: an RGB value needs 3 numbers, got {len(x)}")
        vals = tuple(_number(e, w) for e in x)
    else:
        vals = (_number(x, w),) * 3
    for v in vals:
        _check_range(v, w, lo, hi, positive)
    return vals  # type: ignore[return-value]


def _is_spectral_object(x: Any) -> bool:
    from goniometer.spectral import is_spectral
    return is_spectral(x)


def _spectral_value(x: Any, w: str, lo, hi, positive: bool, spectra: list, field: str, index: bool) -> RGB:
    """A spectral table's spectrum (checked against the field's range at its nodes) appended to
    ``spectra``; returns its RGB equivalent (``goniometer.spectral.rgb_equivalent``)."""
    from goniometer.spectral import SpectrumError, from_toml, is_spectral, rgb_equivalent
    try:
        sp = x if is_spectral(x) else from_toml(x, w)
    except SpectrumError as e:
        raise StackError(str(e)) from None
    nodes = np.asarray(sp.at(np.asarray(sp.wavelength_nm))) if hasattr(sp, "wavelength_nm") else None
    if nodes is not None:
        for v in nodes:
            _check_range(float(v), f"{w}.value", lo, hi, positive)
    rgb = rgb_equivalent(sp, index=index, lo=0.0 if lo is None else lo, hi=hi)
    if index or positive:
        for v in rgb:
            if not v > 0.0:
                raise StackError(f"{w}: the spectrum's RGB equivalent {list(rgb)} must be > 0")
    spectra.append((field, sp))
    return rgb


def _validate_structure(layers: tuple[Layer, ...], source: str) -> None:
    if not layers:
        raise StackError(f"{source}: layers: at least one layer is required")
    prev: Layer | None = None
    for i, x in enumerate(layers):
        where = f"{source}: layers[{i}]"
        last = i == len(layers) - 1
        if isinstance(x, Interface):
            for a in x.alpha_xy:
                if not 0.0 <= a <= 1.0:
                    raise StackError(f"{where}.roughness: {a} is outside [0, 1]")
            if not isinstance(x.multiple_scattering, (bool, np.bool_)):
                raise StackError(f"{where}.multiple_scattering: {x.multiple_scattering!r} is not a boolean "
                                 f"(true or false)")
            if x.rotation_deg != 0.0 and not x.is_anisotropic:
                raise StackError(f"{where}.rotation_deg: a rotation needs an anisotropic roughness")
            if x.is_conductor and not last:
                raise StackError(f"{where}.extinction: a conductor (extinction > 0) must be the last layer")
            if x.film is not None:
                _check_film(x.film, f"{where}.film")
        elif isinstance(x, Medium):
            for a in x.scattering_albedo:
                if not 0.0 <= a <= 1.0:
                    raise StackError(f"{where}.scattering_albedo: {a!r} is outside [0, 1]")
            _check_g(x.g, f"{where}.g")
            if prev is None:
                raise StackError(f"{where}.type: a medium cannot be the top layer (it must lie below an interface)")
            if isinstance(prev, Medium):
                raise StackError(f"{where}.type: two media in a row (merge their optical depths)")
            if last:
                raise StackError(f"{where}.type: a medium must lie above an interface or a Lambertian base")
        elif isinstance(x, Lambertian):
            if not last:
                raise StackError(f"{where}.type: a lambertian base is opaque and must be the last layer")
        else:
            raise StackError(f"{where}.type: unknown layer {x!r}")
        prev = x
    n_if = sum(isinstance(x, Interface) for x in layers)
    if n_if > MAX_INTERFACES:
        raise StackError(f"{source}: layers: {n_if} interfaces; at most {MAX_INTERFACES} are allowed")
