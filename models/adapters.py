"""Models without a package: the adapter specs that ``--model`` accepts beside the registered names
(``docs/models.md``, "Writing a model (plugins)", adapters).

* ``python:MODULE:NAME`` -- ``MODULE`` is a dotted module name importable from ``sys.path`` or the
  path of a ``.py`` file; ``NAME`` is

  - a :class:`models.base.Model` subclass (built with no arguments) or instance (copied): used as
    it is, under the spec as its name;
  - or a vectorised callable ``f(l, v, stack) -> (..., 3)``: ``l`` (3,) towards the light, ``v``
    (..., 3) towards the viewer, values without cosine in 1/sr, RGB last (``docs/models.md`` §1).
    It is wrapped as a model (:class:`FunctionModel`) with ``top = 0`` and ``internal = f``: the
    whole function is compared with the reference's internal paths as well as its total. It
    accepts every stack (the function reads it); its sides are ``f.sides`` if the function has
    that attribute, else ``("brdf",)``. On each stack it is first called once on a probe
    (``l = (0, 0, 1)``, ``v`` of shape (2, 3)), and a function that raises or returns another
    shape than (2, 3) is refused with the reason.

* ``mitsuba:FILE.xml`` / ``mitsuba:FILE.json`` -- any Mitsuba 3 BSDF, loaded by Mitsuba itself
  (``mi.load_file`` for XML, ``mi.load_dict(json.load(...))`` for JSON) in the variant of
  :func:`models.production.mitsuba.mitsuba_variant` and evaluated by
  :class:`models.production.mitsuba.MitsubaBSDF` (importance mode, ``si.wi = l``, divided by
  ``|v_z|``; single precision). It is a fixed BSDF: it accepts every stack, does not read it, and
  says so in its description and under ``approximations``. ``top = 0``, ``internal`` = the BSDF;
  both sides (the BTDF is the BSDF below the surface). Cost: one batched call per light direction
  with the vectorised variant; with ``scalar_rgb`` one Python-level call per direction, about
  5 us each (a 90 x 360 slice at 5 x 5 sub-cells: about 4 s per incident direction).

  Dirac lobes (the components whose flags hold ``DeltaReflection``, ``DeltaTransmission`` or
  ``Null``: the smooth ``conductor`` and ``dielectric``, ``plastic``'s specular lobe,
  ``thindielectric``'s reflection and its straight-through transmission), to which ``eval`` gives
  no value, are the model's delta lobes
  (:meth:`MitsubaFileModel.delta_lobes`): Mitsuba's ``sample`` restricted to each such component
  gives its direction and its weight (the lobe's reflectance or flux-based transmittance), and the
  harness puts it whole in the cell that holds the direction (``docs/models.md`` §3, "Delta
  lobes"). ``roughconductor`` and ``roughdielectric`` with ``alpha = 0`` are no delta lobes to
  Mitsuba (it clamps alpha to 1e-4 and flags them glossy): they are evaluated like any other.

  On a polarized file (``docs/polarization.md``, "Models on polarized files") a file whose BSDF is
  one of the plugins that carry polarization (:data:`models.production.mitsuba.POLARIZING_PLUGINS`: ``conductor``,
  ``roughconductor``, ``dielectric``, ``pplastic``) is a polarized model: the same file is loaded a
  second time in the polarized variant (:func:`models.production.mitsuba.mitsuba_polarized_variant`)
  and its Mueller matrices (:meth:`models.production.mitsuba.MitsubaBSDF.eval_mueller`, channel
  ``c`` at :func:`models.production.mitsuba.channel_wavelengths`) are judged element by element,
  taken from Mitsuba's ``stokes_basis`` frames to the file's s/p frames (``mueller_frames =
  "mitsuba"``), their delta lobes' matrices too. Any other plugin is judged on the intensity only, and
  the evaluation says why.

Every failure is a :class:`models.base.ModelError` whose message is one line starting with the spec:
a malformed spec, a module that does not import, a missing attribute, something that is neither a
Model nor callable, a file Mitsuba refuses or that holds no BSDF, Mitsuba missing.
"""

from __future__ import annotations

import copy
import hashlib
import importlib
import importlib.util
import json
import re
import sys
from pathlib import Path
from typing import Any, Callable

import numpy as np

from goniometer.stack import Stack
from models.base import SIDES, DeltaLobe, Model, ModelError, ModelValue

