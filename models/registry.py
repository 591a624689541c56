"""The model names and where they live: the built-in models, the models that installed
distributions register (entry-point group ``goniometer.models``, :mod:`models.plugins`) and the
adapter specs ``python:MODULE:NAME`` and ``mitsuba:FILE`` (:mod:`models.adapters`).

Everything is built on demand: there is no global state but the cached entry-point scan of
:func:`models.plugins.installed` (``models.plugins.clear_cache()`` clears it). The built-in models
come first, in display order, then the plugins' in entry-point name order. A model name
registered twice (a plugin and a built-in, or two plugins) is a :class:`models.plugins.PluginError`
naming both distributions, raised by every function here that lists the models
(``docs/models.md``, "Writing a model (plugins)").
"""

from __future__ import annotations

import hashlib
from typing import Sequence

from models import adapters, plugins
from models.base import Model, ModelError
from models.plugins import Plugin, PluginError

#: the ``source`` of the models this project ships (``gonio models``)
BUILT_IN = "built-in"

__all__ = ["BUILT_IN", "FITTED", "all_models", "catalogue", "check_names", "code_key", "fitted_models", "get",
           "is_spec", "models_for", "sources"]


def _built_in_models() -> list[Model]:
    """Every analytic model of this project, in display order (fresh instances)."""
    from models.belcour import BelcourAniso, BelcourBati19, BelcourBTDF, BelcourForward, BelcourSymmetric
    from models.multilayer_lut import MultilayerLUT
    from models.weidlich_wilkie import Elek10, WW09, WWBati19
    found: list[Model] = [WW09(), Elek10(), WWBati19(), BelcourForward(), BelcourSymmetric(), BelcourBati19(),
                          BelcourBTDF(), BelcourAniso(), MultilayerLUT()]
    # production coat models (issue 13): OpenPBR and Standard Surface coats, Kulla-Conty GGX interface,
    # Mitsuba 3's own BSDFs
    from models.production import (GGXKullaConty, MitsubaPrincipled, MitsubaRoughPlastic, OpenPBRCoat,
                                   StandardSurfaceCoat)
    found += [OpenPBRCoat(), StandardSurfaceCoat(), GGXKullaConty(), MitsubaRoughPlastic(), MitsubaPrincipled()]
    # thin-film iridescence (docs/spectral.md "Models", docs/iridescence-models.md)
    from models.iridescence import BelcourIridescence
    from models.production.openpbr_thin_film import OpenPBRThinFilm
    found += [BelcourIridescence(), OpenPBRThinFilm()]
    # pbrt-v4's LayeredBxDF estimator (docs/pbrt-layered.md)
    from models.pbrt_layered import built_in_models as pbrt_layered
    found += pbrt_layered()
    return found


#: models fitted to a file on request (``gonio fit``, ``gonio evaluate --model NAME``)
FITTED = ("hp15-fit", "ggx1-fit", "ggx2-fit")


def fitted_models() -> dict[str, type[Model]]:
    """The fitted model classes by name (they need parameters: build them with a fit)."""
    from models.fitted import GGX1Fit, GGX2Fit, HP15Fit
    return {c.name: c for c in (HP15Fit, GGX1Fit, GGX2Fit)}


def _project() -> str:
    import goniometer
    return f"goniometer {goniometer.__version__}"


def _plugins(built_in: Sequence[str]) -> tuple[Plugin, ...]:
    """The installed plugins, checked against the built-in names and each other (PluginError)."""
    found = plugins.installed()
    taken: dict[str, Plugin | None] = {n: None for n in built_in}
    for p in found:
        if p.name in taken:
            other = taken[p.name]
            first = (f"the built-in models ({_project()})" if other is None
                     else f"entry point {other.entry_point!r} of {other.source}")
            raise PluginError(f"model name {p.name!r} is registered twice: by {first} and by entry point "
                              f"{p.entry_point!r} of {p.source} (entry-point group {plugins.GROUP}); "
                              f"uninstall or rename one")
        taken[p.name] = p
    return found


def all_models() -> dict[str, Model]:
    """Every analytic model of the harness by its name: the built-in ones in display order, then
    the plugins' (entry-point name order). Raises PluginError on a name clash."""
    found = {m.name: m for m in _built_in_models()}
    for p in _plugins([*found, *FITTED]):
        found[p.name] = p.build()
    return found


def catalogue() -> dict[str, Model | type[Model]]:
    """Every name the harness knows: the analytic models (built-in, then plugins), then the fitted ones."""
    return {**all_models(), **fitted_models()}


def sources() -> dict[str, str]:
    """Where each name of :func:`catalogue` comes from: :data:`BUILT_IN` or ``"<distribution> <version>"``."""
    built_in = [m.name for m in _built_in_models()]
    out = {n: BUILT_IN for n in built_in}
    out.update({p.name: p.source for p in _plugins([*built_in, *FITTED])})
    out.update({n: BUILT_IN for n in FITTED})
    return out


is_spec = adapters.is_spec


class UnknownModel(ModelError):
    """A model name that is neither registered nor an adapter spec; the message lists the known names
    (the one wording of every command: ``unknown model 'x' (known: ...; or python:MODULE:NAME,
    mitsuba:FILE.xml|.json)``)."""

    def __init__(self, name: str, known: Sequence[str]) -> None:
        super().__init__(f"unknown model {name!r} (known: {', '.join(known)}; or python:MODULE:NAME, "
                         f"mitsuba:FILE.xml|.json)")
        self.name = name


def get(name: str) -> Model:
    """The model called ``name``, or the adapter of the spec ``name`` (``python:MODULE:NAME``,
    ``mitsuba:FILE``); :class:`ModelError` naming the known ones otherwise."""
    if is_spec(name):
        return adapters.resolve(name)
    models = all_models()
    if name not in models:
        raise UnknownModel(name, list(models))
    return models[name]


def models_for(names: Sequence[str] | None) -> dict[str, Model]:
    """:func:`all_models`, followed by the adapters of the specs among ``names`` (in their order):
    the models an evaluation of ``names`` chooses from. A bad spec raises ModelError."""
    found = all_models()
    for n in names or ():
        if is_spec(n) and n not in found:
            found[n] = adapters.resolve(n)
    return found


def check_names(names: Sequence[str], *, also: Sequence[str] = ()) -> None:
    """Raise ModelError for the first of ``names`` that is neither a name of :func:`catalogue`
    (nor of ``also``) nor a valid adapter spec (which is resolved, so that a missing module or a file
    Mitsuba refuses is caught before any work)."""
    known = catalogue()
    for n in names:
        if is_spec(n):
            adapters.resolve(n)
        elif n not in known and n not in also:
            raise UnknownModel(n, [*known, *also])


def code_key(names: Sequence[str] | None) -> str:
    """Hash of the code that ``names`` (None: every registered model) depend on outside ``goniometer``
    and ``models``: each plugin's distribution, version and module sources (:func:`models.plugins.module_key`),
    each adapter spec's module or file (:func:`models.adapters.code_identity`); ``""`` when there is
    none, so that built-in models keep the key they had. Enters the report's cache key."""
    parts = []
    built_in = [m.name for m in _built_in_models()]
    for p in _plugins([*built_in, *FITTED]):
        if names is None or p.name in names:
            parts.append(f"plugin {p.name} {p.source} {p.value} {plugins.module_key(p.module)}")
    for n in names or ():
        if is_spec(n):
            parts.append(f"adapter {n} {adapters.code_identity(n)}")
    if not parts:
        return ""
    return hashlib.sha256("\n".join(sorted(parts)).encode()).hexdigest()[:16]
