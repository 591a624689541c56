"""A table definition of ``gonio lut``: the quantity, the fixed parameters, the grid and its
parametrization, the rays (``docs/lut.md`` section 2, which this module implements).

A definition is a TOML file::

    name = "ggx_E"                    # file names and the C array's name (a C identifier)
    quantity = "albedo"               # QUANTITIES
    masking = "height-correlated"     # Smith masking of single-scattering interfaces (MASKING)
    rays = 5_000_000                  # rays per cell, or
    stderr = 2e-4                     # a target standard error per cell (rays from a pilot run)

    [interface]                       # albedo quantities: one GGX interface
    fresnel = "white"                 # white (F = 1) | conductor | dielectric

    [[axes]]                          # slowest first: the array's first index
    parameter = "mu"
    nodes = 32
    placement = "node"                # u_i = i / (N - 1); "texel": (i + 0.5) / N
    clamp = [1e-4, 1.0]               # u clamped before it is mapped

    [[axes]]
    parameter = "roughness"
    nodes = 32
    clamp = [1e-4, 1.0]
    map = "alpha=r^2"                 # GGX alpha = u^2 (MAPS)

Fixed roughness values are GGX alpha, as in material files (``docs/material-format.md``); an axis
maps its coordinate to alpha through its ``map``. Every error is a :class:`LutError` naming the
field (``axes[1].nodes: 0 is outside [1, 4096]``).
"""

from __future__ import annotations

import json
import math
import os
import re
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from goniometer.run.settings import MASKING
from goniometer.tomlfile import read_toml

#: what a table holds (``docs/lut.md`` section 3)
QUANTITIES = ("albedo", "albedo-average", "coat-albedo", "coat-darkening", "coat-roughness")
#: the part of an interface's albedo an ``albedo`` or ``albedo-average`` table holds
PARTS = ("both", "reflected", "transmitted")
FRESNEL = ("white", "conductor", "dielectric")
SIDES = ("outside", "inside")
BASES = ("conductor", "lambertian")
#: how a coat-darkening cell reads the runs (``docs/lut.md`` section 3): the layering's own albedo
#: relation at the incident direction, or ``gonio production``'s estimator at that direction
DARKENINGS = ("albedo", "production")
PLACEMENTS = ("node", "texel")
#: how an axis maps its coordinate u (after the clamp and the range) to its parameter
MAPS = {
    "linear": "the parameter is u",
    "alpha=r^2": "GGX alpha = u^2 (u is the perceptual roughness r: Cycles, OpenPBR, three.js)",
    "alpha=r": "GGX alpha = u (MaterialX's albedo table)",
    "ior=ior_from_F0(z^4)": "index (1 + u^2) / (1 - u^2), the index whose F0 is u^4 (Cycles' glass tables)",
}
#: the parameters an axis can set, by the section of the definition they belong to
INCIDENT = ("mu", "theta")
PARAMETERS = {
    "mu": None, "theta": None,
    "roughness": "interface", "ior": "interface",
    "coat_ior": "coat", "coat_roughness": "coat",
    "base_albedo": "base", "base_roughness": "base",
}
#: the maps each parameter takes (the first is the default)
PARAMETER_MAPS = {
    "mu": ("linear",), "theta": ("linear",), "base_albedo": ("linear",),
    "roughness": ("alpha=r^2", "alpha=r"), "coat_roughness": ("alpha=r^2", "alpha=r"),
    "base_roughness": ("alpha=r^2", "alpha=r"),
    "ior": ("linear", "ior=ior_from_F0(z^4)"), "coat_ior": ("linear", "ior=ior_from_F0(z^4)"),
}
#: the default range [lo, hi] of u's map per parameter (theta in degrees)
RANGES = {"theta": (0.0, 90.0)}
#: the sections each quantity reads
SECTIONS = {"albedo": ("interface",), "albedo-average": ("interface",), "coat-albedo": ("coat", "base"),
            "coat-darkening": ("coat", "base"), "coat-roughness": ("coat", "base")}
#: the keys of each section (with what they must be)
SECTION_KEYS = {
    "interface": ("fresnel", "roughness", "ior", "extinction", "side"),
    "coat": ("ior", "roughness"),
    "base": ("kind", "albedo", "roughness", "ior"),
}
TOP_KEYS = ("name", "description", "quantity", "part", "masking", "multiple_scattering", "rays", "stderr", "seed",
            "average_nodes", "darkening", "resolution", "axes", "interface", "coat", "base", "published", "score")