PYTHON = "python:"
MITSUBA = "mitsuba:"
PREFIXES = (PYTHON, MITSUBA)
#: the probe a wrapped function is called on once per stack
PROBE_L = np.array([0.0, 0.0, 1.0])
PROBE_V = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]])
#: what the approximations of a model without a top/internal split say
NO_SPLIT = "no top/internal split (top = 0): its whole value is compared with the internal paths too"

__all__ = ["FunctionModel", "MitsubaFileModel", "PREFIXES", "code_identity", "is_spec", "resolve"]


def is_spec(name: str) -> bool:
    """Whether ``name`` is an adapter spec (``python:...`` or ``mitsuba:...``) rather than a model name."""
    return isinstance(name, str) and name.startswith(PREFIXES)


def resolve(spec: str) -> Model:
    """The model of the adapter spec ``spec``; ModelError (one line, starting with the spec) otherwise."""
    if spec.startswith(PYTHON):
        return _python(spec)
    if spec.startswith(MITSUBA):
        return _mitsuba(spec)
    raise ModelError(f"{spec}: not an adapter spec (python:MODULE:NAME or mitsuba:FILE.xml|.json)")


def code_identity(spec: str) -> str:
    """What the values of ``spec`` depend on outside this project, as a short hash: the sources of
    the Python module (its top-level package) or the Mitsuba file's bytes and Mitsuba's version.
    Keys a report's cached evaluations, so that an edited function or file is evaluated again."""
    from models.plugins import module_key
    if spec.startswith(PYTHON):
        module, _ = _split_python(spec)
        if _is_path(module):
            return _file_hash(Path(module))
        return module_key(module)
    path = Path(spec[len(MITSUBA):])
    from models.production.mitsuba import mitsuba_module
    mi = mitsuba_module()
    return _file_hash(path) + "-" + (getattr(mi, "__version__", "none") if mi is not None else "none")


def _file_hash(path: Path) -> str:
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()[:16]
    except OSError:
        return "unreadable"


def _one_line(e: BaseException) -> str:
    """An exception's message on one line, without Mitsuba's ``[file.cpp:123]`` prefix."""
    return re.sub(r"^\[[\w.]+:\d+\]\s*", "", " ".join(str(e).split())) or type(e).__name__


# ---------------------------------------------------------------------- python:MODULE:NAME

def _split_python(spec: str) -> tuple[str, str]:
    module, sep, name = spec[len(PYTHON):].rpartition(":")
    if not sep or not module or not name:
        raise ModelError(f"{spec}: expected python:MODULE:NAME (a module or a .py file, and a Model subclass "
                         f"or a function f(l, v, stack) in it)")
    return module, name


def _is_path(module: str) -> bool:
    return module.endswith(".py") or "/" in module or "\\" in module


def _import(spec: str, module: str) -> Any:
    if _is_path(module):
        path = Path(module)
        if not path.is_file():
            raise ModelError(f"{spec}: no file {module}")
        key = "_gonio_adapter_" + hashlib.sha256(str(path.resolve()).encode()).hexdigest()[:12]
        stamp = (path.stat().st_mtime_ns, path.stat().st_size)
        loaded = sys.modules.get(key)
        if loaded is not None and getattr(loaded, "__gonio_stamp__", None) == stamp:
            return loaded   # imported already, unchanged: its functions (and their compiled code) are reused
        mod_spec = importlib.util.spec_from_file_location(key, path)
        mod = importlib.util.module_from_spec(mod_spec)
        try:
            mod_spec.loader.exec_module(mod)
        except Exception as e:  # noqa: BLE001 -- the user's module: any failure is a one-line refusal
            raise ModelError(f"{spec}: importing {module} raised {type(e).__name__}: {_one_line(e)}") from None
        mod.__gonio_stamp__ = stamp
        sys.modules[key] = mod
        return mod
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as e:
        raise ModelError(f"{spec}: cannot import module {module!r}: {_one_line(e)}") from None
    except Exception as e:  # noqa: BLE001
        raise ModelError(f"{spec}: importing {module} raised {type(e).__name__}: {_one_line(e)}") from None


def _python(spec: str) -> Model:
    module, name = _split_python(spec)
    mod = _import(spec, module)
    if not hasattr(mod, name):
        raise ModelError(f"{spec}: module {module!r} has no attribute {name!r}")
    target = getattr(mod, name)
    if isinstance(target, type) and issubclass(target, Model):
        try:
            model = target()
        except Exception as e:  # noqa: BLE001
            raise ModelError(f"{spec}: {name}() raised {type(e).__name__}: {_one_line(e)}") from None
    elif isinstance(target, Model):
        model = copy.copy(target)
    elif callable(target) and not isinstance(target, type):
        return FunctionModel(spec, target)
    else:
        raise ModelError(f"{spec}: {module}.{name} is a {type(target).__name__}, not a Model subclass or a "
                         f"function f(l, v, stack)")
    model.name = spec   # the name the user typed keys the outputs
    return model


class FunctionModel(Model):
    """A vectorised function ``f(l, v, stack) -> (..., 3)`` as a model: ``top = 0``, ``internal = f``
    (module docstring). It accepts every stack and is called on whole arrays of directions."""

    anisotropic = True
    scattering = True
    films = True

    def __init__(self, spec: str, function: Callable[[np.ndarray, np.ndarray, Stack], Any]) -> None:
        self.name = spec
        self.function = function
        sides = tuple(getattr(function, "sides", ("brdf",)))
        if not sides or any(s not in SIDES for s in sides):
            raise ModelError(f"{spec}: the function's sides attribute must name sides among {SIDES}, got {sides}")
        self.sides = sides
        doc = (getattr(function, "__doc__", None) or "").strip().splitlines()
        self.description = f"{spec}: a function f(l, v, stack) (top = 0)" + (f"; {doc[0]}" if doc else "")
        self.approximation = f"a function f(l, v, stack); {NO_SPLIT}"

    def _call(self, stack: Stack, l: np.ndarray, v: np.ndarray) -> np.ndarray:
        try:
            out = self.function(l, v, stack)
        except Exception as e:  # noqa: BLE001 -- the user's function: any failure is a one-line refusal
            raise ModelError(f"{self.name}: the function raised {type(e).__name__}: {_one_line(e)}") from None
        try:
            out = np.asarray(out, dtype=np.float64)
        except (TypeError, ValueError):
            raise ModelError(f"{self.name}: the function returned a {type(out).__name__}, not an array of "
                             f"numbers") from None
        want = v.shape[:-1] + (3,)
        if out.shape != want:
            raise ModelError(f"{self.name}: the function returned shape {out.shape} for v of shape {v.shape}; "
                             f"expected {want} (RGB last)")
        return out

    def support_reason(self, stack: Stack) -> str | None:
        """None, or why the function fails its probe on ``stack`` (one line)."""
        try:
            self._call(stack, PROBE_L.copy(), PROBE_V.copy())
        except ModelError as e:
            msg = str(e)[len(self.name) + 2:]
            return f"on the probe l = (0, 0, 1), v of shape {PROBE_V.shape}: {msg}"
        return None

    def _evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> ModelValue:
        internal = self._call(stack, l, v)
        return ModelValue(np.zeros_like(internal), internal)


# ---------------------------------------------------------------------- mitsuba:FILE

def _mitsuba(spec: str) -> Model:
    from models.production.mitsuba import NOT_INSTALLED, MitsubaBSDF, mitsuba_variant
    path = Path(spec[len(MITSUBA):])
    if not str(path) or path.suffix.lower() not in (".xml", ".json"):
        raise ModelError(f"{spec}: expected mitsuba:FILE.xml or mitsuba:FILE.json")
    if not path.is_file():
        raise ModelError(f"{spec}: no file {path}")
    variant = mitsuba_variant()
    if variant is None:
        raise ModelError(f"{spec}: {NOT_INSTALLED} (pip install mitsuba)")
    try:
        bsdf = MitsubaBSDF.from_file(path, variant)
    except ValueError as e:   # not a BSDF, not JSON, not a plugin dictionary
        raise ModelError(f"{spec}: {_one_line(e)}") from None
    except (RuntimeError, TypeError, OSError) as e:
        raise ModelError(f"{spec}: Mitsuba refused the file: {_one_line(e)}") from None
    return MitsubaFileModel(spec, bsdf, path)