AXIS_KEYS = ("parameter", "nodes", "placement", "clamp", "range", "map")
PUBLISHED_KEYS = ("source", "array", "decimals")
SCORE_KEYS = ("tolerance",)
MAX_NODES = 4096
MAX_CELLS = 1 << 20
#: Gauss-Legendre nodes in mu of an ``albedo-average`` table (default)
AVERAGE_NODES = 32
#: rows of the classic grid of a coat run (rings about the normal; one azimuth cell)
COAT_RESOLUTION = (90, 1)
#: the OpenPBR formulas' practical tolerance on the darkening factor (``[score] tolerance``)
SCORE_TOLERANCE = 0.01


class LutError(ValueError):
    """An invalid table definition or option; the message names the field and the allowed range."""


@dataclass(frozen=True)
class Axis:
    """One axis of a table: ``nodes`` coordinates ``u`` (``placement``, then ``clamp``), mapped
    into ``range`` and then through ``map`` to the values of ``parameter``."""

    parameter: str
    nodes: int
    placement: str = "node"
    clamp: tuple[float, float] | None = None
    range: tuple[float, float] = (0.0, 1.0)
    map: str = "linear"

    def coordinates(self) -> np.ndarray:
        """The unit coordinates of the nodes: ``i / (N - 1)`` (node-aligned; one node: 0) or
        ``(i + 0.5) / N`` (texel centres), then clamped."""
        i = np.arange(self.nodes, dtype=np.float64)
        if self.placement == "texel":
            u = (i + 0.5) / self.nodes
        else:
            u = i / (self.nodes - 1) if self.nodes > 1 else np.zeros(1)
        if self.clamp is not None:
            u = np.clip(u, self.clamp[0], self.clamp[1])
        return u

    def values(self) -> np.ndarray:
        """The parameter's value at every node (alpha for a roughness, an index, mu, theta in degrees)."""
        u = self.range[0] + (self.range[1] - self.range[0]) * self.coordinates()
        if self.map == "alpha=r^2":
            return u * u
        if self.map == "ior=ior_from_F0(z^4)":
            return ior_from_f0(u ** 4)
        return u

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"parameter": self.parameter, "nodes": self.nodes, "placement": self.placement,
                             "range": list(self.range), "map": self.map}
        if self.clamp is not None:
            d["clamp"] = list(self.clamp)
        return d


def ior_from_f0(f0: np.ndarray) -> np.ndarray:
    """The index whose normal-incidence reflectance in air is ``f0``: ``(1 + sqrt f0) / (1 - sqrt f0)``."""
    s = np.sqrt(np.asarray(f0, dtype=np.float64))
    return (1.0 + s) / (1.0 - s)


@dataclass(frozen=True)
class Published:
    """A renderer's published table to compare with: ``array`` (the C array's name in the file
    ``--published`` gives), stored with ``decimals`` decimals, described by ``source``."""

    source: str
    array: str
    decimals: int