class MitsubaFileModel(Model):
    """A fixed Mitsuba 3 BSDF loaded from a file (module docstring): every stack is accepted and
    none is read; ``top = 0``, ``internal`` = the BSDF, both sides."""

    sides = ("brdf", "btdf")
    anisotropic = True
    scattering = True
    films = True

    #: Mitsuba's polarized ``eval`` in its ``stokes_basis`` frames (module docstring)
    mueller_frames = "mitsuba"

    def __init__(self, spec: str, bsdf: Any, path: Path | None = None) -> None:
        from models.production.mitsuba import POLARIZING_PLUGINS, plugin_name
        self.name = spec
        self.bsdf = bsdf
        self.path = path
        self.plugin = plugin_name(bsdf.bsdf)
        #: Mueller matrices from the plugins that carry polarization (module docstring)
        self.polarized = self.plugin in POLARIZING_PLUGINS
        self._polarized_bsdf: Any = None
        self.description = f"{spec}: a fixed Mitsuba BSDF; it does not read the stack"
        deltas = bsdf.delta_components("brdf") + bsdf.delta_components("btdf")
        delta = (f"; its delta lobes (components {', '.join(str(c) for c in sorted(set(deltas)))}) are sampled by "
                 f"Mitsuba and put whole in the cells that hold their directions" if deltas else "")
        self.approximation = (f"a fixed Mitsuba BSDF ({spec[len(MITSUBA):]}, variant {bsdf.variant}); "
                              f"it does not read the stack; {NO_SPLIT}{delta}")

    def support_reason(self, stack: Stack) -> str | None:
        return None

    def _evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> ModelValue:
        internal = self.bsdf.eval(l, v, side=side)
        return ModelValue(np.zeros_like(internal), internal)

    def delta_lobes(self, stack: Stack, l: np.ndarray, side: str) -> list[DeltaLobe]:
        """The BSDF's Dirac lobes (its components flagged ``DeltaReflection`` or ``DeltaTransmission``:
        the smooth ``conductor``, ``dielectric``, ``plastic``, ...), sampled by Mitsuba
        (:meth:`models.production.mitsuba.MitsubaBSDF.delta_lobes`); ``internal`` as the rest."""
        return [DeltaLobe(v, w) for v, w in self.bsdf.delta_lobes(l, side=side)]

    def delta_lobes_mueller(self, stack: Stack, l: np.ndarray, side: str) -> list[DeltaLobe]:
        """The Dirac lobes' Mueller matrices in the polarized variant, in ``stokes_basis`` frames."""
        from models.production.mitsuba import channel_wavelengths
        return [DeltaLobe(v, m) for v, m in
                self.polarized_bsdf().delta_lobes_mueller(l, channel_wavelengths(stack), side=side)]

    def mueller_reason(self, stack: Stack) -> str | None:
        """Why this file gives no Mueller matrices: a plugin that depolarizes (None for the
        plugins that carry polarization, :data:`~models.production.mitsuba.POLARIZING_PLUGINS`)."""
        from models.production.mitsuba import POLARIZING_PLUGINS
        if not self.polarized:
            return (f"Mitsuba's {self.plugin} is judged on the intensity only: of its plugins only "
                    f"{', '.join(POLARIZING_PLUGINS)} carry polarization, the others depolarize "
                    f"(docs/polarization.md, Models on polarized files)")
        return super().mueller_reason(stack)

    def support_mueller_reason(self, stack: Stack) -> str | None:
        from models.production.mitsuba import mitsuba_polarized_variant
        if mitsuba_polarized_variant() is None:
            return "this Mitsuba has no polarized variant (scalar_spectral_polarized)"
        return None

    def mueller_note(self, stack: Stack) -> str | None:
        from models.production.mitsuba import channel_wavelengths, mitsuba_polarized_variant
        nm = ", ".join(f"{x:g}" for x in channel_wavelengths(stack))
        smooth = ("; its delta lobes sampled by Mitsuba and put whole in the cells that hold their directions"
                  if self.bsdf.delta_components("brdf") or self.bsdf.delta_components("btdf") else "")
        return (f"Mitsuba's {self.plugin} in {mitsuba_polarized_variant()}, R G B at {nm} nm, from its stokes_basis "
                f"frames to the file's s/p frames{smooth}")

    def polarized_bsdf(self) -> Any:
        """The file's BSDF loaded in the polarized variant (loaded on first use)."""
        if self._polarized_bsdf is None:
            from models.production.mitsuba import MitsubaBSDF, mitsuba_polarized_variant
            variant = mitsuba_polarized_variant()
            if self.path is not None:
                self._polarized_bsdf = MitsubaBSDF.from_file(self.path, variant)
            else:
                self._polarized_bsdf = MitsubaBSDF(self.bsdf.spec, variant)
        return self._polarized_bsdf

    def _evaluate_mueller(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> np.ndarray:
        from models.production.mitsuba import channel_wavelengths
        return self.polarized_bsdf().eval_mueller(l, v, channel_wavelengths(stack), side=side)