@dataclass(frozen=True)
class Definition:
    """A validated table definition (module docstring; ``docs/lut.md`` section 2)."""

    name: str
    quantity: str
    axes: tuple[Axis, ...]
    masking: str = "separable"
    multiple_scattering: bool = False
    rays: int | None = None
    stderr: float | None = None
    seed: int = 1
    part: str = "both"
    average_nodes: int = AVERAGE_NODES
    resolution: tuple[int, int] = COAT_RESOLUTION
    darkening: str = "albedo"
    interface: Mapping[str, Any] = field(default_factory=dict)
    coat: Mapping[str, Any] = field(default_factory=dict)
    base: Mapping[str, Any] = field(default_factory=dict)
    description: str = ""
    published: Published | None = None
    score_tolerance: float = SCORE_TOLERANCE

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(a.nodes for a in self.axes)

    @property
    def cells(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64)) if self.axes else 1

    @property
    def incident_axis(self) -> int | None:
        """The index of the axis of incident directions (mu or theta), or None."""
        for k, a in enumerate(self.axes):
            if a.parameter in INCIDENT:
                return k
        return None

    @property
    def uses_slices(self) -> bool:
        """True if the runs record classic slices (``resolution``): the production estimators."""
        return self.quantity == "coat-roughness" or (self.quantity == "coat-darkening"
                                                     and self.darkening == "production")

    @property
    def c_name(self) -> str:
        """The C array's name (the definition's name)."""
        return self.name

    def axis_values(self) -> list[np.ndarray]:
        return [a.values() for a in self.axes]

    def with_rays(self, rays: int | None = None, stderr: float | None = None) -> "Definition":
        """A copy whose rays are ``rays`` per cell (``--rays``) or whose target is ``stderr``
        (``--stderr``); either replaces both of the file's keys."""
        from dataclasses import replace
        if rays is not None:
            _int_in(rays, "--rays", 1, 10**12)
            return replace(self, rays=int(rays), stderr=None)
        if stderr is not None:
            _stderr(stderr, "--stderr")
            return replace(self, rays=None, stderr=float(stderr))
        return self

    def to_dict(self) -> dict[str, Any]:
        """The definition as JSON-ready data (the output's ``definition``; the checkpoints' identity)."""
        d: dict[str, Any] = {"name": self.name, "quantity": self.quantity, "masking": self.masking,
                             "multiple_scattering": self.multiple_scattering, "seed": self.seed,
                             "axes": [a.to_dict() for a in self.axes]}
        d["rays" if self.rays is not None else "stderr"] = self.rays if self.rays is not None else self.stderr
        if self.quantity in ("albedo", "albedo-average"):
            d["part"] = self.part
        if self.quantity == "albedo-average":
            d["average_nodes"] = self.average_nodes
        if self.quantity == "coat-darkening":
            d["darkening"] = self.darkening
        if self.uses_slices:
            d["resolution"] = list(self.resolution)
        for s in SECTIONS[self.quantity]:
            d[s] = dict(getattr(self, s))
        if self.description:
            d["description"] = self.description
        if self.published is not None:
            d["published"] = {"source": self.published.source, "array": self.published.array,
                              "decimals": self.published.decimals}
        if self.quantity == "coat-darkening":
            d["score"] = {"tolerance": self.score_tolerance}
        return d

    def identity(self) -> dict[str, Any]:
        """What makes two computations the same table (checkpoints): the definition without its
        description and its published reference."""
        d = self.to_dict()
        d.pop("description", None)
        d.pop("published", None)
        d.pop("score", None)
        return json.loads(json.dumps(d))


# --------------------------------------------------------------------------- reading

def load_definition(path: str | os.PathLike) -> Definition:
    """Read and validate a definition file; :class:`LutError` names the file and the field."""
    data = read_toml(path, LutError)
    try:
        return definition_from_dict(data)
    except LutError as e:
        raise LutError(f"{path}: {e}") from None


def definition_from_dict(d: Mapping[str, Any]) -> Definition:
    """Validate a parsed definition (module docstring)."""
    _unknown(d, TOP_KEYS, "")
    name = d.get("name")
    if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
        raise LutError(f"name: {name!r} must be a C identifier (letters, digits, _; it names the files and the "
                       f"C array)")
    quantity = _choice(d.get("quantity"), QUANTITIES, "quantity")
    masking = _choice(d.get("masking", "separable"), MASKING, "masking")
    ms = d.get("multiple_scattering", False)
    if not isinstance(ms, bool):
        raise LutError(f"multiple_scattering: {ms!r} is not a boolean (true or false)")
    rays, stderr = d.get("rays"), d.get("stderr")
    if (rays is None) == (stderr is None):
        raise LutError("rays, stderr: give exactly one: rays per cell (an integer) or a target standard error "
                       "per cell (rays from a pilot run)")
    if rays is not None:
        _int_in(rays, "rays", 1, 10**12)
    else:
        _stderr(stderr, "stderr")
    seed = d.get("seed", 1)
    _int_in(seed, "seed", 0, 2**62)
    part = _choice(d.get("part", "both"), PARTS, "part")
    if "part" in d and quantity not in ("albedo", "albedo-average"):
        raise LutError(f"part: only an albedo or albedo-average table takes part (this is {quantity})")
    average_nodes = d.get("average_nodes", AVERAGE_NODES)
    if "average_nodes" in d and quantity != "albedo-average":
        raise LutError(f"average_nodes: only an albedo-average table takes it (this is {quantity})")
    _int_in(average_nodes, "average_nodes", 2, 512)
    darkening = _choice(d.get("darkening", "albedo"), DARKENINGS, "darkening")
    if "darkening" in d and quantity != "coat-darkening":
        raise LutError(f"darkening: only a coat-darkening table takes it (this is {quantity})")
    resolution = d.get("resolution", list(COAT_RESOLUTION))
    if "resolution" in d and not (quantity == "coat-roughness" or (quantity == "coat-darkening"
                                                                   and darkening == "production")):
        raise LutError("resolution: only the production estimators record slices (coat-roughness, coat-darkening "
                       "with darkening = \"production\")")
    if not isinstance(resolution, list) or len(resolution) != 2:
        raise LutError(f"resolution: {resolution!r} must be [n_theta, n_phi] (the coat runs' classic grid)")
    _int_in(resolution[0], "resolution (n_theta)", 2, 1000)
    _int_in(resolution[1], "resolution (n_phi)", 1, 4000)
    axes = _axes(d.get("axes"))
    sections = {}
    for s in ("interface", "coat", "base"):
        if s in d and s not in SECTIONS[quantity]:
            raise LutError(f"{s}: {_a(quantity)} table has no [{s}] (it takes {', '.join(SECTIONS[quantity])})")
        table = d.get(s, {})
        if not isinstance(table, dict):
            raise LutError(f"{s}: must be a table ([{s}])")
        _unknown(table, SECTION_KEYS[s], f"{s}.")
        sections[s] = dict(table)
    published = _published(d.get("published"))
    score = d.get("score", {})
    if not isinstance(score, dict):
        raise LutError("score: must be a table ([score])")
    _unknown(score, SCORE_KEYS, "score.")
    if score and quantity != "coat-darkening":
        raise LutError(f"score: only a coat-darkening table is scored against OpenPBR's formulas (this is {quantity})")
    tol = score.get("tolerance", SCORE_TOLERANCE)
    if not _is_num(tol) or not 0.0 < tol < 1.0:
        raise LutError(f"score.tolerance: {tol!r} is outside (0, 1)")
    description = d.get("description", "")
    if not isinstance(description, str):
        raise LutError("description: must be a string")
    defn = Definition(name=name, quantity=quantity, axes=axes, masking=masking, multiple_scattering=ms,
                      rays=None if rays is None else int(rays), stderr=None if stderr is None else float(stderr),
                      seed=int(seed), part=part, average_nodes=int(average_nodes),
                      resolution=(int(resolution[0]), int(resolution[1])), darkening=darkening,
                      description=description,
                      published=published, score_tolerance=float(tol), **sections)
    _check_quantity(defn)
    return defn


def _axes(raw: Any) -> tuple[Axis, ...]:
    if raw is None:
        raw = []
    if not isinstance(raw, list) or not all(isinstance(a, dict) for a in raw):
        raise LutError("axes: must be an array of tables ([[axes]])")
    if len(raw) > 4:
        raise LutError(f"axes: {len(raw)} axes; a table has at most 4")
    out, seen = [], {}
    for k, a in enumerate(raw):
        where = f"axes[{k}]"
        _unknown(a, AXIS_KEYS, f"{where}.")
        p = _choice(a.get("parameter"), tuple(PARAMETERS), f"{where}.parameter")
        if p in seen:
            raise LutError(f"{where}.parameter: {p} is already set by axes[{seen[p]}]")
        seen[p] = k
        nodes = a.get("nodes")
        _int_in(nodes, f"{where}.nodes", 1, MAX_NODES)
        placement = _choice(a.get("placement", "node"), PLACEMENTS, f"{where}.placement")
        clamp = a.get("clamp")
        if clamp is not None:
            clamp = _pair(clamp, f"{where}.clamp")
            if not 0.0 <= clamp[0] <= clamp[1] <= 1.0:
                raise LutError(f"{where}.clamp: {list(clamp)} must satisfy 0 <= lo <= hi <= 1 (it clamps u)")
        rng = _pair(a["range"], f"{where}.range") if "range" in a else RANGES.get(p, (0.0, 1.0))
        allowed = PARAMETER_MAPS[p]
        m = _choice(a.get("map", allowed[0]), allowed, f"{where}.map")
        if p in ("roughness", "coat_roughness", "base_roughness") and "map" not in a:
            raise LutError(f"{where}.map: a roughness axis says how u gives GGX alpha: one of {', '.join(allowed)}")
        axis = Axis(p, int(nodes), placement, clamp, rng, m)
        _check_axis_values(axis, where)
        out.append(axis)
    cells = int(np.prod([a.nodes for a in out], dtype=np.int64)) if out else 1
    if cells > MAX_CELLS:
        raise LutError(f"axes: {cells} cells; a table has at most {MAX_CELLS}")
    return tuple(out)


#: the allowed values of each parameter (lo, hi, lo open, hi open), as the error names them
LIMITS = {
    "mu": (0.0, 1.0, True, False), "theta": (0.0, 90.0, False, True),
    "roughness": (0.0, 1.0, False, False), "coat_roughness": (0.0, 1.0, False, False),
    "base_roughness": (0.0, 1.0, False, False), "base_albedo": (0.0, 1.0, False, False),
    "ior": (0.0, math.inf, True, True), "coat_ior": (0.0, math.inf, True, True),
}


def _interval(p: str) -> str:
    lo, hi, lo_open, hi_open = LIMITS[p]
    return f"{'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"


def _in_limits(p: str, v: float) -> bool:
    lo, hi, lo_open, hi_open = LIMITS[p]
    return (v > lo if lo_open else v >= lo) and (v < hi if hi_open else v <= hi) and math.isfinite(v)


def _check_axis_values(axis: Axis, where: str) -> None:
    with np.errstate(divide="ignore", invalid="ignore"):
        values = axis.values()
    what = {"alpha=r^2": "GGX alpha", "alpha=r": "GGX alpha"}.get(axis.map, axis.parameter)
    for v in values:
        if not _in_limits(axis.parameter, float(v)):
            raise LutError(f"{where}: a node gives {what} {float(v):g}, outside {_interval(axis.parameter)}; "
                           f"clamp u or change its range")


def _published(raw: Any) -> Published | None:
    if raw is None:
        return None
    if not isinstance(raw, dict):
        raise LutError("published: must be a table ([published])")
    _unknown(raw, PUBLISHED_KEYS, "published.")
    source, array = raw.get("source", ""), raw.get("array")
    if not isinstance(source, str):
        raise LutError("published.source: must be a string")
    if not isinstance(array, str) or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", array):
        raise LutError(f"published.array: {array!r} must name a C array")
    decimals = raw.get("decimals", 6)
    _int_in(decimals, "published.decimals", 0, 12)
    return Published(source, array, int(decimals))


# --------------------------------------------------------------------------- the quantity's parameters

def _check_quantity(d: Definition) -> None:
    """The sections and axes a quantity needs (``docs/lut.md`` section 3)."""
    q = d.quantity
    owners = set(SECTIONS[q]) | {None}
    for k, a in enumerate(d.axes):
        if PARAMETERS[a.parameter] not in owners:
            raise LutError(f"axes[{k}].parameter: {_a(q)} table has no {a.parameter} (its parameters: "
                           f"{', '.join(p for p, s in PARAMETERS.items() if s in owners)})")
    inc = [k for k, a in enumerate(d.axes) if a.parameter in INCIDENT]
    if q in ("albedo-average", "coat-roughness"):
        if inc:
            raise LutError(f"axes[{inc[0]}].parameter: {_a(q)} table has no incident axis "
                           f"({'it integrates over mu' if q == 'albedo-average' else 'it is read at normal incidence'})")
    elif not inc:
        raise LutError(f"axes: {_a(q)} table needs an incident axis (parameter mu or theta)")
    elif len(inc) > 1:
        raise LutError(f"axes[{inc[1]}].parameter: one incident axis only (axes[{inc[0]}] is one)")
    if "interface" in SECTIONS[q]:
        _check_interface(d)
    else:
        _check_coat(d)


def _axis_of(d: Definition, parameter: str) -> int | None:
    for k, a in enumerate(d.axes):
        if a.parameter == parameter:
            return k
    return None


def _fixed(d: Definition, section: str, key: str, parameter: str, p_limits: str, default: Any = None,
           required: bool = True) -> None:
    """A fixed key of a section, or the axis that sets it (never both)."""
    table = getattr(d, section)
    axis = _axis_of(d, parameter)
    if key in table and axis is not None:
        raise LutError(f"{section}.{key}: set by axes[{axis}] too; give one of them")
    if key not in table:
        if axis is None and required and default is None:
            raise LutError(f"{section}.{key}: required (or an axis with parameter {parameter})")
        return
    v = table[key]
    if not _is_num(v) or not _in_limits(p_limits, float(v)):
        raise LutError(f"{section}.{key}: {v!r} is outside {_interval(p_limits)}")


def _check_interface(d: Definition) -> None:
    t = d.interface
    fresnel = _choice(t.get("fresnel"), FRESNEL, "interface.fresnel")
    _fixed(d, "interface", "roughness", "roughness", "roughness")
    if fresnel == "white":
        for k in ("ior", "extinction", "side"):
            if k in t:
                raise LutError(f"interface.{k}: a white interface (F = 1) takes no {k}")
        if _axis_of(d, "ior") is not None:
            raise LutError(f"axes[{_axis_of(d, 'ior')}].parameter: a white interface (F = 1) has no index")
    else:
        _fixed(d, "interface", "ior", "ior", "ior")
    if fresnel == "conductor":
        ext = t.get("extinction")
        if not _is_num(ext) or not 0.0 < float(ext) < math.inf:
            raise LutError(f"interface.extinction: {ext!r} is outside (0, inf) (a conductor's extinction)")
        if "side" in t:
            raise LutError("interface.side: a conductor is lit from outside only")
    if fresnel == "dielectric":
        if "extinction" in t:
            raise LutError("interface.extinction: a dielectric takes no extinction (fresnel = \"conductor\")")
        _choice(t.get("side", "outside"), SIDES, "interface.side")
        if "ior" in t and float(t["ior"]) == 1.0:
            raise LutError("interface.ior: 1 is index-matched: the interface scatters nothing")
    if fresnel != "dielectric" and d.part == "transmitted":
        raise LutError(f"part: a {fresnel} interface transmits nothing")


def _check_coat(d: Definition) -> None:
    _fixed(d, "coat", "ior", "coat_ior", "coat_ior")
    _fixed(d, "coat", "roughness", "coat_roughness", "coat_roughness")
    kind = _choice(d.base.get("kind"), BASES, "base.kind")
    _fixed(d, "base", "albedo", "base_albedo", "base_albedo")
    if kind == "lambertian":
        for k in ("roughness", "ior"):
            if k in d.base:
                raise LutError(f"base.{k}: a Lambertian base takes no {k}")
        if _axis_of(d, "base_roughness") is not None:
            raise LutError(f"axes[{_axis_of(d, 'base_roughness')}].parameter: a Lambertian base has no roughness")
        if d.quantity == "coat-roughness":
            raise LutError("base.kind: a coat-roughness table needs a conductor base (a Lambertian has no roughness)")
    else:
        _fixed(d, "base", "roughness", "base_roughness", "base_roughness")
        n = d.base.get("ior", 1.0)
        if not _is_num(n) or not 0.0 < float(n) < math.inf:
            raise LutError(f"base.ior: {n!r} is outside (0, inf) (the real part of the conductor's index)")


# --------------------------------------------------------------------------- small checks

def _a(word: str) -> str:
    """``word`` with its indefinite article."""
    return f"{'an' if word[0] in 'aeiou' else 'a'} {word}"


def _unknown(d: Mapping[str, Any], allowed: tuple[str, ...], where: str) -> None:
    unknown = sorted(set(d) - set(allowed))
    if unknown:
        raise LutError(f"{where}{unknown[0]}: unknown key (allowed: {', '.join(allowed)})")


def _choice(v: Any, allowed: tuple[str, ...], where: str) -> str:
    if v not in allowed:
        raise LutError(f"{where}: {v!r} is not one of {', '.join(allowed)}")
    return v


def _is_num(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _int_in(v: Any, where: str, lo: int, hi: int) -> None:
    if not isinstance(v, int) or isinstance(v, bool) or not lo <= v <= hi:
        raise LutError(f"{where}: {v!r} is outside [{lo}, {hi}] (a whole number)")


def _stderr(v: Any, where: str) -> None:
    if not _is_num(v) or not 0.0 < float(v) < 0.5:
        raise LutError(f"{where}: {v!r} is outside (0, 0.5) (a target standard error per cell)")


def _pair(v: Any, where: str) -> tuple[float, float]:
    if not isinstance(v, list) or len(v) != 2 or not all(_is_num(x) for x in v):
        raise LutError(f"{where}: {v!r} must be [lo, hi] (two numbers)")
    return float(v[0]), float(v[1])


__all__ = ["QUANTITIES", "PARTS", "FRESNEL", "SIDES", "BASES", "DARKENINGS", "PLACEMENTS", "MAPS", "PARAMETERS", "LutError",
           "Axis", "Published", "Definition", "load_definition", "definition_from_dict", "ior_from_f0"]
